"""``bench/stereo.py --scene NAME=JSON``: a scene of the user's, checked before anything runs."""

import argparse

import pytest
from bench_module import load_bench


def _parser():
    p = argparse.ArgumentParser()
    p.exit_on_error = True
    return p


@pytest.mark.parametrize(
    "spec",
    [
        "no-equals-sign",
        '={"range_m": 3}',  # no name
        'd1-clean-2m={"range_m": 3}',  # a suite scene's name
        "x={not json}",
        "x=[1, 2]",
        'x={"range_m": 3, "warp": 2}',  # no such StereoScene field
        'x={"range_m": -1}',  # the scene's own check
    ],
)
def test_a_malformed_scene_is_refused_by_name(spec, capsys):
    bench = load_bench("stereo")
    with pytest.raises(SystemExit):
        bench._own_scene(_parser(), spec)
    assert "--scene" in capsys.readouterr().err


def test_a_scene_of_ones_own_joins_the_suite_as_own():
    bench = load_bench("stereo")
    name = bench._own_scene(_parser(), 'far={"range_m": 4.5, "spin_axis_body": [0, 0.5, 1]}')
    assert name == "far" and bench.SCENES["far"] == (
        "own",
        {"range_m": 4.5, "spin_axis_body": (0, 0.5, 1)},
    )
    scene = bench.scene_of("far", 4, seed=0)
    assert scene.range_m == 4.5 and scene.n_frames() == 4
