"""Derivatives of the refined pose by the implicit function theorem at the optimum."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from jaxpose.core.geometry import (
    Pose,
    hat,
)
from jaxpose.core.refine._model import (
    _tangent_cost,
)
from jaxpose.core.refine._options import _Config
from jaxpose.core.refine._problem import _Problem


def _implicit_parts(pose: Pose, prob: _Problem, cfg: _Config):
    """Exact Hessian ``d^2 C / d xi^2`` at ``pose`` and the map ``prob -> grad_xi C``."""
    zero = jnp.zeros(6, pose.t.dtype)
    H = jax.hessian(_tangent_cost)(zero, pose, prob, cfg)

    def grad_of(p):
        return jax.grad(_tangent_cost)(zero, pose, p, cfg)

    return H, grad_of


def _solve_hessian(H, rhs):
    # Symmetric, possibly (robust kernels) indefinite: a plain LU solve.
    return jnp.linalg.solve(H, rhs)


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def _with_implicit_grad(cfg: _Config, R, t, prob: _Problem):
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
