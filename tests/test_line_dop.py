"""Line information blocks (Yang et al. 2024 eq. 9 in the DOP state of Ning et al. 2018): closed
form, finite differences, null space, transforms, bad input; selection on mixed point/line sets
against brute force."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxpose
from jaxpose import PinholeCamera, Pose
from jaxpose import select as sel
from jaxpose.core.dilution import dop_from_information, information_blocks, point_jacobians
from jaxpose.core.geometry import so3_exp
from jaxpose.core.line_dop import line_information_blocks, line_jacobians
from jaxpose.core.residuals import line_from_segment, line_residuals

CAMERA = PinholeCamera.from_focal_length(0.05, 5e-6, (2048, 2048))


def scene(seed, n_lines=6, n_points=0, seq="XYZ"):
    """Random segments (and points) of a ~1 m target seen at ~10 m, tilted."""
    rng = np.random.default_rng(seed)
    angles = np.deg2rad(rng.uniform(-30.0, 30.0, 3))
    pose = Pose.from_euler(
        angles, np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), 10.0]), seq
    )
    segments = rng.uniform(-0.5, 0.5, (n_lines, 2, 3))
    points = rng.uniform(-0.5, 0.5, (n_points, 3))
    return segments, points, pose


def unit_normals(segments, pose):
    """Unit normals of the projected segments (pixels), by NumPy."""
    pix = np.asarray(CAMERA.project(pose.apply(jnp.asarray(segments.reshape(-1, 3))))).reshape(
        -1, 2, 2
    )
    d = pix[:, 1] - pix[:, 0]
    n = np.c_[-d[:, 1], d[:, 0]]
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def hat(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def tangent_point_jacobian(p_body, pose):
    """d(u, v)/d(T, delta) by hand for x_cam = exp([delta]_x) R p + T at delta = 0."""
    R, t = np.asarray(pose.R), np.asarray(pose.t)
    X, Y, Z = R @ p_body + t
    fx, fy = float(CAMERA.fx), float(CAMERA.fy)
    duv = np.array([[fx / Z, 0.0, -fx * X / Z**2], [0.0, fy / Z, -fy * Y / Z**2]])
    return duv @ np.c_[np.eye(3), -hat(R @ p_body)]


def perturbed_pose(x, pose, seq, parameterization):
    if parameterization == "euler":
        return Pose.from_euler(x[3:], x[:3], seq)
    return Pose(so3_exp(x[3:]) @ pose.R, x[:3])


# ----------------------------------------------------------------------------- the Jacobian
def test_rows_equal_normal_times_point_jacobian_closed_form():
    segments, _, pose = scene(0)
    L = np.asarray(line_jacobians(segments, pose, CAMERA, parameterization="tangent"))
    n = unit_normals(segments, pose)
    for j, seg in enumerate(segments):
        for k in range(2):
            ref = n[j] @ tangent_point_jacobian(seg[k], pose)
            # The sign of a distance is a convention; the information does not depend on it.
            sign = np.sign(L[j, k] @ ref)
            np.testing.assert_allclose(sign * L[j, k], ref, rtol=1e-9, atol=1e-6)


@pytest.mark.parametrize("seq", ["XYZ", "zyx"])
def test_rows_equal_normal_times_point_jacobian_euler(seq):
    segments, _, pose = scene(1, seq=seq)
    L = np.asarray(line_jacobians(segments, pose, CAMERA, sequence=seq))
    H = np.asarray(point_jacobians(segments.reshape(-1, 3), pose, CAMERA, sequence=seq))
    ref = np.einsum("ji,jkil->jkl", unit_normals(segments, pose), H.reshape(-1, 2, 2, 6))
    np.testing.assert_allclose(np.abs(L), np.abs(ref), rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(np.sign(L * ref)[np.abs(ref) > 1e-3], 1.0)


@pytest.mark.parametrize(
    ("seq", "parameterization"), [("XYZ", "euler"), ("zyx", "euler"), ("XYZ", "tangent")]
)
def test_jacobian_matches_finite_differences_of_the_eq9_residual(seq, parameterization):
    segments, _, pose = scene(2, seq=seq)
    pix = CAMERA.project(pose.apply(jnp.asarray(segments.reshape(-1, 3)))).reshape(-1, 2, 2)
    observed = line_from_segment(pix[:, 0], pix[:, 1])  # the line seen at the true pose

    def residuals(x):
        p = perturbed_pose(x, pose, seq, parameterization)
        return line_residuals(pose=p, segments_body=segments, lines_img=observed, camera=CAMERA)

    x0 = np.r_[
        np.asarray(pose.t),
        np.asarray(pose.euler(seq)) if parameterization == "euler" else np.zeros(3),
    ]
    np.testing.assert_allclose(residuals(x0), 0.0, atol=1e-7)
    h = 1e-6
    fd = np.stack(
        [(residuals(x0 + h * e) - residuals(x0 - h * e)) / (2 * h) for e in np.eye(6)], -1
    )
    L = np.asarray(
        line_jacobians(segments, pose, CAMERA, sequence=seq, parameterization=parameterization)
    )
    np.testing.assert_allclose(L, fd, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(jax.jacrev(residuals)(x0), jax.jacfwd(residuals)(x0), atol=1e-8)


# ----------------------------------------------------------------------------- the block
def test_block_is_psd_rank_two_and_below_its_endpoints_as_points():
    segments, _, pose = scene(3)
    A = np.asarray(line_information_blocks(segments, pose, CAMERA))
    P = np.asarray(information_blocks(segments.reshape(-1, 3), pose, CAMERA)).reshape(-1, 2, 6, 6)
    for j in range(len(segments)):
        np.testing.assert_allclose(A[j], A[j].T, atol=1e-9)
        ev = np.linalg.eigvalsh(A[j])
        assert ev[0] > -1e-8 * ev[-1]
        assert np.sum(ev > 1e-9 * ev[-1]) == 2
        # Two distances along n carry no more than the four pixel coordinates of the endpoints.
        gap = np.linalg.eigvalsh(P[j].sum(0) - A[j])
        assert gap[0] > -1e-8 * ev[-1]


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    z=st.floats(2.0, 50.0),
    parameterization=st.sampled_from(["euler", "tangent"]),
)
def test_line_block_never_exceeds_its_endpoints_and_its_rows_are_normal_projections(
    seed, z, parameterization
):
    rng = np.random.default_rng(seed)
    pose = Pose.from_euler(rng.uniform(-1.0, 1.0, 3), np.r_[rng.uniform(-0.3, 0.3, 2), z])
    segments = rng.uniform(-0.5, 0.5, (3, 2, 3))
    L = np.asarray(line_jacobians(segments, pose, CAMERA, parameterization=parameterization))
    H = np.asarray(
        point_jacobians(segments.reshape(-1, 3), pose, CAMERA, parameterization=parameterization)
    ).reshape(3, 2, 2, 6)
    n = unit_normals(segments, pose)
    scale = np.abs(H).max()
    # |row| = |n^T H_k| whatever the sign convention, and the row lies in the span of H_k's rows.
    np.testing.assert_allclose(
        np.abs(np.einsum("jkl,jkl->jk", L, np.einsum("ji,jkil->jkl", n, H))),
        np.sum(L**2, -1),
        rtol=1e-8,
        atol=1e-8 * scale**2,
    )
    A = np.einsum("jki,jkl->jil", L, L)
    P = np.einsum("jkai,jkal->jil", H, H)
    for j in range(3):
        assert np.linalg.eigvalsh(P[j] - A[j])[0] > -1e-9 * np.linalg.norm(P[j])


def _line_motions(segment, pose):
    """State motions (T, delta) keeping the 3-D line on itself: slide along it, rotate about it."""
    R = np.asarray(pose.R)
    u = R @ (segment[1] - segment[0])
    u = u / np.linalg.norm(u)
    # x_cam = exp([delta]_x) R p + T moves by dT + delta x (R p): the rotation about the line
    # through R p_1 + t is delta = u, dT = -u x (R p_1).
    return np.r_[u, 0.0, 0.0, 0.0], np.r_[-np.cross(u, R @ segment[0]), u]


def test_block_annihilates_motions_along_the_line_and_its_range_does_not_depend_on_the_endpoints():
    segments, _, pose = scene(4)
    A = np.asarray(line_information_blocks(segments, pose, CAMERA, parameterization="tangent"))
    Ae = np.asarray(line_information_blocks(segments, pose, CAMERA))
    P = np.asarray(information_blocks(segments[:, 0], pose, CAMERA, parameterization="tangent"))
    # The endpoints slid along their 3-D lines (other places, other lengths).
    s = np.array([-0.7, 1.6])
    slid = segments[:, :1] + s[None, :, None] * (segments[:, 1:] - segments[:, :1])
    B = np.asarray(line_information_blocks(slid, pose, CAMERA, parameterization="tangent"))
    for j, seg in enumerate(segments):
        scale = np.linalg.norm(A[j])
        for v in _line_motions(seg, pose):
            v = v / np.linalg.norm(v)
            assert np.linalg.norm(A[j] @ v) < 1e-9 * scale
            assert np.linalg.norm(B[j] @ v) < 1e-9 * np.linalg.norm(B[j])
        slide = _line_motions(seg, pose)[0]
        # A point on the line sees the slide (it moves along the image line); not the rotation
        # about the line, which leaves every point of the line in place.
        assert np.linalg.norm(P[j] @ slide) > 1e-3 * np.linalg.norm(P[j])
        assert np.linalg.norm(Ae[j] @ slide) < 1e-9 * np.linalg.norm(Ae[j])  # T is shared
        # Sliding the endpoints changes how much the line tells, not what it tells about.
        proj = [np.linalg.eigh(X)[1][:, -2:] for X in (A[j], B[j])]
        np.testing.assert_allclose(proj[0] @ proj[0].T, proj[1] @ proj[1].T, atol=1e-6)
        assert not np.allclose(A[j], B[j], rtol=1e-3)


def test_sigma_mask_and_end_on_segments():
    segments, _, pose = scene(5)
    A = np.asarray(line_information_blocks(segments, pose, CAMERA))
    sigma = np.linspace(0.5, 2.0, len(segments))
    np.testing.assert_allclose(
        line_information_blocks(segments, pose, CAMERA, sigma=sigma), A / sigma[:, None, None] ** 2
    )
    np.testing.assert_allclose(line_information_blocks(segments, pose, CAMERA, sigma=2.0), A / 4.0)
    bad = segments.copy()
    bad[2] = np.nan
    mask = np.ones(len(segments), bool)
    mask[2] = False
    Am = np.asarray(line_information_blocks(bad, pose, CAMERA, mask=mask))
    np.testing.assert_array_equal(Am[2], 0.0)
    np.testing.assert_allclose(Am[mask], A[mask])
    point = segments.copy()
    point[1, 1] = point[1, 0]  # both endpoints on one pixel: no image line
    with pytest.raises(ValueError, match=r"segments_body\[1\] has zero length"):
        line_information_blocks(point, pose, CAMERA)  # a known zero-length segment is refused
    # traced it is not looked at: a zero block, NaN-free
    Ap = np.asarray(jax.jit(lambda s: line_information_blocks(s, pose, CAMERA))(point))
    np.testing.assert_array_equal(Ap[1], 0.0)
    assert np.all(np.isfinite(Ap))


def test_mixed_dop_equals_the_stacked_observation_matrix():
    segments, points, pose = scene(6, n_lines=3, n_points=2)
    H = np.asarray(point_jacobians(points, pose, CAMERA)).reshape(-1, 6)
    L = np.asarray(line_jacobians(segments, pose, CAMERA)).reshape(-1, 6)
    Q = np.linalg.inv(np.r_[H, L].T @ np.r_[H, L])
    A = jnp.sum(information_blocks(points, pose, CAMERA), 0) + jnp.sum(
        jaxpose.line_information_blocks(segments, pose, CAMERA), 0
    )
    res = dop_from_information(A)
    np.testing.assert_allclose(res.pdop, np.sqrt(np.trace(Q[:3, :3])), rtol=1e-8)
    np.testing.assert_allclose(res.adop, np.sqrt(np.trace(Q[3:, 3:])), rtol=1e-8)
    # Adding a line never makes the DOP worse (information only grows).
    less = dop_from_information(A - jaxpose.line_information_blocks(segments[:1], pose, CAMERA)[0])
    assert less.pdop >= res.pdop and less.adop >= res.adop


# ----------------------------------------------------------------------------- transforms
def test_jit_vmap_and_gradient_of_the_mixed_dop():
    segments, points, pose = scene(7, n_lines=3, n_points=3)
    A = line_information_blocks(segments, pose, CAMERA)
    np.testing.assert_allclose(
        jax.jit(line_information_blocks)(segments, pose, CAMERA), A, rtol=1e-12
    )
    poses = Pose(jnp.stack([pose.R, pose.R.T]), jnp.stack([pose.t, pose.t + 1.0]))
    batched = jax.vmap(lambda p: line_information_blocks(segments, p, CAMERA))(poses)
    np.testing.assert_allclose(batched[0], A, rtol=1e-12)
    np.testing.assert_allclose(
        batched[1],
        line_information_blocks(segments, Pose(pose.R.T, pose.t + 1.0), CAMERA),
        rtol=1e-12,
    )
    Ap = jnp.sum(information_blocks(points, pose, CAMERA), 0)

    def pdop(seg):
        return dop_from_information(
            Ap + jnp.sum(line_information_blocks(seg, pose, CAMERA), 0)
        ).pdop

    g = np.asarray(jax.jit(jax.grad(pdop))(jnp.asarray(segments)))
    h = 1e-6
    flat = segments.reshape(-1)
    for i in (0, 4, 9, 17):
        e = np.zeros_like(flat)
        e[i] = h
        fd = (
            pdop((flat + e).reshape(segments.shape)) - pdop((flat - e).reshape(segments.shape))
        ) / (2 * h)
        np.testing.assert_allclose(g.reshape(-1)[i], fd, rtol=1e-4, atol=1e-12)

    # ... and with respect to the pose (through the observed line and the Jacobian point).
    def adop_at(t):
        p = Pose(pose.R, t)
        A = jnp.sum(information_blocks(points, p, CAMERA), 0)
        return dop_from_information(
            A + jnp.sum(line_information_blocks(segments, p, CAMERA), 0)
        ).adop

    gt = np.asarray(jax.grad(adop_at)(pose.t))
    fd = [(adop_at(pose.t + h * e) - adop_at(pose.t - h * e)) / (2 * h) for e in jnp.eye(3)]
    np.testing.assert_allclose(gt, fd, rtol=1e-4)
    # vmap of grad: one gradient per pose.
    gv = jax.vmap(
        lambda p: jax.grad(lambda s: jnp.sum(line_information_blocks(s, p, CAMERA)))(segments)
    )(poses)
    assert gv.shape == (2, *segments.shape) and np.all(np.isfinite(gv))


def test_gradients_are_nan_free_for_masked_nan_and_end_on_segments():
    segments, _, pose = scene(8, n_lines=5)
    segments[1, 1] = segments[1, 0]
    segments[3] = np.nan
    mask = jnp.arange(5) != 3

    def total(seg):
        return jnp.sum(line_information_blocks(seg, pose, CAMERA, mask=mask))

    g = jax.jit(jax.grad(total))(jnp.asarray(segments))
    assert np.all(np.isfinite(np.asarray(g)))
    np.testing.assert_array_equal(g[3], 0.0)


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_bad_input_raises_value_error_naming_the_argument():
    segments, _, pose = scene(9)
    with pytest.raises(ValueError, match="segments_body"):
        line_information_blocks(segments[:, 0], pose, CAMERA)
    with pytest.raises(ValueError, match="segments_body"):
        line_information_blocks(segments[None], pose, CAMERA)
    with pytest.raises(ValueError, match="mask"):
        line_information_blocks(segments, pose, CAMERA, mask=np.ones(2, bool))
    with pytest.raises(ValueError, match="pose"):
        line_information_blocks(
            segments, Pose(jnp.stack([pose.R] * 2), jnp.stack([pose.t] * 2)), CAMERA
        )
    with pytest.raises(ValueError, match="parameterization"):
        line_information_blocks(segments, pose, CAMERA, parameterization="quaternion")
    with pytest.raises(ValueError, match="parameterization"):
        line_jacobians(segments, pose, CAMERA, parameterization="quaternion")
    with pytest.raises(ValueError, match="sigma"):
        line_information_blocks(segments, pose, CAMERA, sigma=np.ones(len(segments) + 1))
    with pytest.raises(ValueError, match="sigma"):
        line_information_blocks(segments, pose, CAMERA, sigma=-1.0)
    with pytest.raises(ValueError, match="sequence"):
        line_information_blocks(segments, pose, CAMERA, sequence="xYz")
    with pytest.raises(ValueError, match="sigma"):
        line_information_blocks(segments, pose, CAMERA, sigma=np.r_[np.nan, np.ones(5)])
    with pytest.raises(ValueError, match="pose"):
        line_information_blocks(segments, pose.R, CAMERA)


# ----------------------------------------------------------------------------- mixed selection
N_POINTS, N_LINES, M = 6, 5, 5  # 11 features: one compilation per method for the whole file


def mixed_blocks(seed, weighted=False):
    """Point blocks then line blocks of one scene; short and long segments."""
    segments, points, pose = scene(100 + seed, n_lines=N_LINES, n_points=N_POINTS)
    rng = np.random.default_rng(seed)
    mid = segments.mean(1, keepdims=True)
    segments = mid + rng.uniform(0.05, 1.5, (N_LINES, 1, 1)) * (segments - mid)
    sp = rng.uniform(0.5, 2.0, N_POINTS) if weighted else None
    sl = rng.uniform(0.3, 1.5, N_LINES) if weighted else None
    return np.concatenate(
        [
            np.asarray(information_blocks(points, pose, CAMERA, sigma=sp)),
            np.asarray(line_information_blocks(segments, pose, CAMERA, sigma=sl)),
        ]
    )


def brute_force(blocks, m):
    """Every m-subset with np.linalg.inv: {criterion: (values sorted, best subset)}."""
    subsets = np.array(list(itertools.combinations(range(len(blocks)), m)))
    Mx = blocks[subsets].sum(1)
    d = np.sqrt(np.diagonal(Mx, axis1=1, axis2=2))
    ev = np.linalg.eigvalsh(Mx / (d[:, :, None] * d[:, None, :]))
    ok = ev[:, 0] > 1e3 * np.finfo(float).eps * ev[:, -1]
    Q = np.linalg.inv(np.where(ok[:, None, None], Mx, np.eye(6)))
    out = {}
    for name, s in (("pdop", slice(0, 3)), ("adop", slice(3, 6))):
        v = np.where(ok, np.sqrt(np.trace(Q[:, s, s], axis1=1, axis2=2)), np.inf)
        order = np.argsort(v, kind="stable")
        out[name] = (v[order], subsets[order[0]])
    return out


def dop_of(blocks, idx, criterion):
    Q = np.linalg.inv(blocks[np.asarray(idx)].sum(0))
    s = slice(0, 3) if criterion == "pdop" else slice(3, 6)
    return np.sqrt(np.trace(Q[s, s]))


@pytest.mark.parametrize("seed", range(4))
def test_exhaustive_and_branch_and_bound_on_mixed_blocks_equal_brute_force(seed):
    blocks = mixed_blocks(seed, weighted=seed % 2 == 1)
    ref = brute_force(blocks, M)
    ex = sel.exhaustive(blocks, M)
    for criterion in ("pdop", "adop"):
        values, best = ref[criterion]
        unique = values[1] > values[0] * (1 + 1e-8)
        got = ex.pdop_idx if criterion == "pdop" else ex.adop_idx
        np.testing.assert_allclose(getattr(ex, criterion), values[0], rtol=1e-9)
        bb = sel.branch_and_bound(blocks, M, criterion=criterion)
        np.testing.assert_allclose(bb.value, values[0], rtol=1e-9)
        if unique:
            np.testing.assert_array_equal(got, best)
            np.testing.assert_array_equal(bb.idx, best)


def test_exhaustive_float32_kernel_on_mixed_blocks_returns_the_float64_optimum():
    blocks = np.stack([mixed_blocks(seed) for seed in range(3)])
    f64 = sel.exhaustive_batch(blocks, M)
    f32 = sel.exhaustive_batch(blocks, M, kernel_dtype=jnp.float32)
    for name in ("pdop_idx", "adop_idx", "pdop", "adop"):
        np.testing.assert_array_equal(getattr(f32, name), getattr(f64, name))


def test_optimal_mixed_subsets_use_lines_and_beat_points_only():
    """Non-trivial cases: the optimum takes lines and beats the best points-only subset."""
    with_lines = 0
    for seed in range(4):
        blocks = mixed_blocks(seed)
        best = brute_force(blocks, M)["adop"][1]
        with_lines += np.any(best >= N_POINTS)
        points_only = brute_force(blocks[:N_POINTS], M)["adop"][0][0]
        assert dop_of(blocks, best, "adop") <= points_only * (1 + 1e-12)
    assert with_lines >= 2


@pytest.mark.parametrize("criterion", ["pdop", "adop"])
def test_greedy_on_mixed_blocks_equals_a_numpy_backward_elimination(criterion):
    for seed in range(3):
        blocks = mixed_blocks(seed)
        keep = list(range(len(blocks)))
        while len(keep) > M:
            scores = [dop_of(blocks, [j for j in keep if j != k], criterion) for k in keep]
            keep.pop(int(np.argmin(scores)))
        np.testing.assert_array_equal(sel.greedy(blocks, M, criterion=criterion), keep)
        # ... and never beats the optimum.
        optimum = brute_force(blocks, M)[criterion][0][0]
        assert dop_of(blocks, keep, criterion) >= optimum * (1 - 1e-12)


def test_lines_only_selection_and_a_padded_mixed_set():
    blocks = mixed_blocks(0)
    lines = blocks[N_POINTS:]
    ref = brute_force(lines, 4)["pdop"]
    np.testing.assert_allclose(sel.exhaustive(lines, 4).pdop, ref[0][0], rtol=1e-9)
    np.testing.assert_allclose(sel.branch_and_bound(lines, 4).value, ref[0][0], rtol=1e-9)
    # Masked-out entries of a padded set are never selected.
    mask = np.ones(len(blocks), bool)
    mask[[1, N_POINTS + 2]] = False
    keep = np.flatnonzero(mask)
    ref = brute_force(blocks[keep], M)["pdop"]
    ex = sel.exhaustive(blocks, M, mask=mask)
    np.testing.assert_allclose(ex.pdop, ref[0][0], rtol=1e-9)
    assert not set(np.asarray(ex.pdop_idx)) & {1, N_POINTS + 2}
    assert not set(np.asarray(sel.greedy(blocks, M, mask=mask))) & {1, N_POINTS + 2}
