"""Stereo point-line pose tracking of a tumbling target (Yang et al. 2024, seed 001).

Per stereo pair (rectified, see :mod:`jaxpose.vision.stereo_match`):

1. features of the left image (:mod:`jaxpose.vision.stereo_features`): ORB points, LSD lines
   (eq. 1) with LBD descriptors;
2. frame-to-keyframe matching: ORB searched around the keyframe points' predicted pixels
   (constant-velocity prediction, ratio test) then RANSAC on the fundamental matrix; LBD by KNN +
   ratio test (eqs. 2-3) gated by the predicted segment midpoints;
3. pose: the keyframe's 3-D features are the "body" of :func:`jaxpose.refine.refine_pose`, which
   minimises the point+line reprojection cost (eqs. 8-10) with a robust kernel by LM on se(3)
   (eqs. 11-13), in ``passes`` rounds that drop features left beyond ``reject_px``; the result
   ``T_cur_kf`` composed with the keyframe's pose gives the target pose
   ``T_cur_target = T_cur_kf T_kf_target``: the trajectory is the chain of these increments;
4. keyframe re-anchoring: when the inliers fall below ``keyframe_ratio`` times those of the first
   frame tracked against the keyframe (or below ``keyframe_min``), the current frame becomes the
   keyframe: its features get stereo correspondences by epipolar ZNCC search (eqs. 4-5) and are
   triangulated with the rig (:meth:`jaxpose.camera.StereoCamera.triangulate`) into 3-D points
   and segments in its left camera frame. Only keyframes need 3-D features, so the stereo stages
   run on keyframes only; ``keyframe_every=1`` is the paper's pure frame-to-frame scheme;
5. an explicit :data:`~jaxpose.status.Status.LOST` (pose NaN) when too few features match, the
   solver fails, the fit error is large, or the step from the prediction is implausible; the
   tracker keeps the last good keyframe and a constant-velocity prediction and tries again on the
   next frame.

Points-only mode (``use_lines=False``) is the paper's comparison. The first pose is given (the
ground truth of a rendered sequence, or the identity: the target frame is then the first left
camera frame, as in the paper, which has no model of the target).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..camera import StereoCamera
from ..geometry import Pose, rotation_angle
from ..refine import refine_pose
from ..status import Status
from ..vision.stereo_features import (
    FeatureOptions,
    extract,
    match_lines,
    match_points_guided,
    ransac_filter,
)
from ..vision.stereo_match import (
    StereoMatchOptions,
    disparity_range,
    match_lines_stereo,
    match_points_stereo,
)

__all__ = ["FrameResult", "StereoTracker", "TrackerOptions", "target_roi"]

STAGES = ("features", "stereo", "triangulate", "match", "pose")


@dataclass(frozen=True)
class TrackerOptions:
    """Options of :class:`StereoTracker`.

    Attributes:
        use_lines: fuse line features (``False``: points-only mode).
        depth_range_m: depths searched by the epipolar search (sets the disparity range).
        depth_margin_m: once the target depth is known, search only ``depth +- margin`` (the
            target's half size plus a margin; ``None`` searches the whole range every frame).
        robust: kernel of eq. 10 (``"huber"``, ``"cauchy"``, ``"tukey"`` or ``None``).
        sigma_px, line_sigma_px: pixel noise of points and line distances (information matrices).
        max_points, max_lines: padding sizes of the solver (one compiled function for a sequence).
        min_features: fewer matched features (points + lines) than this is LOST.
        max_rms_px: a post-fit RMS reprojection error above this is LOST.
        max_jump_deg, max_jump_m: a pose further than this from the prediction is LOST.
        keyframe_ratio, keyframe_min: re-anchor when inliers fall below ``ratio`` times the
            inliers of the first frame tracked against the keyframe, or below ``keyframe_min``.
        search_radius_px: guided matching radius around the keyframe features' predicted pixels
            (constant-velocity prediction); lines use twice this radius on their midpoints.
        keyframe_every: re-anchor at least every this many frames (1: frame to frame).
        inlier_px: post-fit residual below which a feature counts as an inlier.
        passes, reject_px: LM passes; features with a residual above ``reject_px`` after a pass
            are left out of the next.
    """

    use_lines: bool = True
    depth_range_m: tuple[float, float] = (0.6, 8.0)
    depth_margin_m: float | None = 0.8
    robust: str | None = "huber"
    sigma_px: float = 1.0
    line_sigma_px: float = 1.0
    max_points: int = 768
    max_lines: int = 96
    min_features: int = 12
    max_rms_px: float = 4.0
    max_jump_deg: float = 10.0
    max_jump_m: float = 0.25
    keyframe_ratio: float = 0.6
    keyframe_min: int = 50
    search_radius_px: float = 20.0
    keyframe_every: int = 1000
    inlier_px: float = 2.0
    passes: int = 3
    reject_px: float = 1.5
    features: FeatureOptions = field(default_factory=FeatureOptions)
    stereo: StereoMatchOptions = field(default_factory=StereoMatchOptions)


@dataclass
class FrameResult:
    """Tracking output of one frame.

    ``R, t``: target pose in the left camera (NaN when lost); ``status``: :class:`Status` (``OK``
    or ``LOST``); ``n_points, n_lines``: features used by the solver; ``inliers``: post-fit
    inliers; ``rms_px``: post-fit RMS; ``keyframe``: this frame became the keyframe;
    ``timings``: seconds by stage (:data:`STAGES`).
    """

    index: int
    R: np.ndarray
    t: np.ndarray
    status: int
    n_points: int = 0
    n_lines: int = 0
    inliers: int = 0
    rms_px: float = float("nan")
    keyframe: bool = False
    timings: dict = field(default_factory=dict)


@dataclass
class _Keyframe:
    index: int
    R: np.ndarray  # target pose in this keyframe's left camera
    t: np.ndarray
    points3d: np.ndarray  # (P, 3) in the keyframe camera
    pixels: np.ndarray  # (P, 2)
    point_desc: np.ndarray
    segments3d: np.ndarray  # (L, 2, 3)
    line_desc: np.ndarray


def target_roi(image: np.ndarray, *, threshold: int = 10, step: int = 4) -> np.ndarray | None:
    """Bounding box ``(u0, v0, u1, v1)`` of the pixels brighter than ``threshold`` (a target on a
    dark sky), from a ``step``-subsampled image; ``None`` when nothing is bright."""
    small = np.asarray(image)[::step, ::step]
    vv, uu = np.nonzero(small > threshold)
    if len(uu) < 4:
        return None
    return np.array([uu.min(), vv.min(), uu.max() + 1, vv.max() + 1], float) * step


def _pad(a: np.ndarray, n: int, fill: float = 0.0) -> np.ndarray:
    out = np.full((n, *a.shape[1:]), fill, dtype=np.float64)
    out[: min(n, len(a))] = a[:n]
    return out


def _lines_np(segments: np.ndarray) -> np.ndarray:
    """Homogeneous lines ``(s, 1) x (e, 1)`` of ``(k, 2, 2)`` segments (eq. 7; the NumPy twin of
    :func:`jaxpose.residuals.line_from_segment`, kept eager so a varying ``k`` compiles nothing)."""
    one = np.ones((len(segments), 1))
    return np.cross(np.c_[segments[:, 0], one], np.c_[segments[:, 1], one])


@eqx.filter_jit
def _solve(pose0, P, uv, mask, S, L, lmask, camera, robust, sigma, line_sigma):
    """One LM solve (eq. 10) and the post-fit errors of every point (pixels) and line (largest
    endpoint distance, pixels). Points-only mode passes an all-False ``lmask``: one compiled
    function serves both modes."""
    res = refine_pose(
        pose0,
        P,
        uv,
        camera,
        mask=mask,
        sigma=sigma,
        robust=robust,
        max_steps=30,
        rtol=1e-9,
        atol=1e-10,
        segments_body=S,
        lines_img=L,
        line_mask=lmask,
        line_sigma=line_sigma,
    )
    pose = res.pose
    e_p = jnp.linalg.norm(camera.project_body(pose, P) - uv, axis=-1)
    pix = camera.project_body(pose, S.reshape(-1, 3)).reshape(-1, 2, 2)
    n = jnp.linalg.norm(L[:, :2], axis=-1, keepdims=True)
    d = (jnp.einsum("ki,kmi->km", L[:, :2], pix) + L[:, 2:3]) / jnp.where(n > 0, n, 1.0)
    return res, e_p, jnp.max(jnp.abs(d), axis=-1)


@eqx.filter_jit
def _triangulate(rig: StereoCamera, left, right):
    return rig.triangulate(left, right)


class StereoTracker:
    """Frame-to-keyframe stereo point-line tracker (module docstring).

    Args:
        rig: rectified rig (``R_rl = I``, ``t_rl = (-b, 0, 0)``, identical ideal cameras), e.g.
            :meth:`~jaxpose.camera.StereoCamera.from_baseline` or ``rectify().rectified_camera()``.
        initial_pose: target pose in the left camera at the first frame (``None``: identity).
        options: :class:`TrackerOptions`.
    """

    def __init__(
        self,
        rig: StereoCamera,
        initial_pose: Pose | None = None,
        *,
        options: TrackerOptions = TrackerOptions(),
    ):
        if not isinstance(rig, StereoCamera):
            raise ValueError("rig must be a StereoCamera")
        if rig.left.width <= 0 or rig.left.height <= 0:
            raise ValueError("the rig's cameras need an image size (width, height)")
        R_rl = np.asarray(rig.R_rl)
        if (
            not np.allclose(R_rl, np.eye(3), atol=1e-9)
            or abs(float(rig.t_rl[1])) > 1e-9
            or abs(float(rig.t_rl[2])) > 1e-9
        ):
            raise ValueError(
                "StereoTracker needs a rectified rig (R_rl = I, t_rl = (-b, 0, 0)); rectify the "
                "images "
                "with rig.rectify() and use its rectified_camera()"
            )
        if rig.left.has_distortion() or rig.right.has_distortion():
            raise ValueError("StereoTracker needs undistorted (rectified) images and cameras")
        self.rig = rig
        self.options = options
        pose = Pose.identity() if initial_pose is None else initial_pose
        self._R0, self._t0 = np.asarray(pose.R, float), np.asarray(pose.t, float)
        disparity_range(rig, *options.depth_range_m)  # validates the range
        self._last_depth = float(self._t0[2]) if initial_pose is not None else None
        self.keyframe: _Keyframe | None = None
        self._T_prev_kf = np.eye(4)  # previous frame's pose relative to the keyframe camera
        self._delta = np.eye(4)  # last inter-frame increment (constant-velocity prediction)
        self._since_kf = 0
        self._kf_reference = None
        self.index = 0

    # ------------------------------------------------------------------ stages
    def _stereo(self, left, right, feats, timings):
        o = self.options
        t0 = time.perf_counter()
        disp = self._disparities()
        pm = match_points_stereo(left, right, feats.points, disp, options=o.stereo)
        if o.use_lines and len(feats.segments):
            lm = match_lines_stereo(left, right, feats.segments, disp, options=o.stereo)
            line_ok = lm.ok
        else:
            lm, line_ok = None, np.zeros(len(feats.segments), bool)
        t1 = time.perf_counter()
        ip = np.nonzero(pm.ok)[0][: o.max_points]
        il = np.nonzero(line_ok)[0][: o.max_lines]
        n_tri = o.max_points + 2 * o.max_lines
        pl = np.concatenate(
            [feats.points[ip], feats.segments[il].reshape(-1, 2) if len(il) else np.zeros((0, 2))]
        )
        pr = np.concatenate(
            [
                pm.pixels_right[ip],
                lm.segments_right[il].reshape(-1, 2) if len(il) else np.zeros((0, 2)),
            ]
        )
        X = np.asarray(_triangulate(self.rig, _pad(pl, n_tri, 1.0), _pad(pr, n_tri, 0.0)))
        P = X[: len(ip)]
        S = X[len(ip) : len(ip) + 2 * len(il)].reshape(-1, 2, 3)
        lo, hi = o.depth_range_m
        okp = np.isfinite(P).all(1) & (P[:, 2] > lo) & (P[:, 2] < hi)
        oks = np.isfinite(S).all((1, 2)) & (S[..., 2] > lo).all(1) & (S[..., 2] < hi).all(1)
        timings["stereo"] = t1 - t0
        timings["triangulate"] = time.perf_counter() - t1
        return (ip[okp], P[okp]), (il[oks], S[oks])

    def _make_keyframe(self, R, t, left, right, feats, timings):
        """Make the current frame the keyframe: stereo correspondence and triangulation of its
        features (only keyframes need 3-D features, so the stereo stages run only here)."""
        (ip, P), (il, S) = self._stereo(left, right, feats, timings)
        self.keyframe = _Keyframe(
            self.index, R, t, P, feats.points[ip], feats.point_desc[ip], S, feats.line_desc[il]
        )
        self._T_prev_kf = np.eye(4)
        self._since_kf = 0
        self._kf_reference = None  # inliers of the first frame tracked against this keyframe

    def _disparities(self) -> tuple[int, int]:
        """Disparities searched: around the last known target depth (``+- depth_margin_m``) when
        there is one, else the whole ``depth_range_m``."""
        o = self.options
        lo, hi = o.depth_range_m
        z = self._last_depth
        if o.depth_margin_m is not None and z is not None and np.isfinite(z) and z > 0:
            lo, hi = max(lo, z - o.depth_margin_m), min(hi, z + o.depth_margin_m)
            if not lo < hi:
                lo, hi = o.depth_range_m
        return disparity_range(self.rig, lo, hi)

    def _project(self, points: np.ndarray, T: np.ndarray) -> np.ndarray:
        """Pixels (ideal pinhole, NumPy) of keyframe-frame points moved by ``T`` (4x4)."""
        X = points @ T[:3, :3].T + T[:3, 3]
        z = np.where(X[:, 2] > 1e-6, X[:, 2], 1e-6)
        c = self.rig.left
        return np.stack(
            [float(c.fx) * X[:, 0] / z + float(c.cx), float(c.fy) * X[:, 1] / z + float(c.cy)], 1
        )

    # ------------------------------------------------------------------ main entry
    def process(self, left: np.ndarray, right: np.ndarray, *, roi=None) -> FrameResult:
        """Track one rectified stereo pair (grayscale uint8); returns its :class:`FrameResult`."""
        o = self.options
        left, right = np.asarray(left), np.asarray(right)
        H, W = self.rig.left.height, self.rig.left.width
        if left.shape[:2] != (H, W) or right.shape[:2] != (H, W):
            raise ValueError(
                f"images must be {W}x{H} (the rig's size); got {left.shape} and {right.shape}"
            )
        timings = dict.fromkeys(STAGES, 0.0)
        t0 = time.perf_counter()
        roi = target_roi(left) if roi is None else roi
        feats = extract(left, options=o.features, roi=roi, lines=o.use_lines)
        timings["features"] = time.perf_counter() - t0
        k = self.index
        self.index += 1
        if self.keyframe is None:
            self._make_keyframe(self._R0, self._t0, left, right, feats, timings)
            kf = self.keyframe
            return FrameResult(
                k,
                self._R0,
                self._t0,
                int(Status.OK),
                len(kf.points3d),
                len(kf.segments3d),
                keyframe=True,
                timings=timings,
            )

        kf = self.keyframe
        t1 = time.perf_counter()
        T_pred = self._delta @ self._T_prev_kf
        pred = self._project(kf.points3d, T_pred)
        i_kf, i_cur = match_points_guided(
            pred,
            kf.point_desc,
            feats.points,
            feats.point_desc,
            radius_px=o.search_radius_px,
            options=o.features,
        )
        i_kf, i_cur = ransac_filter(kf.pixels, feats.points, i_kf, i_cur, options=o.features)
        if o.use_lines and len(kf.line_desc) and len(feats.line_desc):
            mid = self._project(kf.segments3d.mean(1), T_pred)
            near = ((mid[:, None] - feats.segments.mean(1)[None]) ** 2).sum(-1) < (
                2 * o.search_radius_px
            ) ** 2
            l_kf, l_cur = match_lines(
                kf.line_desc, feats.line_desc, options=o.features, allowed=near
            )
        else:
            l_kf, l_cur = np.zeros(0, int), np.zeros(0, int)
        i_kf, i_cur = i_kf[: o.max_points], i_cur[: o.max_points]
        l_kf, l_cur = l_kf[: o.max_lines], l_cur[: o.max_lines]
        timings["match"] = time.perf_counter() - t1

        t2 = time.perf_counter()
        make_keyframe = False
        n_p, n_l = len(i_kf), len(l_kf)
        result = FrameResult(
            k,
            np.full((3, 3), np.nan),
            np.full(3, np.nan),
            int(Status.LOST),
            n_p,
            n_l,
            timings=timings,
        )
        if n_p + n_l >= o.min_features:
            mask = np.arange(o.max_points) < n_p
            lmask = np.arange(o.max_lines) < n_l
            seg_cur = feats.segments[l_cur]
            L = _lines_np(seg_cur) if n_l else np.zeros((0, 3))
            args = (
                jnp.asarray(_pad(kf.points3d[i_kf], o.max_points)),
                jnp.asarray(_pad(feats.points[i_cur], o.max_points)),
            )
            line_args = (
                jnp.asarray(_pad(kf.segments3d[l_kf], o.max_lines)),
                jnp.asarray(_pad(L, o.max_lines)),
            )
            statics = (self.rig.left, o.robust, o.sigma_px, o.line_sigma_px)
            pose0 = Pose(jnp.asarray(T_pred[:3, :3]), jnp.asarray(T_pred[:3, 3]))
            for _ in range(o.passes):
                # each pass restarts from the last pose without the features it left beyond
                # reject_px (ORB-SLAM's outlier passes): the robust kernel alone still lets
                # mismatches along the epipolar lines, which RANSAC cannot see, pull the pose
                res, e_p, e_l = _solve(
                    pose0,
                    args[0],
                    args[1],
                    jnp.asarray(mask),
                    line_args[0],
                    line_args[1],
                    jnp.asarray(lmask),
                    *statics,
                )
                pose0 = res.pose
                mask = mask & (np.asarray(e_p) < o.reject_px)
                lmask = lmask & (np.asarray(e_l) < o.reject_px)
            R_ck, t_ck = np.asarray(res.pose.R), np.asarray(res.pose.t)
            e_p, e_l = np.asarray(e_p)[:n_p], np.asarray(e_l)[:n_l]
            inliers = int(np.sum(e_p < o.inlier_px) + np.sum(e_l < o.inlier_px))
            inl_err = np.concatenate([e_p[e_p < o.inlier_px], e_l[e_l < o.inlier_px]])
            rms = float(np.sqrt(np.mean(inl_err**2))) if len(inl_err) else float("inf")
            jump_deg = float(
                np.degrees(rotation_angle(jnp.asarray(R_ck), jnp.asarray(T_pred[:3, :3])))
            )
            jump_m = float(np.linalg.norm(t_ck - T_pred[:3, 3]))
            good = (
                int(res.status) in (Status.OK, Status.NOT_CONVERGED)
                and np.all(np.isfinite(R_ck))
                and inliers >= o.min_features
                and rms <= o.max_rms_px
                and jump_deg <= o.max_jump_deg
                and jump_m <= o.max_jump_m
            )
            result.inliers, result.rms_px = inliers, rms
            if good:
                T_ck = np.eye(4)
                T_ck[:3, :3], T_ck[:3, 3] = R_ck, t_ck
                self._delta = T_ck @ np.linalg.inv(self._T_prev_kf)
                self._T_prev_kf = T_ck
                self._since_kf += 1
                result.R = R_ck @ kf.R
                result.t = R_ck @ kf.t + t_ck
                result.status = int(Status.OK)
                self._last_depth = float(result.t[2])
                if self._kf_reference is None:
                    self._kf_reference = inliers
                if (
                    inliers < o.keyframe_ratio * self._kf_reference
                    or inliers < o.keyframe_min
                    or self._since_kf >= o.keyframe_every
                ):
                    make_keyframe = True
        if result.status != Status.OK:
            # keep the keyframe; predict one more step of constant motion for the next try
            self._T_prev_kf = T_pred
        timings["pose"] = time.perf_counter() - t2
        if make_keyframe:
            self._make_keyframe(result.R, result.t, left, right, feats, timings)
            result.keyframe = True
        return result
