"""Figures of ``stereo-track`` (Yang et al. 2024, Figs. 3-5): the chaser track in the target frame
and the per-axis position and attitude over time, estimate solid and truth dashed in one colour per
axis, with their errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np

AXIS_COLOURS = {"x": "tab:blue", "y": "tab:orange", "z": "tab:green"}


def _column(rows, name):
    return np.array([r.get(name, np.nan) for r in rows], dtype=float)


def track_figure(rows, path: Path, title: str) -> None:
    """3-D chaser position in the target frame, equal scale on the three axes."""
    import matplotlib.pyplot as plt

    has_truth = "chaser_true_x" in rows[0]
    est = np.stack([_column(rows, f"chaser_est_{a}") for a in "xyz"], 1)
    fig = plt.figure(figsize=(6.4, 5.6))
    ax = fig.add_subplot(projection="3d")
    ax.plot(*est.T, color="tab:blue", lw=1.2, label="estimate")
    pts = [est]
    if has_truth:
        true = np.stack([_column(rows, f"chaser_true_{a}") for a in "xyz"], 1)
        ax.plot(*true.T, "--", color="black", lw=0.9, label="truth")
        pts.append(true)
    allp = np.concatenate(pts)
    allp = allp[np.isfinite(allp).all(1)]
    if len(allp):
        centre = 0.5 * (allp.max(0) + allp.min(0))
        half = 0.5 * max(float(np.max(allp.max(0) - allp.min(0))), 1e-3) * 1.05
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(f"Chaser position in the target frame\n({title}; equal scale)", fontsize=10)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def series_figure(rows, path: Path, dt: float, title: str, *, kind: str) -> None:
    """Per-axis chaser position (``kind="position"``) or Euler angles (``"attitude"``) over time:
    estimate solid and truth dashed in one colour per axis, and the error below."""
    import matplotlib.pyplot as plt

    if kind == "position":
        est, true, err = "chaser_est_{}", "chaser_true_{}", "err_pos_{}_mm"
        labels = ("chaser position (m)", "error (mm)")
        names = {"x": "x", "y": "y", "z": "z"}
    else:
        est, true, err = "euler_est_{}_deg", "euler_true_{}_deg", "err_att_{}_deg"
        labels = ("Euler angle (deg)", "error (deg)")
        names = {"x": "roll", "y": "pitch", "z": "yaw"}
    has_truth = "chaser_true_x" in rows[0]
    time_s = _column(rows, "frame") * dt
    n = 2 if has_truth else 1
    fig, axes = plt.subplots(n, 1, figsize=(8, 3.3 * n), squeeze=False, sharex=True)
    top = axes[0, 0]
    for a in "xyz":
        c = AXIS_COLOURS[a]
        top.plot(time_s, _column(rows, est.format(a)), color=c, lw=1.2, label=f"{names[a]}")
        if has_truth:
            top.plot(time_s, _column(rows, true.format(a)), "--", color=c, lw=0.9)
            axes[1, 0].plot(time_s, _column(rows, err.format(a)), color=c, lw=1.0, label=names[a])
    if has_truth:
        top.plot([], [], "-", color="gray", label="estimate")
        top.plot([], [], "--", color="gray", label="truth")
        axes[1, 0].axhline(0.0, color="gray", lw=0.5)
        axes[1, 0].set_ylabel(labels[1])
        axes[1, 0].legend(ncol=3, fontsize=8)
    top.set_ylabel(labels[0])
    top.legend(ncol=5 if has_truth else 3, fontsize=8)
    for ax in axes[:, 0]:
        ax.set_xlabel("time (s)")
        ax.tick_params(labelbottom=True)
        ax.grid(alpha=0.3)
    top.set_title(f"{'Position' if kind == 'position' else 'Attitude'} ({title})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_figures(rows, out: Path, dt: float, title: str) -> list[Path]:
    """``fig3_position_track.png``, ``fig4_position.png``, ``fig5_attitude.png`` in ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    out = Path(out)
    paths = [out / n for n in ("fig3_position_track.png", "fig4_position.png", "fig5_attitude.png")]
    track_figure(rows, paths[0], title)
    series_figure(rows, paths[1], dt, title, kind="position")
    series_figure(rows, paths[2], dt, title, kind="attitude")
    return paths
