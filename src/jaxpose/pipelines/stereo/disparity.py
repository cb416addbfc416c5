"""The disparity windows of the stereo search: where along its row each feature's match is
sought (the ZNCC search of Yang et al. 2024, eq. 4, runs over ``[d_min, d_max]``).

Without a map every feature searches the disparities of the target's depth range. With one, the
window of the map's depths seen from the predicted pose (:func:`depth_window`); once the tracker
has followed the target for a few frames, each matched feature searches around its landmark's
predicted disparity and each unmatched one around its matched neighbours'
(:func:`feature_windows`), within a margin measured from the last frame
(:func:`measured_margin`). A narrow window is both faster and harder to fool with a repeated
texture.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial import cKDTree

from jaxpose.core.camera import StereoCamera
from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo._arrays import find, rt
from jaxpose.pipelines.stereo.landmarks import LandmarkMap
from jaxpose.pipelines.stereo.options import TrackerOptions
from jaxpose.vision.stereo_match import disparity_range

__all__ = ["depth_window", "feature_windows", "measured_margin"]


def depth_window(
    landmarks: LandmarkMap,
    rig: StereoCamera,
    options: TrackerOptions,
    last_depth: float | None,
    pose_pred: Pose | None = None,
) -> tuple[int, int]:
    """Disparities searched (pixels, ``(d_min, d_max)``). With a map and a predicted pose: the
    depths of the landmarks visible from the prediction (5th to 95th percentile), widened by
    half their spread plus ``depth_margin_m / 8`` each side (structure turning into view lies
    within the target, whose visible depth extent the map measures); else around the last known
    target depth ``last_depth`` (``+- depth_margin_m``); else the whole ``depth_range_m``."""
    o = options
    lo, hi = o.depth_range_m
    z = last_depth
    if o.depth_margin_m is not None and pose_pred is not None and len(landmarks.points) >= 20:
        cand = landmarks.candidates("points", pose_pred)
        if len(cand) >= 20:
            R, t = rt(pose_pred)
            depth = landmarks.points.X[cand] @ R[2] + t[2]
            z0, z1 = np.percentile(depth, [5, 95])
            pad = 0.5 * (z1 - z0) + o.depth_margin_m / 8
            lo, hi = max(lo, z0 - pad), min(hi, z1 + pad)
            if lo < hi:
                return disparity_range(rig, lo, hi)
            lo, hi = o.depth_range_m
    if o.depth_margin_m is not None and z is not None and np.isfinite(z) and z > 0:
        lo, hi = max(lo, z - o.depth_margin_m), min(hi, z + o.depth_margin_m)
        if not lo < hi:
            lo, hi = o.depth_range_m
    return disparity_range(rig, lo, hi)


def feature_windows(
    landmarks: LandmarkMap,
    rig: StereoCamera,
    options: TrackerOptions,
    feats,
    pose_pred: Pose | None,
    matches,
    base: np.ndarray,
    margin: float,
    warm: bool,
):
    """Disparities searched for each feature, ``((N, 2), (M, 2), predicted)`` (int64 pixels).

    ``base``: the window of :func:`depth_window`, which every feature gets without matches
    (``matches=None``, also after a lost frame). With ``matches = (i_m, i_cur, l_m, l_cur)``
    (landmark and feature indices of the matched points and segments) and ``warm`` (the tracker
    has followed the target for ``predicted_disparity_after`` frames in a row):

    * a point matched to a landmark: the landmark's disparity at ``pose_pred``, plus or minus
      the measured margin ``margin`` (pixels, :func:`measured_margin`);
    * a matched segment: its landmark's endpoint disparities, widened by ``margin`` and half
      their difference (the segment found may reach beyond the landmark's);
    * an unmatched feature near matched points (at least 2 within ``neighbour_px``; a segment:
      at two of its endpoints and midpoint): the range of their predicted disparities widened
      by ``margin`` and by that range again (a rigid surface's disparity varies smoothly; a
      depth edge among the neighbours widens the window by itself);
    * the others: ``base``.

    Not ``warm``, every feature keeps ``base`` (the predicted disparities are still returned,
    so that the margin is measured). A true disparity outside its window usually puts the ZNCC
    maximum on the window's edge, which the search rejects (no sub-pixel parabola there): a
    narrow window mostly loses such a match, unless a second peak inside it passes the NCC
    threshold. ``predicted`` holds the matched points' indices and predicted disparities, for
    the margin (``None`` without matches)."""
    o = options
    dp = np.tile(base, (len(feats.points), 1)).astype(np.float64)
    dl = np.tile(base, (len(feats.segments), 1)).astype(np.float64)
    if matches is None:
        return dp.astype(np.int64), dl.astype(np.int64), None
    i_m, i_cur, l_m, l_cur = matches
    R, t = rt(pose_pred)
    fb = float(rig.left.fx) * float(rig.baseline)
    m = margin
    with np.errstate(divide="ignore", invalid="ignore"):
        z = landmarks.points.X[i_m] @ R[2] + t[2]
        d = fb / z
    good = np.isfinite(d) & (z > 0)
    i_cur, d = i_cur[good], d[good]
    if not warm:  # the depth window; the margin measured
        return dp.astype(np.int64), dl.astype(np.int64), (i_cur, d)
    matched = np.zeros(len(dp), bool)
    matched[i_cur] = True
    if len(i_cur) >= 3:
        tree = cKDTree(feats.points[i_cur])

        def around(pixels):
            dist, j = tree.query(pixels, k=min(8, len(i_cur)), distance_upper_bound=o.neighbour_px)
            near = np.isfinite(dist)
            dj = np.where(near, d[np.minimum(j, len(d) - 1)], np.nan)
            lo, hi = np.nanmin(dj, 1), np.nanmax(dj, 1)
            spread = hi - lo
            known = near.sum(1) >= 2
            return known, lo - m - spread, hi + m + spread

        free = np.nonzero(~matched)[0]
        if len(free):
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                known, lo, hi = around(feats.points[free])
            dp[free[known]] = np.stack([lo[known], hi[known]], 1)
        if len(feats.segments):
            seg = feats.segments
            q = np.concatenate([seg[:, 0], seg[:, 1], seg.mean(1)])
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                known, lo, hi = (a.reshape(3, -1) for a in around(q))
            lo, hi = np.where(known, lo, np.inf), np.where(known, hi, -np.inf)
            known = known.sum(0) >= 2  # two of the endpoints and the midpoint
            dl[known] = np.stack([lo[:, known].min(0), hi[:, known].max(0)], 1)
    dp[i_cur] = np.stack([d - m, d + m], 1)
    if len(l_m):
        with np.errstate(divide="ignore", invalid="ignore"):
            zl = landmarks.lines.X[l_m] @ R[2] + t[2]  # (k, 2)
            dd = fb / zl
        ok = np.isfinite(dd).all(1) & (zl > 0).all(1)
        slack = m + 0.5 * np.abs(dd[:, 1] - dd[:, 0])
        dl[l_cur[ok]] = np.stack([dd[ok].min(1) - slack[ok], dd[ok].max(1) + slack[ok]], 1)
    # never wider than the window of the map's depths
    dp = np.clip(dp, base[0], base[1])
    dl = np.clip(dl, base[0], base[1])
    dp = np.stack([np.floor(dp[:, 0]), np.maximum(np.ceil(dp[:, 1]), np.floor(dp[:, 0]) + 2)], 1)
    dl = np.stack([np.floor(dl[:, 0]), np.maximum(np.ceil(dl[:, 1]), np.floor(dl[:, 0]) + 2)], 1)
    return dp.astype(np.int64), dl.astype(np.int64), (i_cur, d)


def measured_margin(feats, stereo, predicted) -> float | None:
    """The next frame's margin around the predicted disparities (pixels) from this frame's
    matched points: ``4 sigma + 2`` px (within 3-24 px), ``sigma`` the robust scale (median
    absolute value over 0.6745) of their measured minus predicted disparities; ``None`` (keep
    the margin) without predictions or with fewer than 10 such points. A tail of larger
    differences (a landmark matched to the wrong keypoint, a stereo mismatch) falls outside the
    window and is left unmatched."""
    if predicted is None or stereo is None:
        return None
    idx, d_pred = predicted
    q, j = find(stereo.point_idx, idx) if len(stereo.point_idx) else (np.zeros(0, int),) * 2
    if len(q) < 10:
        return None
    d_meas = feats.points[idx[q], 0] - stereo.pixels_right[j, 0]
    sigma = float(np.median(np.abs(d_meas - d_pred[q]))) / 0.6745
    return float(np.clip(4.0 * sigma + 2.0, 3.0, 24.0))
