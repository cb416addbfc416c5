"""Figures of the pose study: standard deviations against noise, and the scatter of refined poses
against the predicted covariance ellipses."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxpose.studies._plotting import plain_log_labels, pyplot

__all__ = ["plot_scatter", "plot_std"]

AXES = ("tx", "ty", "tz", "wx", "wy", "wz")
_PANELS = [(slice(0, 3), 1e3, "mm", "position"), (slice(3, 6), 180 / np.pi, "deg", "attitude")]


def plot_std(path: Path, groups: list[dict], names: list[str]) -> None:
    """Per geometry, predicted (lines) and Monte Carlo (markers) std of each axis vs noise."""
    plt = pyplot()
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FixedLocator, NullFormatter, ScalarFormatter

    fig, axes = plt.subplots(
        len(names), 2, figsize=(10, 3.3 * len(names) + 0.6), squeeze=False, layout="constrained"
    )
    for row, name in enumerate(names):
        gs = sorted((g for g in groups if g["geometry"] == name), key=lambda g: g["noise_px"])
        s = np.array([g["noise_px"] for g in gs])
        pred = np.array([g["pred_std"] for g in gs])
        emp = np.array([g["emp_std"] or [np.nan] * len(AXES) for g in gs])  # None: no trial
        for col, (sl, scale, unit, what) in enumerate(_PANELS):
            ax = axes[row, col]
            for k, i in enumerate(range(sl.start, sl.stop)):
                ax.plot(s, pred[:, i] * scale, "-", color=f"C{k}")
                ax.plot(s, emp[:, i] * scale, "o", color=f"C{k}", ms=5)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.xaxis.set_major_locator(FixedLocator(s))
            ax.xaxis.set_major_formatter(ScalarFormatter())
            ax.xaxis.set_minor_formatter(NullFormatter())
            plain_log_labels(ax.yaxis, ax.get_ylim())
            ax.set_xlabel("pixel noise sigma (px)")
            ax.set_ylabel(f"std ({unit})")
            ax.set_title(f"{name}: {what}", fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
            handles = [
                Line2D([], [], color=f"C{k}", label=AXES[i])
                for k, i in enumerate(range(sl.start, sl.stop))
            ]
            handles += [
                Line2D([], [], color="k", label="predicted"),
                Line2D([], [], color="k", ls="", marker="o", ms=5, label="Monte Carlo"),
            ]
            ax.legend(handles=handles, fontsize=7, ncol=2)
    fig.suptitle("Pose error std: predicted covariance (lines) and Monte Carlo (markers)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _ellipse(cov2, k):
    vals, vecs = np.linalg.eigh(cov2)
    a = np.linspace(0, 2 * np.pi, 100)
    circle = np.stack([np.cos(a), np.sin(a)])
    return (vecs @ (np.sqrt(np.maximum(vals, 0))[:, None] * circle)) * k


def plot_scatter(path: Path, raw: dict, names: list[str], sigma: float) -> None:
    """Refined poses at ``sigma`` with the predicted 1, 2, 3-sigma ellipses; each axis is fitted
    to the 3-sigma ellipse and the points (scales differ between x and y)."""
    plt = pyplot()

    pairs = [((0, 2), 1e3, "mm"), ((3, 4), 180 / np.pi, "deg")]
    fig, axes = plt.subplots(
        len(names), 2, figsize=(9, 3.8 * len(names) + 0.6), squeeze=False, layout="constrained"
    )
    for row, name in enumerate(names):
        r = raw[(name, sigma)]
        for col, ((i, j), scale, unit) in enumerate(pairs):
            ax = axes[row, col]
            e = r["errors"][:, [i, j]] * scale
            ax.plot(e[:, 0], e[:, 1], ".", ms=2, alpha=0.5, label="refined poses")
            c2 = r["covariance"][np.ix_([i, j], [i, j])] * scale**2
            for k in (1, 2, 3):
                x, y = _ellipse(c2, k)
                ax.plot(x, y, "k-", lw=0.8, label="predicted 1, 2, 3 sigma" if k == 1 else None)
            x3, y3 = _ellipse(c2, 3)
            for setlim, ext in (
                (ax.set_xlim, max(np.abs(x3).max(), np.abs(e[:, 0]).max(initial=0))),
                (ax.set_ylim, max(np.abs(y3).max(), np.abs(e[:, 1]).max(initial=0))),
            ):
                setlim(-1.1 * ext, 1.1 * ext)
            ax.set_xlabel(f"{AXES[i]} error ({unit})")
            ax.set_ylabel(f"{AXES[j]} error ({unit})")
            ax.set_title(f"{name}, {sigma:g} px", fontsize=10)
    fig.suptitle("Refined poses against the predicted covariance")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=2, markerscale=4)
    fig.savefig(path, dpi=110)
    plt.close(fig)
