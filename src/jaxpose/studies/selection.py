"""Monte Carlo study of feature-point selection: Ning, Zhang, Wang (2018), Section 5.

Reproduces Table 4 (``n`` in 12, 14, 16, 18 with ``m = 8``: mean and max PDOP and ADOP ratios of
the quasi-optimal selection to the exhaustive optimum; Fig. 6 histograms), Tables 5-6 (``m`` from 4
to 17 of ``n = 18``: mean DOP of the optimal and quasi-optimal subsets and of all points, % decrease
and ratio to all; Fig. 8) and the timing comparison (Figs. 9-10).

How a run is organised:

* A *group* is one ``(n, m)``; its cases are drawn from ``SeedSequence([seed, n, case])``, so the
  points of case ``c`` do not depend on ``m``, on the chunking or on the number of devices (the
  ``n = 18`` cases of Table 4 are the cases of Tables 5-6).
* Cases are processed in *chunks*; each finished chunk is saved under ``OUT/chunks/`` with the
  scenario's fingerprint, and a rerun with the same options loads it instead of recomputing it
  (an interrupted run resumes where it stopped).
* Every chunk is spread over all local JAX devices with ``jax.sharding`` (a 1-D ``cases`` mesh),
  the road to multi-GPU and multi-host runs; a case is computed the same way on any device count.

Outputs: ``results.json`` (schema in ``docs/methods.md``, plus the derived Tables 5-6), PNG
figures, and with ``--dump-cases`` ``cases.npz`` holding every case for independent re-checks.

The default scenario (Table 3 of the paper is lost) is documented in :class:`Scenario`.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.dilution import dop_from_information, information_blocks
from jaxpose.core.geometry import Pose

__all__ = [
    "PAPER_GROUPS",
    "Scenario",
    "StudyResult",
    "default_groups",
    "make_cases",
    "run_study",
]

TABLE4_GROUPS = [(12, 8), (14, 8), (16, 8), (18, 8)]
TABLE56_GROUPS = [(18, m) for m in range(4, 18)]
PAPER_GROUPS = sorted(set(TABLE4_GROUPS + TABLE56_GROUPS))


@dataclasses.dataclass(frozen=True)
class Scenario:
    """Simulation parameters (Ning et al. Table 3 is lost; these are jaxpose's documented defaults).

    Features are uniform in a ``plane_size_m`` square of the body ``z = 0`` plane centred at
    ``plane_centre_m`` (the body origin by default; ``(0.5, 0.5)`` puts the origin at a corner, as
    MATLAB's ``rand`` would), seen by a ``focal_length_m`` lens with ``pixel_size_m`` pixels on an
    ``image_size`` sensor. The target origin sits at ``(offset_x_m, offset_y_m, range_m)`` in the
    camera frame and the relative attitude is ``attitude_deg`` (Euler angles of ``sequence`` in
    degrees, the same for every case; with ``random_attitude`` each case draws each angle
    uniformly in ``[-attitude_deg, +attitude_deg]``).

    The selection and the DOP *ratios* do not depend on focal length or pixel size (DOP scales as
    pixel size / focal length); they depend on range, offset and attitude (README table).
    """

    focal_length_m: float = 0.05
    pixel_size_m: float = 5.5e-6
    image_size: tuple[int, int] = (2048, 2048)
    range_m: float = 10.0
    offset_x_m: float = 0.0
    offset_y_m: float = 0.0
    attitude_deg: tuple[float, float, float] = (20.0, 20.0, 20.0)
    random_attitude: bool = False
    plane_size_m: float = 1.0
    plane_centre_m: tuple[float, float] = (0.0, 0.0)
    sequence: str = "XYZ"
    parameterization: str = "euler"
    sigma_px: float = 1.0

    def camera(self) -> PinholeCamera:
        return PinholeCamera.from_focal_length(
            self.focal_length_m, self.pixel_size_m, self.image_size
        )

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["image_size"] = list(self.image_size)
        d["attitude_deg"] = list(self.attitude_deg)
        d["plane_centre_m"] = list(self.plane_centre_m)
        return d

    def fingerprint(self, seed: int) -> str:
        blob = json.dumps({"scenario": self.to_dict(), "seed": seed, "v": 1}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


def make_cases(scenario: Scenario, n: int, cases: range | list[int], seed: int):
    """Points ``(C, n, 3)`` (body frame, m) and attitudes ``(C, 3)`` (rad) of the given cases."""
    half = scenario.plane_size_m / 2.0
    pts, att = [], []
    for c in cases:
        rng = np.random.default_rng(np.random.SeedSequence([seed, n, c]))
        xy = rng.uniform(-half, half, size=(n, 2)) + np.asarray(scenario.plane_centre_m)
        pts.append(np.c_[xy, np.zeros(n)])
        a = np.asarray(scenario.attitude_deg, dtype=float)
        if scenario.random_attitude:
            a = rng.uniform(-a, a)
        att.append(np.deg2rad(a))
    return np.asarray(pts), np.asarray(att)


def _translation(scenario: Scenario) -> np.ndarray:
    return np.array([scenario.offset_x_m, scenario.offset_y_m, scenario.range_m])


def _kernels(scenario: Scenario, m: int):
    """Jitted per-chunk functions: blocks, quasi selection, exhaustive optima, DOP of subsets."""
    from jaxpose.core import select as sel

    camera = scenario.camera()
    t = jnp.asarray(_translation(scenario))

    def blocks_and_cam(points, angles):
        pose = Pose.from_euler(angles, t, scenario.sequence)
        blocks = information_blocks(
            points,
            pose,
            camera,
            sigma=scenario.sigma_px,
            sequence=scenario.sequence,
            parameterization=scenario.parameterization,
        )
        return blocks, pose.apply(points)

    @jax.jit
    def prepare(points, angles):
        blocks, points_cam = jax.vmap(blocks_and_cam)(points, angles)
        all_dop = jax.vmap(dop_from_information)(jnp.sum(blocks, axis=1))
        return blocks, points_cam, all_dop.pdop, all_dop.adop

    @jax.jit
    def quasi(points_cam):
        return jax.vmap(lambda p: sel.quasi_optimal(p, m))(points_cam)

    # A bad case gets a status (counted in results.json as failed_cases), not an exception.
    exhaustive = jax.jit(lambda blocks: sel.exhaustive_batch(blocks, m, throw=False))

    @jax.jit
    def subset(blocks, idx):
        return jax.vmap(sel.subset_dop)(blocks, idx)

    compiled: dict = {}  # AOT executables per input shape: compiled once, outside the timings
    return prepare, quasi, exhaustive, subset, compiled


def _shard(x, sharding):
    return jax.device_put(x, sharding) if sharding is not None else x


def _run_chunk(kernels, points, angles, sharding):
    """One chunk: returns per-case arrays and the run times of the two selection methods."""
    prepare, quasi, exhaustive, subset, compiled = kernels
    points, angles = _shard(points, sharding), _shard(angles, sharding)
    blocks, points_cam, pdop_all, adop_all = prepare(points, angles)
    jax.block_until_ready(blocks)
    # Compile outside the timed region (AOT, once per shape), then time each method.
    key = blocks.shape
    if key not in compiled:
        compiled[key] = (quasi.lower(points_cam).compile(), exhaustive.lower(blocks).compile())
    q_fn, e_fn = compiled[key]
    # The quasi-optimal call takes microseconds, so dispatch noise dominates one timing: best of 5.
    t_quasi = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        q_idx = jax.block_until_ready(q_fn(points_cam))
        t_quasi = min(t_quasi, time.perf_counter() - t0)
    t1 = time.perf_counter()
    opt = jax.block_until_ready(e_fn(blocks))
    t_opt = time.perf_counter() - t1
    pdop_q, adop_q = subset(blocks, q_idx)
    out = {
        "points_body": points,
        "quasi_idx": q_idx,
        "opt_pdop_idx": opt.pdop_idx,
        "opt_adop_idx": opt.adop_idx,
        "pdop_quasi": pdop_q,
        "pdop_opt": opt.pdop,
        "adop_quasi": adop_q,
        "adop_opt": opt.adop,
        "pdop_all": pdop_all,
        "adop_all": adop_all,
        "status": opt.status,
        "angles": angles,
    }
    out = {k: np.asarray(v) for k, v in out.items()}
    return out, t_quasi, t_opt


@dataclasses.dataclass
class StudyResult:
    """In-memory result: ``results`` is what ``results.json`` holds, ``cases`` the case arrays."""

    results: dict
    cases: dict[tuple[int, int], dict[str, np.ndarray]]


def default_groups(n: list[int] | None, m: list[int] | None) -> list[tuple[int, int]]:
    """Groups to run: the paper's (Table 4 and Tables 5-6) unless ``n``/``m`` are given."""
    if n is None and m is None:
        return list(PAPER_GROUPS)
    ns = n or [12, 14, 16, 18]
    ms = m or [8]
    groups = [(a, b) for a in ns for b in ms]
    bad = [(a, b) for a, b in groups if b < 4 or b > a]
    if bad:
        raise ValueError(f"each group needs 4 <= m <= n; got (n, m) = {bad}")
    return groups


def _device_sharding():
    devices = jax.devices()
    if len(devices) == 1:
        return None, 1
    mesh = Mesh(np.asarray(devices), ("cases",))
    return NamedSharding(mesh, PartitionSpec("cases")), len(devices)


def run_study(
    scenario: Scenario = Scenario(),
    groups: list[tuple[int, int]] | None = None,
    *,
    cases: int = 1000,
    seed: int = 0,
    chunk_size: int = 250,
    out_dir: str | Path | None = None,
    progress: bool = True,
) -> StudyResult:
    """Run the selection study; resumable when ``out_dir`` is given.

    Args:
        scenario: simulation parameters.
        groups: ``(n, m)`` pairs; default :data:`PAPER_GROUPS`.
        cases: cases per group (the paper: 1000).
        seed: master seed.
        chunk_size: cases per chunk (the unit of resumption and of device sharding).
        out_dir: where chunks are kept (``out_dir/chunks``); ``None`` keeps nothing on disk.
        progress: show a tqdm progress bar.
    """
    from tqdm.auto import tqdm

    if not jax.config.jax_enable_x64:
        raise ValueError(
            "the selection study needs float64: jax.config.update('jax_enable_x64', True)"
        )
    groups = list(groups or PAPER_GROUPS)
    if cases < 1:
        raise ValueError(f"cases must be >= 1; got {cases}")
    for n, m in groups:
        if not 4 <= m <= n:
            raise ValueError(f"each group needs 4 <= m <= n; got (n, m) = ({n}, {m})")
    sharding, ndev = _device_sharding()
    chunk_size = max(ndev, int(math.ceil(min(chunk_size, cases) / ndev)) * ndev)
    fp = scenario.fingerprint(seed)
    chunk_dir = Path(out_dir) / "chunks" if out_dir is not None else None
    if chunk_dir is not None:
        chunk_dir.mkdir(parents=True, exist_ok=True)

    starts = list(range(0, cases, chunk_size))
    bar = tqdm(
        total=len(groups) * len(starts), desc="select-study", unit="chunk", disable=not progress
    )
    per_group: dict[tuple[int, int], dict[str, np.ndarray]] = {}
    timings: dict[tuple[int, int], list[float]] = {}
    kernel_cache: dict[int, tuple] = {}
    for n, m in groups:
        parts, t_quasi, t_opt = [], 0.0, 0.0
        for start in starts:
            stop = min(start + chunk_size, cases)
            path = chunk_dir / f"n{n}_m{m}_c{start:06d}_{stop:06d}.npz" if chunk_dir else None
            if path is not None and path.is_file():
                with np.load(path) as z:
                    if str(z["fingerprint"]) == fp:
                        parts.append(
                            {k: z[k] for k in z.files if k not in ("fingerprint", "times")}
                        )
                        t_quasi += float(z["times"][0])
                        t_opt += float(z["times"][1])
                        bar.update(1)
                        continue
            if m not in kernel_cache:
                kernel_cache[m] = _kernels(scenario, m)
            idx = list(range(start, stop))
            padded = idx + [idx[-1]] * (chunk_size - len(idx))  # equal chunk shape: one compile
            points, angles = make_cases(scenario, n, padded, seed)
            out, tq, te = _run_chunk(kernel_cache[m], points, angles, sharding)
            out = {k: v[: len(idx)] for k, v in out.items()}
            frac = len(idx) / chunk_size
            tq, te = tq * frac, te * frac
            if path is not None:
                tmp = path.with_suffix(".tmp.npz")
                np.savez(tmp, fingerprint=fp, times=np.array([tq, te]), **out)
                tmp.replace(path)
            parts.append(out)
            t_quasi += tq
            t_opt += te
            bar.update(1)
            bar.set_postfix(n=n, m=m)
        per_group[(n, m)] = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        timings[(n, m)] = [t_quasi / cases, t_opt / cases]
    bar.close()
    results = _summarise(scenario, seed, per_group, timings, ndev)
    return StudyResult(results, per_group)


def _stats(x):
    x = np.asarray(x, dtype=float)
    return {"mean": float(np.mean(x)), "max": float(np.max(x))}


def _summarise(scenario, seed, per_group, timings, ndev) -> dict:
    groups = []
    for (n, m), g in per_group.items():
        groups.append(
            {
                "n": n,
                "m": m,
                "cases": int(len(g["pdop_opt"])),
                "pdop_ratio": _stats(g["pdop_quasi"] / g["pdop_opt"]),
                "adop_ratio": _stats(g["adop_quasi"] / g["adop_opt"]),
                "pdop": {
                    "optimal_mean": float(np.mean(g["pdop_opt"])),
                    "quasi_mean": float(np.mean(g["pdop_quasi"])),
                    "all_mean": float(np.mean(g["pdop_all"])),
                },
                "adop": {
                    "optimal_mean": float(np.mean(g["adop_opt"])),
                    "quasi_mean": float(np.mean(g["adop_quasi"])),
                    "all_mean": float(np.mean(g["adop_all"])),
                },
                "time_s": {
                    "optimal_per_case": timings[(n, m)][1],
                    "quasi_per_case": timings[(n, m)][0],
                },
                "failed_cases": int(np.sum(g["status"] != 0)),
            }
        )
    return {
        "scenario": {
            **scenario.to_dict(),
            "seed": seed,
            "devices": ndev,
            "units": {
                "pdop": "m per px",
                "adop": "rad per px",
                "time": "s per case, batched, after compilation",
            },
        },
        "groups": groups,
        "tables_5_6": _tables_5_6(groups),
    }


def _tables_5_6(groups: list[dict]) -> dict:
    """Tables 5-6 of the paper from the ``n = 18`` groups: mean DOP, % decrease, ratio to all."""
    rows = sorted((g for g in groups if g["n"] == 18), key=lambda g: g["m"])
    tables = {}
    for key in ("pdop", "adop"):
        table = []
        prev = None
        for g in rows:
            opt, quasi, all_ = g[key]["optimal_mean"], g[key]["quasi_mean"], g[key]["all_mean"]
            table.append(
                {
                    "m": g["m"],
                    "optimal_mean": opt,
                    "optimal_decrease_pct": None
                    if prev is None
                    else 100 * (prev[0] - opt) / prev[0],
                    "optimal_ratio_to_all": opt / all_,
                    "quasi_mean": quasi,
                    "quasi_decrease_pct": None
                    if prev is None
                    else 100 * (prev[1] - quasi) / prev[1],
                    "quasi_ratio_to_all": quasi / all_,
                    "all_mean": all_,
                }
            )
            prev = (opt, quasi)
        tables[key] = table
    return tables


# ----------------------------------------------------------------------------- outputs


def write_outputs(
    result: StudyResult, out_dir: str | Path, *, dump_cases: bool = False
) -> list[Path]:
    """Write ``results.json``, the figures and (optionally) ``cases.npz``; return the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / "results.json"]
    paths[0].write_text(json.dumps(result.results, indent=1))
    if dump_cases:
        arrays = {}
        scenario = _scenario_from_results(result.results)
        K = np.asarray(scenario.camera().K)
        t = _translation(scenario)
        seq = result.results["scenario"]["sequence"]
        for (n, m), g in result.cases.items():
            pre = f"n{n}_m{m}/"
            R = np.asarray(
                jax.vmap(lambda a: Pose.from_euler(a, jnp.asarray(t), seq).R)(g["angles"])
            )
            arrays[pre + "points_body"] = g["points_body"]
            arrays[pre + "R"] = R
            arrays[pre + "t"] = np.broadcast_to(t, (len(R), 3)).copy()
            arrays[pre + "K"] = K
            for k in ("quasi_idx", "opt_pdop_idx", "opt_adop_idx"):
                arrays[pre + k] = np.sort(g[k], axis=-1)
            for k in ("pdop_quasi", "pdop_opt", "adop_quasi", "adop_opt", "pdop_all", "adop_all"):
                arrays[pre + k] = g[k]
        paths.append(out_dir / "cases.npz")
        np.savez_compressed(paths[-1], **arrays)
    paths += _figures(result, out_dir)
    return paths


def _scenario_from_results(results: dict) -> Scenario:
    fields = {f.name for f in dataclasses.fields(Scenario)}
    d = {k: v for k, v in results["scenario"].items() if k in fields}
    d["image_size"] = tuple(d["image_size"])
    d["attitude_deg"] = tuple(d["attitude_deg"])
    d["plane_centre_m"] = tuple(d["plane_centre_m"])
    return Scenario(**d)


def _figures(result: StudyResult, out_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    groups = result.results["groups"]
    m8 = sorted((g for g in groups if g["m"] == 8), key=lambda g: g["n"])
    if m8:  # Fig. 6: ratio histograms
        fig, axes = plt.subplots(
            2, len(m8), figsize=(3.2 * len(m8), 5.2), squeeze=False, sharey="row"
        )
        for j, g in enumerate(m8):
            c = result.cases[(g["n"], 8)]
            for i, key in enumerate(("pdop", "adop")):
                ratio = c[f"{key}_quasi"] / c[f"{key}_opt"]
                axes[i, j].hist(
                    ratio, bins=np.arange(1.0, max(2.6, ratio.max() + 0.05), 0.05), color=f"C{i}"
                )
                axes[i, j].set_title(f"n = {g['n']}, m = 8: {key.upper()} ratio", fontsize=9)
                axes[i, j].set_xlabel(f"{key.upper()}_quasi / {key.upper()}_opt")
        axes[0, 0].set_ylabel("cases")
        axes[1, 0].set_ylabel("cases")
        fig.suptitle("DOP ratios of the quasi-optimal selection (Ning et al. Fig. 6)")
        fig.tight_layout()
        paths.append(out_dir / "fig6_ratio_histograms.png")
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)
    n18 = sorted((g for g in groups if g["n"] == 18), key=lambda g: g["m"])
    if len(n18) > 1:  # Fig. 8: mean DOP against m
        fig, axes = plt.subplots(1, 2, figsize=(10, 4))
        ms = [g["m"] for g in n18]
        for ax, key, unit in zip(axes, ("pdop", "adop"), ("m/px", "rad/px"), strict=True):
            ax.plot(ms, [g[key]["optimal_mean"] for g in n18], "o-", label="optimal")
            ax.plot(ms, [g[key]["quasi_mean"] for g in n18], "s--", label="quasi-optimal")
            ax.axhline(n18[0][key]["all_mean"], color="k", lw=0.8, label="all 18 points")
            ax.set_xlabel("selected points m (of n = 18)")
            ax.set_ylabel(f"mean {key.upper()} ({unit})")
            ax.set_yscale("log")
            ax.legend()
        fig.suptitle("Mean DOP against the number of selected points (Ning et al. Fig. 8)")
        fig.tight_layout()
        paths.append(out_dir / "fig8_dop_vs_m.png")
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)
    # Figs. 9-10: time per case of both methods on shared log axes (the paper's point is the gap)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    panels = [
        (
            axes[0],
            sorted((g for g in groups if g["m"] == 8), key=lambda g: g["n"]),
            "n",
            "total points n (m = 8)",
        ),
        (axes[1], n18, "m", "selected points m (n = 18)"),
    ]
    for ax, gs, x, label in panels:
        if not gs:
            ax.set_visible(False)
            continue
        xs = [g[x] for g in gs]
        ax.plot(
            xs, [g["time_s"]["optimal_per_case"] for g in gs], "o-", label="optimal (exhaustive)"
        )
        ax.plot(xs, [g["time_s"]["quasi_per_case"] for g in gs], "s--", label="quasi-optimal")
        ax.set_yscale("log")
        ax.set_xlabel(label)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("time per case (s), batched")
    fig.suptitle("Time per case on this machine, after compilation (Ning et al. Figs. 9-10)")
    fig.tight_layout()
    paths.append(out_dir / "fig9_10_timing.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def format_report(results: dict) -> str:
    """Plain-text Table 4, Tables 5-6 and timings."""
    lines = [
        "Table 4: DOP ratios quasi-optimal / optimal",
        f"{'n':>4} {'m':>3} {'cases':>6} "
        f"{'PDOP avg':>9} {'PDOP max':>9} {'ADOP avg':>9} {'ADOP max':>9} "
        f"{'t_opt/case':>11} {'t_quasi/case':>12}",
    ]
    for g in sorted(results["groups"], key=lambda g: (g["m"] != 8, g["n"], g["m"])):
        lines.append(
            f"{g['n']:>4} {g['m']:>3} {g['cases']:>6} "
            f"{g['pdop_ratio']['mean']:9.4f} {g['pdop_ratio']['max']:9.4f} "
            f"{g['adop_ratio']['mean']:9.4f} {g['adop_ratio']['max']:9.4f} "
            f"{g['time_s']['optimal_per_case']:11.3e} {g['time_s']['quasi_per_case']:12.3e}"
        )
    for key, name in (("pdop", "Table 5: PDOP (m/px)"), ("adop", "Table 6: ADOP (rad/px)")):
        rows = results.get("tables_5_6", {}).get(key, [])
        if len(rows) < 2:
            continue
        lines += [
            "",
            f"{name}, n = 18",
            f"{'m':>3} {'opt mean':>10} {'% dec':>7} {'/all':>6} "
            f"{'quasi mean':>11} {'% dec':>7} {'/all':>6}",
        ]
        for r in rows:

            def pct(x):
                return "      -" if x is None else f"{x:7.1f}"

            lines.append(
                f"{r['m']:>3} {r['optimal_mean']:10.3e} {pct(r['optimal_decrease_pct'])} "
                f"{r['optimal_ratio_to_all']:6.3f} {r['quasi_mean']:11.3e} "
                f"{pct(r['quasi_decrease_pct'])} {r['quasi_ratio_to_all']:6.3f}"
            )
    return "\n".join(lines)


# ----------------------------------------------------------------------------- command line


def add_scenario_arguments(parser: argparse.ArgumentParser) -> None:
    d = Scenario()
    g = parser.add_argument_group(
        "scenario (Ning et al. Table 3 is lost; defaults documented in the README)"
    )
    g.add_argument("--focal-length-mm", type=float, default=d.focal_length_m * 1e3)
    g.add_argument("--pixel-size-um", type=float, default=d.pixel_size_m * 1e6)
    g.add_argument(
        "--image-size", type=int, nargs=2, default=list(d.image_size), metavar=("W", "H")
    )
    g.add_argument(
        "--range-m", type=float, default=d.range_m, help="target range along the boresight"
    )
    g.add_argument(
        "--offset-m", type=float, nargs=2, default=[d.offset_x_m, d.offset_y_m], metavar=("X", "Y")
    )
    g.add_argument(
        "--attitude-deg",
        type=float,
        nargs=3,
        default=list(d.attitude_deg),
        metavar=("A1", "A2", "A3"),
    )
    g.add_argument(
        "--random-attitude", action="store_true", help="draw each angle in [-A, A] per case"
    )
    g.add_argument(
        "--sequence",
        default=d.sequence,
        help="Euler sequence of the attitude state (SciPy naming: upper case intrinsic, lower case extrinsic)",
    )
    g.add_argument("--plane-size-m", type=float, default=d.plane_size_m)
    g.add_argument(
        "--plane-centre-m",
        type=float,
        nargs=2,
        default=list(d.plane_centre_m),
        metavar=("X", "Y"),
        help="centre of the feature square in the body frame (0.5 0.5: origin at a corner)",
    )


def scenario_from_args(args) -> Scenario:
    return Scenario(
        focal_length_m=args.focal_length_mm * 1e-3,
        pixel_size_m=args.pixel_size_um * 1e-6,
        image_size=tuple(args.image_size),
        range_m=args.range_m,
        offset_x_m=args.offset_m[0],
        offset_y_m=args.offset_m[1],
        attitude_deg=tuple(args.attitude_deg),
        random_attitude=args.random_attitude,
        sequence=args.sequence,
        plane_size_m=args.plane_size_m,
        plane_centre_m=tuple(args.plane_centre_m),
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--n", type=int, nargs="+", help="total points per case (default: the paper's groups)"
    )
    parser.add_argument(
        "--m", type=int, nargs="+", help="selected points (default: the paper's groups)"
    )
    parser.add_argument("--cases", type=int, default=1000, help="cases per group (default 1000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--chunk-size", type=int, default=250, help="cases per resumable chunk")
    parser.add_argument(
        "--out", default="select-study", help="output folder (default ./select-study)"
    )
    parser.add_argument(
        "--dump-cases", action="store_true", help="also write cases.npz (methods.md format)"
    )
    parser.add_argument("--no-progress", action="store_true")
    add_scenario_arguments(parser)


def run(args) -> int:
    scenario = scenario_from_args(args)
    groups = default_groups(args.n, args.m)
    t0 = time.perf_counter()
    result = run_study(
        scenario,
        groups,
        cases=args.cases,
        seed=args.seed,
        chunk_size=args.chunk_size,
        out_dir=args.out,
        progress=not args.no_progress,
    )
    paths = write_outputs(result, args.out, dump_cases=args.dump_cases)
    print(format_report(result.results))
    print(f"\nwrote {', '.join(str(p) for p in paths)} in {time.perf_counter() - t0:.1f} s")
    return 0
