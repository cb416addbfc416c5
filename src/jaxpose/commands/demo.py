"""``jaxpose demo``: the main jobs on embedded defaults, no files needed, with a short report.

Sections (each writes its figures under ``--out``):

1. DOP and feature selection (Ning et al. 2018): a small Monte Carlo selection study, quasi-optimal
   against the exhaustive optimum, with the ratio histograms of the paper's Fig. 6.
2. Monocular pose initialisation (Sharma, Ventura, D'Amico 2018): a rendered Tango image, its pose
   from no prior, the overlay of the detected edges and the projected model.
3. Stereo point-line tracking (Yang, Kang, Yuan, Qiu): a short rendered stereo sequence of the
   tumbling target (10.2 deg/s at 2 m), tracked with points and lines; per-axis RMS errors and
   the figures of ``jaxpose stereo-track`` (which runs the full two turns).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from jaxpose.commands._common import (
    CommandError,
    add_out_argument,
    add_progress_argument,
    nonnegative_int,
    positive_int,
    progress,
    stage,
)

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_out_argument(parser, "demo", "report and figures")
    parser.add_argument(
        "--cases", type=positive_int, default=100, help="cases per group of the selection study"
    )
    parser.add_argument(
        "--seed", type=nonnegative_int, default=0, help="seed of the selection and stereo sections"
    )
    parser.add_argument(
        "--stereo-frames",
        type=nonnegative_int,
        default=25,
        help="frames of the stereo section at 5 Hz (0 skips it)",
    )
    add_progress_argument(parser)


def _selection(out: Path, cases: int, seed: int, show: bool) -> list[str]:
    from jaxpose.studies.selection import Scenario, run_study, write_outputs

    t0 = time.perf_counter()
    result = run_study(
        Scenario(),
        [(12, 8), (14, 8), (16, 8)],
        cases=cases,
        seed=seed,
        progress=show,
        progress_desc="demo 1/3: selection study",
    )
    paths = write_outputs(result, out / "selection")
    lines = [
        "1. DOP and feature selection (Ning et al. 2018): quasi-optimal vs exhaustive optimum",
        f"   scenario: 1 m plane at {Scenario().range_m:g} m, "
        f"attitude {Scenario().attitude_deg} deg, {cases} cases per group",
        "      n  m  mean PDOP ratio  max   mean ADOP ratio  max   time per case: optimal  quasi",
    ]
    for g in result.results["groups"]:
        pdop, adop, tm = g["pdop_ratio"], g["adop_ratio"], g["time_s"]
        lines.append(
            f"     {g['n']:2d} {g['m']:2d}      {pdop['mean']:.4f}     {pdop['max']:.3f}"
            f"      {adop['mean']:.4f}     {adop['max']:.3f}"
            f"        {tm['optimal_per_case'] * 1e3:8.3f} ms {tm['quasi_per_case'] * 1e6:6.1f} us"
        )
    lines.append(
        "   (times batched over the cases; bench/selection.py measures the speed-ups properly)"
    )
    pngs = ", ".join(p.name for p in paths if p.suffix == ".png")
    lines.append(f"   figures: {pngs} in {out / 'selection'}")
    lines.append(f"   ({time.perf_counter() - t0:.1f} s including compilation)")
    return lines


def _monocular(out: Path, show: bool) -> list[str]:
    from jaxpose.pipelines.monocular import demo_report

    t0 = time.perf_counter()
    # One pipeline call: minutes of compilation the first time, seconds from the cache after.
    with stage("demo 2/3: monocular initialisation", enabled=show):
        r = demo_report(out / "monocular")
    lines = ["2. Monocular pose initialisation (Sharma et al. 2018) on a rendered Tango image"]
    lines.append(
        f"   confidence: {r['confidence']}, reprojection error: "
        + ("-" if r["reprojection_error_px"] is None else f"{r['reprojection_error_px']:.2f} px")
    )
    if r.get("coarse_range_m") is not None:
        lines.append(
            f"   range: true {r['range_true_m']:.2f} m, coarse (ROI) {r['coarse_range_m']:.2f} m"
        )
    if "translation_error_m" in r:
        lines.append(
            f"   pose error: {r['translation_error_m'] * 100:.1f} cm, "
            f"{r['rotation_error_deg']:.2f} deg; "
            f"success: {r['success']}; ESA score {r['esa_score']:.4f}"
        )
    lines.append(f"   overlay: {r['overlay']}")
    lines.append(
        f"   ({time.perf_counter() - t0:.1f} s including compilation; "
        f"pipeline {r['runtime_s']:.2f} s)"
    )
    return lines


def _stereo(out: Path, frames: int, seed: int, show: bool) -> list[str]:
    from jaxpose.pipelines.stereo import TrackerOptions
    from jaxpose.studies.stereo_track import summarize, track_sequence, write_outputs
    from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence

    t0 = time.perf_counter()
    scene = StereoScene(frames=frames, seed=seed)
    rig = default_rig(1024, 768)
    with progress(
        total=frames, desc="demo 3/3: stereo tracking", unit="frame", enabled=show
    ) as bar:
        results, truths, seconds = track_sequence(
            render_sequence(scene, rig), rig, options=TrackerOptions(use_lines=True), progress=bar
        )
    report = summarize(results, truths, seconds)
    folder = out / "stereo"
    write_outputs(report, folder, 1.0 / scene.frame_rate_hz, "points+lines")
    s = report["summary"]
    turn = scene.rate_deg_s * (frames - 1) / scene.frame_rate_hz
    return [
        "3. Stereo point-line tracking (Yang et al.) of a tumbling target, rendered 1024x768 pairs",
        f"   {frames} frames at {scene.frame_rate_hz:g} Hz, {scene.rate_deg_s:g} deg/s "
        f"({turn:.0f} deg of spin), range {scene.range_m:g} m; first pose from ground truth",
        f"   lost frames: {s['lost_frames']}; RMS position error (x, y, z): "
        + ", ".join(f"{v:.1f}" for v in s["rms_position_mm"])
        + " mm; RMS attitude error: "
        + ", ".join(f"{v:.2f}" for v in s["rms_attitude_deg"])
        + " deg",
        f"   tracking {s['fps']} frames/s; trajectory.csv and figures in {folder}",
        f"   ({time.perf_counter() - t0:.1f} s including rendering and compilation; "
        "jaxpose stereo-track runs the paper's two turns)",
    ]


def run(args) -> int:
    if args.stereo_frames == 1:  # before a minute of other sections
        raise CommandError(f"--stereo-frames must be 0 or at least 2; got {args.stereo_frames}")
    show = not args.no_progress
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    report = ["jaxpose demo", ""]
    report += _selection(out, args.cases, args.seed, show)
    report += [""] + _monocular(out, show)
    if args.stereo_frames:
        report += [""] + _stereo(out, args.stereo_frames, args.seed, show)
    text = "\n".join(report)
    (out / "report.txt").write_text(text + "\n")
    print(text)
    return 0
