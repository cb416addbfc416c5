"""What the lines buy, axis by axis, over several runs of ``bench/stereo.py``.

Issue 16 asks that, on every scene with blur or glints, points + lines be lower than points only
on every axis (x, y, z position, roll, pitch, yaw attitude). One run answers yes or no per scene;
this script reads the ``results.json`` of several runs (noise seeds, both modes: run
``bench/stereo.py`` without ``--points-lines-only``) and asks how large the lines' gain is on
each axis against the scatter between the two modes: per scene and run, the ratio of the
points + lines RMS to the points-only RMS on each axis; per axis, the geometric mean of the
ratios, the standard deviation of their logarithms (as a fraction) and the count lower; the
scene-runs lower on every axis. Run from the repository root::

    python bench/stereo.py --split all --frames 30 --seed S --out runs/lines-S   # S = 0, 1, 2
    python bench/stereo_lines_gain.py runs/lines-0 runs/lines-1 runs/lines-2

Prints a Markdown table, writes ``lines_gain.png`` (each scene-run's per-axis change, in per
cent, by axis) to ``--out``, and ends with one JSON line.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from runs_together import load_runs, ratio_stats, scene_label  # noqa: E402

AXES = ("x", "y", "z", "roll", "pitch", "yaw")


def load(paths) -> list[dict]:
    """Scene records of ``bench/stereo.py`` results (files or the folders holding them) that have
    both modes; a path without any such record is an error (it names the path)."""
    runs = load_runs(
        paths,
        lambda r: "points-only" in r and "points+lines" in r,
        "stereo_lines_gain",
        "no scene run in both modes (run bench/stereo.py without --points-lines-only)",
    )
    return [r for _, rows in runs for r in rows]


def log_ratios(record: dict) -> np.ndarray:
    """``(6,)`` log of points + lines over points only, RMS position x, y, z then attitude."""
    pl, po = record["points+lines"], record["points-only"]
    a = np.r_[pl["rms_position_mm"], pl["rms_attitude_deg"]].astype(float)
    b = np.r_[po["rms_position_mm"], po["rms_attitude_deg"]].astype(float)
    return np.log(a / b)


def summarise(records: list[dict], every_scene: bool = False) -> dict:
    """Per-axis figures over the scene-runs with blur or glints (all with ``every_scene``)."""
    rows = [r for r in records if every_scene or r["scene"].get("blur") or r["scene"].get("glints")]
    # a mode that lost its track has no RMS: such scene-runs are named, not compared
    compared = [_has_rms(r["points+lines"]) and _has_rms(r["points-only"]) for r in rows]
    lost = [scene_label(r["scene"]) for r, ok in zip(rows, compared, strict=True) if not ok]
    rows = [r for r, ok in zip(rows, compared, strict=True) if ok]
    if not rows:
        raise SystemExit("stereo_lines_gain: no scene with blur or glints and an RMS in both modes")
    L = np.array([log_ratios(r) for r in rows])
    per_axis = {ax: ratio_stats(L[:, i]) for i, ax in enumerate(AXES)}
    # the target's verdict as bench/stereo.py recorded it (every axis lower), not decided again
    every = [scene_label(r["scene"]) for r in rows if r["lines_help"]]
    return {"rows": rows, "log_ratios": L, "per_axis": per_axis, "every_axis": every, "lost": lost}


def _has_rms(mode: dict) -> bool:
    """Three positive position RMS and three attitude RMS (none where the track was lost)."""
    v = list(mode.get("rms_position_mm") or []) + list(mode.get("rms_attitude_deg") or [])
    return len(v) == 6 and all(x is not None and x > 0 for x in v)


def figure(s: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    L = 100 * (np.exp(s["log_ratios"]) - 1)
    fig, ax = plt.subplots(figsize=(7.5, 4))
    rng = np.random.default_rng(0)
    for i, name in enumerate(AXES):
        jitter = rng.uniform(-0.18, 0.18, len(L))
        ax.scatter(i + jitter, L[:, i], s=14, alpha=0.7, color="tab:blue")
        g = 100 * (s["per_axis"][name]["geometric_mean_ratio"] - 1)
        ax.plot([i - 0.3, i + 0.3], [g, g], color="k", lw=2)
    ax.axhline(0, color="grey", lw=0.8, ls="--")
    ax.set_xticks(range(len(AXES)), AXES)
    ax.set_ylabel("points + lines against points only (%)")
    ax.set_title(
        f"{len(L)} scene-runs with blur or glints: below 0, the lines lower that axis "
        "(bar: geometric mean)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results", nargs="+", help="results.json files of bench/stereo.py, or folders")
    p.add_argument("--every-scene", action="store_true", help="not only blur or glints")
    p.add_argument("--out", type=Path, default=Path("runs/bench-stereo-lines-gain"))
    a = p.parse_args(argv)
    s = summarise(load(a.results), a.every_scene)
    print("| scene | seed | " + " | ".join(AXES) + " | every axis lower |")
    print("|---|---|" + "---|" * (len(AXES) + 1))
    for r, lr in zip(s["rows"], s["log_ratios"], strict=True):
        cells = " | ".join(f"{100 * (math.exp(v) - 1):+.1f}%" for v in lr)
        print(
            f"| {r['scene']['name']} | {r['scene'].get('seed', 0)} | {cells} | "
            f"{'yes' if r['lines_help'] else 'no'} |"
        )
    n = len(s["rows"])
    for ax, f in s["per_axis"].items():
        print(
            f"{ax}: geometric mean {100 * (f['geometric_mean_ratio'] - 1):+.1f}%, "
            f"sd {100 * f['sd_log']:.1f}%, lower on {f['lower']} of {n}"
        )
    a.out.mkdir(parents=True, exist_ok=True)
    figure(s, a.out / "lines_gain.png")
    print(
        json.dumps(
            {
                "bench": "stereo-lines-gain",
                "scene_runs": n,
                "every_axis_lower": f"{len(s['every_axis'])}/{n}",
                "every_axis_lower_runs": s["every_axis"],
                "left_out_lost_track": s["lost"],
                "per_axis": s["per_axis"],
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
