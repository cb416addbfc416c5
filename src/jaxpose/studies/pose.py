"""``jaxpose pose-study``: predicted pose covariance against Monte Carlo scatter.

For each geometry (a point set seen from a fixed pose by a fixed camera) and each pixel noise
level ``sigma``, the study

1. predicts the pose covariance ``sigma^2 (H^T H)^-1`` at the true pose with
   :func:`jaxpose.core.refine.pose_covariance` (the DOP module's tangent Jacobian);
2. draws ``trials`` noisy images (independent Gaussian noise of ``sigma`` pixels per axis), refines
   every one with :func:`jaxpose.core.refine.refine_pose` (LM, one ``jit(vmap(...))`` call per group)
   from an initial guess (the true pose perturbed by ``--init-perturbation``, or EPnP with
   ``--init epnp``);
3. compares the per-axis standard deviations of the refined poses' errors, in the covariance's
   coordinates (``dt = t_est - t_true`` in metres, ``dw = log(R_est R_true^T)`` in radians, both in
   the camera frame), with the predicted ones, and reports the mean NEES
   ``e^T Sigma^-1 e`` (6 for a consistent covariance).

The check of the issue: at 0.5 px every axis of every geometry has ``|std_emp / std_pred - 1| <=
0.10`` (with 1000 trials the std estimate itself has a relative standard error of about 2.2%).

Outputs in ``--out``: ``results.json`` (``{"scenario", "groups": [...], "check"}``),
``std_vs_noise.png`` (predicted lines and empirical markers per axis, per geometry) and
``scatter.png`` (refined poses at the check noise with the predicted 1, 2, 3-sigma ellipses).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.geometry import Pose, euler_to_dcm, so3_exp, so3_log
from jaxpose.core.refine import pose_covariance, refine_pose
from jaxpose.core.status import Status

__all__ = ["GEOMETRIES", "Geometry", "add_arguments", "make_geometry", "run", "run_group"]

AXES = ("tx", "ty", "tz", "wx", "wy", "wz")


@dataclasses.dataclass(frozen=True)
class Geometry:
    """One observation geometry (deterministic given its fields and ``seed``).

    ``shape`` is ``"cube"`` (points uniform in a cube of side ``size_m``) or ``"plane"`` (uniform
    in a square of side ``size_m`` in the body x-y plane, tilted by ``tilt_deg`` about the camera
    x axis); the target is at ``range_m`` along the boresight, slightly off-centre, with attitude
    ``euler_deg`` (``"xyz"``) for cubes. Camera: ``focal_px``, principal point at the centre of a
    ``width x height`` image.
    """

    name: str
    n_points: int = 20
    shape: str = "cube"
    size_m: float = 1.0
    range_m: float = 5.0
    tilt_deg: float = 0.0
    euler_deg: tuple[float, float, float] = (20.0, -15.0, 30.0)
    focal_px: float = 1000.0
    width: int = 1024
    height: int = 1024
    seed: int = 0


GEOMETRIES = {
    g.name: g
    for g in (
        Geometry("cube-3m", range_m=3.0),
        Geometry("cube-15m", range_m=15.0),
        Geometry("cube-6pts-5m", n_points=6, range_m=5.0, seed=1),
        Geometry(
            "plane-8m-tilt40",
            shape="plane",
            range_m=8.0,
            tilt_deg=40.0,
            focal_px=3000.0,
            width=2048,
            height=2048,
            seed=2,
        ),
    )
}


def make_geometry(g: Geometry):
    """``(points_body (n, 3), true pose, camera)`` of a geometry."""
    rng = np.random.default_rng(g.seed)
    if g.shape == "cube":
        P = rng.uniform(-0.5, 0.5, (g.n_points, 3)) * g.size_m
        R = euler_to_dcm(jnp.deg2rad(jnp.asarray(g.euler_deg)))
    elif g.shape == "plane":
        P = np.c_[rng.uniform(-0.5, 0.5, (g.n_points, 2)) * g.size_m, np.zeros(g.n_points)]
        R = euler_to_dcm(jnp.asarray([math.radians(g.tilt_deg), 0.0, 0.3]))
    else:
        raise ValueError(f"geometry shape must be 'cube' or 'plane'; got {g.shape!r}")
    t = jnp.asarray([0.05 * g.range_m, -0.03 * g.range_m, g.range_m])
    camera = PinholeCamera(
        g.focal_px,
        g.focal_px,
        (g.width - 1) / 2,
        (g.height - 1) / 2,
        width=g.width,
        height=g.height,
    )
    return jnp.asarray(P), Pose(R, t), camera


def _initial_poses(pose: Pose, trials: int, perturbation: tuple[float, float], key) -> Pose:
    k1, k2 = jax.random.split(key)
    rot_deg, trans_frac = perturbation
    w = jax.random.normal(k1, (trials, 3)) * math.radians(rot_deg) / math.sqrt(3)
    dt = jax.random.normal(k2, (trials, 3)) * trans_frac * jnp.linalg.norm(pose.t) / math.sqrt(3)
    return Pose(so3_exp(w) @ pose.R, pose.t + dt)


@jax.jit
def _tangent_errors(R_est, t_est, pose: Pose):
    dw = so3_log(R_est @ pose.R.T)
    return jnp.concatenate([t_est - pose.t, dw], axis=-1)


@jax.jit
def _solve_batch(pose0, pixels, points_body, camera, sigma):
    """Every trial of a group in one call (compiled once per point count)."""
    return jax.vmap(
        lambda p0, u: refine_pose(points_body, u, p0, camera, sigma=sigma, throw=False)
    )(pose0, pixels)


def _solver_camera(camera: PinholeCamera) -> PinholeCamera:
    # Image size is static in PinholeCamera; drop it so that geometries share compilations.
    return PinholeCamera(camera.fx, camera.fy, camera.cx, camera.cy, camera.dist)


def run_group(
    geometry: Geometry,
    sigma: float,
    trials: int,
    *,
    seed: int = 0,
    init: str = "perturbed",
    perturbation: tuple[float, float] = (2.0, 0.02),
) -> dict:
    """One (geometry, noise) group; returns its summary and the raw errors ``(trials, 6)``."""
    P, pose, camera = make_geometry(geometry)
    n = P.shape[0]
    key = jax.random.fold_in(jax.random.PRNGKey(seed), int(round(sigma * 1e6)))
    key = jax.random.fold_in(key, geometry.seed)
    k_noise, k_init = jax.random.split(key)
    clean = camera.project(pose.apply(P))
    pixels = clean + sigma * jax.random.normal(k_noise, (trials, n, 2), dtype=clean.dtype)
    if init == "epnp":
        from jaxpose.core.pnp import epnp

        init_res = jax.jit(jax.vmap(lambda u: epnp(P, u, camera, throw=False)))(pixels)
        pose0 = init_res.pose
    elif init == "perturbed":
        pose0 = _initial_poses(pose, trials, perturbation, k_init)
    else:
        raise ValueError(f"init must be 'perturbed' or 'epnp'; got {init!r}")

    t0 = time.perf_counter()
    res = _solve_batch(pose0, pixels, P, _solver_camera(camera), jnp.asarray(sigma, P.dtype))
    res.pose.t.block_until_ready()
    elapsed = time.perf_counter() - t0
    ok = np.asarray(res.status) == Status.OK
    err = np.asarray(_tangent_errors(res.pose.R, res.pose.t, pose))[ok]
    cov = np.asarray(pose_covariance(P, pose, camera, sigma=sigma))
    pred = np.sqrt(np.diag(cov))
    emp = err.std(axis=0, ddof=1)
    nees = float(np.mean(np.einsum("ti,ij,tj->t", err, np.linalg.inv(cov), err)))
    summary = {
        "geometry": geometry.name,
        "noise_px": sigma,
        "trials": trials,
        "ok_fraction": float(ok.mean()),
        "pred_std": pred.tolist(),
        "emp_std": emp.tolist(),
        "ratio": (emp / pred).tolist(),
        "emp_mean": err.mean(axis=0).tolist(),
        "nees_mean": nees,
        "median_steps": float(np.median(np.asarray(res.num_steps))),
        "time_s": elapsed,
    }
    return {"summary": summary, "errors": err, "covariance": cov}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("out/pose-study"), help="output folder")
    parser.add_argument("--trials", type=int, default=1000, help="Monte Carlo trials per group")
    parser.add_argument(
        "--noise", type=float, nargs="+", default=[0.1, 0.5, 1.0, 2.0], help="pixel noise levels"
    )
    parser.add_argument(
        "--geometries",
        nargs="+",
        default=list(GEOMETRIES),
        choices=list(GEOMETRIES),
        help="geometries to run",
    )
    parser.add_argument(
        "--init",
        choices=["perturbed", "epnp"],
        default="perturbed",
        help="initial guess: the true pose perturbed, or EPnP on each noisy image",
    )
    parser.add_argument(
        "--init-perturbation",
        type=float,
        nargs=2,
        default=[2.0, 0.02],
        metavar=("DEG", "FRACTION"),
        help="rms rotation (deg) and translation (fraction of range) of the perturbation",
    )
    parser.add_argument(
        "--check-noise",
        type=float,
        default=0.5,
        help="noise level (px) of the 10%% agreement check",
    )
    parser.add_argument(
        "--tolerance",
        type=float,
        default=0.10,
        help="allowed |std_emp / std_pred - 1| per axis at --check-noise",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    if args.trials < 2:
        raise ValueError(f"--trials must be at least 2; got {args.trials}")
    if any(s <= 0 for s in args.noise):
        raise ValueError(f"--noise levels must be positive; got {args.noise}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    noise = sorted(set(args.noise) | {args.check_noise})
    groups, raw = [], {}
    jobs = [(g, s) for g in args.geometries for s in noise]
    for name, sigma in tqdm(jobs, desc="pose-study", unit="group"):
        r = run_group(
            GEOMETRIES[name],
            sigma,
            args.trials,
            seed=args.seed,
            init=args.init,
            perturbation=tuple(args.init_perturbation),
        )
        groups.append(r["summary"])
        raw[(name, sigma)] = r
    checked = [g for g in groups if g["noise_px"] == args.check_noise]
    worst = max(abs(x - 1.0) for g in checked for x in g["ratio"])
    results = {
        "scenario": {
            "geometries": [dataclasses.asdict(GEOMETRIES[n]) for n in args.geometries],
            "noise_px": noise,
            "trials": args.trials,
            "init": args.init,
            "init_perturbation": list(args.init_perturbation),
            "seed": args.seed,
            "axes": list(AXES),
            "units": {"t": "m", "w": "rad"},
            "coordinates": "dt = t_est - t_true (camera frame); dw = log(R_est R_true^T)",
            "solver": "refine_pose(method='lm', backend='native'), sigma-weighted",
        },
        "groups": groups,
        "check": {
            "noise_px": args.check_noise,
            "tolerance": args.tolerance,
            "max_abs_ratio_minus_1": worst,
            "passed": bool(worst <= args.tolerance),
        },
    }
    (out / "results.json").write_text(json.dumps(results, indent=2))
    if not args.no_plots:
        _plot_std(out / "std_vs_noise.png", groups, args.geometries)
        _plot_scatter(out / "scatter.png", raw, args.geometries, args.check_noise)
    print(f"{'geometry':<16} {'noise':>6} " + " ".join(f"{a:>7}" for a in AXES) + "   NEES")
    for g in groups:
        print(
            f"{g['geometry']:<16} {g['noise_px']:>6.2f} "
            + " ".join(f"{x:>7.3f}" for x in g["ratio"])
            + f" {g['nees_mean']:>6.2f}"
        )
    verdict = "PASS" if results["check"]["passed"] else "FAIL"
    print(
        f"std_emp / std_pred at {args.check_noise} px: worst |ratio - 1| = {worst:.3f} "
        f"(tolerance {args.tolerance}) {verdict}; results in {out}"
    )
    print(json.dumps(results["check"]))
    return 0


def _plot_std(path: Path, groups: list[dict], names: list[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(names), 2, figsize=(10, 3.2 * len(names)), squeeze=False)
    colors = ["C0", "C1", "C2"]
    for row, name in enumerate(names):
        gs = sorted((g for g in groups if g["geometry"] == name), key=lambda g: g["noise_px"])
        s = np.array([g["noise_px"] for g in gs])
        pred = np.array([g["pred_std"] for g in gs])
        emp = np.array([g["emp_std"] for g in gs])
        for col, (sl, scale, unit) in enumerate(
            [(slice(0, 3), 1e3, "mm"), (slice(3, 6), 180 / np.pi, "deg")]
        ):
            ax = axes[row, col]
            for k, i in enumerate(range(sl.start, sl.stop)):
                ax.plot(s, pred[:, i] * scale, "-", color=colors[k], label=f"{AXES[i]} predicted")
                ax.plot(s, emp[:, i] * scale, "o", color=colors[k], label=f"{AXES[i]} Monte Carlo")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("pixel noise sigma (px)")
            ax.set_ylabel(f"std ({unit})")
            ax.set_title(f"{name}: {'position' if col == 0 else 'attitude'}")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _ellipse(cov2, k):
    vals, vecs = np.linalg.eigh(cov2)
    a = np.linspace(0, 2 * np.pi, 100)
    circle = np.stack([np.cos(a), np.sin(a)])
    return (vecs @ (np.sqrt(np.maximum(vals, 0))[:, None] * circle)) * k


def _plot_scatter(path: Path, raw: dict, names: list[str], sigma: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = [((0, 2), 1e3, "mm"), ((3, 4), 180 / np.pi, "deg")]
    fig, axes = plt.subplots(len(names), 2, figsize=(9, 4 * len(names)), squeeze=False)
    for row, name in enumerate(names):
        r = raw[(name, sigma)]
        for col, ((i, j), scale, unit) in enumerate(pairs):
            ax = axes[row, col]
            e = r["errors"][:, [i, j]] * scale
            ax.plot(e[:, 0], e[:, 1], ".", ms=2, alpha=0.5, label="refined poses")
            c2 = r["covariance"][np.ix_([i, j], [i, j])] * scale**2
            for k in (1, 2, 3):
                x, y = _ellipse(c2, k)
                ax.plot(x, y, "k-", lw=0.8, label="predicted 1-2-3 sigma" if k == 1 else None)
            ax.set_xlabel(f"{AXES[i]} ({unit})")
            ax.set_ylabel(f"{AXES[j]} ({unit})")
            ax.set_title(f"{name}, {sigma} px")
            ax.axis("equal")
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
