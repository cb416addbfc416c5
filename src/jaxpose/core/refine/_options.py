"""Options of :func:`refine_pose`: methods, back-ends and their validation."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from jaxpose.core import residuals as _res
from jaxpose.core.geometry import (
    euler_to_dcm,
)

METHODS = ("lm", "gauss-newton", "newton-raphson")
BACKENDS = ("native", "optimistix")
MIN_FEATURES = 3
"""At least three valid features (points + lines, two equations each) for six pose unknowns
(Sharma et al. 2018: "at least three matches ... are required")."""


@dataclasses.dataclass(frozen=True)
class _Config:
    method: str
    robust: str | None
    robust_scale: float | None
    max_steps: int
    rtol: float
    atol: float
    sequence: str
    has_lines: bool


def _config(method, robust, robust_scale, max_steps, rtol, atol, sequence, has_lines) -> _Config:
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}; got {method!r}")
    if robust not in _res.ROBUST_KINDS:
        raise ValueError(f"robust must be one of {_res.ROBUST_KINDS}; got {robust!r}")
    if robust_scale is not None and not robust_scale > 0:
        raise ValueError(f"robust_scale must be positive; got {robust_scale}")
    if int(max_steps) < 1:
        raise ValueError(f"max_steps must be at least 1; got {max_steps}")
    euler_to_dcm(jnp.zeros(3), sequence)  # validates the sequence
    return _Config(
        method,
        robust,
        None if robust_scale is None else float(robust_scale),
        int(max_steps),
        float(rtol),
        float(atol),
        sequence,
        bool(has_lines),
    )
