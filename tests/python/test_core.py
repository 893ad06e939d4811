"""Core types from Python: meshes from arrays, frames, cloud batches (zero-copy views), the errors, the
settings bound from C++ (defaults, docs, nested settings)."""

import re

import numpy as np
import pytest

import perch2


def box_mesh(size=0.1, name="box"):
    h = size / 2
    v = np.array([[x, y, z] for z in (-h, h) for y in (-h, h) for x in (-h, h)], dtype=np.float64)
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], dtype=np.int64)
    return v, f


def test_errors_are_value_and_os_errors():
    assert issubclass(perch2.InvalidInput, ValueError)
    assert issubclass(perch2.FileError, OSError)


def test_mesh_from_arrays_like_trimesh_and_open3d():
    v, f = box_mesh()
    rgba = np.tile(np.array([[255, 0, 0, 255]], np.uint8), (8, 1))  # trimesh: visual.vertex_colors (n, 4)
    m = perch2.Mesh(v, f, colors=rgba, name="box")
    assert m.vertices.dtype == np.float32 and m.vertices.shape == (8, 3)
    np.testing.assert_allclose(m.vertices, v, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(m.faces, f)
    np.testing.assert_array_equal(m.colors, np.tile([255, 0, 0], (8, 1)))
    m2 = perch2.Mesh(v, f.astype(np.int32), colors=np.full((8, 3), 0.5))  # Open3D: float colours in [0, 1]
    assert (m2.colors == 128).all()
    # per-vertex uv (trimesh) become per-corner uv; a texture is needed with them
    tex = np.zeros((4, 4, 3), np.uint8)
    m3 = perch2.Mesh(v, f, uv=np.zeros((8, 2)), texture=tex)
    assert m3.has_texture() and m3.corner_uvs.shape == (12, 3, 2)
    # views, not copies: the array properties share the mesh's storage
    assert np.shares_memory(m.vertices, m.vertices)
    m.vertices[0, 0] = 1.0
    assert m.vertices[0, 0] == 1.0


@pytest.mark.parametrize(
    "kwargs, fragment",
    [
        (dict(vertices=np.zeros((8, 2))), "vertices: must have shape (n, 3)"),
        (dict(vertices=np.zeros((8, 3), np.complex64)), "vertices: must hold real numbers, got complex64"),
        (dict(faces=np.array([[0, 1, 9]])), "triangle references vertex 9 of 8"),
        (dict(faces=np.zeros((3, 4), np.int64)), "faces: must have shape (m, 3)"),
        (dict(colors=np.zeros((7, 3), np.uint8)), "colors: must have shape (8, 3)"),
        (dict(colors=np.full((8, 3), 2.0)), "float colours must lie in [0, 1]"),
        (dict(uv=np.zeros((8, 2))), "has texture coordinates but no texture"),
        (dict(uv=np.zeros((5, 2)), texture=np.zeros((2, 2, 3), np.uint8)), "uv: must be per vertex"),
        (dict(texture=np.zeros((2, 2, 3), np.float32)), "texture: must be uint8"),
        (dict(vertices=np.full((8, 3), np.nan)), "has a non-finite vertex"),
    ],
)
def test_bad_mesh_arrays_raise_invalid_input(kwargs, fragment):
    v, f = box_mesh()
    args = dict(vertices=v, faces=f)
    args.update(kwargs)
    with pytest.raises(perch2.InvalidInput, match=re.escape(fragment)):
        perch2.Mesh(**args)


def test_load_mesh_missing_file_is_file_error(tmp_path):
    with pytest.raises(perch2.FileError, match="nothing.ply"):
        perch2.load_mesh(str(tmp_path / "nothing.ply"))
    with pytest.raises(OSError):
        perch2.load_mesh(str(tmp_path / "nothing.ply"))


def test_load_mesh_scale_and_save_round_trip(tmp_path):
    v, f = box_mesh()
    perch2.save_ply(str(tmp_path / "box.ply"), perch2.Mesh(v * 1000, f, name="box"))  # millimetres
    m = perch2.load_mesh(str(tmp_path / "box.ply"), scale=0.001)
    np.testing.assert_allclose(m.vertices, v, atol=1e-6)
    assert m.name == "box"
    with pytest.raises(perch2.InvalidInput, match="scale"):
        perch2.load_mesh(str(tmp_path / "box.ply"), scale=0.0)


K = np.array([[500.0, 0, 32], [0, 500, 24], [0, 0, 1]])


def test_frame_views_share_the_frames_storage():
    depth = np.full((48, 64), 0.8, np.float32)
    rgb = np.zeros((48, 64, 3), np.uint8)
    f = perch2.RgbdFrame(depth, rgb, K)
    assert f.camera.width == 64 and f.camera.height == 48
    a, b = f.depth_m, f.depth_m
    assert np.shares_memory(a, b) and a.dtype == np.float32
    a[0, 0] = 2.0
    assert f.depth_m[0, 0] == 2.0  # a view of the C++ frame, not a copy
    assert not np.shares_memory(f.depth_m, depth)  # numpy -> C++ images is one copy (documented)
    assert np.shares_memory(f.rgb, f.rgb)
    # uint16 depth with a scale
    f16 = perch2.RgbdFrame((depth * 1000).astype(np.uint16), None, K, depth_scale_m=0.001)
    np.testing.assert_allclose(f16.depth_m, 0.8, atol=1e-6)
    assert f16.rgb is None
    # strided input is copied correctly
    big = np.zeros((96, 128), np.float32)
    big[::2, ::2] = np.arange(48 * 64, dtype=np.float32).reshape(48, 64) / 1e4
    fs = perch2.RgbdFrame(big[::2, ::2], None, K)
    np.testing.assert_array_equal(fs.depth_m, big[::2, ::2])


@pytest.mark.parametrize(
    "depth, rgb, Km, scale, fragment",
    [
        (np.zeros((48, 64), np.float64), None, K, None, "depth: must be float32 (metres) or uint16"),
        (np.zeros((48, 64, 1), np.float32), None, K, None, "depth: must be an H x W array"),
        (np.zeros((48, 64), np.uint16), None, K, None, "depth: is uint16: pass depth_scale_m"),
        (np.zeros((48, 64), np.float32), None, K, 0.001, "depth_scale_m: applies to uint16 depth only"),
        (np.full((48, 64), np.nan, np.float32), None, K, None, "depth: depth at pixel (0, 0) is nan"),
        (np.full((48, 64), -1, np.float32), None, K, None, "depth must be finite and >= 0"),
        (np.zeros((48, 64), np.float32), np.zeros((48, 64, 3), np.float32), K, None, "rgb: must be uint8"),
        (np.zeros((48, 64), np.float32), np.zeros((48, 64), np.uint8), K, None, "rgb: must be an H x W x 3"),
        (np.zeros((48, 64), np.float32), np.zeros((40, 64, 3), np.uint8), K, None, "rgb: is 64 x 40"),
        (np.zeros((48, 64), np.float32), None, np.eye(4), None, "K"),
        (np.zeros((48, 64), np.float32), None, np.diag([0.0, 500, 1]), None, "K: focal lengths must be positive"),
        (np.zeros((48, 64), np.float32), None, perch2.Intrinsics(500, 500, 32, 24, 640, 480), None,
         "but K is for 640 x 480"),
        ([[0.5, 0.5]], None, K, None, "depth: must be float32"),  # a list of Python floats is float64
        ("depth.png", None, K, None, "depth"),
    ],
)
def test_bad_frames_raise_invalid_input_naming_the_argument(depth, rgb, Km, scale, fragment):
    with pytest.raises(perch2.InvalidInput, match=re.escape(fragment)):
        perch2.RgbdFrame(depth, rgb, Km, depth_scale_m=scale)


def test_cloud_batch_arrays_are_views():
    pts = np.random.default_rng(0).normal(size=(10, 3))
    c = perch2.CloudBatch(pts, offsets=[0, 4, 10])
    assert len(c) == 10 and c.num_clouds() == 2 and c.cloud_size(1) == 6
    np.testing.assert_array_equal(c.cloud, [0] * 4 + [1] * 6)
    np.testing.assert_allclose(c.points, pts, atol=1e-6)
    x = c.x
    assert np.shares_memory(x, c.x)  # both views of the C++ vector
    x[0] = 42.0
    assert c.points[0, 0] == 42.0
    del c
    assert x[0] == 42.0  # the view keeps the batch alive
    with pytest.raises(perch2.InvalidInput, match="offsets must start at 0 and end at the point count"):
        perch2.CloudBatch(pts, offsets=[0, 4])
    with pytest.raises(perch2.InvalidInput, match="offsets must not decrease"):
        perch2.CloudBatch(pts, offsets=[0, 6, 4, 10])
    with pytest.raises(perch2.InvalidInput, match="rgb: must have 10 entries"):
        perch2.CloudBatch(pts, rgb=[0, 1])


def test_unknown_and_unbuilt_backends_raise_invalid_input():
    v, f = box_mesh()
    mesh = perch2.Mesh(v, f)
    with pytest.raises(perch2.InvalidInput, match="backend: unknown backend 'gpu'"):
        perch2.Renderer([mesh], backend="gpu")
    if "cuda" not in perch2.backends():
        with pytest.raises(perch2.InvalidInput, match="perch2 was built without CUDA"):
            perch2.SixDofEstimator([mesh], backend="cuda")
    else:  # an nvcc build: without a visible GPU, the reason (CUDA_VISIBLE_DEVICES= hides every device)
        import subprocess
        import sys

        code = "import perch2, numpy as np\ntry:\n    perch2.Renderer([perch2.Mesh(np.eye(3), [[0, 1, 2]])], backend='cuda')\n" \
               "except perch2.InvalidInput as e:\n    print(e)"
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             env=dict(__import__("os").environ, CUDA_VISIBLE_DEVICES="")).stdout
        assert "backend: 'cuda': no CUDA device visible" in out, out
    assert {"cpu", "thrust_omp"} <= set(perch2.backends())


def test_settings_defaults_come_from_cpp_and_nested_settings_are_live():
    s = perch2.SixDofSettings()
    assert s.render.stride == 8 and s.gicp.icp_warmup_iterations == 8  # the C++ lambdas' values
    assert s.local.turns.fine_turns == 144 and s.local.turns.climb_shift_m == 0.0  # 6-DoF: no shifts
    assert s.first_pass_target_stride == 4 and perch2.SixDofSettings.first_pass_target_stride.__doc__
    assert s.screen.stride == 16 and s.screen.keep_fraction == pytest.approx(0.34) and not s.screen.in_scene
    assert perch2.ScreenSettings.keep_fraction.__doc__
    s.local.turns.geometry_tolerance = 0.05
    assert s.local.turns.geometry_tolerance == pytest.approx(0.05)  # nested settings are references, not copies
    assert s.scene.local_search_placed_only
    s.gicp.lm.lambda_up = 7.0
    assert s.gicp.lm.lambda_up == 7.0
    t = perch2.TabletopSettings()
    assert t.cost.normalization == perch2.Normalization.Fractions and t.xy_step_m == pytest.approx(0.08)
    t.workspace_xy_m = (-0.5, -0.5, 0.5, 0.5)
    assert t.workspace_xy_m == pytest.approx((-0.5, -0.5, 0.5, 0.5))
    t.workspace_xy_m = None
    assert t.workspace_xy_m is None
    t.icp.up_cam = [0.0, 0.0, 1.0]
    np.testing.assert_array_equal(t.icp.up_cam, [0, 0, 1])
    # the 3-DoF yaw search and the 6-DoF final surface fit, defaults from their C++ structs
    assert t.yaw_search.enabled and t.yaw_search.turns.sweep_turns == 36 and t.yaw_search.turns.final_stride == 1
    assert t.yaw_search.turns.climb_shift_m == pytest.approx(0.001)
    # the 3-DoF default: the fine sweep at stride 2, the climb at every pixel; the 6-DoF local search climbs at 2
    assert t.yaw_search.turns.fine_stride == 2 and t.yaw_search.turns.climb_stride == 1
    assert s.local.turns.fine_stride == 2 and s.local.turns.climb_stride == 0
    # the 3-DoF search refines 64 points of a stride-6 render and climbs the yaw search's best two starts
    assert t.render.stride == 6 and t.icp_max_points == 64 and t.yaw_search.turns.climbed_starts == 2
    assert s.local.turns.sweep_turns == 24 and s.local.turns.climbed_starts == 0  # the 6-DoF sweep every 15 deg
    assert t.missing_depth_hides and t.second_look and t.second_look_margin_m == pytest.approx(0.01)
    assert t.polish_rounds == 2 and t.polish_stride == 1 and t.polish_max_distance_m == pytest.approx(0.01)
    assert perch2.TurnSearchSettings.geometry_tolerance.__doc__
    t.yaw_search.enabled = False
    assert not t.yaw_search.enabled
    assert s.fit.iterations == 20 and s.fit_stride == 1 and s.fit_cost_slack == pytest.approx(0.01)
    s.fit.iterations = 0
    assert s.fit.iterations == 0


def test_docstrings_are_the_cpp_comments():
    assert "grid step in x and y on the table, metres" in perch2.TabletopSettings.xy_step_m.__doc__
    assert "Fewer acceptable, non-overlapping poses" in perch2.TabletopSettings.strict_instances.__doc__
    assert "6-DoF PERCH 2.0" in perch2.SixDofEstimator.__doc__
    assert "ADD(-S)" in perch2.Scores.auc_add_or_adds.__doc__
    assert "Grid" in dir(perch2.KnnMethod) and "uniform spatial grid" in perch2.KnnMethod.Grid.__doc__


def _table_with_box(h=120, w=160, f=150.0):
    """Depth of a camera 0.6 m above a table (z = 0.6 m everywhere) with a 6 cm cube on it."""
    depth = np.full((h, w), 0.6, np.float32)
    depth[50:70, 70:90] = 0.54  # the cube's top face, 6 cm nearer
    rgb = np.full((h, w, 3), 128, np.uint8)
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]], np.float64)
    return depth, rgb, K


def test_segment_frame_removes_the_plane_and_labels_the_object():
    depth, rgb, K = _table_with_box()
    frame = perch2.RgbdFrame(depth, rgb, K)
    s = perch2.segment_frame(frame, perch2.SegmentationSettings(), 0.0)
    assert s.plane is not None and s.support_pixels > 10000
    assert len(s.segments) == 1 and s.segments[0].pixels == 400
    labels = s.labels
    assert labels.dtype == np.int32 and labels.shape == depth.shape
    assert (labels[50:70, 70:90] == 1).all() and labels.sum() == 400
    settings = perch2.SegmentationSettings()
    assert settings.max_planes == 3 and settings.plane.min_inlier_fraction == pytest.approx(0.1)
    settings.max_planes = 0
    with pytest.raises(perch2.InvalidInput, match="max_planes"):
        perch2.segment_frame(frame, settings, 0.0)


def test_segment_readings_segments_a_mask_and_checks_it():
    depth, rgb, K = _table_with_box()
    frame = perch2.RgbdFrame(depth, rgb, K)
    mask = np.zeros(depth.shape, bool)
    mask[50:70, 70:80] = True  # the left half of the cube's top
    s = perch2.segment_readings(frame, mask, perch2.SegmentationSettings(), 0.0)
    assert len(s.segments) == 1 and s.segments[0].pixels == 200 and s.plane is None
    assert (s.labels[50:70, 70:80] == 1).all() and s.labels.sum() == 200
    with pytest.raises(perch2.InvalidInput, match="mask"):
        perch2.segment_readings(frame, mask[:10])
    with pytest.raises(perch2.InvalidInput, match="bool or uint8"):
        perch2.segment_readings(frame, mask.astype(np.float32))


def test_estimate_scene_objects_and_bad_requests():
    v, f = box_mesh(0.06)
    est = perch2.SixDofEstimator([perch2.Mesh(v, f)], backend="cpu")
    depth, rgb, K = _table_with_box()
    r = est.estimate_scene(depth, rgb, K, [(0, 1)])
    assert len(r.missing) == 1 and len(r.poses) + r.missing[0] == 1
    assert r.search.timings.total > 0 and len(r.segments) == 1
    r2 = est.estimate_scene(perch2.RgbdFrame(depth, rgb, K), [perch2.SixDofObject(0, 0)])
    assert r2.poses == [] and r2.missing == [0]
    with pytest.raises(perch2.InvalidInput, match="unknown model"):
        est.estimate_scene(depth, rgb, K, [(3, 1)])
    with pytest.raises(perch2.InvalidInput, match="objects\\[0\\]"):
        est.estimate_scene(depth, rgb, K, ["cube"])
    assert est.settings.scene.min_inlier_fraction == pytest.approx(0.55)
    assert est.settings.scene.min_colour_fraction == pytest.approx(0.3)
    assert est.settings.scene.piece_area_faces == pytest.approx(1.0)
    assert est.settings.scene.half_jobs
    assert est.settings.scene.max_colour_mismatch == pytest.approx(0.5)
    assert r.jobs + r.screened_out >= 1
    assert r.reverted <= r.refined  # spare placements: candidates refined after the box is placed
    assert r.residual_segments == 0 and est.settings.scene.residual_pass
    assert "segment" in perch2.SceneSettings.__doc__.lower() or perch2.SceneSettings.__doc__
    assert est.settings.scene.spare_placements == 2 and est.settings.scene.retrieval_jobs_per_object == 0
    settings = perch2.SixDofSettings()
    settings.scene.spare_placements = 0  # each object's first placements, whatever their scores
    r0 = perch2.SixDofEstimator([perch2.Mesh(v, f)], backend="cpu", settings=settings).estimate_scene(
        depth, rgb, K, [(0, 1)])
    assert len(r0.poses) == len(r.poses) and r0.missing == r.missing  # one box: the same answer
    assert r0.refined == 0 and r0.reverted == 0  # one object and no spare: nothing placed before it
    for field in ("spare_placements", "retrieval_jobs_per_object"):
        settings = perch2.SixDofSettings()
        setattr(settings.scene, field, -1)
        with pytest.raises(perch2.InvalidInput, match=field):
            perch2.SixDofEstimator([perch2.Mesh(v, f)], backend="cpu", settings=settings).estimate_scene(
                depth, rgb, K, [(0, 1)])
    # the screen before the first pass: bad values are refused by name; in_scene turns it on here too
    for field, value in (("stride", 8), ("icp_iterations", 0), ("keep_fraction", 0.0), ("min_keep", 0)):
        settings = perch2.SixDofSettings()
        setattr(settings.screen, field, value)
        with pytest.raises(perch2.InvalidInput, match="screen." + field):
            perch2.SixDofEstimator([perch2.Mesh(v, f)], backend="cpu", settings=settings).estimate_scene(
                depth, rgb, K, [(0, 1)])
    settings = perch2.SixDofSettings()
    settings.screen.in_scene = True
    rs = perch2.SixDofEstimator([perch2.Mesh(v, f)], backend="cpu", settings=settings).estimate_scene(
        depth, rgb, K, [(0, 1)])
    assert len(rs.poses) == len(r.poses) and rs.missing == r.missing
    assert r.search.proposals_screened_out == 0 and r.search.timings.screen == 0.0
    # the coarse meshes: defaults, and bad values refused by name when the estimator is built
    c = perch2.SixDofSettings().coarse_mesh
    assert (c.min_stride, c.min_triangles, c.texture_factor) == (8, 8000, 2)
    assert c.cell_fraction == pytest.approx(0.025) and perch2.CoarseMeshSettings.cell_fraction.__doc__
    for field, value in (("cell_fraction", 0.0), ("texture_factor", 0), ("min_stride", -1)):
        settings = perch2.SixDofSettings()
        setattr(settings.coarse_mesh, field, value)
        with pytest.raises(perch2.InvalidInput, match="coarse_mesh." + field):
            perch2.SixDofEstimator([perch2.Mesh(v, f)], backend="cpu", settings=settings)


def test_detect_settings_and_what_a_detection_reports():
    v, f = box_mesh(0.06)
    est = perch2.SixDofEstimator([perch2.Mesh(v, f)], backend="cpu")
    depth, rgb, K = _table_with_box()
    settings = perch2.DetectSettings()
    assert settings.retrieval_jobs_per_object == 3 and settings.seed_depth and settings.retrieval_acceptable_only
    assert settings.max_colour_mismatch == pytest.approx(0.15)
    assert (settings.retrieval_viewpoints, settings.retrieval_inplane_rotations) == (12, 2)
    assert settings.retrieval_screen_keep == 6
    assert settings.retrieval_align_inplane and settings.retrieval_align_min_elongation == pytest.approx(2.0)
    found = est.detect(depth, rgb, K, settings)  # one model: nothing to rank, no coarse search
    assert found.retrieved_out == 0 and found.search.timings.retrieve == 0
    settings.retrieval_viewpoints = 0  # ranked by colour coverage
    assert len(est.detect(depth, rgb, K, settings).poses) == len(found.poses)
    settings.retrieval_jobs_per_object = 0  # every model on every segment
    r = est.detect(depth, rgb, K, settings)
    assert r.retrieved_out == 0 and r.missing == []
    for p in r.poses:  # detect()'s score: pose_score x depth_agreement x colour and evidence factors
        assert 0 <= p.score <= p.depth_agreement <= 1
    settings.retrieval_jobs_per_object = -1
    with pytest.raises(perch2.InvalidInput, match="retrieval_jobs_per_object"):
        est.detect(depth, rgb, K, settings)
    settings.retrieval_jobs_per_object, settings.retrieval_viewpoints = 2, -1
    with pytest.raises(perch2.InvalidInput, match="retrieval_viewpoints"):
        est.detect(depth, rgb, K, settings)
    settings.retrieval_viewpoints, settings.retrieval_screen_keep = 12, -1
    with pytest.raises(perch2.InvalidInput, match="retrieval_screen_keep"):
        est.detect(depth, rgb, K, settings)
    for field, bad in (("half_evidence_readings", -1.0), ("half_evidence_readings", float("nan")),
                       ("max_below_plane_m", float("nan")), ("max_below_plane_m", -0.01)):
        settings = perch2.DetectSettings()
        setattr(settings, field, bad)
        with pytest.raises(perch2.InvalidInput, match=field):
            est.detect(depth, rgb, K, settings)
    settings = perch2.DetectSettings()
    settings.max_below_plane_m = float("inf")  # no support-plane test
    assert est.detect(depth, rgb, K, settings).below_plane == 0


def test_depth_agreement_is_the_share_of_the_visible_surface_the_readings_show():
    v, f = box_mesh(0.06)
    est = perch2.SixDofEstimator([perch2.Mesh(v, f)], backend="cpu")
    depth, rgb, K = _table_with_box()
    mask = np.zeros(depth.shape, bool)
    mask[50:70, 70:90] = True
    full = est.estimate(depth, rgb, K, [(0, mask, None)]).poses[0]
    assert full.found and full.depth_agreement == pytest.approx(1.0)
    holes = depth.copy()
    holes[50:70, 70:80] = 0  # half the top face without readings (dropout): counts neither way
    half = est.estimate(holes, rgb, K, [(0, mask, None)]).poses[0]
    assert half.found and half.depth_agreement == pytest.approx(1.0)
    behind = depth.copy()
    behind[50:70, 70:80] += 0.05  # half of it reads 5 cm deeper: the render there covers other depths
    off = est.estimate(behind, rgb, K, [(0, mask, None)]).poses[0]
    assert off.found and off.depth_agreement < 0.9
