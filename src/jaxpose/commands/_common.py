"""Plumbing shared by every ``jaxpose`` command.

* :class:`CommandError`: a user's mistake. :func:`jaxpose.cli.main` prints it as one line
  ``jaxpose COMMAND: error: ...`` on stderr and exits with status 2 (no traceback); so do argparse's
  own errors, a ``ValueError`` and a missing file.
* :func:`enable_compilation_cache`: the persistent XLA compilation cache (``$JAXPOSE_CACHE_DIR``,
  default ``~/.cache/jaxpose/xla``); :func:`jaxpose.cli.main` turns it on for every command.
* :func:`progress` and :func:`stage`: tqdm bars on stderr (stdout stays clean for ``--json``).
* One spelling for the shared options: :func:`add_out_argument` (``--out``, default
  ``./jaxpose-out/<command>``), :func:`add_progress_argument` (``--no-progress``),
  :func:`add_figures_argument` (``--no-figures``), :func:`add_image_size_argument`
  (``--image-size W H``, ``WxH`` accepted).
* ``argparse`` types that refuse bad values naming the option: :func:`positive_float`,
  :func:`nonnegative_float`, :func:`finite_float`, :func:`positive_int`, :func:`nonnegative_int`.
* :class:`HelpFormatter`: every option's help ends with its default.
* :func:`add_option_argument` and :func:`with_options`: ``--option NAME=VALUE`` (repeatable)
  sets any field of a command's frozen options object (``group.field`` for a nested group).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path

__all__ = [
    "DEFAULT_OUT_ROOT",
    "CommandError",
    "HelpFormatter",
    "add_figures_argument",
    "add_image_size_argument",
    "add_option_argument",
    "add_out_argument",
    "add_progress_argument",
    "cache_dir",
    "default_out",
    "enable_compilation_cache",
    "finite_float",
    "nonnegative_float",
    "nonnegative_int",
    "positive_float",
    "positive_int",
    "progress",
    "stage",
    "with_options",
]

DEFAULT_OUT_ROOT = Path("jaxpose-out")


class CommandError(Exception):
    """A user's mistake (bad option, bad file): one line on stderr and exit status 2.

    The message should name the option, file or field and say what is expected, e.g.
    ``CommandError("--range-m must be positive; got -10")``.
    """


# ----------------------------------------------------------------------------- compilation cache


def cache_dir() -> Path:
    """Folder of the persistent XLA cache: ``$JAXPOSE_CACHE_DIR`` or ``~/.cache/jaxpose/xla``."""
    env = os.environ.get("JAXPOSE_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "jaxpose" / "xla"


def enable_compilation_cache(min_compile_time_s: float = 0.0) -> Path | None:
    """Persist XLA compilations between runs; returns the cache folder (``None`` if unavailable).

    Every compilation that takes at least ``min_compile_time_s`` is stored: the monocular pipeline
    compiles for about two minutes the first time and loads in seconds afterwards; a study's many
    small kernels (a fraction of a second each) add up to most of a short run, hence the default 0.
    A read-only home or a JAX without the option runs without the cache.
    """
    import jax

    path = cache_dir()
    try:
        path.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(path))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_time_s))
        with contextlib.suppress(AttributeError, KeyError):  # newer JAX: also cache tiny entries
            jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    except (OSError, AttributeError):
        return None
    return path


# ----------------------------------------------------------------------------- progress


def progress(
    iterable: Iterable | None = None,
    *,
    total: int | None = None,
    desc: str = "",
    unit: str = "it",
    enabled: bool = True,
):
    """A tqdm bar on stderr (``--json`` output on stdout stays clean); a no-op bar if disabled.

    Use as ``for x in progress(items, desc=...)`` or ``with progress(total=n) as bar:
    bar.update(1)``.
    """
    from tqdm import tqdm

    return tqdm(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        file=sys.stderr,
        disable=not enabled,
        dynamic_ncols=True,
    )


@contextlib.contextmanager
def stage(desc: str, *, enabled: bool = True, interval_s: float = 0.5) -> Iterator[None]:
    """A one-line ticker ``desc: 00:12`` on stderr while one long step runs (compilation, a single
    pipeline call): a step with no natural count still shows that it is alive."""
    from tqdm import tqdm

    if not enabled:
        yield
        return
    bar = tqdm(
        total=None, desc=desc, bar_format="{desc}: {elapsed}", file=sys.stderr, dynamic_ncols=True
    )
    done = threading.Event()

    def tick() -> None:
        while not done.wait(interval_s):
            bar.refresh()

    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()
        bar.close()


# ----------------------------------------------------------------------------- shared options


def default_out(command: str) -> Path:
    """The default output folder of a command: ``./jaxpose-out/<command>``."""
    return DEFAULT_OUT_ROOT / command


def out_folder(text: str) -> Path:
    """``--out``'s type: a path that is a folder or can become one (no file on it or on the way
    to it, its nearest existing folder writable), checked before any work starts."""
    path = Path(text)
    for part in (path, *path.parents):
        if part.exists():
            if not part.is_dir():
                what = "is a file" if part == path else f"lies below the file {part}"
                raise argparse.ArgumentTypeError(f"{text}: cannot be a folder ({what})")
            if not os.access(part, os.W_OK | os.X_OK):
                raise argparse.ArgumentTypeError(f"{text}: the folder {part} is not writable")
            break
    return path


def add_out_argument(parser: argparse.ArgumentParser, command: str, what: str = "outputs") -> None:
    """``--out DIR`` with the shared default ``./jaxpose-out/<command>`` (:func:`out_folder`)."""
    parser.add_argument(
        "--out", type=out_folder, default=default_out(command), help=f"folder for the {what}"
    )


def add_progress_argument(parser: argparse.ArgumentParser) -> None:
    """``--no-progress``: no progress bar on stderr."""
    parser.add_argument(
        "--no-progress", action="store_true", help="do not show progress bars (on stderr)"
    )


def add_figures_argument(parser: argparse.ArgumentParser) -> None:
    """``--no-figures``: skip the PNG figures."""
    parser.add_argument("--no-figures", action="store_true", help="do not write the PNG figures")


class _ImageSize(argparse.Action):
    def __call__(self, parser, namespace, values, option_string=None):
        parts = values[0].lower().split("x") if len(values) == 1 else list(values)
        try:
            size = [int(p) for p in parts]
        except ValueError:
            size = []
        if len(size) != 2 or min(size) < 1:
            parser.error(
                f"argument {option_string}: expected two positive integers W H (or WxH); "
                f"got {' '.join(values)!r}"
            )
        setattr(namespace, self.dest, tuple(size))


def add_image_size_argument(
    parser, default: tuple[int, int], help: str = "image size in pixels"
) -> None:
    """``--image-size W H`` (``WxH`` accepted too), parsed to a tuple ``(W, H)`` of ints >= 1."""
    parser.add_argument(
        "--image-size",
        nargs="+",
        action=_ImageSize,
        default=tuple(default),
        help=help,
    )


# ----------------------------------------------------------------------------- argparse types


def _number(kind, text: str):
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected {'an integer' if kind is int else 'a number'}; got {text!r}"
        ) from None
    if kind is float and not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number; got {text!r}")
    return value


def finite_float(text: str) -> float:
    """A finite float (no nan, no inf)."""
    return _number(float, text)


def positive_float(text: str) -> float:
    """A finite float > 0."""
    value = _number(float, text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive; got {text!r}")
    return value


def nonnegative_float(text: str) -> float:
    """A finite float >= 0."""
    value = _number(float, text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be zero or positive; got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1."""
    value = _number(int, text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1; got {text!r}")
    return value


def nonnegative_int(text: str) -> int:
    """An integer >= 0 (seeds, counts that may be zero)."""
    value = _number(int, text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be zero or positive; got {text!r}")
    return value


# ----------------------------------------------------------------------------- help and errors


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the description's line breaks and ends each option's help with its default (none
    for flags, ``--help``, options whose default is ``None`` or empty (a repeatable option given
    no value) and helps that state it already)."""

    def _format_args(self, action: argparse.Action, default_metavar: str | None) -> str:
        if isinstance(action, _ImageSize):  # two numbers (or one WxH), shown as the two
            return "W H"
        return super()._format_args(action, default_metavar)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if (
            "default" in text  # the help states its default itself
            or action.default is None
            or action.default is argparse.SUPPRESS
            or (isinstance(action.default, list | tuple) and not action.default)
            or isinstance(action.default, bool)
            or not action.option_strings
            or isinstance(action, argparse._HelpAction | argparse._VersionAction)
        ):
            return text
        default = action.default
        if isinstance(default, list | tuple):
            shown = " ".join(str(x) for x in default)
        else:
            shown = str(default)
        return f"{text} (default: {shown.replace('%', '%%')})".strip()


class CommandParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors raise :class:`CommandError` (one line, exit 2,
    printed by :func:`jaxpose.cli.main`) instead of printing the usage and exiting itself."""

    def error(self, message: str):  # type: ignore[override]
        raise CommandError(f"{message} (see {self.prog} --help)")


# ----------------------------------------------------------------------------- --option NAME=VALUE
def add_option_argument(parser: argparse.ArgumentParser, options_name: str, example: str) -> None:
    """``--option NAME=VALUE``, repeatable: a field of ``options_name`` (e.g. ``InitOptions``)
    set from the command line; see :func:`with_options`. ``example``: a ``GROUP.FIELD=VALUE`` of
    those options, shown in the help."""
    parser.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help=f"set a field of {options_name} (repeat for several): NAME a field, or GROUP.FIELD "
        f"for a nested group (e.g. {example}); VALUE a Python literal (1.5, True, "
        "None, (1, 2)) or a bare word taken as a string",
    )


def _literal(text: str):
    import ast

    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        if text.replace("-", "_").isidentifier():  # a bare word: a string (lsd, dop, ...)
            return text
        return _NOT_A_VALUE


_NOT_A_VALUE = object()


def _checked_value(value, annotation, where: str):
    """``value`` for a field annotated ``annotation`` (its string or type): ``bool`` takes True or
    False, ``int`` an integer, ``float`` a number (an integer is taken as a float); any other
    annotation (a union, a string, a container) is left to the options object's own checks."""
    kind = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", "")
    if kind == "bool" and not isinstance(value, bool):
        raise CommandError(f"{where} takes True or False; got {value!r}")
    if kind == "int" and (isinstance(value, bool) or not isinstance(value, int)):
        raise CommandError(f"{where} takes an integer; got {value!r}")
    if kind == "float":
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise CommandError(f"{where} takes a number; got {value!r}")
        value = float(value)
    return value


def with_options(base, items: Iterable[str], flag: str = "--option"):
    """``base`` (a frozen dataclass of options) with the ``NAME=VALUE`` items set, in order.

    ``NAME`` is a field of ``base`` or ``GROUP.FIELD`` with ``GROUP`` a field of ``base`` that is
    itself a dataclass; ``VALUE`` a Python literal, or a bare word taken as a string. A field
    annotated ``float``, ``int`` or ``bool`` takes only that kind. Raises
    :class:`CommandError` naming the item for a missing ``=``, an unknown field (listing the
    known ones), a value of the wrong kind, or one the options object refuses (its own
    ``ValueError`` or ``TypeError``)."""
    import dataclasses

    options = base
    kind = type(base).__name__
    for item in items:
        name, eq, text = item.partition("=")
        name = name.strip()
        head = f"{flag} {item!r}"
        if not eq or not name:
            raise CommandError(
                f"{head}: expected NAME=VALUE (NAME: a field of {kind}, or GROUP.FIELD)"
            )
        group, _, field = name.rpartition(".")
        if "." in group:
            raise CommandError(f"{head}: one level of GROUP.FIELD at most")
        target = getattr(options, group, None) if group else options
        if not dataclasses.is_dataclass(target):
            groups = [f.name for f in dataclasses.fields(options) if _is_group(options, f.name)]
            raise CommandError(
                f"{head}: {kind} has no option group {group!r} (groups: "
                f"{', '.join(groups) or 'none'})"
            )
        names = [f.name for f in dataclasses.fields(target)]
        if field not in names:
            owner = kind if not group else f"{type(target).__name__} ({kind}.{group})"
            raise CommandError(
                f"{head}: {owner} has no field {field!r} (fields: {', '.join(names)})"
            )
        value = _literal(text.strip())
        if value is _NOT_A_VALUE:
            raise CommandError(f"{head}: {text.strip()!r} is neither a Python literal nor a word")
        annotation = next(f.type for f in dataclasses.fields(target) if f.name == field)
        value = _checked_value(value, annotation, f"{head}: {kind}.{name}")
        try:
            inner = dataclasses.replace(target, **{field: value})
            options = dataclasses.replace(options, **{group: inner}) if group else inner
        except (ValueError, TypeError) as err:
            raise CommandError(f"{head}: {err}") from None
    return options


def _is_group(options, name: str) -> bool:
    import dataclasses

    return dataclasses.is_dataclass(getattr(options, name, None))
