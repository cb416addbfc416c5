"""The stereo tracker's search by projection against the renderer's ground truth.

Two measurements on one scene (a scene of ``bench/stereo.py`` or ``--scene NAME=JSON``):

* **ORB between two frames** (frames 0 and 1): ORB at the tracker's keypoint budget for the
  scene, each keypoint of frame 0 ray-cast to the body at the true pose
  (``stereo_diagnose.raycast``) and projected into frame 1; a keypoint of frame 1 within 1.5
  px is the same corner found again. Reported: how many are found again, the share found on
  the same pyramid level, the median Hamming distance of their descriptors on the same level
  and on another, the median change of ORB's orientation; and, after the tracker's
  ``cornerSubPix`` refinement, how many distinct corners the keypoints are (keypoints within 1
  px of each other joined).
* **The tracker's matches** (every frame, the tracker from the true first pose with the
  ``--option`` items): the landmarks it searched (predicted visible), those with a keypoint
  within 1.5 px of their projection at the *true* pose (findable), those it matched and those
  it matched to a keypoint within 1.5 px of that projection (right). The map's own errors
  enter through the landmarks' positions, so "right" is exact on frame 1 (the map of frame 0
  at the true pose) and an upper estimate later.

    python bench/stereo_matching.py --scene 'far={"range_m": 4.3, "rate_deg_s": 13}' --frames 12
    python bench/stereo_matching.py --scenes d6-blur-5m-slow --option descriptor_memory=4

Ends with one JSON line of the figures (medians over the frames for the second part).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).parent))

import stereo  # bench/stereo.py  # noqa: E402
from stereo_diagnose import raycast  # noqa: E402

from jaxpose.pipelines.stereo import StereoTracker, TrackerOptions, target_roi  # noqa: E402
from jaxpose.pipelines.stereo._arrays import project  # noqa: E402
from jaxpose.pipelines.stereo.tracker import target_area  # noqa: E402
from jaxpose.vision.stereo_features import _hamming, detect_points  # noqa: E402
from jaxpose.vision.stereo_render import (  # noqa: E402
    default_rig,
    render_sequence,
    tumbler_model,
)

FOUND_PX = 1.5  # a keypoint this close to a corner's true pixel is that corner found again


def orb_between_frames(frames, rig, options) -> dict:
    """ORB keypoints of ``frames[0]`` found again in ``frames[1]`` (module docstring)."""
    model = tumbler_model()
    fo = options.features
    orb = cv2.ORB_create(
        nfeatures=fo.n_points, fastThreshold=fo.orb_fast_threshold, nlevels=fo.orb_levels
    )
    found = []
    for fr in frames[:2]:
        kps, desc = orb.detectAndCompute(fr.left, None)
        found.append(
            (
                np.array([k.pt for k in kps]),
                desc,
                np.array([k.octave for k in kps]),
                np.array([k.angle for k in kps]),
            )
        )
    (p0, d0, o0, a0), (p1, d1, o1, a1) = found
    f0, f1 = frames[0], frames[1]
    X = raycast(p0, np.asarray(f0.pose.R), np.asarray(f0.pose.t), rig.left, model)
    on = np.nonzero(np.isfinite(X[:, 0]))[0]
    dist, j = cKDTree(p1).query(project(rig.left, f1.pose, X[on]))
    i0, i1 = on[dist < FOUND_PX], j[dist < FOUND_PX]
    if len(i0) == 0:
        raise SystemExit("no corner of frame 0 is found again in frame 1: is the target in view?")
    h = _hamming(d0, d1, i0, i1)
    same = o0[i0] == o1[i1]
    turn = np.abs((a0[i0] - a1[i1] + 180.0) % 360.0 - 180.0)
    refined = detect_points(f0.left, options=fo, roi=target_roi(f0.left))[0]
    pairs = cKDTree(refined).query_pairs(1.0, output_type="ndarray")
    n_corners = _components(len(refined), pairs)
    return {
        "keypoints": len(p0),
        "on_target": len(on),
        "found_again": len(i0),
        "same_level_share": round(float(same.mean()), 3),
        "hamming_same_level_median": float(np.median(h[same])) if same.any() else None,
        "hamming_other_level_median": float(np.median(h[~same])) if (~same).any() else None,
        "hamming_within_cap_share": round(float(np.mean(h <= fo.max_hamming_point)), 3),
        "orientation_change_median_deg": round(float(np.median(turn)), 1),
        "refined_keypoints": len(refined),
        "distinct_corners_1px": n_corners,
    }


def _components(n: int, pairs: np.ndarray) -> int:
    """Connected components of ``n`` nodes joined by ``pairs`` ``(K, 2)``."""
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return int(connected_components(graph, directed=False)[0])


def tracker_matches(frames, rig, options) -> list[dict]:
    """Per frame: landmarks searched, findable, matched, matched right (module docstring)."""
    import jaxpose.pipelines.stereo.tracker as tracker_module

    search = tracker_module.match_by_projection
    rows, truth = [], {}

    def counted(landmarks, feats, pose_pred, camera, radius, **kw):
        out = search(landmarks, feats, pose_pred, camera, radius, **kw)
        (i_m, i_cur, cand), _ = out
        true_px = project(camera, truth["pose"], landmarks.points.X[cand])
        dist, _ = cKDTree(feats.points).query(true_px)
        right = np.linalg.norm(
            project(camera, truth["pose"], landmarks.points.X[i_m]) - feats.points[i_cur], axis=1
        )
        rows.append(
            {
                "frame": truth["index"],
                "searched": len(cand),
                "findable": int((dist < FOUND_PX).sum()),
                "matched": len(i_m),
                "right": int((right < FOUND_PX).sum()),
                "radius_px": round(float(radius), 2),
            }
        )
        return out

    tracker_module.match_by_projection = counted
    try:
        tr = StereoTracker(rig, frames[0].pose, options=options)
        for fr in frames:
            truth.update(pose=fr.pose, index=fr.index)
            tr.process(fr.left, fr.right)
    finally:
        tracker_module.match_by_projection = search
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--scenes", nargs=1, default=None, choices=list(stereo.SCENES))
    p.add_argument("--scene", default=None, help="a scene of your own, NAME=JSON")
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed of the rendering")
    p.add_argument("--option", action="append", default=[], help="a TrackerOptions NAME=VALUE")
    args = p.parse_args(argv)
    if (args.scene is None) == (args.scenes is None):
        p.error("give one of --scenes or --scene")
    if args.frames < 2:
        p.error("--frames must be at least 2")
    name = stereo._own_scene(p, args.scene) if args.scene else args.scenes[0]
    scene = stereo.scene_of(name, args.frames, args.seed)
    rig = default_rig()
    frames = list(render_sequence(scene, rig))
    base = TrackerOptions(depth_range_m=stereo.depth_range(scene))
    options = stereo.tracker_options(args.option, base)
    # the tracker's keypoint budget for the target's size in frame 0
    probe = StereoTracker(rig, frames[0].pose, options=options)
    budget = probe.feature_options(target_area(frames[0].left))
    orb = orb_between_frames(frames, rig, replace(options, features=budget))
    print("ORB between frames 0 and 1:", json.dumps(orb), flush=True)
    rows = tracker_matches(frames, rig, options)
    print("| frame | searched | findable | matched | right | radius px |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['frame']} | {r['searched']} | {r['findable']} | {r['matched']} | "
            f"{r['right']} | {r['radius_px']} |"
        )
    med = {k: float(np.median([r[k] for r in rows])) for k in ("findable", "matched", "right")}
    print(
        json.dumps(
            {
                "scene": name,
                "seed": args.seed,
                "frames": args.frames,
                "options": args.option,
                "orb_between_frames": orb,
                "median_findable": med["findable"],
                "median_matched": med["matched"],
                "median_right": med["right"],
                "right_over_findable": round(med["right"] / max(med["findable"], 1), 3),
                "right_over_matched": round(med["right"] / max(med["matched"], 1), 3),
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
