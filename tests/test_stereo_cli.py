"""``jaxpose stereo-track`` through :func:`jaxpose.cli.main`: bad options and bad stereo folders
give exit status 2 and one error line naming the option, file or field; a folder run honours
``--frames``, reports errors only with ``poses.csv`` and never writes NaN into its JSON line."""

import json

import cv2
import numpy as np
import pytest

from jaxpose.cli import main
from jaxpose.core.geometry import dcm_to_quat
from jaxpose.vision.stereo_render import StereoScene, default_rig, render_stereo_frame

W, H = 320, 240


def _cli(argv, capsys):
    try:
        code = main(argv)
    except SystemExit as done:  # argparse's own errors
        code = done.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def pairs():
    rig = default_rig(W, H)
    scene = StereoScene(frames=3, range_m=1.2)
    return rig, [render_stereo_frame(scene, rig, k) for k in range(3)]


def _folder(path, pairs, *, n=3, calibration=None, truth=False):
    rig, frames = pairs
    (path / "left").mkdir(parents=True)
    (path / "right").mkdir()
    for fr in frames[:n]:
        cv2.imwrite(str(path / "left" / f"{fr.index:06d}.png"), fr.left)
        cv2.imwrite(str(path / "right" / f"{fr.index:06d}.png"), fr.right)
    cam = {"Nu": W, "Nv": H, "cameraMatrix": np.asarray(rig.left.K).tolist()}
    data = {"left": cam, "right": cam, "R_rl": np.eye(3).tolist(), "t_rl": [-0.3, 0.0, 0.0]}
    if calibration is not None:
        data = calibration(data)
    (path / "calibration.json").write_text(json.dumps(data))
    if truth:
        rows = ["frame,qw,qx,qy,qz,tx,ty,tz"]
        for fr in frames[:n]:
            q = np.asarray(dcm_to_quat(np.asarray(fr.pose.R)))
            rows.append(",".join(str(v) for v in [fr.index, *q, *np.asarray(fr.pose.t)]))
        (path / "poses.csv").write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize(
    "argv, option",
    [
        (["--frame-rate-hz", "-5"], "--frame-rate-hz"),
        (["--frame-rate-hz", "0"], "--frame-rate-hz"),
        (["--frame-rate-hz", "nan"], "--frame-rate-hz"),
        (["--rate-deg-s", "nan"], "--rate-deg-s"),
        (["--rate-deg-s", "1e-6"], "--rate-deg-s"),
        (["--seed", "-1"], "--seed"),
        (["--frames", "1"], "--frames"),
        (["--frames", "10000000"], "--frames"),
        (["--range-m", "0.2"], "--range-m"),
        (["--blur", "2"], "--blur"),
        (["--glints", "-1"], "--glints"),
        (["--image-size", "640"], "--image-size"),
        (["--image-size", "0x480"], "--image-size"),
    ],
)
def test_bad_options_exit_2_naming_the_option(argv, option, capsys, tmp_path):
    code, _, err = _cli(["stereo-track", *argv, "--out", str(tmp_path)], capsys)
    assert code == 2
    line = [x for x in err.splitlines() if "error" in x][-1]
    assert line.startswith("jaxpose stereo-track: error:") and option in line
    assert "Traceback" not in err


def test_a_slow_spin_is_refused_before_rendering_and_says_what_to_change(capsys, tmp_path):
    code, _, err = _cli(["stereo-track", "--rate-deg-s", "1e-6", "--out", str(tmp_path)], capsys)
    assert code == 2 and "--frames" in err and "limit" in err
    assert not (tmp_path / "trajectory.csv").exists()


def test_folder_run_honours_frames_and_reports_errors_with_a_truth_file(pairs, tmp_path, capsys):
    folder = _folder(tmp_path / "seq", pairs, truth=True)
    out = tmp_path / "out"
    code, stdout, err = _cli(
        ["stereo-track", "--images", str(folder), "--frames", "2", "--json", "--out", str(out)],
        capsys,
    )
    assert code == 0, err
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["frames"] == 2 and summary["lost_frames"] == 0
    # started at the identity, aligned on the first frame: errors of a few mm on a 1.2 m scene
    assert max(summary["rms_position_mm"]) < 20.0
    assert max(summary["rms_attitude_deg"]) < 1.0
    for name in ("trajectory.csv", "fig3_position_track.png", "fig4_position.png"):
        assert (out / name).is_file()


def test_folder_with_one_pair_and_no_truth_writes_no_nan(pairs, tmp_path, capsys):
    folder = _folder(tmp_path / "seq", pairs, n=1)
    out = tmp_path / "out"
    code, stdout, err = _cli(
        ["stereo-track", "--images", str(folder), "--json", "--no-figures", "--out", str(out)],
        capsys,
    )
    assert code == 0, err
    line = stdout.strip().splitlines()[-1]
    assert "NaN" not in line and "Infinity" not in line
    summary = json.loads(line)
    assert summary["frames"] == 1 and summary["fps"] is None
    assert summary["rms_position_mm"] is None  # no poses.csv: no errors


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda d: {k: v for k, v in d.items() if k != "right"}, ["calibration.json", "'right'"]),
        (lambda d: {**d, "t_rl": "abc"}, ["calibration.json", "'t_rl'"]),
        (lambda d: {**d, "R_rl": np.diag([1.0, 1.0, -1.0]).tolist()}, ["'R_rl'", "rotation"]),
        (lambda d: {**d, "left": {"cameraMatrix": "abc"}}, ["calibration.json", "'left'"]),
        (lambda d: {**d, "right": {"Nu": 320}}, ["calibration.json", "'right'"]),
    ],
)
def test_bad_calibration_names_file_and_field_and_leaves_no_file(
    pairs, tmp_path, capsys, edit, words
):
    folder = _folder(tmp_path / "seq", pairs, n=2, calibration=edit)
    before = sorted(p.name for p in folder.rglob("*"))
    code, _, err = _cli(
        ["stereo-track", "--images", str(folder), "--out", str(tmp_path / "out")], capsys
    )
    assert code == 2 and "Traceback" not in err
    line = err.strip().splitlines()[-1]
    assert line.startswith("jaxpose stereo-track: error:")
    for w in words:
        assert w in line
    assert sorted(p.name for p in folder.rglob("*")) == before


def test_unreadable_and_wrong_size_images_are_named(pairs, tmp_path, capsys):
    folder = _folder(tmp_path / "a", pairs, n=2)
    bad = folder / "right" / "000001.png"
    bad.write_bytes(b"not a png")
    code, _, err = _cli(["stereo-track", "--images", str(folder), "--out", str(tmp_path)], capsys)
    assert code == 2 and str(bad) in err and "cannot read" in err
    folder = _folder(tmp_path / "b", pairs, n=2)
    small = folder / "left" / "000001.png"
    cv2.imwrite(str(small), np.zeros((120, 160), np.uint8))
    code, _, err = _cli(["stereo-track", "--images", str(folder), "--out", str(tmp_path)], capsys)
    assert code == 2 and str(small) in err and "160x120" in err and f"{W}x{H}" in err


def test_rendering_options_with_images_are_refused(pairs, tmp_path, capsys):
    folder = _folder(tmp_path / "seq", pairs, n=2)
    code, _, err = _cli(
        ["stereo-track", "--images", str(folder), "--range-m", "3", "--out", str(tmp_path)],
        capsys,
    )
    assert code == 2 and "--range-m" in err and "--images" in err
    # the monocular start needs the target's model, which a folder does not carry
    code, _, err = _cli(
        ["stereo-track", "--images", str(folder), "--init", "monocular", "--out", str(tmp_path)],
        capsys,
    )
    assert code == 2 and "--init monocular" in err and "model" in err


def test_help_shows_every_option_with_a_default(capsys):
    code, out, _ = _cli(["stereo-track", "--help"], capsys)
    assert code == 0
    text = " ".join(out.split())
    for option in (
        "--frames",
        "--rate-deg-s",
        "--range-m",
        "--blur",
        "--glints",
        "--frame-rate-hz",
        "--seed",
        "--image-size",
        "--init",
        "--points-only",
        "--images",
        "--out",
        "--no-figures",
        "--no-progress",
    ):
        assert option in text
    assert text.count("default") >= 11  # every option that takes a value
