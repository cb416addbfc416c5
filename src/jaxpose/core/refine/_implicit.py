"""Derivatives of the refined pose by the implicit function theorem at the optimum."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
from jaxtyping import Array

from jaxpose.core.geometry import (
    Pose,
    hat,
)
from jaxpose.core.refine._model import (
    _tangent_cost,
)
from jaxpose.core.refine._options import RefineOptions
from jaxpose.core.refine._problem import _Problem


def _implicit_parts(pose: Pose, prob: _Problem, cfg: RefineOptions):
    """Exact Hessian ``d^2 C / d xi^2`` at ``pose`` and the map ``prob -> grad_xi C``."""
    zero = jnp.zeros(6, pose.t.dtype)
    H = jax.hessian(_tangent_cost)(zero, pose, prob, cfg)

    def grad_of(p):
        return jax.grad(_tangent_cost)(zero, pose, p, cfg)

    return H, grad_of


def _hessian_singular(H: Array) -> Array:
    """True when the (possibly indefinite) Hessian is not safely invertible: the smallest
    eigenvalue magnitude of the Jacobi-scaled matrix below ``1e3 * eps`` times the largest (the
    threshold of :func:`jaxpose.core.dilution.dop_from_information`)."""
    diag = jnp.abs(jnp.diagonal(H))
    ok_diag = jnp.all(diag > 0) & jnp.all(jnp.isfinite(H))
    d = jnp.sqrt(jnp.where(diag > 0, diag, 1.0))
    S = H / (d[:, None] * d[None, :])
    S = jnp.where(ok_diag, S, jnp.eye(H.shape[0], dtype=H.dtype))
    ev = jnp.abs(jnp.linalg.eigvalsh(0.5 * (S + S.T)))
    tol = 1e3 * float(jnp.finfo(H.dtype).eps)
    return ~ok_diag | (jnp.min(ev) <= tol * jnp.max(ev))


def _solve_hessian(H, rhs):
    """``H^-1 rhs`` for a symmetric, possibly (robust kernels) indefinite ``H`` (LU), and zero
    where ``H`` is singular: the implicit derivative is then undefined, and a safe matrix in that
    branch keeps NaN out of values and gradients (the status says why)."""
    bad = _hessian_singular(H)
    H_safe = jnp.where(bad, jnp.eye(H.shape[0], dtype=H.dtype), H)
    return jnp.where(bad, 0.0, jnp.linalg.solve(H_safe, rhs))


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def _with_implicit_grad(cfg: RefineOptions, R, t, prob: _Problem):
    """Identity on ``(R, t)``; its JVP is the implicit function theorem at the optimum."""
    return R, t


@_with_implicit_grad.defjvp
def _with_implicit_grad_jvp(cfg, primals, tangents):
    R, t, prob = primals
    _, _, dprob = tangents
    pose = Pose(R, t)
    H, grad_of = _implicit_parts(pose, prob, cfg)
    _, dg = jax.jvp(grad_of, (prob,), (dprob,))
    dxi = -_solve_hessian(H, dg)
    return (R, t), (hat(dxi[3:]) @ R, dxi[:3])
