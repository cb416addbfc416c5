"""jaxpose.solve_pnp: the batched, OpenCV-like entry point (EPnP/DLT/RANSAC + refinement).

OpenCV is the live oracle of the refined poses. Compilation dominates the run time, so most
tests share one configuration: batches of 12 problems of 20 points, refined by LM.
"""

import os
import subprocess
import sys

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from pnp_scenes import BATCH, K, N, angle, scenes

import jaxpose
from jaxpose import (
    PinholeCamera,
    PnPOptions,
    Pose,
    RansacOptions,
    RefineOptions,
    Status,
    solve_pnp,
)
from jaxpose.core.geometry import so3_exp

CAM_DIST = PinholeCamera(800.0, 790.0, 322.0, 238.0, jnp.array([-0.08, 0.02, 1e-3, -1e-3, 0.0]))


def cv_refined(P, pix, K):
    """OpenCV's EPnP + solvePnPRefineLM, and its RMS reprojection error."""
    _, rvec, tvec = cv2.solvePnP(P, pix, K, None, flags=cv2.SOLVEPNP_EPNP)
    rvec, tvec = cv2.solvePnPRefineLM(P, pix, K, None, rvec, tvec)
    proj, _ = cv2.projectPoints(P, rvec, tvec, K, None)
    return (
        cv2.Rodrigues(rvec)[0],
        tvec.ravel(),
        float(np.sqrt(np.mean(np.sum((proj[:, 0] - pix) ** 2, -1)))),
    )


# ----------------------------------------------------------------------------- accuracy


@pytest.mark.parametrize("planar", [False, True], ids=["general", "planar"])
def test_refined_error_no_larger_than_opencv_refine_lm(rng, planar):
    P, pix, R, t = scenes(rng, planar=planar, depth=8.0, noise=0.5)
    res = solve_pnp(P, pix, K)
    assert res.R.shape == (BATCH, 3, 3) and res.status.shape == (BATCH,)
    assert np.all(np.asarray(res.status) == Status.OK)
    ours = np.asarray(res.reprojection_error)
    for b in range(BATCH):
        _, _, cv_rms = cv_refined(P[b], pix[b], K)
        assert ours[b] <= cv_rms + 1e-9
    assert np.all(angle(np.asarray(res.R), R) < np.radians(2.0))


def test_single_problem_noise_free_with_K_and_with_a_distorted_camera(rng):
    P, pix, R, t = scenes(rng, count=1)
    res = solve_pnp(P[0], pix[0], K)
    assert res.R.shape == (3, 3) and res.status.shape == ()
    assert angle(np.asarray(res.R), R[0]) < 1e-10
    np.testing.assert_allclose(np.asarray(res.t), t[0], atol=1e-9)
    assert float(res.reprojection_error) < 1e-8
    pix_d = CAM_DIST.project(Pose(jnp.asarray(R[0]), jnp.asarray(t[0])).apply(jnp.asarray(P[0])))
    res = solve_pnp(P[0], pix_d, CAM_DIST)
    assert angle(np.asarray(res.R), R[0]) < 1e-10
    assert float(res.reprojection_error) < 1e-8


def test_leading_axes_broadcast(rng):
    """One model seen in a (3, 4) grid of images: points (n, 3), pixels (3, 4, n, 2)."""
    P, _, _, _ = scenes(rng, count=1)
    R = np.asarray(so3_exp(rng.normal(size=(BATCH, 3)) * 0.5))
    t = np.stack([np.zeros(BATCH), np.zeros(BATCH), np.linspace(3.0, 9.0, BATCH)], -1)
    cam = np.einsum("bij,nj->bni", R, P[0]) + t[:, None]
    pix = cam[..., :2] / cam[..., 2:] * 800.0 + [320.0, 240.0]
    res = solve_pnp(P[0], pix.reshape(3, 4, N, 2), K)
    assert res.R.shape == (3, 4, 3, 3) and res.inliers.shape == (3, 4, N)
    assert np.all(angle(np.asarray(res.R).reshape(BATCH, 3, 3), R) < 1e-9)


def test_planar_long_range_as_often_right_as_opencv_ippe(rng):
    """The two-fold ambiguity of a far plane: EPnP's pose and its mirror are both refined."""
    Kf = np.array([[3000.0, 0.0, 1023.5], [0.0, 3000.0, 1023.5], [0.0, 0.0, 1.0]])
    P, pix, R, _ = scenes(rng, planar=True, depth=15.0, noise=0.5, K=Kf)
    res = solve_pnp(P, pix, Kf)
    ours = angle(np.asarray(res.R), R) < np.radians(5.0)
    ippe = []
    for b in range(BATCH):
        _, rvec, _ = cv2.solvePnP(P[b], pix[b], Kf, None, flags=cv2.SOLVEPNP_IPPE)
        ippe.append(angle(cv2.Rodrigues(rvec)[0], R[b]) < np.radians(5.0))
    assert ours.sum() >= np.sum(ippe)
    assert np.all(np.asarray(res.planar))


def lm_refined(P, pix, K, start):
    """``refine_pose`` (the LM, converged to solve_pnp's tolerance) from the poses in ``start``."""
    return jax.vmap(
        lambda p, x, R, t: jaxpose.refine_pose(
            p, x, Pose(R, t), K, options=PnPOptions().refine, throw=False
        )
    )(P, pix, start.R, start.t)


@pytest.mark.parametrize(
    "depth, noise, n",
    [(6.0, 0.0, N), (8.0, 0.5, N), (20.0, 2.0, 8)],
    ids=["exact", "noisy", "hard"],
)
def test_fast_refinement_agrees_with_the_lm(rng, depth, noise, n):
    """solve_pnp refines by a few Gauss-Newton steps and hands the problems that have not
    converged to the LM: the answer is the LM's (refine_pose from the same EPnP pose) to the
    stopping tolerance, with the same statuses; OpenCV's solvePnPRefineLM finds no lower error.
    The "hard" batch (8 points, 2 px, 20 m) leaves most problems to the LM, more than one group
    (16) of them."""
    from jaxpose.core.pnp._gauss_newton import gauss_newton_pnp

    P, pix, R, t = scenes(rng, count=40, n=n, depth=depth, noise=noise)
    res = solve_pnp(P, pix, K, throw=False)
    start = solve_pnp(P, pix, K, options=PnPOptions(refine=None), throw=False)
    lm = lm_refined(P, pix, K, start.pose)
    np.testing.assert_array_equal(np.asarray(res.status), np.asarray(lm.status))
    assert np.all(np.asarray(res.status) == Status.OK)
    tol = PnPOptions().refine.rtol
    np.testing.assert_allclose(np.asarray(res.R), np.asarray(lm.pose.R), atol=10 * tol)
    np.testing.assert_allclose(np.asarray(res.t), np.asarray(lm.pose.t), atol=10 * tol * depth)
    np.testing.assert_allclose(
        np.asarray(res.reprojection_error), np.asarray(lm.rms_px), rtol=1e-6, atol=1e-9
    )
    for b in range(0, 40, 8):
        _, _, cv_rms = cv_refined(P[b], pix[b], K)
        assert float(res.reprojection_error[b]) <= cv_rms + 1e-9
    # how many problems the Gauss-Newton alone leaves unconverged (the LM's share)
    xy = (pix - K[:2, 2]) / K[[0, 1], [0, 1]]
    _, _, ok = jax.vmap(
        lambda p, x, R, t: gauss_newton_pnp(
            p, x, jnp.ones(n), jnp.asarray(K[[0, 1], [0, 1]]), Pose(R, t), rtol=tol, atol=1e-9
        )
    )(P, xy, start.R, start.t)
    left = int(np.sum(~np.asarray(ok)))
    assert left == 0 if noise == 0 else (left > 16 if n == 8 else True)


# ----------------------------------------------------------------------------- methods


def test_dlt_and_closed_form_only(rng):
    P, pix, R, _ = scenes(rng, depth=4.0, noise=0.3)
    for method, refine in (("dlt", "lm"), ("epnp", None)):
        res = solve_pnp(
            P,
            pix,
            K,
            options=PnPOptions(
                method=method,
                refine=(
                    None if refine is None else RefineOptions(method=refine, rtol=1e-6, atol=1e-9)
                ),
            ),
        )
        assert np.all(np.asarray(res.status) == Status.OK), method
        assert np.all(angle(np.asarray(res.R), R) < np.radians(2.0)), method


@pytest.mark.slow
def test_ransac_with_robust_refinement(rng):
    P, pix, R, _ = scenes(rng, depth=5.0, noise=0.3)
    bad = np.argsort(rng.random((BATCH, N)), axis=1) < int(0.4 * N)  # 40% outliers in each
    pix = np.where(bad[..., None], pix + rng.uniform(30, 150, pix.shape), pix)
    res = solve_pnp(
        P,
        pix,
        K,
        options=PnPOptions(
            method="ransac",
            refine=RefineOptions(rtol=1e-6, atol=1e-9, robust="huber"),
            ransac=RansacOptions(threshold_px=3.0),
        ),
    )
    assert np.all(np.asarray(res.status) == Status.OK)
    assert np.all(angle(np.asarray(res.R), R) < np.radians(1.0))
    np.testing.assert_array_equal(np.asarray(res.inliers), ~bad)


def mixed_batch(count=71):
    """General and planar problems together: an odd number (padding over two devices) that three
    host threads do not divide either. The chunked, the threaded and the two-device tests share
    this one batch, so that they share its compiled solves (compilation is most of their time)."""
    rng = np.random.default_rng(7)
    Pg, pixg, Rg, _ = scenes(rng, count=count // 2, depth=6.0, noise=0.3)
    Pp, pixp, Rp, _ = scenes(rng, count=count - count // 2, planar=True, depth=6.0, noise=0.3)
    return tuple(np.concatenate(a) for a in ((Pg, Pp), (pixg, pixp), (Rg, Rp)))


def test_large_batches_run_in_chunks_and_refine_planar_problems_twice():
    """Above FUSED_MAX problems: closed form, a planarity check, then refinement, by chunks."""
    P, pix, R = mixed_batch()
    res = solve_pnp(P, pix, K, options=PnPOptions(chunk=32))
    assert res.R.shape == (len(P), 3, 3)
    assert np.all(np.asarray(res.status) == Status.OK)
    err = angle(np.asarray(res.R), R)  # one planar scene is ill-conditioned: 5 deg, as OpenCV's
    assert np.all(err < np.radians(10.0)) and np.median(err) < np.radians(0.5)
    np.testing.assert_array_equal(np.asarray(res.planar), np.arange(len(P)) >= len(P) // 2)


def test_host_threads_take_the_callers_precision():
    """The host threads compute in the caller's ``jax_enable_x64`` (a context of the calling
    thread, such as the pipelines' float64, does not reach a worker by itself)."""
    from jaxpose.core._threads import in_threads

    for x64, dtype in ((False, jnp.float32), (True, jnp.float64)):
        with jax.enable_x64(x64):
            out = in_threads(lambda i: jnp.zeros(1) + i, [0, 1, 2])
        assert [x.dtype for x in out] == [dtype] * 3


def test_host_threads_give_the_same_poses_and_statuses():
    """A batch split over host threads (padded to equal parts) gives the one-thread answer, with
    each bad problem's status in its place."""
    P, pix, _ = mixed_batch()
    pix = pix.copy()
    pix[5, 3] = np.nan  # one bad problem in the first part, none in the others
    one = solve_pnp(P, pix, K, throw=False, options=PnPOptions(chunk=32, workers=1))
    three = solve_pnp(P, pix, K, throw=False, options=PnPOptions(chunk=32, workers=3))
    assert len(P) % 3 != 0  # the parts are padded
    status = np.asarray(three.status)
    assert status.shape == (len(P),) and status[5] == Status.NONFINITE_INPUT
    np.testing.assert_array_equal(status, np.asarray(one.status))
    np.testing.assert_allclose(np.asarray(three.R), np.asarray(one.R), atol=1e-8)
    np.testing.assert_allclose(np.asarray(three.t), np.asarray(one.t), atol=1e-8)
    with pytest.raises(ValueError, match="workers"):
        solve_pnp(P, pix, K, options=PnPOptions(workers=0))


@pytest.mark.slow
def test_two_devices_give_the_same_poses(tmp_path):
    """With two (forced host) devices the batch is split over them, padded to an even size."""
    P, pix, _ = mixed_batch()
    one = solve_pnp(P, pix, K, options=PnPOptions(chunk=32))
    np.savez(tmp_path / "in.npz", P=P, pix=pix, K=K)
    code = (
        "import jax, numpy as np; jax.config.update('jax_enable_x64', True);"
        "import jaxpose; assert jax.local_device_count() == 2;"
        f"d = np.load({str(tmp_path / 'in.npz')!r});"
        "r = jaxpose.solve_pnp(d['P'], d['pix'], d['K'], options=jaxpose.PnPOptions(chunk=32));"
        f"np.savez({str(tmp_path / 'out.npz')!r}, R=r.R, t=r.t, status=r.status)"
    )
    env = dict(
        os.environ,
        XLA_FLAGS=os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2",
        JAX_PLATFORMS="cpu",
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    two = np.load(tmp_path / "out.npz")
    np.testing.assert_array_equal(two["status"], np.asarray(one.status))
    # other compiled programs round differently, and the refinement may then stop one step
    # earlier or later: the two answers agree to the refinement's own stopping tolerance (the
    # eager entry points now compile with other XLA options, and 1e-7 differences were seen)
    tol = PnPOptions().refine.rtol
    np.testing.assert_allclose(two["R"], np.asarray(one.R), atol=tol)
    np.testing.assert_allclose(two["t"], np.asarray(one.t), atol=tol * np.abs(one.t).max())


# ----------------------------------------------------------------------------- bad inputs


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_bad_input_raises_clear_value_errors(rng):
    P, pix, _, _ = scenes(rng, count=1)
    P, pix = P[0], pix[0]
    with pytest.raises(ValueError, match="same number of points"):
        solve_pnp(P, pix[:-1], K)
    with pytest.raises(ValueError, match="at least 4 points"):
        solve_pnp(P[:3], pix[:3], K)
    with pytest.raises(ValueError, match=r"\(\.\.\., n, 3\)"):
        solve_pnp(P[:, :2], pix, K)
    with pytest.raises(ValueError, match="do not broadcast"):
        solve_pnp(np.stack([P, P]), np.stack([pix, pix, pix]), K)
    with pytest.raises(ValueError, match="method"):
        solve_pnp(P, pix, K, options=PnPOptions(method="p3p"))
    with pytest.raises(ValueError, match="robust"):
        solve_pnp(P, pix, K, options=PnPOptions(refine=RefineOptions(robust="l1")))
    with pytest.raises(ValueError, match="PnPOptions.refine must be a RefineOptions"):
        PnPOptions(refine="lm")
    with pytest.raises(ValueError, match="options must be a PnPOptions"):
        solve_pnp(P, pix, K, options={"method": "epnp"})
    with pytest.raises(ValueError, match="needs at least 6 points"):
        solve_pnp(P[:5], pix[:5], K, options=PnPOptions(method="dlt"))
    with pytest.raises(ValueError, match="camera"):
        solve_pnp(P, pix, np.eye(4))
    nan = P.copy()
    nan[3, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        solve_pnp(nan, pix, K)
    line = np.stack([np.linspace(-1, 1, N), np.linspace(0, 2, N), np.zeros(N)], -1)
    with pytest.raises(ValueError, match="degenerate"):
        solve_pnp(line, pix, K)
    straddle = rng.uniform(-1.0, 1.0, (N, 3))
    cam = straddle + [0.0, 0.0, 0.2]
    with pytest.raises(ValueError, match="behind the camera"):
        solve_pnp(straddle, cam[:, :2] / cam[:, 2:] * 800.0 + [320.0, 240.0], K)


def test_bad_problems_in_a_batch_get_a_status(rng):
    P, pix, R, _ = scenes(rng, depth=5.0, noise=0.3)
    P[1, 4] = np.nan  # NaN
    mask = np.ones((BATCH, N), bool)
    mask[2, 3:] = False  # three valid points
    P[3] = np.stack([np.linspace(-1, 1, N), np.linspace(0, 2, N), np.zeros(N)], -1)  # collinear
    res = solve_pnp(P, pix, K, mask=mask, throw=False)
    status = np.asarray(res.status)
    assert status[1] == Status.NONFINITE_INPUT
    assert status[2] == Status.TOO_FEW_POINTS
    assert status[3] == Status.DEGENERATE
    good = np.arange(BATCH) >= 4
    assert np.all(status[good] == Status.OK)
    assert np.all(angle(np.asarray(res.R)[good], R[good]) < np.radians(2.0))
    assert np.all(np.isinf(np.asarray(res.reprojection_error)[1:4]))
    assert np.all(np.isfinite(np.asarray(res.R))) and np.all(np.isfinite(np.asarray(res.t)))
    with pytest.raises(ValueError, match=r"at 1 of 12"):
        solve_pnp(P, pix, K, mask=mask)


def test_public_names():
    for name in ("solve_pnp", "epnp", "dlt", "ransac_pnp", "PnPResult"):
        assert hasattr(jaxpose, name)


def test_inside_jit_and_gradient_through_the_refinement(rng):
    """Traced inputs: solve_pnp runs inside the caller's jit (bad input -> Equinox runtime error
    with throw=True), and the refined pose is differentiable (implicit function theorem)."""
    P, pix, _, _ = scenes(rng, count=1, noise=0.3)
    P, pix = P[0], pix[0]

    def depth_and_error(x):  # the refined depth, and the reprojection error at the optimum
        res = solve_pnp(P, x, K, throw=False)
        return jnp.stack([res.t[2], res.reprojection_error])

    grad = jax.jit(jax.jacrev(depth_and_error))(jnp.asarray(pix))  # (2, n, 2)
    assert np.all(np.isfinite(np.asarray(grad)))
    assert np.abs(np.asarray(grad[1])).max() > 0  # the error has its derivatives too
    eps = 1e-6
    for i, j in ((5, 1), (11, 0)):
        step = np.zeros_like(pix)
        step[i, j] = eps
        up, down = solve_pnp(P, pix + step, K), solve_pnp(P, pix - step, K)
        fd_depth = (float(up.t[2]) - float(down.t[2])) / (2 * eps)
        fd_error = (float(up.reprojection_error) - float(down.reprojection_error)) / (2 * eps)
        np.testing.assert_allclose(float(grad[0, i, j]), fd_depth, rtol=1e-4, atol=1e-10)
        np.testing.assert_allclose(float(grad[1, i, j]), fd_error, rtol=1e-4, atol=1e-10)
