"""How the stereo tracker's map renews itself when the target turns: frame by frame, against
ray-cast truth.

For every tracked frame: the map's size, the point landmarks matched (search by projection),
those the frame added, the inliers, and for the matched landmarks, split by age (frames since
the landmark was created: "young" up to 3, the frames before ``mature_obs`` lets a landmark into
the pose solve, "old" beyond):

- ``e_true``: the distance (pixels) between the matched keypoint and the landmark projected at
  the frame's **true** pose; its percentiles say how many matches are near their landmark at
  all (a mismatch or a landmark that slid on the surface lies pixels away);
- the landmark's position error against the body point that the matched keypoint's ray hits at
  the true pose (ray-cast on the model), in the camera's axes: ``lat`` across the line of sight
  and ``dep`` along it, millimetres (medians).

The landmark errors hold the pose errors of the frames that placed the landmark (a landmark put
at a pose off by 0.5 degree sits about 4 mm off at 0.5 m from the body's centre). Run from the
repository root::

    python bench/stereo_turnover.py 'fast-5m={"range_m": 5.0, "rate_deg_s": 18,
        "frame_rate_hz": 5, "noise_sigma": 0.02}' --frames 30       # (one line)
    python bench/stereo_turnover.py d6-blur-5m-slow --frames 12
    python bench/stereo_turnover.py SCENE --option anchor_points=True
    python bench/stereo_turnover.py SCENE_A SCENE_B --figure turnover.png   # side by side

``SCENE``: a scene of ``bench/stereo.py``, ``hNN`` of ``bench/stereo_heldout.py``'s default draw,
or ``NAME={StereoScene fields as JSON}``; several scenes run one after the other. Prints a row a
frame and ends with one JSON line: per scene, the figures pooled over frames 1-9 and over frames
10 onwards. ``--figure PATH``: the rows of every scene side by side.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

YOUNG_FRAMES = 3  # a landmark this many frames old or younger is "young"


def _errors_by_age(X_map, age, uv, pose, rig, model, raycast, project):
    """``e_true`` (pixels) of each match and the landmarks' lateral and depth errors (metres,
    camera axes; NaN where the keypoint's ray misses the model)."""
    R, t = np.asarray(pose.R), np.asarray(pose.t)
    e_true = np.linalg.norm(project(rig.left, pose, X_map) - uv, axis=1)
    d_cam = (X_map - raycast(uv, R, t, rig.left, model)) @ R.T
    lat = np.linalg.norm(d_cam[:, :2], axis=1)
    dep = np.abs(d_cam[:, 2])
    young = age <= YOUNG_FRAMES
    return e_true, lat, dep, young


def _median_mm(x) -> float | None:
    x = x[np.isfinite(x)]
    return round(1e3 * float(np.median(x)), 1) if len(x) else None


def _figures(e, lat, dep, young) -> dict:
    """The figures of a set of matches (one frame's, or frames pooled): the share of matches
    beyond 2 px of their true projections and the young and old landmarks' median errors."""
    return {
        "share_e_true_over_2px": round(float(np.mean(e > 2.0)), 3) if len(e) else None,
        "young_lat_dep_mm": [_median_mm(lat[young]), _median_mm(dep[young])],
        "old_lat_dep_mm": [_median_mm(lat[~young]), _median_mm(dep[~young])],
    }


def turnover(name: str, frames: int, seed: int, option=()) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    import stereo  # bench/stereo.py
    from stereo_diagnose import raycast, rendered

    from jaxpose.pipelines.stereo import StereoTracker
    from jaxpose.pipelines.stereo._arrays import project
    from jaxpose.vision.stereo_render import tumbler_model

    rig, seq, base = rendered(name, frames, seed)
    opts = stereo.tracker_options(option, base)
    seen = {}

    class Spy(StereoTracker):
        """The tracker, keeping each frame's point matches and the map they were made on."""

        def _fit_frame(self, k, left, feats, stereo_, pose_pred, matches, clock):
            m = self.map.points
            seen.update(i_m=matches[0], uv=feats.points[matches[1]], X=m.X.copy(), ids=m.ids.copy())
            return super()._fit_frame(k, left, feats, stereo_, pose_pred, matches, clock)

    tracker = Spy(rig, seq[0].pose, options=opts)
    model = tumbler_model()
    born: dict[int, int] = {}
    rows, pooled = [], {"early": [], "late": []}
    for k, fr in enumerate(seq):
        before = len(born)
        result = tracker.process(fr.left, fr.right)
        for i in tracker.map.points.ids.tolist():
            born.setdefault(i, k)
        if k == 0 or "i_m" not in seen:
            continue
        i_m = seen.pop("i_m")
        age = np.array([k - born[i] for i in seen["ids"][i_m]], int)
        e, lat, dep, young = _errors_by_age(
            seen["X"][i_m], age, seen["uv"], fr.pose, rig, model, raycast, project
        )
        row = {
            "frame": k,
            "map": int(len(seen["ids"])),
            "matched": int(len(i_m)),
            "added": len(born) - before,
            "inliers": int(result.inliers),
            "young": int(young.sum()),
            "e_true_px_pct_10_25_50_75_90": [
                round(float(v), 2) for v in np.percentile(e, [10, 25, 50, 75, 90])
            ]
            if len(e)
            else None,
            **_figures(e, lat, dep, young),
        }
        rows.append(row)
        pooled["early" if k < 10 else "late"].append((e, lat, dep, young))
        print(
            f"frame {k:3d}: map {row['map']:5d}, matched {row['matched']:4d} "
            f"({row['young']} young), added {row['added']:4d}, inliers {row['inliers']:4d}, "
            f"e_true percentiles {row['e_true_px_pct_10_25_50_75_90']} px, "
            f"young lat/dep {row['young_lat_dep_mm']} mm, old {row['old_lat_dep_mm']} mm",
            flush=True,
        )
    summary = {}
    for part, items in pooled.items():
        if not items:
            continue
        e, lat, dep, young = (np.concatenate(v) for v in zip(*items, strict=True))
        summary[part] = {
            "matches": int(len(e)),
            "median_e_true_px": round(float(np.median(e)), 2),
            **_figures(e, lat, dep, young),
        }
    return {
        "scene": name,
        "frames": frames,
        "seed": seed,
        "option": list(option),
        "summary": summary,
        "rows": rows,
    }


def figure(results: list[dict], path: str) -> None:
    """Per frame, one line a scene: the landmarks matched and the inliers; the matches' median
    distance to their true projections and the share beyond 2 px; the older landmarks' error
    across the line of sight."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, res in enumerate(results):
        color = colors[i % len(colors)]
        label = res["scene"].split("=")[0]
        rows = res["rows"]
        k = [r["frame"] for r in rows]
        axes[0].plot(k, [r["matched"] for r in rows], color=color, label=f"{label}: matched")
        axes[0].plot(k, [r["inliers"] for r in rows], "--", color=color, label=f"{label}: inliers")
        pct = [r["e_true_px_pct_10_25_50_75_90"] or [np.nan] * 5 for r in rows]
        axes[1].plot(k, [p[2] for p in pct], color=color, label=f"{label}: median")
        axes[1].plot(k, [p[4] for p in pct], ":", color=color, label=f"{label}: 90th percentile")
        for key, style, what in (
            ("old_lat_dep_mm", "-", f"older than {YOUNG_FRAMES} frames"),
            ("young_lat_dep_mm", "--", "younger"),
        ):
            lateral = [np.nan if r[key][0] is None else r[key][0] for r in rows]
            axes[2].plot(k, lateral, style, color=color, label=f"{label}: {what}")
    axes[0].set_title("point landmarks matched, inliers")
    axes[1].set_title("match to true projection (px)")
    axes[2].set_title("landmark error across the line of sight (mm)")
    for ax in axes:
        ax.set_xlabel("frame")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "scenes",
        nargs="+",
        metavar="SCENE",
        help="a suite scene, hNN, or NAME={StereoScene fields as JSON}",
    )
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed of the rendering")
    p.add_argument(
        "--option", action="append", default=[], help="a TrackerOptions field, NAME=VALUE"
    )
    p.add_argument("--figure", default=None, help="a PNG of the scenes' rows side by side")
    args = p.parse_args(argv)
    results = [turnover(s, args.frames, args.seed, tuple(args.option)) for s in args.scenes]
    if args.figure:
        figure(results, args.figure)
        print(f"figure: {args.figure}")
    lines = [{k: v for k, v in out.items() if k != "rows"} for out in results]
    print(json.dumps({"bench": "stereo_turnover", "scenes": lines}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
