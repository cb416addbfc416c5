"""Options of :func:`~jaxpose.core.refine.refine_pose`: one frozen, validated object."""

from __future__ import annotations

import dataclasses
import math

from jaxpose.core import residuals as _res
from jaxpose.core._checks import _is_real
from jaxpose.core.geometry import DEFAULT_EULER_SEQUENCE, parse_euler_sequence

METHODS = ("lm", "gauss-newton", "newton-raphson")
BACKENDS = ("native", "optimistix")
MIN_FEATURES = 3
"""At least three valid features (points + lines, two equations each) for six pose unknowns
(Sharma et al. 2018: "at least three matches ... are required")."""


@dataclasses.dataclass(frozen=True)
class RefineOptions:
    """How :func:`~jaxpose.core.refine.refine_pose` solves (hashable: static under ``jit``).

    Attributes:
        method: ``"lm"`` (Levenberg-Marquardt on the tangent, the default), ``"gauss-newton"``
            (undamped, tangent) or ``"newton-raphson"`` (Sharma et al. 2018 eqs. 23-29: undamped
            steps on ``[t, Euler angles]``).
        robust: ``None``, ``"huber"``, ``"cauchy"`` or ``"tukey"`` (IRLS weights, see
            :mod:`jaxpose.core.residuals`).
        robust_scale: kernel scale ``c`` in units of ``sigma`` (``None``: the kernel's default,
            :data:`jaxpose.core.residuals.DEFAULT_ROBUST_SCALE`).
        max_steps: iteration budget (at least 1).
        rtol, atol: convergence when an accepted step has ``|dt| <= atol + rtol |t|`` (metres) and
            ``|dw| <= atol + rtol`` (radians); optimistix's own test for that back-end.
        sequence: Euler sequence of ``"newton-raphson"`` (SciPy's naming, see
            :mod:`jaxpose.core.geometry`).
        backend: ``"native"`` (closed-form ``6 x 6`` normal equations in a ``while_loop``, fast
            under ``vmap``) or ``"optimistix"``.

    Raises:
        ValueError: an unknown method, kernel, back-end or sequence; a non-positive scale,
            budget or tolerance; a number field given as a string or a bool.
    """

    method: str = "lm"
    robust: str | None = None
    robust_scale: float | None = None
    max_steps: int = 50
    rtol: float = 1e-10
    atol: float = 1e-12
    sequence: str = DEFAULT_EULER_SEQUENCE
    backend: str = "native"

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"RefineOptions.method must be one of {METHODS}; got {self.method!r}")
        if self.robust not in _res.ROBUST_KINDS:
            raise ValueError(
                f"RefineOptions.robust must be one of {_res.ROBUST_KINDS}; got {self.robust!r}"
            )
        if self.backend not in BACKENDS:
            raise ValueError(
                f"RefineOptions.backend must be one of {BACKENDS}; got {self.backend!r}"
            )
        # a string ("1e-3") was parsed by float() and a bool taken as 1 or 0: refused by name
        for name in ("robust_scale", "max_steps", "rtol", "atol"):
            value = getattr(self, name)
            if not (_is_real(value) or (name == "robust_scale" and value is None)):
                what = "an integer" if name == "max_steps" else "a number"
                if name == "robust_scale":
                    what += " or None"
                raise ValueError(f"RefineOptions.{name} must be {what}; got {value!r}")
        if self.robust_scale is not None:
            if not float(self.robust_scale) > 0:
                raise ValueError(
                    f"RefineOptions.robust_scale must be positive; got {self.robust_scale}"
                )
            object.__setattr__(self, "robust_scale", float(self.robust_scale))
        if not math.isfinite(self.max_steps) or int(self.max_steps) != self.max_steps:
            raise ValueError(f"RefineOptions.max_steps must be an integer; got {self.max_steps!r}")
        if int(self.max_steps) < 1:
            raise ValueError(f"RefineOptions.max_steps must be at least 1; got {self.max_steps}")
        object.__setattr__(self, "max_steps", int(self.max_steps))
        for name in ("rtol", "atol"):
            value = float(getattr(self, name))
            if not value >= 0:
                raise ValueError(f"RefineOptions.{name} must be >= 0; got {getattr(self, name)}")
            object.__setattr__(self, name, value)
        parse_euler_sequence(self.sequence)  # raises ValueError for a bad sequence
