"""The pose-study command: predicted covariance vs Monte Carlo (small run)."""

import json

import pytest

from jaxpose.cli import main


def test_pose_study_small_run(tmp_path, capsys):
    out = tmp_path / "study"
    rc = main(
        [
            "pose-study",
            "--trials",
            "200",
            "--noise",
            "0.5",
            "2.0",
            "--geometries",
            "cube-3m",
            "plane-8m-tilt40",
            "--tolerance",
            "0.2",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert rc == 0
    results = json.loads((out / "results.json").read_text())
    assert {"scenario", "groups", "check"} <= set(results)
    assert len(results["groups"]) == 4
    for g in results["groups"]:
        assert g["trials"] == 200 and g["ok_fraction"] == 1.0
        assert len(g["pred_std"]) == len(g["emp_std"]) == len(g["ratio"]) == 6
        assert 4.0 < g["nees_mean"] < 8.0
    assert results["check"]["passed"], results["check"]
    assert (out / "std_vs_noise.png").stat().st_size > 10_000
    assert (out / "scatter.png").stat().st_size > 10_000
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert json.loads(last)["passed"] is True


def test_pose_study_bad_arguments(tmp_path, capsys):
    assert main(["pose-study", "--trials", "1", "--out", str(tmp_path)]) == 2
    assert "trials" in capsys.readouterr().err
    assert main(["pose-study", "--noise", "-1", "--out", str(tmp_path)]) == 2
    assert "--noise" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv, option",
    [
        (["--check-noise", "0"], "--check-noise"),
        (["--check-noise", "-1"], "--check-noise"),
        (["--check-noise", "nan"], "--check-noise"),
        (["--init-perturbation", "nan", "0.02"], "--init-perturbation"),
        (["--init-perturbation", "2", "-0.1"], "--init-perturbation"),
        (["--noise", "0.5", "inf"], "--noise"),
        (["--tolerance", "0"], "--tolerance"),
        (["--trials", "0"], "--trials"),
        (["--seed", "-1"], "--seed"),
        (["--geometries", "sphere"], "--geometries"),
    ],
)
def test_pose_study_refuses_bad_values_naming_the_option(argv, option, tmp_path, capsys):
    assert main(["pose-study", *argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jaxpose pose-study: error: ") and option in err[0]
    assert not (tmp_path / "results.json").exists()


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"check_noise": 0.0}, "check_noise"),
        ({"check_noise": float("nan")}, "check_noise"),
        ({"noise": [0.5, -1.0]}, "noise"),
        ({"perturbation": (float("nan"), 0.02)}, "perturbation"),
        ({"trials": 1}, "trials"),
        ({"geometries": ["sphere"]}, "geometries"),
    ],
)
def test_run_study_refuses_bad_values_naming_the_argument(kwargs, name):
    from jaxpose.studies.pose import run_study

    with pytest.raises(ValueError, match=name):
        run_study(**({"geometries": ["cube-3m"], "trials": 2} | kwargs), progress=False)


def test_run_group_refuses_a_bad_sigma():
    from jaxpose.studies.pose import GEOMETRIES, run_group

    for sigma in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="sigma"):
            run_group(GEOMETRIES["cube-3m"], sigma, 10)
