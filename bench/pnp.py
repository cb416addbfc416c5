"""Benchmark of the pose solvers (issue 3, item 9; issue 17.4): jaxpose against OpenCV and PoseLib.

In one run:

(a) **Throughput and accuracy** for batch sizes ``B`` in 1, 100, 10 000 and ``n`` in 6, 20, 100
    points: jaxpose ``solve_pnp`` (EPnP alone, and EPnP + Levenberg-Marquardt) batched, against
    Python loops over OpenCV (``SOLVEPNP_EPNP``, ``SOLVEPNP_SQPNP``, EPnP +
    ``solvePnPRefineLM``) and PoseLib (``estimate_absolute_pose``: LO-RANSAC over P3P with its
    bundle adjustment; few iterations since the data hold no outliers). Problems per second
    (wall clock, after compilation), CPU time a problem (this process, all threads: a figure
    that waiting for a core on a shared machine does not inflate) and median rotation (deg) and
    translation (mm) errors.
    Competitor loops run over at most ``--loop-max`` problems (their time per problem does not
    depend on ``B``); medians are compared on that same subset. Every figure is the best of
    ``--repeats`` passes (jaxpose's after its compiling call), since the machine is shared.
(b) **Single problem** after compilation: ``solve_pnp`` on one ``(20, 3)`` problem, median wall
    time.
(c) **Compilation** of the batched solve (``B = 10 000, n = 20``): first call minus a later one,
    wall clock and CPU time of this process, with JAX's persistent compilation cache off (on a
    machine shared with other jobs the wall time grows with the load average; the CPU time
    much less).
(d) **Planar targets at long range** (the case where OpenCV's EPnP and ITERATIVE flip): 20 points
    in a 1 m square, range 5-15 m, tilt 10-60 deg, ``f = 3000`` px, 0.5 px noise: how often the
    rotation error is below 5 deg, for jaxpose (EPnP + LM from the EPnP pose and its mirror) and
    OpenCV's EPnP, EPnP + RefineLM, ITERATIVE, SQPnP and IPPE on the same scenes.
(e) **Where the time goes** (``--no-profile`` skips it): the closed-form and refinement stages
    of the batched solve timed apart (CPU time a problem, one thread) and the op counts of their
    optimised HLO.

Issue 17.4's figures are ratios to OpenCV's SQPnP in the same run: CPU time a problem of the
one-thread solve (target <= 1) and its median errors (target <= 1).

General scenes: points uniform in a 1 m cube, range 3-15 m, any attitude, ``f = 1000`` px on a
``1280 x 960`` image, 0.5 px Gaussian noise.

Dependencies beyond jaxpose: ``opencv`` (a jaxpose dependency) and ``poselib`` (bench only:
``pip install poselib``; its column is skipped when it is missing).

    python bench/pnp.py                # full run (about 5 minutes on 2 CPU cores)
    python bench/pnp.py --quick        # B in 1, 100 and n = 20 only; 200 planar scenes
    python bench/pnp.py --sizes 10000 --points 20 --planar 1000   # the throughput target only

XLA runs one execution of these solvers on about one CPU core, so on a CPU ``solve_pnp`` splits a
large batch (``>= 2 * THREAD_MIN_PROBLEMS``) over host threads, one per core, each running the
same compiled solver: the default figures include that. At ``B = 10 000, n = 20`` the jaxpose
EPnP + LM figure is also taken with ``workers=1`` (one thread) and with one JAX device per CPU
core (a child process with ``XLA_FLAGS=--xla_force_host_platform_device_count=<cores>``;
``solve_pnp`` then splits the batch over the devices with ``shard_map`` instead of threads).

Prints a table and, last, one JSON line with every figure. The machine's load average is
printed too: the figures are wall-clock times on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time

import jax

jax.config.update("jax_enable_x64", True)
# no persistent compilation cache: the compile figures are those of a fresh process
jax.config.update("jax_enable_compilation_cache", False)

import cv2  # noqa: E402
import numpy as np  # noqa: E402

import jaxpose  # noqa: E402
from jaxpose import PnPOptions, RefineOptions  # noqa: E402
from jaxpose.core.geometry import so3_exp  # noqa: E402
from jaxpose.io.software import software_versions  # noqa: E402

try:  # bench-only dependency
    import poselib
except ImportError:  # pragma: no cover
    poselib = None

GENERAL_K = np.array([[1000.0, 0.0, 639.5], [0.0, 1000.0, 479.5], [0.0, 0.0, 1.0]])
PLANAR_K = np.array([[3000.0, 0.0, 1023.5], [0.0, 3000.0, 1023.5], [0.0, 0.0, 1.0]])
NOISE_PX = 0.5


# ----------------------------------------------------------------------------- scenes
def random_rotations(rng, count):
    q = rng.normal(size=(count, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.asarray(jaxpose.core.geometry.quat_to_dcm(q))


def project(K, R, t, points):
    cam = np.einsum("bij,bnj->bni", R, points) + t[:, None]
    uv = cam[..., :2] / cam[..., 2:]
    return uv * K[[0, 1], [0, 1]] + K[:2, 2]


def general_scenes(count, n, seed=0):
    """Points in a 1 m cube, range 3-15 m near the boresight, any attitude, 0.5 px noise."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-0.5, 0.5, (count, n, 3))
    R = random_rotations(rng, count)
    z = rng.uniform(3.0, 15.0, count)
    t = np.stack([rng.uniform(-0.1, 0.1, count) * z, rng.uniform(-0.1, 0.1, count) * z, z], -1)
    pixels = project(GENERAL_K, R, t, points) + rng.normal(0.0, NOISE_PX, (count, n, 2))
    return points, pixels, R, t


def planar_scenes(count, n=20, seed=1):
    """20 points in a 1 m square, range 5-15 m, tilt 10-60 deg, f = 3000 px, 0.5 px noise."""
    rng = np.random.default_rng(seed)
    points = np.concatenate(
        [rng.uniform(-0.5, 0.5, (count, n, 2)), np.zeros((count, n, 1))], axis=-1
    )
    spin = rng.uniform(-np.pi, np.pi, count)
    R_spin = np.asarray(so3_exp(np.stack([0 * spin, 0 * spin, spin], -1)))
    tilt = np.radians(rng.uniform(10.0, 60.0, count))
    axis_angle = rng.uniform(-np.pi, np.pi, count)
    axis = np.stack([np.cos(axis_angle), np.sin(axis_angle), 0 * axis_angle], -1)
    R = np.asarray(so3_exp(axis * tilt[:, None])) @ R_spin
    rng_z = rng.uniform(5.0, 15.0, count)
    t = np.stack(
        [rng.uniform(-0.05, 0.05, count) * rng_z, rng.uniform(-0.05, 0.05, count) * rng_z, rng_z],
        -1,
    )
    pixels = project(PLANAR_K, R, t, points) + rng.normal(0.0, NOISE_PX, (count, n, 2))
    return points, pixels, R, t


def rotation_error_deg(R_est, R_true):
    cos = (np.einsum("bij,bij->b", R_est, R_true) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def errors(R_est, t_est, R_true, t_true):
    return rotation_error_deg(R_est, R_true), np.linalg.norm(t_est - t_true, axis=-1)


# ----------------------------------------------------------------------------- competitors
def cv_loop(points, pixels, K, flags, refine_lm=False):
    R = np.full((len(points), 3, 3), np.nan)
    t = np.full((len(points), 3), np.nan)
    dist = np.zeros(5)
    t0 = time.perf_counter()
    for b in range(len(points)):
        ok, rvec, tvec = cv2.solvePnP(points[b], pixels[b], K, dist, flags=flags)
        if ok and refine_lm:
            rvec, tvec = cv2.solvePnPRefineLM(points[b], pixels[b], K, dist, rvec, tvec)
        if ok:
            R[b] = cv2.Rodrigues(rvec)[0]
            t[b] = tvec.ravel()
    return time.perf_counter() - t0, R, t


def cv_ippe_loop(points, pixels, K):
    """IPPE's two solutions, the lower reprojection error kept (OpenCV's own choice)."""
    return cv_loop(points, pixels, K, cv2.SOLVEPNP_IPPE)


def poselib_loop(points, pixels, K):
    cam = {
        "model": "PINHOLE",
        "width": int(2 * K[0, 2] + 1),
        "height": int(2 * K[1, 2] + 1),
        "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2]],
    }
    ransac = {"max_reproj_error": 8.0, "min_iterations": 10, "max_iterations": 1000}
    R = np.full((len(points), 3, 3), np.nan)
    t = np.full((len(points), 3), np.nan)
    t0 = time.perf_counter()
    for b in range(len(points)):
        pose, _ = poselib.estimate_absolute_pose(pixels[b], points[b], cam, ransac, {})
        R[b], t[b] = pose.R, pose.t
    return time.perf_counter() - t0, R, t


# ----------------------------------------------------------------------------- jaxpose
def jax_solve(points, pixels, K, refine, repeats=3, workers=None):
    """``(compile_s, compile_cpu_s, best_run_s, R, t, status, best_run_cpu_s)`` of a batched
    ``solve_pnp`` (CPU time of this process, all its threads)."""

    def call():
        res = jaxpose.solve_pnp(
            points,
            pixels,
            K,
            throw=False,
            options=PnPOptions(
                refine=(
                    None if refine is None else RefineOptions(method=refine, rtol=1e-6, atol=1e-9)
                ),
                workers=workers,
            ),
        )
        return jax.block_until_ready(res)

    t0, c0 = time.perf_counter(), time.process_time()
    res = call()
    first, first_cpu = time.perf_counter() - t0, time.process_time() - c0
    best, best_cpu = math.inf, math.inf
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        res = call()
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    return (
        max(first - best, 0.0),
        max(first_cpu - best_cpu, 0.0),
        best,
        np.asarray(res.R),
        np.asarray(res.t),
        np.asarray(res.status),
        best_cpu,
    )


def median(x):
    x = x[np.isfinite(x)]
    return float(np.median(x)) if x.size else math.nan


# ----------------------------------------------------------------------------- parts
def bench_grid(sizes, counts, loop_max, repeats):
    rows = []
    for n in counts:
        points, pixels, R, t = general_scenes(max(sizes), n, seed=n)
        for B in sizes:
            P, X, Rt, tt = points[:B], pixels[:B], R[:B], t[:B]
            m = min(B, loop_max)
            entry = {"B": B, "n": n, "loop_problems": m, "methods": {}}
            variants = [("jaxpose EPnP", None, None), ("jaxpose EPnP+LM", "lm", None)]
            if B >= 2 * jaxpose.core.pnp.THREAD_MIN_PROBLEMS and jax.local_device_count() == 1:
                # solve_pnp's default splits this batch over host threads: show one thread too
                variants.append(("jaxpose EPnP+LM (1 thread)", "lm", 1))
            for name, refine, workers in variants:
                comp, comp_cpu, run, Re, te, st, cpu = jax_solve(
                    P, X, GENERAL_K, refine, repeats, workers
                )
                er, et = errors(Re, te, Rt, tt)
                entry["methods"][name] = {
                    "per_s": B / run,
                    "cpu_us": 1e6 * cpu / B,
                    "compile_s": comp,
                    "compile_cpu_s": comp_cpu,
                    "ok": float(np.mean(st == 0)),
                    "rot_deg": median(er[:m]),
                    "trans_m": median(et[:m]),
                    "rot_deg_all": median(er),
                    "trans_m_all": median(et),
                }
            sub = (P[:m], X[:m], GENERAL_K)
            competitors = [
                ("OpenCV EPnP", cv_loop, sub + (cv2.SOLVEPNP_EPNP,)),
                ("OpenCV SQPnP", cv_loop, sub + (cv2.SOLVEPNP_SQPNP,)),
                ("OpenCV EPnP+RefineLM", cv_loop, sub + (cv2.SOLVEPNP_EPNP, True)),
            ]
            if poselib is not None:
                competitors.append(("PoseLib", poselib_loop, sub))
            for name, fn, fn_args in competitors:
                # best of `repeats` passes, as for jaxpose (the machine is shared)
                runs, cpus = [], []
                for _ in range(repeats):
                    c0 = time.process_time()
                    runs.append(fn(*fn_args))
                    cpus.append(time.process_time() - c0)
                secs = min(r[0] for r in runs)
                Re, te = runs[-1][1:]
                er, et = errors(Re, te, Rt[:m], tt[:m])
                entry["methods"][name] = {
                    "per_s": m / secs,
                    "cpu_us": 1e6 * min(cpus) / m,
                    "ok": float(np.mean(np.isfinite(er))),
                    "rot_deg": median(er),
                    "trans_m": median(et),
                }
            rows.append(entry)
            print_grid_row(entry)
    return rows


def print_grid_row(entry, title=True):
    if title:
        print(
            f"\nB = {entry['B']}, n = {entry['n']} (loops over {entry['loop_problems']} problems)"
        )
    head = ("method", "problems/s", "CPU us", "rot deg", "trans mm", "ok", "compile s")
    print("  {:27s} {:>11s} {:>7s} {:>8s} {:>8s} {:>6s} {:>10s}".format(*head))
    for name, m in entry["methods"].items():
        comp = f"{m['compile_s']:10.2f}" if "compile_s" in m else f"{'':10s}"
        cpu = f"{m['cpu_us']:7.1f}" if "cpu_us" in m else f"{'':7s}"
        figures = (
            f"{m['per_s']:11.0f} {cpu} {m['rot_deg']:8.4f} {1e3 * m['trans_m']:8.2f} {m['ok']:6.3f}"
        )
        print(f"  {name:27s} {figures} {comp}")


def bench_single(repeats=200):
    points, pixels, _, _ = general_scenes(1, 20, seed=7)
    P, X = points[0], pixels[0]
    # the compiling call, then a few more: the first calls after a compilation run slower
    # (about 2x for a few hundred milliseconds, measured), which is not the steady state
    for _ in range(50):
        jax.block_until_ready(jaxpose.solve_pnp(P, X, GENERAL_K))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(jaxpose.solve_pnp(P, X, GENERAL_K))
        times.append(time.perf_counter() - t0)
    return {"median_ms": 1e3 * float(np.median(times)), "min_ms": 1e3 * float(np.min(times))}


def bench_planar(count):
    points, pixels, R, t = planar_scenes(count)
    out = {}
    for name, refine in (("jaxpose EPnP", None), ("jaxpose EPnP+LM", "lm")):
        _, _, run, Re, te, _, _ = jax_solve(points, pixels, PLANAR_K, refine, repeats=1)
        out[name] = (run, Re, te)
    out["OpenCV EPnP"] = cv_loop(points, pixels, PLANAR_K, cv2.SOLVEPNP_EPNP)
    out["OpenCV EPnP+RefineLM"] = cv_loop(
        points, pixels, PLANAR_K, cv2.SOLVEPNP_EPNP, refine_lm=True
    )
    out["OpenCV ITERATIVE"] = cv_loop(points, pixels, PLANAR_K, cv2.SOLVEPNP_ITERATIVE)
    out["OpenCV SQPnP"] = cv_loop(points, pixels, PLANAR_K, cv2.SOLVEPNP_SQPNP)
    out["OpenCV IPPE"] = cv_ippe_loop(points, pixels, PLANAR_K)
    rows = {}
    print(f"\nPlanar targets at long range ({count} scenes): rotation error < 5 deg")
    print(f"  {'method':24s} {'success':>8s} {'median rot deg':>15s} {'problems/s':>12s}")
    for name, (secs, Re, te) in out.items():
        er, et = errors(Re, te, R, t)
        rate = float(np.mean(np.where(np.isfinite(er), er, np.inf) < 5.0))
        rows[name] = {
            "success": rate,
            "rot_deg": median(er),
            "trans_m": median(et),
            "per_s": count / secs,
        }
        print(f"  {name:24s} {rate:8.3f} {rows[name]['rot_deg']:15.4f} {count / secs:12.0f}")
    return rows


def bench_profile(B=10_000, n=20, repeats=3):
    """Where the time of the batched solve goes (issue 17.4): its two compiled stages (closed
    form, refinement) timed apart as the jitted functions ``solve_pnp`` runs, and the op counts
    of their optimised HLO (``jax.jit(f).lower(...).compile().as_text()``)."""
    import re
    from collections import Counter

    from jaxpose.core.pnp import _solve

    points, pixels, _, _ = general_scenes(B, n, seed=n)
    intrinsics, _ = _solve._intrinsics(GENERAL_K)
    cfg = _solve._Static("epnp", 1e-3, None, PnPOptions().refine, False, PnPOptions().chunk)
    args = (points, pixels, np.ones((B, n), bool), None)
    stage1 = _solve._compiled("stage1", cfg, False, 1)
    stage2 = _solve._compiled("stage2", cfg, False, 1)
    init = jax.block_until_ready(stage1(*args, intrinsics))
    jax.block_until_ready(stage2(init, *args[:3], intrinsics))
    out = {}
    for name, f, a in (
        ("closed form (EPnP)", stage1, args),
        ("refinement", stage2, (init,) + args[:3]),
    ):
        best = math.inf
        for _ in range(repeats):
            c0 = time.process_time()
            jax.block_until_ready(f(*a, intrinsics))
            best = min(best, time.process_time() - c0)
        text = f.lower(*a, intrinsics).compile().as_text()
        ops = Counter(re.findall(r"= \S+ ([a-z][\w-]*)\(", text))
        calls = Counter(re.findall(r'custom_call_target="([^"]+)"', text))
        out[name] = {
            "cpu_us": 1e6 * best / B,
            "fusions": ops["fusion"],
            "while_loops": len(re.findall(r"\bwhile\(", text)),
            "custom_calls": dict(calls),
            "hlo_lines": text.count("\n"),
        }
    print(f"\nWhere the time goes (B = {B}, n = {n}, one thread, CPU time a problem):")
    for name, m in out.items():
        print(
            f"  {name:20s} {m['cpu_us']:6.1f} us  {m['fusions']:4d} fusions  "
            f"{m['while_loops']:3d} loops  custom calls {m['custom_calls'] or 'none'}"
        )
    return out


def all_cores_child(devices, repeats):
    """Run in a child process with ``devices`` forced host devices: EPnP + LM at the target size."""
    assert jax.local_device_count() == devices, jax.devices()
    points, pixels, R, t = general_scenes(10_000, 20, seed=20)
    comp, comp_cpu, run, Re, te, st, _ = jax_solve(points, pixels, GENERAL_K, "lm", repeats)
    er, et = errors(Re, te, R, t)
    print(
        json.dumps(
            {
                "per_s": len(points) / run,
                "compile_s": comp,
                "compile_cpu_s": comp_cpu,
                "ok": float(np.mean(st == 0)),
                "rot_deg": median(er[:2000]),
                "trans_m": median(et[:2000]),
            }
        )
    )


def bench_all_cores(entry, repeats):
    """EPnP + LM at B = 10 000, n = 20 with one JAX device per core (a child process, since the
    device count is fixed when JAX starts): ``solve_pnp`` splits the batch over the devices."""
    import subprocess
    import sys

    if jax.default_backend() != "cpu":
        backend = jax.default_backend()
        print(f"\n  (the run with one JAX device per core is for a CPU; this one is on {backend})")
        return
    cores = os.cpu_count()
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={cores}")
    cmd = [sys.executable, __file__, "--all-cores-child", str(cores), "--repeats", str(repeats)]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        print(f"  (all-cores run failed: {proc.stderr[-500:]})")
        return
    entry["methods"][f"jaxpose EPnP+LM ({cores} devices)"] = json.loads(
        proc.stdout.splitlines()[-1]
    )
    print(f"\nB = {entry['B']}, n = 20 again, one JAX device per core:")
    cores_only = {k: v for k, v in entry["methods"].items() if "devices" in k}
    print_grid_row({**entry, "methods": cores_only}, title=False)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, for a smoke run")
    parser.add_argument("--loop-max", type=int, default=10_000, help="problems per competitor loop")
    parser.add_argument("--planar", type=int, default=1000, help="planar scenes")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sizes", type=int, nargs="+", help="batch sizes (default 1 100 10000)")
    parser.add_argument(
        "--points", type=int, nargs="+", help="points per problem (default 6 20 100)"
    )
    parser.add_argument("--all-cores-child", type=int, help=argparse.SUPPRESS)
    parser.add_argument(
        "--no-profile", action="store_true", help="skip the per-stage profile of the solve"
    )
    args = parser.parse_args(argv)
    if args.all_cores_child:
        return all_cores_child(args.all_cores_child, args.repeats)
    sizes = tuple(args.sizes or ((1, 100) if args.quick else (1, 100, 10_000)))
    counts = tuple(args.points or ((20,) if args.quick else (6, 20, 100)))
    planar = 200 if args.quick else args.planar
    load0 = os.getloadavg()
    print(
        f"jaxpose bench/pnp.py on {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} CPUs, load average {load0[0]:.1f}; jax {jax.__version__}, "
        f"OpenCV {cv2.__version__}, PoseLib {getattr(poselib, '__version__', 'missing')}"
    )

    grid = bench_grid(sizes, counts, args.loop_max, args.repeats)
    single = bench_single()
    print(
        f"\nSingle problem (n = 20) after compilation: median {single['median_ms']:.3f} ms, "
        f"best {single['min_ms']:.3f} ms"
    )
    planar_rows = bench_planar(planar) if planar > 0 else None
    profile = None if args.no_profile else bench_profile(repeats=args.repeats)
    big = next((g for g in grid if g["B"] == max(sizes) and g["n"] == 20), None)
    if big is not None and (os.cpu_count() or 1) > 1 and jax.local_device_count() == 1:
        bench_all_cores(big, args.repeats)

    targets = {}
    if big is not None:
        ours, cv = big["methods"]["jaxpose EPnP+LM"], big["methods"]["OpenCV EPnP+RefineLM"]
        targets["throughput_ratio"] = ours["per_s"] / cv["per_s"]
        one = big["methods"].get("jaxpose EPnP+LM (1 thread)")
        if one is not None:
            targets["throughput_ratio_one_thread"] = one["per_s"] / cv["per_s"]
            # CPU time a problem: insensitive to waiting for a core on a loaded machine
            targets["cpu_time_ratio_one_thread"] = cv["cpu_us"] / one["cpu_us"]
        cores = next((m for k, m in big["methods"].items() if k.endswith("devices)")), None)
        if cores is not None:
            targets["throughput_ratio_all_cores"] = cores["per_s"] / cv["per_s"]
        sq = big["methods"]["OpenCV SQPnP"]
        base = one if one is not None else ours
        # issue 17.4: CPU time a problem on one thread at most SQPnP's, medians no worse
        targets["cpu_time_ratio_vs_sqpnp"] = base["cpu_us"] / sq["cpu_us"]
        targets["rot_ratio_vs_sqpnp"] = base["rot_deg"] / sq["rot_deg"]
        targets["trans_ratio_vs_sqpnp"] = base["trans_m"] / sq["trans_m"]
        targets["median_rot_no_worse_than_sqpnp"] = base["rot_deg"] <= sq["rot_deg"]
        targets["median_trans_no_worse_than_sqpnp"] = base["trans_m"] <= sq["trans_m"]
        targets["median_rot_no_worse"] = ours["rot_deg"] <= cv["rot_deg"] * 1.0001
        targets["median_trans_no_worse"] = ours["trans_m"] <= cv["trans_m"] * 1.0001
        targets["compile_s"] = ours["compile_s"]
        targets["compile_cpu_s"] = ours["compile_cpu_s"]
    targets["single_ms"] = single["median_ms"]
    if planar_rows is not None:
        best_cv = max(planar_rows["OpenCV SQPnP"]["success"], planar_rows["OpenCV IPPE"]["success"])
        targets["planar_success"] = planar_rows["jaxpose EPnP+LM"]["success"]
        targets["planar_best_opencv"] = best_cv
    print("\nTargets (issues 3 and 17.4):")
    if "throughput_ratio" in targets:
        print(
            f"  B={max(sizes)}, n=20 EPnP+LM vs loop of OpenCV EPnP+RefineLM: "
            f"{targets['throughput_ratio']:.1f}x (target >= 5x); median errors no worse: "
            f"rotation {targets['median_rot_no_worse']}, "
            f"translation {targets['median_trans_no_worse']}"
        )
        if "throughput_ratio_one_thread" in targets:
            print(
                f"  the same with workers=1 (one host thread): "
                f"{targets['throughput_ratio_one_thread']:.1f}x"
            )
        if "cpu_time_ratio_one_thread" in targets:
            print(
                "  CPU time a problem, OpenCV loop / jaxpose with workers=1: "
                f"{targets['cpu_time_ratio_one_thread']:.1f}x"
            )
        if "throughput_ratio_all_cores" in targets:
            print(
                f"  the same on all {os.cpu_count()} cores (one JAX device each): "
                f"{targets['throughput_ratio_all_cores']:.1f}x"
            )
        print(
            "  issue 17.4, one thread against OpenCV SQPnP: CPU time a problem "
            f"{targets['cpu_time_ratio_vs_sqpnp']:.2f}x SQPnP's (target <= 1); median errors "
            f"{targets['rot_ratio_vs_sqpnp']:.4f}x (rotation), "
            f"{targets['trans_ratio_vs_sqpnp']:.4f}x (translation) SQPnP's (target <= 1)"
        )
        print(
            f"  compilation of the batched solve: {targets['compile_s']:.2f} s wall, "
            f"{targets['compile_cpu_s']:.2f} s CPU (target <= 10 s)"
        )
    print(f"  single problem after compilation: {targets['single_ms']:.3f} ms (target <= 1 ms)")
    if planar_rows is not None:
        print(
            f"  planar long range, rot < 5 deg: jaxpose {targets['planar_success']:.3f}, best "
            f"OpenCV (SQPnP/IPPE) {targets['planar_best_opencv']:.3f} (target: at least as often)"
        )
    load1 = os.getloadavg()
    print(f"  load average at start {load0[0]:.1f}, at end {load1[0]:.1f} on {os.cpu_count()} CPUs")
    print(
        json.dumps(
            {
                "bench": "pnp",
                "backend": jax.default_backend(),
                "cpus": os.cpu_count(),
                "load_average": [load0[0], load1[0]],
                "grid": grid,
                "single": single,
                "planar": planar_rows,
                "profile": profile,
                "targets": targets,
                "software": software_versions(),
            }
        )
    )


if __name__ == "__main__":
    main()
