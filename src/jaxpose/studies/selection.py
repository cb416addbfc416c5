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
* Every chunk is spread over all JAX devices with ``jax.sharding`` (a 1-D ``cases`` mesh); in a
  multi-process run (:mod:`jaxpose.studies._distributed`, ``docs/distributed.md``) that is every
  process's devices, each process draws only its own cases, and process 0 alone reads and writes
  the chunk files. A case is computed the same way on any device or process count.

Outputs: ``results.json`` (schema in ``docs/formats.md``, plus the derived Tables 5-6), PNG
figures, and with ``--dump-cases`` ``cases.npz`` holding every case for independent re-checks.

The default scenario (Table 3 of the paper is lost) is documented in :class:`Scenario`.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.core._checks import is_finite_number
from jaxpose.core.camera import PinholeCamera
from jaxpose.core.dilution import dop_from_information, information_blocks
from jaxpose.core.geometry import DEFAULT_EULER_SEQUENCE, Pose, parse_euler_sequence
from jaxpose.studies import _distributed as _dist
from jaxpose.studies import _selection_figures as _figures
from jaxpose.studies._selection_figures import format_report
from jaxpose.studies._selection_plan import (
    MAX_OUTSIDE_FRACTION,
    MAX_STUDY_BYTES,
    MAX_STUDY_SUBSETS,
    MAX_SUBSETS_PER_CASE,
    OutsideImageWarning,
    _behind_camera,
    _check_in_front,
    _check_in_image,
    _outside_error,
    _outside_image,
    _outside_warning,
    _translation,
    check_group,
    check_plan,
)

__all__ = [
    "PAPER_GROUPS",
    "Scenario",
    "StudyResult",
    "ResumeWarning",
    "MAX_SUBSETS_PER_CASE",
    "MAX_STUDY_SUBSETS",
    "MAX_STUDY_BYTES",
    "MAX_OUTSIDE_FRACTION",
    "OutsideImageWarning",
    "check_group",
    "check_plan",
    "default_groups",
    "format_report",
    "make_cases",
    "run_study",
]

TABLE4_GROUPS = [(12, 8), (14, 8), (16, 8), (18, 8)]
TABLE56_GROUPS = [(18, m) for m in range(4, 18)]
PAPER_GROUPS = sorted(set(TABLE4_GROUPS + TABLE56_GROUPS))


_POSITIVE_FIELDS = {
    "focal_length_m": "--focal-length-mm",
    "pixel_size_m": "--pixel-size-um",
    "range_m": "--range-m",
    "plane_size_m": "--plane-size-m",
    "sigma_px": "sigma_px",
}
_FINITE_FIELDS = [
    ("offset_x_m", "--offset-m", 1),
    ("offset_y_m", "--offset-m", 1),
    ("attitude_deg", "--attitude-deg", 3),
    ("plane_centre_m", "--plane-centre-m", 2),
]


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
    sequence: str = DEFAULT_EULER_SEQUENCE
    parameterization: str = "euler"
    sigma_px: float = 1.0

    def __post_init__(self) -> None:
        for name, option in _POSITIVE_FIELDS.items():
            value = getattr(self, name)
            if not (is_finite_number(value) and value > 0):
                raise ValueError(
                    f"Scenario.{name} ({option}) must be a positive finite number; got {value!r}"
                )
        for name, option, size in _FINITE_FIELDS:
            value = getattr(self, name)
            values = np.asarray(value, dtype=float).reshape(-1)
            if values.size != size or not np.all(np.isfinite(values)):
                raise ValueError(
                    f"Scenario.{name} ({option}) must be {size} finite number(s); got {value!r}"
                )
        size = tuple(self.image_size)
        if len(size) != 2 or not all(isinstance(v, int | np.integer) and v >= 1 for v in size):
            raise ValueError(
                f"Scenario.image_size (--image-size) must be two integers >= 1; got {size!r}"
            )
        try:
            parse_euler_sequence(self.sequence)
        except ValueError as err:
            raise ValueError(f"Scenario.sequence (--sequence): {err}") from None
        if self.parameterization not in ("euler", "tangent"):
            raise ValueError(
                "Scenario.parameterization must be 'euler' or 'tangent'; "
                f"got {self.parameterization!r}"
            )

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


@functools.lru_cache(maxsize=8)
def _prepare_kernel(scenario: Scenario):
    """Jitted ``(points (C, n, 3), angles (C, 3)) -> (blocks, points_cam, pdop_all, adop_all)``;
    one function per scenario, traced once per point count."""
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

    return prepare


@functools.partial(jax.jit, static_argnums=1)
def _quasi_kernel(points_cam, m: int):
    from jaxpose.core import select as sel

    return jax.vmap(lambda p: sel.quasi_optimal(p, m))(points_cam)


@functools.partial(jax.jit, static_argnums=1)
def _exhaustive_kernel(blocks, m: int):
    from jaxpose.core import select as sel

    # A bad case gets a status (counted in results.json as failed_cases), not an exception.
    # (The float32 kernel gives identical optima here and scores faster, but traces a larger
    # program: a warm Table 4 run took more CPU with it, 7.6 s against 6.9 s.)
    return sel.exhaustive_batch(blocks, m, throw=False)


@jax.jit
def _subset_kernel(blocks, idx):
    from jaxpose.core import select as sel

    return jax.vmap(sel.subset_dop)(blocks, idx)


def _shard(x, sharding, length: int):
    # x holds this process's rows of the chunk (all of them in a one-process run).
    return _dist.global_array(x, sharding, length)


def _run_chunk(scenario: Scenario, m: int, points, angles, sharding, compiled: dict, length: int):
    """One chunk: returns per-case arrays, the run times of the two selection methods and (random
    attitudes) how many features fall outside the image.

    ``points`` and ``angles`` are this process's rows of a chunk of ``length`` cases; the returned
    arrays hold every case of the chunk (gathered from all processes)."""
    points, angles = _shard(points, sharding, length), _shard(angles, sharding, length)
    blocks, points_cam, pdop_all, adop_all = _prepare_kernel(scenario)(points, angles)
    jax.block_until_ready(blocks)
    z_min = float(jnp.min(points_cam[..., 2]))
    if not z_min > 0:
        raise _behind_camera(z_min)
    outside = 0
    if scenario.random_attitude:  # a fixed attitude was checked before any work
        outside = _outside_image(scenario, points_cam)
        if outside > MAX_OUTSIDE_FRACTION * points_cam.shape[0] * points_cam.shape[1]:
            share = outside / (points_cam.shape[0] * points_cam.shape[1])
            raise _outside_error(scenario, share, "the features drawn in a chunk")
    # Compile outside the timed region (AOT, once per shape), then time each method.
    key = (blocks.shape, m)
    if key not in compiled:
        compiled[key] = (
            _quasi_kernel.lower(points_cam, m).compile(),
            _exhaustive_kernel.lower(blocks, m).compile(),
        )
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
    pdop_q, adop_q = _subset_kernel(blocks, q_idx)
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
    out = _dist.to_host(out)  # NumPy, every case of the chunk on every process
    return out, t_quasi, t_opt, outside


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
        raise ValueError(f"each group needs 4 <= m <= n (--n, --m); got (n, m) = {bad}")
    for a, b in groups:
        check_group(a, b)
    return groups


class ResumeWarning(UserWarning):
    """A chunk file of an earlier run could not be read and is recomputed."""


def _load_chunk(path: Path, fingerprint: str) -> tuple[dict, float, float] | None:
    """The saved chunk at ``path`` if it belongs to this scenario and seed, else ``None``; an
    unreadable (truncated, corrupt) file is reported with a :class:`ResumeWarning`."""
    import warnings
    import zipfile

    if not path.is_file():
        return None
    try:
        with np.load(path) as z:
            if str(z["fingerprint"]) != fingerprint:
                return None
            part = {k: z[k] for k in z.files if k not in ("fingerprint", "times")}
            t_quasi, t_opt = (float(x) for x in z["times"][:2])
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
        warnings.warn(
            f"chunk file {path} is unreadable ({type(err).__name__}: {err}); recomputing it",
            ResumeWarning,
            stacklevel=3,
        )
        return None
    return part, t_quasi, t_opt


def _device_sharding():
    # Every global device: all processes' in a multi-process run (jaxpose.studies._distributed).
    return _dist.case_sharding()


def run_study(
    scenario: Scenario = Scenario(),
    groups: list[tuple[int, int]] | None = None,
    *,
    cases: int = 1000,
    seed: int = 0,
    chunk_size: int = 250,
    out_dir: str | Path | None = None,
    progress: bool = True,
    progress_desc: str = "select-study",
) -> StudyResult:
    """Run the selection study; resumable when ``out_dir`` is given.

    Args:
        scenario: simulation parameters.
        groups: ``(n, m)`` pairs; default :data:`PAPER_GROUPS`.
        cases: cases per group (the paper: 1000).
        seed: master seed.
        chunk_size: cases per chunk (the unit of resumption and of device sharding).
        out_dir: where chunks are kept (``out_dir/chunks``); ``None`` keeps nothing on disk.
        progress: show a progress bar (tqdm, on stderr).
        progress_desc: the bar's label.
    """
    from jaxpose.commands._common import progress as progress_bar

    if not jax.config.jax_enable_x64:
        raise ValueError(
            "the selection study needs float64: jax.config.update('jax_enable_x64', True)"
        )
    groups = list(groups or PAPER_GROUPS)
    if not (isinstance(chunk_size, int | np.integer) and chunk_size >= 1):
        raise ValueError(f"chunk_size (--chunk-size) must be an integer >= 1; got {chunk_size!r}")
    for n, m in groups:
        check_group(n, m)
    check_plan(groups, cases)
    _check_in_front(scenario)
    _check_in_image(scenario)
    sharding, ndev = _device_sharding()
    chunk_size = max(ndev, int(math.ceil(min(chunk_size, cases) / ndev)) * ndev)
    fp = scenario.fingerprint(seed)
    chunk_dir = Path(out_dir) / "chunks" if out_dir is not None else None
    if chunk_dir is not None and _dist.is_writer():
        chunk_dir.mkdir(parents=True, exist_ok=True)

    starts = list(range(0, cases, chunk_size))
    bar = progress_bar(
        total=len(groups) * len(starts),
        desc=progress_desc,
        unit="chunk",
        enabled=progress and _dist.is_writer(),
    )
    per_group: dict[tuple[int, int], dict[str, np.ndarray]] = {}
    timings: dict[tuple[int, int], list[float]] = {}
    compiled: dict = {}
    drawn, outside = 0, 0  # features of the computed chunks (random attitudes), and outside
    try:
        for n, m in groups:
            parts, t_quasi, t_opt = [], 0.0, 0.0
            bar.set_postfix(n=n, m=m)
            for start in starts:
                stop = min(start + chunk_size, cases)
                path = chunk_dir / f"n{n}_m{m}_c{start:06d}_{stop:06d}.npz" if chunk_dir else None
                # Process 0 reads the chunk file and sends it to the others.
                saved = _dist.broadcast_from_writer(
                    lambda path=path: _load_chunk(path, fp) if path is not None else None
                )
                if saved is not None:
                    parts.append(saved[0])
                    t_quasi += saved[1]
                    t_opt += saved[2]
                    bar.update(1)
                    continue
                idx = list(range(start, stop))
                padded = idx + [idx[-1]] * (chunk_size - len(idx))  # equal chunk shape: one compile
                rows = _dist.local_rows(chunk_size, sharding)  # this process's cases only
                points, angles = make_cases(scenario, n, padded[rows], seed)
                out, tq, te, off = _run_chunk(
                    scenario, m, points, angles, sharding, compiled, chunk_size
                )
                drawn, outside = drawn + chunk_size * n, outside + off
                out = {k: v[: len(idx)] for k, v in out.items()}
                frac = len(idx) / chunk_size
                tq, te = tq * frac, te * frac
                if path is not None and _dist.is_writer():
                    tmp = path.with_suffix(".tmp.npz")
                    np.savez(tmp, fingerprint=fp, times=np.array([tq, te]), **out)
                    tmp.replace(path)
                parts.append(out)
                t_quasi += tq
                t_opt += te
                bar.update(1)
            per_group[(n, m)] = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
            timings[(n, m)] = [t_quasi / cases, t_opt / cases]
    finally:
        bar.close()
    if outside and _dist.is_writer():
        _outside_warning(scenario, outside / drawn, f"the {drawn} features drawn")
    results = _summarise(scenario, seed, per_group, timings, ndev)
    return StudyResult(results, per_group)


def _finite(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _stats(x) -> dict:
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return {"mean": None, "max": None}
    return {"mean": _finite(np.mean(x)), "max": _finite(np.max(x))}


def _mean(x) -> float | None:
    return _finite(np.mean(x)) if np.size(x) else None


def _summarise(scenario, seed, per_group, timings, ndev) -> dict:
    """``results.json``: per group the statistics over the cases whose status is OK (the others
    are counted in ``failed_cases``); ``null`` where no case succeeded, never NaN."""
    groups = []
    for (n, m), g in per_group.items():
        ok = g["status"] == 0
        groups.append(
            {
                "n": n,
                "m": m,
                "cases": int(len(g["pdop_opt"])),
                "pdop_ratio": _stats(g["pdop_quasi"][ok] / g["pdop_opt"][ok]),
                "adop_ratio": _stats(g["adop_quasi"][ok] / g["adop_opt"][ok]),
                "pdop": {
                    "optimal_mean": _mean(g["pdop_opt"][ok]),
                    "quasi_mean": _mean(g["pdop_quasi"][ok]),
                    "all_mean": _mean(g["pdop_all"][ok]),
                },
                "adop": {
                    "optimal_mean": _mean(g["adop_opt"][ok]),
                    "quasi_mean": _mean(g["adop_quasi"][ok]),
                    "all_mean": _mean(g["adop_all"][ok]),
                },
                "time_s": {
                    "optimal_per_case": timings[(n, m)][1],
                    "quasi_per_case": timings[(n, m)][0],
                },
                "failed_cases": int(np.sum(~ok)),
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

    def ratio(a, b):
        return None if a is None or b is None else a / b

    def decrease(prev, now):
        return None if prev is None or now is None else 100 * (prev - now) / prev

    tables = {}
    for key in ("pdop", "adop"):
        table = []
        prev = (None, None)
        for g in rows:
            opt, quasi, all_ = g[key]["optimal_mean"], g[key]["quasi_mean"], g[key]["all_mean"]
            table.append(
                {
                    "m": g["m"],
                    "optimal_mean": opt,
                    "optimal_decrease_pct": decrease(prev[0], opt),
                    "optimal_ratio_to_all": ratio(opt, all_),
                    "quasi_mean": quasi,
                    "quasi_decrease_pct": decrease(prev[1], quasi),
                    "quasi_ratio_to_all": ratio(quasi, all_),
                    "all_mean": all_,
                }
            )
            prev = (opt, quasi)
        tables[key] = table
    return tables


# ----------------------------------------------------------------------------- outputs


def write_outputs(
    result: StudyResult, out_dir: str | Path, *, dump_cases: bool = False, figures: bool = True
) -> list[Path]:
    """Write ``results.json``, the figures and (optionally) ``cases.npz``; return the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / "results.json"]
    paths[0].write_text(json.dumps(result.results, indent=1, allow_nan=False))
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
    if figures:
        paths += _figures.figures(result, out_dir)
    return paths


def _scenario_from_results(results: dict) -> Scenario:
    fields = {f.name for f in dataclasses.fields(Scenario)}
    d = {k: v for k, v in results["scenario"].items() if k in fields}
    d["image_size"] = tuple(d["image_size"])
    d["attitude_deg"] = tuple(d["attitude_deg"])
    d["plane_centre_m"] = tuple(d["plane_centre_m"])
    return Scenario(**d)
