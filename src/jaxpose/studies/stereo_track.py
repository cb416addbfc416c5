"""``jaxpose stereo-track``: render (or read) a stereo sequence of a tumbling target and track it.

Yang et al. 2024 end to end: :mod:`jaxpose.vision.stereo_render` draws the sequence
(two turns at 10.2 deg/s by default, the paper's lab rate), :class:`jaxpose.pipelines.stereo.
StereoTracker` tracks it, and this module writes

* ``trajectory.csv``: per frame the estimated and true target pose in the left camera, the chaser
  position in the target frame (the paper's Figs. 3-4 quantity: the hovering chaser seen from the
  spinning target moves on a circle), status, feature counts and errors;
* ``fig3_position_track.png`` (3-D chaser track, estimate vs truth), ``fig4_position.png``
  (per-axis chaser position and its error over time), ``fig5_attitude.png`` (per-axis attitude
  and its error);
* with ``--json``, a last line ``{"frames", "rms_position_mm": [x, y, z], "rms_attitude_deg":
  [r, p, y], "lost_frames", "fps"}``.

Errors: position ``c_est - c_true`` with ``c = -R^T t`` (chaser in target axes, mm); attitude the
``xyz`` Euler angles (roll, pitch, yaw) of ``R_est R_true^T`` (deg). RMS over tracked frames
(lost frames are counted apart). ``fps`` counts tracking only (rendering excluded).

``--images DIR`` reads ``DIR/left/*.png`` and ``DIR/right/*.png`` (sorted, paired) and
``DIR/calibration.json`` (``{"left": camera, "right": camera, "R_rl": 3x3, "t_rl": [3]}``, cameras
in the ``camera.json`` layout of :func:`jaxpose.io.load_camera`); the pair is rectified with
OpenCV when needed, the first frame defines the target frame (identity pose) and no errors are
computed.
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np

__all__ = ["add_arguments", "run", "track_sequence", "summarize", "write_outputs"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--frames", type=int, default=None, help="frames to render (default: two full turns)"
    )
    parser.add_argument(
        "--rate-deg-s", type=float, default=10.2, help="spin rate, deg/s (default 10.2)"
    )
    parser.add_argument(
        "--range-m", type=float, default=2.0, help="chaser-target range, m (default 2)"
    )
    parser.add_argument(
        "--blur", type=float, default=0.0, help="motion blur: exposure / frame interval (0..1)"
    )
    parser.add_argument(
        "--glints", type=float, default=0.0, help="specular glint strength (0: none; 1.5 strong)"
    )
    parser.add_argument(
        "--frame-rate-hz", type=float, default=5.0, help="camera frame rate (default 5)"
    )
    parser.add_argument("--seed", type=int, default=0, help="noise seed")
    parser.add_argument(
        "--image-size", default="1024x768", help="rendered image size WxH (default 1024x768)"
    )
    parser.add_argument("--points-only", action="store_true", help="track with ORB points only")
    parser.add_argument(
        "--images", type=Path, default=None, help="folder with left/, right/ and calibration.json"
    )
    parser.add_argument("--out", type=Path, default=Path("runs/stereo-track"), help="output folder")
    parser.add_argument("--no-figures", action="store_true", help="skip the figures")
    parser.add_argument("--json", action="store_true", help="print the summary as a JSON last line")


def _euler_deg(R: np.ndarray) -> np.ndarray:
    from jaxpose.core.geometry import dcm_to_euler

    return np.degrees(np.asarray(dcm_to_euler(R)))


def track_sequence(
    frames, rig, *, use_lines: bool = True, initial_pose=None, options=None, progress=None
):
    """Track an iterable of frames (objects with ``left``, ``right``, optional ``pose``, ``roi``).

    Returns ``(results, truths, seconds)``: the :class:`~jaxpose.pipelines.stereo.FrameResult` of
    each frame, the true poses (``None`` where unknown) and the tracking time of each frame.
    """
    from jaxpose.pipelines.stereo import StereoTracker, TrackerOptions

    options = TrackerOptions(use_lines=use_lines) if options is None else options
    tracker, results, truths, seconds = None, [], [], []
    for fr in frames:
        truth = getattr(fr, "pose", None)
        if tracker is None:
            tracker = StereoTracker(
                rig, truth if initial_pose is None else initial_pose, options=options
            )
        t0 = time.perf_counter()
        res = tracker.process(fr.left, fr.right)
        seconds.append(time.perf_counter() - t0)
        results.append(res)
        truths.append(truth)
        if progress is not None:
            progress.update(1)
    return results, truths, seconds


def summarize(results, truths, seconds) -> dict:
    """Per-axis RMS errors, lost frames and frame rate (module docstring), plus per-frame rows."""
    from jaxpose.core.status import Status

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
        c_est = -res.R.T @ res.t if ok else np.full(3, np.nan)
        row.update({f"t_est_{a}": v for a, v in zip("xyz", res.t, strict=True)})
        row.update({f"chaser_est_{a}": v for a, v in zip("xyz", c_est, strict=True)})
        row.update(
            {
                f"euler_est_{a}_deg": v
                for a, v in zip("xyz", _euler_deg(res.R) if ok else [np.nan] * 3, strict=True)
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
                e_att = _euler_deg(res.R @ Rt.T)
                pos_err.append(e_pos)
                att_err.append(e_att)
            else:
                e_pos = e_att = np.full(3, np.nan)
            row.update({f"err_pos_{a}_mm": v for a, v in zip("xyz", e_pos, strict=True)})
            row.update({f"err_att_{a}_deg": v for a, v in zip("xyz", e_att, strict=True)})
        rows.append(row)

    def rms(e):
        return np.sqrt(np.mean(np.square(e), axis=0)).tolist() if len(e) else [float("nan")] * 3

    total = float(np.sum(seconds[1:])) if len(seconds) > 1 else float("nan")
    summary = {
        "frames": len(results),
        "rms_position_mm": [round(x, 3) for x in rms(pos_err)],
        "rms_attitude_deg": [round(x, 4) for x in rms(att_err)],
        "lost_frames": int(sum(r.status != Status.OK for r in results)),
        "fps": round((len(seconds) - 1) / total, 2) if total > 0 else float("nan"),
    }
    return {"summary": summary, "rows": rows}


def write_outputs(report: dict, out, dt: float, title: str, *, figures: bool = True) -> None:
    """Write a :func:`summarize` report to the folder ``out``: ``trajectory.csv`` (one row a
    frame) and, with ``figures``, the paper's Figs. 3-5 (``fig3_position_track.png``,
    ``fig4_position.png``, ``fig5_attitude.png``); ``dt`` is the frame interval in seconds,
    ``title`` names the mode in the figures."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    _write_csv(report["rows"], out / "trajectory.csv")
    if figures:
        _figures(report["rows"], out, dt, title)


def _write_csv(rows, path: Path) -> None:
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})


def _figures(rows, out: Path, dt: float, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def col(name):
        return np.array([r.get(name, np.nan) for r in rows], dtype=float)

    time_s = col("frame") * dt
    has_truth = "chaser_true_x" in rows[0]
    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="3d")
    ax.plot(col("chaser_est_x"), col("chaser_est_y"), col("chaser_est_z"), label="estimate")
    if has_truth:
        ax.plot(
            col("chaser_true_x"), col("chaser_true_y"), col("chaser_true_z"), "--", label="truth"
        )
    ax.set_xlabel("x (m)"), ax.set_ylabel("y (m)"), ax.set_zlabel("z (m)")
    ax.set_title(f"Chaser position in the target frame ({title})")
    ax.legend()
    fig.savefig(out / "fig3_position_track.png", dpi=110)
    plt.close(fig)
    for name, est, true, err, unit in (
        ("fig4_position.png", "chaser_est_{}", "chaser_true_{}", "err_pos_{}_mm", ("m", "mm")),
        (
            "fig5_attitude.png",
            "euler_est_{}_deg",
            "euler_true_{}_deg",
            "err_att_{}_deg",
            ("deg", "deg"),
        ),
    ):
        fig, axes = plt.subplots(
            2 if has_truth else 1, 1, figsize=(8, 6 if has_truth else 3.2), squeeze=False
        )
        for a in "xyz":
            axes[0, 0].plot(time_s, col(est.format(a)), label=f"{a} estimate")
            if has_truth:
                axes[0, 0].plot(time_s, col(true.format(a)), "--", lw=0.8, label=f"{a} truth")
                axes[1, 0].plot(time_s, col(err.format(a)), label=a)
        axes[0, 0].set_ylabel(unit[0])
        axes[0, 0].legend(ncol=3, fontsize=7)
        if has_truth:
            axes[1, 0].set_ylabel(f"error ({unit[1]})")
            axes[1, 0].legend(ncol=3, fontsize=7)
        axes[-1, 0].set_xlabel("time (s)")
        axes[0, 0].set_title(title)
        fig.tight_layout()
        fig.savefig(out / name, dpi=110)
        plt.close(fig)


def _image_frames(folder: Path):
    """Rig and frames of a folder of rectified-or-not image pairs (module docstring)."""
    import cv2

    from jaxpose.core.camera import StereoCamera
    from jaxpose.io import load_camera
    from jaxpose.vision.stereo_rectify import rectify

    calib = folder / "calibration.json"
    if not calib.is_file():
        raise ValueError(f"{calib} not found (left/right cameras and R_rl, t_rl)")
    data = json.loads(calib.read_text())
    tmp = folder / ".left_camera.json"
    cams = []
    for side in ("left", "right"):
        tmp.write_text(json.dumps(data[side]))
        cams.append(load_camera(tmp))
    tmp.unlink()
    rig = StereoCamera(
        cams[0],
        cams[1],
        np.asarray(data.get("R_rl", np.eye(3)), float),
        np.asarray(data["t_rl"], float),
    )
    lefts = sorted((folder / "left").glob("*.png"))
    rights = sorted((folder / "right").glob("*.png"))
    if not lefts or len(lefts) != len(rights):
        raise ValueError(
            f"{folder}: need as many left/*.png as right/*.png (got {len(lefts)}, {len(rights)})"
        )
    rect = rectify(rig)
    rectified = rect.rectified_camera()

    class _Frame:
        def __init__(self, a, b):
            self.left, self.right = a, b

    def gen():
        for a, b in zip(lefts, rights, strict=True):
            la, rb = rect.remap(
                cv2.imread(str(a), cv2.IMREAD_GRAYSCALE), cv2.imread(str(b), cv2.IMREAD_GRAYSCALE)
            )
            yield _Frame(la, rb)

    return rectified, gen(), len(lefts)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    use_lines = not args.points_only
    if args.images is not None:
        rig, frames, n = _image_frames(Path(args.images))
        dt = 1.0 / args.frame_rate_hz
        from jaxpose.core.geometry import Pose

        initial = Pose.identity()
    else:
        if args.range_m <= 0.5:
            raise ValueError(
                f"--range-m must exceed 0.5 m (the target is 1 m across); got {args.range_m}"
            )
        if not 0.0 <= args.blur <= 1.0:
            raise ValueError(f"--blur must be in [0, 1]; got {args.blur}")
        scene = StereoScene(
            rate_deg_s=args.rate_deg_s,
            range_m=args.range_m,
            frame_rate_hz=args.frame_rate_hz,
            frames=args.frames,
            blur=args.blur,
            glints=args.glints,
            seed=args.seed,
        )
        try:
            width, height = (int(v) for v in str(args.image_size).lower().split("x"))
        except ValueError:
            raise ValueError(
                f"--image-size must look like 1024x768; got {args.image_size!r}"
            ) from None
        rig = default_rig(width, height)
        n = scene.n_frames()
        frames = render_sequence(scene, rig)
        dt, initial = 1.0 / scene.frame_rate_hz, None
    from jaxpose.pipelines.stereo import TrackerOptions

    opts = TrackerOptions(
        use_lines=use_lines, depth_range_m=(0.3, max(8.0, 3 * getattr(args, "range_m", 2.0)))
    )
    with tqdm(total=n, disable=args.json, desc="stereo-track") as bar:
        results, truths, seconds = track_sequence(
            frames, rig, use_lines=use_lines, initial_pose=initial, options=opts, progress=bar
        )
    report = summarize(results, truths, seconds)
    mode = "points+lines" if use_lines else "points only"
    write_outputs(report, out, dt, mode, figures=not args.no_figures)
    stage = {
        k: float(np.mean([r.timings.get(k, 0.0) for r in results[1:]])) for k in results[0].timings
    }
    (out / "summary.json").write_text(
        json.dumps(
            {
                **report["summary"],
                "mean_stage_s": stage,
                "mode": "points+lines" if use_lines else "points-only",
            },
            indent=1,
        )
    )
    s = report["summary"]
    if args.json:
        print(json.dumps(s))
    else:
        print(
            f"{s['frames']} frames, lost {s['lost_frames']}, "
            f"RMS position (mm) {s['rms_position_mm']}, RMS attitude (deg) "
            f"{s['rms_attitude_deg']}, {s['fps']} fps (tracking only); wrote {out}"
        )
    return 0
