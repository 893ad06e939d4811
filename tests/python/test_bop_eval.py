"""perch2.bop (lazy images, detections in both RLE forms, results CSV) and perch2.eval (the numbers of
`perch2 eval --json`)."""

import json

import numpy as np
import pytest

import perch2
from conftest import run


def coco_rle_counts(mask):
    """Independent COCO RLE (pycocotools' rleEncode): runs over the column-major mask, 0-run first."""
    flat = mask.astype(bool).ravel(order="F")
    counts, value, n = [], False, 0
    for v in flat:
        if v != value:
            counts.append(n)
            value, n = v, 0
        n += 1
    counts.append(n)
    return counts


def test_dataset_images_load_lazily_as_views(dataset_6dof):
    ds = perch2.bop.Dataset(str(dataset_6dof))
    images = list(ds.images())
    assert len(images) == 2 and images[0]._image is None  # nothing read yet
    im = images[0]
    assert im.info.camera.width == 640 and len(im.info.gt) >= 2  # from the JSON, no pixels read
    assert im._image is None
    d = im.depth_m
    assert d.shape == (480, 640) and d.dtype == np.float32 and (d > 0).any()
    assert np.shares_memory(d, im.depth_m)  # views of the one loaded image
    assert im.rgb.shape == (480, 640, 3) and len(im.masks_visib) == len(im.info.gt)
    np.testing.assert_array_equal(im.K, [[im.info.camera.fx, 0, im.info.camera.cx],
                                         [0, im.info.camera.fy, im.info.camera.cy], [0, 0, 1]])
    assert ds.model_info(ds.targets()[0].obj_id).diameter_m > 0
    with pytest.raises(perch2.InvalidInput, match="99"):
        ds.image(99, 0)
    with pytest.raises(perch2.FileError, match="nowhere"):
        perch2.bop.Dataset(str(dataset_6dof / "nowhere"))


def test_detections_rle_both_forms(dataset_6dof, tmp_out):
    dets = perch2.bop.load_detections(str(dataset_6dof / "detections_synth.json"))
    assert dets and all(d.has_mask() for d in dets)
    d = dets[0]
    mask = d.mask()
    assert mask.shape == (480, 640) and mask.dtype == np.uint8
    r = perch2.bop.rle_encode(mask.astype(bool))
    assert list(r.counts) == coco_rle_counts(mask)
    assert list(r.counts) == list(d.segmentation.counts)
    s = perch2.bop.rle_to_string(r)
    assert list(perch2.bop.rle_from_string(s, 480, 640).counts) == list(r.counts)
    np.testing.assert_array_equal(perch2.bop.rle_decode(r), mask)
    for compressed in (True, False):
        path = str(tmp_out / f"dets_{compressed}.json")
        perch2.bop.save_detections(path, dets, compressed)
        text = open(path).read()
        assert ('"counts": "' in text or '"counts":"' in text) == compressed
        back = perch2.bop.load_detections(path)
        assert [list(b.segmentation.counts) for b in back] == [list(a.segmentation.counts) for a in dets]
    made = perch2.bop.Detection(1, 0, 5, 0.9, (1, 2, 3, 4), mask=mask.astype(bool))
    assert list(made.segmentation.counts) == list(r.counts)
    assert perch2.bop.detections_by_image(dets)[(d.scene_id, d.image_id)][0] == 0
    with pytest.raises(perch2.InvalidInput, match="RLE string: character outside"):
        perch2.bop.rle_from_string("{{{", 4, 4)


def ground_truth_rows(ds):
    rows = []
    for (scene_id, im_id), targets in ds.targets_by_image().items():
        for g in ds.info(scene_id, im_id).gt:
            rows.append(perch2.PoseEstimate(scene_id, im_id, g.obj_id, 1.0, g.T_cam_obj, 0.5))
    return rows


def test_results_csv_round_trip_and_errors(dataset_6dof, tmp_out):
    ds = perch2.bop.Dataset(str(dataset_6dof))
    rows = ground_truth_rows(ds)
    path = str(tmp_out / "gt.csv")
    perch2.bop.save_results_csv(path, rows)
    back = perch2.bop.load_results_csv(path)
    assert len(back) == len(rows)
    for a, b in zip(rows, back):
        assert (a.scene_id, a.im_id, a.obj_id) == (b.scene_id, b.im_id, b.obj_id)
        np.testing.assert_allclose(a.T_cam_obj, b.T_cam_obj, atol=1e-6)
    (tmp_out / "bad.csv").write_text("scene_id,im_id,obj_id,score,R,t,time\n1,0,5,1,1 0 0,0 0 0,1\n")
    with pytest.raises(perch2.FileError, match="bad.csv:2"):
        perch2.bop.load_results_csv(str(tmp_out / "bad.csv"))
    with pytest.raises(perch2.FileError):
        perch2.bop.load_results_csv(str(tmp_out / "missing.csv"))


def test_eval_gives_the_numbers_of_perch2_eval_json(cli, dataset_6dof, tmp_out):
    ds = perch2.bop.Dataset(str(dataset_6dof))
    rows = ground_truth_rows(ds)
    rows[0].T_cam_obj = rows[0].T_cam_obj @ np.array([[1, 0, 0, 0.004], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    path = tmp_out / "res.csv"
    perch2.bop.save_results_csv(str(path), rows)
    run(cli, "eval", "--dataset", dataset_6dof, "--results", path, "--json", tmp_out / "cli.json")
    expect = json.loads((tmp_out / "cli.json").read_text())
    got = perch2.eval.evaluate(str(dataset_6dof), str(path))
    assert got == expect
    overall = got["overall"]
    assert "auc_add_or_adds" in overall and "auc_add_s" not in overall
    assert overall["adds_below_1cm"] == 1.0 and overall["auc_add"] < 1.0  # 4 mm off on one instance
    report, _ = perch2.eval.report(str(dataset_6dof), str(path), vsd=False)
    assert not report.vsd_computed and report.overall.auc_add_or_adds == pytest.approx(overall["auc_add_or_adds"])
    assert "ADD(-S)" in perch2.eval.format_report(report)
    calls = []
    perch2.eval.report(str(dataset_6dof), rows, vsd=False, progress=lambda d, t: calls.append((d, t)))
    assert calls[-1][0] == calls[-1][1] == 2


def test_rows_and_image_results_pickle(dataset_6dof):
    import pickle

    ds = perch2.bop.Dataset(str(dataset_6dof))
    runner = perch2.BopRunner(ds.bop, perch2.RunOptions("6dof", backend="cpu"))
    scene_id, im_id = runner.images()[0]
    r = runner.estimate(scene_id, im_id)
    back = pickle.loads(pickle.dumps(r))
    assert back.sixdof is None and r.sixdof is not None  # the full result stays behind
    assert (back.scene_id, back.im_id, back.seconds, back.stages) == (r.scene_id, r.im_id, r.seconds, r.stages)
    assert back.row_found == r.row_found and back.row_models == r.row_models and back.instances == r.instances
    for a, b in zip(r.rows, back.rows):
        assert (a.scene_id, a.im_id, a.obj_id, a.score, a.time_s) == (b.scene_id, b.im_id, b.obj_id, b.score, b.time_s)
        np.testing.assert_array_equal(a.T_cam_obj, b.T_cam_obj)
    t = pickle.loads(pickle.dumps(ds.targets()[0]))
    assert (t.scene_id, t.im_id, t.obj_id, t.inst_count) == (ds.targets()[0].scene_id, ds.targets()[0].im_id,
                                                           ds.targets()[0].obj_id, ds.targets()[0].inst_count)


def test_images_from_bytes_estimate_like_images_from_files(dataset_6dof):
    import pickle

    ds = perch2.bop.Dataset(str(dataset_6dof))
    runner = perch2.BopRunner(ds.bop, perch2.RunOptions("6dof", backend="cpu"))
    scene_id, im_id = runner.images()[0]
    o = runner.load_options()
    files = ds.read_image_files(scene_id, im_id, o.rgb, o.depth, o.masks_visib, o.masks)
    files = pickle.loads(pickle.dumps(files))  # as a driver would send them
    assert files.depth.path.endswith("000000.png") and files.depth.bytes[:4] == b"\x89PNG"
    image = perch2.decode_image(ds.info(scene_id, im_id), files)
    np.testing.assert_array_equal(image.frame.depth_m, ds.load_image(scene_id, im_id).frame.depth_m)
    a, b = runner.estimate(image).rows, runner.estimate(scene_id, im_id).rows
    assert [r.obj_id for r in a] == [r.obj_id for r in b]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.T_cam_obj, y.T_cam_obj)
    files.depth = perch2.FileBytes("sent/depth.png", files.depth.bytes[:50])
    with pytest.raises(perch2.FileError, match="sent/depth.png"):
        perch2.decode_image(ds.info(scene_id, im_id), files)


def test_results_writer_resume_and_torn_lines(dataset_6dof, tmp_out):
    ds = perch2.bop.Dataset(str(dataset_6dof))
    rows = ground_truth_rows(ds)
    by_image = {}
    for r in rows:
        by_image.setdefault((r.scene_id, r.im_id), []).append(r)
    (k0, r0), (k1, r1) = sorted(by_image.items())
    path = str(tmp_out / "stream.csv")
    with perch2.bop.ResultsWriter(path) as w:
        w.write_image(*k0, r0)
        w.write_image(5, 5, [])  # an image with no rows still counts as done
        with pytest.raises(perch2.InvalidInput):
            w.write_image(*k0, r0)  # each image exactly once
    assert perch2.bop.completed_images(path) == {k0: len(r0), (5, 5): 0}
    with open(path, "a") as f:
        f.write("1,1,5,0.9,1 0 0")  # a torn last line
    with pytest.raises(perch2.FileError, match="torn"):
        perch2.bop.load_results_csv(path)
    kept, torn = perch2.bop.load_results_csv(path, drop_torn_last_line=True, return_torn_line=True)
    assert len(kept) == len(r0) and torn == len(r0) + 2
    w = perch2.bop.ResultsWriter(path, resume=True)
    assert w.is_done(*k0) and not w.is_done(*k1) and w.resume_notes()
    w.write_image(*k1, r1)
    w.close()
    assert len(perch2.bop.load_results_csv(path)) == len(rows)
    with pytest.raises(perch2.InvalidInput, match="closed"):
        w.done()


def test_a_malformed_entry_costs_only_its_image(dataset_6dof, tmp_out):
    import shutil

    root = tmp_out / "bad_entry"
    shutil.copytree(dataset_6dof, root)
    gt = root / "test" / "000001" / "scene_gt.json"
    data = json.loads(gt.read_text())
    data["1"][0]["cam_R_m2c"] = [1, 2]  # not 9 numbers
    gt.write_text(json.dumps(data))
    ds = perch2.bop.Dataset(str(root))
    assert list(ds.bad_images()) == [(1, 1)] and "cam_*_m2c" in ds.bad_image(1, 1).reason
    assert ds.bad_image(1, 0) is None and ds.image_ids() == [(1, 0)]
    with pytest.raises(perch2.FileError, match="scene_gt.json"):
        ds.info(1, 1)
