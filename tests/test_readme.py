"""The README is a user guide that works as written: its first Python block runs from the parent
folder of a clone named ``jaxpose`` (the folder must not shadow the package), the PnP block that
continues it gives the statuses it shows, its two commands are the ones CI runs, and it stays
short."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, re.S)


def _run(code: str, tmp_path: Path) -> subprocess.CompletedProcess:
    """Run ``code`` as a script in ``tmp_path``, which holds a folder ``jaxpose`` that is this
    checkout (as a clone would be), with this checkout's package first on the path."""
    (tmp_path / "jaxpose").symlink_to(ROOT, target_is_directory=True)
    script = tmp_path / "tour.py"
    script.write_text(code)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        [str(ROOT / "src")] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    )
    return subprocess.run(
        [sys.executable, script.name],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


@pytest.mark.slow
def test_first_block_and_pnp_block_run_from_a_clones_parent(tmp_path):
    blocks = _python_blocks(README.read_text())
    assert len(blocks) >= 2, "the README needs the DOP block and the PnP block"
    first, pnp = blocks[0], blocks[1]
    assert "solve_pnp" in pnp and "throw=False" in pnp
    assert "../" not in first and "open(" not in first, "the first block must need no files"
    proc = _run(first + "\n" + pnp, tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = proc.stdout
    # the first block prints DOPs in m/px and rad/px and a ratio to the optimum >= 1
    pdop, adop = (float(x) for x in re.search(r"PDOP (\S+) m/px, ADOP (\S+) rad/px", out).groups())
    assert 0 < pdop < 1 and 0 < adop < 1
    ratio = float(re.search(r"m/px, (\S+) x the optimum", out).group(1))
    assert 1.0 <= ratio < 2.0
    # the PnP block: the one broken problem has its own status, the 99 others are solved, as the
    # comment in the README says
    assert "{'OK': 99, 'NONFINITE_INPUT': 1}" in out
    assert "{'OK': 99, 'NONFINITE_INPUT': 1}" in pnp
    err_mm = float(re.search(r"median position error (\S+) mm", out).group(1))
    assert 0 < err_mm < 50  # 0.5 px of noise on a 1 m plate at 10 m: millimetres


def test_first_block_runs_alone_without_files():
    first = _python_blocks(README.read_text())[0]
    compile(first, "README first block", "exec")  # valid as-is
    assert "import jaxpose as jp" in first


def test_the_two_commands_are_the_ones_ci_runs():
    text = README.read_text()
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    marker = next(i for i, line in enumerate(ci) if "keep the two identical" in line)
    test_command = ci[marker + 1].strip()
    assert test_command == 'pip install -q -e ".[test]" && python -m pytest -q -n 2'
    commands = re.search(r"## The two commands\n.*?```bash\n(.*?)```", text, re.S).group(1)
    lines = [line for line in commands.splitlines() if line and not line.startswith("#")]
    venv = "python3.11 -m venv .venv && . .venv/bin/activate && "
    assert lines == [venv + "pip install -e . && jaxpose demo", venv + test_command]


def test_readme_is_short_and_self_contained():
    text = README.read_text()
    assert text.count("\n") <= 350, text.count("\n")
    assert len(text) <= 25000, len(text)
    assert "../shared" not in text and "shared/docs" not in text
    assert not re.search(r"\bseed 00[012]\b", text, re.I)
    assert not re.search(r"\b[Ss]ession \d", text)
    # every system is in the tour and in the results
    for needle in (
        "jp.dop(",
        "solve_pnp(",
        "initialise_pose(",
        "StereoTracker(",
        "calibration.json",
        "cameraMatrix",
        "## Current results",
    ):
        assert needle in text, needle


@pytest.mark.slow
def test_stereo_block_tracks_a_folder_in_the_layout_shown(tmp_path):
    """The README's stereo folder (its calibration.json as shown, three rendered pairs) and its
    Python block: every frame tracked on tens of points."""
    import json

    import cv2

    from jaxpose.core.camera import PinholeCamera, StereoCamera
    from jaxpose.vision.stereo_render import StereoScene, render_sequence

    text = README.read_text()
    calibration = next(b for b in re.findall(r"```json\n(.*?)```", text, re.S) if '"t_rl"' in b)
    data = json.loads(calibration)
    folder = tmp_path / "my_sequence"
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True)
    (folder / "calibration.json").write_text(calibration)
    left = PinholeCamera.from_K(
        data["left"]["cameraMatrix"], width=data["left"]["Nu"], height=data["left"]["Nv"]
    )
    rig = StereoCamera.from_baseline(left, -float(data["t_rl"][0]))
    for frame in render_sequence(StereoScene(frames=3), rig):
        cv2.imwrite(str(folder / "left" / f"{frame.index:06d}.png"), frame.left)
        cv2.imwrite(str(folder / "right" / f"{frame.index:06d}.png"), frame.right)
    block = next(b for b in _python_blocks(text) if "StereoTracker(" in b)
    proc = _run(block.replace("print(i, ", "print('FRAME', i, "), tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    frames = [line.split() for line in proc.stdout.splitlines() if line.startswith("FRAME")]
    assert [f[1:3] for f in frames] == [["0", "OK"], ["1", "OK"], ["2", "OK"]]
    assert all(int(f[3]) > 50 for f in frames)  # points used by the pose, each frame
