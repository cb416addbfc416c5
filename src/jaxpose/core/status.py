"""Status codes shared by every batched routine of jaxpose.

Batched code never raises for one bad problem: it returns an ``int32`` status per problem (and
``inf`` in the figures that cannot be computed) so that a Monte Carlo batch survives a bad lane.
Eager entry points (``throw=True``, their default) turn a non-zero status into a
:class:`ValueError` whose text is the member's message, made exact for the function that raised
it (:meth:`Status.describe`: e.g. the minimum point count, 3 for ``refine_pose``, 4 for EPnP and
DOP, 6 for the DLT, ``m`` for a selection).
"""

from __future__ import annotations

import enum

import equinox as eqx
import jax
import numpy as np
from jaxtyping import ArrayLike, Int

__all__ = ["MESSAGES", "Status", "raise_for_status", "status_message", "throw_for_status"]


class Status(enum.IntEnum):
    """Why a problem could not be solved (0 means it was). Each member carries its message."""

    def __new__(cls, value: int, template: str):
        member = int.__new__(cls, value)
        member._value_ = value
        member.template = template
        return member

    OK = 0, "ok"
    TOO_FEW_POINTS = 1, "too few valid points (at least {min_points} are needed)"
    BEHIND_CAMERA = 2, "a point is at or behind the camera (z <= 0 in the camera frame)"
    SINGULAR = (
        3,
        "singular geometry: the information matrix H^T H is not invertible "
        "(collinear or coincident points, or too few distinct directions)",
    )
    NONFINITE_INPUT = 4, "the input holds NaN or inf"
    NOT_CONVERGED = 5, "the solver did not converge within its iteration budget"
    DEGENERATE = 6, "degenerate configuration for this solver (collinear or coincident points)"
    NO_SOLUTION = 7, "no solution was found"
    LOST = 8, "tracking lost: too few features survived"
    NOT_A_ROTATION = 9, "the pose's R is not a rotation matrix (R^T R != I or det R <= 0)"
    GIMBAL_LOCK = (
        10,
        "the Euler sequence of the attitude state is at gimbal lock: the attitude DOP in Euler "
        "angles is infinite (the PDOP is not; use parameterization='tangent' or another sequence)",
    )
    DEGENERATE_LINE = (
        11,
        "an image line in lines_img has no direction (l1 = l2 = 0: not a line); mask it out "
        "with line_mask",
    )

    @property
    def message(self) -> str:
        """The message without a function's context (``"too few valid points"``)."""
        return self.describe()

    def describe(self, min_points: int | None = None) -> str:
        """The message, exact for a function whose minimum point count is ``min_points``."""
        if "{min_points}" not in self.template:
            return self.template
        if min_points is None:
            return self.template.split(" (")[0]
        return self.template.format(min_points=int(min_points))


MESSAGES: dict[int, str] = {int(s): s.message for s in Status}
"""Context-free message of every code (see :meth:`Status.describe` for the exact one)."""


def status_message(code: int | Int[ArrayLike, ""], min_points: int | None = None) -> str:
    """Human-readable text of a status code (exact when ``min_points`` is given)."""
    try:
        return Status(int(code)).describe(min_points)
    except ValueError:
        return f"unknown status {int(code)}"


def raise_for_status(status, what: str = "problem", *, min_points: int | None = None) -> None:
    """Raise ``ValueError`` naming every distinct failure in ``status`` (array or scalar)."""
    status = np.asarray(status)
    bad = status != Status.OK
    if not bad.any():
        return
    parts = []
    for code in np.unique(status[bad]):
        idx = np.argwhere(status == code)
        where = (
            ""
            if status.ndim == 0
            else f" (at {len(idx)} of {status.size}, first {tuple(int(i) for i in idx[0])})"
        )
        parts.append(f"{status_message(code, min_points)}{where}")
    raise ValueError(f"{what}: " + "; ".join(parts))


def check_throw(throw) -> bool:
    """``throw`` as a bool, or a ``ValueError`` naming it: ``None`` had been taken as ``False``
    and the string ``"no"`` as ``True``."""
    if not isinstance(throw, bool | np.bool_):
        raise ValueError(f"throw must be True or False; got {throw!r}")
    return bool(throw)


def throw_for_status(result, what: str, field: str, *, min_points: int | None = None):
    """The ``throw=True`` path of every solver: fail loudly on a bad ``result.status``.

    Eager (concrete status): :func:`raise_for_status` raises ``ValueError``. Under ``jit`` or
    ``vmap`` the error is attached to ``result.<field>`` with ``equinox.branched_error_if``, so
    it is raised at run time with the message of the status that occurred.
    """
    status = result.status
    if not isinstance(status, jax.core.Tracer):
        raise_for_status(status, what, min_points=min_points)
        return result
    messages = [f"{what}: {status_message(code, min_points)}" for code in range(len(Status))]
    leaf = eqx.branched_error_if(getattr(result, field), status != Status.OK, status, messages)
    return eqx.tree_at(lambda r: getattr(r, field), result, leaf)
