"""perch2.Tracker from Python: a generated video (perch2 generate --mode video) tracked from perch2's own
search, as `perch2 track` does, numpy frames in; bad input raises InvalidInput naming it."""

import numpy as np
import pytest

import perch2
from conftest import run


@pytest.fixture(scope="module")
def video(cli, tmp_path_factory):
    """1 scene, 10 frames of a hand-held camera circling 3 objects (seed 11, as tests/cli_track_smoke.cmake)."""
    out = tmp_path_factory.mktemp("video")
    run(cli, "generate", "--mode", "video", "--scenes", "1", "--images-per-scene", "10", "--objects", "3",
        "--seed", "11", "--out", out)
    return perch2.bop.Dataset(out)


def models_of(ds):
    ids = sorted(ds.models_info().keys())
    return ids, [perch2.sixdof_model(ds.load_model(i), ds.model_info(i)) for i in ids]


def test_tracker_follows_a_video_from_the_search(video):
    ids, models = models_of(video)
    images = list(video.images(masks_visib=False))
    assert len(images) == 10
    targets = video.targets_by_image()[(1, 0)]
    objects = [(ids.index(t.obj_id), t.inst_count) for t in targets]
    found = perch2.SixDofEstimator(models).estimate_scene(images[0].frame, objects)
    tracker = perch2.Tracker(models)
    r = tracker.start(images[0].frame, found)  # a SixDofSceneResult: its found poses
    assert len(r.objects) == 3
    for image in images[1:]:
        # numpy in: the same arrays a camera driver gives
        r = tracker.update(image.depth_m, image.rgb, image.K)
        assert r.timings.total > 0
        for o in r.objects:
            assert o.state == perch2.TrackState.Tracking
            assert 0.6 <= o.score <= 1
            T = o.T_cam_obj
            assert T.shape == (4, 4) and T.dtype == np.float32
            # the nearest ground-truth instance of its model, by translation
            gt = [g.T_cam_obj for g in image.info.gt if g.obj_id == ids[o.model]]
            assert min(np.linalg.norm(T[:3, 3] - g[:3, 3]) for g in gt) < 0.02
    assert [o.object for o in tracker.objects] == [0, 1, 2]


def test_tracker_settings_and_starts(video):
    ids, models = models_of(video)
    image = next(video.images(masks_visib=False))
    s = perch2.TrackSettings()
    s.recovery.background = False
    s.min_score = 0.5
    tracker = perch2.Tracker(models, backend="cpu", settings=s)
    assert tracker.backend == "cpu"
    assert tracker.settings.min_score == pytest.approx(0.5)
    tracker.settings.recovery.per_frame = 2  # a live reference
    assert tracker.settings.recovery.per_frame == 2
    g = image.info.gt[0]
    r = tracker.start(image.frame, [(ids.index(g.obj_id), g.T_cam_obj)])
    assert len(r.objects) == 1 and r.objects[0].state == perch2.TrackState.Tracking
    assert -1.0 <= r.objects[0].appearance <= 1.0
    start = perch2.TrackStart(ids.index(g.obj_id), g.T_cam_obj)
    assert tracker.start(image.frame, [start]).objects[0].model == ids.index(g.obj_id)


def test_tracker_refuses_bad_input(video):
    ids, models = models_of(video)
    image = next(video.images(masks_visib=False))
    tracker = perch2.Tracker(models)
    with pytest.raises(perch2.InvalidInput, match="start\\(\\) first"):
        tracker.update(image.frame)
    with pytest.raises(perch2.InvalidInput, match="no objects"):
        tracker.start(image.frame, [])
    with pytest.raises(perch2.InvalidInput, match="model 99"):
        tracker.start(image.frame, [(99, np.eye(4))])
    with pytest.raises(perch2.InvalidInput, match="starts\\[0\\]"):
        tracker.start(image.frame, ["cat"])
    g = image.info.gt[0]
    tracker.start(image.frame, [(ids.index(g.obj_id), g.T_cam_obj)])
    with pytest.raises(perch2.InvalidInput, match="depth"):
        tracker.update(image.depth_m.astype(np.int32), image.rgb, image.K)
    depth = image.depth_m.copy()
    depth[5, 7] = np.nan
    with pytest.raises(perch2.InvalidInput, match="pixel \\(7, 5\\) is nan"):
        tracker.update(depth, image.rgb, image.K)
    with pytest.raises(perch2.InvalidInput, match="camera differs"):
        tracker.update(image.depth_m[:240, :320].copy(), image.rgb[:240, :320].copy(), image.K)
    bad = perch2.TrackSettings()
    bad.min_visible_ratio = 2.0
    with pytest.raises(perch2.InvalidInput, match="min_visible_ratio"):
        perch2.Tracker(models, settings=bad)
    bad = perch2.TrackSettings()
    assert bad.turn_hold.sweep_every_frames == 10 and bad.turn_hold.sweep_turns == 36
    bad.turn_hold.sweep_stride = 0
    with pytest.raises(perch2.InvalidInput, match="sweep_stride"):
        perch2.Tracker(models, settings=bad)
    bad = perch2.TrackSettings()
    assert bad.min_appearance == pytest.approx(0.1) and bad.max_track_move_m == pytest.approx(0.06)
    bad.min_appearance = -2.0
    with pytest.raises(perch2.InvalidInput, match="min_appearance"):
        perch2.Tracker(models, settings=bad)
    bad = perch2.TrackSettings()
    assert bad.recovery.max_jump_m == pytest.approx(0.1)
    bad.recovery.contradicted_fraction = -0.5
    with pytest.raises(perch2.InvalidInput, match="contradicted_fraction"):
        perch2.Tracker(models, settings=bad)
