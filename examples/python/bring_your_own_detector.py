#!/usr/bin/env python3
"""Bring your own detector: instance masks as numpy arrays (from any segmentation model) into
perch2.SixDofEstimator, one RGB-D frame at a time.

    python examples/python/bring_your_own_detector.py --dataset DIR [--detections DETS.json]

`detect()` below stands for your detector (Mask R-CNN, YOLO-seg, SAM/CNOS, ...): it returns, per object,
an obj_id, an H x W bool mask and optionally a box. Here it reads a BOP/COCO detection file (decoding each
RLE mask to a numpy array) or, without one, the dataset's ground-truth visible masks; replace it with a call
to your model. Prints each pose with its distance to the ground truth.
"""

import argparse

import numpy as np

import perch2


def detect(image, detections):
    """[(obj_id, mask H x W bool, box (x, y, w, h) or None), ...] for one image."""
    if detections is None:  # the ground-truth visible masks, as a perfect detector would give
        return [(g.obj_id, m.astype(bool), None) for g, m in zip(image.info.gt, image.masks_visib)]
    out = []
    for d in detections.get((image.scene_id, image.im_id), []):
        if d.has_mask() and d.score >= 0.5:
            out.append((d.category_id, d.mask().astype(bool), tuple(int(round(v)) for v in d.bbox)))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", required=True, help="a BOP dataset (models, camera, depth, rgb)")
    ap.add_argument("--detections", help="a BOP/COCO detection file (default: ground-truth masks)")
    ap.add_argument("--backend", default="thrust_omp")
    ap.add_argument("--images", type=int, default=1, help="how many images to estimate")
    a = ap.parse_args()

    ds = perch2.bop.Dataset(a.dataset)
    detections = None
    if a.detections:
        detections = {}
        for d in perch2.bop.load_detections(a.detections):
            detections.setdefault((d.scene_id, d.image_id), []).append(d)

    obj_ids = sorted(ds.models_info())
    models = [perch2.sixdof_model(ds.load_model(i), ds.model_info(i)) for i in obj_ids]  # mesh + symmetries
    estimator = perch2.SixDofEstimator(models, backend=a.backend)

    for image in list(ds.images())[: a.images]:
        found = detect(image, detections)
        instances = [(obj_ids.index(obj_id), mask, box) for obj_id, mask, box in found]
        # depth: H x W float32 metres (0 = no reading); rgb: H x W x 3 uint8; K: 3 x 3
        result = estimator.estimate(image.depth_m, image.rgb, image.K, instances)
        for (obj_id, _, _), p in zip(found, result.poses):
            gts = [g.T_cam_obj for g in image.info.gt if g.obj_id == obj_id]
            d = min((np.linalg.norm(p.T_cam_obj[:3, 3] - T[:3, 3]) for T in gts), default=float("nan"))
            print(f"image {image.scene_id}/{image.im_id} obj {obj_id}: t = {np.round(p.T_cam_obj[:3, 3], 3)} m, "
                  f"score {p.score:.2f}, {1000 * d:.1f} mm from the ground truth")
        print(f"  {result.timings.total:.2f} s for {len(instances)} instances")


if __name__ == "__main__":
    main()
