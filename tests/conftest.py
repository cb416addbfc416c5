"""Test configuration: float64 and strict dtype promotion (house style), shared fixtures."""

import os
from pathlib import Path

# The suite is bound by XLA's compilation, not by the compiled code: its tests compile with the
# backend's optimisation off (compile-heavy PnP tests: 145 -> 84 s of CPU; the results they check
# are the same functions at other optimisation; LLVM's expensive passes off: a cold run of
# test_solve_pnp.py 133 -> 108 s, of test_refine.py with test_bad_inputs_core.py 152 -> 137 s on
# the 2-core Xeon, 2026-12-01). Speed is measured by the benches in bench/, which
# use the package's defaults. Set JAXPOSE_TEST_XLA_OPT=1 to test at XLA's default optimisation.
# Subprocesses that the tests start (CLI, notebooks, README) inherit the flags.
# XLA aborts the process on a flag it does not know, and flag names change between releases
# (jaxlib 0.11 refuses --xla_cpu_use_fusion_emitters), so the flags are tried in a child process
# first, once per run (the xdist workers inherit the result), and an unknown one is left out.


def _xla_takes(flags: list[str]) -> bool:
    import subprocess
    import sys

    env = dict(os.environ, XLA_FLAGS=" ".join(flags), JAX_PLATFORMS="cpu")
    probe = [sys.executable, "-c", "import jax; jax.numpy.zeros(1).block_until_ready()"]
    return subprocess.run(probe, env=env, capture_output=True, timeout=300).returncode == 0


if os.environ.get("JAXPOSE_TEST_XLA_OPT") != "1" and "JAXPOSE_TEST_XLA_FLAGS" not in os.environ:
    _given = os.environ.get("XLA_FLAGS", "").split()
    _flags = [
        f
        for f in (
            "--xla_backend_optimization_level=0",
            "--xla_cpu_use_fusion_emitters=false",
            "--xla_llvm_disable_expensive_passes=true",
        )
        if not any(g.split("=")[0] == f.split("=")[0] for g in _given)
    ]
    if not _xla_takes(_given + _flags):
        _flags = [f for f in _flags if _xla_takes(_given + [f])]
    os.environ["XLA_FLAGS"] = " ".join(_given + _flags)
    os.environ["JAXPOSE_TEST_XLA_FLAGS"] = " ".join(_flags)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")

# One persistent XLA cache for the whole run, shared by the xdist workers and by the CLI commands
# that the tests call (they honour JAXPOSE_CACHE_DIR): each heavy solver compiles once per run.
_CACHE = Path(__file__).resolve().parents[1] / ".pytest_cache" / "jax-compilation"
os.environ.setdefault("JAXPOSE_CACHE_DIR", str(_CACHE))
jax.config.update("jax_compilation_cache_dir", os.environ["JAXPOSE_CACHE_DIR"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
# The processes the tests start that do not go through the CLI (notebook kernels, bench scripts)
# read JAX's own variables: they share the run's cache too.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.environ["JAXPOSE_CACHE_DIR"])
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SPEEDPLUS = Path(os.environ.get("JAXPOSE_SPEEDPLUS", REPO.parent / "shared" / "data" / "speedplus"))


@pytest.fixture(autouse=True)
def _typecheck_off(request):
    """Tests marked ``typecheck_off`` run without jaxtyping's checks (see pyproject.toml)."""
    if request.node.get_closest_marker("typecheck_off") is None:
        yield
        return
    import jaxtyping

    before = jaxtyping.config.jaxtyping_disable
    jaxtyping.config.update("jaxtyping_disable", True)
    try:
        yield
    finally:
        jaxtyping.config.update("jaxtyping_disable", before)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def speedplus_dir():
    if not (SPEEDPLUS / "labels.csv").is_file():
        pytest.skip(f"SPEED+ sample not found at {SPEEDPLUS}")
    return SPEEDPLUS


def pytest_collection_modifyitems(config, items):
    """The longer tests (marked ``slow``: notebooks, benches, subprocesses) run first, so that
    the two xdist workers end on short tests together instead of one finishing a notebook while
    the other waits. The sort is stable: the order within each group is the collection's."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
