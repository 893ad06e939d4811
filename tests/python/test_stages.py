"""The stages from Python (Renderer, KnnIndex, Registration, Cost) on both CPU backends, each checked against
an independent numpy computation in float64."""

import numpy as np
import pytest

import perch2

BACKENDS = ["cpu", "thrust_omp"]


def box(size=0.1):
    h = size / 2
    v = np.array([[x, y, z] for z in (-h, h) for y in (-h, h) for x in (-h, h)])
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])
    return perch2.Mesh(v, f, colors=np.full((8, 3), 200, np.uint8), name="box")


def pose(rx=0.0, ry=0.0, t=(0.0, 0.0, 0.5)):
    cx, sx, cy, sy = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Ry @ Rx, t
    return T


CAMERA = perch2.Intrinsics(100.0, 100.0, 32.0, 24.0, 64, 48)


@pytest.mark.parametrize("backend", BACKENDS)
def test_render_front_face_matches_the_pinhole_model(backend):
    r = perch2.Renderer([box()], backend=backend)
    s = perch2.RenderSettings()
    s.stride = 1
    c = r.render(0, pose(), CAMERA, s)
    assert c.num_clouds() == 1
    # Independent: the front face z = 0.45 covers the pixels whose ray meets |x|, |y| <= 0.05 there.
    u, v = np.meshgrid(np.arange(64), np.arange(48))
    inside = (np.abs((u - 32) / 100 * 0.45) <= 0.05) & (np.abs((v - 24) / 100 * 0.45) <= 0.05)
    assert len(c) == inside.sum()
    np.testing.assert_allclose(c.z, 0.45, atol=1e-6)
    np.testing.assert_array_equal(np.sort(c.pixel), np.flatnonzero(inside.ravel()))
    assert (c.rgb == 0xC8C8C8).all()
    # the arrays are owned by the returned batch (views, no copy)
    assert np.shares_memory(c.z, c.z)


def test_backends_render_the_same_batch_of_hypotheses():
    poses = np.stack([pose(0.3 * k, 0.2 * k, (0.01 * k, 0.0, 0.5 + 0.05 * k)) for k in range(5)])
    out = [perch2.Renderer([box()], backend=b).render(0, poses, CAMERA) for b in BACKENDS]
    for name in ("x", "y", "z", "rgb", "pixel", "offsets"):
        np.testing.assert_array_equal(getattr(out[0], name), getattr(out[1], name))
    assert out[0].num_clouds() == 5


def test_render_rejects_bad_requests():
    r = perch2.Renderer([box()], backend="cpu")
    with pytest.raises(perch2.InvalidInput, match="hypothesis 0: model index 3 out of range"):
        r.render(3, pose(), CAMERA)
    with pytest.raises(perch2.InvalidInput, match="RenderSettings::stride: must be >= 1"):
        s = perch2.RenderSettings()
        s.stride = 0
        r.render(0, pose(), CAMERA, s)
    with pytest.raises(perch2.InvalidInput, match=r"T_cam_obj: must have shape \(n, 4, 4\)"):
        r.render(0, np.zeros((2, 3, 4)), CAMERA)
    with pytest.raises(perch2.InvalidInput, match="T_cam_obj: is not a finite rigid transform"):
        r.render(0, np.diag([2.0, 1, 1, 1]), CAMERA)
    with pytest.raises(perch2.InvalidInput, match="camera: must be a perch2.Intrinsics"):
        r.render(0, pose(), np.eye(3))
    with pytest.raises(perch2.InvalidInput, match="occluder depth: expected 64x48"):
        r.render(0, pose(), CAMERA, occluder_depth=np.zeros((10, 10), np.float32))
    with pytest.raises(perch2.InvalidInput, match="model: must have 2 entries"):
        r.render([0, 0, 0], np.stack([pose(), pose()]), CAMERA)


def clouds(seed=1, n_targets=(300, 200), n_queries=(50, 40)):
    rng = np.random.default_rng(seed)
    t = [rng.uniform(-0.1, 0.1, size=(n, 3)) for n in n_targets]
    q = [rng.uniform(-0.1, 0.1, size=(n, 3)) for n in n_queries]
    targets = perch2.CloudBatch(np.concatenate(t), offsets=np.cumsum([0, *n_targets]))
    queries = perch2.CloudBatch(np.concatenate(q), offsets=np.cumsum([0, *n_queries]))
    return t, q, targets, queries


@pytest.mark.parametrize("backend", BACKENDS)
def test_knn_matches_brute_force_in_float64(backend):
    t, q, targets, queries = clouds()
    index = perch2.KnnIndex(targets, backend=backend)
    s = perch2.KnnSettings()
    s.k = 3
    res = index.knn(queries, [1, 0], s)  # cloud 0 searches segment 1, cloud 1 segment 0
    assert res.index.shape == (90, 3)
    base = [0, len(t[0])]
    tf = [np.asarray(a, np.float32).astype(np.float64) for a in t]
    qf = [np.asarray(a, np.float32).astype(np.float64) for a in q]
    expect_idx, expect_d2 = [], []
    for c, seg in ((0, 1), (1, 0)):
        d2 = ((qf[c][:, None, :] - tf[seg][None, :, :]) ** 2).sum(-1)
        order = np.argsort(d2, axis=1, kind="stable")[:, :3]
        expect_idx.append(order + base[seg])
        expect_d2.append(np.take_along_axis(d2, order, 1))
    np.testing.assert_array_equal(res.index, np.concatenate(expect_idx))
    np.testing.assert_allclose(res.sq_distance_m2, np.concatenate(expect_d2), rtol=1e-5, atol=1e-9)
    rad = index.radius(queries, [1, 0], 0.02)
    counts = np.diff(rad.offsets)
    d2_all = [((qf[0][:, None] - tf[1][None]) ** 2).sum(-1), ((qf[1][:, None] - tf[0][None]) ** 2).sum(-1)]
    np.testing.assert_array_equal(counts, np.concatenate([(d <= 0.02**2).sum(1) for d in d2_all]))
    with pytest.raises(perch2.InvalidInput, match="query_segment: segment index 5 of query cloud 0 out of range"):
        index.knn(queries, [5, 0], s)
    s.k = 0
    with pytest.raises(perch2.InvalidInput, match="KnnSettings::k: must be >= 1"):
        index.knn(queries, 0, s)


def move(c, T):
    """The batch's points moved by T (numpy), as a new batch."""
    p = c.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    return perch2.CloudBatch(p, offsets=c.offsets, rgb=c.rgb, pixel=c.pixel)


@pytest.mark.parametrize("backend", BACKENDS)
def test_icp_and_gicp_undo_a_small_motion(backend):
    s = perch2.RenderSettings()
    s.stride = 1
    cam = perch2.Intrinsics(100.0, 100.0, 32.0, 24.0, 64, 48)  # the box well inside the image
    target = perch2.Renderer([box()], backend="cpu").render(0, pose(0.5, 0.6), cam, s)
    delta = pose(0.03, -0.02, (0.004, -0.003, 0.002))
    source = move(target, delta)
    reg = perch2.Registration(target, backend=backend)
    for result in (reg.icp(source), reg.gicp(source)):
        assert len(result) == 1 and result.converged[0] == 1
        fixed = move(source, result.T_corr[0].astype(np.float64))
        err = np.linalg.norm(fixed.points - target.points, axis=1)
        assert np.median(err) < 1e-4, np.median(err)  # the exact alignment exists: every point has its twin
    with pytest.raises(perch2.InvalidInput, match="GicpSettings::k_neighbors: must be in"):
        g = perch2.GicpSettings()
        g.k_neighbors = 1
        reg.gicp(source, 0, g)


@pytest.mark.parametrize("backend", BACKENDS)
def test_cost_counts_match_numpy(backend):
    s = perch2.RenderSettings()
    s.stride = 1
    cam = perch2.Intrinsics(100.0, 100.0, 32.0, 24.0, 64, 48)
    r = perch2.Renderer([box()], backend="cpu")
    observed = r.render(0, pose(0.5, 0.6), cam, s)
    rendered = r.render(0, np.stack([pose(0.5, 0.6), pose(0.5, 0.6, (0.02, 0, 0.5))]), cam, s)
    cost = perch2.Cost(observed, backend=backend)
    cs = perch2.CostSettings()
    cs.use_color = False
    out = cost.evaluate(rendered, None, cs)
    assert len(out) == 2 and out[0].rendered_depth_outliers == 0 and out[0].total == 0
    obs = observed.points.astype(np.float64)
    for h in range(2):
        a, b = rendered.offsets[h], rendered.offsets[h + 1]
        pts = rendered.points[a:b].astype(np.float64)
        d2 = ((pts[:, None] - obs[None]) ** 2).sum(-1)
        assert out[h].rendered_points == b - a
        assert out[h].rendered_depth_outliers == int((d2.min(1) > cs.delta_m**2).sum())
        assert out[h].observed_depth_outliers == int((d2.min(0) > cs.delta_m**2).sum())
    assert out[1].rendered_depth_outliers > 0
    req = perch2.CostRequest()
    req.add(3)
    req.add(0)
    with pytest.raises(perch2.InvalidInput, match="observed segment 3 out of range"):
        cost.evaluate(rendered, req, cs)
