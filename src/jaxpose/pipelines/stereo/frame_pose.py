"""The pose of one frame from its matched landmarks: point+line reprojection cost (Yang et al.
2024, eqs. 8-10) minimised by :func:`jaxpose.core.refine.refine_pose` in a few passes that drop
the features left beyond ``reject_px``, on the left and (for stereo-matched features) the right
image."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.core.camera import StereoCamera
from jaxpose.core.geometry import Pose
from jaxpose.core.refine import RefineOptions, refine_pose
from jaxpose.core.status import Status
from jaxpose.pipelines.stereo._arrays import (
    find,
    lines_from_segments,
    nearest_rotation,
    pad,
    project,
)
from jaxpose.pipelines.stereo.keyframes import FrameStereo
from jaxpose.pipelines.stereo.options import TrackerOptions

__all__ = ["PoseFit", "fit_pose", "postfit_errors", "postfit_summary"]


@functools.partial(jax.jit, static_argnames=("robust",))
def _solve(pose0, P, uv, mask, S, L, lmask, camera, robust, sigma, line_sigma):
    """One LM solve (eq. 10) and the post-fit errors of every point (pixels) and line (largest
    endpoint distance, pixels). Points-only mode passes an all-False ``lmask``: one compiled
    function serves both modes."""
    res = refine_pose(
        P,
        uv,
        pose0,
        camera,
        mask=mask,
        sigma=sigma,
        segments_body=S,
        lines_img=L,
        line_mask=lmask,
        line_sigma=line_sigma,
        # converged at steps of 1e-7 (relative position, radians): three orders below the
        # pose's noise, and 0.5-1.3 fewer steps in the first pass than at 1e-9
        options=RefineOptions(robust=robust, max_steps=30, rtol=1e-7, atol=1e-8),
        throw=False,
    )
    pose = res.pose
    e_p = jnp.linalg.norm(camera.project(pose.apply(P)) - uv, axis=-1)
    pix = camera.project(pose.apply(S.reshape(-1, 3))).reshape(-1, 2, 2)
    n = jnp.linalg.norm(L[:, :2], axis=-1, keepdims=True)
    d = (jnp.einsum("ki,kmi->km", L[:, :2], pix) + L[:, 2:3]) / jnp.where(n > 0, n, 1.0)
    return res, e_p, jnp.max(jnp.abs(d), axis=-1)


@dataclass
class PoseFit:
    """Result of :func:`fit_pose`.

    Attributes:
        pose: the fitted pose; ``solver_ok``: the solver returned ``OK`` or ``NOT_CONVERGED``.
        e_points, e_lines: post-fit errors (pixels) of the left-image matches, ``(n_p,)`` and
            ``(n_l,)``; ``in_points``, ``in_lines``: those below ``inlier_px``.
        kept_points: the left-image point matches left in the last pass (below
            ``reject_px`` after the pass before); ``kept_errors``: the errors of every feature
            (left and right) left in the last pass, points and lines.
        inliers, rms_px: inlier count and RMS of the inliers' errors (``inf`` without inliers).
        window_lines: the line matches whose observations the windowed adjustment may take in
            (``None``: the inliers, ``in_lines``); set by a feature budget that covers the
            window (``TrackerOptions.budget_window``).
    """

    pose: Pose
    solver_ok: bool
    e_points: np.ndarray
    e_lines: np.ndarray
    in_points: np.ndarray
    in_lines: np.ndarray
    kept_points: np.ndarray
    kept_errors: tuple[np.ndarray, np.ndarray]
    inliers: int
    rms_px: float
    window_lines: np.ndarray | None = None


def fit_pose(
    landmarks,
    feats,
    stereo: FrameStereo | None,
    matches,
    pose_pred: Pose,
    rig: StereoCamera,
    options: TrackerOptions,
    line_sigma: float,
    *,
    point_sigma=None,
    point_sigma_right=None,
) -> PoseFit:
    """Fit the pose of the frame from ``matches`` (``(i_m, i_cur, l_m, l_cur)``: landmark and
    feature indices of the matched points and lines), starting at ``pose_pred``.

    The right-image residuals of a matched landmark whose feature has a stereo match use
    ``x_right = R X + t + t_rl = R (X + R^T t_rl) + t``: the same pose with the body point shifted
    by ``R^T t_rl``, re-evaluated at the latest ``R`` on every pass (exact at the fixed point; the
    shift changes by ``|t_rl|`` times the rotation update). The same holds for the right segment
    of a matched segment with a stereo match. Each pass restarts from the last pose without the
    features it left beyond ``reject_px`` (ORB-SLAM's outlier passes): the robust kernel alone
    still lets mismatches on repetitive texture pull the pose. ``point_sigma``: ``(n_p,)`` pixel
    noise of each matched point (its left and right residuals; default ``sigma_px``);
    ``point_sigma_right``: ``(n_p,)`` the right residuals' own, where they differ."""
    o = options
    i_m, i_cur, l_m, l_cur = matches
    n_p, n_l = len(i_m), len(l_m)
    q_r, uv_r = np.zeros(0, int), np.zeros((0, 2))
    if o.stereo_residuals and stereo is not None and len(stereo.point_idx):
        q, j = find(stereo.point_idx, i_cur)
        keep = o.max_points - n_p
        q_r, uv_r = q[:keep], stereo.pixels_right[j[:keep]]
    n_r = len(q_r)
    t_rl = np.asarray(rig.t_rl, float)
    ql_r, seg_r = np.zeros(0, int), np.zeros((0, 2, 2))
    if (
        o.stereo_residuals
        and o.line_stereo_residuals
        and stereo is not None
        and n_l
        and len(stereo.line_idx)
    ):
        q, j = stereo.right_lines(l_cur)
        keep = o.max_lines - n_l
        ql_r, seg_r = q[:keep], project(rig.left, None, stereo.segments[j[:keep]] + t_rl)
    n_lr = len(ql_r)
    mask = np.arange(o.max_points) < n_p + n_r
    young = np.zeros(n_p, bool)
    if o.mature_obs > 1:
        # landmarks seen in fewer than mature_obs stereo frames are matched but left out of the
        # solve: their residuals at the fitted pose still decide whether they are refined
        young = landmarks.points.n_obs[i_m] < o.mature_obs
        mask[:n_p] &= ~young
        mask[n_p : n_p + n_r] &= ~young[q_r]
    lmask = np.arange(o.max_lines) < n_l + n_lr
    L = (
        lines_from_segments(np.concatenate([feats.segments[l_cur], seg_r]))
        if n_l
        else np.zeros((0, 3))
    )
    X_m = landmarks.points.X[i_m]
    sigma = np.full(o.max_points, float(o.sigma_px))
    if point_sigma is not None:
        ps = np.asarray(point_sigma, float)
        sigma[:n_p], sigma[n_p : n_p + n_r] = ps, ps[q_r]
    if point_sigma_right is not None:
        sigma[n_p : n_p + n_r] = np.asarray(point_sigma_right, float)[q_r]
    X_l = landmarks.lines.X[l_m]
    # NumPy arrays straight into the compiled solve (a jnp.asarray first is an eager dispatch,
    # about 0.06 ms each, 22 a frame)
    uv_all = pad(np.concatenate([feats.points[i_cur], uv_r]), o.max_points)
    L_pad = pad(L, o.max_lines)
    statics = (
        rig.left,
        o.robust,
        sigma,  # arrays: a new value compiles nothing
        np.full(o.max_lines, float(line_sigma)),
    )
    pose0 = pose_pred
    for _ in range(o.passes):
        shift = np.asarray(pose0.R).T @ t_rl
        P_all = np.concatenate([X_m, X_m[q_r] + shift])
        S_all = np.concatenate([X_l, X_l[ql_r] + shift])
        res, e_p, e_l = _solve(
            pose0,
            pad(P_all, o.max_points),
            uv_all,
            mask,
            pad(S_all, o.max_lines),
            L_pad,
            lmask,
            *statics,
        )
        pose0 = res.pose
        mask = mask & (np.asarray(e_p) < o.reject_px)
        lmask = lmask & (np.asarray(e_l) < o.reject_px)
    kept_errors = (np.asarray(e_p)[mask], np.asarray(e_l)[lmask])
    e_p, e_l = np.asarray(e_p)[:n_p], np.asarray(e_l)[:n_l]
    # the LM retraction exp(xi) R keeps whatever departure from orthonormality R has, and the
    # constant-velocity prediction R_k R_(k-1)^T R_k compounds it by 1 + sqrt(2) a frame; a
    # quaternion round trip returns the nearest rotation
    return PoseFit(
        pose=nearest_rotation(res.pose),
        solver_ok=int(res.status) in (Status.OK, Status.NOT_CONVERGED),
        kept_points=mask[:n_p] | (young & (e_p < o.reject_px)),
        kept_errors=kept_errors,
        **postfit_summary(e_p, e_l, o.inlier_px),
    )


def postfit_errors(landmarks, feats, matches, pose: Pose, camera) -> tuple[np.ndarray, np.ndarray]:
    """Post-fit errors (pixels) of the left-image matches at ``pose``: ``(n_p,)`` distances of
    the points' projections to their features, ``(n_l,)`` largest distance of a landmark
    segment's projected endpoints to its feature's image line (Yang et al. 2024, eq. 9). The
    NumPy counterpart of the errors :func:`fit_pose`'s compiled solve returns, for matches the
    solve did not see (the feature budget's)."""
    i_m, i_cur, l_m, l_cur = matches
    e_p = np.linalg.norm(
        project(camera, pose, landmarks.points.X[i_m]) - feats.points[i_cur], axis=1
    )
    e_l = np.zeros(len(l_m))
    if len(l_m):
        pix = project(camera, pose, landmarks.lines.X[l_m])  # (n_l, 2, 2)
        L = lines_from_segments(feats.segments[l_cur])
        nrm = np.linalg.norm(L[:, :2], axis=1, keepdims=True)
        d = (np.einsum("ki,kmi->km", L[:, :2], pix) + L[:, 2:3]) / np.where(nrm > 0, nrm, 1.0)
        e_l = np.max(np.abs(d), axis=1)
    return e_p, e_l


def postfit_summary(e_points, e_lines, inlier_px: float) -> dict:
    """The :class:`PoseFit` fields that follow from the post-fit errors: ``e_points``,
    ``e_lines``, the inlier flags (below ``inlier_px``), the inlier count and the RMS of the
    inliers' errors (``inf`` without inliers)."""
    in_p, in_l = e_points < inlier_px, e_lines < inlier_px
    inl = np.concatenate([e_points[in_p], e_lines[in_l]])
    return dict(
        e_points=e_points,
        e_lines=e_lines,
        in_points=in_p,
        in_lines=in_l,
        inliers=int(in_p.sum() + in_l.sum()),
        rms_px=float(np.sqrt(np.mean(inl**2))) if len(inl) else float("inf"),
    )
