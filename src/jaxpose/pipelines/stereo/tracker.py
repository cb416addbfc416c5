"""Stereo point-line pose tracking of a tumbling target (Yang et al. 2024).

Per stereo pair (rectified, see :mod:`jaxpose.vision.stereo_match`):

1. features of the left image (:mod:`jaxpose.vision.stereo_features`): ORB points (sub-pixel
   corners), LSD lines (eq. 1) with LBD descriptors;
2. search by projection against a body-frame landmark map
   (:class:`~jaxpose.pipelines.stereo.landmarks.LandmarkMap`, :mod:`~jaxpose.pipelines.stereo.
   guided`): the landmarks visible from the predicted pose (constant-velocity prediction) are
   projected, ORB matched by ratio test among the keypoints within ``search_radius_px``, LBD
   (eqs. 2-3) among the segments parallel to and overlapping a projected landmark segment;
3. pose (:mod:`~jaxpose.pipelines.stereo.frame_pose`): the matched landmarks are the "body" of
   :func:`jaxpose.core.refine.refine_pose`, which minimises the point+line reprojection cost (eqs.
   8-10) with a robust kernel by LM (eqs. 11-13), in ``passes`` rounds that drop features left
   beyond ``reject_px``. The result is the target pose itself (body to left camera): nothing is
   chained from frame to frame;
4. map update on keyframes (:mod:`~jaxpose.pipelines.stereo.keyframes`, every ``keyframe_every``
   tracked frames): stereo correspondences by epipolar ZNCC search (eqs. 4-5), triangulated with
   the rig; matched features refine their landmarks, the others become new landmarks. Lines are
   weighted by their measured residual scale relative to the points'. When the target turns back
   to a face seen before, the landmarks of that face are found again, so the error stays bounded
   instead of accumulating as a chain of frame-to-keyframe increments does (the paper's scheme);
5. an explicit :data:`~jaxpose.core.status.Status.LOST` (pose NaN) when too few features match, the
   solver fails, the fit error is large, or the step from the prediction is implausible; the
   tracker keeps the map and a constant-velocity prediction and tries again on the next frame
   with a doubled search radius.

Points-only mode (``use_lines=False``) is the paper's comparison. The first pose is given (the
ground truth of a rendered sequence, as the paper initialises, or the identity: the target frame is
then the first left camera frame); it places the first landmarks in the body frame. A first frame
with fewer than ``min_features`` triangulated features (a black or unreadable frame) is
``TOO_FEW_POINTS`` with a NaN pose, and the map starts at the next frame that has them.
"""

from __future__ import annotations

import time
from dataclasses import replace

import jax.numpy as jnp
import numpy as np

from jaxpose.core.camera import StereoCamera
from jaxpose.core.geometry import Pose
from jaxpose.core.status import Status
from jaxpose.pipelines.stereo._arrays import angle_deg, compose, fraction, project, relative, rt
from jaxpose.pipelines.stereo.budget import fit_pose_budgeted, stage_timer
from jaxpose.pipelines.stereo.guided import match_by_projection
from jaxpose.pipelines.stereo.keyframes import (
    observe_point_rays,
    stereo_correspondences,
    update_map,
)
from jaxpose.pipelines.stereo.landmarks import LandmarkMap
from jaxpose.pipelines.stereo.options import (
    STAGES,
    FrameResult,
    TrackerOptions,
    lost_pose,
)
from jaxpose.vision.stereo_features import FeatureOptions, extract
from jaxpose.vision.stereo_match import disparity_range

__all__ = ["StereoTracker", "as_gray_uint8", "target_area", "target_roi"]


def target_roi(image: np.ndarray, *, threshold: int = 10, step: int = 4) -> np.ndarray | None:
    """Bounding box ``(u0, v0, u1, v1)`` of the pixels brighter than ``threshold`` (a target on a
    dark sky), from a ``step``-subsampled image; ``None`` when nothing is bright."""
    small = np.asarray(image)[::step, ::step]
    vv, uu = np.nonzero(small > threshold)
    if len(uu) < 4:
        return None
    return np.array([uu.min(), vv.min(), uu.max() + 1, vv.max() + 1], float) * step


def target_area(image: np.ndarray, *, threshold: int = 10, step: int = 4) -> float:
    """Apparent area of the target, pixels: the pixels brighter than ``threshold`` (a target on a
    dark sky), counted on a ``step``-subsampled image."""
    small = np.asarray(image)[::step, ::step]
    return float(np.count_nonzero(small > threshold)) * step * step


def as_gray_uint8(image, name: str = "image") -> np.ndarray:
    """A 2-D ``uint8`` view of a grayscale image: ``uint8`` as is; ``uint16`` divided by 257;
    floating point taken on the 0-255 scale, non-finite pixels set to 0 (black), clipped."""
    a = np.asarray(image)
    if a.ndim != 2:
        raise ValueError(f"{name} must be a 2-D grayscale image; got shape {a.shape}")
    if a.dtype == np.uint8:
        return a
    if a.dtype == np.uint16:
        return (a.astype(np.float64) / 257.0 + 0.5).astype(np.uint8)
    if np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer):
        f = np.nan_to_num(a.astype(np.float64), nan=0.0, posinf=255.0, neginf=0.0)
        return np.clip(f + 0.5, 0, 255).astype(np.uint8)
    raise ValueError(f"{name} must be a numeric image; got dtype {a.dtype}")


def _finite(pose: Pose) -> bool:
    return bool(np.all(np.isfinite(np.asarray(pose.R))) and np.all(np.isfinite(np.asarray(pose.t))))


def _fractional_step(motion: Pose, steps: int) -> Pose:
    """The per-frame increment of a ``motion`` spread over ``steps`` frames (rotation vector and
    translation divided by ``steps``)."""
    if steps <= 1:
        return motion
    return fraction(motion, float(steps))


class StereoTracker:
    """Map-based stereo point-line tracker (module docstring).

    Args:
        rig: rectified rig (``R_rl = I``, ``t_rl = (-b, 0, 0)``, identical ideal cameras), e.g.
            :meth:`~jaxpose.core.camera.StereoCamera.from_baseline` or
            ``jaxpose.vision.stereo_rectify.rectify(rig).rectified_camera()``.
        initial_pose: target pose in the left camera at the first frame (``None``: identity, the
            target frame is the first left camera frame).
        options: :class:`~jaxpose.pipelines.stereo.TrackerOptions`.
    """

    def __init__(
        self,
        rig: StereoCamera,
        initial_pose: Pose | None = None,
        *,
        options: TrackerOptions | None = None,
    ):
        options = TrackerOptions() if options is None else options
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
                "images with jaxpose.vision.stereo_rectify.rectify(rig) and use its "
                "rectified_camera()"
            )
        if rig.left.has_distortion() or rig.right.has_distortion():
            raise ValueError("StereoTracker needs undistorted (rectified) images and cameras")
        if not isinstance(options, TrackerOptions):
            raise ValueError("options must be a TrackerOptions")
        self.rig = rig
        self.options = options
        pose = Pose.identity() if initial_pose is None else initial_pose
        pose = Pose(jnp.asarray(pose.R), jnp.asarray(pose.t))
        if not _finite(pose):
            raise ValueError("initial_pose must be finite")
        self.initial_pose = pose
        disparity_range(rig, *options.depth_range_m)  # validates the range
        self._last_depth = float(pose.t[2]) if initial_pose is not None else None
        self.map = LandmarkMap(
            max_view_deg=options.max_view_deg,
            max_obs=options.max_obs,
            cull_after=options.cull_after,
            cull_ratio=options.cull_ratio,
            keep_obs=options.keep_obs,
        )
        self._pose_prev = pose  # last good pose (body to left camera)
        self._delta = Pose.identity()  # last inter-frame motion (constant-velocity prediction)
        self._misses = 0  # frames lost since the last good one
        self._since_kf = 0
        self._started = False  # the map has its first landmarks
        self._rejected_p: set = set()
        self._rejected_l: set = set()
        self.index = 0
        self._line_scale = 1.0  # running ratio of line to point residual scales (line_sigma)
        self._radius = float(options.search_radius_px)  # search-by-projection radius

    # ------------------------------------------------------------------ scene-dependent settings
    def feature_options(self, target_area_px: float | None = None) -> FeatureOptions:
        """The feature options of a frame whose target covers ``target_area_px`` pixels: the ORB
        budget at one keypoint per ``keypoint_spacing_px^2`` pixels of target (a constant
        keypoint density on the target, whatever its range and attitude)."""
        o = self.options
        if o.keypoint_spacing_px is None or target_area_px is None:
            return o.features
        n = int(round(target_area_px / o.keypoint_spacing_px**2, -2))
        return replace(o.features, n_points=max(100, min(o.features.n_points, n)))

    def _update_radius(self, landmarks_xyz: np.ndarray, pose_pred: Pose, pose: Pose) -> None:
        """The next frame's search radius from this frame's prediction error (``adaptive_radius``):
        the pixels of the matched landmarks at the predicted and at the fitted pose."""
        o = self.options
        if not o.adaptive_radius or len(landmarks_xyz) < 10:
            return
        cam = self.rig.left
        moved = np.linalg.norm(
            project(cam, pose_pred, landmarks_xyz) - project(cam, pose, landmarks_xyz), axis=1
        )
        r = 3.0 * float(np.percentile(moved, 90)) + 3.0 * o.sigma_px
        self._radius = float(np.clip(r, 0.5 * o.search_radius_px, 4.0 * o.search_radius_px))

    def _disparities(self, pose_pred: Pose | None = None) -> tuple[int, int]:
        """Disparities searched. With a map and a predicted pose: the depths of the landmarks
        visible from the prediction (5th to 95th percentile), widened by half their spread
        plus ``depth_margin_m / 8`` each side (structure turning into view lies within the
        target, whose visible depth extent the map measures); else around the last known target
        depth (``+- depth_margin_m``); else the whole ``depth_range_m``."""
        o = self.options
        lo, hi = o.depth_range_m
        z = self._last_depth
        if o.depth_margin_m is not None and pose_pred is not None and len(self.map.points) >= 20:
            cand = self.map.candidates("points", pose_pred)
            if len(cand) >= 20:
                R, t = rt(pose_pred)
                depth = self.map.points.X[cand] @ R[2] + t[2]
                z0, z1 = np.percentile(depth, [5, 95])
                pad = 0.5 * (z1 - z0) + o.depth_margin_m / 8
                lo, hi = max(lo, z0 - pad), min(hi, z1 + pad)
                if lo < hi:
                    return disparity_range(self.rig, lo, hi)
                lo, hi = o.depth_range_m
        if o.depth_margin_m is not None and z is not None and np.isfinite(z) and z > 0:
            lo, hi = max(lo, z - o.depth_margin_m), min(hi, z + o.depth_margin_m)
            if not lo < hi:
                lo, hi = o.depth_range_m
        return disparity_range(self.rig, lo, hi)

    def update_line_scale(self, e_p: np.ndarray, e_l: np.ndarray) -> None:
        """Fold a frame's measured residual scales into the running line weight: the line noise
        relative to the point noise, ``sigma_l / sigma_p``, each from the median of the residuals
        kept by the last pass (a point's is the 2-D distance, median ``1.177 sigma`` for Gaussian
        pixel noise; a line's the larger of its two endpoint distances, median ``1.052 sigma``).
        An exponential average over frames (``line_scale_memory``) steadies the few lines of a
        frame."""
        if len(e_p) < 10 or len(e_l) < 3:
            return
        s_p = float(np.median(e_p)) / 1.1774
        s_l = float(np.median(e_l)) / 1.0518
        if not (s_p > 0 and s_l > 0):
            return
        ratio = float(np.clip(s_l / s_p, 0.2, 2.0))
        a = self.options.line_scale_memory
        self._line_scale = a * self._line_scale + (1 - a) * ratio

    @property
    def line_scale(self) -> float:
        """The running ratio of the line to the point residual scale (weight of the lines)."""
        return self._line_scale

    # ------------------------------------------------------------------ main entry
    def _stereo(self, left, right, feats, timings, pose_pred=None):
        return stereo_correspondences(
            left, right, feats, self.rig, self._disparities(pose_pred), self.options, timings
        )

    def _first_frame(self, left, right, feats, timings) -> FrameResult:
        """Start the map at the initial pose (frame 0, or the first frame with enough features)."""
        o = self.options
        pose = self.initial_pose
        stereo = self._stereo(left, right, feats, timings)
        k = self.index - 1
        if len(stereo.point_idx) + len(stereo.line_idx) < o.min_features:
            return FrameResult(k, lost_pose(), int(Status.TOO_FEW_POINTS), timings=timings)
        update_map(self.map, self.rig, o, pose, feats, stereo, {}, {}, set(), set(), k)
        if o.mature_obs > 1:  # the first frame's landmarks sit at the given pose: mature
            self.map.points.n_obs[:] = np.maximum(self.map.points.n_obs, o.mature_obs)
        self._started = True
        self._since_kf = 0
        return FrameResult(
            k,
            pose,
            int(Status.OK),
            len(self.map.points),
            len(self.map.lines),
            keyframe=True,
            timings=timings,
        )

    def process(self, left: np.ndarray, right: np.ndarray, *, roi=None) -> FrameResult:
        """Track one rectified stereo pair (grayscale; ``uint8``, or converted by
        :func:`as_gray_uint8`); returns its :class:`~jaxpose.pipelines.stereo.FrameResult`."""
        o = self.options
        left, right = np.asarray(left), np.asarray(right)
        H, W = self.rig.left.height, self.rig.left.width
        if left.shape[:2] != (H, W) or right.shape[:2] != (H, W):
            raise ValueError(
                f"images must be {W}x{H} (the rig's size); got {left.shape} and {right.shape}"
            )
        left, right = as_gray_uint8(left, "left"), as_gray_uint8(right, "right")
        timings = dict.fromkeys(STAGES, 0.0)
        t0 = time.perf_counter()
        roi = target_roi(left) if roi is None else roi
        area = target_area(left)
        feats = extract(left, options=self.feature_options(area), roi=roi, lines=o.use_lines)
        timings["features"] = time.perf_counter() - t0
        k = self.index
        self.index += 1
        if not self._started:
            return self._first_frame(left, right, feats, timings)

        pose_pred = compose(self._delta, self._pose_prev)
        stereo = None
        if o.stereo_residuals or o.keyframe_every <= 1:
            stereo = self._stereo(left, right, feats, timings, pose_pred)
        t1 = time.perf_counter()
        radius = self._radius * (2.0 if self._misses else 1.0)
        (i_m, i_cur, cand), (l_m, l_cur, lcand) = match_by_projection(
            self.map,
            feats,
            pose_pred,
            self.rig.left,
            radius,
            use_lines=o.use_lines,
            line_angle_deg=o.line_angle_deg,
            options=o.features,
        )
        if len(i_m) > o.max_points:  # keep the best-observed landmarks
            keep = np.argsort(-self.map.points.n_obs[i_m], kind="stable")[: o.max_points]
            i_m, i_cur = i_m[keep], i_cur[keep]
        if o.stereo_residuals and len(i_m) > o.max_points // 2:
            keep = np.argsort(-self.map.points.n_obs[i_m], kind="stable")[: o.max_points // 2]
            i_m, i_cur = i_m[keep], i_cur[keep]
        l_m, l_cur = l_m[: o.max_lines], l_cur[: o.max_lines]
        timings["match"] = time.perf_counter() - t1

        t2 = time.perf_counter()
        n_p, n_l = len(i_m), len(l_m)
        result = FrameResult(k, lost_pose(), int(Status.LOST), n_p, n_l, timings=timings)
        update = None
        if n_p + n_l >= o.min_features:
            line_sigma = o.line_sigma_px * (self._line_scale if o.measured_line_sigma else 1.0)
            fit = fit_pose_budgeted(  # all matches, or feature_budget of them (budget.py)
                self.map,
                feats,
                stereo,
                (i_m, i_cur, l_m, l_cur),
                pose_pred,
                self.rig,
                o,
                line_sigma,
                frame=k,
                stage=stage_timer(timings),
            )
            pose = fit.pose
            finite = _finite(pose)
            jump_deg = float(angle_deg(pose.R, pose_pred.R)) if finite else np.inf
            jump_m = float(np.linalg.norm(np.asarray(pose.t) - np.asarray(pose_pred.t)))
            good = (
                fit.solver_ok
                and finite
                and fit.inliers >= o.min_features
                and fit.rms_px <= o.max_rms_px
                and jump_deg <= o.max_jump_deg * (1 + self._misses)
                and jump_m <= o.max_jump_m * (1 + self._misses)
            )
            result.inliers, result.rms_px = fit.inliers, fit.rms_px
            if good:
                self._update_radius(self.map.points.X[i_m[fit.in_points]], pose_pred, pose)
                steps = self._misses + 1
                self._delta = _fractional_step(relative(pose, self._pose_prev), steps)
                self._pose_prev = pose
                self._misses = 0
                if o.measured_line_sigma and n_l:
                    self.update_line_scale(*fit.kept_errors)
                result.pose = pose
                result.status = int(Status.OK)
                self._last_depth = float(pose.t[2])
                in_p, in_l = fit.in_points, fit.in_lines
                self.map.record("points", cand, i_m[in_p], k)
                if o.frame_rays:
                    kept = fit.kept_points  # left in the last pass: residual below reject_px
                    observe_point_rays(
                        self.map,
                        self.rig,
                        i_m[kept],
                        feats.points[i_cur[kept]],
                        pose,
                        right=False,
                    )
                self.map.record("lines", lcand, l_m[in_l], k)
                self._since_kf += 1
                update = (
                    dict(zip(i_cur[in_p].tolist(), i_m[in_p].tolist(), strict=True)),
                    dict(zip(l_cur[in_l].tolist(), l_m[in_l].tolist(), strict=True)),
                )
                self._rejected_p = set(i_cur[~in_p].tolist())
                self._rejected_l = set(l_cur[~in_l].tolist())
        if result.status != Status.OK:
            self._misses += 1
            self._pose_prev = pose_pred  # predict one more step of constant motion next time
        timings["pose"] = time.perf_counter() - t2 - timings["budget"]
        if update is not None and (
            self._since_kf >= o.keyframe_every or result.inliers < o.keyframe_min
        ):
            if stereo is None:
                stereo = self._stereo(left, right, feats, timings, pose_pred)
            update_map(
                self.map,
                self.rig,
                o,
                result.pose,
                feats,
                stereo,
                *update,
                self._rejected_p,
                self._rejected_l,
                k,
            )
            self._since_kf = 0
            result.keyframe = True
        return result
