"""Status codes shared by every batched routine of jaxpose.

Batched code never raises for one bad problem: it returns an ``int32`` status per problem (and
``inf`` in the figures that cannot be computed) so that a Monte Carlo batch survives a bad lane.
Eager entry points turn a non-zero status into a :class:`ValueError` whose text is
:data:`MESSAGES` of the code (see :func:`raise_for_status`).
"""

from __future__ import annotations

import enum

import equinox as eqx
import jax
import numpy as np

__all__ = ["MESSAGES", "Status", "raise_for_status", "status_message", "throw_for_status"]


class Status(enum.IntEnum):
    """Why a problem could not be solved (0 means it was)."""

    OK = 0
    TOO_FEW_POINTS = 1
    BEHIND_CAMERA = 2
    SINGULAR = 3
    NONFINITE_INPUT = 4
    NOT_CONVERGED = 5
    DEGENERATE = 6
    NO_SOLUTION = 7
    LOST = 8


MESSAGES: dict[int, str] = {
    Status.OK: "ok",
    Status.TOO_FEW_POINTS: "too few valid points (at least 4 are needed)",
    Status.BEHIND_CAMERA: "a point is at or behind the camera (z <= 0 in the camera frame)",
    Status.SINGULAR: "singular geometry: the information matrix H^T H is not invertible "
    "(collinear or coincident points, or too few distinct directions)",
    Status.NONFINITE_INPUT: "the input holds NaN or inf",
    Status.NOT_CONVERGED: "the solver did not converge within its iteration budget",
    Status.DEGENERATE: "degenerate configuration for this solver",
    Status.NO_SOLUTION: "no solution was found",
    Status.LOST: "tracking lost: too few features survived",
}


def status_message(code: int) -> str:
    """Human-readable text of a status code."""
    return MESSAGES.get(int(code), f"unknown status {int(code)}")


def raise_for_status(status, what: str = "problem") -> None:
    """Raise ``ValueError`` naming every distinct failure in ``status`` (array or scalar)."""
    status = np.asarray(status)
    bad = status != Status.OK
    if not bad.any():
        return
    parts = []
    for code in np.unique(status[bad]):
        idx = np.argwhere(status == code)
        where = (
            "" if status.ndim == 0 else f" (at {len(idx)} of {status.size}, first {tuple(idx[0])})"
        )
        parts.append(f"{status_message(code)}{where}")
    raise ValueError(f"{what}: " + "; ".join(parts))


def throw_for_status(result, what: str, field: str):
    """The ``throw=True`` path of every solver: fail loudly on a bad ``result.status``.

    Eager (concrete status): :func:`raise_for_status` raises ``ValueError``. Under ``jit`` or
    ``vmap`` the error is attached to ``result.<field>`` with ``equinox.branched_error_if``, so
    it is raised at run time with the message of the status that occurred.
    """
    status = result.status
    if not isinstance(status, jax.core.Tracer):
        raise_for_status(status, what)
        return result
    messages = [f"{what}: {status_message(code)}" for code in range(len(Status))]
    leaf = eqx.branched_error_if(getattr(result, field), status != Status.OK, status, messages)
    return eqx.tree_at(lambda r: getattr(r, field), result, leaf)
