"""The native back-end: Levenberg-Marquardt / Gauss-Newton as a ``lax.while_loop`` over
closed-form ``6 x 6`` normal equations."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from jaxpose.core.geometry import (
    Pose,
)
from jaxpose.core.refine._model import (
    _linearize,
    _retract,
)
from jaxpose.core.refine._options import RefineOptions
from jaxpose.core.refine._problem import _Problem


def _scaled_cholesky_solve(A: Array, b: Array, damping=None):
    """Solve ``(A + damping * diag(A)) x = b`` for a ``6 x 6`` SPD ``A``; also a singular flag.

    Jacobi scaling ``S = D^-1/2 A D^-1/2`` (metres and radians differ in scale), then Cholesky
    written element by element: under ``vmap`` this is vector arithmetic over the batch, with no
    per-matrix LAPACK call. ``singular`` is set when a pivot of the factored matrix falls below
    ``1e3 * eps`` (the threshold of :func:`jaxpose.core.dilution.dop_from_information`).
    """
    n = A.shape[-1]
    dtype = A.dtype
    eps = float(jnp.finfo(dtype).eps)
    tol = 1e3 * eps
    diag = jnp.diagonal(A)
    d = jnp.sqrt(jnp.maximum(diag, jnp.maximum(jnp.max(diag), 1.0) * eps * eps))
    S = A / (d[:, None] * d[None, :])
    if damping is not None:
        S = S + damping * jnp.eye(n, dtype=dtype)
    bs = b / d
    zero = jnp.zeros((), dtype)
    L = [[None] * n for _ in range(n)]
    ok = jnp.asarray(True)
    for j in range(n):
        piv2 = S[j, j] - sum((L[j][k] ** 2 for k in range(j)), zero)
        ok = ok & (piv2 > tol)
        L[j][j] = jnp.sqrt(jnp.maximum(piv2, tol))
        for i in range(j + 1, n):
            L[i][j] = (S[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), zero)) / L[j][j]
    y = [None] * n
    for i in range(n):
        y[i] = (bs[i] - sum((L[i][k] * y[k] for k in range(i)), zero)) / L[i][i]
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - sum((L[k][i] * x[k] for k in range(i + 1, n)), zero)) / L[i][i]
    return jnp.stack(x) / d, ~ok


# ----------------------------------------------------------------------------- native solver


_NEGLIGIBLE_DECREASE = 1e-12
"""Predicted decrease ``1/2 d^T A d`` of the whitened cost below which a step is negligible: a
step of ``1e-6`` standard deviations of the pose (``sigma`` as given), far below any statistical
meaning; it saves the last verifying iteration of most problems."""

_LAMBDA0 = 1e-3
"""Initial LM damping (relative to the Jacobi-scaled normal matrix, whose diagonal is 1)."""


def _singular(A: Array) -> Array:
    """Singularity test of :func:`jaxpose.core.dilution.dop_from_information` (Jacobi-scaled
    pivots)."""
    eps = float(jnp.finfo(A.dtype).eps)
    d = jnp.sqrt(jnp.maximum(jnp.diagonal(A), jnp.finfo(A.dtype).tiny))
    L = jnp.linalg.cholesky(A / (d[:, None] * d[None, :]))
    piv = jnp.diagonal(L) ** 2
    return ~jnp.all(jnp.isfinite(L)) | (jnp.min(piv) <= 1e3 * eps * jnp.max(piv))


class _State(eqx.Module):
    pose: Pose
    A: Array
    g: Array
    cost: Array
    lam: Array
    delta: Array  # the next step, solved from (A, g, lam)
    step: Array
    done: Array
    bad: Array
    final: Array  # converged on a negligible next step, which is then taken unverified


def _native_solve(pose0: Pose, prob: _Problem, cfg: RefineOptions):
    """One linearisation per iteration: the candidate's normal equations are kept if accepted,
    and the next step is solved from them at once, so that convergence is seen one
    linearisation earlier (a negligible next step is taken without evaluating the cost there:
    with quadratic convergence it moves the pose by less than the tolerance)."""
    dtype = prob.points.dtype
    lm = cfg.method == "lm"
    eps = float(jnp.finfo(dtype).eps)

    def cond(st: _State):
        return (~st.done) & (st.step <= cfg.max_steps)

    def body(st: _State):
        first = st.step == 0
        cand = _retract(st.pose, st.delta, cfg)
        A, g, cost = _linearize(cand, prob, cfg)
        ok = jnp.isfinite(cost) & jnp.all(jnp.isfinite(A)) & jnp.all(jnp.isfinite(g))
        accept = ok & (cost <= st.cost) if lm else ok
        keep = lambda new, old: jnp.where(accept, new, old)  # noqa: E731
        pose = jax.tree.map(keep, cand, st.pose)
        A, g, cost = keep(A, st.A), keep(g, st.g), keep(cost, st.cost)
        lam = jnp.where(
            first, st.lam, jnp.where(accept, jnp.maximum(st.lam * 0.1, 1e-12), st.lam * 10.0)
        )
        delta, singular = _scaled_cholesky_solve(A, -g, lam if lm else None)
        finite = jnp.all(jnp.isfinite(delta))
        delta = jnp.where(finite, delta, 0.0)
        dt, dw = delta[:3], delta[3:]
        small = (jnp.linalg.norm(dt) <= cfg.atol + cfg.rtol * jnp.linalg.norm(pose.t)) & (
            jnp.linalg.norm(dw) <= cfg.atol + cfg.rtol
        )
        # Converged: after an accepted linearisation, the lightly damped next step is small, or
        # the model predicts a decrease at the round-off level of the cost (smaller steps
        # cannot be resolved) or below _NEGLIGIBLE_DECREASE. (A heavily damped step is small
        # for another reason.)
        pred = -jnp.dot(g, delta) - 0.5 * jnp.dot(delta, A @ delta)
        flat = pred <= 1e3 * eps * cost + _NEGLIGIBLE_DECREASE
        light = (lam <= 1.0) if lm else jnp.asarray(True)
        converged = (small | flat) & light & accept
        bad = ~finite | (jnp.asarray(False) if lm else singular) | ~ok
        return _State(
            pose=pose,
            A=A,
            g=g,
            cost=cost,
            lam=lam,
            delta=delta,
            step=st.step + 1,
            done=converged | bad | (cost <= jnp.finfo(dtype).tiny) | (lam > 1e12),
            bad=bad & ~accept,
            final=converged & ~bad,
        )

    # The first iteration takes a zero step from pose0 and linearises there (one copy of the
    # linearisation in the compiled loop): A = 0, g = 0 and cost = inf make it accept.
    inf = jnp.asarray(jnp.inf, dtype)
    st0 = _State(
        pose0,
        jnp.zeros((6, 6), dtype),
        jnp.zeros(6, dtype),
        inf,
        jnp.asarray(_LAMBDA0, dtype),
        jnp.zeros(6, dtype),
        jnp.asarray(0, jnp.int32),
        jnp.asarray(False),
        jnp.asarray(False),
        jnp.asarray(False),
    )
    st = jax.lax.while_loop(cond, body, st0)
    pose = jax.tree.map(
        lambda a, b: jnp.where(st.final, a, b), _retract(st.pose, st.delta, cfg), st.pose
    )
    converged = st.done & ~st.bad
    steps = jnp.maximum(st.step - 1, 0) + st.final.astype(jnp.int32)
    return pose, steps, converged, _singular(st.A) | st.bad
