"""Stereo tracking benchmark: a scene suite, points+lines against points-only, time by stage.

Twelve rendered scenes span range 1.5-5 m, spin 5-20 deg/s (about a principal axis or off the
principal axes with nutation), camera rate 5-15 Hz, blur 0-1.5, glints 0-1.5, a light that sweeps
and sensor noise. Six are **development** scenes (parameters of the tracker may be chosen on
them) and six **check** scenes (only reported). Each scene is rendered once, all its frames
first (rendering is timed apart and excluded from the frame rate), and both trackers track the
same frames as a stream (``track_stream``: the next pair's features extracted while this one is
tracked, as a camera's frames would be). The first tracked frame compiles the solver and is left
out of the timings; a frame's time is from one result to the next.

    python bench/stereo.py                                  # the whole suite, one turn a scene
    python bench/stereo.py --frames 60 --split dev          # a quicker look at the dev scenes
    python bench/stereo.py --scenes d1-clean-2m --timing-only --frames 30   # time by stage
    python bench/stereo.py --budget-sweep --frames 20       # feature budget: stereo_budget.py
    python bench/stereo.py --frames 30 --rerun-busy         # scenes slowed by other work, again
    python bench/stereo.py --scene 'far={"range_m": 4.5, "nutation_deg": 15}' --frames 30
                                      # a scene of your own (StereoScene fields), split "own"

Writes ``runs/bench-stereo/results.json`` (per scene and mode: the stereo-track summary and the
mean time per stage; with ``--frame-rows`` each frame's row too), ``rms_vs_range_rate.png``
(per-axis RMS against range and spin rate),
prints a Markdown table and, last, one JSON line: scenes run, how many meet the targets of
issue 16 (per-axis RMS position <= 5 mm per metre of range, attitude <= 1 deg, no lost frame)
per split, the median wall frame rate (``median_fps``) and CPU seconds a frame
(``median_cpu_s_per_frame``, ``time.process_time`` of the process), a machine yardstick run on
the same frames before and after each scene's tracking, averaged (``median_opencv_yardstick_ms``:
OpenCV's ORB and block matching of a pair, see :func:`yardstick_ms`) and the frame's wall time
over it (``median_frame_over_yardstick``: a figure that moves with the code, not with the
machine, to first order), the scenes whose fps other work on the machine changed
(``scenes_on_a_busy_machine``: their yardstick before and after differs, or it or the frame's
wall over CPU time lies above the run's median, by more than ``BUSY_FACTOR``; a note under the
table names each; with ``--rerun-busy`` each is tracked once more, the faster run kept, and
``scenes_rerun`` has its first and second fps and whether its errors came out the same), the
wall and CPU
milliseconds a frame by stage (``median_stage_ms``, ``median_stage_cpu_ms``; points+lines,
medians over the scenes) and the machine's load average before and after the run.

Targets are checked per scene on the points+lines mode; "lines help" says whether points+lines
is lower than points-only on every axis (asked for the scenes with blur or glints).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from jaxpose.io.software import software_versions  # noqa: E402
from jaxpose.pipelines.stereo import (  # noqa: E402
    STAGES,
    StereoTracker,
    TrackerOptions,
    smooth_sequence,
    track_stream,
)
from jaxpose.studies._plotting import plain_log_labels  # noqa: E402
from jaxpose.studies.stereo_track import summarize  # noqa: E402
from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence  # noqa: E402

OFF_AXIS = (0.3, -0.2, 1.0)

#: name -> (split, StereoScene parameters)
SCENES: dict[str, tuple[str, dict]] = {
    "d1-clean-2m": ("dev", dict(range_m=2.0, rate_deg_s=10.2)),
    "d2-blur-3m-fast": ("dev", dict(range_m=3.0, rate_deg_s=15.0, blur=1.0)),
    "d3-glints-1.5m-10hz": (
        "dev",
        dict(range_m=1.5, rate_deg_s=8.0, frame_rate_hz=10.0, glints=1.5, sun_sweep_deg=60.0),
    ),
    "d4-glints-4m-slow": ("dev", dict(range_m=4.0, rate_deg_s=6.0, glints=1.0, noise_sigma=0.02)),
    "d5-tumble-2.5m": (
        "dev",
        dict(
            range_m=2.5,
            rate_deg_s=12.0,
            frame_rate_hz=10.0,
            spin_axis_body=OFF_AXIS,
            nutation_deg=10.0,
            precession_deg_s=4.0,
        ),
    ),
    "d6-blur-5m-slow": ("dev", dict(range_m=5.0, rate_deg_s=5.0, blur=0.5)),
    "c1-blur1.5-1.8m-20dps-15hz": (
        "check",
        dict(range_m=1.8, rate_deg_s=20.0, frame_rate_hz=15.0, blur=1.5),
    ),
    "c2-glints-blur-3.5m-sweep": (
        "check",
        dict(
            range_m=3.5,
            rate_deg_s=10.0,
            frame_rate_hz=8.0,
            glints=1.5,
            blur=0.5,
            sun_sweep_deg=90.0,
        ),
    ),
    "c3-tumble-2.2m": (
        "check",
        dict(
            range_m=2.2,
            rate_deg_s=14.0,
            spin_axis_body=(-0.4, 0.3, 1.0),
            nutation_deg=15.0,
            precession_deg_s=6.0,
        ),
    ),
    "c4-noise-4.5m-12hz": (
        "check",
        dict(range_m=4.5, rate_deg_s=8.0, frame_rate_hz=12.0, noise_sigma=0.02, glints=0.5),
    ),
    "c5-blur-glints-1.5m-slow": (
        "check",
        dict(range_m=1.5, rate_deg_s=5.0, blur=1.0, glints=1.0),
    ),
    "c6-tumble-3m-fast-sweep": (
        "check",
        dict(
            range_m=3.0,
            rate_deg_s=18.0,
            frame_rate_hz=10.0,
            spin_axis_body=(0.5, 0.5, 1.0),
            nutation_deg=20.0,
            precession_deg_s=5.0,
            sun_sweep_deg=45.0,
        ),
    ),
}

MODES = ("points+lines", "points-only")


def scene_of(name: str, frames: int | None, seed: int) -> StereoScene:
    """The scene ``name``; ``frames=None``: one full turn at its rate and frame rate."""
    params = dict(SCENES[name][1])
    rate, fps = params.get("rate_deg_s", 10.2), params.get("frame_rate_hz", 5.0)
    n = frames if frames is not None else int(np.ceil(360.0 / rate * fps)) + 1
    return StereoScene(frames=n, seed=seed, **params)


def depth_range(scene: StereoScene) -> tuple[float, float]:
    """The depths (m) the bench's trackers search on ``scene``: 0.3 m to three times its range,
    at least 8 m."""
    return (0.3, max(8.0, 3 * scene.range_m))


def tracker_options(items, base: TrackerOptions | None = None) -> TrackerOptions:
    """``base`` (default ``TrackerOptions()``) with the ``NAME=VALUE`` items of ``--option``
    (``features.mu=0.03`` sets a field of a nested option group): the CLI's own
    :func:`jaxpose.commands._common.with_options`, its errors as ``ValueError``."""
    from jaxpose.commands._common import CommandError, with_options

    try:
        return with_options(TrackerOptions() if base is None else base, items)
    except CommandError as err:
        raise ValueError(str(err)) from None


def meets_targets(summary: dict, range_m: float) -> bool:
    """Issue 16's targets on one run: per-axis RMS position <= 5 mm per metre of range,
    attitude <= 1 deg, no lost frame."""
    pos, att = summary["rms_position_mm"], summary["rms_attitude_deg"]
    if pos is None or att is None:
        return False
    return max(pos) <= 5.0 * range_m and max(att) <= 1.0 and summary["lost_frames"] == 0


_YARDSTICK: list = []


def yardstick_ms(left: np.ndarray, right: np.ndarray) -> float:
    """Milliseconds of a fixed OpenCV workload on one stereo pair, the machine's yardstick: ORB
    (2000 keypoints, eight levels) on the left image and block matching of the pair
    (``cv2.StereoBM``, 128 disparities, 15-pixel blocks). The tracker's frame time over this,
    in the same run, compares machines: both are mostly OpenCV and NumPy on the same cores."""
    import cv2

    if not _YARDSTICK:
        _YARDSTICK.extend([cv2.ORB_create(nfeatures=2000), cv2.StereoBM_create(128, 15)])
    orb, bm = _YARDSTICK
    t0 = time.perf_counter()
    orb.detectAndCompute(left, None)
    bm.compute(left, right)
    return 1000.0 * (time.perf_counter() - t0)


def run_scene(
    name: str,
    frames: int | None,
    modes=MODES,
    seed: int = 0,
    options=None,
    *,
    rows=False,
    smooth=False,
    init: str = "truth",
) -> dict:
    """One scene rendered once and tracked in each mode, started at the true first pose or
    (``init="identity"``) without it, errors after aligning the first frame; ``rows``: keep the
    per-frame rows of :func:`~jaxpose.studies.stereo_track.summarize` (features, inliers,
    post-fit RMS, errors);
    ``smooth``: also the points + lines run's poses adjusted all at once after the last frame
    (:func:`~jaxpose.pipelines.stereo.smooth_sequence`, offline), under ``"smoothed"``."""
    if init not in ("truth", "identity"):
        raise ValueError(f"init must be 'truth' or 'identity'; got {init!r}")
    scene = scene_of(name, frames, seed)
    rig = default_rig()
    depth = depth_range(scene)
    trackers, logs = {}, {m: ([], [], []) for m in modes}
    cpu = {m: [] for m in modes}
    # every frame rendered first (rendering excluded from the times; a camera hands the
    # tracker its frames as they come), then each mode tracks them as a stream: the next
    # pair's features extracted while this one is tracked (track_stream)
    t_render = time.perf_counter()
    frames = list(render_sequence(scene, rig))
    render_s = time.perf_counter() - t_render
    # the machine's yardstick on the same frames before and after the tracking, averaged: this
    # machine's speed drifts within minutes, and one side alone lent a scene the speed of the
    # minutes before or after its tracking
    before = [yardstick_ms(fr.left, fr.right) for fr in frames]
    start = frames[0].pose if init == "truth" else None  # None: the identity
    for mode in modes:
        base = TrackerOptions() if options is None else options
        opts = replace(base, use_lines=mode == "points+lines", depth_range_m=depth)
        if smooth and mode == "points+lines":
            opts = replace(opts, keep_history=True)
        trackers[mode] = StereoTracker(rig, start, options=opts)
        results, truths, seconds = logs[mode]
        t0, c0 = time.perf_counter(), time.process_time()
        stream = track_stream(trackers[mode], ((fr.left, fr.right) for fr in frames))
        for fr, res in zip(frames, stream, strict=True):
            t1, c1 = time.perf_counter(), time.process_time()
            seconds.append(t1 - t0)
            cpu[mode].append(c1 - c0)
            results.append(res)
            truths.append(fr.pose)
            t0, c0 = time.perf_counter(), time.process_time()
    after = [yardstick_ms(fr.left, fr.right) for fr in frames]
    yardstick = [0.5 * (a + b) for a, b in zip(before, after, strict=True)]
    split, params = SCENES[name]
    out = {
        "scene": {
            "name": name,
            "split": split,
            **{k: (list(v) if isinstance(v, tuple) else v) for k, v in params.items()},
            "range_m": scene.range_m,
            "rate_deg_s": scene.rate_deg_s,
            "frame_rate_hz": scene.frame_rate_hz,
            "frames": scene.n_frames(),
            "seed": seed,
        },
        "init": init,
        "render_s_per_frame": render_s / scene.n_frames(),
        # frames 0-1 left out, as from the frame rate
        "opencv_yardstick_ms": float(np.mean(yardstick[2:])) if len(yardstick) > 2 else None,
        "opencv_yardstick_ms_before_after": (
            [float(np.mean(before[2:])), float(np.mean(after[2:]))] if len(yardstick) > 2 else None
        ),
    }
    for mode, (results, truths, seconds) in logs.items():
        # frame 0 makes the first keyframe; frame 1 compiles the solver: both left out of timings
        rep = summarize(results, truths, seconds)  # its fps leaves frames 0-1 out
        stage = {k: float(np.mean([r.timings[k] for r in results[2:]])) for k in STAGES}
        if len(results) > 2:  # the features of the next pair, extracted during this one
            stage["features_ahead"] = float(
                np.mean([r.timings.get("features_ahead", 0.0) for r in results[2:]])
            )
        stage_cpu = {k: float(np.mean([r.cpu_timings[k] for r in results[2:]])) for k in STAGES}
        out[mode] = {
            **rep["summary"],
            "meets_targets": meets_targets(rep["summary"], scene.range_m),
            "compile_s": seconds[1] if len(seconds) > 1 else None,
            "keyframes": int(sum(r.keyframe for r in results)),
            "mean_stage_s": stage,
            "mean_stage_cpu_s": stage_cpu,
            "mean_frame_s": float(np.mean(seconds[2:])) if len(seconds) > 2 else None,
            # CPU seconds of this process a frame (all its threads): steadier than wall time on
            # a shared machine, for ratios between versions
            "mean_frame_cpu_s": float(np.mean(cpu[mode][2:])) if len(seconds) > 2 else None,
        }
        if rows:
            out[mode]["rows"] = rep["rows"]
        if smooth and mode == "points+lines":
            out[mode]["smoothed"] = _smoothed(trackers[mode], results, truths, scene.range_m)
    if set(MODES) <= set(modes):
        a, b = out["points+lines"], out["points-only"]
        if a["rms_position_mm"] and b["rms_position_mm"]:
            out["lines_help"] = bool(
                all(x < y for x, y in zip(a["rms_position_mm"], b["rms_position_mm"], strict=True))
                and all(
                    x < y for x, y in zip(a["rms_attitude_deg"], b["rms_attitude_deg"], strict=True)
                )
            )
    return out


def _smoothed(tracker, results, truths, range_m: float) -> dict:
    """Errors of the tracker's sequence adjusted all at once (offline smoothing)."""
    c0 = time.process_time()
    poses = smooth_sequence(tracker)
    cpu = time.process_time() - c0
    res = [replace(r, pose=poses[r.index]) if r.index in poses else r for r in results]
    s = summarize(res, truths, [0.0] * len(res))["summary"]
    return {
        "rms_position_mm": s["rms_position_mm"],
        "rms_attitude_deg": s["rms_attitude_deg"],
        "meets_targets": meets_targets(s, range_m),
        "cpu_s": cpu,
    }


def run_scenes(
    names, frames, modes, seed, options, out: Path, *, rows=False, smooth=False, init="truth"
) -> list[dict]:
    """:func:`run_scene` on each scene in turn, ``out/results.json`` rewritten after each (a run
    cut short keeps what it did) and a progress line on stderr."""
    results = []
    for name in names:
        r = run_scene(
            name, frames, modes, seed=seed, options=options, rows=rows, smooth=smooth, init=init
        )
        results.append(r)
        (out / "results.json").write_text(json.dumps(results, indent=1))
        m = r["points+lines"]
        print(
            f"done {name}: {m['rms_position_mm']} mm, {m['rms_attitude_deg']} deg, "
            f"lost {m['lost_frames']}, targets {m['meets_targets']}, {m['fps']} fps, "
            f"{m['mean_frame_cpu_s']} CPU s a frame",
            file=sys.stderr,
            flush=True,
        )
    return results


def figure(results: list[dict], path: Path) -> None:
    """Per-axis RMS position per metre of range and attitude against range and spin rate."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"x": "tab:blue", "y": "tab:orange", "z": "tab:green"}
    # held-out: bench/stereo_heldout.py; own: --scene
    markers = {"dev": "o", "check": "^", "held-out": "s", "own": "D"}
    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5))
    for r in results:
        m = r.get("points+lines")
        if m is None or m["rms_position_mm"] is None:
            continue
        s = r["scene"]
        for i, a in enumerate("xyz"):
            for col, key in ((0, "range_m"), (1, "rate_deg_s")):
                kw = dict(color=colours[a], marker=markers[s["split"]], ls="none", ms=6)
                axes[0, col].plot(s[key], m["rms_position_mm"][i] / s["range_m"], **kw)
                axes[1, col].plot(s[key], m["rms_attitude_deg"][i], **kw)
    for col, label in ((0, "range (m)"), (1, "spin rate (deg/s)")):
        axes[0, col].axhline(5.0, color="red", lw=0.8, ls="--")
        axes[1, col].axhline(1.0, color="red", lw=0.8, ls="--")
        for row in (0, 1):
            axes[row, col].set_xlabel(label)
            axes[row, col].grid(alpha=0.3)
            axes[row, col].set_yscale("log")
        axes[0, col].set_ylabel("RMS position / range (mm per m)")
        axes[1, col].set_ylabel("RMS attitude (deg)")
    handles = (
        [
            plt.Line2D([], [], color=colours[a], marker="s", ls="none", label=f"{a} / {ang}")
            for a, ang in zip("xyz", ("roll", "pitch", "yaw"), strict=True)
        ]
        + [
            plt.Line2D([], [], color="gray", marker=markers[k], ls="none", label=f"{k} scenes")
            for k in markers
            if any(r["scene"]["split"] == k for r in results)
        ]
        + [plt.Line2D([], [], color="red", ls="--", lw=0.8, label="target")]
    )
    for ax in axes.flat:  # plain numbers on the log axes (0.5, 2, not 5 x 10^-1, 2 x 10^0)
        plain_log_labels(ax.yaxis, ax.get_ylim())
    fig.suptitle("Stereo tracking, points+lines: per-axis RMS per scene", y=0.99)
    fig.legend(handles=handles, loc="upper center", ncol=6, fontsize=8, bbox_to_anchor=(0.5, 0.955))
    fig.tight_layout(rect=(0, 0, 1, 0.91))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table(results: list[dict], modes) -> list[str]:
    lines = [
        "| scene | split | range m | rate deg/s | Hz | mode | lost | RMS position x, y, z (mm) "
        "| RMS attitude r, p, y (deg) | targets | fps |",
        "|" + "---|" * 11,
    ]
    for r in results:
        s = r["scene"]
        for mode in modes:
            m = r[mode]
            pos = ", ".join(f"{v:.1f}" for v in m["rms_position_mm"] or [])
            att = ", ".join(f"{v:.2f}" for v in m["rms_attitude_deg"] or [])
            lines.append(
                f"| {s['name']} | {s['split']} | {s['range_m']:g} | {s['rate_deg_s']:g} | "
                f"{s['frame_rate_hz']:g} | {mode} | {m['lost_frames']} | {pos} | {att} | "
                f"{'yes' if m['meets_targets'] else 'no'} | {m['fps']} |"
            )
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--scenes", nargs="+", default=None, choices=list(SCENES))
    p.add_argument("--split", choices=("dev", "check", "all"), default="all")
    p.add_argument(
        "--scene",
        action="append",
        default=[],
        metavar="NAME=JSON",
        help="a scene of your own, its StereoScene parameters as a JSON object, e.g. "
        """'tumble-4.5m={"range_m": 4.5, "rate_deg_s": 8, "nutation_deg": 15}' (split "own"; """
        "run alone, or with --scenes)",
    )
    p.add_argument("--frames", type=int, default=None, help="frames per scene (default: one turn)")
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed of the rendering")
    p.add_argument("--points-lines-only", action="store_true", help="skip the points-only mode")
    p.add_argument("--timing-only", action="store_true", help="points+lines only, one scene")
    p.add_argument(
        "--budget-sweep",
        action="store_true",
        help="accuracy and pose-stage time against the feature budget N for the dop, random and "
        "response rules (bench/stereo_budget.py) on the selected scenes",
    )
    p.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a TrackerOptions field for every scene (a Python literal), e.g. window_frames=0; "
        "a field of its feature or stereo options as features.mu=0.03, stereo.window=11",
    )
    p.add_argument(
        "--init",
        choices=("truth", "identity"),
        default="truth",
        help="first pose: the rendered truth, or the identity (no ground truth, as a user "
        "starts; errors after aligning the first frame)",
    )
    p.add_argument(
        "--frame-rows",
        action="store_true",
        help="keep each frame's row (features, inliers, post-fit RMS, errors) in results.json",
    )
    p.add_argument(
        "--smooth",
        action="store_true",
        help="also adjust each points+lines run all at once after its last frame (offline "
        "smoothing, smooth_sequence) and report those errors",
    )
    p.add_argument(
        "--rerun-busy",
        action="store_true",
        help="track once more each scene whose fps other work on the machine changed (named "
        "under the table); the table and JSON line then have the faster of its two runs",
    )
    p.add_argument("--out", type=Path, default=Path("runs/bench-stereo"))
    p.add_argument(
        "--from-results",
        nargs="+",
        type=Path,
        default=None,
        help="report on saved results.json files (e.g. the dev and check splits run apart)",
    )
    args = p.parse_args(argv)
    if args.budget_sweep:  # feature budget (issue 17.3): its own bench module and outputs
        from stereo_budget import main as budget_main

        sweep = ["--split", args.split, "--seed", str(args.seed)]
        sweep += ["--scenes", *args.scenes] if args.scenes else []
        sweep += ["--frames", str(args.frames)] if args.frames else []
        return budget_main(sweep)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.from_results:
        results = [r for f in args.from_results for r in json.loads(f.read_text())]
        modes = tuple(m for m in MODES if m in results[0])
        report(results, modes, args.out, results[0]["scene"]["frames"], None)
        return 0
    own = [_own_scene(p, spec) for spec in args.scene]
    names = args.scenes or [n for n, (s, _) in SCENES.items() if args.split in ("all", s)]
    names = [*(args.scenes or []), *own] if own else names
    modes = ("points+lines",) if args.timing_only or args.points_lines_only else MODES
    if args.timing_only:
        names = names[:1]
    load0 = os.getloadavg()
    try:
        options = tracker_options(args.option) if args.option else None
    except ValueError as e:
        p.error(str(e))
    results = run_scenes(
        names,
        args.frames,
        modes,
        args.seed,
        options,
        args.out,
        rows=args.frame_rows,
        smooth=args.smooth,
        init=args.init,
    )
    if args.rerun_busy:
        results = rerun_busy_scenes(results, args, modes, options)
    report(results, modes, args.out, args.frames, load0, timing=args.timing_only)
    return 0


def own_scene_params(spec: str) -> tuple[str, dict]:
    """``NAME=JSON`` (a scene of one's own): its name and ``StereoScene`` fields, checked by the
    scene itself; ``ValueError`` naming what is wrong."""
    name, sep, text = spec.partition("=")
    if not sep or not name or name in SCENES:
        raise ValueError(f"a scene of your own is NAME=JSON with a new name; got {spec!r}")
    try:
        params = json.loads(text)
        if not isinstance(params, dict):
            raise ValueError(f"a JSON object of StereoScene fields, not {type(params).__name__}")
        params = {k: tuple(v) if isinstance(v, list) else v for k, v in params.items()}
        StereoScene(frames=2, **params)  # the scene's own checks
    except (ValueError, TypeError) as e:  # JSONDecodeError is a ValueError
        raise ValueError(f"scene {name}: {e}") from None
    return name, params


def _own_scene(parser, spec: str) -> str:
    """``--scene NAME=JSON``: the scene added to :data:`SCENES` (split ``own``); its name."""
    try:
        name, params = own_scene_params(spec)
    except ValueError as e:
        parser.error(f"--scene: {e}")
    SCENES[name] = ("own", params)
    return name


def _met_by_split(results, run, splits) -> dict:
    """``{split: "met/scenes"}``: how many scenes of each split meet the targets, read from
    ``run(points+lines record)`` (the causal run itself, or its smoothed one)."""
    out = {}
    for split in splits:
        rows = [r for r in results if r["scene"]["split"] == split]
        out[split] = (
            f"{sum(bool(run(r['points+lines'])['meets_targets']) for r in rows)}/{len(rows)}"
        )
    return out


def _smoothed_summary(results) -> dict:
    """Targets met by the smoothed runs per split (``--smooth``; empty without)."""
    rows = [r for r in results if "smoothed" in r["points+lines"]]
    if not rows:
        return {}
    return {
        "smoothed_meets_targets": _met_by_split(
            rows, lambda m: m["smoothed"], sorted({r["scene"]["split"] for r in rows})
        ),
        "smoothed": {
            r["scene"]["name"]: [
                r["points+lines"]["smoothed"]["rms_position_mm"],
                r["points+lines"]["smoothed"]["rms_attitude_deg"],
            ]
            for r in rows
        },
    }


def _rerun_summary(results) -> dict:
    """The scenes tracked again after a busy first run (``--rerun-busy``), their first fps and
    whether their errors came out the same; empty when none was."""
    rows = [r for r in results if r.get("rerun")]
    if not rows:
        return {}
    return {
        "scenes_rerun": {
            r["scene"]["name"]: {
                "first_fps": r["rerun"]["first_fps"].get("points+lines"),
                "second_fps": _second_fps(r),
                "fps": r["points+lines"]["fps"],  # the faster, the run the table has
                "same_errors": r["rerun"]["same_errors"],
            }
            for r in rows
        }
    }


def _stage_medians(results, key: str) -> dict:
    rows = [r["points+lines"].get(key) for r in results]
    rows = [row for row in rows if row]
    if not rows:
        return {}
    return {
        k: round(1000 * float(np.median([row.get(k, 0.0) for row in rows])), 1) for k in rows[0]
    }


def _yardstick_summary(results) -> dict:
    """Medians over the scenes of the OpenCV yardstick (:func:`yardstick_ms`) and of the
    points+lines frame's wall time over it (``1000 / fps / yardstick``); empty for results saved
    before the yardstick."""
    pairs = [
        (r["opencv_yardstick_ms"], r["points+lines"]["fps"])
        for r in results
        if r.get("opencv_yardstick_ms") and r["points+lines"].get("fps")
    ]
    if not pairs:
        return {}
    return {
        "median_opencv_yardstick_ms": round(float(np.median([y for y, _ in pairs])), 2),
        "median_frame_over_yardstick": round(
            float(np.median([1000.0 / f / y for y, f in pairs])), 2
        ),
    }


#: A scene's frame rate is flagged as not its own when the yardstick measured around it changed
#: by more than this factor between before and after, or lies this far above the run's median,
#: or when its frame's wall time over the process's CPU time does.
BUSY_FACTOR = 1.3


def busy_scenes(results, factor: float = BUSY_FACTOR) -> list[dict]:
    """The scenes whose frame rate other work on the machine changed, by two signs: the
    yardstick (:func:`yardstick_ms`) measured before and after the scene differs by more than
    ``factor`` (one over the other) or their mean lies more than ``factor`` above the median over
    the scenes (other work around the tracking); or the frame's wall time over the process's CPU
    time lies more than ``factor`` above the run's median (other work during the tracking: the
    tracker's threads wait for the cores; about 0.6, 0.54-0.76, over the scenes of five draws
    on a 2-core machine where nothing else ran). Each: the scene's name, the two yardsticks (ms)
    and their median, the wall over CPU ratio and its median, and the frame over the yardstick
    (a ratio of the same machine's speed, which the first sign leaves about as it is)."""
    timed = [r for r in results if r.get("opencv_yardstick_ms_before_after")]
    if not timed:
        return []
    median = float(np.median([r["opencv_yardstick_ms"] for r in timed]))

    def wall_over_cpu(r):
        m = r["points+lines"]
        wall, cpu = m.get("mean_frame_s"), m.get("mean_frame_cpu_s")
        return wall / cpu if wall and cpu else None

    ratios = [q for q in map(wall_over_cpu, timed) if q is not None]
    median_ratio = float(np.median(ratios)) if ratios else None
    out = []
    for r in timed:
        before, after = r["opencv_yardstick_ms_before_after"]
        spread = max(before, after) / max(min(before, after), 1e-9)
        q = wall_over_cpu(r)
        waited = q is not None and q > factor * median_ratio
        if spread > factor or r["opencv_yardstick_ms"] > factor * median or waited:
            fps = r["points+lines"].get("fps")
            out.append(
                {
                    "scene": r["scene"]["name"],
                    "yardstick_ms_before_after": [round(before, 1), round(after, 1)],
                    "median_yardstick_ms": round(median, 1),
                    "wall_over_cpu": None if q is None else round(q, 2),
                    "median_wall_over_cpu": None if q is None else round(median_ratio, 2),
                    "frame_over_yardstick": round(1000.0 / fps / r["opencv_yardstick_ms"], 2)
                    if fps
                    else None,
                }
            )
    return out


def busy_notes(busy: list[dict]) -> list[str]:
    """One line for each scene of ``busy`` (:func:`busy_scenes`), for the printed report."""
    notes = []
    for b in busy:
        before, after = b["yardstick_ms_before_after"]
        waited = (
            f", its frame's wall over CPU time {b['wall_over_cpu']:g} against a median of "
            f"{b['median_wall_over_cpu']:g}"
            if b["wall_over_cpu"] is not None
            else ""
        )
        notes.append(
            f"note: {b['scene']} ran while other work shared the machine (yardstick {before:g} "
            f"ms before it, {after:g} after, the run's median {b['median_yardstick_ms']:g}"
            f"{waited}): its fps is not its own; run it again alone"
        )
    return notes


#: What must come out the same when a scene is tracked again (the tracks do not depend on the
#: machine's load: only its times may move).
_ACCURACY_KEYS = ("rms_position_mm", "rms_attitude_deg", "lost_frames", "meets_targets")


def rerun_busy(results: list[dict], rerun, factor: float = BUSY_FACTOR) -> list[dict]:
    """The results with each scene of :func:`busy_scenes` tracked once more (``rerun(name)``:
    a fresh :func:`run_scene` of it) and its record the faster run's in points + lines (other
    work on the machine only slows a run down; the second can be slowed more than the first),
    which keeps under ``"rerun"`` both runs' fps per mode, which run it is (``"kept"``) and
    whether the errors came out the same (they should: only the times move with the machine's
    load). One retry: a scene busy again is named again by the report."""
    busy = {b["scene"] for b in busy_scenes(results, factor)}
    out = []
    for r in results:
        name = r["scene"]["name"]
        if name not in busy:
            out.append(r)
            continue
        again = rerun(name)
        modes = [m for m in MODES if r.get(m) and again.get(m)]
        second = (again["points+lines"]["fps"] or 0) >= (r["points+lines"]["fps"] or 0)
        kept = dict(again if second else r)
        kept["rerun"] = {
            "first_fps": {m: r[m]["fps"] for m in modes},
            "second_fps": {m: again[m]["fps"] for m in modes},
            "kept": "second" if second else "first",
            "same_errors": all(
                r[m].get(k) == again[m].get(k) for m in modes for k in _ACCURACY_KEYS
            ),
        }
        out.append(kept)
    return out


def rerun_busy_scenes(results: list[dict], args, modes, options) -> list[dict]:
    """``--rerun-busy`` of a bench run with the command line ``args`` (``frames``, ``seed``,
    ``frame_rows``, ``smooth``, ``init``, ``out``): :func:`rerun_busy` with a fresh
    :func:`run_scene` of each busy scene; ``out/results.json`` rewritten."""
    results = rerun_busy(
        results,
        lambda name: run_scene(
            name,
            args.frames,
            modes,
            seed=args.seed,
            options=options,
            rows=args.frame_rows,
            smooth=args.smooth,
            init=args.init,
        ),
    )
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    return results


def rerun_notes(results: list[dict]) -> list[str]:
    """One line for each scene that :func:`rerun_busy` tracked again."""
    notes = []
    for r in results:
        info = r.get("rerun")
        if not info:
            continue
        first = info["first_fps"].get("points+lines")
        second = _second_fps(r)
        same = "the errors the same" if info["same_errors"] else "THE ERRORS DIFFER"
        notes.append(
            f"note: {r['scene']['name']} tracked again after a busy first run: "
            f"{first:g} fps first, {second:g} the second time ({same}); the table has "
            + (f"the faster, the {info['kept']} run" if "kept" in info else "the second run")
        )
    return notes


def _second_fps(record: dict) -> float | None:
    """The points + lines fps of a re-tracked scene's second run (results saved before the
    bench kept the faster run have the second run's record and no ``second_fps``)."""
    info = record["rerun"]
    if "second_fps" not in info:
        return record["points+lines"]["fps"]
    return info["second_fps"].get("points+lines")


def machine_report(results: list[dict]) -> tuple[list[str], dict]:
    """What a report says of the machine around each scene: the notes under the table (the
    scenes on a busy machine, :func:`busy_notes`, and those tracked again, :func:`rerun_notes`)
    and the JSON line's fields (``scenes_on_a_busy_machine``, ``scenes_rerun``)."""
    busy = busy_scenes(results)
    fields = {"scenes_on_a_busy_machine": [b["scene"] for b in busy], **_rerun_summary(results)}
    return busy_notes(busy) + rerun_notes(results), fields


_STAGE_LABELS = {
    "features": "features (waited for)",
    "features_ahead": "features extracted ahead, in the worker",
}


def report(results, modes, out: Path, frames, load0, *, timing: bool = False) -> None:
    """Markdown table, figure and the last JSON line of a run (or of saved results)."""
    notes, machine = machine_report(results)
    print("\n".join(table(results, modes) + notes))
    if timing or len(results) == 1:
        m = results[0]["points+lines"]
        cpu = m.get("mean_stage_cpu_s", {})
        print(
            "\n| stage | wall ms a frame | CPU ms a frame |\n|---|---|---|\n"
            + "\n".join(
                f"| {_STAGE_LABELS.get(k, k)} | {1000 * v:.1f} | "
                + (f"{1000 * cpu[k]:.1f} |" if k in cpu else "(in the stages it overlaps) |")
                for k, v in m["mean_stage_s"].items()
            )
        )
    figure(results, out / "rms_vs_range_rate.png")
    fps = [r["points+lines"]["fps"] for r in results if r["points+lines"]["fps"]]
    # the suite's two splits, and the others where present (--scene, held-out draws reported
    # with --from-results)
    splits = ("dev", "check") + tuple(
        k for k in ("own", "held-out") if any(r["scene"]["split"] == k for r in results)
    )
    summary = {
        "scenes": len(results),
        "frames_per_scene": frames,
        "init": sorted({r.get("init", "truth") for r in results}),  # older runs: the truth
        "meets_targets": _met_by_split(results, lambda m: m, splits),
        "lines_help_with_blur_or_glints": [
            r["scene"]["name"]
            for r in results
            if r.get("lines_help") and (r["scene"].get("blur") or r["scene"].get("glints"))
        ],
        "median_fps": float(np.median(fps)) if fps else None,
        **_yardstick_summary(results),
        **machine,
        **_smoothed_summary(results),
        "median_cpu_s_per_frame": float(
            np.median([r["points+lines"]["mean_frame_cpu_s"] for r in results])
        ),
        # per stage, points+lines, median over the scenes: wall and CPU milliseconds a frame
        "median_stage_ms": _stage_medians(results, "mean_stage_s"),
        "median_stage_cpu_ms": _stage_medians(results, "mean_stage_cpu_s"),
        "load_average": None
        if load0 is None
        else [round(x, 2) for x in (*load0, *os.getloadavg())],
        "software": software_versions(),
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    sys.exit(main())
