"""Test configuration: float64 and strict dtype promotion (house style), shared fixtures."""

import os
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SPEEDPLUS = Path(os.environ.get("JAXPOSE_SPEEDPLUS", REPO.parent / "shared" / "data" / "speedplus"))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def speedplus_dir():
    if not (SPEEDPLUS / "labels.csv").is_file():
        pytest.skip(f"SPEED+ sample not found at {SPEEDPLUS}")
    return SPEEDPLUS
