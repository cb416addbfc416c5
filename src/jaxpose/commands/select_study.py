"""``jaxpose select-study``: the Monte Carlo selection study of Ning, Zhang, Wang (2018), Sec. 5
(Table 4, Tables 5-6, Figs. 6 and 8-10), run by :func:`jaxpose.studies.selection.run_study`.

Writes ``results.json``, the figures and the resumable chunks under ``--out``; a rerun with the
same options loads the finished chunks (an interrupted study resumes), and a chunk file that cannot
be read is recomputed with a warning naming it. Groups above
:data:`jaxpose.studies.selection.MAX_SUBSETS_PER_CASE` subsets per case are refused, and so is a
``--cases`` that plans more than :data:`~jaxpose.studies.selection.MAX_STUDY_SUBSETS` subsets or
:data:`~jaxpose.studies.selection.MAX_STUDY_BYTES` bytes of case data over all groups (checked
before anything starts), and a scenario that puts more than
:data:`~jaxpose.studies.selection.MAX_OUTSIDE_FRACTION` of the feature square outside the
``--image-size`` sensor (a smaller share runs with a one-line warning).
"""

from __future__ import annotations

import argparse
import time

from jaxpose.commands._common import (
    add_figures_argument,
    add_image_size_argument,
    add_out_argument,
    add_progress_argument,
    finite_float,
    nonnegative_int,
    positive_float,
    positive_int,
)
from jaxpose.commands._distributed import add_distributed_arguments, start_distributed

__all__ = ["add_arguments", "add_scenario_arguments", "euler_sequence", "run", "scenario_from_args"]


def euler_sequence(text: str) -> str:
    """An Euler sequence as SciPy names it (``XYZ``, ``zyx``, ``ZXZ``); argparse names the option
    in its error."""
    from jaxpose.core.geometry import parse_euler_sequence

    try:
        parse_euler_sequence(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    return text


def add_scenario_arguments(parser: argparse.ArgumentParser) -> None:
    """The :class:`~jaxpose.studies.selection.Scenario` options, each refusing bad values."""
    from jaxpose.studies.selection import Scenario

    d = Scenario()
    g = parser.add_argument_group(
        "scenario (Ning et al. Table 3 is lost; jaxpose's defaults, documented in Scenario)"
    )
    g.add_argument(
        "--focal-length-mm",
        type=positive_float,
        default=d.focal_length_m * 1e3,
        help="focal length (mm)",
    )
    g.add_argument(
        "--pixel-size-um",
        type=positive_float,
        default=d.pixel_size_m * 1e6,
        help="pixel pitch (um)",
    )
    add_image_size_argument(
        g,
        d.image_size,
        help="sensor size in pixels, W H (or WxH): it sets the principal point (the DOPs do not "
        "depend on it) and which features are in the image; a scenario with more than "
        "MAX_OUTSIDE_FRACTION = 5 %% of the feature square outside it is refused, a smaller "
        "share is reported with a warning",
    )
    g.add_argument(
        "--range-m",
        type=positive_float,
        default=d.range_m,
        help="target range along the boresight (m)",
    )
    g.add_argument(
        "--offset-m",
        type=finite_float,
        nargs=2,
        default=[d.offset_x_m, d.offset_y_m],
        metavar=("X", "Y"),
        help="lateral offset of the target origin in the camera frame (m)",
    )
    g.add_argument(
        "--attitude-deg",
        type=finite_float,
        nargs=3,
        default=list(d.attitude_deg),
        metavar=("A1", "A2", "A3"),
        help="relative attitude, Euler angles of --sequence (deg)",
    )
    g.add_argument(
        "--random-attitude", action="store_true", help="draw each angle in [-A, A] per case"
    )
    g.add_argument(
        "--sequence",
        type=euler_sequence,
        default=d.sequence,
        help="Euler sequence of the attitude state, named as SciPy names them (upper case "
        "intrinsic, lower case extrinsic)",
    )
    g.add_argument(
        "--plane-size-m",
        type=positive_float,
        default=d.plane_size_m,
        help="side of the square holding the feature points (m)",
    )
    g.add_argument(
        "--plane-centre-m",
        type=finite_float,
        nargs=2,
        default=list(d.plane_centre_m),
        metavar=("X", "Y"),
        help="centre of the feature square in the body frame (0.5 0.5: origin at a corner)",
    )


def scenario_from_args(args):
    from jaxpose.studies.selection import Scenario

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
        "--n",
        type=positive_int,
        nargs="+",
        help="total points per case (default: the paper's groups; with --m only: 12 14 16 18)",
    )
    parser.add_argument(
        "--m",
        type=positive_int,
        nargs="+",
        help="selected points (default: the paper's groups; with --n only: 8)",
    )
    parser.add_argument(
        "--cases",
        type=positive_int,
        default=1000,
        help="cases per group (as in the paper); a number that plans more than MAX_STUDY_SUBSETS "
        "subsets or MAX_STUDY_BYTES of case data over all groups is refused",
    )
    parser.add_argument("--seed", type=nonnegative_int, default=0, help="master seed")
    parser.add_argument(
        "--chunk-size",
        type=positive_int,
        default=250,
        help="cases per resumable chunk (a rerun with the same options loads finished chunks)",
    )
    add_out_argument(parser, "select-study", "results, figures and resumable chunks")
    parser.add_argument(
        "--dump-cases", action="store_true", help="also write cases.npz (every case, re-checkable)"
    )
    add_progress_argument(parser)
    add_figures_argument(parser)
    add_scenario_arguments(parser)
    add_distributed_arguments(parser)


def run(args) -> int:
    from jaxpose.studies.selection import (
        check_plan,
        default_groups,
        format_report,
        run_study,
        write_outputs,
    )

    scenario = scenario_from_args(args)
    groups = default_groups(args.n, args.m)
    check_plan(groups, args.cases)  # --cases that plans too much work: refused before anything
    writer = start_distributed(args)  # before any JAX computation
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
    if not writer:  # every process holds the results; process 0 writes and reports them
        return 0
    paths = write_outputs(result, args.out, dump_cases=args.dump_cases, figures=not args.no_figures)
    print(format_report(result.results))
    print(f"\nwrote {', '.join(str(p) for p in paths)} in {time.perf_counter() - t0:.1f} s")
    return 0
