"""Stereo tracking benchmark: accuracy of points+lines vs points-only, and time by stage.

Renders each scene once and feeds every frame to two trackers (points+lines and points-only), so
both modes see identical images; rendering is timed apart and excluded from the frame rate.

    python bench/stereo.py                      # the README table: 2 ranges x {clean, blur+glints}
    python bench/stereo.py --frames 60 --scenes clean@2   # a quick look
    python bench/stereo.py --timing-only --frames 30      # time by stage at 1024x768

Writes ``runs/bench-stereo/results.json`` (per scene and mode: the stereo-track summary and the
mean time per stage) and prints a Markdown table. The first tracked frame of each tracker
includes JIT compilation; it is reported as ``compile_s`` and left out of the stage means and fps.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from jaxpose.pipelines.stereo import STAGES, StereoTracker, TrackerOptions  # noqa: E402
from jaxpose.studies.stereo_track import summarize  # noqa: E402
from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence  # noqa: E402

SCENES = {
    "clean@2": dict(range_m=2.0),
    "blur+glints@2": dict(range_m=2.0, blur=1.0, glints=1.5),
    "clean@3": dict(range_m=3.0),
    "blur+glints@3": dict(range_m=3.0, blur=1.0, glints=1.5),
}


def run_scene(
    name: str,
    frames: int | None,
    frame_rate_hz: float,
    modes=("points+lines", "points-only"),
    seed: int = 0,
):
    scene = StereoScene(frames=frames, frame_rate_hz=frame_rate_hz, seed=seed, **SCENES[name])
    rig = default_rig()
    trackers, logs = {}, {m: ([], [], []) for m in modes}
    render_s = 0.0
    t_render = time.perf_counter()
    for fr in render_sequence(scene, rig):
        render_s += time.perf_counter() - t_render
        for mode in modes:
            if mode not in trackers:
                opts = TrackerOptions(use_lines=mode == "points+lines")
                trackers[mode] = StereoTracker(rig, fr.pose, options=opts)
            t0 = time.perf_counter()
            res = trackers[mode].process(fr.left, fr.right)
            results, truths, seconds = logs[mode]
            seconds.append(time.perf_counter() - t0)
            results.append(res)
            truths.append(fr.pose)
        t_render = time.perf_counter()
    out = {
        "scene": {
            "name": name,
            **SCENES[name],
            "frames": scene.n_frames(),
            "frame_rate_hz": frame_rate_hz,
            "rate_deg_s": scene.rate_deg_s,
            "seed": seed,
        },
        "render_s_per_frame": render_s / scene.n_frames(),
    }
    for mode, (results, truths, seconds) in logs.items():
        # frame 0 makes the first keyframe; frame 1 compiles the solver: both left out of timings
        rep = summarize(results, truths, [0.0] + seconds[2:] if len(seconds) > 2 else seconds)
        stage = {k: float(np.mean([r.timings[k] for r in results[2:]])) for k in STAGES}
        out[mode] = {
            **rep["summary"],
            "compile_s": seconds[1] if len(seconds) > 1 else float("nan"),
            "keyframes": int(sum(r.keyframe for r in results)),
            "mean_stage_s": stage,
            "mean_frame_s": float(np.mean(seconds[2:])) if len(seconds) > 2 else float("nan"),
        }
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    p.add_argument("--frames", type=int, default=None, help="frames per scene (default: two turns)")
    p.add_argument("--frame-rate-hz", type=float, default=5.0)
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed of the rendering")
    p.add_argument("--timing-only", action="store_true", help="points+lines only, one scene")
    p.add_argument("--out", type=Path, default=Path("runs/bench-stereo"))
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    modes = ("points+lines",) if args.timing_only else ("points+lines", "points-only")
    scenes = args.scenes[:1] if args.timing_only else args.scenes
    results = []
    for name in scenes:
        r = run_scene(name, args.frames, args.frame_rate_hz, modes, seed=args.seed)
        results.append(r)
        (args.out / "results.json").write_text(json.dumps(results, indent=1))
        print(f"done {name}", file=sys.stderr, flush=True)
    print(
        "| scene | mode | frames | lost | RMS position x, y, z (mm) "
        "| RMS attitude r, p, y (deg) | fps | " + " | ".join(f"{s} (ms)" for s in STAGES) + " |"
    )
    print("|" + "---|" * (7 + len(STAGES)))
    for r in results:
        for mode in modes:
            m = r[mode]
            pos = ", ".join(f"{v:.1f}" for v in m["rms_position_mm"])
            att = ", ".join(f"{v:.2f}" for v in m["rms_attitude_deg"])
            stages = " | ".join(f"{1000 * m['mean_stage_s'][s]:.0f}" for s in STAGES)
            print(
                f"| {r['scene']['name']} | {mode} | {m['frames']} | {m['lost_frames']} "
                f"| {pos} | {att} | "
                f"{m['fps']} | {stages} |"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
