"""Search by projection: the landmarks of the map matched to the features of the current frame
around their pixels predicted from the constant-velocity pose (ORB-SLAM's guided search)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo._arrays import project
from jaxpose.pipelines.stereo.landmarks import LandmarkMap
from jaxpose.vision.stereo_features import FeatureOptions, knn_ratio_match_pairs, match_lines

__all__ = ["match_by_projection", "match_points_within"]


def match_points_within(pred, desc, feats, radius, options: FeatureOptions):
    """ORB ratio-test matching of landmark descriptors ``desc`` (``(k, 32)``, or ``(k, S, 32)``:
    each landmark's ``S`` recent ones, the nearest counts; predicted at pixels ``pred``,
    ``(k, 2)``) to the keypoints of ``feats`` within ``radius`` pixels (two k-d trees: only those
    pairs are scored). Returns the landmark and keypoint index pairs."""
    if len(pred) == 0 or len(feats.points) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    near = cKDTree(pred).sparse_distance_matrix(
        cKDTree(feats.points), radius, output_type="ndarray"
    )  # every pair within radius (distance 0 included), as arrays
    rows, cols = near["i"].astype(int), near["j"].astype(int)
    order = np.argsort(rows * len(feats.points) + cols)  # by landmark, then keypoint
    rows, cols = rows[order], cols[order]
    twins = (pred, feats.points, options.twin_px) if options.twin_px > 0 else None
    return knn_ratio_match_pairs(
        desc,
        feats.point_desc,
        rows,
        cols,
        ratio=options.point_ratio,
        max_distance=options.max_hamming_point,
        twins=twins,
    )


def _inside(uv: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    W, H = camera.width, camera.height
    return (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)


def match_by_projection(
    landmarks: LandmarkMap,
    feats,
    pose_pred: Pose,
    camera: PinholeCamera,
    radius: float,
    *,
    use_lines: bool,
    line_angle_deg: float,
    options: FeatureOptions,
):
    """The visible landmarks projected with the predicted pose; ORB (ratio test) among the current
    keypoints within ``radius`` of each; LBD (Yang et al. 2024, eqs. 2-3) among the current
    segments parallel to (``line_angle_deg``) and overlapping a projected landmark segment.

    Returns ``((i_m, i_cur, cand), (l_m, l_cur, lcand))``: matched landmark and feature indices of
    points and lines and the landmarks searched (predicted visible)."""
    cand = landmarks.candidates("points", pose_pred)
    pred = project(camera, pose_pred, landmarks.points.X[cand])
    inside = _inside(pred, camera)
    cand, pred = cand[inside], pred[inside]
    i_m, i_cur = match_points_within(pred, landmarks.points.memory[cand], feats, radius, options)
    i_m = cand[i_m]
    l_m = l_cur = lcand = np.zeros(0, int)
    if use_lines and len(landmarks.lines) and len(feats.line_desc):
        lcand = landmarks.candidates("lines", pose_pred)
        seg = project(camera, pose_pred, landmarks.lines.X[lcand])  # (K, 2, 2)
        mid = seg.mean(1)
        inside = _inside(mid, camera)
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
            (cosang > np.cos(np.radians(line_angle_deg)))
            & (perp < radius)
            & (along < 0.5 * (lp[:, None] + lc[None]) + radius)
        )
        l_m, l_cur = match_lines(
            landmarks.lines.desc[lcand], feats.line_desc, options=options, allowed=allowed
        )
        l_m = lcand[l_m]
    return (i_m, i_cur, cand), (l_m, l_cur, lcand)
