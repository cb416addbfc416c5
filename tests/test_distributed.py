"""Studies across processes: two CPU processes on localhost (``jax.distributed``, gloo collectives)
give the ``results.json`` of one process, timings aside; the multi-process options refuse bad
values with one-line errors."""

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from jaxpose.cli import main
from jaxpose.studies import _distributed as dist

REPO = Path(__file__).resolve().parents[1]

SELECT = ["--n", "8", "--m", "5", "--cases", "6", "--seed", "3", "--chunk-size", "4"]
POSE = ["--trials", "21", "--noise", "0.5", "--geometries", "cube-3m", "--seed", "2"]
# One interpreter per rank runs both studies, then resumes the selection study after dropping one
# of its two chunk files (process 0 reads the other and sends it to process 1).
DRIVER = f"""
import json, shutil, sys
from pathlib import Path
from jaxpose.cli import main
out, extra = Path(sys.argv[1]), sys.argv[2:]
common = ["--no-figures", "--no-progress", *extra]
assert main(["select-study", *{SELECT!r}, "--out", str(out / "select"), *common]) == 0
assert main(["pose-study", *{POSE!r}, "--out", str(out / "pose"), *common]) == 0
import jax
if jax.process_index() == 0:
    shutil.copy(out / "select" / "results.json", out / "select_first.json")
    (out / "select" / "chunks" / "n8_m5_c000004_000006.npz").unlink()
assert main(["select-study", *{SELECT!r}, "--out", str(out / "select"), *common]) == 0
print("devices", len(jax.devices()), "processes", jax.process_count())
"""


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _without_timings(value):
    if isinstance(value, dict):
        return {k: _without_timings(v) for k, v in value.items() if k != "time_s"}
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


def _results(path: Path) -> dict:
    return _without_timings(json.loads(path.read_text()))


def _start(out: Path, devices: int, extra: list[str], env_extra: dict, log: Path):
    env = dict(
        os.environ,
        JAX_PLATFORMS="cpu",
        XLA_FLAGS=os.environ.get("XLA_FLAGS", "")
        + f" --xla_force_host_platform_device_count={devices}",
        PYTHONPATH=os.pathsep.join([str(REPO / "src"), os.environ.get("PYTHONPATH", "")]),
        **env_extra,
    )
    env.pop("JAXPOSE_DISTRIBUTED", None)
    handle = log.open("w")
    return subprocess.Popen(
        [sys.executable, "-c", DRIVER, str(out), *extra],
        env=env,
        stdout=handle,
        stderr=subprocess.STDOUT,
        cwd=out.parent,
    ), handle


@pytest.mark.slow
def test_two_processes_give_the_results_of_one(tmp_path):
    port = _free_port()
    address = f"127.0.0.1:{port}"
    # The coordinator listens on the loopback interface only.
    bind = {"JAX_COORDINATOR_BIND_ADDRESS": address}
    runs = {"one": (tmp_path / "one", 2, [], {})}
    for rank in (0, 1):
        flags = ["--coordinator-address", address, "--num-processes", "2", "--process-id"]
        runs[f"rank{rank}"] = (tmp_path / "two", 1, [*flags, str(rank)], bind)
    (tmp_path / "one").mkdir()
    (tmp_path / "two").mkdir()
    procs = {}
    deadline = time.monotonic() + 300
    try:
        # The reference runs beside the pair: one process with two devices, so every device gets
        # the same block of cases (a block's size can change a solver's last bits).
        for name, (out, devices, extra, env) in runs.items():
            procs[name] = _start(out, devices, extra, env, tmp_path / f"{name}.log")
        for name, (proc, _) in procs.items():
            left = max(1.0, deadline - time.monotonic())
            rc = proc.wait(timeout=left)
            assert rc == 0, (
                f"{name} exited with {rc}:\n" + (tmp_path / f"{name}.log").read_text()[-3000:]
            )
    finally:
        for proc, handle in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=30)
            handle.close()
    assert "devices 2 processes 2" in (tmp_path / "rank1.log").read_text()
    assert "devices 2 processes 1" in (tmp_path / "one.log").read_text()
    one, two = tmp_path / "one", tmp_path / "two"
    reference = _results(one / "select" / "results.json")
    assert reference["groups"][0]["cases"] == 6
    assert _results(two / "select_first.json") == reference
    assert _results(two / "select" / "results.json") == reference  # resumed
    assert sorted(p.name for p in (two / "select" / "chunks").iterdir()) == [
        "n8_m5_c000000_000004.npz",
        "n8_m5_c000004_000006.npz",
    ]
    pose = _results(one / "pose" / "results.json")
    assert pose["groups"][0]["trials"] == 21
    assert _results(two / "pose" / "results.json") == pose


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--num-processes", "0"], "--num-processes"),
        (["--process-id", "-1"], "--process-id"),
        (["--coordinator-address", "localhost"], "--coordinator-address"),
        (["--coordinator-address", "127.0.0.1:99999"], "--coordinator-address"),
        (["--coordinator-address", "a b:12"], "--coordinator-address"),
    ],
)
@pytest.mark.parametrize("command", ["select-study", "pose-study"])
def test_bad_process_options_are_refused(command, argv, message, tmp_path, capsys):
    assert main([command, *argv, "--out", str(tmp_path), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--coordinator-address", "127.0.0.1:1", "--num-processes", "2", "--process-id", "2"],
         "[0, N)"),
        (["--num-processes", "2", "--process-id", "0"], "go together"),
    ],
)  # fmt: skip
def test_process_options_that_do_not_fit_together_are_refused(argv, message, tmp_path, capsys):
    args = ["--n", "8", "--m", "5", "--cases", "2", "--no-figures", "--no-progress"]
    assert main(["select-study", *args, *argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "results.json").exists()


def test_options_object_checks_its_values():
    with pytest.raises(ValueError, match="--num-processes"):
        dist.DistributedOptions(num_processes=0)
    with pytest.raises(ValueError, match=r"\[0, N\)"):
        dist.DistributedOptions(num_processes=3, process_id=3)
    with pytest.raises(ValueError, match="--coordinator-address"):
        dist.DistributedOptions(coordinator_address="host:0")
    assert dist.check_address("[::1]:8476") == "[::1]:8476"
    assert dist.check_address("node-01.cluster:1234") == "node-01.cluster:1234"
    assert not dist.DistributedOptions().explicit


def test_environment_flag(monkeypatch, tmp_path, capsys):
    # Without options or flag: a one-process run, nothing started.
    assert dist.initialize(dist.DistributedOptions(), environ={}) is False
    assert dist.initialize(environ={dist.ENV_FLAG: "0"}) is False
    with pytest.raises(ValueError, match=dist.ENV_FLAG):
        dist.initialize(environ={dist.ENV_FLAG: "maybe"})
    # The flag outside a cluster: JAX detects nothing, and the command says what to give.
    for name in list(os.environ):
        if name.startswith(("SLURM_", "OMPI_", "JAX_COORDINATOR", "KUBERNETES_")):
            monkeypatch.delenv(name)
    monkeypatch.setenv(dist.ENV_FLAG, "1")
    args = ["--n", "8", "--m", "5", "--cases", "2", "--no-figures", "--no-progress"]
    assert main(["select-study", *args, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--coordinator-address" in err, err
    assert not (tmp_path / "results.json").exists()


def test_one_process_helpers_are_the_identity():
    import numpy as np

    sharding, ndev = dist.case_sharding()
    assert dist.is_writer()
    assert dist.local_rows(10, sharding) == slice(0, 10)
    assert dist.broadcast_from_writer(lambda: {"a": np.arange(3)})["a"].tolist() == [0, 1, 2]
    x = np.arange(12.0).reshape(6, 2)
    out = dist.map_cases(lambda a, b: a * b, (x,), (2.0,))
    np.testing.assert_array_equal(out, 2 * x)
    assert ndev == len(__import__("jax").devices())
