"""EPnP, DLT and RANSAC (jaxpose.core.pnp): OpenCV as a live oracle, masks, statuses, small algebra.

Compilation dominates the run time here, so the tests share a few compiled functions: batches of
12 problems of 20 points (fewer points through the mask) and single problems of 12 points.
"""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from pnp_scenes import BATCH, K, N, angle, scenes

from jaxpose import PinholeCamera, Pose, RansacOptions, Status, dlt, epnp, ransac_pnp
from jaxpose.core import pnp
from jaxpose.core.geometry import rotation_angle
from jaxpose.core.pnp import _linalg

CAM = PinholeCamera.from_K(K)
CAM_DIST = PinholeCamera(800.0, 790.0, 322.0, 238.0, jnp.array([-0.08, 0.02, 1e-3, -1e-3, 0.0]))
RANGES = (2.0, 10.0, 50.0)
N_ONE = 12


def _batched(solver):
    return jax.jit(
        jax.vmap(lambda p, x, m, c: solver(p, x, c, mask=m, throw=False), in_axes=(0, 0, 0, None))
    )


batched_epnp = _batched(epnp)
batched_dlt = _batched(dlt)
one_epnp = jax.jit(lambda p, x, c, m: epnp(p, x, c, mask=m, throw=False))
ALL = np.ones((BATCH, N), bool)
ALL_ONE = np.ones(N_ONE, bool)


# ----------------------------------------------------------------------------- OpenCV oracle


@pytest.mark.parametrize("planar", [False, True], ids=["general", "planar"])
def test_epnp_equals_opencv_epnp_where_opencv_is_right(rng, planar):
    compared = 0
    for depth in RANGES:
        P, pix, R, t = scenes(rng, planar=planar, depth=depth)
        res = batched_epnp(P, pix, ALL, CAM)
        assert np.all(np.asarray(res.status) == Status.OK)
        assert np.all(np.asarray(res.planar) == planar)
        R_ours, t_ours = np.asarray(res.R), np.asarray(res.t)
        # against the truth: noise-free data give the pose to rounding error
        assert np.all(angle(R_ours, R) < 1e-9)
        np.testing.assert_allclose(t_ours, t, atol=1e-9 * depth)
        assert np.all(np.asarray(res.reprojection_error) < 1e-7)
        for b in range(BATCH):
            ok, rvec, tvec = cv2.solvePnP(P[b], pix[b], K, None, flags=cv2.SOLVEPNP_EPNP)
            R_cv = cv2.Rodrigues(rvec)[0]
            cv_right = (
                ok
                and angle(R_cv, R[b]) < 1e-6
                and np.linalg.norm(tvec.ravel() - t[b]) < 1e-6 * depth
            )
            if cv_right:  # OpenCV's EPnP has no planar case and is often wrong on planes
                compared += 1
                assert angle(R_ours[b], R_cv) < 1e-6
                np.testing.assert_allclose(t_ours[b], tvec.ravel(), atol=1e-6 * depth)
    # OpenCV is right on about 35% of noise-free planar scenes and on every general one
    assert compared >= (5 if planar else 3 * BATCH)


def test_epnp_noisy_accuracy_matches_opencv(rng):
    """With 0.5 px noise EPnP is as accurate as OpenCV's (median over 36 scenes)."""
    ours, cv = [], []
    for _ in range(3):
        P, pix, R, _ = scenes(rng, depth=6.0, noise=0.5)
        ours.extend(angle(np.asarray(batched_epnp(P, pix, ALL, CAM).R), R))
        for b in range(BATCH):
            _, rvec, _ = cv2.solvePnP(P[b], pix[b], K, None, flags=cv2.SOLVEPNP_EPNP)
            cv.append(float(angle(cv2.Rodrigues(rvec)[0], R[b])))
    assert np.median(ours) <= 1.1 * np.median(cv)


# ----------------------------------------------------------------------------- DLT


def test_dlt_recovers_truth_and_reports_degenerate_input(rng):
    P, pix, R, t = scenes(rng, depth=4.0)
    mask = ALL.copy()
    mask[: BATCH // 2, 6:] = False  # six points in the first half, twenty in the second
    Pp, pixp, _, _ = scenes(rng, count=1, planar=True)
    P[-1], pix[-1] = Pp[0], pixp[0]  # coplanar: degenerate for the DLT
    mask[-2, 5:] = False  # five points: too few
    res = batched_dlt(P, pix, mask, CAM)
    status = np.asarray(res.status)
    assert status[-1] == Status.DEGENERATE and status[-2] == Status.TOO_FEW_POINTS
    good = slice(0, BATCH - 2)
    assert np.all(status[good] == Status.OK)
    assert np.all(angle(np.asarray(res.R[good]), R[good]) < 1e-8)
    np.testing.assert_allclose(np.asarray(res.t[good]), t[good], atol=1e-8)


# ----------------------------------------------------------------------------- RANSAC


def test_ransac_iterations_eq35():
    assert pnp.ransac_iterations(0.999, 0.5, 6) == 439
    assert pnp.ransac_iterations(0.99, 1.0, 6) == 1
    assert pnp.ransac_iterations(0.99, 0.7, 6) == int(np.ceil(np.log(0.01) / np.log(1 - 0.7**6)))
    with pytest.raises(ValueError, match="confidence"):
        pnp.ransac_iterations(1.0, 0.5)


def test_ransac_recovers_pose_with_30_to_50_percent_outliers(rng):
    count, n = 6, 30
    P, pix, R, _ = scenes(rng, count=count, n=n, depth=5.0, noise=0.3)
    bad = np.zeros((count, n), bool)
    for b, fraction in enumerate(np.linspace(0.3, 0.5, count)):
        idx = rng.choice(n, int(round(fraction * n)), replace=False)
        bad[b, idx] = True
        pix[b, idx] += rng.uniform(40, 200, (len(idx), 2)) * rng.choice([-1, 1], (len(idx), 2))
    keys = jax.random.split(jax.random.key(3), count)
    solve = jax.jit(
        jax.vmap(
            lambda p, x, k: ransac_pnp(
                p, x, CAM, key=k, options=RansacOptions(threshold_px=3.0), throw=False
            )
        )
    )
    res = solve(P, pix, keys)
    assert np.all(np.asarray(res.status) == Status.OK)
    assert np.all(angle(np.asarray(res.R), R) < np.radians(1.0))
    np.testing.assert_array_equal(np.asarray(res.inliers), ~bad)
    assert np.all(np.asarray(res.reprojection_error) < 1.0)


# ----------------------------------------------------------------------------- jit, vmap, masks


def test_padding_with_mask_equals_unpadded_single_problems(rng):
    """Padded to 20 points with garbage under a mask, in a vmapped batch: the same poses as
    each problem alone at its own size (12 points), to rounding."""
    P, pix, _, _ = scenes(rng, n=N_ONE, depth=4.0, noise=0.5)
    pad = N - N_ONE
    Pp = np.concatenate([P, np.full((BATCH, pad, 3), np.nan)], axis=1)
    pixp = np.concatenate([pix, rng.uniform(0, 640, (BATCH, pad, 2))], axis=1)
    mask = np.broadcast_to(np.arange(N) < N_ONE, (BATCH, N))
    padded = batched_epnp(Pp, pixp, mask, CAM)
    for b in range(3):
        one = one_epnp(P[b], pix[b], CAM, ALL_ONE)
        np.testing.assert_allclose(np.asarray(padded.R[b]), np.asarray(one.R), atol=1e-12)
        np.testing.assert_allclose(np.asarray(padded.t[b]), np.asarray(one.t), atol=1e-11)
        np.testing.assert_allclose(
            float(padded.reprojection_error[b]), float(one.reprojection_error), rtol=1e-9
        )
    assert not np.asarray(padded.inliers)[:, N_ONE:].any()


def test_camera_with_distortion(rng):
    P, _, R, t = scenes(rng, count=1, n=N_ONE, depth=3.0)
    pix = CAM_DIST.project(Pose(jnp.asarray(R[0]), jnp.asarray(t[0])).apply(jnp.asarray(P[0])))
    res = one_epnp(P[0], pix, CAM_DIST, ALL_ONE)
    assert int(res.status) == Status.OK
    assert angle(np.asarray(res.R), R[0]) < 1e-8
    assert float(res.reprojection_error) < 1e-6


def test_float32(rng):
    P, pix, R, _ = scenes(rng, count=1, n=N_ONE, depth=4.0, noise=0.2)
    res = one_epnp(P[0].astype(np.float32), pix[0].astype(np.float32), CAM, ALL_ONE)
    assert res.R.dtype == jnp.float32
    assert int(res.status) == Status.OK
    assert angle(np.asarray(res.R, float), R[0]) < np.radians(1.0)


# ----------------------------------------------------------------------------- bad inputs


def test_bad_values_give_statuses(rng):
    P, pix, _, _ = scenes(rng, count=1, n=N_ONE)
    P, pix = P[0], pix[0]
    nan = P.copy()
    nan[2, 1] = np.nan
    line = np.stack(
        [np.linspace(-1, 1, N_ONE), np.linspace(0, 2, N_ONE), np.linspace(1, 3, N_ONE)], -1
    )
    # points on both sides of the camera plane: the exact solution puts some behind the camera
    straddle = rng.uniform(-1.0, 1.0, (N_ONE, 3))
    cam = straddle + [0.0, 0.0, 0.2]
    assert np.any(cam[:, 2] < 0)
    straddle_pix = cam[:, :2] / cam[:, 2:] * 800.0 + [320.0, 240.0]
    cases = [
        (Status.NONFINITE_INPUT, nan, pix, ALL_ONE),
        (Status.TOO_FEW_POINTS, P, pix, np.arange(N_ONE) < 3),
        (Status.DEGENERATE, line, pix, ALL_ONE),
        (Status.BEHIND_CAMERA, straddle, straddle_pix, ALL_ONE),
        (Status.OK, nan, pix, np.arange(N_ONE) != 2),  # the NaN point is masked out
    ]
    for want, points, pixels, mask in cases:
        res = one_epnp(points, pixels, CAM, mask)
        assert int(res.status) == want, Status(want).name
        if want != Status.OK:
            assert np.isinf(float(res.reprojection_error))
            np.testing.assert_array_equal(np.asarray(res.R), np.eye(3))
            assert np.all(np.isfinite(np.asarray(res.t)))


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_shape_errors():
    with pytest.raises(ValueError, match="points_body"):
        epnp(np.zeros((5, 2)), np.zeros((5, 2)), CAM, throw=False)
    with pytest.raises(ValueError, match="pixels"):
        epnp(np.zeros((5, 3)), np.zeros((4, 2)), CAM, throw=False)
    with pytest.raises(ValueError, match="mask"):
        epnp(np.zeros((5, 3)), np.zeros((5, 2)), CAM, mask=np.ones(4, bool), throw=False)
    with pytest.raises(ValueError, match="camera"):
        epnp(np.zeros((5, 3)), np.zeros((5, 2)), np.eye(2), throw=False)
    with pytest.raises(ValueError, match="sample_size"):
        ransac_pnp(np.zeros((5, 3)), np.zeros((5, 2)), CAM, key=jax.random.key(0), throw=False)


# ----------------------------------------------------------------------------- planar mirror


def test_planar_flip_is_the_weak_perspective_mirror(rng):
    P, _, R, t = scenes(rng, count=1, planar=True, depth=200.0)
    pose = Pose(jnp.asarray(R[0]), jnp.asarray(t[0]))
    normal = jnp.array([0.0, 0.0, 1.0])
    flipped = pnp.planar_flip(pose, jnp.zeros(3), normal)
    assert abs(float(jnp.linalg.det(flipped.R)) - 1.0) < 1e-12
    a = CAM.project(pose.apply(jnp.asarray(P[0])))
    b = CAM.project(flipped.apply(jnp.asarray(P[0])))
    assert float(jnp.max(jnp.abs(a - b))) < 0.5  # almost the same image at 200 m
    assert float(rotation_angle(flipped.R, pose.R)) > np.radians(1.0)  # another attitude
    twice = pnp.planar_flip(flipped, jnp.zeros(3), normal)
    np.testing.assert_allclose(np.asarray(twice.R), R[0], atol=1e-12)


# ----------------------------------------------------------------------------- small algebra


def test_small_eigensolver_and_solve(rng):
    mats = [rng.normal(size=(4, 4)) for _ in range(20)]
    mats = [m + m.T for m in mats]
    mats += [np.eye(4), np.diag([1.0, 1.0, 2.0, 1e-12]), np.zeros((4, 4))]
    w, V = jax.jit(jax.vmap(_linalg._eigh_small))(jnp.asarray(np.stack(mats)))
    w, V = np.asarray(w), np.asarray(V)
    for A, wi, Vi in zip(mats, w, V, strict=True):
        tol = 1e-12 * (1 + np.abs(A).max())
        np.testing.assert_allclose(wi, np.linalg.eigvalsh(A), atol=tol)
        np.testing.assert_allclose(A @ Vi, Vi * wi, atol=tol)
        np.testing.assert_allclose(Vi.T @ Vi, np.eye(4), atol=1e-12)
    B = rng.normal(size=(3, 3))
    B = B @ B.T
    w3, _ = _linalg._eigh_small(jnp.asarray(B), descending=True)
    np.testing.assert_allclose(np.asarray(w3), np.linalg.eigvalsh(B)[::-1], rtol=1e-12)
    N = rng.normal(size=(5, 5))
    N = N @ N.T + np.eye(5)
    b = rng.normal(size=(5, 2))
    x = _linalg._spd_solve(jnp.asarray(N), jnp.asarray(b))
    np.testing.assert_allclose(np.asarray(x), np.linalg.solve(N, b), rtol=1e-10)
