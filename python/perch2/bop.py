"""BOP datasets from Python: the reader with lazily loaded images, detection files, results CSV, and the
per-dataset estimation loops of `perch2 estimate` (same models, settings and rows as the CLI).

    ds = perch2.bop.Dataset("/data/lm")
    for image in ds.images():            # nothing is read until a pixel attribute is used
        depth_m, rgb = image.depth_m, image.rgb
    rows = perch2.bop.estimate_6dof(ds, masks="detections.json")   # the rows `perch2 estimate --mode 6dof` writes
    perch2.bop.save_results_csv("results.csv", rows)

Everything here calls the C++ library (perch2._perch2, BopRunner for the runs); only the loops over images
are Python.
"""

from ._perch2 import (  # noqa: F401  (the C++ dataset layer, re-exported)
    BopDataset,
    BopImage,
    BopInstances,
    BadImage,
    BopRunner,
    BoxKind,
    Detection,
    FileBytes,
    ImageError,
    ImageFiles,
    ImageInfo,
    ImageResult,
    ModelInfo,
    PoseEstimate,
    ResultsWriter,
    RunMode,
    Rle,
    RunOptions,
    SixDofEstimator,
    TabletopEstimator,
    TabletopModel,
    Target,
    bop_id,
    bop_instances_from_detections,
    bop_instances_from_gt,
    completed_images,
    decode_image,
    detections_by_image,
    estimate_bop_image,
    load_detections,
    load_models_info,
    load_results_csv,
    only_targets,
    rle_decode,
    rle_encode,
    rle_from_string,
    rle_to_string,
    save_detections,
    save_results_csv,
    sixdof_model,
    symmetric_about_z,
    tabletop_model,
    tabletop_variant,
    usable_instances,
)


class Image:
    """One image of a dataset, read on first use of a pixel attribute (depth_m, rgb, masks_visib, masks,
    frame) and then kept. `info` (camera, ground truth, T_cam_world) needs no read."""

    def __init__(self, dataset, scene_id, im_id, rgb=True, depth=True, masks_visib=True, masks=False):
        self._dataset = dataset
        self.scene_id, self.im_id = scene_id, im_id
        self._parts = dict(rgb=rgb, depth=depth, masks_visib=masks_visib, masks=masks)
        self._image = None

    @property
    def info(self):
        return self._dataset.info(self.scene_id, self.im_id)

    @property
    def bop_image(self):
        """The loaded perch2.BopImage (read now if it was not yet)."""
        if self._image is None:
            self._image = self._dataset.load_image(self.scene_id, self.im_id, **self._parts)
        return self._image

    @property
    def frame(self):
        return self.bop_image.frame

    @property
    def depth_m(self):
        """H x W float32 metres (a view of the loaded image, no copy)."""
        return self.bop_image.frame.depth_m

    @property
    def rgb(self):
        """H x W x 3 uint8 (a view of the loaded image, no copy), or None."""
        return self.bop_image.frame.rgb

    @property
    def K(self):
        return self.info.camera.K

    @property
    def masks_visib(self):
        return self.bop_image.masks_visib

    @property
    def masks(self):
        return self.bop_image.masks

    def __repr__(self):
        return f"perch2.bop.Image(scene_id={self.scene_id}, im_id={self.im_id})"


class Dataset:
    """A BOP dataset (perch2.BopDataset: opening it parses the JSON files only) whose images load lazily.
    Every BopDataset method is available on it (model_info, load_model, targets, info, load_image, ...)."""

    def __init__(self, root, split="test", targets_file="", models_dir="", ground_truth=True):
        self.bop = BopDataset(str(root), split=split, targets_file=targets_file, models_dir=models_dir,
                              ground_truth=ground_truth)

    def __getattr__(self, name):
        return getattr(self.bop, name)

    def image(self, scene_id, im_id, **parts):
        """A lazy Image; parts: rgb, depth, masks_visib (default True), masks (default False)."""
        if not self.bop.has_image(scene_id, im_id):
            self.bop.info(scene_id, im_id)  # raises InvalidInput naming the image
        return Image(self.bop, scene_id, im_id, **parts)

    def images(self, scenes=None, **parts):
        """Lazy images of the split in (scene, image) order, optionally only those of `scenes`."""
        for scene_id, im_id in self.bop.image_ids():
            if scenes is None or scene_id in scenes:
                yield Image(self.bop, scene_id, im_id, **parts)

    def targets_by_image(self, first_scene=0, last_scene=1 << 30):
        """{(scene_id, im_id): [Target, ...]} in ascending order, as `perch2 estimate` visits them."""
        out = {}
        for t in self.bop.targets():
            if first_scene <= t.scene_id <= last_scene and t.inst_count > 0:
                out.setdefault((t.scene_id, t.im_id), []).append(t)
        return dict(sorted(out.items()))

    def __repr__(self):
        return f"perch2.bop.Dataset({self.bop.root()!r}, {len(self.bop.image_ids())} images)"


def _bop(dataset):
    return dataset if isinstance(dataset, Dataset) else Dataset(dataset)


def estimate(dataset, options, scenes=None, progress=None, errors=None):
    """Every target image of a BOP dataset through perch2.BopRunner (what `perch2 estimate` runs): the
    models loaded and the estimator built once, one image at a time. Returns the BOP rows. An image that
    cannot be estimated (a bad file, a malformed entry) raises perch2.ImageError, or, with `errors` a list,
    is appended to it and skipped. progress(done, total), if given, is called after each image. A dataset
    given by its path is opened without its ground truth unless the masks come from it (6-DoF, masks "gt")."""
    if isinstance(dataset, Dataset):
        ds = dataset
    else:
        ds = Dataset(dataset, ground_truth=options.mode == RunMode.SixDof and options.masks == "gt")
    runner = BopRunner(ds.bop, options)
    images = runner.images(*(scenes or (0, 1 << 30)))
    rows = []
    for n, (scene_id, im_id) in enumerate(images):
        try:
            rows += runner.estimate(scene_id, im_id).rows
        except ImageError as e:
            if errors is None:
                raise
            errors.append(e)
        if progress:
            progress(n + 1, len(images))
    return rows


def estimate_3dof(dataset, variant="perch2c", backend="thrust_omp", settings=None, **kw):
    """3-DoF estimation of every target of a BOP dataset, as `perch2 estimate --mode 3dof`: the target
    objects' models (z up, one yaw when symmetric about z), the variant's settings (over `settings`) with
    strict_instances off, the table frame from scene_camera.json when given. Returns the BOP rows (score =
    1 / (1 + cost), time = seconds of the image's estimate). Other keywords as estimate()."""
    return estimate(dataset, RunOptions("3dof", backend=backend, variant=variant, tabletop=settings), **kw)


def estimate_6dof(dataset, masks="gt", box="full", backend="thrust_omp", settings=None, **kw):
    """6-DoF estimation of every target instance of a BOP dataset, as `perch2 estimate --mode 6dof`: instances
    from the ground-truth visible masks (masks="gt"; box "full" or "visible") or a detection file (COCO RLE),
    the targets kept, instances without enough depth skipped. Returns the BOP rows (score in [0, 1]). Other
    keywords as estimate()."""
    return estimate(dataset, RunOptions("6dof", backend=backend, masks=str(masks), box=box, sixdof=settings), **kw)
