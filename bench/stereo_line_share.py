"""What the lines add to a frame's pose, axis by axis: the per-frame Cramer-Rao variance with the
lines against without them.

    python bench/stereo_line_share.py SCENE [SCENE ...] [--frames 16] [--seeds 0]
        [--option NAME=VALUE ...] [--figure PATH [--compare LOG]]

Runs the stereo tracker (points + lines, first pose given, ``--option`` as in
``bench/stereo.py``) on scenes of ``bench/stereo.py`` (or ``hNN`` of
``bench/stereo_heldout.py``). On every frame it takes the matches the pose solve receives and
their weighted Jacobian rows, as the ``"dop"`` feature budget builds them
(:func:`jaxpose.pipelines.stereo.budget.feature_rows`: left and right image, points at
``sigma_px``, lines at the tracker's measured line noise), and computes the pose covariance
of independent noise from the points' rows alone and from all rows. Reported per scene and
seed, over frames 2 on: the median points and lines matched, and the median ratio of the two
variances (all over points only) per camera axis: translation x, y, z and rotation about x,
y, z (the roll, pitch and yaw of the stereo page's attitude errors); and per axis of the
chaser position in the target frame, ``c = -R^T t`` (the stereo-track metric's x, y, z,
:func:`chaser_map`). ``sqrt`` of a ratio is
what the lines can lower that axis's per-frame error by, if the errors were independent pixel
noise: a ratio of 0.98 is 1% of RMS.

The run-to-run scatter of the tracker's RMS errors when its features change is 10-40%
(``docs/stereo-evaluation.md``), so an axis whose ratio is near 1 is one on which
"points + lines lower than points only" is a coin toss. ``--figure PATH`` draws that ceiling,
``100 (1 - sqrt(ratio))`` per cent, per scene and axis; ``--compare LOG`` adds, hatched, the
runs of an earlier output of this script (its last line, e.g. with other ``--option``). The
last line is one JSON line of the figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

AXES = ("tx", "ty", "tz", "rx", "ry", "rz")


def variance_ratios(rows: np.ndarray, n_point_rows: int, G: np.ndarray | None = None) -> np.ndarray:
    """The diagonal of ``G (J^T J)^-1 G^T`` over all the weighted rows ``(n, k, 6)`` over the
    same of the first ``n_point_rows`` (the points) alone. ``G``: ``(m, 6)`` linear map of the
    rows' state (``feature_rows``: translation, then the tangent rotation;
    :mod:`jaxpose.core.dilution`); ``None``: the state itself, ``(6,)`` ratios."""
    rows = np.asarray(rows, float).reshape(len(rows), -1, 6)
    ip = np.einsum("nki,nkj->ij", rows[:n_point_rows], rows[:n_point_rows])
    ia = np.einsum("nki,nkj->ij", rows, rows)
    G = np.eye(6) if G is None else np.asarray(G, float)
    var_all = np.einsum("ij,jk,ik->i", G, np.linalg.inv(ia), G)
    var_points = np.einsum("ij,jk,ik->i", G, np.linalg.inv(ip), G)
    return var_all / var_points


def chaser_map(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``(3, 6)``: the first-order change of the chaser position in the target frame,
    ``c = -R^T t`` (the stereo-track metric), for a translation change ``dt`` and a tangent
    attitude change ``e`` (``R <- exp([e]_x) R``): ``dc = -R^T (dt + [t]_x e)``, the ``"dop"``
    budget's chaser rows turned into the target frame."""
    from jaxpose.pipelines.stereo.budget import _chaser_rows

    return -np.asarray(R, float).T @ _chaser_rows(t)


def run(name: str, frames: int, seed: int, options) -> dict:
    """One scene and seed tracked with the per-frame variance ratios recorded."""
    import jaxpose.pipelines.stereo.tracker as tracker_module
    from jaxpose.pipelines.stereo import StereoTracker
    from jaxpose.pipelines.stereo.budget import _bucket, _dop_inputs
    from jaxpose.vision.stereo_render import default_rig, render_sequence

    sys.path.insert(0, str(Path(__file__).parent))
    from stereo import depth_range
    from stereo_diagnose import _scene_by_name

    scene = _scene_by_name(name, frames, seed)
    rig = default_rig()
    log = []
    fit = tracker_module.fit_pose_budgeted

    def recording(landmarks, feats, stereo, matches, pose_pred, rig_, o, line_sigma, **kw):
        i_m = matches[0]
        rows, _, _ = _dop_inputs(
            landmarks, feats, stereo, matches, np.arange(len(i_m)), pose_pred, rig_, o, line_sigma
        )
        n_pad = _bucket(len(i_m), 64)  # the points' padded rows come first
        G = chaser_map(np.asarray(pose_pred.R), np.asarray(pose_pred.t))
        ratios = np.r_[variance_ratios(rows, n_pad), variance_ratios(rows, n_pad, G)]
        log.append((len(i_m), len(matches[2]), ratios))
        return fit(landmarks, feats, stereo, matches, pose_pred, rig_, o, line_sigma, **kw)

    opts = replace(options, use_lines=True, depth_range_m=depth_range(scene))
    pairs = list(render_sequence(scene, rig))
    tracker = StereoTracker(rig, pairs[0].pose, options=opts)
    tracker_module.fit_pose_budgeted = recording
    try:
        for fr in pairs:
            tracker.process(fr.left, fr.right)
    finally:
        tracker_module.fit_pose_budgeted = fit
    kept = log[1:]  # frames 2 on (frame 0 starts the map without a solve)
    if not kept:
        raise SystemExit(f"{name}: no frame was solved")
    ratio = np.median([r for _, _, r in kept], axis=0)
    return {
        "scene": name,
        "seed": seed,
        "points": float(np.median([p for p, _, _ in kept])),
        "lines": float(np.median([q for _, q, _ in kept])),
        "variance_ratio": dict(zip(AXES, np.round(ratio[:6], 4).tolist(), strict=True)),
        "chaser_variance_ratio": dict(zip("xyz", np.round(ratio[6:], 4).tolist(), strict=True)),
    }


def figure(groups, path: Path) -> None:
    """Bars of the per-frame RMS ceiling ``100 (1 - sqrt(ratio))`` per scene and axis;
    ``groups``: ``[(label, runs)]``, ``runs`` as in the JSON line, drawn side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs0 = groups[0][1]
    names = [f"{r['scene'].split('-')[0]} s{r['seed']}" for r in runs0]
    fig, axes = plt.subplots(1, len(runs0), figsize=(2.1 * len(runs0) + 1, 3.4), sharey=True)
    axes = np.atleast_1d(axes)
    width = 0.8 / len(groups)
    colours = ["tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:red", "tab:brown"]
    for j, (label, runs) in enumerate(groups):
        for ax, r in zip(axes, runs, strict=True):
            gain = 100 * (1 - np.sqrt([r["variance_ratio"][a] for a in AXES]))
            ax.bar(
                np.arange(6) + (j - (len(groups) - 1) / 2) * width,
                gain,
                width,
                color=colours,
                hatch="//" if j else None,
                edgecolor="k" if j else None,
                label=label,
            )
    for ax, name, r in zip(axes, names, runs0, strict=True):
        ax.set_xticks(range(6), ["tx", "ty", "tz", "roll", "pitch", "yaw"], fontsize=7)
        ax.set_title(f"{name}: {r['lines']:.0f} lines, {r['points']:.0f} points", fontsize=8)
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_ylabel("most the lines can lower a frame's RMS (%)", fontsize=8)
    if len(groups) > 1:
        axes[-1].legend(fontsize=7, loc="upper right")
    fig.suptitle(
        "Per-frame Cramer-Rao ceiling of the lines' gain, per camera axis (median over frames)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("scenes", nargs="+", help="scenes of bench/stereo.py or hNN")
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--option", action="append", default=[], help="NAME=VALUE tracker option")
    ap.add_argument("--figure", type=Path, default=None, help="PNG of the ceilings")
    ap.add_argument("--compare", type=Path, default=None, help="earlier output, drawn beside")
    args = ap.parse_args(argv)
    keys = [(name, seed) for name in args.scenes for seed in args.seeds]
    compare = None
    if args.compare is not None:
        try:
            line = json.loads(args.compare.read_text().strip().splitlines()[-1])
            compare = {(r["scene"], r["seed"]): r for r in line["runs"]}
        except (OSError, ValueError, IndexError, KeyError, TypeError) as err:
            ap.error(f"--compare {args.compare}: not an output of this script ({err})")
        if set(compare) != set(keys):
            ap.error(f"--compare {args.compare}: its scenes and seeds are not this run's")
        compare_label = ", ".join(line.get("options", [])) or "defaults"
    sys.path.insert(0, str(Path(__file__).parent))
    from stereo import tracker_options
    from stereo_bound import check_scenes

    check_scenes(ap, args.scenes)
    try:
        options = tracker_options(args.option)
    except ValueError as err:
        ap.error(str(err))
    out = []
    print(
        "| scene | seed | points | lines | variance ratio "
        + ", ".join(AXES)
        + " | chaser x, y, z |"
    )
    print("|---|---|---|---|---|---|")
    for name in args.scenes:
        for seed in args.seeds:
            r = run(name, args.frames, seed, options)
            v = ", ".join(f"{x:.3f}" for x in r["variance_ratio"].values())
            c = ", ".join(f"{x:.3f}" for x in r["chaser_variance_ratio"].values())
            row = f"| {name} | {seed} | {r['points']:.0f} | {r['lines']:.0f} | {v} | {c} |"
            print(row, flush=True)
            out.append(r)
    print(json.dumps({"frames": args.frames, "options": args.option, "runs": out}))
    if args.figure is not None:
        groups = [(", ".join(args.option) or "defaults", out)]
        if compare is not None:
            groups.append((compare_label, [compare[k] for k in keys]))
        figure(groups, args.figure)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
