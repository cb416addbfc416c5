"""``jaxpose stereo-track``: render (or read) a stereo sequence of a tumbling target and track it.

Yang et al. 2024 end to end: :mod:`jaxpose.vision.stereo_render` draws the sequence (two turns at
10.2 deg/s by default, the paper's lab rate), :class:`jaxpose.pipelines.stereo.StereoTracker`
tracks it, and this module writes

* ``trajectory.csv``: per frame the estimated and true target pose in the left camera, the chaser
  position in the target frame (the paper's Figs. 3-4 quantity: the hovering chaser seen from the
  spinning target moves on a circle), status, feature counts and errors;
* ``fig3_position_track.png`` (3-D chaser track, estimate and truth, equal scale),
  ``fig4_position.png`` (per-axis chaser position and its error over time), ``fig5_attitude.png``
  (per-axis attitude and its error);
* ``summary.json`` and, with ``--json``, a last line ``{"frames", "rms_position_mm": [x, y, z],
  "rms_attitude_deg": [r, p, y], "lost_frames", "fps", "start_s"}`` (``null`` for what was not
  measured).

Start: ``--init truth`` (default for a rendered sequence, as the paper initialises) gives the
tracker the true first pose; ``--init identity`` starts without ground truth: the target frame is
the first left camera frame; ``--init monocular`` starts from the monocular initialisation
(:func:`jaxpose.initialise_pose`, Sharma, Ventura, D'Amico 2018) of the first left image with the
rendered target's wireframe model (:func:`jaxpose.vision.stereo_render.tumbler_model`), falling
back to the identity when it finds no full pose (:func:`monocular_start`). Errors are always
reported after aligning the first tracked frame, ``est_k est_0^-1 truth_0`` (a no-op for
``--init truth``); ``summary.json`` also holds the start (``init``) and, for the monocular start
with a truth, its own error before the alignment.

Errors: position ``c_est - c_true`` with ``c = -R^T t`` (chaser in target axes, mm); attitude the
``XYZ`` Euler angles (roll, pitch, yaw) of ``R_est R_true^T`` (deg). RMS over tracked frames
(lost frames are counted apart). ``fps`` counts tracking only (rendering excluded), from the
third frame on: frame 0 starts the map and frame 1 compiles the pose solver, one-off costs whose
seconds together are ``start_s`` (with fewer than four frames, from the second frame on).

``--images DIR`` reads a stereo folder (layout in :mod:`jaxpose.studies._stereo_folder`:
``calibration.json``, ``left/*.png``, ``right/*.png``, optional ``poses.csv``); the pairs are
rectified with OpenCV, the tracker starts at the identity and errors are computed only when
``poses.csv`` is given.
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np

from jaxpose.io.software import software_versions

__all__ = [
    "MAX_FRAMES",
    "add_arguments",
    "monocular_start",
    "run",
    "summarize",
    "track_sequence",
    "write_outputs",
]

#: Most frames a run may plan (two turns at a very slow spin would never finish).
MAX_FRAMES = 20000

_RENDER_DEFAULTS = {
    "rate_deg_s": 10.2,
    "range_m": 2.0,
    "blur": 0.0,
    "glints": 0.0,
    "seed": 0,
    "image_size": (1024, 768),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from jaxpose.commands._common import (
        add_figures_argument,
        add_image_size_argument,
        add_option_argument,
        add_out_argument,
        add_progress_argument,
        finite_float,
        nonnegative_float,
        nonnegative_int,
        positive_float,
        positive_int,
    )

    d = _RENDER_DEFAULTS
    parser.add_argument(
        "--frames",
        type=positive_int,
        default=None,
        help=f"frames to track, 2 to {MAX_FRAMES} (default: two full turns; with --images: all "
        "pairs, else the first N)",
    )
    parser.add_argument(
        "--rate-deg-s",
        type=finite_float,
        default=d["rate_deg_s"],
        help=f"spin rate of the rendered target, deg/s; two turns must fit in {MAX_FRAMES} frames",
    )
    parser.add_argument(
        "--range-m",
        type=positive_float,
        default=d["range_m"],
        help="chaser-target range of the rendering, m, above 0.5",
    )
    parser.add_argument(
        "--blur",
        type=nonnegative_float,
        default=d["blur"],
        help="motion blur of the rendering: exposure / frame interval, 0 to 1.5",
    )
    parser.add_argument(
        "--glints",
        type=nonnegative_float,
        default=d["glints"],
        help="specular glint strength of the rendering (0: none, 1.5: strong)",
    )
    parser.add_argument(
        "--frame-rate-hz", type=positive_float, default=5.0, help="camera frame rate, Hz"
    )
    parser.add_argument(
        "--seed", type=nonnegative_int, default=d["seed"], help="sensor-noise seed of the rendering"
    )
    add_image_size_argument(parser, d["image_size"], help="rendered image size, pixels")
    parser.add_argument(
        "--init",
        choices=("truth", "identity", "monocular"),
        default=None,
        help="first pose: the rendered truth, the identity (target frame = first left camera "
        "frame), or the monocular initialisation of the first left image with the rendered "
        "target's model; errors after aligning the first frame (default: truth; identity with "
        "--images)",
    )
    parser.add_argument(
        "--points-only",
        action="store_true",
        help="track with ORB points only (the paper's comparison)",
    )
    parser.add_argument(
        "--images",
        type=Path,
        default=None,
        help="a stereo folder: calibration.json, left/*.png, right/*.png, optional poses.csv "
        "(default: render a sequence)",
    )
    parser.add_argument(
        "--feature-budget",
        type=positive_int,
        default=None,
        help="solve each frame's pose on at most N of the matched points and lines, at least 4 "
        "(default: all)",
    )
    parser.add_argument(
        "--budget-rule",
        choices=("dop", "random", "response"),
        default=None,
        help="which N features of --feature-budget: lowest DOP at the predicted pose, random, or "
        "strongest detector response (default: dop)",
    )
    add_option_argument(
        parser, "TrackerOptions (jaxpose.pipelines.stereo)", "stereo.line_trim_px=1.5"
    )
    add_out_argument(parser, "stereo-track", "trajectory, figures and summary")
    add_figures_argument(parser)
    add_progress_argument(parser)
    parser.add_argument(
        "--json", action="store_true", help="print the summary as a JSON last line on stdout"
    )


def _euler_deg(R: np.ndarray) -> np.ndarray:
    from jaxpose.core.geometry import dcm_to_euler

    return np.degrees(np.asarray(dcm_to_euler(R)))


def track_sequence(
    frames,
    rig,
    *,
    use_lines: bool = True,
    initial_pose=None,
    options=None,
    progress=None,
    prefetch: bool = True,
):
    """Track an iterable of frames (objects with ``left``, ``right``, optional ``pose``).

    ``initial_pose``: the tracker's first pose (``None``: the first frame's ``pose``, the truth
    of a rendered sequence, or the identity when it has none), or a function of the first frame
    that returns it (e.g. :func:`monocular_start`). ``prefetch``: the next frame's features
    extracted while this one is tracked (:func:`~jaxpose.pipelines.stereo.track_stream`; the
    same poses). Returns ``(results, truths, seconds)``: the
    :class:`~jaxpose.pipelines.stereo.FrameResult` of each frame, the true poses (``None`` where
    unknown) and the tracking time of each frame (wall seconds from one result to the next,
    less the time ``frames`` took to produce the next frame: rendering or reading excluded).
    """
    from jaxpose.pipelines.stereo import StereoTracker, TrackerOptions, track_stream

    options = TrackerOptions(use_lines=use_lines) if options is None else options
    it = iter(frames)
    first = next(it, None)
    if first is None:
        return [], [], []
    start = initial_pose(first) if callable(initial_pose) else initial_pose
    truth0 = getattr(first, "pose", None)
    tracker = StereoTracker(rig, truth0 if start is None else start, options=options)
    results, truths, seconds = [], [], []
    reading = [0.0]  # seconds spent producing frames

    def pairs():
        fr = first
        while fr is not None:
            truths.append(getattr(fr, "pose", None))
            yield fr.left, fr.right
            t0 = time.perf_counter()
            fr = next(it, None)
            reading[0] += time.perf_counter() - t0

    t, r = time.perf_counter(), 0.0
    for res in track_stream(tracker, pairs(), prefetch=prefetch):
        now = time.perf_counter()
        seconds.append(now - t - (reading[0] - r))
        t, r = now, reading[0]
        results.append(res)
        if progress is not None:
            progress.update(1)
    return results, truths, seconds


def monocular_start(image, rig, model, *, info: dict | None = None):
    """The tracker's first pose from one left image without ground truth: the monocular
    initialisation (:func:`jaxpose.initialise_pose`) with the target's wireframe ``model`` and the
    rig's left camera. When it finds no full pose (confidence ``"none"`` or ``"position-only"``)
    the start is the identity (the target frame is then the first left camera frame). ``info``,
    when given, receives ``init``, ``confidence`` and ``message``."""
    from jaxpose import initialise_pose
    from jaxpose.core.geometry import Pose

    res = initialise_pose(np.asarray(image), rig.left, model)
    found = res.pose is not None and res.confidence in ("high", "low")
    if info is not None:
        info.update(
            init="monocular" if found else "identity (the monocular initialisation found no pose)",
            confidence=res.confidence,
            message=res.message,
        )
    if not found:
        return Pose.identity()
    return Pose(np.asarray(res.pose.R, float), np.asarray(res.pose.t, float))


def _start_error(start, truth) -> dict:
    """Attitude (deg) and position (mm, target origin in the camera) error of a first pose."""
    from jaxpose.core.geometry import rotation_angle

    R, t = np.asarray(start.R, float), np.asarray(start.t, float)
    Rt, tt = np.asarray(truth.R, float), np.asarray(truth.t, float)
    return {
        "start_attitude_error_deg": float(np.degrees(rotation_angle(R, Rt))),
        "start_position_error_mm": float(1000 * np.linalg.norm(t - tt)),
    }


def _alignment(results, truths):
    """``est_j^-1 truth_j`` of the first tracked frame ``j`` with a truth (module docstring):
    right-multiplied to every estimate, it maps the tracker's target frame onto the true one."""
    from jaxpose.core.geometry import Pose
    from jaxpose.core.status import Status

    for res, truth in zip(results, truths, strict=True):
        if truth is not None and res.status == Status.OK:
            est = Pose(res.R, res.t)
            return est.inverse() @ Pose(np.asarray(truth.R, float), np.asarray(truth.t, float))
    return None


_START_FRAMES = 2  # frames left out of the frame rate: the map's start and the solver's compilation


def summarize(results, truths, seconds) -> dict:
    """Per-axis RMS errors after aligning the first tracked frame, lost frames and frame rate
    (module docstring), plus per-frame rows. Values not measured (no truth, one frame) are
    ``None``."""
    from jaxpose.core.geometry import Pose
    from jaxpose.core.status import Status

    align = _alignment(results, truths)
    rows, pos_err, att_err = [], [], []
    for res, truth in zip(results, truths, strict=True):
        row = {
            "frame": res.index,
            "status": int(res.status),
            "keyframe": int(res.keyframe),
            "n_points": res.n_points,
            "n_lines": res.n_lines,
            "inliers": res.inliers,
            "rms_px": res.rms_px,
        }
        ok = res.status == Status.OK
        R_est, t_est = res.R, res.t
        if ok and align is not None:
            aligned = Pose(R_est, t_est) @ align
            R_est, t_est = np.asarray(aligned.R, float), np.asarray(aligned.t, float)
        c_est = -R_est.T @ t_est if ok else np.full(3, np.nan)
        row.update({f"t_est_{a}": v for a, v in zip("xyz", t_est, strict=True)})
        row.update({f"chaser_est_{a}": v for a, v in zip("xyz", c_est, strict=True)})
        row.update(
            {
                f"euler_est_{a}_deg": v
                for a, v in zip("xyz", _euler_deg(R_est) if ok else [np.nan] * 3, strict=True)
            }
        )
        if truth is not None:
            Rt, tt = np.asarray(truth.R), np.asarray(truth.t)
            c_true = -Rt.T @ tt
            row.update({f"t_true_{a}": v for a, v in zip("xyz", tt, strict=True)})
            row.update({f"chaser_true_{a}": v for a, v in zip("xyz", c_true, strict=True)})
            row.update(
                {f"euler_true_{a}_deg": v for a, v in zip("xyz", _euler_deg(Rt), strict=True)}
            )
            if ok:
                e_pos = (c_est - c_true) * 1000.0
                e_att = _euler_deg(R_est @ Rt.T)
                pos_err.append(e_pos)
                att_err.append(e_att)
            else:
                e_pos = e_att = np.full(3, np.nan)
            row.update({f"err_pos_{a}_mm": v for a, v in zip("xyz", e_pos, strict=True)})
            row.update({f"err_att_{a}_deg": v for a, v in zip("xyz", e_att, strict=True)})
        rows.append(row)

    def rms(e, digits):
        if not len(e):
            return None
        return [round(float(x), digits) for x in np.sqrt(np.mean(np.square(e), axis=0))]

    # the steady rate: frame 0 starts the map and frame 1 compiles the pose solver (one-off
    # costs, reported apart as start_s); with fewer than 4 frames, every frame after the first
    skip = _START_FRAMES if len(seconds) > _START_FRAMES + 1 else min(1, len(seconds))
    steady = seconds[skip:]
    total = float(np.sum(steady))
    summary = {
        "frames": len(results),
        "rms_position_mm": rms(pos_err, 3),
        "rms_attitude_deg": rms(att_err, 4),
        "lost_frames": int(sum(r.status != Status.OK for r in results)),
        "fps": round(len(steady) / total, 2) if total > 0 else None,
        "start_s": round(float(np.sum(seconds[:skip])), 3) if skip else None,
    }
    return {"summary": summary, "rows": rows}


def write_outputs(report: dict, out, dt: float, title: str, *, figures: bool = True) -> None:
    """Write a :func:`summarize` report to the folder ``out``: ``trajectory.csv`` (one row a
    frame) and, with ``figures``, the paper's Figs. 3-5 (``fig3_position_track.png``,
    ``fig4_position.png``, ``fig5_attitude.png``); ``dt`` is the frame interval in seconds,
    ``title`` names the mode in the figures."""
    from jaxpose.studies._stereo_figures import write_figures

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    _write_csv(report["rows"], out / "trajectory.csv")
    if figures:
        write_figures(report["rows"], out, dt, title)


def _write_csv(rows, path: Path) -> None:
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})


def _rendered(args):
    """Scene, rig and frames of a rendered run; ``ValueError`` naming the option."""
    from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence

    d = {k: getattr(args, k) for k in _RENDER_DEFAULTS}
    if d["range_m"] <= 0.5:
        raise ValueError(
            f"--range-m must exceed 0.5 m (the target is 1 m across); got {d['range_m']}"
        )
    if d["blur"] > 1.5:
        raise ValueError(f"--blur must be in [0, 1.5] (exposure / frame interval); got {d['blur']}")
    if args.frames is None:
        if d["rate_deg_s"] == 0:
            raise ValueError("--rate-deg-s 0 never completes two turns; set --frames")
        planned = 720.0 / abs(d["rate_deg_s"]) * args.frame_rate_hz + 1
        if planned > MAX_FRAMES:
            raise ValueError(
                f"two turns at --rate-deg-s {d['rate_deg_s']} and --frame-rate-hz "
                f"{args.frame_rate_hz} are {planned:.3g} frames, over the limit of {MAX_FRAMES}; "
                f"raise --rate-deg-s, lower --frame-rate-hz or set --frames"
            )
    scene = StereoScene(
        rate_deg_s=d["rate_deg_s"],
        range_m=d["range_m"],
        frame_rate_hz=args.frame_rate_hz,
        frames=args.frames,
        blur=d["blur"],
        glints=d["glints"],
        seed=d["seed"],
    )
    rig = default_rig(*d["image_size"])
    return rig, render_sequence(scene, rig), scene.n_frames(), d["range_m"]


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from jaxpose.commands._common import with_options
    from jaxpose.core.geometry import Pose
    from jaxpose.pipelines.stereo import TrackerOptions

    if args.frames is not None and not 2 <= args.frames <= MAX_FRAMES:
        raise ValueError(f"--frames must be between 2 and {MAX_FRAMES}; got {args.frames}")
    if args.feature_budget is not None and args.feature_budget < 4:
        raise ValueError(f"--feature-budget must be at least 4; got {args.feature_budget}")
    w, h = args.image_size
    if w < 64 or h < 48:
        raise ValueError(f"--image-size must be at least 64x48; got {w}x{h}")
    use_lines = not args.points_only
    asked = with_options(
        TrackerOptions(use_lines=use_lines, feature_budget=args.feature_budget), args.option
    )
    if asked.use_lines != use_lines:
        raise ValueError("set use_lines with --points-only, not with --option")  # before rendering
    if args.budget_rule is not None and asked.feature_budget is None:
        # without a budget every matched feature is used and no rule chooses
        raise ValueError(f"--budget-rule {args.budget_rule} needs --feature-budget N")
    dt = 1.0 / args.frame_rate_hz
    if args.images is not None:
        given = [
            "--" + k.replace("_", "-")
            for k, v in _RENDER_DEFAULTS.items()
            if tuple(np.atleast_1d(getattr(args, k))) != tuple(np.atleast_1d(v))
        ]
        if given:
            raise ValueError(
                f"{', '.join(given)} set the rendering and do not apply to --images; leave "
                f"{'it' if len(given) == 1 else 'them'} out"
            )
        if args.init in ("truth", "monocular"):
            raise ValueError(
                f"--init {args.init} needs a rendered sequence (the monocular start needs the "
                "target's wireframe model, which a stereo folder does not carry); --images starts "
                "at the identity"
            )
        from jaxpose.studies._stereo_folder import open_stereo_folder

        folder = open_stereo_folder(args.images)
        if args.frames is not None and args.frames > len(folder):
            raise ValueError(
                f"--frames {args.frames}: {args.images} holds {len(folder)} stereo pairs"
            )
        rig, n = folder.rig, len(folder) if args.frames is None else args.frames
        frames = folder.frames(n)
        initial, range_m = Pose.identity(), 2.0
    else:
        rig, frames, n, range_m = _rendered(args)
        initial = Pose.identity() if args.init == "identity" else None
        if args.init == "monocular":
            from jaxpose.vision.stereo_render import tumbler_model

            model = tumbler_model()

            def initial(frame):
                pose = monocular_start(frame.left, rig, model, info=start_info)
                start_info.update(_start_error(pose, frame.pose))
                return pose

    start_info = {"init": args.init or ("identity" if args.images is not None else "truth")}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    opts = TrackerOptions(
        use_lines=use_lines,
        depth_range_m=(0.3, max(8.0, 3 * range_m)),
        feature_budget=args.feature_budget,
        budget_rule=args.budget_rule or "dop",
    )
    opts = with_options(opts, args.option)
    with tqdm(total=n, disable=args.no_progress, desc="stereo-track", unit="frame") as bar:
        results, truths, seconds = track_sequence(
            frames, rig, use_lines=use_lines, initial_pose=initial, options=opts, progress=bar
        )
    report = summarize(results, truths, seconds)
    mode = "points+lines" if use_lines else "points only"
    write_outputs(report, out, dt, mode, figures=not args.no_figures)
    tracked = results[1:] or results
    stage = {
        k: float(np.mean([r.timings.get(k, 0.0) for r in tracked])) for k in results[0].timings
    }
    s = report["summary"]
    (out / "summary.json").write_text(
        json.dumps(
            {
                **s,
                "mean_stage_s": stage,
                "mode": mode.replace(" ", "-"),
                "start": start_info,
                "software": software_versions(),
            },
            indent=1,
        )
    )
    if args.json:
        print(json.dumps(s))
    else:
        print(
            f"{s['frames']} frames, lost {s['lost_frames']}, "
            f"RMS position (mm) {s['rms_position_mm']}, RMS attitude (deg) "
            f"{s['rms_attitude_deg']}, {s['fps']} fps (tracking only); wrote {out}"
        )
    return 0
