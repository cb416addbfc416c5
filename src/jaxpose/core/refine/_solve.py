"""``refine_pose``: refine a pose by minimising point (and line) reprojection errors."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import ArrayLike, Bool, Float

from jaxpose.core._checks import check_positive, is_rotation
from jaxpose.core.camera import PinholeCamera
from jaxpose.core.geometry import (
    Pose,
)
from jaxpose.core.refine._implicit import _with_implicit_grad
from jaxpose.core.refine._model import (
    _cost_from_residuals,
    _residuals,
)
from jaxpose.core.refine._native import _native_solve
from jaxpose.core.refine._optimistix import _optimistix_solve
from jaxpose.core.refine._options import MIN_FEATURES, RefineOptions
from jaxpose.core.refine._problem import _prepare
from jaxpose.core.refine._result import RefineResult
from jaxpose.core.status import Status, check_throw, throw_for_status


@eqx.filter_jit
def _refine(pose0, prob, valid, lvalid, finite_input, lines_ok, cfg: RefineOptions):
    dtype = prob.points.dtype
    if cfg.backend == "native":
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
    rotation = is_rotation(pose0.R)
    status = jnp.select(
        [
            ~finite_input,
            ~lines_ok,
            ~rotation,
            n_valid < MIN_FEATURES,
            behind,
            singular | ~finite_out,
            ~converged,
        ],
        [
            Status.NONFINITE_INPUT,
            Status.DEGENERATE_LINE,
            Status.NOT_A_ROTATION,
            Status.TOO_FEW_POINTS,
            Status.BEHIND_CAMERA,
            Status.SINGULAR,
            Status.NOT_CONVERGED,
        ],
        Status.OK,
    ).astype(jnp.int32)
    bad_input = (~finite_input) | ~lines_ok | ~rotation | (n_valid < MIN_FEATURES) | ~finite_out
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
    points_body: Float[ArrayLike, "n 3"],
    pixels: Float[ArrayLike, "n 2"],
    pose0: Pose,
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    mask: Bool[ArrayLike, " n"] | None = None,
    sigma: Float[ArrayLike, " n"] | Float[ArrayLike, ""] | float | None = None,
    segments_body: Float[ArrayLike, "k 2 3"] | None = None,
    lines_img: Float[ArrayLike, "k 3"] | None = None,
    line_mask: Bool[ArrayLike, " k"] | None = None,
    line_sigma: Float[ArrayLike, " k"] | Float[ArrayLike, ""] | float | None = None,
    options: RefineOptions = RefineOptions(),
    throw: bool = True,
) -> RefineResult:
    """Refine a pose by minimising point (and line) reprojection errors.

    The joint robust cost of Yang et al. 2024 eq. 10 over the pose; the methods and the tangent
    coordinates are described in :mod:`jaxpose.core.refine`. One problem; use ``jax.vmap`` for
    batches (sets of different sizes share one compiled function through ``mask``/``line_mask``
    padding), with ``throw=False`` so that one bad lane does not stop the batch. Differentiable
    with respect to every array input by implicit differentiation at the optimum (native
    back-end; optimistix's ``ImplicitAdjoint`` for the other).

    Args:
        points_body: ``(n, 3)`` model points, metres.
        pixels: ``(n, 2)`` observed pixels of those points.
        pose0: initial pose (``x_cam = R p + t``), e.g. from EPnP.
        camera: :class:`~jaxpose.core.camera.PinholeCamera` or ``3x3`` ``K``.
        mask: ``(n,)`` bool, valid points of a padded set (invalid ones may hold NaN).
        sigma: pixel noise per axis, scalar or ``(n,)``; ``None`` is 1 pixel (weights 1/sigma^2).
        segments_body: ``(k, 2, 3)`` 3-D segment endpoints (body frame) for line features.
        lines_img: ``(k, 3)`` observed homogeneous lines
            (:func:`~jaxpose.core.residuals.line_from_segment` of the observed segment endpoints).
        line_mask: ``(k,)`` bool, valid lines (only with lines: ``ValueError`` without them).
        line_sigma: pixel noise of the line distances; defaults to a scalar ``sigma``, else 1
            (only with lines, like ``line_mask``). A valid line with ``l1 = l2 = 0`` has no
            direction: status ``DEGENERATE_LINE``.
        options: :class:`RefineOptions` (method, robust kernel, budget, tolerances, back-end).
        throw: raise for a non-``OK`` status (``ValueError`` eagerly, an Equinox runtime error
            under ``jit``); pass ``False`` under ``vmap`` and read ``status``.

    Returns:
        :class:`RefineResult`.

    Raises:
        ValueError: wrong shapes or options (at trace time); with ``throw=True``, a bad status.
    """
    if not isinstance(options, RefineOptions):
        raise ValueError(f"options must be a RefineOptions; got {type(options).__name__}")
    check_positive(sigma, "sigma (pixel noise)")
    check_positive(line_sigma, "line_sigma (pixel noise of the lines)")
    pose0, prob, valid, lvalid, finite_input, lines_ok = _prepare(
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
    res = _refine(pose0, prob, valid, lvalid, finite_input, lines_ok, options)
    if check_throw(throw):
        res = throw_for_status(res, "refine_pose", "cost", min_points=MIN_FEATURES)
    return res
