"""Predicted pose covariance against Monte Carlo scatter (run by ``jaxpose pose-study``).

For each geometry (a point set seen from a fixed pose by a fixed camera) and each pixel noise
level ``sigma``, the study

1. predicts the pose covariance ``sigma^2 (H^T H)^-1`` at the true pose with
   :func:`jaxpose.core.refine.pose_covariance` (the DOP module's tangent Jacobian);
2. draws ``trials`` noisy images (independent Gaussian noise of ``sigma`` pixels per axis), refines
   every one with :func:`jaxpose.core.refine.refine_pose` (LM, one ``jit(vmap(...))`` call per
   group) from an initial guess (the true pose perturbed by ``--init-perturbation``, or EPnP with
   ``--init epnp``);
3. compares the per-axis standard deviations of the refined poses' errors, in the covariance's
   coordinates (``dt = t_est - t_true`` in metres, ``dw = log(R_est R_true^T)`` in radians, both in
   the camera frame), with the predicted ones, and reports the mean NEES
   ``e^T Sigma^-1 e`` (6 for a consistent covariance).

The check: at 0.5 px every axis of every geometry has ``|std_emp / std_pred - 1| <=
0.10`` (with 1000 trials the std estimate itself has a relative standard error of about 2.2%).

:func:`run_study` runs every group; the command writes to ``--out``: ``results.json``
(``{"scenario", "groups": [...], "check"}``), ``std_vs_noise.png`` (predicted lines and
empirical markers per axis, per geometry) and ``scatter.png`` (refined poses at the check noise
with the predicted 1, 2, 3-sigma ellipses).
"""

from __future__ import annotations

import dataclasses
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
from jaxpose.studies import _distributed as _dist

__all__ = ["GEOMETRIES", "Geometry", "make_geometry", "run_group", "run_study", "write_figures"]

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
    """One (geometry, noise) group; returns its summary and the raw errors ``(trials, 6)``.

    ``sigma`` is the pixel noise (a positive finite number), ``perturbation`` the rms rotation
    (deg) and translation (fraction of the range) of the initial guesses."""
    sigma = _check_positive(sigma, "sigma")
    if not (isinstance(trials, int) and trials >= 2):
        raise ValueError(f"trials must be an integer >= 2; got {trials!r}")
    P, pose, camera = make_geometry(geometry)
    n = P.shape[0]
    key = jax.random.fold_in(jax.random.PRNGKey(seed), int(round(sigma * 1e6)) % 2**32)
    key = jax.random.fold_in(key, geometry.seed)
    k_noise, k_init = jax.random.split(key)
    clean = camera.project(pose.apply(P))
    pixels = clean + sigma * jax.random.normal(k_noise, (trials, n, 2), dtype=clean.dtype)
    if init == "epnp":
        from jaxpose.core.pnp import epnp

        init_res = _dist.map_cases(
            jax.jit(jax.vmap(lambda u: epnp(P, u, camera, throw=False))), (pixels,)
        )
        pose0 = jax.tree.map(jnp.asarray, init_res.pose)
    elif init == "perturbed":
        pose0 = _initial_poses(pose, trials, perturbation, k_init)
    else:
        raise ValueError(f"init must be 'perturbed' or 'epnp'; got {init!r}")

    t0 = time.perf_counter()
    # The trials are sharded over every device (of every process in a multi-process run).
    res = _dist.map_cases(
        _solve_batch, (pose0, pixels), (P, _solver_camera(camera), jnp.asarray(sigma, P.dtype))
    )
    elapsed = time.perf_counter() - t0
    ok = np.asarray(res.status) == Status.OK
    err = np.asarray(_tangent_errors(res.pose.R, res.pose.t, pose))[ok]
    cov = np.asarray(pose_covariance(P, pose, camera, sigma=sigma))
    pred = np.sqrt(np.diag(cov))
    summary = {
        "geometry": geometry.name,
        "noise_px": sigma,
        "trials": trials,
        "ok_fraction": float(ok.mean()),
        "pred_std": pred.tolist(),
    }
    if len(err) >= 2:
        emp = err.std(axis=0, ddof=1)
        summary |= {
            "emp_std": emp.tolist(),
            "ratio": (emp / pred).tolist(),
            "emp_mean": err.mean(axis=0).tolist(),
            "nees_mean": float(np.mean(np.einsum("ti,ij,tj->t", err, np.linalg.inv(cov), err))),
        }
    else:  # no spread from fewer than two converged trials: no figure, said so (not NaN)
        summary |= {"emp_std": None, "ratio": None, "emp_mean": None, "nees_mean": None}
        summary["message"] = f"{len(err)} of {trials} trials converged (status OK): no Monte Carlo"
    summary |= {
        "median_steps": float(np.median(np.asarray(res.num_steps))),
        "time_s": elapsed,
    }
    return {"summary": summary, "errors": err, "covariance": cov}


#: the most trials of a group: all of a group's trials are drawn and solved at once (a million
#: takes about a gigabyte and a minute or so on a 2-core CPU; the check's 2.2% standard error
#: needs a thousand).
MAX_TRIALS = 1_000_000


def _check_positive(value, name: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number; got {value!r}")
    return value


def run_study(
    geometries: list[str] | None = None,
    noise: list[float] = (0.1, 0.5, 1.0, 2.0),
    trials: int = 1000,
    *,
    seed: int = 0,
    init: str = "perturbed",
    perturbation: tuple[float, float] = (2.0, 0.02),
    check_noise: float = 0.5,
    tolerance: float = 0.10,
    progress: bool = True,
) -> tuple[dict, dict]:
    """Every (geometry, noise) group; returns ``(results, raw)``: what ``results.json`` holds and
    the per-group output of :func:`run_group` keyed by ``(geometry name, noise)``.

    Raises ``ValueError`` naming the argument (and its ``--option``) for an unknown geometry,
    fewer than 2 trials, a noise level, ``check_noise`` or ``tolerance`` that is not a positive
    finite number, or a perturbation that is not finite and non-negative.
    """
    from jaxpose.commands._common import progress as progress_bar

    geometries = list(GEOMETRIES) if geometries is None else list(geometries)
    unknown = [g for g in geometries if g not in GEOMETRIES]
    if unknown or not geometries:
        raise ValueError(
            f"geometries (--geometries) must be among {list(GEOMETRIES)}; got {unknown}"
        )
    if not (isinstance(trials, int) and trials >= 2):
        raise ValueError(f"trials (--trials) must be an integer >= 2; got {trials!r}")
    if trials > MAX_TRIALS:
        raise ValueError(
            f"trials (--trials) must be at most {MAX_TRIALS} (a group's trials are solved at "
            f"once); got {trials}"
        )
    noise = [_check_positive(s, "noise levels (--noise)") for s in noise]
    check_noise = _check_positive(check_noise, "check_noise (--check-noise)")
    tolerance = _check_positive(tolerance, "tolerance (--tolerance)")
    perturbation = tuple(float(x) for x in perturbation)
    if len(perturbation) != 2 or not all(math.isfinite(x) and x >= 0 for x in perturbation):
        raise ValueError(
            "perturbation (--init-perturbation) must be two finite numbers >= 0 (deg, fraction "
            f"of range); got {perturbation!r}"
        )
    levels = sorted(set(noise) | {check_noise})
    groups, raw = [], {}
    jobs = [(g, s) for g in geometries for s in levels]
    for name, sigma in progress_bar(
        jobs, desc="pose-study", unit="group", enabled=progress and _dist.is_writer()
    ):
        r = run_group(
            GEOMETRIES[name], sigma, trials, seed=seed, init=init, perturbation=perturbation
        )
        groups.append(r["summary"])
        raw[(name, sigma)] = r
    checked = [g for g in groups if g["noise_px"] == check_noise]
    ratios = [x for g in checked for x in (g["ratio"] or [np.nan] * len(AXES))]
    worst = max(abs(x - 1.0) for x in ratios) if ratios and np.all(np.isfinite(ratios)) else None
    results = {
        "scenario": {
            "geometries": [dataclasses.asdict(GEOMETRIES[n]) for n in geometries],
            "noise_px": levels,
            "trials": trials,
            "init": init,
            "init_perturbation": list(perturbation),
            "seed": seed,
            "axes": list(AXES),
            "units": {"t": "m", "w": "rad"},
            "coordinates": "dt = t_est - t_true (camera frame); dw = log(R_est R_true^T)",
            "solver": "refine_pose (Levenberg-Marquardt), sigma-weighted",
        },
        "groups": groups,
        "check": {
            "noise_px": check_noise,
            "tolerance": tolerance,
            "max_abs_ratio_minus_1": worst,
            "passed": bool(worst is not None and worst <= tolerance),
        },
    }
    return results, raw


def write_figures(out: Path, results: dict, raw: dict) -> list[Path]:
    """``std_vs_noise.png`` and ``scatter.png`` in ``out``; returns their paths."""
    from jaxpose.studies._pose_figures import plot_scatter, plot_std

    names = [g["name"] for g in results["scenario"]["geometries"]]
    paths = [out / "std_vs_noise.png", out / "scatter.png"]
    plot_std(paths[0], results["groups"], names)
    plot_scatter(paths[1], raw, names, results["check"]["noise_px"])
    return paths
