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
5. windowed adjustment (:mod:`~jaxpose.pipelines.stereo.window`, ``window_frames``): the last
   frames' poses and their point landmarks adjusted jointly, each landmark's older rays kept as
   a prior, every frame beyond 3 m and every 2nd-4th nearer (``window_every``,
   ``window_depth_m``), 12 frames instead of 8 while the target is far (``window_frames_far``,
   ``window_far_m``); an adjusted frame's result is its adjusted pose;
6. an explicit :data:`~jaxpose.core.status.Status.LOST` (pose NaN) when too few features match, the
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

from dataclasses import replace

import jax.numpy as jnp
import numpy as np

from jaxpose.core._checks import check_pose, check_rotation
from jaxpose.core._compile import in_float64
from jaxpose.core.camera import StereoCamera
from jaxpose.core.geometry import Pose
from jaxpose.core.status import Status
from jaxpose.pipelines.stereo._arrays import (
    angle_deg,
    compose,
    fraction,
    lines_from_segments,
    project,
    relative,
    rt,
    warm_up_projection,
)
from jaxpose.pipelines.stereo._clock import StageClock
from jaxpose.pipelines.stereo.anchor import PatchAnchors, stereo_normals
from jaxpose.pipelines.stereo.budget import fit_pose_budgeted
from jaxpose.pipelines.stereo.disparity import depth_window, feature_windows, measured_margin
from jaxpose.pipelines.stereo.follow import follow
from jaxpose.pipelines.stereo.frames import (
    as_gray_uint8,
    checked_pair,
    detect_features,
    far_window,
    feature_options,
    fine_corners,
    target_area,
    target_roi,
    window_cadence,
)
from jaxpose.pipelines.stereo.guided import match_by_projection
from jaxpose.pipelines.stereo.keyframes import (
    observe_left_planes,
    observe_point_rays,
    stereo_correspondences,
    update_map,
)
from jaxpose.pipelines.stereo.landmarks import LandmarkMap, map_origin, surface_normals
from jaxpose.pipelines.stereo.options import (
    STAGES,
    FrameResult,
    TrackerOptions,
    lost_pose,
)
from jaxpose.pipelines.stereo.window import WindowAdjuster
from jaxpose.vision.stereo_features import FeatureOptions, FrameFeatures
from jaxpose.vision.stereo_match import disparity_range

__all__ = ["StereoTracker", "as_gray_uint8", "target_area", "target_roi"]


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
            target frame is the first left camera frame). Poses are reported in its frame; an
            origin outside the target is moved to the first landmarks inside (``map_origin``).
        options: :class:`~jaxpose.pipelines.stereo.TrackerOptions`.
    """

    @in_float64
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
        check_pose(pose, "initial_pose")
        pose = Pose(jnp.asarray(pose.R), jnp.asarray(pose.t))
        if not _finite(pose):
            raise ValueError("initial_pose must be finite")
        check_rotation(pose.R, "initial_pose.R")
        if float(pose.t[2]) < 0:
            raise ValueError(
                f"initial_pose puts the target behind the left camera (t_z = "
                f"{float(pose.t[2]):.3f} m); the camera looks along +z"
            )
        self.initial_pose = pose
        disparity_range(rig, *options.depth_range_m)  # validates the range
        self._last_depth = float(pose.t[2]) if initial_pose is not None else None
        self.map = LandmarkMap(
            max_view_deg=options.max_view_deg,
            max_obs=options.max_obs,
            cull_after=options.cull_after,
            cull_ratio=options.cull_ratio,
            keep_obs=options.keep_obs,
            descriptor_memory=options.descriptor_memory,
        )
        self._pose_prev = pose  # last good pose (body to left camera)
        self._delta = Pose.identity()  # last inter-frame motion (constant-velocity prediction)
        self._misses = 0  # frames lost since the last good one
        self._fine = None  # the last frame's keypoints were full-resolution corners (detect)
        self._run = 0  # frames tracked in a row since the first or the last lost one
        self._since_kf = 0
        self._started = False  # the map has its first landmarks
        self._rejected_p: set = set()
        self._rejected_l: set = set()
        self.index = 0
        self._line_scale = 1.0  # running ratio of line to point residual scales (line_sigma)
        self._radius = float(options.search_radius_px)  # search-by-projection radius
        self._disparity_margin = float(options.disparity_margin_px)  # around predicted disparity
        self._window = (
            WindowAdjuster(
                rig,
                options.window_frames,
                options.window_iterations,
                max_points=options.window_points,
                max_lines=options.max_lines,
                motion_sigma=options.window_motion_sigma,
                free_lines=options.window_free_lines and options.use_lines,
                held_lines=options.window_held_lines,
                gauge=options.window_gauge,
                anchors=options.window_anchors,
                anchor_points=options.window_anchor_points,
                history=options.keep_history,
            )
            if options.window_frames
            else None
        )
        self._anchors = (
            PatchAnchors(
                half=options.anchor_half_px,
                min_cornerness=options.anchor_cornerness,
                affine_prior=options.anchor_affine_prior,
            )
            if options.anchor_points
            else None
        )
        self._rays = None  # the ray record of the frame being tracked (windowed adjustment)
        self._followed = np.zeros(0, np.int64)  # the last solve's point landmarks (stable ids)
        self._since_adjust = 0  # tracked frames since the last adjustment (window_every)
        self._since_global = 0  # tracked frames since the last global adjustment
        self._far = False  # the window holds _far_frames frames (far_window)
        self.map_origin = np.zeros(3)  # the map's origin in the given target frame (map_origin)
        self._far_frames = max(options.window_frames, options.window_frames_far)
        warm_up_projection(rig.left)
        if self._window is not None:
            self._window.warm_up((self._far_frames,) if options.window_far_m else ())

    # ------------------------------------------------------------------ scene-dependent settings
    def feature_options(self, target_area_px: float | None = None) -> FeatureOptions:
        """The feature options of a frame whose target covers ``target_area_px`` pixels
        (:func:`~jaxpose.pipelines.stereo.frames.feature_options`)."""
        return feature_options(self.options, target_area_px)

    def detect(self, left: np.ndarray, *, roi=None, threads: bool | None = None) -> FrameFeatures:
        """The features :meth:`process` extracts from a left image (``uint8`` grey of the rig's
        size; :func:`~jaxpose.pipelines.stereo.frames.detect_features`). Call it once a frame,
        in the frames' order (as :meth:`process` and :func:`~jaxpose.pipelines.stereo.
        track_stream` do): they depend on the image, the options and the keypoints' kind of the
        frame before (:func:`~jaxpose.pipelines.stereo.frames.fine_corners`' hysteresis), not on
        the poses or the map, so :func:`~jaxpose.pipelines.stereo.track_stream` extracts the
        next pair's in another thread. ``threads``: the lines in a second thread beside the
        points' (default ``options.threads``; the same features either way)."""
        o = self.options
        if threads is not None and bool(threads) != o.threads:
            o = replace(o, threads=bool(threads))
        area = target_area(left)
        self._fine = fine_corners(o, area, self._fine)
        return detect_features(left, o, roi=roi, area=area, fine=self._fine)

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
        """Disparities searched when no feature has its own window
        (:func:`~jaxpose.pipelines.stereo.disparity.depth_window`)."""
        return depth_window(self.map, self.rig, self.options, self._last_depth, pose_pred)

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

    def feature_disparities(self, feats, pose_pred: Pose | None, matches=None):
        """Disparities searched for each feature, ``((N, 2), (M, 2), predicted)``
        (:func:`~jaxpose.pipelines.stereo.disparity.feature_windows`): around each matched
        feature's predicted disparity once ``predicted_disparity_after`` frames are tracked in a
        row, else the window of the map's depths. ``matches``: ``(i_m, i_cur, l_m, l_cur)``."""
        o = self.options
        base = np.array(self._disparities(pose_pred), np.int64)
        if matches is None or not o.predicted_disparity or self._misses:
            matches = None
        warm = self._run >= o.predicted_disparity_after
        return feature_windows(
            self.map, self.rig, o, feats, pose_pred, matches, base, self._disparity_margin, warm
        )

    def _update_disparity_margin(self, feats, stereo, predicted) -> None:
        """The next frame's margin around the predicted disparities
        (:func:`~jaxpose.pipelines.stereo.disparity.measured_margin`)."""
        margin = measured_margin(feats, stereo, predicted)
        if margin is not None:
            self._disparity_margin = margin

    # ------------------------------------------------------------------ main entry
    def _stereo(self, left, right, feats, clock, pose_pred=None, matches=None):
        dp, dl, predicted = self.feature_disparities(feats, pose_pred, matches)
        o = self.options
        stereo = stereo_correspondences(left, right, feats, self.rig, (dp, dl), o, clock)
        self._update_disparity_margin(feats, stereo, predicted)
        return stereo

    def _first_frame(self, left, right, feats, clock) -> FrameResult:
        """Start the map at the initial pose (frame 0, or the first frame with enough features)."""
        o = self.options
        stereo = self._stereo(left, right, feats, clock)
        k = self.index - 1
        self.map_origin = map_origin(self.initial_pose, stereo.points)
        R0, t0 = rt(self.initial_pose)
        pose = Pose(jnp.asarray(R0), jnp.asarray(t0 + R0 @ self.map_origin))  # of the map
        if len(stereo.point_idx) + len(stereo.line_idx) < o.min_features:
            return FrameResult(
                k,
                lost_pose(),
                int(Status.TOO_FEW_POINTS),
                timings=clock.wall,
                cpu_timings=clock.cpu,
            )
        self._pose_prev = pose
        log = None
        if self._window is not None:
            R, t = rt(pose)
            log = self._window.start(R, t, fixed=True, index=k)  # the gauge
        with clock.stage("map"):
            added = update_map(
                self.map, self.rig, o, pose, feats, stereo, {}, {}, set(), set(), k, log=log
            )
            self._capture(left, right, added, pose)
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
            timings=clock.wall,
            cpu_timings=clock.cpu,
        )

    @in_float64
    def process(
        self, left: np.ndarray, right: np.ndarray, *, roi=None, features=None
    ) -> FrameResult:
        """The :class:`~jaxpose.pipelines.stereo.FrameResult` of one rectified stereo pair (grey
        or BGR of any depth, :func:`as_gray_uint8`). ``roi``: the target's box ``[u0, v0, u1,
        v1]`` in the left image (default: :func:`target_roi`), checked by ``check_roi``.
        ``features``: this pair's :meth:`detect`, extracted ahead (``roi`` is then unused)."""
        o = self.options
        left, right = checked_pair(left, right, self.rig)
        if features is not None and not isinstance(features, FrameFeatures):
            raise TypeError(
                f"features must be the FrameFeatures of StereoTracker.detect; got {type(features)}"
            )
        clock = StageClock(STAGES)
        with clock.stage("features"):
            feats = self.detect(left, roi=roi) if features is None else features
        k = self.index
        self.index += 1
        if not self._started:
            return self.given_frame(self._first_frame(left, right, feats, clock))

        pose_pred = compose(self._delta, self._pose_prev)
        with clock.stage("match"):
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
            if self._anchors is not None and len(i_m):
                feats = self._align(left, feats, i_m, i_cur, pose_pred)
            if self._anchors is not None and o.anchor_follow_px:
                feats, i_m, i_cur = follow(
                    self._anchors,
                    self.map.points,
                    self.rig.left,
                    left,
                    feats,
                    (i_m, i_cur),
                    self._followed,
                    cand,
                    pose_pred,
                    search_px=o.anchor_follow_px,
                    duplicate_px=o.duplicate_px,
                    limit=o.max_points // 2 if o.stereo_residuals else o.max_points,
                )
        stereo = None
        if o.stereo_residuals or o.keyframe_every <= 1:
            stereo = self._stereo(left, right, feats, clock, pose_pred, (i_m, i_cur, l_m, l_cur))

        with clock.stage("pose"):
            result, update = self._fit_frame(
                k, left, feats, stereo, pose_pred, (i_m, i_cur, cand, l_m, l_cur, lcand), clock
            )
        for seconds in (clock.wall, clock.cpu):  # the budget's selection is its own stage
            seconds["pose"] -= seconds["budget"]
        if update is not None and (
            self._since_kf >= o.keyframe_every or result.inliers < o.keyframe_min
        ):
            if stereo is None:
                stereo = self._stereo(left, right, feats, clock, pose_pred)
            with clock.stage("map"):
                added = update_map(
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
                    log=self._rays,
                )
                self._capture(left, right, added, result.pose)
            self._since_kf = 0
            result.keyframe = True
        if self._rays is not None:
            depth, self._rays = float(self._rays.t[2]), None  # the map origin's depth
            self._since_adjust += 1
            self._since_global += 1
            if self._since_adjust >= window_cadence(o, depth):
                self._since_adjust = 0
                spanning = bool(o.window_anchors) and self._since_global >= o.window_anchor_every
                if spanning:
                    self._since_global = 0
                with clock.stage("map"):
                    self._adjust_window(result, spanning=spanning)
        return self.given_frame(result)

    def given_frame(self, item):
        """A pose (or a frame result's) of the map's target frame in the given one, the frame
        of ``initial_pose``: ``(R, t - R map_origin)`` (the same pose when the map kept the given
        origin, :func:`~jaxpose.pipelines.stereo.landmarks.map_origin`). ``tracker.map`` holds
        its landmarks in the map's frame: ``X + map_origin`` in the given one."""
        pose = getattr(item, "pose", item)
        if not self.map_origin.any():
            return item  # a lost frame's NaN pose stays NaN below
        R, t = rt(pose)
        moved = Pose(jnp.asarray(R), jnp.asarray(t - R @ self.map_origin))
        return replace(item, pose=moved) if hasattr(item, "pose") else moved

    def _capture(self, left, right, added, pose: Pose) -> None:
        """Keep the reference patches of the new point landmarks (``anchor_points``), with
        their surface normals from the stereo pair's slant where ``anchor_normals="stereo"``."""
        if self._anchors is None:
            return
        R, t = rt(pose)
        normals = None
        if self.options.anchor_normals == "stereo":
            normals = stereo_normals(left, right, self.rig.left, added[1], added[2], R)
        self._anchors.capture(left, added[0], added[1], R, t, normals)
        if len(self._anchors) > 2 * max(len(self.map.points), 1000):
            self._anchors.keep(self.map.points.ids)

    def _reanchor(self, left, feats, i_cur, j, pose: Pose) -> None:
        """Take anew, at their (aligned) pixels ``feats.points[i_cur]``, the patches of the
        landmarks ``j`` whose view has turned ``anchor_turn_deg`` from their reference
        (``anchor_points``)."""
        o = self.options
        if self._anchors is None or not o.anchor_turn_deg:
            return
        R, t = rt(pose)
        m = self.map.points
        self._anchors.reanchor(left, m.ids[j], feats.points[i_cur], m.X[j], R, t, o.anchor_turn_deg)

    def _align(self, left, feats, i_m, i_cur, pose: Pose):
        """The features with the matched keypoints moved to their landmarks' aligned patches."""
        R, t = rt(pose)
        m = self.map.points
        normals = surface_normals(m.X, i_m) if self.options.anchor_normals == "map" else None
        px, _ = self._anchors.align(
            left, self.rig.left, m.ids[i_m], m.X[i_m], feats.points[i_cur], R, t, normals
        )
        points = feats.points.copy()
        points[i_cur] = px
        return replace(feats, points=points)

    def _adjust_window(self, result: FrameResult, *, spanning: bool = False) -> None:
        """Jointly adjust the window's poses and landmarks (``window_frames``; ``spanning``:
        with the kept past frames, ``window_anchors``); the frame's result, the last pose and
        the constant-velocity motion become the adjusted ones."""
        win = self._window
        if not win.adjust(self.map, spanning=spanning):
            return
        last = win.frames[-1]
        pose = Pose(jnp.asarray(last.R), jnp.asarray(last.t))
        if len(win.frames) >= 2 and win.frames[-2].index == last.index - 1:
            prev = win.frames[-2]
            self._delta = relative(pose, Pose(jnp.asarray(prev.R), jnp.asarray(prev.t)))
        self._pose_prev = pose
        result.pose = pose
        self._last_depth = float(last.t[2])

    def _fit_frame(self, k, left, feats, stereo, pose_pred, matches, clock: StageClock):
        """The pose of frame ``k`` (left image ``left``) from its matches, the tracker's state
        moved on when it is good; returns the frame's result and the map update (matched feature
        to landmark, or ``None``)."""
        o = self.options
        i_m, i_cur, cand, l_m, l_cur, lcand = matches
        n_p, n_l = len(i_m), len(l_m)
        result = FrameResult(
            k, lost_pose(), int(Status.LOST), n_p, n_l, timings=clock.wall, cpu_timings=clock.cpu
        )
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
                stage=clock.stage,  # the selection is its own stage (taken off "pose" below)
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
                self._run += 1
                if o.measured_line_sigma and n_l:
                    self.update_line_scale(*fit.kept_errors)
                result.pose = pose
                result.status = int(Status.OK)
                self._last_depth = float(pose.t[2])
                in_p, in_l = fit.in_points, fit.in_lines
                if self._window is not None:
                    R, t = rt(pose)
                    z = self.map.points.X[i_m[in_p]] @ R[2] + t[2]  # the inliers' depths
                    far = far_window(o, float(np.median(z)) if len(z) >= 10 else None, self._far)
                    if far != self._far:
                        self._far = far
                        self._window.resize(self._far_frames if far else o.window_frames)
                    self._rays = self._window.start(R, t, index=k)
                self.map.record("points", cand, i_m[in_p], k)
                self._followed = np.sort(self.map.points.ids[i_m[in_p]])
                self._reanchor(left, feats, i_cur[in_p], i_m[in_p], pose)
                if o.frame_rays:
                    kept = fit.kept_points  # left in the last pass: residual below reject_px
                    observe_point_rays(
                        self.map,
                        self.rig,
                        i_m[kept],
                        feats.points[i_cur[kept]],
                        pose,
                        right=False,
                        log=self._rays,
                    )
                self.map.record("lines", lcand, l_m[in_l], k)
                in_w = in_l if fit.window_lines is None else fit.window_lines
                if o.frame_planes and o.line_planes and in_w.any():
                    observe_left_planes(
                        self.map,
                        self.rig,
                        l_m[in_w],
                        feats.segments[l_cur[in_w]],
                        pose,
                        log=self._rays,
                    )
                if self._rays is not None and in_w.any():
                    self._rays.line_ids = self.map.lines.ids[l_m[in_w]]
                    self._rays.lines = lines_from_segments(feats.segments[l_cur[in_w]])
                    self._rays.line_weight = 1.0 / line_sigma**2
                self._since_kf += 1
                update = (
                    dict(zip(i_cur[in_p].tolist(), i_m[in_p].tolist(), strict=True)),
                    dict(zip(l_cur[in_l].tolist(), l_m[in_l].tolist(), strict=True)),
                )
                self._rejected_p = set(i_cur[~in_p].tolist())
                self._rejected_l = set(l_cur[~in_l].tolist())
        if result.status != Status.OK:
            self._followed = np.zeros(0, np.int64)
            self._misses += 1
            self._run = 0
            self._pose_prev = pose_pred  # predict one more step of constant motion next time
        return result, update
