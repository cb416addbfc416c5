"""Body-frame landmark map of the stereo tracker (jaxpose.pipelines.stereo.landmarks) and the sparse
Hamming KNN it uses; reference values from independent constructions (known geometry, dense
brute force)."""

import numpy as np
import pytest

from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo import LandmarkMap
from jaxpose.vision.stereo_features import knn_ratio_match, knn_ratio_match_pairs


def _look_at(centre_body):
    """Pose of a camera at ``centre_body`` looking at the body origin (body to camera)."""
    z = -centre_body
    z = z / np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return Pose(R, -R @ centre_body)


def test_observe_triangulates_from_rays_and_keeps_near_parallel_ones():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(5, 3)) * 0.2
    m = LandmarkMap()
    pose = _look_at(np.array([0.0, 0.0, -2.0]))
    idx = m.add("points", X + 0.05, np.zeros((5, 32), np.uint8), pose, 0)
    # one ray each: underdetermined, the points keep their (wrong) initial positions
    c0 = np.array([0.0, 0.0, -2.0])
    m.observe(idx, np.broadcast_to(c0, X.shape), X - c0)
    np.testing.assert_allclose(m.points.X, X + 0.05)
    # rays from three more centres around the target: the exact points (noise-free rays)
    for c in ([1.0, 0.0, -1.7], [-0.5, 0.4, -1.9], [0.3, -0.8, -1.6]):
        c = np.asarray(c)
        m.observe(idx, np.broadcast_to(c, X.shape), (X - c) * rng.uniform(0.5, 2.0, (5, 1)))
    np.testing.assert_allclose(m.points.X, X, atol=1e-9)


def test_observe_matches_the_stereo_triangulation():
    from jaxpose import PinholeCamera, StereoCamera

    cam = PinholeCamera(800.0, 800.0, 319.5, 239.5, width=640, height=480)
    rig = StereoCamera.from_baseline(cam, 0.3)
    X = np.array([[0.1, -0.05, 2.0], [-0.2, 0.1, 2.4]])
    left, right = (np.asarray(p) for p in rig.project(X))
    m = LandmarkMap()
    pose = Pose(np.eye(3), np.zeros(3))  # body = left camera
    idx = m.add("points", np.zeros_like(X), np.zeros((2, 32), np.uint8), pose, 0)
    K_inv = np.linalg.inv(np.asarray(cam.K))
    d_l = np.c_[left, np.ones(2)] @ K_inv.T
    d_r = np.c_[right, np.ones(2)] @ K_inv.T
    m.observe(idx, np.zeros((2, 3)), d_l)
    m.observe(idx, np.broadcast_to([0.3, 0.0, 0.0], (2, 3)), d_r)  # right centre, left frame
    np.testing.assert_allclose(m.points.X, X, atol=1e-9)


def test_candidates_use_the_viewing_cone_and_the_camera_side():
    m = LandmarkMap(max_view_deg=60.0)
    pose = _look_at(np.array([0.0, 0.0, -2.0]))
    X = np.array([[0.0, 0.0, -0.3], [0.0, 0.0, 0.3]])
    m.add("points", X, np.zeros((2, 32), np.uint8), pose, 0)  # both seen from -z
    assert list(m.candidates("points", pose)) == [0, 1]
    # from 45 deg away: inside the cone; from the far side (180 deg): not searched
    pose45 = _look_at(np.array([np.sqrt(2.0), 0.0, -np.sqrt(2.0)]))
    assert list(m.candidates("points", pose45)) == [0, 1]
    pose_b = _look_at(np.array([0.0, 0.0, 2.0]))
    assert len(m.candidates("points", pose_b)) == 0
    # segments use their midpoints
    m.add("lines", X[None], np.zeros((1, 32), np.uint8), pose, 0)
    assert list(m.candidates("lines", pose)) == [0]
    with pytest.raises(ValueError):
        LandmarkMap(max_view_deg=0.0)


def test_refine_running_mean_and_culling():
    m = LandmarkMap(max_obs=4, cull_after=4, cull_ratio=0.5, keep_obs=3)
    pose = Pose(np.eye(3), np.array([0.0, 0.0, 2.0]))
    m.add("points", np.zeros((3, 3)), np.zeros((3, 32), np.uint8), pose, 0)
    new_desc = np.full((1, 32), 7, np.uint8)
    m.refine("points", [0], np.array([[0.3, 0.0, 0.0]]), new_desc, pose, 5)
    np.testing.assert_allclose(m.points.X[0], [0.15, 0.0, 0.0])  # mean of two observations
    assert m.points.n_obs[0] == 2 and m.points.last_seen[0] == 5
    assert (m.points.desc[0] == 7).all()
    m.refine("points", [2, 2], None, np.zeros((2, 32), np.uint8), pose, 6)  # X kept
    np.testing.assert_allclose(m.points.X[2], 0.0)
    assert m.points.n_obs[2] == 3
    # all three predicted visible 4 times, never found: landmark 2 (3 observations) is kept
    for _ in range(4):
        m.record("points", [0, 1, 2], [], 7)
    m.cull()
    assert len(m.points) == 1 and m.points.n_obs[0] == 3


def test_pairs_knn_equals_the_dense_allowed_matrix():
    rng = np.random.default_rng(3)
    ref = rng.integers(0, 256, (40, 32), dtype=np.uint8)
    cur = ref[rng.permutation(40)[:30]].copy()
    cur[:, :3] ^= rng.integers(0, 256, (30, 3), dtype=np.uint8)  # a few flipped bits
    allowed = rng.random((40, 30)) < 0.3
    i_ref, i_cur = np.nonzero(allowed)
    a = knn_ratio_match(ref, cur, ratio=0.8, max_distance=64, allowed=allowed)
    b = knn_ratio_match_pairs(ref, cur, i_ref[::-1], i_cur[::-1], ratio=0.8, max_distance=64)
    order_a, order_b = np.argsort(a[0]), np.argsort(b[0])
    np.testing.assert_array_equal(a[0][order_a], b[0][order_b])
    np.testing.assert_array_equal(a[1][order_a], b[1][order_b])
    # brute-force reference of one reference descriptor
    pop = np.array([bin(i).count("1") for i in range(256)])
    for r, c in zip(*b, strict=True):
        cands = np.nonzero(allowed[r])[0]
        dist = pop[ref[r] ^ cur[cands]].sum(1)
        assert cands[np.argmin(dist)] == c
    with pytest.raises(ValueError):
        knn_ratio_match_pairs(ref, cur, [0, 1], [0], ratio=0.8, max_distance=64)


def test_descriptor_memory_keeps_the_latest_observations_and_matches_the_nearest():
    rng = np.random.default_rng(5)
    pose = Pose(np.eye(3), np.array([0.0, 0.0, 2.0]))
    d = rng.integers(0, 256, (5, 32), dtype=np.uint8)  # one descriptor an observation
    m = LandmarkMap(descriptor_memory=3)
    m.add("points", np.zeros((2, 3)), d[:2], pose, 0)
    np.testing.assert_array_equal(m.points.memory[0], d[[0, 0, 0]])  # the first fills all
    for k in (2, 3, 4):  # three more observations of landmark 0: the oldest slot goes first
        m.refine("points", [0], None, d[k : k + 1], pose, k)
    np.testing.assert_array_equal(np.sort(m.points.memory[0], 0), np.sort(d[[2, 3, 4]], 0))
    np.testing.assert_array_equal(m.points.desc[0], d[4])
    np.testing.assert_array_equal(m.points.memory[1], d[[1, 1, 1]])
    m.points._keep(np.array([False, True]))  # culling keeps the memory with its landmark
    np.testing.assert_array_equal(m.points.memory[0], d[[1, 1, 1]])
    # matching: the distance to a landmark is the smallest over its memory (brute force)
    pop = np.array([bin(i).count("1") for i in range(256)])
    mem = rng.integers(0, 256, (6, 3, 32), dtype=np.uint8)
    cur = mem[np.arange(6), rng.integers(0, 3, 6)].copy()  # each is one of the slots
    cur[:, :2] ^= rng.integers(0, 256, (6, 2), dtype=np.uint8)
    i_ref, i_cur = np.repeat(np.arange(6), 6), np.tile(np.arange(6), 6)
    got = knn_ratio_match_pairs(mem, cur, i_ref, i_cur, ratio=0.8, max_distance=64)
    dist = pop[mem[:, None] ^ cur[None, :, None]].sum(-1).min(-1)  # (6 ref, 6 cur)
    best = np.argmin(dist, 1)
    second = np.sort(dist, 1)[:, 1]
    keep = (dist[np.arange(6), best] <= 64) & (dist[np.arange(6), best] < 0.8 * second)
    np.testing.assert_array_equal(got[0], np.nonzero(keep)[0])
    np.testing.assert_array_equal(got[1], best[keep])
    assert keep.sum() >= 4  # the slots matched are found, not an empty agreement
    with pytest.raises(ValueError, match="descriptor_memory"):
        LandmarkMap(descriptor_memory=0)


def test_closed_form_rectified_triangulation_equals_the_rig():
    from jaxpose import PinholeCamera, StereoCamera
    from jaxpose.pipelines.stereo.keyframes import triangulate_rectified

    cam = PinholeCamera(900.0, 900.0, 511.5, 383.5, width=1024, height=768)
    rig = StereoCamera.from_baseline(cam, 0.3)
    X = np.random.default_rng(4).uniform([-0.5, -0.4, 1.5], [0.5, 0.4, 3.5], (20, 3))
    left, right = (np.asarray(p) for p in rig.project(X))
    np.testing.assert_allclose(triangulate_rectified(rig, left, right), X, atol=1e-9)
    np.testing.assert_allclose(
        triangulate_rectified(rig, left, right),
        np.asarray(rig.triangulate(left, right)),
        atol=1e-9,
    )
    bad = triangulate_rectified(rig, left[:1], left[:1] + [1.0, 0.0])  # negative disparity
    assert np.isnan(bad).all()


def test_observe_lines_intersects_the_planes_and_moves_endpoints_across_the_line():
    # a body-frame line through P0 along u; planes through four camera centres and the line
    rng = np.random.default_rng(1)
    P0, u = np.array([0.1, -0.2, 0.3]), np.array([0.6, 0.3, -0.74])
    u /= np.linalg.norm(u)
    m = LandmarkMap()
    pose = _look_at(np.array([0.0, 0.0, -2.0]))
    # wrong initial endpoints: off the line by a perpendicular offset, at along-line 0.1 and 0.4
    off = np.cross(u, [0.0, 0.0, 1.0])
    off = 0.03 * off / np.linalg.norm(off)
    start = np.stack([P0 + 0.1 * u + off, P0 + 0.4 * u - off])
    (i,) = m.add("lines", start[None], np.zeros((1, 32), np.uint8), pose, 0)
    c0 = np.array([0.0, 0.0, -2.0])
    n0 = np.cross(P0 - c0, u)
    m.observe_lines([i], n0[None], [n0 @ c0])  # one plane: underdetermined, nothing moves
    np.testing.assert_allclose(m.lines.X[i], start)
    for c in ([1.0, 0.2, -1.7], [-0.5, 0.4, -1.9], [0.3, -0.8, -1.6]):
        n = np.cross(P0 - np.asarray(c), u) * rng.uniform(0.5, 2.0)  # any scale
        m.observe_lines([i], n[None], [n @ np.asarray(c)], [rng.uniform(0.5, 2.0)])
    X = m.lines.X[i]
    # on the line, and each endpoint kept its along-line position (moved perpendicularly)
    for e, s in enumerate((0.1, 0.4)):
        np.testing.assert_allclose(X[e], P0 + s * u + (start[e] - P0 - s * u) @ u * u, atol=1e-9)
        np.testing.assert_allclose(np.cross(X[e] - P0, u), 0.0, atol=1e-9)


def test_sym3_eigvalsh_agrees_with_lapack_and_keeps_the_conditioning_test():
    """The closed-form eigenvalues the map's conditioning tests use, against
    ``np.linalg.eigvalsh``: ray-projector sums from nearly parallel rays (a near-double
    eigenvalue) to wide ones (the map's matrices), a triple eigenvalue, zero and random
    symmetric matrices."""
    from jaxpose.pipelines.stereo._arrays import sym3_eigvalsh
    from jaxpose.pipelines.stereo.landmarks import rays_meet

    rng = np.random.default_rng(3)
    k = 2000
    d0 = rng.normal(size=(k, 3))
    M = np.zeros((k, 3, 3))
    for _ in range(3):
        d = d0 + rng.normal(size=(k, 3)) * 10 ** rng.uniform(-7, 0, (k, 1))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        M += rng.uniform(0.1, 1.0, (k, 1, 1)) * (np.eye(3) - d[:, :, None] * d[:, None, :])
    G = rng.normal(size=(500, 3, 3))
    M = np.concatenate([M, np.zeros((1, 3, 3)), 2.0 * np.eye(3)[None], G + G.transpose(0, 2, 1)])
    want, got = np.linalg.eigvalsh(M), sym3_eigvalsh(M)
    scale = np.maximum(np.abs(want).max(1), 1e-300)
    assert np.all(np.abs(got - want).max(1) <= 1e-7 * scale)
    np.testing.assert_array_equal(got[:, 0] > 1e-4 * got[:, 2], want[:, 0] > 1e-4 * want[:, 2])
    np.testing.assert_array_equal(rays_meet(M), want[:, 0] > 1e-4 * want[:, 2])
    assert 0 < np.sum(want[:k, 0] > 1e-4 * want[:k, 2]) < k  # both sides of the test exercised


def test_array_helpers_equal_their_numpy_references():
    """The map's scatter sum, 3 x 3 solves, per-frame products and sorted lookup against
    ``np.add.at``, ``np.linalg.solve``, a gathered ``einsum`` and an ``argsort`` lookup."""
    from jaxpose.pipelines.stereo._arrays import find, rows_times, scatter_add, solve3

    rng = np.random.default_rng(5)
    idx = rng.integers(0, 50, 4000)
    vals = rng.normal(size=(4000, 3, 3))
    want = rng.normal(size=(50, 3, 3))
    got = want.copy()
    np.add.at(want, idx, vals)
    scatter_add(got, idx, vals)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    strided = np.zeros((50, 2, 3))[:, 0]  # not contiguous: the slow path, still in place
    scatter_add(strided, idx, vals[:, 0])
    ref = np.zeros((50, 3))
    np.add.at(ref, idx, vals[:, 0])
    np.testing.assert_allclose(strided, ref, atol=1e-12)
    A = rng.normal(size=(300, 3, 3))
    b = rng.normal(size=(300, 3))
    np.testing.assert_allclose(solve3(A, b), np.linalg.solve(A, b[..., None])[..., 0], rtol=1e-7)
    assert not np.isfinite(solve3(np.zeros((1, 3, 3)), np.ones((1, 3)))).any()
    mats, v = rng.normal(size=(6, 3, 3)), rng.normal(size=(200, 3))
    for frame in (np.sort(rng.integers(0, 6, 200)), rng.integers(0, 6, 200)):  # grouped, not
        want = np.einsum("na,nab->nb", v, mats[frame])
        np.testing.assert_allclose(rows_times(v, mats, frame), want, rtol=1e-12, atol=1e-12)
    keys = np.sort(rng.choice(10_000, 500, replace=False))
    queries = rng.integers(0, 10_000, 2000)
    q, at = find(keys, queries, increasing=True)
    q_ref, at_ref = find(rng.permutation(keys), queries)  # the general path, shuffled keys
    np.testing.assert_array_equal(q, q_ref)
    np.testing.assert_array_equal(keys[at], queries[q])
    np.testing.assert_array_equal(np.isin(queries, keys), np.isin(np.arange(2000), q))
