"""Keyframes: the stereo correspondences of a frame and the update of the landmark map.

A keyframe's features get stereo correspondences by epipolar ZNCC search (Yang et al. 2024, eqs.
4-5) and are triangulated with the rig. Those matched to a landmark refine it when their disparity
agrees with it (a point: the least-squares intersection of all its observation rays; a line: of
all its observation planes), the others become new landmarks. Rays and planes are weighted by
``1 / depth^2``, i.e. by the angular (pixel) error of the observation.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import equinox as eqx
import numpy as np
from scipy.spatial import cKDTree

from jaxpose.core.camera import StereoCamera
from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo._arrays import (
    find,
    lines_from_segments,
    pad,
    project,
    rt,
    unit_rows,
)
from jaxpose.pipelines.stereo._clock import StageClock
from jaxpose.pipelines.stereo.landmarks import LandmarkMap
from jaxpose.pipelines.stereo.options import TrackerOptions
from jaxpose.pipelines.stereo.row_lines import row_segment_disparities
from jaxpose.vision.stereo_match import match_points_stereo, match_stereo, steep_segments

__all__ = [
    "FrameStereo",
    "line_disparity_agrees",
    "observe_line_planes",
    "observe_point_rays",
    "stereo_correspondences",
    "triangulate_rectified",
    "update_map",
]


@dataclass
class FrameStereo:
    """Stereo correspondences of one frame's features with a valid depth.

    Attributes:
        point_idx: ``(p,)`` keypoint indices; ``points``: ``(p, 3)`` left-camera points, metres;
        pixels_right: ``(p, 2)`` their right-image pixels.
        line_idx: ``(l,)`` segment indices; ``segments``: ``(l, 2, 3)`` left-camera endpoints.
        row_lines: ``(l,)`` whether a segment's depth is the points' beside it (a segment along
            the rows, :mod:`~jaxpose.pipelines.stereo.row_lines`) rather than its own stereo
            match; ``None``: none is.
    """

    point_idx: np.ndarray
    points: np.ndarray
    pixels_right: np.ndarray
    line_idx: np.ndarray
    segments: np.ndarray
    row_lines: np.ndarray | None = None

    def matched_lines(self) -> np.ndarray:
        """``(l,)`` whether each segment has a right-image match of its own."""
        if self.row_lines is None:
            return np.ones(len(self.line_idx), bool)
        return ~self.row_lines

    def right_lines(self, l_cur: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Of the frame's segments ``l_cur`` (feature indices), those with a right-image match of
        their own (a row line's right image is not observed): their positions in ``l_cur`` and
        their rows here."""
        q, j = find(self.line_idx, l_cur)
        own = self.matched_lines()[j]
        return q[own], j[own]


def triangulate_rectified(rig: StereoCamera, left: np.ndarray, right: np.ndarray) -> np.ndarray:
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


def stereo_correspondences(
    left,
    right,
    feats,
    rig: StereoCamera,
    disparities,
    options: TrackerOptions,
    clock: StageClock | None = None,
) -> FrameStereo:
    """Stereo correspondence (eqs. 4-5) and triangulation of the frame's features, searched over
    ``disparities``: one ``(d_min, d_max)`` for every feature, or a pair of arrays, ``(N, 2)``
    ranges of the points and ``(M, 2)`` of the segments; times the stages ``stereo`` and
    ``triangulate`` on ``clock``."""
    o = options
    clock = StageClock(("stereo", "triangulate")) if clock is None else clock
    with clock.stage("stereo"):
        pm, lm, line_ok = _search(left, right, feats, disparities, o)
    with clock.stage("triangulate"):
        return _triangulate_frame(rig, feats, pm, lm, line_ok, o)


_POOL: list = []


def _search(left, right, feats, disparities, o: TrackerOptions):
    if np.ndim(disparities[0]) == 2:
        d_points, d_lines = disparities
    else:
        d_points = d_lines = disparities
    if o.use_lines and len(feats.segments):
        pool = None
        if o.threads:  # a second thread (NumPy and OpenCV release the GIL): match_stereo
            if not _POOL:
                _POOL.append(ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxpose-zncc"))
            pool = _POOL[0]
        pm, lm = match_stereo(
            left,
            right,
            feats.points,
            d_points,
            feats.segments,
            d_lines,
            options=o.stereo,
            executor=pool,
        )
        return pm, lm, lm.ok
    pm = match_points_stereo(left, right, feats.points, d_points, options=o.stereo)
    return pm, None, np.zeros(len(feats.segments), bool)


def _intrinsics(camera) -> np.ndarray:
    """``(fx, fy, cx, cy)`` as floats: the camera's ``K`` built eagerly from its JAX scalars took
    about 0.7 ms, twice a frame."""
    return np.array([float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)])


def _triangulate_frame(rig, feats, pm, lm, line_ok, o: TrackerOptions) -> FrameStereo:
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
    rectified = np.allclose(_intrinsics(rig.left), _intrinsics(rig.right))
    if rectified:
        X = triangulate_rectified(rig, pl, pr)
    else:
        X = np.asarray(_triangulate(rig, pad(pl, n_tri, 1.0), pad(pr, n_tri, 0.0)))
    P = X[: len(ip)]
    S = X[len(ip) : len(ip) + 2 * len(il)].reshape(-1, 2, 3)
    lo, hi = o.depth_range_m
    okp = np.isfinite(P).all(1) & (P[:, 2] > lo) & (P[:, 2] < hi)
    oks = np.isfinite(S).all((1, 2)) & (S[..., 2] > lo).all(1) & (S[..., 2] < hi).all(1)
    il, S = il[oks], S[oks]
    rows = np.zeros(len(il), bool)
    if o.use_lines and o.row_lines and rectified and len(feats.segments) and o.max_lines > len(il):
        ir, Sr = _row_segments(rig, feats, ip[okp], pm.pixels_right[ip[okp]], line_ok, o)
        ir, Sr = ir[: o.max_lines - len(il)], Sr[: o.max_lines - len(il)]
        ok = (Sr[..., 2] > lo).all(1) & (Sr[..., 2] < hi).all(1)
        il, S = np.concatenate([il, ir[ok]]), np.concatenate([S, Sr[ok]])
        rows = np.concatenate([rows, np.ones(ok.sum(), bool)])
    return FrameStereo(ip[okp], P[okp], pm.pixels_right[ip[okp]], il, S, rows)


def _row_segments(rig, feats, ip, pixels_right, line_ok, o: TrackerOptions):
    """The segments along the rows (within ``min_epipolar_angle_deg`` of them, so without a
    stereo match of their own) that the keypoints beside them give a depth
    (:func:`~jaxpose.pipelines.stereo.row_lines.row_segment_disparities`): their indices and
    left-camera endpoints ``(r, 2, 3)``, on a rectified rig with identical cameras."""
    none = np.zeros(0, int), np.zeros((0, 2, 3))
    if len(ip) == 0:
        return none
    seg = feats.segments
    along = ~steep_segments(seg, o.stereo.min_epipolar_angle_deg)
    ir = np.nonzero(along & ~np.asarray(line_ok, bool))[0]
    if len(ir) == 0:
        return none
    left = feats.points[ip]
    disp, ok = row_segment_disparities(seg[ir], left, left[:, 0] - pixels_right[:, 0])
    ir, disp = ir[ok], disp[ok]
    pl = seg[ir].reshape(-1, 2)
    pr = pl - np.stack([disp.reshape(-1), np.zeros(pl.shape[0])], 1)
    return ir, triangulate_rectified(rig, pl, pr).reshape(-1, 2, 3)


def observe_point_rays(
    landmarks: LandmarkMap,
    rig: StereoCamera,
    idx,
    pixels,
    pose: Pose,
    *,
    right: bool,
    log=None,
) -> None:
    """Observation rays (body frame) of points ``idx`` seen at ``pixels`` of the left (or right)
    image at ``pose``, weighted by ``1 / depth^2`` (pixel-error weighting), into the landmarks'
    multi-view triangulation (:meth:`LandmarkMap.observe`). ``log``: a
    :class:`~jaxpose.pipelines.stereo.window.FrameRays` that records the rays (the windowed
    adjustment moves them when it moves the frame's pose)."""
    if len(idx) == 0:
        return
    cam = rig.right if right else rig.left
    R, t = rt(pose)
    pixels = np.asarray(pixels, float)
    d = np.stack(
        [
            (pixels[:, 0] - float(cam.cx)) / float(cam.fx),
            (pixels[:, 1] - float(cam.cy)) / float(cam.fy),
            np.ones(len(pixels)),
        ],
        1,
    )
    centre = -np.asarray(rig.t_rl, float) if right else np.zeros(3)
    z = landmarks.points.X[idx] @ R[2] + t[2]
    w = 1.0 / np.maximum(z, 1e-3) ** 2
    landmarks.observe(idx, np.broadcast_to((centre - t) @ R, d.shape), d @ R, w)
    if log is not None:
        log.add(landmarks.points.ids[np.asarray(idx, int)], pixels, right, w)


def observe_line_planes(
    landmarks: LandmarkMap,
    rig: StereoCamera,
    idx,
    S,
    pose: Pose,
    *,
    log=None,
    right=None,
    left: bool = True,
) -> None:
    """Observation planes (body frame) of line landmarks ``idx`` from their stereo triangulations
    ``S`` (``(n, 2, 3)``, left camera at ``pose``): the planes through each camera centre and the
    segment, weighted by ``1 / depth^2`` (pixel-error weighting), into the landmarks' multi-view
    line fit (:meth:`LandmarkMap.observe_lines`). ``log``: a
    :class:`~jaxpose.pipelines.stereo.window.FrameRays` that records the planes (camera frame;
    the windowed adjustment moves them when it moves the frame's pose).

    ``right``: ``(n,)`` whether a segment has a right-image match of its own (``None``: all). A
    row line (:attr:`FrameStereo.row_lines`) has none: its right plane would be its left one (the
    baseline lies in both), so its depth, the keypoints' beside it, enters instead as the plane
    through the segment across the line of sight (normal in the left plane, perpendicular to
    the segment), weighted as a disparity of the same pixel noise would be: ``b^2 / Z^4``
    (a depth error ``e`` is a disparity error ``f b e / Z^2``).

    ``left=False``: the right (or across) plane only, where the frame's left plane is added
    apart (``TrackerOptions.frame_planes``, :func:`observe_left_planes`)."""
    if len(idx) == 0:
        return
    R, t = rt(pose)
    idx, S = np.asarray(idx, int), np.asarray(S, float)
    own = np.ones(len(idx), bool) if right is None else np.asarray(right, bool)
    z = np.maximum(S[..., 2].mean(1), 1e-3)
    w = 1.0 / z**2
    C_r = -np.asarray(rig.t_rl, float)
    n_l = unit_rows(np.cross(S[:, 0], S[:, 1]))
    across = unit_rows(np.cross(S[:, 1] - S[:, 0], n_l))  # in the left plane, across the line
    n_r = unit_rows(np.cross(S[:, 0] - C_r, S[:, 1] - C_r))
    b2 = float(np.dot(C_r, C_r))
    C0 = np.zeros(3)
    planes = (  # (normal, offset in the body frame, offset in the camera frame, weight)
        (n_l, n_l @ (C0 - t), n_l @ C0, w),
        (
            np.where(own[:, None], n_r, across),
            np.where(own, n_r @ (C_r - t), (across * (S[:, 0] - t)).sum(1)),
            np.where(own, n_r @ C_r, (across * S[:, 0]).sum(1)),
            np.where(own, w, w * b2 / z**2),
        ),
    )
    for cam, (n, d_body, d_cam, wc) in enumerate(planes):
        if cam == 0 and not left:
            continue
        landmarks.observe_lines(idx, n @ R, d_body, wc)
        if log is not None:
            log.add_planes(landmarks.lines.ids[idx], n, d_cam, cam, wc)


def observe_left_planes(
    landmarks: LandmarkMap, rig: StereoCamera, idx, segments, pose: Pose, *, log=None
) -> None:
    """The left-image observation planes of line landmarks ``idx`` matched in a tracked frame:
    the plane through the left camera centre and each image segment ``segments`` (``(n, 2, 2)``
    pixels, :attr:`FrameFeatures.segments`), weighted ``1 / depth^2`` at the depth of the
    landmark line at ``pose`` (pixel-error weighting, as :func:`observe_line_planes`), into the
    landmarks' multi-view line fit; ``log`` records them (camera ``0``). The lines' analogue of
    :func:`observe_point_rays` for every tracked frame (``TrackerOptions.frame_planes``): a
    line whose first stereo triangulation was off is then refined by the parallax of its later
    views instead of being held where it was put (its new stereo triangulations disagree with
    it and are gated out, :func:`line_disparity_agrees`)."""
    idx = np.asarray(idx, int)
    if len(idx) == 0:
        return
    R, t = rt(pose)
    seg = np.asarray(segments, float)
    if seg.shape != (len(idx), 2, 2):
        raise ValueError(f"segments must be ({len(idx)}, 2, 2) pixels; got {seg.shape}")
    K = np.asarray(rig.left.K, float)
    n = unit_rows(lines_from_segments(seg) @ K)  # the image line's plane: K^T l
    z = landmarks.lines.X[idx] @ R[2] + t[2]  # (n, 2) depths of the landmark's endpoints
    w = 1.0 / np.maximum(z.mean(1), 1e-3) ** 2
    landmarks.observe_lines(idx, n @ R, -(n @ t), w)
    if log is not None:
        log.add_planes(landmarks.lines.ids[idx], n, np.zeros(len(idx)), 0, w)


def line_disparity_agrees(
    landmarks: LandmarkMap, rig: StereoCamera, idx, S, pose: Pose, max_px: float
) -> np.ndarray:
    """Whether the stereo triangulations ``S`` (``(n, 2, 3)``, left camera at ``pose``) of the
    segments matched to line landmarks ``idx`` agree with the landmark lines: at both endpoints,
    the disparity of the landmark line where the endpoint's left ray passes closest to it is
    within ``max_px`` of the segment's own (the point rays' gate)."""
    if len(idx) == 0:
        return np.zeros(0, bool)
    fb = float(rig.left.fx) * float(rig.baseline)
    R, t = rt(pose)
    A = landmarks.lines.X[idx, 0] @ R.T + t
    D = (landmarks.lines.X[idx, 1] - landmarks.lines.X[idx, 0]) @ R.T
    ok = np.ones(len(idx), bool)
    for e in range(2):
        r = S[:, e] / S[:, e, 2:3]  # the left ray of the endpoint, unit depth
        # closest points of the ray lam r and the line A + s D (2x2 normal equations)
        rr, rd, dd = (r * r).sum(1), (r * D).sum(1), (D * D).sum(1)
        ra, da = (r * A).sum(1), (D * A).sum(1)
        det = rr * dd - rd**2
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = (ra * dd - da * rd) / det
            disp_map = fb / lam
        disp_new = fb / S[:, e, 2]
        ok &= (det > 1e-12 * rr * dd) & (lam > 0)
        ok &= np.abs(disp_new - disp_map) < max_px
    return ok


def update_map(
    landmarks: LandmarkMap,
    rig: StereoCamera,
    options: TrackerOptions,
    pose: Pose,
    feats,
    stereo: FrameStereo,
    assoc_p: dict,
    assoc_l: dict,
    rejected_p: set,
    rejected_l: set,
    frame: int,
    *,
    log=None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keyframe update at ``pose``: the frame's triangulated features matched to a landmark refine
    it (when the new depth agrees with the landmark's to ``refine_disparity_px``); the others are
    added as new landmarks (unless rejected by the frame's fit, ``rejected_*``, or an unmatched
    landmark projects within ``duplicate_px``); then the map is culled. ``assoc_*``: current
    feature index -> landmark index; ``log``: records the point rays (``observe_point_rays``).
    Returns the stable ids of the new point landmarks, their left pixels ``(n, 2)`` and their
    disparities ``(n,)`` (pixels)."""
    o = options
    fb = float(rig.left.fx) * float(rig.baseline)
    R, t = rt(pose)
    ip, P, pr = stereo.point_idx, stereo.points, stereo.pixels_right
    il, S = stereo.line_idx, stereo.segments
    Pb = (P - t) @ R  # body frame
    m = landmarks.points
    has = np.array([i in assoc_p for i in ip], bool)
    if has.any():
        idx = np.array([assoc_p[i] for i in ip[has]])
        z_map = m.X[idx] @ R[2] + t[2]
        agree = np.abs(fb / P[has, 2] - fb / z_map) < o.refine_disparity_px
        landmarks.refine("points", idx[agree], None, feats.point_desc[ip[has][agree]], pose, frame)
        if not o.frame_rays:
            left_px = feats.points[ip[has][agree]]
            observe_point_rays(landmarks, rig, idx[agree], left_px, pose, right=False, log=log)
        observe_point_rays(landmarks, rig, idx[agree], pr[has][agree], pose, right=True, log=log)
    new = ~has & ~np.isin(ip, list(rejected_p))
    if new.any() and len(m):
        cand = landmarks.candidates("points", pose)
        cand = cand[~np.isin(cand, list(assoc_p.values()))]
        if len(cand):
            tree = cKDTree(project(rig.left, pose, m.X[cand]))
            d, _ = tree.query(feats.points[ip[new]], distance_upper_bound=o.duplicate_px)
            new[np.nonzero(new)[0][np.isfinite(d)]] = False
    ids = landmarks.add("points", Pb[new], feats.point_desc[ip[new]], pose, frame)
    left_new = feats.points[ip[new]]
    added = (landmarks.points.ids[ids], left_new, left_new[:, 0] - pr[new][:, 0])
    observe_point_rays(landmarks, rig, ids, left_new, pose, right=False, log=log)
    observe_point_rays(landmarks, rig, ids, pr[new], pose, right=True, log=log)
    if o.use_lines and len(il):
        Sb = (S - t) @ R
        has_l = np.array([i in assoc_l for i in il], bool)
        if has_l.any():
            idx = np.array([assoc_l[i] for i in il[has_l]])
            landmarks.refine("lines", idx, None, feats.line_desc[il[has_l]], pose, frame)
            if o.line_planes:
                agree = line_disparity_agrees(
                    landmarks, rig, idx, S[has_l], pose, o.refine_disparity_px
                )
                own = stereo.matched_lines()[has_l][agree]
                observe_line_planes(
                    landmarks,
                    rig,
                    idx[agree],
                    S[has_l][agree],
                    pose,
                    log=log,
                    right=own,
                    left=not o.frame_planes,
                )
        new_l = ~has_l & ~np.isin(il, list(rejected_l))
        ids_l = landmarks.add("lines", Sb[new_l], feats.line_desc[il[new_l]], pose, frame)
        if o.line_planes:
            own = stereo.matched_lines()[new_l]
            observe_line_planes(landmarks, rig, ids_l, S[new_l], pose, log=log, right=own)
    landmarks.cull()
    return added
