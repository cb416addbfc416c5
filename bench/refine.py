"""Benchmark of pose refinement: jaxpose's two back-ends against OpenCV's solvePnPRefineLM.

Every solver starts from the same initial poses (the true pose perturbed by ``--perturb-deg``
degrees and ``--perturb-frac`` of the range) on the same noisy scenes (``n`` points in a 1 m
cube at 3-15 m, f = 800 px, ``--noise`` px). Reported for each batch size ``B``:

* ``cv2 loop``: a Python loop over ``cv2.solvePnPRefineLM``;
* ``native``: ``jit(vmap(refine_pose))``, the closed-form 6x6 normal equations back-end;
* ``optimistix``: the same with ``backend="optimistix"`` (``optimistix.LevenbergMarquardt``);

throughput (problems/s, after compilation), compile time (wall and CPU), single-problem latency
(``B = 1``), and the median rotation (deg) and translation (m) errors against the truth. The last
line is JSON. CPU time is printed beside wall time because shared machines are noisy.

    python bench/refine.py                  # B = 1, 100, 10000; n = 20
    python bench/refine.py --batch 1000 --n 6 20 100
"""

from __future__ import annotations

import argparse
import json
import time

import jax

jax.config.update("jax_enable_x64", True)

import cv2  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxpose import PinholeCamera, Pose, RefineOptions, refine_pose  # noqa: E402
from jaxpose.core.geometry import rotation_angle, so3_exp  # noqa: E402

CAM = PinholeCamera(800.0, 800.0, 320.0, 240.0)


def scenes(B, n, noise, perturb_deg, perturb_frac, seed=0):
    rng = np.random.default_rng(seed)
    P = rng.uniform(-0.5, 0.5, (B, n, 3))
    R = so3_exp(jnp.asarray(rng.normal(size=(B, 3)) * 0.6))
    depth = rng.uniform(3.0, 15.0, B)
    t = np.c_[rng.uniform(-0.3, 0.3, (B, 2)), depth]
    truth = Pose(R, jnp.asarray(t))
    pix = np.asarray(jax.vmap(lambda pose, p: CAM.project(pose.apply(p)))(truth, jnp.asarray(P)))
    pix = pix + noise * rng.normal(size=pix.shape)
    w = rng.normal(size=(B, 3)) * np.deg2rad(perturb_deg) / np.sqrt(3)
    dt = rng.normal(size=(B, 3)) * perturb_frac * depth[:, None] / np.sqrt(3)
    pose0 = Pose(so3_exp(jnp.asarray(w)) @ truth.R, truth.t + jnp.asarray(dt))
    return P, pix, truth, pose0


def errors(R, t, truth):
    rot = np.rad2deg(np.asarray(rotation_angle(jnp.asarray(R), truth.R)))
    trans = np.linalg.norm(np.asarray(t) - np.asarray(truth.t), axis=-1)
    return float(np.median(rot)), float(np.median(trans))


def bench_cv2(P, pix, pose0, truth, repeat_s=2.0):
    K = np.asarray(CAM.K)
    rvecs = np.asarray(pose0.rotvec)
    tvecs = np.asarray(pose0.t)
    B = len(P)
    R_out, t_out = np.zeros((B, 3, 3)), np.zeros((B, 3))
    t0 = time.perf_counter()
    c0 = time.process_time()
    for i in range(B):
        r, t = cv2.solvePnPRefineLM(
            P[i], pix[i], K, None, rvecs[i].reshape(3, 1).copy(), tvecs[i].reshape(3, 1).copy()
        )
        R_out[i] = cv2.Rodrigues(r)[0]
        t_out[i] = np.ravel(t)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"wall_s": wall, "cpu_s": cpu, "per_s": B / wall, "errors": errors(R_out, t_out, truth)}


def bench_jax(P, pix, pose0, truth, backend, repeats=3):
    f = jax.jit(
        jax.vmap(
            lambda p0, x, u: refine_pose(
                x, u, p0, CAM, sigma=0.5, options=RefineOptions(backend=backend), throw=False
            )
        )
    )
    args = (pose0, jnp.asarray(P), jnp.asarray(pix))
    t0, c0 = time.perf_counter(), time.process_time()
    compiled = f.lower(*args).compile()
    compile_wall, compile_cpu = time.perf_counter() - t0, time.process_time() - c0
    out = compiled(*args)
    jax.block_until_ready(out)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(repeats):
        out = compiled(*args)
        jax.block_until_ready(out)
    wall = (time.perf_counter() - t0) / repeats
    cpu = (time.process_time() - c0) / repeats
    ok = float(np.mean(np.asarray(out.status) == 0))
    return {
        "compile_wall_s": compile_wall,
        "compile_cpu_s": compile_cpu,
        "wall_s": wall,
        "cpu_s": cpu,
        "per_s": len(P) / wall,
        "ok_fraction": ok,
        "max_steps_taken": int(np.max(np.asarray(out.num_steps))),
        "errors": errors(out.pose.R, out.pose.t, truth),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 100, 10000])
    parser.add_argument("--n", type=int, nargs="+", default=[20])
    parser.add_argument("--noise", type=float, default=0.5)
    parser.add_argument("--perturb-deg", type=float, default=2.0)
    parser.add_argument("--perturb-frac", type=float, default=0.02)
    parser.add_argument("--backends", nargs="+", default=["native", "optimistix"])
    args = parser.parse_args(argv)
    rows = []
    hdr = (
        f"{'solver':<12} {'B':>6} {'n':>4} {'problems/s':>11} {'wall s':>8} {'cpu s':>8} "
        f"{'compile s (cpu)':>16} {'ratio':>7} {'med rot deg':>12} {'med trans m':>12}"
    )
    print(hdr)
    for n in args.n:
        for B in args.batch:
            P, pix, truth, pose0 = scenes(B, n, args.noise, args.perturb_deg, args.perturb_frac)
            ref = bench_cv2(P, pix, pose0, truth)
            results = {"cv2 loop": ref}
            for backend in args.backends:
                results[backend] = bench_jax(P, pix, pose0, truth, backend)
            for name, r in results.items():
                ratio = r["per_s"] / ref["per_s"]
                comp = (
                    f"{r['compile_wall_s']:.1f} ({r['compile_cpu_s']:.1f})"
                    if "compile_wall_s" in r
                    else "-"
                )
                timing = f"{r['per_s']:>11.0f} {r['wall_s']:>8.4f} {r['cpu_s']:>8.4f}"
                errs = f"{r['errors'][0]:>12.5f} {r['errors'][1]:>12.6f}"
                line = f"{name:<12} {B:>6} {n:>4} {timing} {comp:>16} {ratio:>7.2f} {errs}"
                print(line, flush=True)
                rows.append({"solver": name, "B": B, "n": n, "speedup_vs_cv2": ratio, **r})
    print(json.dumps({"bench": "refine", "noise_px": args.noise, "rows": rows}))


if __name__ == "__main__":
    main()
