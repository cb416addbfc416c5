"""``jaxpose pose-study``: predicted pose covariance against the Monte Carlo scatter of refined
poses, per geometry and pixel noise level (:mod:`jaxpose.studies.pose`).

Writes ``results.json``, ``std_vs_noise.png`` and ``scatter.png`` under ``--out``; prints the
per-axis ratios ``std_emp / std_pred`` and, on its last line, the check as JSON.
"""

from __future__ import annotations

import argparse
import json

from jaxpose.commands._common import (
    add_figures_argument,
    add_out_argument,
    add_progress_argument,
    nonnegative_float,
    nonnegative_int,
    positive_float,
    positive_int,
)
from jaxpose.commands._distributed import add_distributed_arguments, start_distributed

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from jaxpose.studies.pose import GEOMETRIES

    parser.add_argument(
        "--trials", type=positive_int, default=1000, help="Monte Carlo trials per group (>= 2)"
    )
    parser.add_argument(
        "--noise",
        type=positive_float,
        nargs="+",
        default=[0.1, 0.5, 1.0, 2.0],
        help="pixel noise levels (px)",
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
        type=nonnegative_float,
        nargs=2,
        default=[2.0, 0.02],
        metavar=("DEG", "FRACTION"),
        help="rms rotation (deg) and translation (fraction of range) of the perturbation",
    )
    parser.add_argument(
        "--check-noise",
        type=positive_float,
        default=0.5,
        help="noise level (px) of the agreement check",
    )
    parser.add_argument(
        "--tolerance",
        type=positive_float,
        default=0.10,
        help="allowed |std_emp / std_pred - 1| per axis at --check-noise",
    )
    parser.add_argument("--seed", type=nonnegative_int, default=0, help="noise seed")
    add_out_argument(parser, "pose-study", "results and figures")
    add_progress_argument(parser)
    add_figures_argument(parser)
    add_distributed_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from jaxpose.commands._common import CommandError
    from jaxpose.studies.pose import AXES, run_study, write_figures

    if args.trials < 2:
        raise CommandError(f"--trials must be at least 2; got {args.trials}")
    writer = start_distributed(args)  # before any JAX computation
    results, raw = run_study(
        args.geometries,
        args.noise,
        args.trials,
        seed=args.seed,
        init=args.init,
        perturbation=tuple(args.init_perturbation),
        check_noise=args.check_noise,
        tolerance=args.tolerance,
        progress=not args.no_progress,
    )
    if not writer:  # every process holds the results; process 0 writes and reports them
        return 0
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=2, allow_nan=False))
    if not args.no_figures:
        write_figures(out, results, raw)
    print(f"{'geometry':<16} {'noise':>6} " + " ".join(f"{a:>7}" for a in AXES) + "   NEES")
    for g in results["groups"]:
        if g["ratio"] is None:  # fewer than two trials converged
            print(f"{g['geometry']:<16} {g['noise_px']:>6.2f} {g['message']}")
            continue
        print(
            f"{g['geometry']:<16} {g['noise_px']:>6.2f} "
            + " ".join(f"{x:>7.3f}" for x in g["ratio"])
            + f" {g['nees_mean']:>6.2f}"
        )
    check = results["check"]
    worst = check["max_abs_ratio_minus_1"]
    verdict = "PASS" if check["passed"] else "FAIL"
    print(
        f"std_emp / std_pred at {check['noise_px']} px: worst |ratio - 1| = "
        f"{'-' if worst is None else format(worst, '.3f')} "
        f"(tolerance {check['tolerance']}) {verdict}; results in {out}"
    )
    print(json.dumps(check))
    return 0
