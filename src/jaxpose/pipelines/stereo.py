"""Stereo point-line pose tracking of a tumbling target (Yang et al. 2024, seed 001).

Per stereo pair (rectified, see :mod:`jaxpose.vision.stereo_match`):

1. features of the left image (:mod:`jaxpose.vision.stereo_features`): ORB points (sub-pixel
   corners), LSD lines (eq. 1) with LBD descriptors;
2. search by projection against a body-frame landmark map
   (:class:`~jaxpose.pipelines.stereo_map.LandmarkMap`): the landmarks visible from the predicted
   pose (constant-velocity prediction) are projected, ORB matched by ratio test among the
   keypoints within ``search_radius_px``, LBD (eqs. 2-3) among the segments parallel to and
   overlapping a projected landmark segment;
3. pose: the matched landmarks are the "body" of :func:`jaxpose.core.refine.refine_pose`, which
   minimises the point+line reprojection cost (eqs. 8-10) with a robust kernel by LM on se(3)
   (eqs. 11-13), in ``passes`` rounds that drop features left beyond ``reject_px``. The result
   is the target pose itself (body to left camera): nothing is chained from frame to frame;
4. map update on keyframes (every ``keyframe_every`` tracked frames): the frame's features get
   stereo correspondences by epipolar ZNCC search (eqs. 4-5) and are triangulated with the rig
   (:meth:`jaxpose.core.camera.StereoCamera.triangulate`); those matched to a landmark refine it
   when their disparity agrees with it (a point: the least-squares intersection of all its
   observation rays; a line: of all its observation planes), the others become new landmarks.
   Lines are weighted by their measured residual scale relative to the points'. When the target
   turns back to a face seen before, the landmarks of that face are found again, so the error
   stays bounded instead of accumulating as a chain of frame-to-keyframe increments does (the
   paper's scheme);
5. an explicit :data:`~jaxpose.core.status.Status.LOST` (pose NaN) when too few features match, the
   solver fails, the fit error is large, or the step from the prediction is implausible; the
   tracker keeps the map and a constant-velocity prediction and tries again on the next frame
   with a doubled search radius.

Points-only mode (``use_lines=False``) is the paper's comparison. The first pose is given (the
ground truth of a rendered sequence, as the paper initialises, or the identity: the target frame is
then the first left camera frame); it places the first landmarks in the body frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from scipy.spatial import cKDTree

from jaxpose.core.camera import StereoCamera
from jaxpose.core.geometry import Pose
from jaxpose.core.refine import RefineOptions, refine_pose
from jaxpose.core.status import Status
from jaxpose.pipelines.stereo_ba import bundle_adjust
from jaxpose.pipelines.stereo_map import LandmarkMap
from jaxpose.vision.stereo_features import (
    FeatureOptions,
    extract,
    knn_ratio_match_pairs,
    match_lines,
)
from jaxpose.vision.stereo_match import (
    StereoMatchOptions,
    disparity_range,
    match_lines_stereo,
    match_points_stereo,
)

__all__ = ["FrameResult", "StereoTracker", "TrackerOptions", "target_roi"]

STAGES = ("features", "stereo", "triangulate", "match", "pose", "ba")


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
        max_points, max_lines: padding sizes of the solver (one compiled function for a
            sequence); beyond ``max_points`` matches the most observed landmarks are kept.
        min_features: fewer matched features (points + lines) than this is LOST.
        max_rms_px: a post-fit RMS reprojection error above this is LOST.
        max_jump_deg, max_jump_m: a pose further than this from the prediction is LOST.
        search_radius_px: search-by-projection radius around the landmarks' predicted pixels
            (constant-velocity prediction); doubled on the frame after a lost one.
        line_angle_deg: a current segment is a candidate for a landmark segment when their
            directions differ by less than this (and they overlap, within the radius).
        keyframe_every, keyframe_min: the map is updated (stereo triangulation of the frame's
            features) every ``keyframe_every`` tracked frames, or when fewer than
            ``keyframe_min`` inliers remain.
        inlier_px: post-fit residual below which a feature counts as an inlier.
        passes, reject_px: LM passes; features with a residual above ``reject_px`` after a pass
            are left out of the next.
        max_view_deg, max_obs, cull_after, cull_ratio, keep_obs: visibility cone, running-mean
            cap and culling of the :class:`~jaxpose.pipelines.stereo_map.LandmarkMap`.
        refine_disparity_px: a landmark's new triangulation is averaged in only when its
            disparity is within this of the landmark's predicted disparity (stereo mismatches
            are left out).
        duplicate_px: an unmatched feature within this of an unmatched landmark's projection
            does not become a new landmark.
        frame_rays: add every tracked frame's left observation rays to the landmarks'
            triangulations (else only those of keyframes with a stereo match).
        stereo_residuals: also fit the right-image pixels of the matched landmarks.
        ba_every, ba_window, ba_iterations: every ``ba_every`` tracked frames (0: never) the
            frame becomes a bundle-adjustment keyframe, and the last ``ba_window`` of them are
            adjusted jointly with the landmarks they share (:mod:`~jaxpose.pipelines.stereo_ba`;
            the oldest pose of the window is held fixed).
            Off by default: on the rendered two-turn sequences it did not help consistently
            (clean, 2 m: 9.0, 10.8, 6.1 mm RMS without, 17.5, 16.8, 10.9 mm with ``ba_every=3``;
            3 m: 62, 43, 24 mm without, 38, 32, 31 mm with).
        ba_max_change_deg: an adjustment that moves the current pose further than this is
            discarded (a safeguard against a wrong local minimum).
        features: the feature options; 2000 ORB keypoints instead of 1200 (chosen on the clean
            2 m sequences, noise seeds 0-2: per-axis RMS position errors at most 10.5 mm instead
            of at most 16.5 mm, at about 2/3 of the frame rate).
        points_ref_depth_m: the ORB budget ``features.n_points`` holds for a target at this depth;
            farther, the budget shrinks with the target's apparent area, ``(ref / z)^2`` (``z``:
            the last tracked depth of the target origin; rounded to 100, never above
            ``n_points``), i.e. a constant keypoint density on the target. A far target seen
            with the full budget gets weak extra corners (clean 3 m: worse with 2000 than with
            1200 keypoints). ``None``: always ``n_points``.
        line_planes: refine the line landmarks from all their observation planes (the planes
            through each camera centre and the segment, body frame, of every stereo pair that
            matched the landmark; :meth:`~jaxpose.pipelines.stereo_map.LandmarkMap.observe_lines`)
            instead of keeping the first stereo triangulation. A matched segment's planes are
            used only when its stereo triangulation agrees with the landmark line to
            ``refine_disparity_px`` at both endpoints (the point rays' gate): a stereo or LBD
            mismatch would otherwise tilt the line for good.
        line_stereo_residuals: with ``stereo_residuals``, also fit the right-image lines of the
            matched segments that have a stereo match (the landmark segment shifted by
            ``R^T t_rl``, as the points), so that a line counts in both images as a point does.
        measured_line_sigma: weight the lines by their measured noise: ``line_sigma_px`` is
            scaled by the ratio of the line to the point residual scales (medians of the
            residuals kept by the last pass), averaged over frames with weight
            ``line_scale_memory`` on the past.
        ba_prior: weight of the landmarks' ray information (all their earlier observations) as
            a prior in the adjustment (0: the window's observations alone).
    """

    use_lines: bool = True
    depth_range_m: tuple[float, float] = (0.6, 8.0)
    depth_margin_m: float | None = 0.8
    robust: str | None = "huber"
    sigma_px: float = 1.0
    line_sigma_px: float = 1.0
    max_points: int = 2048
    max_lines: int = 96
    min_features: int = 12
    max_rms_px: float = 4.0
    max_jump_deg: float = 10.0
    max_jump_m: float = 0.25
    search_radius_px: float = 12.0
    line_angle_deg: float = 10.0
    keyframe_every: int = 1
    keyframe_min: int = 50
    inlier_px: float = 2.0
    passes: int = 3
    reject_px: float = 1.5
    max_view_deg: float = 60.0
    max_obs: int = 10
    cull_after: int = 8
    cull_ratio: float = 0.25
    keep_obs: int = 3
    refine_disparity_px: float = 1.0
    duplicate_px: float = 2.0
    frame_rays: bool = True
    stereo_residuals: bool = True
    ba_every: int = 0
    ba_window: int = 6
    ba_iterations: int = 5
    ba_max_change_deg: float = 1.0
    ba_prior: float = 1.0
    features: FeatureOptions = field(default_factory=lambda: FeatureOptions(n_points=2000))
    points_ref_depth_m: float | None = 2.0
    line_planes: bool = True
    line_stereo_residuals: bool = True
    measured_line_sigma: bool = True
    line_scale_memory: float = 0.9
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
    :func:`jaxpose.core.residuals.line_from_segment`, kept eager so a varying ``k`` compiles nothing)."""
    one = np.ones((len(segments), 1))
    return np.cross(np.c_[segments[:, 0], one], np.c_[segments[:, 1], one])


@eqx.filter_jit
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
        options=RefineOptions(robust=robust, max_steps=30, rtol=1e-9, atol=1e-10),
        throw=False,
    )
    pose = res.pose
    e_p = jnp.linalg.norm(camera.project(pose.apply(P)) - uv, axis=-1)
    pix = camera.project(pose.apply(S.reshape(-1, 3))).reshape(-1, 2, 2)
    n = jnp.linalg.norm(L[:, :2], axis=-1, keepdims=True)
    d = (jnp.einsum("ki,kmi->km", L[:, :2], pix) + L[:, 2:3]) / jnp.where(n > 0, n, 1.0)
    return res, e_p, jnp.max(jnp.abs(d), axis=-1)


def _triangulate_rectified(rig: StereoCamera, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Closed-form triangulation for a rectified rig with identical cameras (NumPy, no padding):
    ``Z = fx b / (u_l - u_r)``, the ray of the left pixel at that depth (the row of the right
    pixel is the left one's by construction). Equal to :meth:`StereoCamera.triangulate` there
    (tested); non-positive disparities give NaN."""
    c = rig.left
    fx, fy, cx, cy = (float(v) for v in (c.fx, c.fy, c.cx, c.cy))
    d = left[:, 0] - right[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        Z = np.where(d > 0, fx * float(rig.baseline) / d, np.nan)
    return np.stack([(left[:, 0] - cx) * Z / fx, (left[:, 1] - cy) * Z / fy, Z], 1)


@eqx.filter_jit
def _triangulate(rig: StereoCamera, left, right):
    return rig.triangulate(left, right)


class StereoTracker:
    """Map-based stereo point-line tracker (module docstring).

    Args:
        rig: rectified rig (``R_rl = I``, ``t_rl = (-b, 0, 0)``, identical ideal cameras), e.g.
            :meth:`~jaxpose.core.camera.StereoCamera.from_baseline` or ``jaxpose.vision.stereo_rectify.rectify(rig).rectified_camera()``.
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
                "images with jaxpose.vision.stereo_rectify.rectify(rig) and use its rectified_camera()"
            )
        if rig.left.has_distortion() or rig.right.has_distortion():
            raise ValueError("StereoTracker needs undistorted (rectified) images and cameras")
        if options.points_ref_depth_m is not None and not options.points_ref_depth_m > 0:
            raise ValueError(
                f"points_ref_depth_m must be positive or None; got {options.points_ref_depth_m}"
            )
        if not 0.0 <= options.line_scale_memory < 1.0:
            raise ValueError(
                f"line_scale_memory must be in [0, 1); got {options.line_scale_memory}"
            )
        self.rig = rig
        self.options = options
        pose = Pose.identity() if initial_pose is None else initial_pose
        self._T0 = _T(np.asarray(pose.R, float), np.asarray(pose.t, float))
        disparity_range(rig, *options.depth_range_m)  # validates the range
        self._last_depth = float(self._T0[2, 3]) if initial_pose is not None else None
        self.map = LandmarkMap(
            max_view_deg=options.max_view_deg,
            max_obs=options.max_obs,
            cull_after=options.cull_after,
            cull_ratio=options.cull_ratio,
            keep_obs=options.keep_obs,
        )
        self._T_prev = self._T0.copy()  # last good pose (body to left camera)
        self._delta = np.eye(4)  # last inter-frame increment (constant-velocity prediction)
        self._misses = 0  # frames lost since the last good one
        self._since_kf = 0
        self._tracked = 0
        self._ba_frames: list = []  # (pose, landmark ids, pixels, right flags) per BA keyframe
        self.index = 0
        fb = float(rig.left.fx) * float(rig.baseline)
        self._same_intrinsics = bool(np.allclose(np.asarray(rig.left.K), np.asarray(rig.right.K)))
        self._fb = fb
        self._line_scale = 1.0  # running ratio of line to point residual scales (line_sigma)

    # ------------------------------------------------------------------ stages
    def _stereo(self, left, right, feats, timings):
        """Stereo correspondence (eqs. 4-5) and triangulation of the frame's features: indices
        and left-camera 3-D points / segments of those with a valid depth."""
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
        ip = np.nonzero(pm.ok)[0]
        il = np.nonzero(line_ok)[0][: o.max_lines]
        n_tri = o.features.n_points + 2 * o.max_lines
        ip = ip[: n_tri - 2 * len(il)]
        pl = np.concatenate(
            [feats.points[ip], feats.segments[il].reshape(-1, 2) if len(il) else np.zeros((0, 2))]
        )
        pr = np.concatenate(
            [
                pm.pixels_right[ip],
                lm.segments_right[il].reshape(-1, 2) if len(il) else np.zeros((0, 2)),
            ]
        )
        if self._same_intrinsics:
            X = _triangulate_rectified(self.rig, pl, pr)
        else:
            X = np.asarray(_triangulate(self.rig, _pad(pl, n_tri, 1.0), _pad(pr, n_tri, 0.0)))
        P = X[: len(ip)]
        S = X[len(ip) : len(ip) + 2 * len(il)].reshape(-1, 2, 3)
        lo, hi = o.depth_range_m
        okp = np.isfinite(P).all(1) & (P[:, 2] > lo) & (P[:, 2] < hi)
        oks = np.isfinite(S).all((1, 2)) & (S[..., 2] > lo).all(1) & (S[..., 2] < hi).all(1)
        timings["stereo"] = t1 - t0
        timings["triangulate"] = time.perf_counter() - t1
        return (ip[okp], P[okp], pm.pixels_right[ip[okp]]), (il[oks], S[oks])

    def _update_map(self, T, left, right, feats, assoc_p, assoc_l, timings, stereo=None):
        """Keyframe: triangulate the frame's features; fold those matched to a landmark into its
        running mean (when the new depth agrees with the landmark's to ``refine_disparity_px``),
        add the others as new landmarks (unless an unmatched landmark projects within
        ``duplicate_px``), then cull. ``assoc_*``: current feature index -> landmark index."""
        o = self.options
        R, t = T[:3, :3], T[:3, 3]
        if stereo is None:
            stereo = self._stereo(left, right, feats, timings)
        (ip, P, pr), (il, S) = stereo
        k = self.index - 1
        Pb = (P - t) @ R  # body frame
        m = self.map.points
        has = np.array([i in assoc_p for i in ip], bool)
        if has.any():
            idx = np.array([assoc_p[i] for i in ip[has]])
            z_map = m.X[idx] @ R[2] + t[2]
            agree = np.abs(self._fb / P[has, 2] - self._fb / z_map) < o.refine_disparity_px
            self.map.refine("points", idx[agree], None, feats.point_desc[ip[has][agree]], R, t, k)
            if not o.frame_rays:
                self._observe(idx[agree], feats.points[ip[has][agree]], T, right=False)
            self._observe(idx[agree], pr[has][agree], T, right=True)
        new = ~has & ~np.isin(ip, list(self._rejected_p))
        if new.any() and len(m):
            cand = self.map.candidates("points", R, t)
            cand = cand[~np.isin(cand, list(assoc_p.values()))]
            if len(cand):
                tree = cKDTree(self._project(m.X[cand], T))
                d, _ = tree.query(feats.points[ip[new]], distance_upper_bound=o.duplicate_px)
                new[np.nonzero(new)[0][np.isfinite(d)]] = False
        ids = self.map.add("points", Pb[new], feats.point_desc[ip[new]], R, t, k)
        self._observe(ids, feats.points[ip[new]], T, right=False)
        self._observe(ids, pr[new], T, right=True)
        if o.use_lines and len(il):
            Sb = (S - t) @ R
            has_l = np.array([i in assoc_l for i in il], bool)
            if has_l.any():
                idx = np.array([assoc_l[i] for i in il[has_l]])
                self.map.refine("lines", idx, None, feats.line_desc[il[has_l]], R, t, k)
                if o.line_planes:
                    agree = self._line_disparity_agrees(idx, S[has_l], T)
                    self._observe_lines(idx[agree], S[has_l][agree], T)
            new_l = ~has_l & ~np.isin(il, list(self._rejected_l))
            ids_l = self.map.add("lines", Sb[new_l], feats.line_desc[il[new_l]], R, t, k)
            if o.line_planes:
                self._observe_lines(ids_l, S[new_l], T)
        self.map.cull()
        self._since_kf = 0

    def _bundle_adjust(self, T_cur, obs, timings) -> np.ndarray:
        """Add the current frame to the BA window and adjust the window (poses not held fixed and
        the landmarks seen from two keyframes or more); returns the adjusted current pose."""
        o = self.options
        t0 = time.perf_counter()
        self._ba_frames.append([T_cur.copy(), *obs])
        self._ba_frames = self._ba_frames[-o.ba_window :]
        if len(self._ba_frames) < 3:
            return T_cur
        ids = np.concatenate([f[1] for f in self._ba_frames])
        uniq, counts = np.unique(
            np.concatenate([np.unique(f[1]) for f in self._ba_frames]), return_counts=True
        )
        shared = uniq[counts >= 2]
        idx_map = self.map.index_of("points", shared)
        shared, idx_map = shared[idx_map >= 0], idx_map[idx_map >= 0]
        pose_idx = np.concatenate([np.full(len(f[1]), j) for j, f in enumerate(self._ba_frames)])
        uv = np.concatenate([f[2] for f in self._ba_frames])
        right = np.concatenate([f[3] for f in self._ba_frames])
        pos = np.searchsorted(shared, ids)
        use = (pos < len(shared)) & (shared[np.minimum(pos, len(shared) - 1)] == ids)
        if len(shared) < 10:
            return T_cur
        poses = np.stack([f[0] for f in self._ba_frames])
        fixed = np.zeros(len(poses), bool)
        fixed[0] = True
        c = self.rig.left
        res = bundle_adjust(
            poses,
            fixed,
            self.map.points.X[idx_map],
            pose_idx[use],
            pos[use],
            uv[use],
            right[use],
            (float(c.fx), float(c.fy), float(c.cx), float(c.cy)),
            np.asarray(self.rig.t_rl, float),
            huber_px=o.reject_px,
            iterations=o.ba_iterations,
            # what the earlier rays (outside the window too) say of each point, in pixels^2:
            # the ray information is weighted by 1/depth^2 (angles), times fx^2
            prior_info=o.ba_prior * float(c.fx) ** 2 * self.map.points.M[idx_map],
        )
        timings["ba"] = time.perf_counter() - t0
        D = res.poses[-1] @ np.linalg.inv(T_cur)
        change = float(np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1))))
        if not (np.all(np.isfinite(res.poses)) and change <= o.ba_max_change_deg):
            return T_cur
        self.map.set_points(idx_map, res.points)
        for f, T in zip(self._ba_frames, res.poses, strict=True):
            f[0] = T
        return res.poses[-1]

    def _observe(self, idx, pixels, T, *, right: bool) -> None:
        """Observation rays (body frame) of points ``idx`` seen at ``pixels`` of the left (or
        right) image of the pose ``T``, weighted by ``1 / depth^2`` (pixel-error weighting), into
        the landmarks' multi-view triangulation."""
        if len(idx) == 0:
            return
        cam = self.rig.right if right else self.rig.left
        R, t = T[:3, :3], T[:3, 3]
        pixels = np.asarray(pixels, float)
        d = np.stack(
            [
                (pixels[:, 0] - float(cam.cx)) / float(cam.fx),
                (pixels[:, 1] - float(cam.cy)) / float(cam.fy),
                np.ones(len(pixels)),
            ],
            1,
        )
        centre = -np.asarray(self.rig.t_rl, float) if right else np.zeros(3)
        z = self.map.points.X[idx] @ R[2] + t[2]
        w = 1.0 / np.maximum(z, 1e-3) ** 2
        self.map.observe(idx, np.broadcast_to((centre - t) @ R, d.shape), d @ R, w)

    def _update_line_scale(self, e_p: np.ndarray, e_l: np.ndarray) -> None:
        """Fold this frame's measured residual scales into the running line weight: the line
        noise relative to the point noise, ``sigma_l / sigma_p``, each from the median of the
        residuals kept by the last pass (a point's is the 2-D distance, median ``1.177 sigma``
        for Gaussian pixel noise; a line's the larger of its two endpoint distances, median
        ``1.052 sigma``). An exponential average over frames (``line_scale_memory``) steadies the
        few lines of a frame."""
        if len(e_p) < 10 or len(e_l) < 3:
            return
        s_p = float(np.median(e_p)) / 1.1774
        s_l = float(np.median(e_l)) / 1.0518
        if not (s_p > 0 and s_l > 0):
            return
        ratio = float(np.clip(s_l / s_p, 0.2, 2.0))
        a = self.options.line_scale_memory
        self._line_scale = a * self._line_scale + (1 - a) * ratio

    def _line_disparity_agrees(self, idx, S, T) -> np.ndarray:
        """Whether the stereo triangulations ``S`` (``(n, 2, 3)``, left camera) of the segments
        matched to line landmarks ``idx`` agree with the landmark lines: at both endpoints, the
        disparity of the landmark line where the endpoint's left ray passes closest to it is
        within ``refine_disparity_px`` of the segment's own (the point rays' gate)."""
        if len(idx) == 0:
            return np.zeros(0, bool)
        R, t = T[:3, :3], T[:3, 3]
        A = self.map.lines.X[idx, 0] @ R.T + t
        D = (self.map.lines.X[idx, 1] - self.map.lines.X[idx, 0]) @ R.T
        ok = np.ones(len(idx), bool)
        for e in range(2):
            r = S[:, e] / S[:, e, 2:3]  # the left ray of the endpoint, unit depth
            # closest points of the ray lam r and the line A + s D (2x2 normal equations)
            rr, rd, dd = (r * r).sum(1), (r * D).sum(1), (D * D).sum(1)
            ra, da = (r * A).sum(1), (D * A).sum(1)
            det = rr * dd - rd**2
            with np.errstate(divide="ignore", invalid="ignore"):
                lam = (ra * dd - da * rd) / det
                disp_map = self._fb / lam
            disp_new = self._fb / S[:, e, 2]
            ok &= (det > 1e-12 * rr * dd) & (lam > 0)
            ok &= np.abs(disp_new - disp_map) < self.options.refine_disparity_px
        return ok

    def _observe_lines(self, idx, S, T) -> None:
        """Observation planes (body frame) of line landmarks ``idx`` from their stereo
        triangulations ``S`` (``(n, 2, 3)``, left camera, pose ``T``): the planes through each
        camera centre and the segment, weighted by ``1 / depth^2`` (pixel-error weighting), into
        the landmarks' multi-view line fit (:meth:`LandmarkMap.observe_lines`)."""
        if len(idx) == 0:
            return
        R, t = T[:3, :3], T[:3, 3]
        w = 1.0 / np.maximum(S[..., 2].mean(1), 1e-3) ** 2
        for C in (np.zeros(3), -np.asarray(self.rig.t_rl, float)):
            n = np.cross(S[:, 0] - C, S[:, 1] - C)
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
            self.map.observe_lines(idx, n @ R, n @ (C - t), w)

    def _feature_options(self) -> FeatureOptions:
        """The feature options of the next frame: the ORB budget scaled to a constant keypoint
        density on the target (``points_ref_depth_m``)."""
        o = self.options
        z, ref = self._last_depth, o.points_ref_depth_m
        if ref is None or z is None or not np.isfinite(z) or z <= ref:
            return o.features
        n = int(round(o.features.n_points * (ref / z) ** 2, -2))
        return replace(o.features, n_points=max(100, min(o.features.n_points, n)))

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
        """Pixels (ideal pinhole, NumPy) of body points moved by ``T`` (4x4)."""
        X = points @ T[:3, :3].T + T[:3, 3]
        z = np.where(X[..., 2] > 1e-6, X[..., 2], 1e-6)
        c = self.rig.left
        return np.stack(
            [float(c.fx) * X[..., 0] / z + float(c.cx), float(c.fy) * X[..., 1] / z + float(c.cy)],
            -1,
        )

    def _match(self, feats, T_pred, radius):
        """Search by projection: the visible landmarks projected with the predicted pose, ORB
        (ratio test) among the current keypoints within ``radius`` of each; LBD (eqs. 2-3) among
        the current segments parallel to (``line_angle_deg``) and overlapping a projected
        landmark segment. Returns the landmark / feature index pairs and the searched sets."""
        o = self.options
        R, t = T_pred[:3, :3], T_pred[:3, 3]
        H, W = self.rig.left.height, self.rig.left.width
        cand = self.map.candidates("points", R, t)
        pred = self._project(self.map.points.X[cand], T_pred)
        inside = (pred[:, 0] >= 0) & (pred[:, 0] < W) & (pred[:, 1] >= 0) & (pred[:, 1] < H)
        cand, pred = cand[inside], pred[inside]
        i_m, i_cur = _guided(pred, self.map.points.desc[cand], feats, radius, o.features)
        i_m = cand[i_m]
        l_m = l_cur = lcand = np.zeros(0, int)
        if o.use_lines and len(self.map.lines) and len(feats.line_desc):
            lcand = self.map.candidates("lines", R, t)
            seg = self._project(self.map.lines.X[lcand], T_pred)  # (K, 2, 2)
            mid = seg.mean(1)
            inside = (mid[:, 0] >= 0) & (mid[:, 0] < W) & (mid[:, 1] >= 0) & (mid[:, 1] < H)
            lcand, seg, mid = lcand[inside], seg[inside], mid[inside]
            cur = feats.segments
            dp = seg[:, 1] - seg[:, 0]
            dc = cur[:, 1] - cur[:, 0]
            lp = np.linalg.norm(dp, axis=1)
            lc = np.linalg.norm(dc, axis=1)
            cosang = np.abs(dp @ dc.T) / np.maximum(lp[:, None] * lc[None], 1e-9)
            # perpendicular distance of the projected midpoint to the current line
            nrm = np.stack([-dc[:, 1], dc[:, 0]], 1) / np.maximum(lc[:, None], 1e-9)
            perp = np.abs(np.einsum("kj,mj->km", mid, nrm) - (cur[:, 0] * nrm).sum(1)[None])
            along = np.linalg.norm(mid[:, None] - cur.mean(1)[None], axis=-1)
            allowed = (
                (cosang > np.cos(np.radians(o.line_angle_deg)))
                & (perp < radius)
                & (along < 0.5 * (lp[:, None] + lc[None]) + radius)
            )
            l_m, l_cur = match_lines(
                self.map.lines.desc[lcand], feats.line_desc, options=o.features, allowed=allowed
            )
            l_m = lcand[l_m]
        return (i_m, i_cur, cand), (l_m, l_cur, lcand)

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
        feats = extract(left, options=self._feature_options(), roi=roi, lines=o.use_lines)
        timings["features"] = time.perf_counter() - t0
        k = self.index
        self.index += 1
        if k == 0:
            self._rejected_p, self._rejected_l = set(), set()
            self._update_map(self._T0, left, right, feats, {}, {}, timings)
            R0, t0_ = self._T0[:3, :3], self._T0[:3, 3]
            return FrameResult(
                k,
                R0,
                t0_,
                int(Status.OK),
                len(self.map.points),
                len(self.map.lines),
                keyframe=True,
                timings=timings,
            )

        stereo = None
        if o.stereo_residuals or o.keyframe_every <= 1:
            stereo = self._stereo(left, right, feats, timings)
        t1 = time.perf_counter()
        T_pred = self._delta @ self._T_prev
        radius = o.search_radius_px * (2.0 if self._misses else 1.0)
        (i_m, i_cur, cand), (l_m, l_cur, lcand) = self._match(feats, T_pred, radius)
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
        result = FrameResult(
            k,
            np.full((3, 3), np.nan),
            np.full(3, np.nan),
            int(Status.LOST),
            n_p,
            n_l,
            timings=timings,
        )
        update = None
        if n_p + n_l >= o.min_features:
            # right-image residuals of the matched landmarks whose feature has a stereo match:
            # x_right = R X + t + t_rl = R (X + R^T t_rl) + t, the same pose with the body point
            # shifted by R^T t_rl, re-evaluated at the latest R on every pass (exact at the
            # fixed point; the shift changes by |t_rl| times the rotation update)
            q_r, uv_r = np.zeros(0, int), np.zeros((0, 2))
            if o.stereo_residuals and stereo is not None and len(stereo[0][0]):
                ip_s, _, pr_s = stereo[0]
                q, j = _find(ip_s, i_cur)
                keep = o.max_points - n_p
                q_r, uv_r = q[:keep], pr_s[j[:keep]]
            n_r = len(q_r)
            t_rl = np.asarray(self.rig.t_rl, float)
            # the same for the lines: the right segment of a matched segment with a stereo
            # match (the right projection of its triangulation, i.e. the fitted right line)
            ql_r, seg_r = np.zeros(0, int), np.zeros((0, 2, 2))
            if (
                o.stereo_residuals
                and o.line_stereo_residuals
                and stereo is not None
                and n_l
                and len(stereo[1][0])
            ):
                il_s, S_s = stereo[1]
                q, j = _find(il_s, l_cur)
                keep = o.max_lines - n_l
                ql_r, seg_r = q[:keep], self._project(S_s[j[:keep]] + t_rl, np.eye(4))
            n_lr = len(ql_r)
            mask = np.arange(o.max_points) < n_p + n_r
            lmask = np.arange(o.max_lines) < n_l + n_lr
            L = (
                _lines_np(np.concatenate([feats.segments[l_cur], seg_r]))
                if n_l
                else np.zeros((0, 3))
            )
            X_m = self.map.points.X[i_m]
            X_l = self.map.lines.X[l_m]
            uv_all = jnp.asarray(_pad(np.concatenate([feats.points[i_cur], uv_r]), o.max_points))
            L_pad = jnp.asarray(_pad(L, o.max_lines))
            line_sigma = o.line_sigma_px * (self._line_scale if o.measured_line_sigma else 1.0)
            statics = (
                self.rig.left,
                o.robust,
                o.sigma_px,
                jnp.full(o.max_lines, line_sigma),  # an array: a new value compiles nothing
            )
            pose0 = Pose(jnp.asarray(T_pred[:3, :3]), jnp.asarray(T_pred[:3, 3]))
            for _ in range(o.passes):
                # each pass restarts from the last pose without the features it left beyond
                # reject_px (ORB-SLAM's outlier passes): the robust kernel alone still lets
                # mismatches on the repetitive texture pull the pose
                shift = np.asarray(pose0.R).T @ t_rl
                P_all = np.concatenate([X_m, X_m[q_r] + shift])
                S_all = np.concatenate([X_l, X_l[ql_r] + shift])
                res, e_p, e_l = _solve(
                    pose0,
                    jnp.asarray(_pad(P_all, o.max_points)),
                    uv_all,
                    jnp.asarray(mask),
                    jnp.asarray(_pad(S_all, o.max_lines)),
                    L_pad,
                    jnp.asarray(lmask),
                    *statics,
                )
                pose0 = res.pose
                mask = mask & (np.asarray(e_p) < o.reject_px)
                lmask = lmask & (np.asarray(e_l) < o.reject_px)
            T_est = _T(np.asarray(res.pose.R), np.asarray(res.pose.t))
            kept_e = (np.asarray(e_p)[mask], np.asarray(e_l)[lmask])  # residuals of the last pass
            e_p, e_l = np.asarray(e_p)[:n_p], np.asarray(e_l)[:n_l]
            in_p, in_l = e_p < o.inlier_px, e_l < o.inlier_px
            inliers = int(in_p.sum() + in_l.sum())
            inl_err = np.concatenate([e_p[in_p], e_l[in_l]])
            rms = float(np.sqrt(np.mean(inl_err**2))) if len(inl_err) else float("inf")
            D = T_est @ np.linalg.inv(T_pred)
            jump_deg = float(np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1))))
            jump_m = float(np.linalg.norm(T_est[:3, 3] - T_pred[:3, 3]))
            good = (
                int(res.status) in (Status.OK, Status.NOT_CONVERGED)
                and np.all(np.isfinite(T_est))
                and inliers >= o.min_features
                and rms <= o.max_rms_px
                and jump_deg <= o.max_jump_deg * (1 + self._misses)
                and jump_m <= o.max_jump_m * (1 + self._misses)
            )
            result.inliers, result.rms_px = inliers, rms
            if good and o.ba_every > 0 and self._tracked % o.ba_every == o.ba_every - 1:
                kept = np.asarray(mask)
                kl, kr = kept[:n_p], kept[n_p : n_p + n_r]
                ids = self.map.points.ids
                obs = (
                    np.concatenate([ids[i_m[kl]], ids[i_m[q_r[kr]]]]),
                    np.concatenate([feats.points[i_cur[kl]], uv_r[kr]]),
                    np.r_[np.zeros(kl.sum(), bool), np.ones(kr.sum(), bool)],
                )
                T_est = self._bundle_adjust(T_est, obs, timings)
            if good:
                steps = self._misses + 1
                self._delta = _fractional_step(T_est @ np.linalg.inv(self._T_prev), steps)
                self._T_prev = T_est
                self._misses = 0
                if o.measured_line_sigma and n_l:
                    self._update_line_scale(*kept_e)
                result.R, result.t = T_est[:3, :3], T_est[:3, 3]
                result.status = int(Status.OK)
                self._last_depth = float(result.t[2])
                self.map.record("points", cand, i_m[in_p], k)
                if o.frame_rays:
                    kept = mask[:n_p]  # left in the last pass: residual below reject_px
                    self._observe(i_m[kept], feats.points[i_cur[kept]], T_est, right=False)
                self.map.record("lines", lcand, l_m[in_l], k)
                self._since_kf += 1
                self._tracked += 1
                update = (
                    dict(zip(i_cur[in_p].tolist(), i_m[in_p].tolist(), strict=True)),
                    dict(zip(l_cur[in_l].tolist(), l_m[in_l].tolist(), strict=True)),
                )
                self._rejected_p = set(i_cur[~in_p].tolist())
                self._rejected_l = set(l_cur[~in_l].tolist())
        if result.status != Status.OK:
            self._misses += 1
            self._T_prev = T_pred  # predict one more step of constant motion for the next try
        timings["pose"] = time.perf_counter() - t2 - timings["ba"]
        if update is not None and (
            self._since_kf >= o.keyframe_every or result.inliers < o.keyframe_min
        ):
            self._update_map(T_est, left, right, feats, *update, timings, stereo=stereo)
            result.keyframe = True
        return result


def _find(keys: np.ndarray, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``q`` of the ``queries`` present in the non-empty ``keys`` and, for each, its
    index in ``keys`` (sorted lookup)."""
    order = np.argsort(keys)
    pos = np.searchsorted(keys[order], queries)
    hit = (pos < len(keys)) & (keys[order][np.minimum(pos, len(keys) - 1)] == queries)
    q = np.nonzero(hit)[0]
    return q, order[pos[q]]


def _T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, t
    return M


def _fractional_step(D: np.ndarray, steps: int) -> np.ndarray:
    """The per-frame increment of a motion ``D`` (4x4) spread over ``steps`` frames (rotation
    vector and translation divided by ``steps``)."""
    if steps <= 1:
        return D
    import cv2

    rvec, _ = cv2.Rodrigues(D[:3, :3])
    R, _ = cv2.Rodrigues(rvec / steps)
    return _T(R, D[:3, 3] / steps)


def _guided(pred, desc, feats, radius, options):
    """:func:`match_points_guided` with a k-d tree: only pairs within ``radius`` are scored."""
    if len(pred) == 0 or len(feats.points) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    tree = cKDTree(feats.points)
    pairs = tree.query_ball_point(pred, radius)
    rows = np.repeat(np.arange(len(pred)), [len(p) for p in pairs])
    cols = np.fromiter((c for p in pairs for c in p), int, count=len(rows))
    return knn_ratio_match_pairs(
        desc,
        feats.point_desc,
        rows,
        cols,
        ratio=options.point_ratio,
        max_distance=options.max_hamming_point,
    )
