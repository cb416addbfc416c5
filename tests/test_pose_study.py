"""The pose-study command: predicted covariance vs Monte Carlo (small run)."""

import json

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
