"""Benchmark of DOP-based feature-point selection (Ning, Zhang, Wang 2018).

Parts, each a function called by :func:`main`:

(a) :func:`bench_kernel`: the exhaustive kernel (:func:`jaxpose.core.select.exhaustive_batch`,
float64
    and float32-with-float64-recheck) against a plain NumPy loop over subsets (``np.linalg.inv``
    per subset, timed on a sample and extrapolated) and against a straightforward batched
    ``jnp.linalg.inv`` (stack all subset matrices, invert, take traces), in subsets per second;
(b) :func:`bench_quasi`: quasi-optimal against exhaustive per case at ``n = 18, m = 8``;
    :func:`bench_table4`: the whole Table 4 (``n`` in 12, 14, 16, 18, ``m = 8``, ``--cases`` each:
    both exhaustive optima plus quasi-optimal), run time after compilation;
(c) :func:`bench_bnb`: branch and bound at ``n`` = 24, 30, 40, 60, ``m = 8``, both criteria: median
    and max time and nodes over ``--bnb-cases`` cases, the exhaustive search at ``n = 24``, the
    weaker bounds and the NumPy host loop (what the bound and the implementation buy).

Cases are the select-study's default scenario (:class:`jaxpose.studies.selection.Scenario`).
Compile time and run time are reported apart; every run time is the best of ``--repeats`` runs
after a warm-up. Prints a table, then one JSON line with every figure.

    python bench/selection.py                 # full size (Table 4 with 1000 cases per group)
    python bench/selection.py --cases 100     # smaller Table 4
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxpose import select as sel  # noqa: E402
from jaxpose.core.dilution import information_blocks  # noqa: E402
from jaxpose.core.geometry import Pose  # noqa: E402
from jaxpose.studies.selection import Scenario, make_cases  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from bnb_numpy import branch_and_bound_numpy  # noqa: E402  (the test oracle, timed here)

M = 8
TABLE4_N = (12, 14, 16, 18)


# ----------------------------------------------------------------------------- helpers
def problems(n: int, cases: int, seed: int = 0, scenario: Scenario | None = None):
    """Per-point information blocks ``(C, n, 6, 6)`` and camera-frame points ``(C, n, 3)``."""
    scenario = scenario or Scenario()
    points, angles = make_cases(scenario, n, range(cases), seed)
    camera = scenario.camera()
    t = jnp.array([scenario.offset_x_m, scenario.offset_y_m, scenario.range_m])

    @jax.jit
    @jax.vmap
    def one(p, a):
        pose = Pose.from_euler(a, t, scenario.sequence)
        blocks = information_blocks(p, pose, camera, sequence=scenario.sequence)
        return blocks, pose.apply(p)

    blocks, points_cam = one(jnp.asarray(points), jnp.asarray(angles))
    return jax.block_until_ready(blocks), points_cam


def timed(fn, *args, repeats: int = 3):
    """``(compile_s, best_run_s, output)`` of a jitted function (compile = first call)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    compile_s = time.perf_counter() - t0
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t0)
    return compile_s, best, out


def numpy_loop(blocks: np.ndarray, combos) -> tuple[float, int, float, int]:
    """The plain per-subset loop: min PDOP and min ADOP with ``np.linalg.inv``."""
    best_p, best_a, arg_p, arg_a = math.inf, math.inf, -1, -1
    for r, s in enumerate(combos):
        Q = np.linalg.inv(blocks[list(s)].sum(axis=0))
        p = math.sqrt(np.trace(Q[:3, :3]))
        a = math.sqrt(np.trace(Q[3:, 3:]))
        if p < best_p:
            best_p, arg_p = p, r
        if a < best_a:
            best_a, arg_a = a, r
    return best_p, arg_p, best_a, arg_a


def make_batched_inv(n: int, m: int):
    """The straightforward JAX version: stack every subset matrix, invert, take traces."""
    combos = jnp.asarray(list(itertools.combinations(range(n), m)))

    @jax.jit
    def run(blocks):  # (C, n, 6, 6)
        A = jnp.sum(blocks[:, combos], axis=2)  # (C, K, 6, 6)
        Q = jnp.linalg.inv(A)
        d = jnp.diagonal(Q, axis1=-2, axis2=-1)
        p = jnp.sqrt(jnp.sum(d[..., :3], -1))
        a = jnp.sqrt(jnp.sum(d[..., 3:], -1))
        return jnp.argmin(p, 1), jnp.min(p, 1), jnp.argmin(a, 1), jnp.min(a, 1)

    return run, combos


def exhaustive_fn(m: int, **options):
    return jax.jit(lambda b: sel.exhaustive_batch(b, m, throw=False, **options))


# ----------------------------------------------------------------------------- (a)
def bench_kernel(
    n: int = 18,
    cases: int = 100,
    inv_cases: int = 4,
    numpy_subsets: int = 3000,
    repeats: int = 3,
) -> dict:
    """(a) Exhaustive kernel vs NumPy loop vs batched ``jnp.linalg.inv`` at ``n``, ``m = 8``."""
    K = math.comb(n, M)
    blocks, _ = problems(n, max(cases, inv_cases), seed=1)
    out: dict = {"n": n, "m": M, "subsets_per_case": K}

    for name, options in (("float64", {}), ("float32", {"kernel_dtype": jnp.float32})):
        fn = exhaustive_fn(M, **options)
        for label, C in (("batch", cases), ("small", inv_cases)):
            c_s, run_s, res = timed(fn, blocks[:C], repeats=repeats)
            out[f"ours_{name}_{label}"] = {
                "cases": C,
                "compile_s": c_s,
                "run_s": run_s,
                "subsets_per_s": C * K / run_s,
            }
        if name == "float64":
            ref = res

    inv, _ = make_batched_inv(n, M)
    c_s, run_s, (ip, pv, ia, av) = timed(inv, blocks[:inv_cases], repeats=repeats)
    out["batched_inv"] = {
        "cases": inv_cases,
        "compile_s": c_s,
        "run_s": run_s,
        "subsets_per_s": inv_cases * K / run_s,
    }
    # Same optima (up to exact ties) as the kernel on these cases.
    out["batched_inv_agrees"] = bool(
        np.allclose(np.asarray(pv), np.asarray(ref.pdop[:inv_cases]), rtol=1e-9)
        and np.allclose(np.asarray(av), np.asarray(ref.adop[:inv_cases]), rtol=1e-9)
    )

    b0 = np.asarray(blocks[0])
    sample = list(itertools.islice(itertools.combinations(range(n), M), numpy_subsets))
    t0 = time.perf_counter()
    numpy_loop(b0, sample)
    loop_s = time.perf_counter() - t0
    out["numpy_loop"] = {
        "subsets_timed": len(sample),
        "subsets_per_s": len(sample) / loop_s,
        "extrapolated_case_s": K * loop_s / len(sample),
    }
    ours = out["ours_float64_batch"]["subsets_per_s"]
    ours_small = out["ours_float64_small"]["subsets_per_s"]
    out["speedup_vs_numpy"] = ours / out["numpy_loop"]["subsets_per_s"]
    out["speedup_vs_batched_inv"] = ours / out["batched_inv"]["subsets_per_s"]
    out["speedup_vs_batched_inv_same_cases"] = ours_small / out["batched_inv"]["subsets_per_s"]
    out["float32_speedup"] = out["ours_float32_batch"]["subsets_per_s"] / ours
    return out


def bench_float32_error(n: int = 14, cases: int = 100, ranges=(3.0, 10.0, 30.0, 100.0, 300.0)):
    """What :data:`jaxpose.core.select._exhaustive.FLOAT32_MARGIN` rests on: the relative error of
    the float32 kernel's scores against float64 over every subset, at several ranges, and how many
    cases the float32 kernel cannot certify (near-ties, searched again in float64)."""
    import dataclasses
    import sys

    from jaxpose.core.select._kernel import traces

    ex = sys.modules["jaxpose.core.select._exhaustive"]
    K = math.comb(n, M)
    member = jax.nn.one_hot(sel.unrank_combinations(jnp.arange(K), n, M), n).sum(1)

    @jax.jit
    def errors(blocks):
        F64, _ = ex._prepare(blocks, jnp.ones(blocks.shape[:2], bool), jnp.float64)
        sums = jnp.einsum("kcn,sn->kcs", F64, member)
        exact = traces([sums[i] for i in range(21)])
        sums32 = jnp.einsum("kcn,sn->kcs", F64.astype(jnp.float32), member.astype(jnp.float32))
        single = traces([sums32[i] for i in range(21)], tol=1e-13)  # as the float32 kernel
        rel = [jnp.abs(single[j].astype(jnp.float64) / exact[j] - 1) for j in (0, 1)]
        best = [jnp.argmin(exact[j], axis=1) for j in (0, 1)]
        at_best = [jnp.take_along_axis(rel[j], best[j][:, None], 1) for j in (0, 1)]
        second = [jnp.sort(exact[j], axis=1)[:, :2] for j in (0, 1)]
        gap = jnp.minimum(*[s[:, 1] / s[:, 0] - 1 for s in second])
        return jnp.maximum(*rel).max(), jnp.maximum(*at_best).max(), gap

    rows = []
    for r in ranges:
        scenario = dataclasses.replace(Scenario(), range_m=r)
        blocks, _ = problems(n, cases, seed=5, scenario=scenario)
        worst, worst_at_best, gap = errors(blocks)
        rows.append(
            {
                "range_m": r,
                "max_rel_error": float(worst),
                "max_rel_error_at_optimum": float(worst_at_best),
                "uncertified_fraction": float(np.mean(np.asarray(gap) < ex.FLOAT32_MARGIN)),
            }
        )
    return {"n": n, "m": M, "cases": cases, "margin": ex.FLOAT32_MARGIN, "ranges": rows}


# ----------------------------------------------------------------------------- (b)
def bench_quasi(n: int = 18, cases: int = 1000, repeats: int = 3) -> dict:
    """(b) Quasi-optimal vs exhaustive per case at ``n``, ``m = 8``: batched and one case."""
    blocks, points_cam = problems(n, cases, seed=2)
    quasi = jax.jit(jax.vmap(lambda p: sel.quasi_optimal(p, M)))
    ex = exhaustive_fn(M)
    cq, tq, _ = timed(quasi, points_cam, repeats=max(repeats, 20))  # ~1 ms: more repeats
    ce, te, _ = timed(ex, blocks, repeats=repeats)
    quasi1 = jax.jit(lambda p: sel.quasi_optimal(p, M))
    ex1 = jax.jit(lambda b: sel.exhaustive(b, M, throw=False))
    _, tq1, _ = timed(quasi1, points_cam[0], repeats=max(repeats, 20))
    _, te1, _ = timed(ex1, blocks[0], repeats=repeats)
    return {
        "n": n,
        "m": M,
        "cases": cases,
        "quasi_per_case_s": tq / cases,
        "exhaustive_per_case_s": te / cases,
        "speedup_batched": te / tq,
        "quasi_one_case_s": tq1,
        "exhaustive_one_case_s": te1,
        "speedup_one_case": te1 / tq1,
        "compile_s": {"quasi": cq, "exhaustive": ce},
    }


def bench_table4(cases: int = 1000, repeats: int = 1, kernel_dtype=None) -> dict:
    """Whole Table 4: quasi-optimal plus both exhaustive optima for every group (run time)."""
    groups = []
    total = 0.0
    options = {} if kernel_dtype is None else {"kernel_dtype": kernel_dtype}
    for n in TABLE4_N:
        blocks, points_cam = problems(n, cases, seed=3)

        @jax.jit
        def both(blocks, points_cam, _options=options):
            q = jax.vmap(lambda p: sel.quasi_optimal(p, M))(points_cam)
            opt = sel.exhaustive_batch(blocks, M, throw=False, **_options)
            pq, aq = jax.vmap(sel.subset_dop)(blocks, q)
            return opt, pq / opt.pdop, aq / opt.adop

        c_s, run_s, (opt, rp, ra) = timed(both, blocks, points_cam, repeats=repeats)
        total += run_s
        K = math.comb(n, M)
        groups.append(
            {
                "n": n,
                "cases": cases,
                "subsets": cases * K,
                "compile_s": c_s,
                "run_s": run_s,
                "subsets_per_s": cases * K / run_s,
                "pdop_ratio_mean": float(np.mean(rp)),
                "adop_ratio_mean": float(np.mean(ra)),
                "min_ratio": float(min(np.min(rp), np.min(ra))),
                "bad_status": int(np.sum(np.asarray(opt.status) != 0)),
            }
        )
    subsets = sum(g["subsets"] for g in groups)
    return {
        "groups": groups,
        "run_s": total,
        "subsets": subsets,
        "subsets_per_s": subsets / total,
        "kernel_dtype": "float32" if kernel_dtype is not None else "float64",
    }


# ----------------------------------------------------------------------------- (c)
BNB_N = (24, 30, 40, 60)
BNB_SCENARIO = Scenario(focal_length_m=0.0165)  # fx = 3000 px; otherwise the study's default


def _bnb_case_runs(blocks, criterion: str, **options) -> dict:
    """Time and nodes of :func:`jaxpose.core.select.branch_and_bound`, one case at a time."""
    times, nodes, iters, values, idx, heuristic_hit, status = [], [], [], [], [], [], []
    for b in blocks:
        t0 = time.perf_counter()
        res = sel.branch_and_bound(b, M, criterion=criterion, throw=False, **options)
        res = jax.block_until_ready(res)
        times.append(time.perf_counter() - t0)
        nodes.append(int(res.nodes))
        iters.append(int(res.iterations))
        values.append(float(res.value))
        idx.append(np.asarray(res.idx))
        heuristic_hit.append(bool(float(res.heuristic_value) <= float(res.value) * (1 + 1e-12)))
        status.append(int(res.status))
    return {
        "cases": len(times),
        "time_s": {"median": float(np.median(times)), "max": float(np.max(times))},
        "nodes": {"median": float(np.median(nodes)), "max": int(np.max(nodes))},
        "fw_iterations": {"median": float(np.median(iters)), "max": int(np.max(iters))},
        "heuristic_was_optimal": int(np.sum(heuristic_hit)),
        "bad_status": int(np.sum(np.asarray(status) != 0)),
        "_values": values,
        "_idx": idx,
    }


def bench_bnb(args) -> dict | None:
    """(c) Branch and bound at n = 24, 30, 40, 60, m = 8: time and nodes, both criteria.

    Per ``n``: ``--bnb-cases`` cases (default 20) of the paper's scenario (features uniform in a
    1 m square, fx = 3000 px, 10 m range, 20 deg per axis), one case per call (the eager entry
    point, as a user calls it), median and max over cases of wall time and of nodes visited, after
    one compile per ``n`` (reported apart). Also: the exhaustive search at n = 24 (time, and that
    both agree on every case), the weaker bounds and no heuristic incumbent (nodes: what the
    relaxation bound and the ordering buy), and the NumPy host loop with the same algorithm (the
    implementation choice).
    """
    cases = getattr(args, "bnb_cases", 20)
    few = min(cases, 5)
    out: dict = {"m": M, "cases": cases, "fx_px": float(BNB_SCENARIO.camera().fx), "groups": []}
    for n in BNB_N:
        blocks, _ = problems(n, cases, seed=4, scenario=BNB_SCENARIO)
        blocks = np.asarray(blocks)
        t0 = time.perf_counter()
        jax.block_until_ready(sel.branch_and_bound(blocks[0], M, throw=False))
        group: dict = {"n": n, "subsets": math.comb(n, M), "compile_s": time.perf_counter() - t0}
        for criterion in ("pdop", "adop"):
            group[criterion] = _bnb_case_runs(blocks, criterion)
        if n == 24:
            ex = jax.jit(lambda b: sel.exhaustive(b, M, throw=False))
            t0 = time.perf_counter()
            jax.block_until_ready(ex(blocks[0]))
            ex_compile = time.perf_counter() - t0
            ex_times, agree = [], True
            for c, b in enumerate(blocks):
                t0 = time.perf_counter()
                r = jax.block_until_ready(ex(b))
                ex_times.append(time.perf_counter() - t0)
                for crit in ("pdop", "adop"):
                    ours = group[crit]
                    agree &= bool(np.array_equal(getattr(r, f"{crit}_idx"), ours["_idx"][c]))
                    value = float(getattr(r, crit))
                    agree &= bool(np.isclose(value, ours["_values"][c], rtol=1e-9))
            group["exhaustive"] = {
                "compile_s": ex_compile,
                "time_s": {"median": float(np.median(ex_times)), "max": float(np.max(ex_times))},
                "agrees_with_bnb": agree,
            }
            for bound in ("linear", "monotone"):
                group[f"pdop_{bound}_bound"] = _bnb_case_runs(blocks, "pdop", bound=bound)
        if n == 40:
            group["pdop_linear_bound"] = _bnb_case_runs(blocks, "pdop", bound="linear")
            # The classical bound alone takes seconds per case here: a few cases only.
            group["pdop_monotone_bound"] = _bnb_case_runs(blocks[:3], "pdop", bound="monotone")
        if n == 60:
            group["pdop_no_heuristic"] = _bnb_case_runs(blocks, "pdop", heuristic=False)
            group["pdop_linear_bound"] = _bnb_case_runs(blocks, "pdop", bound="linear")
            host = []
            for b in blocks[:few]:
                t0 = time.perf_counter()
                branch_and_bound_numpy(b, M, criterion="pdop")
                host.append(time.perf_counter() - t0)
            group["pdop_numpy_host_loop"] = {
                "cases": few,
                "time_s": {"median": float(np.median(host)), "max": float(np.max(host))},
            }
        for v in group.values():
            if isinstance(v, dict):
                v.pop("_values", None)
                v.pop("_idx", None)
        out["groups"].append(group)
    by_n = {g["n"]: g for g in out["groups"]}
    out["target_n40_median_s_le_2"] = bool(
        max(by_n[40][c]["time_s"]["median"] for c in ("pdop", "adop")) <= 2.0
    )
    out["target_n60_median_s_le_60"] = bool(
        max(by_n[60][c]["time_s"]["median"] for c in ("pdop", "adop")) <= 60.0
    )
    report_bnb(out)
    return out


# ----------------------------------------------------------------------------- report
def _row(label: str, value: str) -> None:
    print(f"  {label:<52} {value}")


def report_kernel(k: dict) -> None:
    print(f"(a) exhaustive kernel, n = {k['n']}, m = {k['m']} ({k['subsets_per_case']} per case)")
    for key in ("ours_float64_batch", "ours_float32_batch", "ours_float64_small", "batched_inv"):
        v = k[key]
        _row(
            f"{key} ({v['cases']} cases)",
            f"{v['subsets_per_s'] / 1e6:8.2f} M subsets/s  (run {v['run_s']:.3f} s, "
            f"compile {v['compile_s']:.1f} s)",
        )
    _row("numpy loop (sample)", f"{k['numpy_loop']['subsets_per_s'] / 1e6:8.4f} M subsets/s")
    _row("speed-up vs numpy loop (target >= 50)", f"{k['speedup_vs_numpy']:8.0f}x")
    _row("speed-up vs batched inv (target >= 10)", f"{k['speedup_vs_batched_inv']:8.1f}x")
    _row("  same case count as batched inv", f"{k['speedup_vs_batched_inv_same_cases']:8.1f}x")
    _row("float32 kernel vs float64", f"{k['float32_speedup']:8.2f}x")


def report_float32(f: dict) -> None:
    print(f"float32 kernel error vs float64, n = {f['n']}, m = {f['m']}, {f['cases']} cases")
    for r in f["ranges"]:
        _row(
            f"range {r['range_m']:g} m: max rel. error (all / optima)",
            f"{r['max_rel_error']:.1e} / {r['max_rel_error_at_optimum']:.1e}, "
            f"{100 * r['uncertified_fraction']:.1f}% near-ties < margin {f['margin']:g}",
        )


def report_quasi(q: dict) -> None:
    print(f"(b) quasi-optimal vs exhaustive per case, n = {q['n']}, m = {q['m']}")
    _row(f"batched ({q['cases']} cases): quasi per case", f"{q['quasi_per_case_s'] * 1e6:10.2f} us")
    _row("batched: exhaustive per case", f"{q['exhaustive_per_case_s'] * 1e6:10.2f} us")
    _row("batched speed-up (target >= 1000)", f"{q['speedup_batched']:10.0f}x")
    _row("one case: quasi", f"{q['quasi_one_case_s'] * 1e6:10.2f} us")
    _row("one case: exhaustive", f"{q['exhaustive_one_case_s'] * 1e6:10.2f} us")
    _row("one-case speed-up", f"{q['speedup_one_case']:10.0f}x")


def report_table4(t: dict) -> None:
    print(f"Table 4 (quasi + min-PDOP + min-ADOP, kernel {t['kernel_dtype']})")
    for g in t["groups"]:
        _row(
            f"n = {g['n']}, {g['cases']} cases, {g['subsets'] / 1e6:.1f} M subsets",
            f"{g['run_s']:7.2f} s  {g['subsets_per_s'] / 1e6:6.2f} M/s  ratios "
            f"{g['pdop_ratio_mean']:.4f} / {g['adop_ratio_mean']:.4f}",
        )
    total = f"{t['run_s']:7.2f} s  {t['subsets_per_s'] / 1e6:6.2f} M/s"
    _row("total run time (target <= 15 s)", total)


def report_bnb(b: dict) -> None:
    print(f"(c) branch and bound, m = {b['m']}, {b['cases']} cases per n (median / max over cases)")
    for g in b["groups"]:
        print(
            f"  n = {g['n']} ({g['subsets'] / 1e6:.1f} M subsets), compile {g['compile_s']:.1f} s"
        )
        for key, v in g.items():
            if not isinstance(v, dict) or "time_s" not in v:
                continue
            nodes = " " * 27
            if "nodes" in v:
                nodes = f"nodes {v['nodes']['median']:9.0f} / {v['nodes']['max']:9d}"
            extra = ""
            if "heuristic_was_optimal" in v:
                extra = f"  start optimal {v['heuristic_was_optimal']}/{v['cases']}"
            if "agrees_with_bnb" in v:
                extra = f"  agrees with b&b: {v['agrees_with_bnb']}"
            _row(
                f"  {key} ({v.get('cases', b['cases'])} cases)",
                f"{v['time_s']['median'] * 1e3:9.1f} / {v['time_s']['max'] * 1e3:9.1f} ms  "
                f"{nodes}{extra}",
            )
    _row(
        "n = 40 median <= 2 s, n = 60 median <= 60 s",
        f"{b['target_n40_median_s_le_2']}, {b['target_n60_median_s_le_60']}",
    )


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=1000, help="cases per Table 4 group")
    parser.add_argument("--kernel-cases", type=int, default=100, help="cases for part (a)")
    parser.add_argument("--inv-cases", type=int, default=4, help="cases for the batched inv")
    parser.add_argument("--numpy-subsets", type=int, default=3000, help="NumPy loop sample")
    parser.add_argument("--quasi-cases", type=int, default=1000, help="cases for part (b)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--bnb-cases", type=int, default=20, help="cases per n for part (c)")
    parts = ["kernel", "quasi", "table4", "table4-f32", "bnb"]
    parser.add_argument("--skip", nargs="*", default=[], choices=parts, help="parts to leave out")
    args = parser.parse_args(argv)

    figures: dict = {
        "machine": {
            "cpu_count": os.cpu_count(),
            "platform": platform.platform(),
            "jax": jax.__version__,
            "backend": jax.default_backend(),
            "load_average_start": list(os.getloadavg()),
        }
    }
    if "kernel" not in args.skip:
        figures["kernel"] = bench_kernel(
            cases=args.kernel_cases,
            inv_cases=args.inv_cases,
            numpy_subsets=args.numpy_subsets,
            repeats=args.repeats,
        )
        report_kernel(figures["kernel"])
        figures["float32_error"] = bench_float32_error()
        report_float32(figures["float32_error"])
    if "quasi" not in args.skip:
        figures["quasi"] = bench_quasi(cases=args.quasi_cases, repeats=args.repeats)
        report_quasi(figures["quasi"])
    if "table4" not in args.skip:
        figures["table4"] = bench_table4(cases=args.cases)
        report_table4(figures["table4"])
    if "table4-f32" not in args.skip:
        figures["table4_float32"] = bench_table4(cases=args.cases, kernel_dtype=jnp.float32)
        report_table4(figures["table4_float32"])
    if "bnb" not in args.skip:
        bnb = bench_bnb(args)
        if bnb is not None:
            figures["bnb"] = bnb
    figures["machine"]["load_average_end"] = list(os.getloadavg())
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    main()
