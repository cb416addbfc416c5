"""The ``jaxpose`` command.

Each sub-command lives in its own module, which provides ``add_arguments(parser)`` and
``run(args) -> int``; :data:`COMMANDS` maps the command name to that module and a one-line help.
Modules are imported only when their command runs (``jaxpose --help`` stays fast).

Every command runs with float64 and the persistent compilation cache
(:func:`jaxpose.commands._common.enable_compilation_cache`). A user's mistake (a bad option, a
missing or malformed file: :class:`~jaxpose.commands._common.CommandError`, ``ValueError``,
``OSError``) is printed as one line ``jaxpose COMMAND: error: ...`` and exits with status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from jaxpose.commands._common import CommandError, CommandParser, HelpFormatter

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
        "jaxpose.commands.select_study",
        "reproduce Ning et al. 2018 Sec. 5: quasi-optimal vs optimal feature selection",
    ),
    "pose-study": (
        "jaxpose.commands.pose_study",
        "predicted pose covariance vs Monte Carlo scatter of refined poses "
        "(noise levels, geometries)",
    ),
    "stereo-track": (
        "jaxpose.studies.stereo_track",
        "Yang et al. 2024: track a tumbling target in a rendered (or given) stereo sequence",
    ),
}


def _version() -> str:
    """``jaxpose X (python A, jax B, ...)``: the versions a bug report or a figure needs."""
    from jaxpose.io.software import software_versions

    v = software_versions()
    rest = ", ".join(f"{k} {v[k]}" for k in v if k != "jaxpose" and v[k] is not None)
    return f"jaxpose {v['jaxpose'] or '0+unknown'} ({rest})"


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser (``jaxpose --help``, ``jaxpose --version``)."""
    parser = CommandParser(
        prog="jaxpose",
        description="Vision-based relative navigation of non-cooperative spacecraft in JAX.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
    return parser


def command_parser(command: str) -> argparse.ArgumentParser:
    """The parser of one sub-command, with its module's options."""
    module = importlib.import_module(COMMANDS[command][0])
    parser = CommandParser(
        prog=f"jaxpose {command}",
        description=COMMANDS[command][1],
        formatter_class=HelpFormatter,
    )
    module.add_arguments(parser)
    return parser


def _fail(prog: str, err: BaseException) -> int:
    message = " ".join(str(err).split()) or type(err).__name__
    print(f"{prog}: error: {message}", file=sys.stderr)
    return 2


def _one_line_warning(prog: str):
    """The package's own warning classes (a recomputed chunk, ...) as one line
    ``jaxpose COMMAND: warning: ...``; other warnings as Python shows them."""
    previous = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if not category.__module__.startswith("jaxpose"):
            return previous(message, category, filename, lineno, file, line)
        print(f"{prog}: warning: {message}", file=sys.stderr if file is None else file)

    return show


def main(argv: list[str] | None = None) -> int:
    """Run ``jaxpose ARGV``; returns the exit status (0, or 2 for a user's mistake)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:
        build_parser().print_help()
        return 2
    if argv[0] not in COMMANDS:
        # --help, --version, or an unknown command: the top-level parser answers.
        try:
            build_parser().parse_args(argv)
        except CommandError as err:
            return _fail("jaxpose", err)
        except SystemExit as done:  # --help or --version printed its answer
            return int(done.code or 0)
        return 2
    command = argv[0]
    prog = f"jaxpose {command}"
    module = importlib.import_module(COMMANDS[command][0])
    try:
        args = command_parser(command).parse_args(argv[1:])
    except CommandError as err:
        return _fail(prog, err)
    except SystemExit as done:  # --help printed its answer
        return int(done.code or 0)
    import jax

    from jaxpose.commands._common import enable_compilation_cache

    jax.config.update("jax_enable_x64", True)
    enable_compilation_cache()
    with warnings.catch_warnings():
        warnings.showwarning = _one_line_warning(prog)
        try:
            return int(module.run(args) or 0)
        except (CommandError, ValueError, OSError) as err:
            return _fail(prog, err)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
