"""Point landmarks followed by their patch where ORB no longer matches them.

Search by projection (:mod:`~jaxpose.pipelines.stereo.guided`) matches a landmark only where ORB
detects a keypoint near its predicted pixel and the descriptors agree. On a target that turns a
few degrees a frame both fail within a few frames for many landmarks that are still in view: on
a fast turn at 3.7 m about 150 of the 250-350 landmarks matched in a frame are not matched in the
next, and about 60% of those still align to their anchored patch
(:class:`~jaxpose.pipelines.stereo.anchor.PatchAnchors`) near their projection. The map then
renews itself at the turn's pace, and each new landmark takes its place at the pose of the frame
that made it, so the pose error of that frame stays in the map.

:func:`follow` keeps such landmarks observed as SVO does (Forster et al. 2014, sec. IV-B, feature
alignment without a detection): from the predicted pixel, an integer ZNCC search and the
Lucas-Kanade alignment of the warped patch, kept at a ZNCC of :data:`FOLLOW_MIN_ZNCC` or more.
Only the landmarks kept in the previous frame's solve are followed, so a track ends where its
patch stops aligning (the correlation, the warp's stretch or the corner test fails), not where
the descriptor does. ``TrackerOptions(anchor_follow_px=3)`` turns it on; it is off by default
(``docs/stereo-evaluation.md``, *Landmarks followed by their patch*).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo._arrays import find, project, rt
from jaxpose.pipelines.stereo.anchor import PatchAnchors
from jaxpose.pipelines.stereo.landmarks import LandmarkSet
from jaxpose.vision.stereo_features import FrameFeatures

__all__ = ["FOLLOW_MIN_ZNCC", "follow"]

#: The least ZNCC of a followed patch with the image. Without a detection that agrees, the
#: alignment alone vouches for the landmark, so it is asked for more than the anchors' 0.8 for
#: a keypoint ORB matched. Chosen on development draws (``docs/stereo-evaluation.md``,
#: *Landmarks followed by their patch*): at 0.8 a few runs drifted far.
FOLLOW_MIN_ZNCC = 0.95


def follow(
    anchors: PatchAnchors,
    points: LandmarkSet,
    camera: PinholeCamera,
    image: np.ndarray,
    feats: FrameFeatures,
    matches: tuple[np.ndarray, np.ndarray],
    followed_ids: np.ndarray,
    visible: np.ndarray,
    pose: Pose,
    *,
    search_px: int,
    duplicate_px: float,
    limit: int,
) -> tuple[FrameFeatures, np.ndarray, np.ndarray]:
    """The frame's features and point matches with the landmarks ``followed_ids`` (stable ids,
    increasing: the last frame's solve) added where ORB did not match them and their patch
    aligns.

    Args:
        anchors: the landmarks' reference patches.
        points: the map's point landmarks (``X (L, 3)`` body frame, ``ids``, ``desc``).
        camera: the left camera; ``image``: the left image (grey).
        feats: the frame's features (``points (N, 2)``, ``point_desc (N, 32)``).
        matches: ``(i_m, i_cur)``, the landmark and keypoint indices ORB matched.
        followed_ids: stable ids of the landmarks to follow.
        visible: indices of the landmarks predicted visible (search by projection's candidates).
        pose: the predicted pose (body to left camera), whose projections start the search.
        search_px: the integer shifts searched each way before the alignment.
        duplicate_px: an unmatched keypoint this near a followed landmark's aligned pixel is that
            landmark's (it takes the aligned pixel; its descriptor renews the landmark's);
            elsewhere a keypoint is added at the aligned pixel with the landmark's descriptor.
        limit: at most this many point matches in all (the best-observed followed first).

    Returns:
        ``(feats, i_m, i_cur)``: the features (keypoints added at the end), and the matches with
        the followed landmarks appended.
    """
    i_m, i_cur = (np.asarray(a, int) for a in matches)
    empty = (feats, i_m, i_cur)
    if not len(followed_ids) or not len(points) or len(i_m) >= limit:
        return empty
    _, j = find(points.ids, np.asarray(followed_ids, np.int64))
    j = j[np.isin(j, visible) & ~np.isin(j, i_m)]
    if not len(j):
        return empty
    j = j[np.argsort(-points.n_obs[j], kind="stable")][: limit - len(i_m)]
    R, t = rt(pose)
    start = project(camera, pose, points.X[j])
    px, ok = anchors.align(
        image,
        camera,
        points.ids[j],
        points.X[j],
        start,
        R,
        t,
        search=search_px,
        min_zncc=max(anchors.min_zncc, FOLLOW_MIN_ZNCC),
    )
    j, px = j[ok], px[ok]
    if not len(j):
        return empty
    use = np.full(len(j), -1)
    free = np.setdiff1d(np.arange(len(feats.points)), i_cur)
    if len(free):
        d, nn = cKDTree(feats.points[free]).query(px, distance_upper_bound=duplicate_px)
        hit = np.nonzero(np.isfinite(d))[0]
        _, first = np.unique(nn[hit], return_index=True)  # one landmark a keypoint
        use[hit[first]] = free[nn[hit[first]]]
    new = use < 0
    n = len(feats.points)
    use[new] = n + np.arange(int(new.sum()))
    pts = np.concatenate([feats.points, px[new]])
    pts[use[~new]] = px[~new]
    response = feats.point_response
    if response is not None:
        response = np.concatenate([response, np.zeros(int(new.sum()), response.dtype)])
    feats = replace(
        feats,
        points=pts,
        point_desc=np.concatenate([feats.point_desc, points.desc[j[new]]]),
        point_response=response,
    )
    return feats, np.concatenate([i_m, j]), np.concatenate([i_cur, use])
