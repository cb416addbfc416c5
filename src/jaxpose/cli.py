"""The ``jaxpose`` command.

Each sub-command lives in its own module, which provides ``add_arguments(parser)`` and
``run(args) -> int``; :data:`COMMANDS` maps the command name to that module and a one-line help.
Modules are imported only when their command runs (``jaxpose --help`` stays fast).
"""

from __future__ import annotations

import argparse
import importlib
import sys

COMMANDS: dict[str, tuple[str, str]] = {
    "demo": (
        "jaxpose.commands.demo",
        "run the main job on an embedded default and print a short report",
    ),
    "init": (
        "jaxpose.commands.init_pose",
        "Sharma et al. 2018: the pose of the target in one image, no prior (JSON on stdout)",
    ),
    "eval-speedplus": (
        "jaxpose.commands.eval_speedplus",
        "run the monocular initialisation on a labelled SPEED+ folder and score it",
    ),
    "select-study": (
        "jaxpose.studies.selection",
        "reproduce Ning et al. 2018 Sec. 5: quasi-optimal vs optimal feature selection",
    ),
    "pose-study": (
        "jaxpose.studies.pose",
        "predicted pose covariance vs Monte Carlo scatter of refined poses "
        "(noise levels, geometries)",
    ),
    "stereo-track": (
        "jaxpose.studies.stereo_track",
        "Yang et al. 2024: track a tumbling target in a rendered (or given) stereo sequence",
    ),
}


def _enable_x64() -> None:
    import jax

    jax.config.update("jax_enable_x64", True)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxpose",
        description="Vision-based relative navigation of non-cooperative spacecraft in JAX.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    if not argv or argv[0] not in COMMANDS:
        # No command (or an unknown one, or --help): the top-level parser answers.
        if not argv:
            parser.print_help()
            return 2
        parser.parse_args(argv)  # prints help or an error and exits
        return 2
    command = argv[0]
    module = importlib.import_module(COMMANDS[command][0])
    sub = argparse.ArgumentParser(prog=f"jaxpose {command}", description=COMMANDS[command][1])
    module.add_arguments(sub)
    args = sub.parse_args(argv[1:])
    _enable_x64()
    try:
        return int(module.run(args) or 0)
    except (ValueError, FileNotFoundError) as err:
        print(f"jaxpose {command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
