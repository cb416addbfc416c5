"""The eager front door: what a user waits for when calling jaxpose eagerly in a fresh process,
the first call of a shape (tracing and compilation included) and later calls, against the same
function under the caller's own ``jax.jit`` and against OpenCV's call for the same job.

    python bench/front_door.py [--calls 200]

- ``jp.dop`` (10 points): an entry point that compiles itself (``eqx.filter_jit``);
- ``PinholeCamera.project`` (20 points, with distortion) and ``so3_exp``: small functions of
  the core that compile once per shape (``small_jit``), against ``cv2.projectPoints`` and
  ``cv2.Rodrigues``;
- ``refine_pose`` (20 points): its input checks run eagerly, the problem set-up and the LM are
  compiled; against ``cv2.solvePnPRefineLM`` on the same points.

Prints a table, then one JSON line of the figures (seconds for first calls, milliseconds for
later calls, medians; ``*_vs_opencv`` is jaxpose's later call over OpenCV's).
"""

import argparse
import json
import time

t0 = time.perf_counter()
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import cv2  # noqa: E402
import numpy as np  # noqa: E402

import jaxpose as jp  # noqa: E402
from jaxpose.core.geometry import so3_exp  # noqa: E402
from jaxpose.core.refine import refine_pose  # noqa: E402

t_import = time.perf_counter() - t0


def _first(fn) -> float:
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t0


def _median_ms(fn, calls: int) -> float:
    times = []
    for k in range(calls):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(k))
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def main(calls: int = 200) -> dict:
    rng = np.random.default_rng(0)
    K = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
    dist = np.array([0.05, -0.01, 1e-3, -1e-3, 0.0])
    camera = jp.PinholeCamera.from_K(K)
    distorted = jp.PinholeCamera.from_K(K, dist)
    pose = jp.Pose.from_euler(np.array([0.1, 0.2, 0.3]), np.array([0.1, -0.1, 5.0]))
    points10 = rng.uniform(-0.5, 0.5, (10, 3))
    points = rng.uniform(-0.5, 0.5, (20, 3))
    rvec, tvec = np.asarray(pose.rotvec), np.asarray(pose.t)
    out = {"import_s": t_import}

    # jp.dop
    out["dop_first_s"] = _first(lambda: jp.dop(points10, pose, camera).pdop)
    out["dop_ms"] = _median_ms(lambda k: jp.dop(points10 + 1e-3 * k, pose, camera).pdop, calls)
    jitted = jax.jit(lambda p: jp.dop(p, pose, camera, throw=False).pdop)
    jitted(points10).block_until_ready()
    out["dop_in_jit_ms"] = _median_ms(lambda k: jitted(points10 + 1e-3 * k), calls)

    # PinholeCamera.project with distortion, a new shape each first call
    cam_points = np.asarray(pose.apply(points))
    out["project_first_s"] = _first(lambda: distorted.project(cam_points))
    out["project_new_shape_s"] = _first(lambda: distorted.project(cam_points[:13]))
    out["project_ms"] = _median_ms(lambda k: distorted.project(cam_points + 1e-4 * k), calls)
    out["opencv_project_ms"] = _median_ms(
        lambda k: cv2.projectPoints(points + 1e-4 * k, rvec, tvec, K, dist)[0], calls
    )

    # so3_exp against cv2.Rodrigues (one rotation vector)
    out["so3_exp_first_s"] = _first(lambda: so3_exp(rvec))
    out["so3_exp_ms"] = _median_ms(lambda k: so3_exp(rvec + 1e-4 * k), calls)
    out["opencv_rodrigues_ms"] = _median_ms(lambda k: cv2.Rodrigues(rvec + 1e-4 * k)[0], calls)

    # refine_pose against cv2.solvePnPRefineLM, from a perturbed pose
    pixels = np.asarray(camera.project(pose.apply(points))) + rng.normal(0, 0.5, (20, 2))
    start = jp.Pose.from_rotvec(rvec + 0.02, tvec + np.array([0.02, -0.01, 0.05]))
    out["refine_first_s"] = _first(lambda: refine_pose(points, pixels, start, camera).pose.R)
    out["refine_new_shape_s"] = _first(
        lambda: refine_pose(points[:13], pixels[:13], start, camera).pose.R
    )
    out["refine_ms"] = _median_ms(
        lambda k: refine_pose(points, pixels + 1e-4 * k, start, camera).pose.R, calls
    )
    r0, t0_ = np.asarray(start.rotvec), np.asarray(start.t)
    out["opencv_refine_lm_ms"] = _median_ms(
        lambda k: cv2.solvePnPRefineLM(points, pixels + 1e-4 * k, K, None, r0.copy(), t0_.copy()),
        calls,
    )
    for name, ours, theirs in (
        ("project", "project_ms", "opencv_project_ms"),
        ("so3_exp", "so3_exp_ms", "opencv_rodrigues_ms"),
        ("refine", "refine_ms", "opencv_refine_lm_ms"),
    ):
        out[f"{name}_vs_opencv"] = out[ours] / out[theirs]

    print(f"import {t_import:.2f} s")
    print(f"{'':34s} {'first call':>12s} {'new shape':>10s} {'later':>10s} {'OpenCV':>10s}")
    rows = (
        ("jp.dop (10 points)", "dop_first_s", None, "dop_ms", None),
        ("PinholeCamera.project (20, dist.)", "project_first_s", "project_new_shape_s",
         "project_ms", "opencv_project_ms"),
        ("so3_exp (one)", "so3_exp_first_s", None, "so3_exp_ms", "opencv_rodrigues_ms"),
        ("refine_pose (20 points)", "refine_first_s", "refine_new_shape_s", "refine_ms",
         "opencv_refine_lm_ms"),
    )  # fmt: skip
    for label, first, new, later, cv in rows:
        print(
            f"{label:34s} {out[first]:10.2f} s "
            + (f"{out[new]:8.2f} s " if new else " " * 11)
            + f"{out[later]:7.3f} ms "
            + (f"{out[cv]:7.3f} ms" if cv else "")
        )
    print(f"jp.dop under the caller's jax.jit: {out['dop_in_jit_ms']:.3f} ms")
    print(json.dumps({k: round(v, 5) for k, v in out.items()}))
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=200, help="later calls timed (median)")
    args = parser.parse_args()
    if args.calls < 1:
        parser.error(f"--calls must be at least 1; got {args.calls}")
    main(args.calls)
