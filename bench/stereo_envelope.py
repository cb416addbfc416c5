"""Where the stereo tracker meets issue 16's targets: range and spin rate, over many scenes.

Reads the ``results.json`` of ``bench/stereo.py`` or ``bench/stereo_heldout.py`` runs (files or
the folders holding them) and asks, scene by scene, how far the points + lines track lies from
its targets: the worst axis of the RMS position over its target (5 mm per metre of range; the
binding target on every scene measured so far) and the worst axis of the RMS attitude (target 1
degree). Counts the scenes that meet the targets by range band and by spin rate, and draws the
envelope: every scene at its range and spin rate, coloured by its worst position axis over the
target. Run from the repository root::

    python bench/stereo_heldout.py --draw-seed 2068 --frames 30 --out runs/d2068   # and others
    python bench/stereo_envelope.py runs/d2068 runs/d2069 --out runs/envelope

Prints a Markdown table, writes ``envelope.png`` to ``--out`` and ends with one JSON line.
Nothing is tracked here: the figures are those of the runs read.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from runs_together import load_runs  # noqa: E402

#: Range bands (m) of the table and the JSON line: the misses measured so far lie at 4-5 m.
RANGE_EDGES = (1.5, 2.5, 3.5, 4.0, 4.5, 5.0)
#: Spin rates (deg/s) at or above this are counted as fast.
FAST_DEG_S = 15.0
#: Issue 16's targets: RMS position per metre of range (mm), RMS attitude (deg).
POSITION_MM_PER_M, ATTITUDE_DEG = 5.0, 1.0


def load(paths) -> list[dict]:
    """Scene records with a points + lines run, each with ``"source"`` (the path it came from):
    a path without a ``results.json`` or without any such record is an error naming it."""
    runs = load_runs(
        paths,
        lambda r: "points+lines" in r,
        "stereo_envelope",
        "no scene tracked with points + lines",
    )
    return [{**r, "source": str(p)} for p, rows in runs for r in rows]


def scene_figures(record: dict) -> dict:
    """One scene's range, spin rate, tumbling or not, worst position axis over its target and
    worst attitude axis (deg), lost frames and whether it meets the targets. A lost track (no
    RMS) counts as a miss with an infinite ratio."""
    s, m = record["scene"], record["points+lines"]
    r = float(s["range_m"])
    pos, att = m.get("rms_position_mm"), m.get("rms_attitude_deg")
    worst_pos = max(pos) / (POSITION_MM_PER_M * r) if pos else float("inf")
    worst_att = max(att) if att else float("inf")
    lost = int(m.get("lost_frames") or 0)
    return {
        "name": s["name"],
        "source": record.get("source", ""),
        "range_m": r,
        "rate_deg_s": float(s["rate_deg_s"]),
        "tumbling": "tumble" in s["name"] or bool(s.get("nutation_deg")),
        "worst_position_over_target": worst_pos,
        "worst_attitude_deg": worst_att,
        "lost_frames": lost,
        "meets": bool(worst_pos <= 1.0 and worst_att <= ATTITUDE_DEG and lost == 0),
    }


def band_label(lo: float, hi: float) -> str:
    return f"{lo:g}-{hi:g} m"


def summarise(rows: list[dict], edges=RANGE_EDGES, fast: float = FAST_DEG_S) -> dict:
    """Scenes meeting the targets out of all, by range band (``edges``, the last band closed),
    and within each band by spin rate below / at or above ``fast``; scenes outside the bands
    are counted in the totals only."""
    by_range, by_spin = {}, {}
    for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        last = i == len(edges) - 2
        inside = [r for r in rows if lo <= r["range_m"] < hi or (last and r["range_m"] == hi)]
        by_range[band_label(lo, hi)] = _count(inside)
        by_spin[band_label(lo, hi)] = {
            f"below {fast:g} deg/s": _count([r for r in inside if r["rate_deg_s"] < fast]),
            f"{fast:g} deg/s or more": _count([r for r in inside if r["rate_deg_s"] >= fast]),
        }
    finite = [r["worst_attitude_deg"] for r in rows if np.isfinite(r["worst_attitude_deg"])]
    return {
        "scenes": len(rows),
        "meet": sum(r["meets"] for r in rows),
        "by_range": by_range,
        "by_range_and_spin": by_spin,
        "misses": [  # a lost track's ratio as None (JSON has no infinity)
            {
                **{k: r[k] for k in ("source", "name", "lost_frames")},
                "worst_position_over_target": _finite(r["worst_position_over_target"]),
            }
            for r in rows
            if not r["meets"]
        ],
        "largest_worst_attitude_deg": max(finite) if finite else None,
        "frames_lost": sum(r["lost_frames"] for r in rows),
    }


def _count(rows: list[dict]) -> dict:
    ratios = [r["worst_position_over_target"] for r in rows]
    return {
        "meet": sum(r["meets"] for r in rows),
        "scenes": len(rows),
        "median_worst_over_target": _finite(float(np.median(ratios))) if rows else None,
    }


def _finite(x: float) -> float | None:
    return x if np.isfinite(x) else None


def table(summary: dict) -> list[str]:
    spins = list(next(iter(summary["by_range_and_spin"].values())))
    lines = [
        "| range | " + " | ".join(spins) + " | all | median worst position axis / target |",
        "|---|" + "---|" * (len(spins) + 2),
    ]
    for band, c in summary["by_range"].items():
        cells = [_cell(summary["by_range_and_spin"][band][k]) for k in spins]
        med = c["median_worst_over_target"]
        lines.append(
            f"| {band} | "
            + " | ".join(cells)
            + f" | {_cell(c)} | "
            + ("-" if med is None else f"{med:.2f}")
            + " |"
        )
    lines.append(f"| all | | | {summary['meet']} of {summary['scenes']} | |")
    return lines


def _cell(c: dict) -> str:
    return f"{c['meet']} of {c['scenes']}" if c["scenes"] else "-"


def figure(rows: list[dict], path: Path, edges=RANGE_EDGES) -> None:
    """Left: each scene at its range and spin rate, coloured by its worst position axis over
    the target (misses ringed in red); right: that ratio against range (the target at 1)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    r = np.array([x["range_m"] for x in rows])
    w = np.array([x["rate_deg_s"] for x in rows])
    q = np.array([min(x["worst_position_over_target"], 10.0) for x in rows])
    tumble = np.array([x["tumbling"] for x in rows])
    miss = ~np.array([x["meets"] for x in rows])
    norm = LogNorm(vmin=0.05, vmax=2.0, clip=True)
    fig, (a0, a1) = plt.subplots(1, 2, figsize=(11, 4.6))
    sc = None
    for sel, marker, label in (
        (~tumble, "o", "spin about a principal axis"),
        (tumble, "^", "tumbling"),
    ):
        if sel.any():
            sc = a0.scatter(
                r[sel],
                w[sel],
                c=q[sel],
                cmap="viridis",
                norm=norm,
                s=34,
                marker=marker,
                label=label,
                edgecolors="none",
            )
            a1.scatter(
                r[sel],
                q[sel],
                c=w[sel],
                cmap="plasma",
                vmin=5,
                vmax=20,
                s=24,
                marker=marker,
                edgecolors="none",
            )
    if miss.any():
        a0.scatter(
            r[miss],
            w[miss],
            s=110,
            facecolors="none",
            edgecolors="red",
            lw=1.2,
            label="misses a target",
        )
    if sc is not None:
        fig.colorbar(sc, ax=a0, label="worst position axis / target")
    a0.set_xlabel("range (m)")
    a0.set_ylabel("spin rate (deg/s)")
    a0.legend(fontsize=8, loc="lower left", framealpha=0.8)
    for e in edges[1:-1]:
        a1.axvline(e, color="grey", lw=0.5, alpha=0.5)
    a1.axhline(1.0, color="red", lw=0.8, ls="--", label="target")
    a1.set_yscale("log")
    a1.set_xlabel("range (m)")
    a1.set_ylabel("worst position axis / target")
    sm = plt.cm.ScalarMappable(cmap="plasma", norm=plt.Normalize(5, 20))
    fig.colorbar(sm, ax=a1, label="spin rate (deg/s)")
    a1.legend(fontsize=8, loc="upper left")
    for ax in (a0, a1):
        ax.grid(alpha=0.3)
    fig.suptitle(
        f"Stereo tracking, points + lines: {int((~miss).sum())} of {len(rows)} scenes meet "
        "issue 16's targets",
        fontsize=11,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results", nargs="+", help="results.json of bench/stereo*.py runs, or folders")
    p.add_argument("--out", type=Path, default=Path("runs/bench-stereo-envelope"))
    a = p.parse_args(argv)
    rows = [scene_figures(r) for r in load(a.results)]
    summary = summarise(rows)
    print("\n".join(table(summary)))
    for m in summary["misses"]:
        print(
            f"miss: {m['source']} {m['name']}: "
            + (
                "no RMS (the track was lost)"
                if m["worst_position_over_target"] is None
                else f"worst position axis {m['worst_position_over_target']:.3f} of its target"
            )
            + f", {m['lost_frames']} frames lost"
        )
    a.out.mkdir(parents=True, exist_ok=True)
    figure(rows, a.out / "envelope.png")
    print(json.dumps({"bench": "stereo-envelope", **summary}, allow_nan=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
