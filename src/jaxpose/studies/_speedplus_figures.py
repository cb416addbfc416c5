"""The figure of ``jaxpose eval-speedplus --out DIR``: every image's errors against the success
criterion, and success and confidence per domain."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxpose.core.metrics import SUCCESS_ROTATION_DEG, SUCCESS_TRANSLATION_M
from jaxpose.studies._plotting import plain_log_labels, pyplot

_COLOURS = {"high": "#1a9850", "low": "#f46d43"}
_MARKERS = "osD^v<>p"


def plot_errors(path: Path, out: dict) -> None:
    """``path`` (PNG): left, the position error (m) against the attitude error (deg) of every
    image with a pose, log axes, coloured by confidence class, one marker per domain, the success
    region shaded (images without a pose are counted in the legend); right, per domain, the share
    of images that succeed and of those classed ``high`` (and how many of those are right).
    ``out``: the dict of :func:`jaxpose.studies.speedplus.evaluate_speedplus`."""
    plt = pyplot()
    rows = out["per_image"]
    domains = sorted({r["domain"] for r in rows})
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.6), gridspec_kw={"width_ratios": [3, 2]})

    posed = [r for r in rows if r.get("rotation_error_deg") is not None]
    t = np.array([max(r["translation_error_m"], 1e-2) for r in posed])
    e = np.array([max(r["rotation_error_deg"], 1e-2) for r in posed])
    xlim = (1e-2, max(20.0, float(t.max()) * 1.5) if len(t) else 20.0)
    ylim = (1e-2, 400.0)
    ax.fill_between(
        [xlim[0], SUCCESS_TRANSLATION_M], ylim[0], SUCCESS_ROTATION_DEG, color="#d9f0d3", zorder=0
    )
    ax.text(
        SUCCESS_TRANSLATION_M * 0.9, SUCCESS_ROTATION_DEG * 0.8, "success", ha="right", va="top"
    )
    for d, marker in zip(domains, _MARKERS * len(domains), strict=False):
        for conf, colour in _COLOURS.items():
            pick = [i for i, r in enumerate(posed) if r["domain"] == d and r["confidence"] == conf]
            if pick:
                ax.scatter(
                    t[pick],
                    e[pick],
                    c=colour,
                    marker=marker,
                    s=36,
                    edgecolors="k",
                    linewidths=0.4,
                    label=f"{d}, {conf} ({len(pick)})",
                    zorder=3,
                )
    no_pose = len(rows) - len(posed)
    if no_pose:
        ax.plot([], [], " ", label=f"no attitude returned: {no_pose}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    plain_log_labels(ax.xaxis, xlim)
    plain_log_labels(ax.yaxis, ylim)
    ax.set_xlabel("position error (m)")
    ax.set_ylabel("attitude error (deg)")
    ax.set_title(f"{len(rows)} images: success {out['success_rate']:.0%}")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(True, which="major", alpha=0.3)

    x = np.arange(len(domains))
    per = [out["per_domain"][d] for d in domains]
    ok = [s["success_rate"] for s in per]
    high = [s["high_confidence"] / s["images"] for s in per]
    bx.bar(x - 0.2, ok, 0.4, color="#91cf60", label="success")
    bx.bar(x + 0.2, high, 0.4, color=_COLOURS["high"], label='classed "high"')
    for i, s in enumerate(per):
        bx.text(
            x[i] - 0.2,
            ok[i] + 0.02,
            f"{round(ok[i] * s['images'])}/{s['images']}",
            ha="center",
            fontsize=8,
        )
        if s["high_confidence"]:
            right = round((s["high_precision"] or 0.0) * s["high_confidence"])
            bx.text(
                x[i] + 0.2,
                high[i] + 0.02,
                f"{right} of {s['high_confidence']} right",
                ha="center",
                fontsize=8,
            )
    bx.set_xticks(x, domains)
    bx.set_ylim(0, 1.3)
    bx.set_ylabel("share of the domain's images")
    bx.legend(fontsize=8, loc="upper left", ncol=2)
    bx.set_title("per domain")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
