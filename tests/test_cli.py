"""The jaxpose command: help for every sub-command, --version, one-line errors with exit 2."""

import argparse
import platform
from importlib import metadata

import pytest

from jaxpose import __version__
from jaxpose.cli import COMMANDS, command_parser, main
from jaxpose.commands import _common

# Commands whose every option must carry a help text (the others' owners adopt the rule).
DOCUMENTED = ("demo", "select-study", "pose-study")


def test_top_level_help_lists_commands(capsys):
    assert main([]) == 2
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert name in out


def test_version(capsys):
    assert main(["--version"]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith(f"jaxpose {__version__} (python {platform.python_version()}, ")
    # the numerical stack a figure depends on, read here from the installed distributions
    for dist, name in [
        ("jax", "jax"),
        ("numpy", "numpy"),
        ("opencv-contrib-python-headless", "opencv"),
    ]:
        assert f"{name} {metadata.version(dist)}" in out


def test_python_dash_m_runs_the_same_command(capsys):
    """``python -m jaxpose`` (no script on PATH, a cluster's srun) is the jaxpose command."""
    import subprocess
    import sys

    assert main(["--version"]) == 0
    expected = capsys.readouterr().out
    run = subprocess.run(
        [sys.executable, "-m", "jaxpose", "--version"], capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout == expected
    bad = subprocess.run(
        [sys.executable, "-m", "jaxpose", "no-such-command"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert bad.returncode == 2 and "no-such-command" in bad.stderr


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_each_command_has_help_with_its_options(command, capsys):
    assert main([command, "--help"]) == 0
    out = capsys.readouterr().out
    assert f"jaxpose {command}" in out and "--" in out.split("options:", 1)[-1]
    assert "(default: )" not in out  # a repeatable option given nothing shows no default


@pytest.mark.parametrize("command", DOCUMENTED)
def test_every_option_has_help_and_shows_its_default(command):
    parser = command_parser(command)
    formatter = parser._get_formatter()
    for action in parser._actions:
        if not action.option_strings or isinstance(action, argparse._HelpAction):
            continue
        assert action.help, f"{command} {action.option_strings[0]} has no help"
        if action.default is not None and not isinstance(action.default, bool):
            text = formatter._get_help_string(action)
            assert "default" in text, f"{command} {action.option_strings[0]}: {text!r}"


def test_unknown_command_is_a_one_line_error(capsys):
    assert main(["no-such-command"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jaxpose: error: ") and "invalid choice" in err[0]


@pytest.mark.parametrize(
    "argv, option",
    [
        (["select-study", "--cases", "x"], "--cases"),
        (["select-study", "--no-such-option"], "--no-such-option"),
        (["pose-study", "--trials", "1.5"], "--trials"),
    ],
)
def test_usage_errors_are_one_line_naming_the_option(argv, option, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"jaxpose {argv[0]}: error: ") and option in err[0]


@pytest.mark.parametrize(
    "kind, text, ok",
    [
        (_common.positive_float, "2.5", 2.5),
        (_common.positive_float, "0", None),
        (_common.positive_float, "-1", None),
        (_common.positive_float, "nan", None),
        (_common.positive_float, "inf", None),
        (_common.nonnegative_float, "0", 0.0),
        (_common.nonnegative_float, "-0.1", None),
        (_common.finite_float, "-3", -3.0),
        (_common.finite_float, "-inf", None),
        (_common.positive_int, "3", 3),
        (_common.positive_int, "0", None),
        (_common.positive_int, "2.0", None),
        (_common.nonnegative_int, "0", 0),
        (_common.nonnegative_int, "-1", None),
    ],
)
def test_option_types(kind, text, ok):
    if ok is None:
        with pytest.raises(argparse.ArgumentTypeError, match=repr(text)):
            kind(text)
    else:
        assert kind(text) == ok


def test_compilation_cache_and_default_out(tmp_path, monkeypatch):
    import jax

    monkeypatch.setenv("JAXPOSE_CACHE_DIR", str(tmp_path / "xla"))
    before = jax.config.jax_compilation_cache_dir
    try:
        assert _common.enable_compilation_cache() == tmp_path / "xla"
        assert (tmp_path / "xla").is_dir()
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "xla")
    finally:
        jax.config.update("jax_compilation_cache_dir", before)
    assert _common.default_out("select-study").as_posix() == "jaxpose-out/select-study"


def test_progress_bars_write_to_stderr_only(capsys):
    assert list(_common.progress(range(3), desc="count")) == [0, 1, 2]
    with _common.stage("one step", interval_s=0.01):
        pass
    out, err = capsys.readouterr()
    assert out == "" and "count" in err and "one step" in err
    list(_common.progress(range(3), desc="quiet", enabled=False))
    with _common.stage("quiet", enabled=False):
        pass
    assert capsys.readouterr().err == ""


def test_annotations_are_checked_while_testing():
    """pyproject's addopts turn on jaxtyping's import hook with beartype for the whole package: a
    call against an annotation fails here (a string for a float field; an int is a float)."""
    import jaxtyping

    from jaxpose.studies.selection import Scenario

    with pytest.raises(jaxtyping.TypeCheckError):
        Scenario(range_m="5")
    with pytest.raises(ValueError, match="--range-m"):  # a bool passes as an int, not as a range
        Scenario(range_m=True)


def test_with_options_sets_fields_and_nested_groups():
    import dataclasses

    from jaxpose.pipelines.monocular import InitOptions
    from jaxpose.pipelines.stereo import TrackerOptions

    base = InitOptions()
    got = _common.with_options(
        base, ["fit_model_weight=0.25", "detection.detector=lsd", "top_k = 3", "trace=True"]
    )
    want = dataclasses.replace(
        base,
        fit_model_weight=0.25,
        top_k=3,
        trace=True,
        detection=dataclasses.replace(base.detection, detector="lsd"),
    )
    assert got == want and base == InitOptions()  # the base is left alone
    t = _common.with_options(
        TrackerOptions(), ["stereo.line_trim_px=1.5", "window_frames=6", "features.subpixel=peak"]
    )
    assert t.stereo.line_trim_px == 1.5 and t.window_frames == 6 and t.features.subpixel == "peak"
    assert _common.with_options(base, []) is base


@pytest.mark.parametrize(
    "item, words",
    [
        ("nope=1", ["InitOptions has no field 'nope'", "fit_model_weight"]),
        ("detection.nope=1", ["DetectionOptions (InitOptions.detection) has no field 'nope'"]),
        ("foo.x=1", ["InitOptions has no option group 'foo'", "detection"]),
        ("a.b.c=1", ["one level"]),
        ("fit_model_weight", ["expected NAME=VALUE"]),
        ("=3", ["expected NAME=VALUE"]),
        ("top_k=[1,", ["neither a Python literal nor a word"]),
        ("top_k=three", ["InitOptions.top_k takes an integer; got 'three'"]),
        ("top_k=2.5", ["takes an integer"]),
        ("trace=1", ["takes True or False"]),
        ("fit_model_weight=lsd", ["takes a number"]),
    ],
)
def test_with_options_errors_name_the_item(item, words):
    from jaxpose.pipelines.monocular import InitOptions

    with pytest.raises(_common.CommandError) as err:
        _common.with_options(InitOptions(), [item])
    for w in words:
        assert w in str(err.value), str(err.value)


def test_with_options_passes_on_what_the_options_refuse():
    from jaxpose.pipelines.stereo import TrackerOptions

    with pytest.raises(_common.CommandError, match="subpixel_half_window"):
        _common.with_options(TrackerOptions(), ["features.subpixel_half_window=0"])


@pytest.mark.parametrize(
    "argv, words",
    [
        (["eval-speedplus", "{tmp}", "--option", "nope=1"], ["--option 'nope=1'"]),
        (["init", "{tmp}/x.png", "--camera", "{tmp}/c.json", "--option", "x"], ["NAME=VALUE"]),
        (["stereo-track", "--frames", "3", "--option", "use_lines=False"], ["--points-only"]),
    ],
)
def test_option_errors_are_one_line(argv, words, tmp_path, capsys):
    if argv[0] == "init":  # the options are read after the files: give it readable ones
        import json

        import cv2
        import numpy as np

        cv2.imwrite(str(tmp_path / "x.png"), np.zeros((64, 64), np.uint8))
        (tmp_path / "c.json").write_text(
            json.dumps(
                {"cameraMatrix": [[100, 0, 32], [0, 100, 32], [0, 0, 1]], "Nu": 64, "Nv": 64}
            )
        )
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"jaxpose {argv[0]}: error: "), err
    for w in words:
        assert w in err[0], err[0]


@pytest.mark.parametrize(
    "command, options",
    [
        ("init", "jaxpose.pipelines.monocular:InitOptions"),
        ("eval-speedplus", "jaxpose.pipelines.monocular:InitOptions"),
        ("stereo-track", "jaxpose.pipelines.stereo:TrackerOptions"),
    ],
)
def test_the_option_example_in_each_help_is_a_valid_setting(command, options):
    import importlib
    import re

    module, name = options.split(":")
    cls = getattr(importlib.import_module(module), name)
    action = next(a for a in command_parser(command)._actions if "--option" in a.option_strings)
    example = re.search(r"\(e\.g\. ([^)]*)\)", action.help).group(1)
    group, field_value = example.split(".", 1)
    field, value = field_value.split("=")
    got = _common.with_options(cls(), [example])
    assert str(getattr(getattr(got, group), field)) == value
