"""Figures and the text report of the selection study (Ning, Zhang, Wang 2018, Figs. 6, 8-10).

Every figure shows only what was run: a histogram panel per ``m = 8`` group (Fig. 6), mean DOP
against ``m`` when at least two ``n = 18`` groups ran (Fig. 8), and one timing panel per sweep that
ran (against ``n`` at ``m = 8``, against ``m`` at ``n = 18``, or every group side by side when the
groups form neither sweep; Figs. 9-10).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxpose.studies._plotting import plain_log_labels, pyplot

__all__ = ["figures", "format_report"]


def _ratio_bins(ratios: list[np.ndarray]) -> np.ndarray:
    """About 40 bins (at least 0.005 wide) from 1 to the largest 99th percentile of a row of
    panels: a few far outliers would otherwise squeeze every other case into one bin."""
    tops = [float(np.quantile(r, 0.99)) for r in ratios if r.size]
    top = max(tops + [1.0])
    width = max((top - 1.0) / 40.0, 0.005)
    return 1.0 + width * np.arange(int(np.ceil((top - 1.0) / width)) + 2)


def _fig6(result, groups: list[dict], out_dir: Path) -> Path:
    plt = pyplot()
    from matplotlib.ticker import MaxNLocator

    k = len(groups)
    fig, axes = plt.subplots(
        2, k, figsize=(max(3.4 * k, 6.0), 5.6), squeeze=False, layout="constrained"
    )
    for i, key in enumerate(("pdop", "adop")):
        ratios = []
        for g in groups:
            c = result.cases[(g["n"], g["m"])]
            ok = c["status"] == 0
            ratios.append(c[f"{key}_quasi"][ok] / c[f"{key}_opt"][ok])
        bins = _ratio_bins(ratios)
        last = bins[-1]
        for j, (g, ratio) in enumerate(zip(groups, ratios, strict=True)):
            ax = axes[i, j]
            over = ratio >= last
            # Cases beyond the axis are counted in the last bin and named on the panel.
            ax.hist(np.minimum(ratio, (bins[-2] + last) / 2), bins=bins, color=f"C{i}")
            if over.any():
                ax.text(
                    0.97,
                    0.95,
                    f"{int(over.sum())} case(s) >= {last:.2f}\n"
                    f"(max {ratio.max():.2f}) in the last bin",
                    transform=ax.transAxes,
                    ha="right",
                    va="top",
                    fontsize=7,
                )
            ax.set_xlim(bins[0], last)
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
            ax.set_title(f"n = {g['n']}, m = {g['m']}: {key.upper()}", fontsize=9)
            ax.set_xlabel(f"{key.upper()} quasi / optimal", fontsize=9)
            if j == 0:
                ax.set_ylabel("cases")
    fig.suptitle("DOP ratio of the quasi-optimal selection\n(Ning et al. 2018, Fig. 6)")
    path = out_dir / "fig6_ratio_histograms.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _fig8(n18: list[dict], out_dir: Path) -> Path:
    plt = pyplot()
    from matplotlib.ticker import MaxNLocator

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), layout="constrained")
    ms = [g["m"] for g in n18]
    for ax, key, unit in zip(axes, ("pdop", "adop"), ("m/px", "rad/px"), strict=True):
        ax.plot(ms, [g[key]["optimal_mean"] for g in n18], "o-", label="optimal")
        ax.plot(ms, [g[key]["quasi_mean"] for g in n18], "s--", label="quasi-optimal")
        ax.axhline(n18[0][key]["all_mean"], color="k", lw=0.8, label="all 18 points")
        ax.set_xlabel("selected points m (of n = 18)")
        ax.set_ylabel(f"mean {key.upper()} ({unit})")
        ax.set_yscale("log")
        plain_log_labels(ax.yaxis, ax.get_ylim())
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.legend()
    fig.suptitle("Mean DOP against the number of selected points (Ning et al. 2018, Fig. 8)")
    path = out_dir / "fig8_dop_vs_m.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _timing_panels(groups: list[dict]) -> list[tuple[list[dict], str, str]]:
    """``(groups, x key, x label)`` per panel: the sweeps that ran, else every group."""
    m8 = sorted((g for g in groups if g["m"] == 8), key=lambda g: g["n"])
    n18 = sorted((g for g in groups if g["n"] == 18), key=lambda g: g["m"])
    panels = []
    if len(m8) > 1:
        panels.append((m8, "n", "total points n (m = 8)"))
    if len(n18) > 1:
        panels.append((n18, "m", "selected points m (n = 18)"))
    covered = {(g["n"], g["m"]) for gs, _, _ in panels for g in gs}
    rest = [g for g in groups if (g["n"], g["m"]) not in covered]
    if rest:
        panels.append((sorted(rest, key=lambda g: (g["n"], g["m"])), "", "group (n, m)"))
    return panels


def _fig9_10(groups: list[dict], out_dir: Path) -> Path:
    plt = pyplot()
    from matplotlib.ticker import MaxNLocator

    panels = _timing_panels(groups)
    fig, axes = plt.subplots(
        1,
        len(panels),
        figsize=(max(5.0 * len(panels), 6.0), 4.2),
        squeeze=False,
        sharey=True,
        layout="constrained",
    )
    for ax, (gs, key, label) in zip(axes[0], panels, strict=True):
        if key:
            xs = [g[key] for g in gs]
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        else:
            xs = np.arange(len(gs))
            ax.set_xticks(xs, [f"({g['n']}, {g['m']})" for g in gs])
            if len(gs) == 1:
                ax.set_xlim(-1, 1)
        style = "-" if key else ""
        t_opt = [g["time_s"]["optimal_per_case"] for g in gs]
        t_quasi = [g["time_s"]["quasi_per_case"] for g in gs]
        ax.plot(xs, t_opt, "o" + style, label="optimal (exhaustive)")
        ax.plot(xs, t_quasi, "s--" if key else "s", label="quasi-optimal")
        ax.set_yscale("log")
        ax.set_xlabel(label)
        ax.grid(True, which="major", alpha=0.3)
        ax.legend(fontsize=8)
    axes[0, 0].set_ylabel("time per case (s), batched")
    fig.suptitle("Time per case on this machine, after compilation\n(Ning et al. 2018, Figs. 9-10)")
    path = out_dir / "fig9_10_timing.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def figures(result, out_dir: Path) -> list[Path]:
    """Write the figures of a :class:`~jaxpose.studies.selection.StudyResult`; return the paths."""
    groups = result.results["groups"]
    paths = []
    m8 = sorted((g for g in groups if g["m"] == 8), key=lambda g: g["n"])
    if m8:
        paths.append(_fig6(result, m8, out_dir))
    n18 = sorted((g for g in groups if g["n"] == 18), key=lambda g: g["m"])
    if len(n18) > 1:
        paths.append(_fig8(n18, out_dir))
    if groups:
        paths.append(_fig9_10(groups, out_dir))
    return paths


def _fmt(x, spec: str, width: int) -> str:
    return "-".rjust(width) if x is None else format(x, f"{width}{spec}")


def format_report(results: dict) -> str:
    """Plain-text Table 4, Tables 5-6 and timings."""
    lines = [
        "Table 4: DOP ratios quasi-optimal / optimal",
        f"{'n':>4} {'m':>3} {'cases':>6} "
        f"{'PDOP avg':>9} {'PDOP max':>9} {'ADOP avg':>9} {'ADOP max':>9} "
        f"{'t_opt/case':>11} {'t_quasi/case':>12}",
    ]
    for g in sorted(results["groups"], key=lambda g: (g["m"] != 8, g["n"], g["m"])):
        lines.append(
            f"{g['n']:>4} {g['m']:>3} {g['cases']:>6} "
            f"{_fmt(g['pdop_ratio']['mean'], '.4f', 9)} {_fmt(g['pdop_ratio']['max'], '.4f', 9)} "
            f"{_fmt(g['adop_ratio']['mean'], '.4f', 9)} {_fmt(g['adop_ratio']['max'], '.4f', 9)} "
            f"{g['time_s']['optimal_per_case']:11.3e} {g['time_s']['quasi_per_case']:12.3e}"
            + (f"  ({g['failed_cases']} failed)" if g.get("failed_cases") else "")
        )
    for key, name in (("pdop", "Table 5: PDOP (m/px)"), ("adop", "Table 6: ADOP (rad/px)")):
        rows = results.get("tables_5_6", {}).get(key, [])
        if len(rows) < 2:
            continue
        lines += [
            "",
            f"{name}, n = 18",
            f"{'m':>3} {'opt mean':>10} {'% dec':>7} {'/all':>6} "
            f"{'quasi mean':>11} {'% dec':>7} {'/all':>6}",
        ]
        for r in rows:
            lines.append(
                f"{r['m']:>3} {_fmt(r['optimal_mean'], '.3e', 10)} "
                f"{_fmt(r['optimal_decrease_pct'], '.1f', 7)} "
                f"{_fmt(r['optimal_ratio_to_all'], '.3f', 6)} "
                f"{_fmt(r['quasi_mean'], '.3e', 11)} "
                f"{_fmt(r['quasi_decrease_pct'], '.1f', 7)} "
                f"{_fmt(r['quasi_ratio_to_all'], '.3f', 6)}"
            )
    return "\n".join(lines)
