"""Two configurations of the stereo tracker timed against each other on the same frames, in one
process.

This machine's speed moves by up to 2x within minutes, so two runs of ``bench/stereo.py`` taken
one after the other do not measure a change that saves a few per cent. Here tracker ``A`` (the
defaults, or ``--base-option``) and tracker ``B`` (``--option``) track the same rendered frames
frame by frame, one after the other, the order alternating from frame to frame and from
repetition to repetition, each pair by :meth:`StereoTracker.process` (the features in the
calling thread; no stream). Reported, over frames 2 onwards (the first tracked frame compiles):
the mean wall and CPU milliseconds a frame of each stage and of the whole ``process`` call, the
ratios ``B / A``, and whether the two trackers' poses are the same to the bit on every frame (a
change meant to leave the tracking alone). Run from the repository root::

    python bench/stereo_paired.py d3-glints-1.5m-10hz --option predicted_disparity=True
    python bench/stereo_paired.py d1-clean-2m d6-blur-5m-slow --frames 20 --reps 3 \\
        --option window_every=2

``--base-rev REV`` runs tracker ``A`` with the package as it was at git revision ``REV`` (a copy
of its ``src/jaxpose`` under another import name, in a temporary folder) and ``B`` with the
working tree: a change of code rather than of options, timed on the same frames in one process
(its options' fields that ``REV`` does not know are left out, and said)::

    python bench/stereo_paired.py d4-glints-4m-slow d1-clean-2m --base-rev HEAD~2

``SCENE``: a scene of ``bench/stereo.py``, ``hNN`` of ``bench/stereo_heldout.py``'s default draw,
or ``NAME={StereoScene fields as JSON}``. Ends with one JSON line: per scene, both
configurations' figures and the ratios.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import io
import json
import re
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))


REPO = Path(__file__).resolve().parents[1]


def package_at(rev: str, folder: Path) -> str:
    """Put the package as it was at git revision ``rev`` under ``folder``, renamed so that it
    imports beside the working tree's (``jaxpose_at_<commit>``: its own imports rewritten), put
    ``folder`` on ``sys.path`` and return the import name. Raises ``ValueError`` for a revision
    git does not know."""
    got = subprocess.run(
        ["git", "rev-parse", "--short=10", f"{rev}^{{commit}}"],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    if got.returncode:
        raise ValueError(f"git does not know the revision {rev!r}: {got.stderr.strip()}")
    name = f"jaxpose_at_{got.stdout.strip()}"
    tar = subprocess.run(
        ["git", "archive", got.stdout.strip(), "src/jaxpose"], cwd=REPO, capture_output=True
    )
    if tar.returncode:
        raise ValueError(f"git archive {rev} src/jaxpose failed: {tar.stderr.decode().strip()}")
    with tarfile.open(fileobj=io.BytesIO(tar.stdout)) as t:
        t.extractall(folder, filter="data")
    (folder / "src" / "jaxpose").rename(folder / name)
    for path in (folder / name).rglob("*.py"):
        text = path.read_text()
        text = re.sub(r"\bjaxpose\.", f"{name}.", text)
        text = re.sub(r"\bfrom jaxpose import\b", f"from {name} import", text)
        text = re.sub(r"^(\s*)import jaxpose$", rf"\1import {name} as jaxpose", text, flags=re.M)
        path.write_text(text)
    sys.path.insert(0, str(folder))
    return name


def _in_package(value, name: str):
    """``value`` (options, cameras, a pose: frozen dataclasses or equinox modules, nested)
    rebuilt from the classes of the same names in package ``name``; a field the other class does
    not have is left out, and said, and so is one whose value it refuses, of another kind than
    its default there (a flag that became a choice): it then keeps its own default."""
    kind = type(value)
    if not kind.__module__.startswith("jaxpose."):
        return value
    module = importlib.import_module(name + kind.__module__[len("jaxpose") :])
    other = getattr(module, kind.__name__)
    if dataclasses.is_dataclass(value):  # (equinox modules are dataclasses too)
        known = {f.name for f in dataclasses.fields(other)}
        fields = {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
        dropped = sorted(set(fields) - known)
        if dropped:
            print(f"note: {name} has no {kind.__name__} field {', '.join(dropped)}: left out")
        kept = {k: _in_package(v, name) for k, v in fields.items() if k in known}
        try:
            return other(**kept)
        except (TypeError, ValueError):  # a field that changed kind: the other's own default
            defaults = {f.name: f.default for f in dataclasses.fields(other)}
            for k in [k for k in kept if type(kept[k]) is not type(defaults.get(k))]:
                try:
                    result = other(**{j: v for j, v in kept.items() if j != k})
                except (TypeError, ValueError):
                    continue
                print(f"note: {name}'s {kind.__name__} refuses {k}={kept[k]!r}: its default")
                return result
            raise
    raise TypeError(f"cannot rebuild a {kind.__name__} in {name}")


def paired(
    name: str, frames: int, reps: int, seed: int, option_a=(), option_b=(), base_package=None
) -> dict:
    """Track scene ``name`` with both configurations, ``reps`` times; the figures of one scene.
    ``base_package``: the import name of :func:`package_at`, configuration ``A``'s code."""
    import stereo  # bench/stereo.py
    from stereo_diagnose import rendered

    from jaxpose.pipelines.stereo import STAGES, StereoTracker

    rig, seq, base = rendered(name, frames, seed)
    configs = {
        "A": stereo.tracker_options(option_a, base),
        "B": stereo.tracker_options(option_b, base),
    }
    kinds = {"A": StereoTracker, "B": StereoTracker}
    start = {c: (rig, seq[0].pose) for c in configs}
    if base_package is not None:
        kinds["A"] = importlib.import_module(base_package + ".pipelines.stereo").StereoTracker
        configs["A"] = _in_package(configs["A"], base_package)
        start["A"] = (_in_package(rig, base_package), _in_package(seq[0].pose, base_package))
    keys = [*STAGES, "frame"]
    wall = {c: {k: [] for k in keys} for c in configs}
    cpu = {c: {k: [] for k in keys} for c in configs}
    same, apart = True, 0.0
    for rep in range(reps):
        trackers = {c: kinds[c](*start[c], options=o) for c, o in configs.items()}
        for i, fr in enumerate(seq):
            order = ["A", "B"] if (i + rep) % 2 == 0 else ["B", "A"]
            out = {}
            for c in order:
                t0, c0 = time.perf_counter(), time.process_time()
                out[c] = res = trackers[c].process(fr.left, fr.right)
                if i < 2:
                    continue
                wall[c]["frame"].append(time.perf_counter() - t0)
                cpu[c]["frame"].append(time.process_time() - c0)
                for k in STAGES:
                    wall[c][k].append(res.timings.get(k, 0.0))
                    cpu[c][k].append(res.cpu_timings.get(k, 0.0))
            same = same and all(
                np.array_equal(np.asarray(getattr(out["A"], a)), np.asarray(getattr(out["B"], a)))
                for a in ("R", "t", "status")
            )
            ta, tb = (np.asarray(out[c].t, float) for c in ("A", "B"))
            if np.isfinite(ta).all() and np.isfinite(tb).all():
                apart = max(apart, float(np.abs(ta - tb).max()))

    def means(d):
        return {k: round(1e3 * float(np.mean(v)), 2) for k, v in d.items() if v}

    res = {
        "scene": name,
        "frames": frames,
        "reps": reps,
        "seed": seed,
        "same_poses": bool(same),
        "max_position_difference_m": apart,  # frames both trackers tracked
    }
    for c in configs:
        res[c] = {"wall_ms": means(wall[c]), "cpu_ms": means(cpu[c])}
    res["ratio_B_over_A"] = {
        what: {
            k: round(res["B"][what][k] / res["A"][what][k], 3)
            for k in res["A"][what]
            if res["A"][what][k] > 0.05 and k in res["B"][what]
        }
        for what in ("wall_ms", "cpu_ms")
    }
    return res


def _print(res: dict) -> None:
    print(
        f"\n{res['scene']}: {res['frames']} frames x {res['reps']}, poses the same: "
        f"{res['same_poses']} (positions at most {res['max_position_difference_m']:.1e} m apart)"
    )
    print(
        f"  {'stage':12s} {'A wall':>8s} {'B wall':>8s} {'B/A':>6s} {'A cpu':>8s} "
        f"{'B cpu':>8s} {'B/A':>6s}"
    )
    for k in res["A"]["wall_ms"]:
        ra = res["ratio_B_over_A"]["wall_ms"].get(k, float("nan"))
        rc = res["ratio_B_over_A"]["cpu_ms"].get(k, float("nan"))
        print(
            f"  {k:12s} {res['A']['wall_ms'][k]:8.1f} {res['B']['wall_ms'][k]:8.1f} {ra:6.3f} "
            f"{res['A']['cpu_ms'][k]:8.1f} {res['B']['cpu_ms'][k]:8.1f} {rc:6.3f}"
        )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scenes", nargs="+", help="scenes (see the module docstring)")
    p.add_argument("--frames", type=int, default=30, help="frames a scene (default 30)")
    p.add_argument("--reps", type=int, default=2, help="repetitions (default 2)")
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed of the rendering")
    p.add_argument("--option", action="append", default=[], help="NAME=VALUE of configuration B")
    p.add_argument(
        "--base-option", action="append", default=[], help="NAME=VALUE of configuration A"
    )
    p.add_argument(
        "--base-rev",
        default=None,
        help="configuration A runs the package at this git revision (module docstring)",
    )
    args = p.parse_args(argv)
    if args.frames < 4:
        p.error(f"--frames must be at least 4; got {args.frames}")
    if args.reps < 1:
        p.error(f"--reps must be at least 1; got {args.reps}")
    import jax

    jax.config.update("jax_enable_x64", True)
    results = []
    base_package = None
    if args.base_rev is not None:
        folder = tempfile.TemporaryDirectory(prefix="jaxpose-base-")  # kept until main returns
        try:
            base_package = package_at(args.base_rev, Path(folder.name))
        except ValueError as err:
            p.error(f"--base-rev: {err}")
    for name in args.scenes:
        try:
            res = paired(
                name, args.frames, args.reps, args.seed, args.base_option, args.option, base_package
            )
        except ValueError as err:
            p.error(f"scene {name}: {err}")
        _print(res)
        results.append(res)
    print(
        json.dumps(
            {
                "bench": "stereo-paired",
                "option_A": args.base_option,
                "option_B": args.option,
                "base_rev": args.base_rev,
                "scenes": results,
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
