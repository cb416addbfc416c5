"""Point and line reprojection residuals, information matrices and robust kernels (pure JAX).

Conventions (Yang et al. 2024, eqs. 7-10):

* **Point residual** (eq. 8): ``e_p = proj(R p + t) - p_obs`` in pixels, *projected minus
  observed*. The paper writes observed minus projected; the sign is flipped here so that the
  residual's Jacobian with respect to the pose is exactly the observation matrix ``H`` of
  :mod:`jaxpose.core.dilution` (``d e_p / d x = + d proj / d x``). Least-squares costs, weights and
  covariances do not depend on the sign.
* **Line residual** (eqs. 7, 9): the observed image segment with endpoints ``s, e`` (pixels) gives
  the homogeneous line ``l = s_h x e_h`` (:func:`line_from_segment`, eq. 7). The residual of a
  3-D segment with body-frame endpoints ``P_s, P_e`` is the pair of *signed* distances in pixels
  ``d = l . (proj(P), 1) / sqrt(l1^2 + l2^2)`` of the two projected endpoints to that line
  (eq. 9, normalised so that the distance is in pixels).
* **Information matrices**: ``Omega = I / sigma^2`` for isotropic pixel noise ``sigma`` (pixels,
  per axis), so the squared Mahalanobis norm ``s = e^T Omega e`` is dimensionless.
* **Robust kernels** follow g2o (and eq. 10): ``rho(s)`` acts on the squared Mahalanobis norm
  ``s``, with ``rho(s) = s`` for plain least squares, and the IRLS weight is ``rho'(s)``. For a
  residual norm ``r = sqrt(s)`` and a scale ``c`` (in units of ``sigma``):

  ========  ==========================================  ==========================
  kind      ``rho(s)``                                  weight ``rho'(r^2)``
  ========  ==========================================  ==========================
  huber     ``s`` if ``r <= c`` else ``2 c r - c^2``     ``1`` or ``c / r``
  cauchy    ``c^2 log(1 + s / c^2)``                    ``1 / (1 + r^2 / c^2)``
  tukey     ``c^2/3 (1 - (1 - s/c^2)^3)``, then const.  ``(1 - r^2/c^2)^2`` or ``0``
  ========  ==========================================  ==========================

  ``rho(s) = 2 rho_classic(sqrt(s))`` for the textbook kernels, so the weights are the classical
  IRLS weights ``psi(r) / r``.

* **Joint cost** (eq. 10): ``sum_i rho(e_pi^T Omega_pi e_pi) + sum_j rho(e_lj^T Omega_lj e_lj)``
  over the valid (masked-in) points and lines.

Every function takes one problem (batches come from ``jax.vmap``) and is NaN-safe in value and
gradient, also at zero residuals.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxpose.core._checks import (
    as_float,
    check_line_inputs,
    check_mask,
    check_pose,
    check_rows,
    check_same_length,
)
from jaxpose.core.camera import PinholeCamera, as_camera
from jaxpose.core.geometry import Pose

__all__ = [
    "DEFAULT_ROBUST_SCALE",
    "ROBUST_KINDS",
    "isotropic_information",
    "joint_cost",
    "line_from_segment",
    "line_residuals",
    "point_residuals",
    "robust_rho",
    "robust_weight",
]

ROBUST_KINDS = (None, "huber", "cauchy", "tukey")

DEFAULT_ROBUST_SCALE = {"huber": 2.4477, "cauchy": 2.4477, "tukey": 4.6851}
"""Default kernel scales ``c`` in units of ``sigma`` (Mahalanobis norm).

Huber and Cauchy at ``sqrt(chi2_2(0.95)) = 2.4477``, the 95% quantile of the norm of a 2-D
whitened residual (ORB-SLAM's choice); Tukey at 4.6851 (95% efficiency in 1-D).
"""


# ----------------------------------------------------------------------------- residuals


def point_residuals(
    points_body: Float[ArrayLike, "n 3"],
    pixels: Float[ArrayLike, "n 2"],
    pose: Pose,
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
) -> Float[Array, "n 2"]:
    """Reprojection errors ``proj(R p_i + t) - pixels_i`` in pixels.

    Yang et al. 2024 eq. 8, sign flipped (see the module docstring).

    Args:
        points_body: ``(n, 3)`` model points, metres.
        pixels: ``(n, 2)`` observed pixels ``(u, v)``.
        pose: body-to-camera pose (``x_cam = R p + t``).
        camera: :class:`~jaxpose.core.camera.PinholeCamera` or ``3x3`` ``K``.
    """
    check_pose(pose)
    points_body = check_rows(points_body, (3,), "points_body")
    pixels = check_rows(pixels, (2,), "pixels")
    check_same_length(points_body, pixels, "points_body", "pixels")
    return as_camera(camera).project(pose.apply(points_body)) - pixels


def line_from_segment(
    s: Float[ArrayLike, "... 2"], e: Float[ArrayLike, "... 2"]
) -> Float[Array, "... 3"]:
    """Homogeneous image line ``l = (s, 1) x (e, 1)`` through two pixels (Yang et al. 2024 eq. 7).

    Not normalised; ``l . (u, v, 1) / sqrt(l1^2 + l2^2)`` is the signed distance in pixels of
    ``(u, v)`` to the line (positive on the left of ``s -> e`` in the image, y down).
    """
    s, e = as_float(s), as_float(e)
    if s.shape[-1:] != (2,) or e.shape[-1:] != (2,):
        raise ValueError(f"segment endpoints must have shape (..., 2); got {s.shape} and {e.shape}")
    one = jnp.ones_like(s[..., :1])
    return jnp.cross(jnp.concatenate([s, one], -1), jnp.concatenate([e, one], -1))


def _line_distance(lines_img: Array, pix: Array) -> Array:
    """Signed distances (pixels) of ``pix (k, m, 2)`` to the lines ``(k, 3)``."""
    l12 = lines_img[:, :2]
    norm2 = jnp.sum(l12**2, axis=-1)
    # Double-where: a degenerate line (s == e) gives 0, with a NaN-free gradient.
    ok = norm2 > 0
    inv = jnp.where(ok, 1.0 / jnp.sqrt(jnp.where(ok, norm2, 1.0)), 0.0)
    return (jnp.einsum("ki,kmi->km", l12, pix) + lines_img[:, 2:3]) * inv[:, None]


def line_residuals(
    segments_body: Float[ArrayLike, "k 2 3"],
    lines_img: Float[ArrayLike, "k 3"],
    pose: Pose,
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
) -> Float[Array, "k 2"]:
    """Signed pixel distances of the projected 3-D segment endpoints to the observed lines.

    Yang et al. 2024 eqs. 7 and 9: ``d = l . (proj(R P + t), 1) / sqrt(l1^2 + l2^2)`` for the
    start and end point of each segment. A degenerate observed line (``l1 = l2 = 0``) gives
    zeros.

    Args:
        segments_body: ``(k, 2, 3)`` segment endpoints in the body frame, metres.
        lines_img: ``(k, 3)`` homogeneous image lines, e.g. :func:`line_from_segment` of the
            observed segment endpoints (any scale).
        pose: body-to-camera pose.
        camera: :class:`~jaxpose.core.camera.PinholeCamera` or ``3x3`` ``K``.

    Returns:
        ``(k, 2)`` signed distances in pixels (start, end).
    """
    check_pose(pose)
    segments_body = check_rows(segments_body, (2, 3), "segments_body")
    lines_img = check_rows(lines_img, (3,), "lines_img")
    check_same_length(segments_body, lines_img, "segments_body", "lines_img")
    pix = as_camera(camera).project(pose.apply(segments_body.reshape(-1, 3))).reshape(-1, 2, 2)
    return _line_distance(lines_img, pix)


# ----------------------------------------------------------------------------- information


def isotropic_information(sigma, count: int, dtype=None) -> Float[Array, "count 2 2"]:
    """``(count, 2, 2)`` information matrices ``I / sigma^2`` (``sigma`` in pixels, per axis).

    ``sigma`` is a scalar or one value per residual; ``None`` means 1 pixel.
    """
    dtype = dtype or jnp.result_type(float)
    s = jnp.ones((count,), dtype) if sigma is None else jnp.broadcast_to(as_float(sigma), (count,))
    return jnp.eye(2, dtype=dtype) / (s**2)[:, None, None]


# ----------------------------------------------------------------------------- robust kernels


def _check_kind(kind) -> None:
    if kind not in ROBUST_KINDS:
        raise ValueError(f"robust kernel must be one of {ROBUST_KINDS}; got {kind!r}")


def _scale(kind, scale):
    return DEFAULT_ROBUST_SCALE[kind] if scale is None else scale


def robust_rho(
    kind: str | None, s: Float[ArrayLike, ...], scale: float | None = None
) -> Float[Array, ...]:
    """Kernel ``rho(s)`` of a squared Mahalanobis norm ``s >= 0`` (g2o convention, eq. 10).

    ``kind=None`` gives ``s``. ``scale`` is ``c`` in units of ``sigma`` (default
    :data:`DEFAULT_ROBUST_SCALE`). See the module docstring for the formulas.
    """
    _check_kind(kind)
    s = as_float(s)
    if kind is None:
        return s
    c = _scale(kind, scale)
    c2 = jnp.asarray(c, s.dtype) ** 2
    if kind == "huber":
        inside = s <= c2
        r = jnp.sqrt(jnp.where(inside, c2, s))  # double-where: no sqrt(0) gradient
        return jnp.where(inside, s, 2.0 * jnp.sqrt(c2) * r - c2)
    if kind == "cauchy":
        return c2 * jnp.log1p(s / c2)
    # tukey
    u = jnp.minimum(s / c2, 1.0)
    return c2 / 3.0 * (1.0 - (1.0 - u) ** 3)


def robust_weight(
    kind: str | None, r: Float[ArrayLike, ...], scale: float | None = None
) -> Float[Array, ...]:
    """IRLS weight ``rho'(r^2) = psi(r) / r`` of a residual norm ``r`` (in units of ``sigma``).

    Equal to the derivative of :func:`robust_rho` at ``s = r^2``: Huber ``min(1, c/|r|)``,
    Cauchy ``1 / (1 + r^2/c^2)``, Tukey ``(1 - r^2/c^2)^2`` inside ``|r| < c`` and 0 outside.
    ``kind=None`` gives ones.
    """
    _check_kind(kind)
    r = as_float(r)
    if kind is None:
        return jnp.ones_like(r)
    return _weight_of_s(kind, r * r, scale)


def _weight_of_s(kind, s, scale):
    """``rho'(s)`` from the squared norm (what the solvers use)."""
    if kind is None:
        return jnp.ones_like(s)
    c = _scale(kind, scale)
    c2 = jnp.asarray(c, s.dtype) ** 2
    if kind == "huber":
        inside = s <= c2
        return jnp.where(inside, 1.0, jnp.sqrt(c2) / jnp.sqrt(jnp.where(inside, c2, s)))
    if kind == "cauchy":
        return 1.0 / (1.0 + s / c2)
    u = s / c2
    return jnp.where(u < 1.0, (1.0 - jnp.minimum(u, 1.0)) ** 2, 0.0)


# ----------------------------------------------------------------------------- joint cost


def _mahalanobis2(residuals: Array, information: Array | None) -> Array:
    if information is None:
        return jnp.sum(residuals**2, axis=-1)
    return jnp.einsum("ni,nij,nj->n", residuals, information, residuals)


def joint_cost(
    points_body: Float[ArrayLike, "n 3"],
    pixels: Float[ArrayLike, "n 2"],
    pose: Pose,
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    point_information: Float[ArrayLike, "n 2 2"] | None = None,
    mask: Bool[ArrayLike, " n"] | None = None,
    segments_body: Float[ArrayLike, "k 2 3"] | None = None,
    lines_img: Float[ArrayLike, "k 3"] | None = None,
    line_information: Float[ArrayLike, "k 2 2"] | None = None,
    line_mask: Bool[ArrayLike, " k"] | None = None,
    robust: str | None = None,
    robust_scale: float | None = None,
) -> Float[Array, ""]:
    """Yang et al. 2024 eq. 10: ``sum rho(e_p^T Omega_p e_p) + sum rho(e_l^T Omega_l e_l)``.

    Information matrices default to the identity (1-pixel noise); use
    :func:`isotropic_information` for ``I / sigma^2``. Masked-out points and lines add nothing
    (their inputs may hold anything finite or not). ``line_mask`` or ``line_information``
    without lines raises ``ValueError`` (it would otherwise be ignored).
    """
    _check_kind(robust)
    has_lines = check_line_inputs(
        segments_body,
        lines_img,
        prefix="joint_cost: ",
        line_mask=line_mask,
        line_information=line_information,
    )
    points_body = check_rows(points_body, (3,), "points_body")
    pixels = check_rows(pixels, (2,), "pixels")
    m = check_mask(mask, points_body.shape[0])
    pts = jnp.where(m[:, None], points_body, 0.0)
    pix = jnp.where(m[:, None], pixels, 0.0)
    s = _mahalanobis2(point_residuals(pts, pix, pose, camera), point_information)
    cost = jnp.sum(jnp.where(m, robust_rho(robust, s, robust_scale), 0.0))
    if has_lines:
        segments_body = check_rows(segments_body, (2, 3), "segments_body")
        lines_img = check_rows(lines_img, (3,), "lines_img")
        lm = check_mask(line_mask, segments_body.shape[0], "line_mask")
        seg = jnp.where(lm[:, None, None], segments_body, 0.0)
        lin = jnp.where(lm[:, None], lines_img, jnp.array([1.0, 0.0, 0.0], lines_img.dtype))
        sl = _mahalanobis2(line_residuals(seg, lin, pose, camera), line_information)
        cost = cost + jnp.sum(jnp.where(lm, robust_rho(robust, sl, robust_scale), 0.0))
    return cost
