"""The direct linear transform (DLT) for one PnP problem (pure JAX).

The ``3 x 4`` projection matrix from ``>= 6`` non-coplanar points (Hartley normalisation of the
3-D points, SVD), then the closest rotation.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import ArrayLike, Bool, Float

from jaxpose.core._compile import eager_jit
from jaxpose.core.camera import PinholeCamera, as_camera
from jaxpose.core.pnp._linalg import _rms_px
from jaxpose.core.pnp._problem import (
    DLT_MIN_POINTS,
    PLANAR_TOL,
    _conclude,
    _control_frame,
    _EPnPOut,
    _problem,
    _solution_status,
    check_planar_tol,
)
from jaxpose.core.pnp._result import PnPResult
from jaxpose.core.status import check_throw, throw_for_status


def _dlt_core(points_body, xy, weights, fxy, planar_tol) -> _EPnPOut:
    c0, axes, scale, planar, degenerate = _control_frame(points_body, weights, planar_tol)
    s = 1.0 / jnp.sqrt(jnp.sum(scale**2))  # about unit RMS distance from the centroid
    Xh = jnp.concatenate([(points_body - c0) * s, jnp.ones_like(points_body[:, :1])], axis=1)
    zero = jnp.zeros_like(Xh)
    x, y = xy[:, :1], xy[:, 1:]
    rows = (
        jnp.concatenate(
            [
                jnp.concatenate([Xh, zero, -x * Xh], axis=1),
                jnp.concatenate([zero, Xh, -y * Xh], axis=1),
            ],
            axis=0,
        )
        * jnp.concatenate([weights, weights])[:, None]
    )
    _, _, vt = jnp.linalg.svd(rows, full_matrices=False)
    P = vt[-1].reshape(3, 4)
    A = P[:, :3] * s
    b = P[:, 3] - A @ c0
    sgn = jnp.where(jnp.linalg.det(A) < 0, -1.0, 1.0)
    A, b = A * sgn, b * sgn
    U, sv, Vt = jnp.linalg.svd(A)
    D = jnp.stack([1.0, 1.0, jnp.sign(jnp.linalg.det(U @ Vt))]).astype(A.dtype)
    R = (U * D) @ Vt
    t = b / (jnp.sum(sv) / 3.0)
    rms = _rms_px(points_body @ R.T + t, xy, weights, fxy)
    too_few = jnp.sum(weights) < DLT_MIN_POINTS
    status = _solution_status(R, t, rms, points_body, weights, too_few, degenerate | planar)
    return _EPnPOut(R, t, status, rms, planar, c0, axes[:, 2])


def dlt(
    points_body: Float[ArrayLike, "n 3"],
    pixels: Float[ArrayLike, "n 2"],
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    mask: Bool[ArrayLike, " n"] | None = None,
    planar_tol: float = PLANAR_TOL,
    throw: bool = True,
) -> PnPResult:
    """Direct linear transform for ``>= 6`` non-coplanar points (one problem).

    The ``3 x 4`` matrix ``P ~ [R | t]`` in normalised image coordinates is the right singular
    vector of the ``2n x 12`` system (3-D points centred and scaled first, Hartley); ``R`` is the
    closest rotation to its left ``3 x 3`` block (SVD), ``t`` its last column over the mean
    singular value. Coplanar points give ``DEGENERATE`` (use :func:`epnp`), fewer than six valid
    points ``TOO_FEW_POINTS``. ``throw=True`` (the default) raises for a status other than
    ``OK``; pass ``throw=False`` under ``vmap`` and read ``status``.
    """
    res = _dlt_eager(points_body, pixels, as_camera(camera), mask, check_planar_tol(planar_tol))
    if check_throw(throw):
        res = throw_for_status(res, "dlt", "reprojection_error", min_points=DLT_MIN_POINTS)
    return res


def _dlt_body(points_body, pixels, camera, mask, planar_tol) -> PnPResult:
    """The compiled body of :func:`dlt` (shape checks at trace time)."""
    prob = _problem(points_body, pixels, camera, mask, "dlt")
    weights = prob.valid.astype(prob.points_body.dtype)
    out = _dlt_core(prob.points_body, prob.xy, weights, prob.fxy, planar_tol)
    return _conclude(prob, out, DLT_MIN_POINTS)


_dlt_eager = eager_jit(_dlt_body, static_argnums=(4,))
