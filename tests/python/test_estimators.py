"""The estimators from Python: the same poses as the perch2 CLI on generated datasets (row for row, 3-DoF
and 6-DoF), masks from numpy, bad inputs, and the GIL released while they run."""

import csv
import sys
import threading
import time

import numpy as np
import pytest

import perch2
from conftest import run


def rows_without_time(path):
    """The CSV's rows with the time column dropped (wall clock, differs between runs)."""
    with open(path) as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["scene_id", "im_id", "obj_id", "score", "R", "t", "time"]
    return [r[:6] for r in rows[1:]]


def manual_3dof(root):
    """The 3-DoF run with the estimator's own binding (not BopRunner): models, settings, per-image glue."""
    ds = perch2.bop.Dataset(str(root))
    images = ds.targets_by_image()
    ids = sorted({t.obj_id for ts in images.values() for t in ts})
    settings = perch2.tabletop_variant("perch2-c")
    settings.strict_instances = False
    est = perch2.TabletopEstimator([perch2.tabletop_model(ds.load_model(i), ds.model_info(i)) for i in ids],
                                   settings=settings)
    model_of = {obj_id: k for k, obj_id in enumerate(ids)}
    rows = []
    for (scene_id, im_id), targets in images.items():
        image = ds.load_image(scene_id, im_id, masks_visib=False)
        rows += perch2.estimate_bop_image(est, image, targets, model_of)[0]
    return rows


def manual_6dof(root):
    """The 6-DoF run (ground-truth masks) with SixDofEstimator's binding and the library's BOP glue."""
    ds = perch2.bop.Dataset(str(root))
    images = ds.targets_by_image()
    ids = sorted({t.obj_id for ts in images.values() for t in ts})
    est = perch2.SixDofEstimator([perch2.sixdof_model(ds.load_model(i), ds.model_info(i)) for i in ids])
    model_of = {obj_id: k for k, obj_id in enumerate(ids)}
    rows = []
    for (scene_id, im_id), targets in images.items():
        image = ds.load_image(scene_id, im_id)
        found = perch2.bop_instances_from_gt(image, model_of, perch2.BoxKind.Full)
        instances = perch2.usable_instances(perch2.only_targets(found, targets), image.frame, est.settings.observed)
        rows += perch2.estimate_bop_image(est, image, instances)[0]
    return rows


def test_3dof_python_gives_the_cli_poses(cli, dataset_3dof, tmp_out):
    run(cli, "estimate", "--mode", "3dof", "--dataset", dataset_3dof, "--out", tmp_out / "cli.csv")
    expect = rows_without_time(tmp_out / "cli.csv")
    assert len(expect) >= 4
    for name, rows in (("runner", perch2.bop.estimate_3dof(str(dataset_3dof))), ("estimator", manual_3dof(dataset_3dof))):
        perch2.bop.save_results_csv(str(tmp_out / f"{name}.csv"), rows)
        assert rows_without_time(tmp_out / f"{name}.csv") == expect, name


def target_detections(dataset, path):
    """The generated detections of target objects only, written with perch2.bop.save_detections (the CLI
    cannot estimate an image with a detection of an object it has no model of)."""
    ids = {t.obj_id for t in perch2.bop.Dataset(str(dataset)).targets()}
    dets = [d for d in perch2.bop.load_detections(str(dataset / "detections_synth.json")) if d.category_id in ids]
    perch2.bop.save_detections(str(path), dets)
    return str(path)


@pytest.mark.parametrize("masks", ["gt", "detections"])
def test_6dof_python_gives_the_cli_poses(cli, dataset_6dof, tmp_out, masks):
    source = "gt" if masks == "gt" else target_detections(dataset_6dof, tmp_out / "detections.json")
    run(cli, "estimate", "--mode", "6dof", "--dataset", dataset_6dof, "--masks", source, "--out", tmp_out / "cli.csv")
    expect = rows_without_time(tmp_out / "cli.csv")
    assert len(expect) >= 3
    runs = [("runner", perch2.bop.estimate_6dof(str(dataset_6dof), masks=source))]
    if masks == "gt":
        runs.append(("estimator", manual_6dof(dataset_6dof)))
    for name, rows in runs:
        perch2.bop.save_results_csv(str(tmp_out / f"{name}.csv"), rows)
        assert rows_without_time(tmp_out / f"{name}.csv") == expect, name


def test_runner_reports_a_bad_image_and_goes_on(dataset_6dof, tmp_out):
    import shutil

    root = tmp_out / "broken"
    shutil.copytree(dataset_6dof, root)
    depth = sorted((root / "test" / "000001" / "depth").glob("*.png"))[0]
    depth.write_bytes(depth.read_bytes()[:100])  # truncated PNG
    errors = []
    rows = perch2.bop.estimate_6dof(str(root), errors=errors)
    assert len(errors) == 1 and isinstance(errors[0], perch2.ImageError)
    assert (errors[0].scene_id, errors[0].im_id) == (1, 0) and depth.name in errors[0].reason
    assert rows and all(r.im_id == 1 for r in rows)
    with pytest.raises(perch2.ImageError, match="scene 1 image 0"):
        perch2.bop.estimate_6dof(str(root))


def gt_instances(ds, scene_id, im_id):
    """The image's ground-truth masks as numpy arrays, the handoff a detector would make."""
    image = ds.image(scene_id, im_id)
    ids = sorted({g.obj_id for g in image.info.gt})
    instances = [(ids.index(g.obj_id), m.astype(bool), None) for g, m in zip(image.info.gt, image.masks_visib)]
    return image, ids, instances


def test_sixdof_with_numpy_masks_finds_the_ground_truth(dataset_6dof):
    ds = perch2.bop.Dataset(str(dataset_6dof))
    scene_id, im_id = ds.image_ids()[0]
    image, ids, instances = gt_instances(ds, scene_id, im_id)
    models = [perch2.sixdof_model(ds.load_model(i), ds.model_info(i)) for i in ids]
    est = perch2.SixDofEstimator(models, backend="thrust_omp")
    r = est.estimate(image.depth_m, image.rgb, image.K, instances)
    assert len(r.poses) == len(instances)
    for p, g in zip(r.poses, image.info.gt):
        assert p.T_cam_obj.shape == (4, 4) and p.T_cam_obj.dtype == np.float32
        assert np.linalg.norm(p.T_cam_obj[:3, 3] - g.T_cam_obj[:3, 3]) < 0.02
        assert 0 <= p.score <= 1
    assert r.timings.total > 0 and r.hypotheses_total > 0
    # the same from a frame object (no copy of the arrays) gives the same poses
    r2 = est.estimate(image.frame, instances)
    for a, b in zip(r.poses, r2.poses):
        np.testing.assert_array_equal(a.T_cam_obj, b.T_cam_obj)


def test_sixdof_bad_instances_raise_invalid_input(dataset_6dof):
    ds = perch2.bop.Dataset(str(dataset_6dof))
    image, ids, instances = gt_instances(ds, *ds.image_ids()[0])
    est = perch2.SixDofEstimator([ds.load_model(i) for i in ids], backend="cpu")
    depth, rgb, K = image.depth_m, image.rgb, image.K
    with pytest.raises(perch2.InvalidInput, match=r"instances\[0\] mask: is 64 x 48 \(W x H\), the depth is 640 x 480"):
        est.estimate(depth, rgb, K, [(0, np.ones((48, 64), bool), None)])
    with pytest.raises(perch2.InvalidInput, match=r"instances\[0\] mask: must be a bool or uint8 mask"):
        est.estimate(depth, rgb, K, [(0, np.ones(depth.shape, np.float32), None)])
    with pytest.raises(perch2.InvalidInput, match=r"instances\[0\] box \(x, y, w, h\): must have shape \(n, 4\)"):
        est.estimate(depth, rgb, K, [(0, instances[0][1], (1, 2, 3))])
    with pytest.raises(perch2.InvalidInput, match=r"instances\[0\]: must be a perch2.SixDofInstance"):
        est.estimate(depth, rgb, K, [(0,)])
    with pytest.raises(perch2.InvalidInput, match="empty"):
        est.estimate(depth, rgb, K, [(0, np.zeros(depth.shape, bool), None)])
    with pytest.raises(perch2.InvalidInput, match="model"):
        est.estimate(depth, rgb, K, [(7, instances[0][1], None)])
    bad = depth.copy()
    bad[10, 20] = np.nan
    with pytest.raises(perch2.InvalidInput, match=r"depth: depth at pixel \(20, 10\) is nan"):
        est.estimate(bad, rgb, K, instances)
    with pytest.raises(perch2.InvalidInput, match="depth: must be float32"):
        est.estimate(depth.astype(np.float64), rgb, K, instances)
    with pytest.raises(perch2.InvalidInput, match="models\\[0\\]: must be a perch2.Mesh"):
        perch2.SixDofEstimator(["cat.ply"])


def test_tabletop_from_numpy_objects_by_name_and_bad_requests(dataset_3dof):
    ds = perch2.bop.Dataset(str(dataset_3dof))
    (scene_id, im_id), targets = next(iter(ds.targets_by_image().items()))
    ids = sorted({t.obj_id for t in ds.targets()})
    meshes = [ds.load_model(i) for i in ids]
    est = perch2.TabletopEstimator(meshes, backend="cpu", variant="perch2-c")
    est.settings.strict_instances = False
    image = ds.image(scene_id, im_id)
    objects = {meshes[ids.index(t.obj_id)].name: t.inst_count for t in targets}
    r = est.estimate(image.depth_m, image.rgb, image.K, objects, T_cam_world=image.info.T_cam_world)
    assert len(r.poses) == sum(t.inst_count for t in targets)
    for p in r.poses:
        T = p.T_world_obj
        assert T.shape == (4, 4) and abs(T[0, 3] - p.x_m) < 1e-5 and abs(T[1, 3] - p.y_m) < 1e-5
        assert p.cost.rendered_points > 0
    assert r.timings.total >= r.timings.render > 0
    with pytest.raises(perch2.InvalidInput, match="model name: no model called 'nope'"):
        est.estimate(image.frame, {"nope": 1})
    with pytest.raises(perch2.InvalidInput, match="T_cam_world: must be a 4 x 4 pose"):
        est.estimate(image.frame, {0: 1}, T_cam_world=np.eye(3))
    with pytest.raises(perch2.InvalidInput, match="variant: unknown variant 'perch3'"):
        perch2.TabletopEstimator(meshes, variant="perch3")
    est.settings.xy_step_m = -1.0  # a live reference into the estimator's settings
    with pytest.raises(perch2.InvalidInput, match="xy_step_m and yaw_step_rad must be finite and > 0"):
        est.estimate(image.frame, {0: 1}, T_cam_world=image.info.T_cam_world)


def progress_during(call):
    """(times a second Python thread ran during the middle 80 % of call(), call's seconds). The thread notes
    the time every 1,000 loops and then yields the GIL (sleep(0)); forced GIL switches are off meanwhile
    (switch interval 100 s), so it can run during call() only if call() releases the GIL."""
    stamps = []
    stop = threading.Event()

    def spin():
        n = 0
        while not stop.is_set():
            n += 1
            if n % 1000 == 0:
                stamps.append(time.perf_counter())
                time.sleep(0)

    interval = sys.getswitchinterval()
    sys.setswitchinterval(100.0)
    try:
        t = threading.Thread(target=spin)
        t.start()
        time.sleep(0.05)
        t0 = time.perf_counter()
        call()
        t1 = time.perf_counter()
        stop.set()
        t.join()
    finally:
        sys.setswitchinterval(interval)
    margin = 0.1 * (t1 - t0)
    return sum(1 for x in stamps if t0 + margin < x < t1 - margin), t1 - t0


def test_the_gil_is_released_while_estimating(dataset_6dof):
    ds = perch2.bop.Dataset(str(dataset_6dof))
    image, ids, instances = gt_instances(ds, *ds.image_ids()[0])
    est = perch2.SixDofEstimator([ds.load_model(i) for i in ids], backend="cpu")
    frame = image.frame
    during, seconds = progress_during(lambda: est.estimate(frame, instances))
    assert seconds > 0.2
    assert during > 20, f"the other thread ran {during} times in {seconds:.2f} s"
    r = perch2.Renderer([ds.load_model(i) for i in ids], backend="cpu")
    s = perch2.RenderSettings()
    s.stride = 1
    poses = np.stack([g.T_cam_obj for g in image.info.gt] * 200)
    during, seconds = progress_during(lambda: r.render(0, poses, image.info.camera, s))
    assert during > 20, f"the other thread ran {during} times in {seconds:.2f} s (render)"


def test_the_gil_test_sees_a_held_gil():
    # The same measurement around a call that holds the GIL (numpy -> C++ conversion of a large frame).
    depth = np.full((5000, 5000), 0.5, np.float32)
    K = perch2.Intrinsics(500, 500, 2500, 2500, 5000, 5000)
    during, seconds = progress_during(lambda: perch2.RgbdFrame(depth, None, K))
    assert during == 0, f"the other thread ran {during} times in {seconds:.2f} s"
