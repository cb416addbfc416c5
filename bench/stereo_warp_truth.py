"""The anchored patches' warp given every true quantity, against the plane facing the view.

Each matched landmark's patch from its reference view is aligned in the current frame through
an affine warp (``jaxpose.pipelines.stereo.anchor``). The tracker predicts that warp from its
estimated poses, the landmark and the plane through it that faces the reference camera. This
bench replaces the prediction by the truth: the true poses of the reference and current frames,
the reference keypoint's physical point (its ray cast into the model at the true reference
pose) and, for ``exact``, the true face through it. ``facing`` keeps the facing plane with the
same true poses and point. Nothing else changes.

It reports, per warp: the RMS errors of the run (chaser position in the target's axes, mm; the
``chaser_position_mm`` of ``bench/stereo_diagnose.py``); the patches aligned a frame; and each
aligned pixel's offset from the physical point's true pixel, split per patch (patches seen four
times or more) into its mean (constant part), what is left (varying part), and a line's slope
over the frames (drift a frame), RMS over the patches, pixels, per image axis::

    python bench/stereo_warp_truth.py d4-glints-4m-slow --frames 30 [--seed 0] [--option ...]
        [--true-landmarks]

``--true-landmarks`` also gives the map the truth: after every frame each point landmark the
anchors hold is moved to its physical point (its first reference keypoint ray-cast at the true
pose of the frame that made it, in the map's frame). The tracker's own stereo triangulation and
adjustment still run within each frame; what the next frame starts from is the true map.

The scene is one of ``bench/stereo.py``, ``hNN`` of ``bench/stereo_heldout.py``'s default draw,
or ``NAME={StereoScene fields as JSON}``. Ends with one JSON line of the figures.
``docs/stereo-evaluation.md``, *Surface normals from the stereo slant*, reports its figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import stereo  # noqa: E402  (bench/stereo.py)
from stereo_diagnose import _errors, _scene_by_name, model_boxes, raycast  # noqa: E402

from jaxpose.pipelines.stereo.anchor import PatchAnchors, affine_to_reference  # noqa: E402
from jaxpose.vision.stereo_render import default_rig, render_sequence, tumbler_model  # noqa: E402

WARPS = ("facing", "exact")


def face_normals(X: np.ndarray, model, tol_m: float = 0.01) -> np.ndarray:
    """Unit normals ``(n, 3)`` of the faces of the model's two boxes (body and wing) nearest the
    body points ``X (n, 3)``; NaN rows for points farther than ``tol_m`` from every face."""
    best = np.full(len(X), np.inf)
    normals = np.full((len(X), 3), np.nan)
    for lo, hi in model_boxes(model):
        for axis in range(3):
            others = [a for a in range(3) if a != axis]
            inside = np.all(
                (X[:, others] >= lo[others] - tol_m) & (X[:, others] <= hi[others] + tol_m), 1
            )
            for value, sign in ((lo[axis], -1.0), (hi[axis], 1.0)):
                gap = np.where(inside, np.abs(X[:, axis] - value), np.inf)
                nearer = gap < best
                best = np.where(nearer, gap, best)
                normals[nearer] = sign * np.eye(3)[axis]
    normals[best > tol_m] = np.nan
    return normals


class TruthAnchors(PatchAnchors):
    """:class:`PatchAnchors` whose warps come from the truth (module docstring); it records
    each aligned pixel's offset from its physical point's true pixel."""

    def __init__(self, base: PatchAnchors, truth, model, warp: str, camera):
        super().__init__(
            half=base.half,
            search_px=base.search,
            min_zncc=base.min_zncc,
            max_scale=base.max_scale,
            background=base.background,
            min_cornerness=base.min_cornerness,
            lk_iterations=base.lk_iterations,
        )
        self.truth, self.model, self.warp, self.camera = truth, model, warp, camera
        self.frame = 0
        self.ref = np.zeros(0, int)  # each patch's reference frame
        self.offsets: dict[tuple[int, int], list] = {}  # (id, reference frame) -> offsets
        self.aligned_counts: list[int] = []  # aligned patches, per call of align
        self.physical: dict[int, np.ndarray] = {}  # landmark id -> its first physical point

    def capture(self, image, ids, uv, R, t, normals=None) -> None:
        n = len(self.ids)
        super().capture(image, ids, uv, R, t, normals)
        self.ref = np.concatenate([self.ref, np.full(len(self.ids) - n, self.frame)])
        new = slice(n, len(self.ids))
        R_k, t_k = self.truth[self.frame]
        X = raycast(self.uv[new], R_k, t_k, self.camera, self.model)
        for i, x in zip(self.ids[new], X, strict=True):
            if np.isfinite(x).all():
                self.physical.setdefault(int(i), x)

    def move_to_truth(self, points, origin=(0.0, 0.0, 0.0)) -> int:
        """Move the map's point landmarks ``points`` (a ``LandmarkSet``, in the map's frame,
        whose origin lies at ``origin`` in the body frame) that have a physical point to it;
        how many moved."""
        rows = [j for j, i in enumerate(points.ids) if int(i) in self.physical]
        if rows:
            X = np.stack([self.physical[int(points.ids[j])] for j in rows])
            points.X[rows] = X - np.asarray(origin, float)
        return len(rows)

    def reanchor(self, image, ids, uv, X_body, R, t, min_deg):
        before = self.uv.copy()
        count = super().reanchor(image, ids, uv, X_body, R, t, min_deg)
        self.ref[np.any(self.uv != before, axis=1)] = self.frame
        return count

    def keep(self, ids_alive) -> None:
        alive = np.isin(self.ids, ids_alive)
        super().keep(ids_alive)
        self.ref = self.ref[alive]

    def align(self, image, camera, ids, X_body, pixels, R_cur, t_cur, normals=None):
        ids = np.asarray(ids, np.int64)
        pixels = np.asarray(pixels, float).reshape(-1, 2)
        pos, has = self._lookup(ids)
        A = np.full((len(ids), 2, 2), np.nan)
        physical = np.full((len(ids), 3), np.nan)
        rows = pos[has]
        X = np.full((len(rows), 3), np.nan)
        for k in np.unique(self.ref[rows]):  # the reference keypoints' physical points
            sel = self.ref[rows] == k
            R_k, t_k = self.truth[k]
            X[sel] = raycast(self.uv[rows[sel]], R_k, t_k, camera, self.model)
        hit = np.isfinite(X).all(axis=1)
        X = np.where(hit[:, None], X, np.asarray(X_body, float)[has])
        physical[has] = np.where(hit[:, None], X, np.nan)
        R_ref = np.stack([self.truth[k][0] for k in self.ref[rows]]) if len(rows) else None
        t_ref = np.stack([self.truth[k][1] for k in self.ref[rows]]) if len(rows) else None
        R_true, t_true = self.truth[self.frame]
        if len(rows):
            A[has] = affine_to_reference(
                camera,
                X,
                self.uv[rows],
                R_ref,
                t_ref,
                R_true,
                t_true,
                face_normals(X, self.model) if self.warp == "exact" else None,
            )
        out, aligned = self.match(image, ids, A, pixels)
        P = physical @ R_true.T + t_true
        fx, fy, cx, cy = (float(v) for v in (camera.fx, camera.fy, camera.cx, camera.cy))
        with np.errstate(invalid="ignore"):
            true_px = np.stack([fx * P[:, 0] / P[:, 2] + cx, fy * P[:, 1] / P[:, 2] + cy], 1)
        ref_of = np.zeros(len(ids), int)
        ref_of[has] = self.ref[rows]
        for j in np.nonzero(aligned & np.isfinite(true_px).all(axis=1))[0]:
            key = (int(ids[j]), int(ref_of[j]))
            self.offsets.setdefault(key, []).append(out[j] - true_px[j])
        self.aligned_counts.append(int(aligned.sum()))
        return out, aligned


def offset_split(offsets: dict) -> dict:
    """Per-patch constant part, varying part and drift a frame of the aligned pixels' offsets
    (RMS over the patches seen four times or more; pixels, per image axis)."""
    means, rest, slopes = [], [], []
    for seq in offsets.values():
        if len(seq) < 4:
            continue
        e = np.asarray(seq)
        m = e.mean(axis=0)
        k = np.arange(len(e)) - (len(e) - 1) / 2
        means.append(m)
        rest.append(e - m)
        slopes.append((k[:, None] * (e - m)).sum(axis=0) / (k**2).sum())
    if not means:
        return {"patches": 0}

    def rms(a):
        return np.round(np.sqrt(np.mean(np.square(a), axis=0)), 3).tolist()

    return {
        "patches": len(means),
        "constant_px": rms(np.array(means)),
        "constant_mean_px": np.round(np.mean(means, axis=0), 3).tolist(),
        "varying_px": rms(np.concatenate(rest)),
        "drift_px_a_frame": rms(np.array(slopes)),
    }


def run(
    name: str, frames: int, seed: int, warp: str, option=(), true_landmarks: bool = False
) -> dict:
    """Track scene ``name`` with the true warps of kind ``warp`` (and, with
    ``true_landmarks``, the map's point landmarks moved to the truth after every frame); the
    figures of one run."""
    from jaxpose.pipelines.stereo import StereoTracker

    scene = _scene_by_name(name, frames, seed)
    rig = default_rig()
    seq = list(render_sequence(scene, rig))
    options = replace(stereo.tracker_options(list(option)), depth_range_m=stereo.depth_range(scene))
    if not options.anchor_points:
        raise ValueError("the bench needs the anchored observations (anchor_points=True)")
    truth = [(np.asarray(fr.pose.R, float), np.asarray(fr.pose.t, float)) for fr in seq]
    tracker = StereoTracker(rig, seq[0].pose, options=options)
    anchors = TruthAnchors(tracker._anchors, truth, tumbler_model(scene.size_m), warp, rig.left)
    tracker._anchors = anchors
    results, moved = [], []
    for k, fr in enumerate(seq):
        anchors.frame = k
        results.append(tracker.process(fr.left, fr.right))
        if true_landmarks:
            moved.append(anchors.move_to_truth(tracker.map.points, tracker.map_origin))
    axis = np.asarray(scene.spin_axis_body, float)
    spin_axis_cam = truth[0][0] @ axis / np.linalg.norm(axis)
    errors = _errors(results[1:], [fr.pose for fr in seq[1:]], spin_axis_cam)
    return {
        "scene": name,
        "seed": seed,
        "frames": frames,
        "warp": warp,
        "true_landmarks": true_landmarks,
        "landmarks_moved_a_frame": round(float(np.mean(moved)), 1) if moved else 0.0,
        "chaser_position_mm": errors["chaser_position_mm"],
        "attitude_deg": errors["attitude_rotvec_deg"],
        "lost": errors["lost"],
        "aligned_a_frame": round(float(np.mean(anchors.aligned_counts or [0])), 1),
        **offset_split(anchors.offsets),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("scene", help="a scene of bench/stereo.py, hNN, or NAME={StereoScene JSON}")
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--seed", type=int, default=0, help="the scene's noise seed")
    p.add_argument("--warps", nargs="+", choices=WARPS, default=list(WARPS))
    p.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a TrackerOptions field for both runs (repeatable), as bench/stereo.py takes it",
    )
    p.add_argument(
        "--true-landmarks",
        action="store_true",
        help="move the map's point landmarks to their physical points after every frame",
    )
    args = p.parse_args(argv)
    if args.frames < 2:
        p.error(f"--frames must be at least 2; got {args.frames}")
    try:
        stereo.tracker_options(args.option)
        _scene_by_name(args.scene, args.frames, args.seed)  # a name it does not know: said
    except ValueError as err:
        p.error(str(err))
    out = []
    for warp in args.warps:
        print(f"{args.scene}, {args.frames} frames, seed {args.seed}: {warp} warp ...", flush=True)
        r = run(args.scene, args.frames, args.seed, warp, args.option, args.true_landmarks)
        out.append(r)
        print(
            f"  chaser position {r['chaser_position_mm']} mm, attitude {r['attitude_deg']} deg, "
            f"{r['aligned_a_frame']} aligned a frame; per patch (px, x y): constant "
            f"{r.get('constant_px')}, varying {r.get('varying_px')}, drift a frame "
            f"{r.get('drift_px_a_frame')} over {r['patches']} patches",
            flush=True,
        )
    print(
        json.dumps(
            {
                "bench": "stereo_warp_truth",
                "options": args.option,
                "true_landmarks": args.true_landmarks,
                "runs": out,
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
