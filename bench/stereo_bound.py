"""What the tracker's point observations allow: the Cramer-Rao bound of the chaser position.

    python bench/stereo_bound.py SCENE [SCENE ...] [--frames 30] [--seeds 0 1 2] [--sigma PX]

Runs the stereo tracker as it is (points + lines, default options, first pose given) on a scene
of ``bench/stereo.py`` (or ``hNN`` of ``bench/stereo_heldout.py``), keeps every tracked frame's
point observations (the left and right pixels of its landmarks, ``keep_history``), and computes
the Cramer-Rao bound of all the frames' poses and the landmarks estimated jointly from exactly
those observations, frame 0's pose given (the gauge): the information of independent pixel noise
of standard deviation ``sigma``, linearised at the true poses and the tracker's landmarks, with
the landmarks eliminated by the Schur complement. ``sigma`` is measured (the MAD-scaled spread of
the observations' reprojection residuals at the true poses and the map's landmarks, which also
holds the landmarks' own errors: an upper estimate) unless ``--sigma`` gives it. The lines are
left out, so the bound is that of the points alone (lines would lower it).

Reported per scene and seed: the tracker's RMS chaser position per axis (the stereo-track
metric, ``c = -R^T t`` in the target frame), the bound's RMS over frames 1.. (the square root
of the mean variance), and the target of issue 16 (5 mm per metre of range). An estimator that
made the most of independent pixel noise would come close to the bound; errors several times
above it come from errors that are not independent pixel noise (the same corner localised
differently as the view changes, windows across a change of depth) or from the estimator.
The last line is one JSON line of the figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """``[v]_x``: ``skew(v) @ w = cross(v, w)``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def observation_jacobians(R, t, X, offset, focal) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of the pixel ``f (x / z, y / z) + c`` of body point ``X`` seen at pose
    ``(R, t)`` (``x_cam = R X + t``) from a camera whose centre sits at ``-offset`` in the left
    camera's frame (``offset = t_rl`` for the right camera of a rectified rig, 0 for the left):
    ``(2, 6)`` with respect to the pose perturbation ``(dtheta, dt)`` (``R <- exp(dtheta) R``,
    ``t <- t + dt``) and ``(2, 3)`` with respect to ``X``."""
    fx, fy = focal
    xc = R @ X + t + offset
    z = xc[2]
    D = np.array([[fx / z, 0.0, -fx * xc[0] / z**2], [0.0, fy / z, -fy * xc[1] / z**2]])
    return D @ np.hstack([-skew(R @ X), np.eye(3)]), D @ R


def project(R, t, points, offsets, focal, centre) -> np.ndarray:
    """Pixels ``(n, 2)`` of body points ``(n, 3)`` at pose ``(R, t)`` seen by cameras whose
    centres sit at ``-offsets (n, 3)`` in the left camera's frame (pinhole, no distortion; the
    pixel of :func:`observation_jacobians`)."""
    xc = np.asarray(points, float) @ R.T + t + offsets
    return np.asarray(focal) * xc[:, :2] / xc[:, 2:3] + np.asarray(centre)


def chaser_jacobian(R, t) -> np.ndarray:
    """``(3, 6)``: the derivative of the chaser position ``c = -R^T t`` (target frame) with
    respect to the pose perturbation ``(dtheta, dt)`` of :func:`observation_jacobians`."""
    return np.hstack([-R.T @ skew(t), -R.T])


def pose_covariance(observations, poses, points, free, focal, sigma) -> np.ndarray:
    """Covariance ``(6 F, 6 F)`` of the free frames' pose perturbations: the inverse of the
    information of independent pixel noise ``sigma`` over ``observations`` (tuples ``(frame,
    point, offset)``), the points estimated jointly and eliminated by the Schur complement.
    ``poses``: ``{frame: (R, t)}``; ``points``: ``{point: X}``; ``free``: the frames whose pose is
    estimated, in order (the others are given). Every point must be seen at least twice across
    the two cameras (its ``3 x 3`` information invertible)."""
    col = {k: 6 * i for i, k in enumerate(free)}
    P = 6 * len(free)
    Hpp = np.zeros((P, P))
    Hll: dict = {}
    Hpl: dict = {}
    for k, j, offset in observations:
        R, t = poses[k]
        Jp, Jl = observation_jacobians(R, t, points[j], offset, focal)
        Hll[j] = Hll.get(j, np.zeros((3, 3))) + Jl.T @ Jl
        if k in col:
            c = col[k]
            Hpp[c : c + 6, c : c + 6] += Jp.T @ Jp
            blocks = Hpl.setdefault(j, {})
            blocks[k] = blocks.get(k, np.zeros((6, 3))) + Jp.T @ Jl
    S = Hpp
    for j, blocks in Hpl.items():
        Hi = np.linalg.inv(Hll[j])
        for a, Ba in blocks.items():
            for b, Bb in blocks.items():
                S[col[a] : col[a] + 6, col[b] : col[b] + 6] -= Ba @ Hi @ Bb.T
    return sigma**2 * np.linalg.inv(S)


def _scene(name: str, frames: int, seed: int):
    """A scene of ``bench/stereo.py`` or ``hNN`` (``stereo_diagnose._scene_by_name``);
    ``ValueError`` naming the choices for an unknown name."""
    sys.path.insert(0, str(Path(__file__).parent))
    from stereo_diagnose import _scene_by_name

    return _scene_by_name(name, frames, seed)


def check_scenes(parser: argparse.ArgumentParser, names) -> None:
    """A usage error (``parser.error``) for the first name that is not a scene of
    ``bench/stereo.py`` or ``hNN``."""
    for name in names:
        try:
            _scene(name, 3, 0)
        except ValueError as err:
            parser.error(str(err))


def bound(name: str, frames: int, seed: int, sigma: float | None = None) -> dict:
    """The tracker's figures and the bound on one scene (module docstring)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from stereo_diagnose import track_with_history

    from jaxpose.studies.stereo_track import summarize

    scene = _scene(name, frames, seed)
    rig, seq, tr, results = track_with_history(scene)
    focal = (float(rig.left.fx), float(rig.left.fy))
    cxy = (float(rig.left.cx), float(rig.left.cy))
    t_rl = np.asarray(rig.t_rl, float)
    truths = [fr.pose for fr in seq]
    summary = summarize(results, truths, [0.0] * len(results))["summary"]
    poses = {k: (np.asarray(p.R, float), np.asarray(p.t, float)) for k, p in enumerate(truths)}
    index = {int(i): k for k, i in enumerate(tr.map.points.ids)}
    X = np.asarray(tr.map.points.X, float)
    observations, residuals, seen = [], [], {}
    for fr in tr._window.history:  # every tracked frame's record (keep_history)
        ids, px, right, _ = fr.arrays()
        R, t = poses[fr.index]
        for i, p, r in zip(ids.tolist(), px, right, strict=True):
            j = index.get(i)
            if j is None:  # culled from the map: its position is not kept
                continue
            offset = t_rl if r else np.zeros(3)
            residuals.append(p - project(R, t, X[j][None], offset, focal, cxy)[0])
            observations.append((fr.index, j, offset))
            seen[j] = seen.get(j, 0) + 1
    observations = [o for o in observations if seen[o[1]] >= 2]
    res = np.asarray(residuals)
    mad = 1.4826 * np.median(np.abs(res - np.median(res, axis=0)), axis=0)
    sig = float(np.mean(mad)) if sigma is None else float(sigma)
    free = sorted({k for k, _, _ in observations if k > 0})
    C = pose_covariance(observations, poses, dict(enumerate(X)), free, focal, sig)
    var = []
    for i, k in enumerate(free):
        J = chaser_jacobian(*poses[k])
        var.append(np.diag(J @ C[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] @ J.T))
    bound_mm = np.sqrt(np.mean(var, axis=0)) * 1000.0
    return {
        "scene": name,
        "seed": seed,
        "frames": frames,
        "sigma_px": round(sig, 3),
        "observations": len(observations),
        "landmarks": len({j for _, j, _ in observations}),
        "tracker_rms_mm": np.round(summary["rms_position_mm"], 1).tolist(),
        "bound_rms_mm": np.round(bound_mm, 1).tolist(),
        "target_mm": round(5.0 * scene.range_m, 2),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("scenes", nargs="+", help="scenes of bench/stereo.py or hNN")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--sigma", type=float, default=None, help="pixel noise (default: measured)")
    args = ap.parse_args(argv)
    if args.frames < 3:
        ap.error(f"--frames must be at least 3; got {args.frames}")
    if args.sigma is not None and not args.sigma > 0:
        ap.error(f"--sigma must be positive; got {args.sigma}")
    check_scenes(ap, args.scenes)
    rows = []
    print("| scene | seed | sigma px | tracker RMS x, y, z mm | bound x, y, z mm | target mm |")
    print("|---|---|---|---|---|---|")
    for name in args.scenes:
        for seed in args.seeds:
            r = bound(name, args.frames, seed, args.sigma)
            rows.append(r)
            print(
                f"| {name} | {seed} | {r['sigma_px']} | {r['tracker_rms_mm']} "
                f"| {r['bound_rms_mm']} | {r['target_mm']} |",
                flush=True,
            )
    print(json.dumps({"frames": args.frames, "runs": rows}))


if __name__ == "__main__":
    main()
