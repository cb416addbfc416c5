"""``refine_pose``: refine a pose by minimising point (and line) reprojection errors."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.geometry import (
    DEFAULT_EULER_SEQUENCE,
    Pose,
)
from jaxpose.core.refine._implicit import _with_implicit_grad
from jaxpose.core.refine._model import (
    _cost_from_residuals,
    _residuals,
)
from jaxpose.core.refine._native import _native_solve
from jaxpose.core.refine._optimistix import _optimistix_solve
from jaxpose.core.refine._options import BACKENDS, MIN_FEATURES, _Config, _config
from jaxpose.core.refine._problem import _prepare
from jaxpose.core.refine._result import RefineResult
from jaxpose.core.status import Status, throw_for_status


@eqx.filter_jit
def _refine(pose0, prob, valid, lvalid, finite_input, cfg: _Config, backend: str):
    dtype = prob.points.dtype
    if backend == "native":
        pose, steps, converged, singular = _native_solve(
            jax.lax.stop_gradient(pose0), jax.lax.stop_gradient(prob), cfg
        )
        R, t = _with_implicit_grad(cfg, pose.R, pose.t, prob)
        pose = Pose(R, t)
    else:
        pose, steps, converged, singular = _optimistix_solve(pose0, prob, cfg)
    e_p, e_l = _residuals(pose, prob)
    use_p, use_l = prob.w_points > 0, prob.w_lines > 0
    count = jnp.sum(use_p) + jnp.sum(use_l)
    sq = jnp.sum(jnp.where(use_p, jnp.sum(e_p**2, -1), 0.0)) + jnp.sum(
        jnp.where(use_l, jnp.sum(e_l**2, -1), 0.0)
    )
    rms = jnp.sqrt(sq / jnp.maximum(count, 1).astype(dtype))
    cost = _cost_from_residuals(e_p, e_l, prob, cfg)
    depth_p = pose.apply(prob.points)[:, 2]
    depth_l = pose.apply(prob.segments.reshape(-1, 3))[:, 2].reshape(-1, 2)
    behind = jnp.any(use_p & (depth_p <= 0)) | jnp.any(use_l[:, None] & (depth_l <= 0))
    n_valid = jnp.sum(valid) + jnp.sum(lvalid)
    finite_out = jnp.all(jnp.isfinite(pose.R)) & jnp.all(jnp.isfinite(pose.t)) & jnp.isfinite(cost)
    status = jnp.select(
        [~finite_input, n_valid < MIN_FEATURES, behind, singular | ~finite_out, ~converged],
        [
            Status.NONFINITE_INPUT,
            Status.TOO_FEW_POINTS,
            Status.BEHIND_CAMERA,
            Status.SINGULAR,
            Status.NOT_CONVERGED,
        ],
        Status.OK,
    ).astype(jnp.int32)
    bad_input = (~finite_input) | (n_valid < MIN_FEATURES) | ~finite_out
    inf = jnp.asarray(jnp.inf, dtype)
    pose = jax.tree.map(lambda a, b: jnp.where(bad_input, a, b), pose0, pose)
    return RefineResult(
        pose=pose,
        status=status,
        rms_px=jnp.where(bad_input, inf, rms),
        num_steps=steps,
        cost=jnp.where(bad_input, inf, cost),
    )


def refine_pose(
    pose0: Pose,
    points_body: Float[Array, "n 3"],
    pixels: Float[Array, "n 2"],
    camera: PinholeCamera | Array,
    *,
    mask: Array | None = None,
    sigma: Float[Array, " n"] | float | None = None,
    segments_body: Float[Array, "k 2 3"] | None = None,
    lines_img: Float[Array, "k 3"] | None = None,
    line_mask: Array | None = None,
    line_sigma: Float[Array, " k"] | float | None = None,
    robust: str | None = None,
    robust_scale: float | None = None,
    method: str = "lm",
    backend: str = "native",
    max_steps: int = 50,
    rtol: float = 1e-10,
    atol: float = 1e-12,
    sequence: str = DEFAULT_EULER_SEQUENCE,
    throw: bool = False,
) -> RefineResult:
    """Refine a pose by minimising point (and line) reprojection errors.

    One problem; use ``jax.vmap`` for batches (sets of different sizes share one compiled
    function through ``mask``/``line_mask`` padding). Differentiable with respect to every array
    input by implicit differentiation at the optimum (native back-end; optimistix's
    ``ImplicitAdjoint`` for the other).

    Args:
        pose0: initial pose (``x_cam = R p + t``), e.g. from EPnP.
        points_body: ``(n, 3)`` model points, metres.
        pixels: ``(n, 2)`` observed pixels of those points.
        camera: :class:`~jaxpose.core.camera.PinholeCamera` or ``3x3`` ``K``.
        mask: ``(n,)`` bool, valid points of a padded set (invalid ones may hold NaN).
        sigma: pixel noise per axis, scalar or ``(n,)``; ``None`` is 1 pixel (weights 1/sigma^2).
        segments_body: ``(k, 2, 3)`` 3-D segment endpoints (body frame) for line features.
        lines_img: ``(k, 3)`` observed homogeneous lines
            (:func:`~jaxpose.core.residuals.line_from_segment` of the observed segment endpoints).
        line_mask: ``(k,)`` bool, valid lines.
        line_sigma: pixel noise of the line distances; defaults to a scalar ``sigma``, else 1.
        robust: ``None``, ``"huber"``, ``"cauchy"`` or ``"tukey"`` (IRLS, see
            :mod:`jaxpose.core.residuals`).
        robust_scale: kernel scale in units of ``sigma`` (default
            :data:`jaxpose.core.residuals.DEFAULT_ROBUST_SCALE`).
        method: ``"lm"``, ``"gauss-newton"`` or ``"newton-raphson"`` (module docstring).
        backend: ``"native"`` (batched closed-form normal equations) or ``"optimistix"``.
        max_steps: iteration budget.
        rtol, atol: convergence when an accepted step has ``|dt| <= atol + rtol |t|`` (metres)
            and ``|dw| <= atol + rtol`` (radians) (optimistix's own test for that back-end).
        sequence: Euler sequence of ``"newton-raphson"``.
        throw: raise for a non-``OK`` status (``ValueError`` eagerly, an Equinox runtime error
            under ``jit``). Leave ``False`` under ``vmap``.

    Returns:
        :class:`RefineResult`.

    Raises:
        ValueError: wrong shapes or options (at trace time); with ``throw=True``, a bad status.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}; got {backend!r}")
    cfg = _config(
        method, robust, robust_scale, max_steps, rtol, atol, sequence, segments_body is not None
    )
    pose0, prob, valid, lvalid, finite_input = _prepare(
        pose0,
        points_body,
        pixels,
        camera,
        mask,
        sigma,
        segments_body,
        lines_img,
        line_mask,
        line_sigma,
    )
    res = _refine(pose0, prob, valid, lvalid, finite_input, cfg, backend)
    if throw:
        res = throw_for_status(res, "refine_pose", "cost")
    return res
