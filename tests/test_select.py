"""Feature-point selection: quasi-optimal, one-step, exhaustive, greedy, the eager entry point."""

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxpose import PinholeCamera, Pose, Status, dop
from jaxpose import select as sel
from jaxpose.core.dilution import information_blocks
from jaxpose.core.select._kernel import PAIRS, traces

N, M = 9, 5  # the small problem most tests share (126 subsets): one compilation each


def scene(seed, n=N, deg=20.0, z=10.0, focal=0.05, pixel=5.5e-6, scale=1.0):
    """Planar features in a 1 m square, seen at ``z`` metres with ``deg`` degrees per axis."""
    rng = np.random.default_rng(seed)
    points = np.c_[rng.uniform(-0.5, 0.5, (n, 2)), np.zeros(n)] * scale
    angles = np.deg2rad(rng.uniform(-deg, deg, 3))
    pose = Pose.from_euler(angles, np.array([0.1, -0.2, z]) * scale)
    cam = PinholeCamera.from_focal_length(focal, pixel, (2048, 2048))
    return points, pose, cam


def blocks_of(points, pose, cam):
    return information_blocks(jnp.asarray(points), pose, cam)


def cases(count, n=N, seed=0):
    """Blocks ``(C, n, 6, 6)`` and camera-frame points ``(C, n, 3)`` of ``count`` scenes."""
    bl, pc = [], []
    for c in range(count):
        points, pose, cam = scene(seed + c, n)
        bl.append(blocks_of(points, pose, cam))
        pc.append(pose.apply(jnp.asarray(points)))
    return jnp.stack(bl), jnp.stack(pc)


# ----------------------------------------------------------------------------- NumPy references
def quasi_reference(points_cam, m, *, one_step=False, self_term=True):
    """The rule written independently: recompute every redundancy from scratch at each step."""
    e = points_cam / np.linalg.norm(points_cam, axis=1, keepdims=True)
    c = (e @ e.T) ** 2
    if not self_term:
        np.fill_diagonal(c, 0.0)
    keep = list(range(len(points_cam)))
    if one_step:
        r = c.sum(axis=1)
        order = sorted(keep, key=lambda i: (-r[i], i))
        return np.sort(order[len(keep) - m :])
    while len(keep) > m:
        r = [sum(c[i, j] for j in keep) for i in keep]
        keep.pop(int(np.argmax(r)))  # first maximum: the lowest index
    return np.asarray(keep)


def dop_numpy(blocks, subset):
    Q = np.linalg.inv(np.asarray(blocks)[list(subset)].sum(axis=0))
    return math.sqrt(np.trace(Q[:3, :3])), math.sqrt(np.trace(Q[3:, 3:]))


def exhaustive_reference(blocks, m):
    """Plain loop over itertools.combinations with np.linalg.inv."""
    best = {"pdop": (math.inf, None), "adop": (math.inf, None)}
    for s in itertools.combinations(range(blocks.shape[0]), m):
        p, a = dop_numpy(blocks, s)
        if p < best["pdop"][0]:
            best["pdop"] = (p, s)
        if a < best["adop"][0]:
            best["adop"] = (a, s)
    return best


# ----------------------------------------------------------------------------- quasi-optimal
@pytest.mark.parametrize("n, m", [(9, 5), (12, 8), (18, 8), (18, 4), (7, 7)])
def test_quasi_matches_bruteforce_numpy(n, m):
    for seed in range(5):
        points, pose, _ = scene(100 + seed, n, deg=30.0)
        pc = np.asarray(pose.apply(jnp.asarray(points)))
        np.testing.assert_array_equal(sel.quasi_optimal(pc, m), quasi_reference(pc, m))
        np.testing.assert_array_equal(sel.one_step(pc, m), quasi_reference(pc, m, one_step=True))


def test_incremental_update_equals_recomputation(rng):
    points, pose, _ = scene(7, 12)
    pc = np.asarray(pose.apply(jnp.asarray(points)))
    e = pc / np.linalg.norm(pc, axis=1, keepdims=True)
    c = (e @ e.T) ** 2
    r0 = np.asarray(sel.redundancies(pc))
    np.testing.assert_allclose(r0, c.sum(axis=1), rtol=1e-14)
    removed = rng.choice(12, size=5, replace=False)
    keep = np.setdiff1d(np.arange(12), removed)
    mask = np.isin(np.arange(12), keep)
    incremental = r0 - c[:, removed].sum(axis=1)
    recomputed = np.asarray(sel.redundancies(pc, mask=mask))
    np.testing.assert_allclose(incremental[keep], recomputed[keep], rtol=1e-13)
    assert np.all(recomputed[removed] == 0)


def test_self_term_changes_nothing():
    for seed in range(10):
        points, pose, _ = scene(200 + seed, 14, deg=30.0)
        pc = np.asarray(pose.apply(jnp.asarray(points)))
        for one_step in (False, True):
            with_self = quasi_reference(pc, 6, one_step=one_step)
            without = quasi_reference(pc, 6, one_step=one_step, self_term=False)
            np.testing.assert_array_equal(with_self, without)


def test_m_equals_n_returns_every_point():
    blocks, pc = cases(1)
    all_idx = np.arange(N)
    np.testing.assert_array_equal(sel.quasi_optimal(pc[0], N), all_idx)
    np.testing.assert_array_equal(sel.one_step(pc[0], N), all_idx)
    np.testing.assert_array_equal(sel.greedy(blocks[0], N), all_idx)
    res = sel.exhaustive(blocks[0], N)
    np.testing.assert_array_equal(res.pdop_idx, all_idx)
    np.testing.assert_array_equal(res.adop_idx, all_idx)
    full = dop(jnp.asarray(scene(0)[0]), scene(0)[1], scene(0)[2])
    np.testing.assert_allclose([res.pdop, res.adop], [full.pdop, full.adop], rtol=1e-12)


def test_ties_go_to_the_lowest_index():
    # A symmetric square: the four corners tie, the centre ones tie.
    xy = np.array([[-1, -1], [1, -1], [-1, 1], [1, 1], [0, 0.0], [0.2, 0], [-0.2, 0], [0, 0.2]])
    pc = np.c_[xy * 0.5, np.full(len(xy), 10.0)]
    np.testing.assert_array_equal(sel.quasi_optimal(pc, 4), quasi_reference(pc, 4))
    np.testing.assert_array_equal(sel.one_step(pc, 4), quasi_reference(pc, 4, one_step=True))


def test_quasi_mask_never_selects_masked_points():
    points, pose, _ = scene(3, 12)
    pc = np.asarray(pose.apply(jnp.asarray(points)))
    mask = np.ones(12, bool)
    mask[[0, 5, 6]] = False
    valid = np.flatnonzero(mask)
    for fn, ref in ((sel.quasi_optimal, False), (sel.one_step, True)):
        got = np.asarray(fn(pc, 6, mask=mask))
        np.testing.assert_array_equal(got, valid[quasi_reference(pc[valid], 6, one_step=ref)])
    # Padding with junk (even NaN) in masked rows does not matter.
    junk = pc.copy()
    junk[~mask] = np.nan
    np.testing.assert_array_equal(
        jax.jit(lambda p: sel.quasi_optimal(p, 6, mask=mask))(junk),
        sel.quasi_optimal(pc, 6, mask=mask),
    )


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 10_000),
    focal_mm=st.floats(10, 200),
    pixel_um=st.floats(2, 20),
    scale=st.floats(0.1, 10),
)
def test_selection_invariant_to_focal_length_pixel_size_and_scale(seed, focal_mm, pixel_um, scale):
    base = scene(seed)
    other = scene(seed, focal=focal_mm * 1e-3, pixel=pixel_um * 1e-6, scale=scale)
    for method in ("quasi", "one-step", "greedy", "exhaustive"):
        for criterion in ("pdop", "adop"):
            a = sel.select_features(*base, M, method=method, criterion=criterion)
            b = sel.select_features(*other, M, method=method, criterion=criterion)
            np.testing.assert_array_equal(a, b, err_msg=f"{method} {criterion}")


# ----------------------------------------------------------------------------- exhaustive
def test_unrank_matches_itertools():
    unrank = jax.jit(sel.unrank_combinations, static_argnums=(1, 2))
    for n, m in [(9, 5), (10, 4), (6, 6), (12, 8), (7, 1)]:
        got = np.asarray(unrank(jnp.arange(math.comb(n, m)), n, m))
        np.testing.assert_array_equal(got, np.array(list(itertools.combinations(range(n), m))))


@pytest.mark.parametrize("n, m", [(9, 5), (10, 4)])
def test_exhaustive_matches_numpy_loop(n, m):
    blocks, _ = cases(4, n=n, seed=10)
    res = sel.exhaustive_batch(blocks, m)
    for c in range(4):
        ref = exhaustive_reference(np.asarray(blocks[c]), m)
        np.testing.assert_array_equal(res.pdop_idx[c], ref["pdop"][1])
        np.testing.assert_array_equal(res.adop_idx[c], ref["adop"][1])
        np.testing.assert_allclose(res.pdop[c], ref["pdop"][0], rtol=1e-10)
        np.testing.assert_allclose(res.adop[c], ref["adop"][0], rtol=1e-10)
    assert np.all(np.asarray(res.status) == Status.OK)


def test_exhaustive_vmap_jit_batch_and_chunks_agree():
    blocks, _ = cases(4)
    batch = sel.exhaustive_batch(blocks, M)
    vm = jax.jit(jax.vmap(lambda b: sel.exhaustive(b, M, throw=False)))(blocks)
    odd_chunks = sel.exhaustive_batch(blocks, M, chunk_size=50)  # 126 = 2 x 50 + 26: padded
    one = sel.exhaustive(blocks[2], M)
    for other in (vm, odd_chunks):
        for field in ("pdop_idx", "adop_idx", "pdop", "adop", "status"):
            np.testing.assert_array_equal(getattr(other, field), getattr(batch, field))
    np.testing.assert_array_equal(one.pdop_idx, batch.pdop_idx[2])
    np.testing.assert_array_equal(one.adop, batch.adop[2])


def test_exhaustive_float32_kernel_returns_the_float64_optimum():
    blocks, _ = cases(6)
    ref = sel.exhaustive_batch(blocks, M)
    f32 = sel.exhaustive_batch(blocks, M, kernel_dtype=jnp.float32)
    np.testing.assert_array_equal(f32.pdop_idx, ref.pdop_idx)
    np.testing.assert_array_equal(f32.adop_idx, ref.adop_idx)
    assert f32.pdop.dtype == jnp.float64
    np.testing.assert_array_equal(f32.pdop, ref.pdop)


@pytest.mark.parametrize("tied_cases", [1, 6])
def test_exhaustive_float32_near_ties_are_redone_in_float64(tied_cases):
    # A duplicated point makes two subsets exactly tied: float32 cannot certify its winner, so the
    # case is searched again in float64 (a few cases: gathered; all of them: the whole batch).
    blocks, _ = cases(6)
    dup = blocks.at[:tied_cases, 1].set(blocks[:tied_cases, 0])
    ref = sel.exhaustive_batch(dup, M)
    f32 = sel.exhaustive_batch(dup, M, kernel_dtype=jnp.float32)
    np.testing.assert_array_equal(f32.pdop_idx, ref.pdop_idx)
    np.testing.assert_array_equal(f32.adop_idx, ref.adop_idx)
    # Ties go to the subset first in lexicographic order: with 0 and 1 identical, never 1 alone.
    for c in range(tied_cases):
        for idx in (ref.pdop_idx[c], ref.adop_idx[c]):
            assert not (1 in idx and 0 not in idx)


def test_exhaustive_mask_equals_search_on_valid_points():
    blocks, _ = cases(2, n=11)
    mask = np.ones((2, 11), bool)
    mask[0, [2, 7]] = False
    mask[1, [0]] = False
    res = sel.exhaustive_batch(blocks, M, mask=mask)
    for c in range(2):
        valid = np.flatnonzero(mask[c])
        ref = exhaustive_reference(np.asarray(blocks[c])[valid], M)
        np.testing.assert_array_equal(res.pdop_idx[c], valid[list(ref["pdop"][1])])
        np.testing.assert_array_equal(res.adop_idx[c], valid[list(ref["adop"][1])])
    for crit in ("pdop", "adop"):
        valid = np.flatnonzero(mask[0])
        np.testing.assert_array_equal(
            sel.greedy(blocks[0], M, criterion=crit, mask=mask[0]),
            valid[np.asarray(sel.greedy(blocks[0][valid], M, criterion=crit))],
        )
    # NaN in a masked-out block is ignored.
    nan_blocks = blocks.at[0, 2].set(jnp.nan)
    res_nan = sel.exhaustive_batch(nan_blocks, M, mask=mask)
    np.testing.assert_array_equal(res_nan.pdop_idx, res.pdop_idx)


def test_subset_dop_matches_dop_of_the_points():
    points, pose, cam = scene(4)
    blocks = blocks_of(points, pose, cam)
    idx = jnp.array([0, 2, 3, 5, 8])
    p, a = sel.subset_dop(blocks, idx)
    ref = dop(jnp.asarray(points)[idx], pose, cam)
    np.testing.assert_allclose([p, a], [ref.pdop, ref.adop], rtol=1e-12)


def test_trace_kernel_matches_inverse_and_flags_singular(rng):
    X = rng.normal(size=(50, 9, 6)) * np.array([1, 1, 0.1, 3, 3, 0.3])
    A = np.einsum("bki,bkj->bij", X, X)
    A[0] = np.outer(X[0, 0], X[0, 0]) + np.outer(X[0, 1], X[0, 1])  # rank 2: singular
    t_pp, t_aa, ok = traces([jnp.asarray(A[:, i, j]) for i, j in PAIRS])
    Q = np.linalg.inv(A[1:])
    np.testing.assert_allclose(t_pp[1:], np.einsum("bii->b", Q[:, :3, :3]), rtol=1e-9)
    np.testing.assert_allclose(t_aa[1:], np.einsum("bii->b", Q[:, 3:, 3:]), rtol=1e-9)
    assert not ok[0] and np.all(ok[1:])


# ------------------------------------------------------------------ greedy and quasi vs optimum
def test_greedy_and_quasi_never_beat_the_optimum():
    blocks, pc = cases(8, n=12, seed=30)
    m = 6
    opt = sel.exhaustive_batch(blocks, m)
    quasi = jax.vmap(lambda p: sel.quasi_optimal(p, m))(pc)
    one = jax.vmap(lambda p: sel.one_step(p, m))(pc)
    g_p = jax.vmap(lambda b: sel.greedy(b, m, criterion="pdop"))(blocks)
    g_a = jax.vmap(lambda b: sel.greedy(b, m, criterion="adop"))(blocks)
    tol = 1 + 1e-12
    for idx in (quasi, one, g_p, g_a):
        p, a = jax.vmap(sel.subset_dop)(blocks, idx)
        assert np.all(np.asarray(p) * tol >= np.asarray(opt.pdop))
        assert np.all(np.asarray(a) * tol >= np.asarray(opt.adop))
    # Greedy on the DOP itself is usually at the optimum.
    p, _ = jax.vmap(sel.subset_dop)(blocks, g_p)
    assert np.mean(np.asarray(p) <= np.asarray(opt.pdop) * tol) >= 0.5


def test_greedy_matches_a_numpy_backward_elimination():
    blocks, _ = cases(3, n=10, seed=40)
    for c in range(3):
        b = np.asarray(blocks[c])
        keep = list(range(10))
        while len(keep) > M:
            scores = [dop_numpy(b, [j for j in keep if j != k])[0] for k in keep]
            keep.pop(int(np.argmin(scores)))
        np.testing.assert_array_equal(sel.greedy(blocks[c], M), keep)


def test_jit_matches_eager():
    blocks, pc = cases(1)
    np.testing.assert_array_equal(
        jax.jit(lambda p: sel.quasi_optimal(p, M))(pc[0]), sel.quasi_optimal(pc[0], M)
    )
    np.testing.assert_array_equal(
        jax.jit(lambda b: sel.greedy(b, M, criterion="adop"))(blocks[0]),
        sel.greedy(blocks[0], M, criterion="adop"),
    )


# ------------------------------------------------------------ select_features and bad inputs
def test_select_features_methods():
    points, pose, cam = scene(5)
    blocks = blocks_of(points, pose, cam)
    pc = pose.apply(jnp.asarray(points))
    opt = sel.exhaustive(blocks, M)
    np.testing.assert_array_equal(
        sel.select_features(points, pose, cam, M), sel.quasi_optimal(pc, M)
    )
    np.testing.assert_array_equal(
        sel.select_features(points, pose, cam, M, method="exhaustive", criterion="adop"),
        opt.adop_idx,
    )
    np.testing.assert_array_equal(
        sel.select_features(points, pose, cam.K, M, method="greedy"), sel.greedy(blocks, M)
    )
    # Weighted DOP: a very noisy point is never in the optimum.
    sigma = np.ones(N)
    sigma[opt.pdop_idx[0]] = 1e3
    idx = sel.select_features(points, pose, cam, M, method="exhaustive", sigma=sigma)
    assert int(opt.pdop_idx[0]) not in np.asarray(idx)


def test_select_features_bnb_equals_exhaustive():
    pytest.importorskip("jaxpose.core.select.bnb")
    points, pose, cam = scene(6)
    for criterion in ("pdop", "adop"):
        np.testing.assert_array_equal(
            sel.select_features(points, pose, cam, M, method="bnb", criterion=criterion),
            sel.select_features(points, pose, cam, M, method="exhaustive", criterion=criterion),
        )


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_bad_inputs_raise_clear_errors():
    points, pose, cam = scene(1)
    pc = np.asarray(pose.apply(jnp.asarray(points)))
    blocks = blocks_of(points, pose, cam)
    with pytest.raises(ValueError, match="cannot select m = 10"):
        sel.quasi_optimal(pc, 10)
    with pytest.raises(ValueError, match="at least 4"):
        sel.exhaustive(blocks, 3)
    with pytest.raises(ValueError, match="at least 4"):
        sel.select_features(points, pose, cam, 2)
    with pytest.raises(ValueError, match="static"):
        sel.greedy(blocks, jnp.int32(5))
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        sel.quasi_optimal(pc[None], 5)
    with pytest.raises(ValueError, match=r"shape \(n, 6, 6\)"):
        sel.exhaustive(blocks[None], 5)
    with pytest.raises(ValueError, match=r"shape \(C, n, 6, 6\)"):
        sel.exhaustive_batch(blocks, 5)
    with pytest.raises(ValueError, match="mask must have shape"):
        sel.quasi_optimal(pc, 5, mask=np.ones(4, bool))
    with pytest.raises(ValueError, match="method must be"):
        sel.select_features(points, pose, cam, 5, method="best")
    with pytest.raises(ValueError, match="criterion must be"):
        sel.greedy(blocks, 5, criterion="gdop")
    nan_pc = pc.copy()
    nan_pc[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        sel.quasi_optimal(nan_pc, 5)
    nan_points = points.copy()
    nan_points[2, 0] = np.nan
    for method in sel.METHODS[:4]:
        with pytest.raises(ValueError, match="NaN"):
            sel.select_features(nan_points, pose, cam, 5, method=method)
    with pytest.raises(ValueError, match="NaN"):
        sel.exhaustive(blocks.at[0, 0, 0].set(jnp.nan), 5)
    with pytest.raises(ValueError, match="NaN"):
        sel.greedy(blocks.at[0, 0, 0].set(jnp.nan), 5)
    behind = pose.apply(jnp.asarray(points)).at[4, 2].set(-1.0)
    with pytest.raises(ValueError, match="behind the camera"):
        sel.one_step(behind, 5)
    with pytest.raises(ValueError, match="too few"):
        sel.quasi_optimal(pc, 5, mask=np.arange(N) < 3)


def test_batched_statuses_instead_of_errors():
    blocks, pc = cases(4)
    bad = blocks.at[1, 0, 0, 0].set(jnp.nan)
    # Case 2: every point on one ray (the same block) makes every subset singular.
    bad = bad.at[2].set(jnp.broadcast_to(blocks[2, 0], blocks[2].shape))
    mask = np.ones((4, N), bool)
    mask[3, 4:] = False  # 4 valid points < m
    res = jax.jit(jax.vmap(lambda b, k: sel.exhaustive(b, M, mask=k, throw=False)))(bad, mask)
    np.testing.assert_array_equal(
        res.status, [Status.OK, Status.NONFINITE_INPUT, Status.SINGULAR, Status.TOO_FEW_POINTS]
    )
    assert np.isfinite(res.pdop[0]) and np.all(np.isinf(np.asarray(res.pdop[1:])))
    assert np.all(np.isinf(np.asarray(res.adop[1:])))
    f32 = sel.exhaustive_batch(bad, M, mask=mask, kernel_dtype=jnp.float32, throw=False)
    for field in ("status", "pdop_idx", "adop_idx", "pdop", "adop"):
        np.testing.assert_array_equal(getattr(f32, field), getattr(res, field))
    with pytest.raises(Exception, match="exhaustive selection"):
        jax.jit(lambda b: sel.exhaustive_batch(b, M))(bad[:3]).pdop.block_until_ready()
    # Quasi-optimal: statuses of the inputs, indices stay in range.
    pcb = pc.at[1, 0, 0].set(jnp.nan).at[2, 3, 2].set(-2.0)
    status = jax.vmap(lambda p, k: sel.selection_status(p, M, mask=k))(pcb, mask)
    np.testing.assert_array_equal(
        status, [Status.OK, Status.NONFINITE_INPUT, Status.BEHIND_CAMERA, Status.TOO_FEW_POINTS]
    )
    idx = jax.jit(jax.vmap(lambda p, k: sel.quasi_optimal(p, M, mask=k)))(pcb, mask)
    assert np.all((np.asarray(idx) >= 0) & (np.asarray(idx) < N))
    np.testing.assert_array_equal(idx[3, :4], [0, 1, 2, 3])  # the valid points are kept first
