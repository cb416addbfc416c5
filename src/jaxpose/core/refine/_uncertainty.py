"""Pose covariance and the sensitivity of the refined pose to every input."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from jaxpose.core._checks import (
    as_float,
    check_line_inputs,
    check_mask,
    check_pose,
    check_rotation,
)
from jaxpose.core.camera import PinholeCamera, as_camera
from jaxpose.core.dilution import dop_from_information, point_jacobians
from jaxpose.core.geometry import (
    Pose,
)
from jaxpose.core.refine._implicit import _hessian_singular, _implicit_parts
from jaxpose.core.refine._model import (
    _tangent_cost,
)
from jaxpose.core.refine._options import MIN_FEATURES, RefineOptions
from jaxpose.core.refine._problem import _prepare
from jaxpose.core.refine._result import RefineResult
from jaxpose.core.status import Status, check_throw, throw_for_status


def pose_covariance(
    points_body: Float[ArrayLike, "n 3"],
    pose: Pose,
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    sigma: Float[ArrayLike, " n"] | Float[ArrayLike, ""] | float = 1.0,
    mask: Bool[ArrayLike, " n"] | None = None,
    segments_body: Float[ArrayLike, "k 2 3"] | None = None,
    lines_img: Float[ArrayLike, "k 3"] | None = None,
    line_sigma: Float[ArrayLike, " k"] | Float[ArrayLike, ""] | float | None = None,
    line_mask: Bool[ArrayLike, " k"] | None = None,
) -> Float[Array, "6 6"]:
    """First-order pose covariance ``(J^T W J)^-1 = sigma^2 (J^T J)^-1`` (metres, radians).

    Coordinates: ``(dt_x, dt_y, dt_z, dw_x, dw_y, dw_z)`` with ``t_true = t + dt`` (metres,
    camera frame) and ``R_true = exp([dw]_x) R`` (radians, rotation about camera-frame axes,
    applied on the left). The Jacobian is :func:`jaxpose.core.dilution.point_jacobians` with
    ``parameterization="tangent"`` through :func:`jaxpose.core.dilution.information_blocks`, so this
    is ``dop(..., parameterization="tangent", sigma=sigma).Q``: one Jacobian for DOP, refinement and
    covariance. Lines add ``J_l^T J_l / sigma_l^2`` with ``J_l = l_hat^T J`` of their projected
    endpoints.

    Returns a ``(6, 6)`` matrix, all ``inf`` when the information matrix is singular (fewer
    than three points, collinear points, ...).

    Raises ``ValueError`` for wrong shapes, a ``line_mask`` or ``line_sigma`` without lines and,
    when they are known (not traced), a ``pose.R`` that is not a rotation or a valid line of
    ``lines_img`` without direction (``l1 = l2 = 0``); traced, such a line gives ``inf``.
    """
    from jaxpose.core.dilution import information_blocks

    check_pose(pose, "pose")
    check_rotation(pose.R, "pose.R", nonfinite_ok=True, prefix="pose_covariance: ")
    has_lines = check_line_inputs(
        segments_body,
        lines_img,
        prefix="pose_covariance: ",
        line_mask=line_mask,
        line_sigma=line_sigma,
    )
    camera = as_camera(camera)
    A = jnp.sum(
        information_blocks(
            points_body, pose, camera, sigma=sigma, mask=mask, parameterization="tangent"
        ),
        axis=0,
    )
    if has_lines:
        segments_body = as_float(segments_body, name="segments_body")
        lines = as_float(lines_img, segments_body.dtype, name="lines_img")
        k = segments_body.shape[0]
        if segments_body.shape[1:] != (2, 3) or lines.shape != (k, 3):
            raise ValueError(
                f"segments_body must be (k, 2, 3) and lines_img (k, 3) for the same k; got "
                f"{segments_body.shape} and {lines.shape}"
            )
        valid = check_mask(line_mask, k, "line_mask")
        l12 = jnp.sum(lines[:, :2] ** 2, axis=-1)
        _check_line_directions(l12, valid)
        J_e = point_jacobians(
            segments_body.reshape(-1, 3), pose, camera, parameterization="tangent"
        ).reshape(k, 2, 2, 6)
        # Masked-out lines add nothing whatever they hold (0 * NaN would be NaN); a valid line
        # that is not finite, or traced without direction, gives NaN, hence an inf covariance.
        J_e = jnp.where(valid[:, None, None, None], J_e, 0.0)
        l_hat = (
            jnp.where(valid[:, None], lines[:, :2], 0.0)
            / jnp.sqrt(jnp.where(valid, l12, 1.0))[:, None]
        )
        J_l = jnp.einsum("ka,kmab->kmb", l_hat, J_e)
        ls = sigma if line_sigma is None and jnp.ndim(sigma) == 0 else line_sigma
        ls = (
            jnp.ones((k,), A.dtype) if ls is None else jnp.broadcast_to(as_float(ls, A.dtype), (k,))
        )
        w = jnp.where(valid, 1.0 / ls**2, 0.0)
        A = A + jnp.einsum("k,kmi,kmj->ij", w, J_l, J_l)
    return dop_from_information(A).Q


def _check_line_directions(l12, valid) -> None:
    """``ValueError`` naming ``lines_img`` and the index of the first valid line with ``l1 = l2 =
    0`` (no direction), when both are known."""
    if isinstance(l12, jax.core.Tracer) or isinstance(valid, jax.core.Tracer):
        return
    bad = np.asarray(valid) & (np.asarray(l12) == 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"pose_covariance: lines_img[{i}] has no direction (l1 = l2 = 0: not a line; "
            f"{int(bad.sum())} such line(s)); mask it out with line_mask"
        )


class PoseSensitivity(eqx.Module):
    """Jacobians of the refined pose's tangent coordinates (see :func:`pose_covariance`).

    Rows are ``(dt_x, dt_y, dt_z, dw_x, dw_y, dw_z)`` (metres, radians) of the optimum as the
    inputs change; e.g. ``d_pixels[:, i, 0]`` is the pose change per pixel of ``u_i``.

    Attributes:
        d_pixels: ``(6, n, 2)`` per pixel.
        d_points_body: ``(6, n, 3)`` per metre of model point coordinates.
        d_intrinsics: ``(6, 4)`` per pixel of ``(fx, fy, cx, cy)``.
        d_dist: ``(6, 5)`` per unit of each distortion coefficient.
        d_segments_body: ``(6, k, 2, 3)`` (zeros ``(6, 0, 2, 3)`` without lines).
        d_lines_img: ``(6, k, 3)`` per unit of the homogeneous line coefficients as given.
        status: ``int32`` :class:`~jaxpose.core.status.Status`: ``OK``, ``NONFINITE_INPUT``,
            ``TOO_FEW_POINTS`` (fewer than three valid features), ``DEGENERATE_LINE`` (a valid
            line of ``lines_img`` with ``l1 = l2 = 0``) or ``SINGULAR`` (the Hessian of the cost
            is not invertible: collinear points, ...). Every Jacobian is ``inf`` when
            the status is not ``OK``.
    """

    d_pixels: Array
    d_points_body: Array
    d_intrinsics: Array
    d_dist: Array
    d_segments_body: Array
    d_lines_img: Array
    status: Int[Array, ""]


def sensitivity(
    points_body: Float[ArrayLike, "n 3"],
    pixels: Float[ArrayLike, "n 2"],
    pose: Pose | RefineResult,
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
) -> PoseSensitivity:
    """Derivatives of the optimal pose with respect to pixels, 3-D points, lines and intrinsics.

    ``pose`` must be the optimum of the same problem (e.g. ``refine_pose(...).pose``, or the
    :class:`RefineResult` itself), and ``options`` the ones it was refined with (only the robust
    kernel and its scale matter here). By the implicit function theorem on
    ``grad_xi C(xi, theta) = 0``: ``d xi / d theta = -H^-1 d(grad_xi C) / d theta`` with the exact
    Hessian ``H`` of the robust cost (``xi`` in the tangent coordinates of
    :func:`pose_covariance`). This is the same rule that :func:`refine_pose` gives to
    ``jax.grad``; here all Jacobians at once.

    Example: ``sensitivity(P, u, res, cam).d_intrinsics[:, 0] * dfx`` is the first-order pose
    error caused by a focal-length error ``dfx`` (pixels).

    Raises:
        ValueError: wrong shapes; with ``throw=True`` (the default), a status other than ``OK``.
    """
    if isinstance(pose, RefineResult):
        pose = pose.pose
    if not isinstance(options, RefineOptions):
        raise ValueError(f"options must be a RefineOptions; got {type(options).__name__}")
    cfg = RefineOptions(robust=options.robust, robust_scale=options.robust_scale)
    camera = as_camera(camera)
    # Validate shapes eagerly (ValueError), then compute everything in one compiled call.
    check_pose(pose, "pose")  # named as sensitivity names it (_prepare says pose0)
    _prepare(
        pose,
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
    res = _sensitivity(
        pose,
        points_body,
        pixels,
        camera,
        mask,
        sigma,
        segments_body,
        lines_img,
        line_mask,
        line_sigma,
        cfg,
    )
    if check_throw(throw):
        res = throw_for_status(res, "sensitivity", "d_pixels", min_points=MIN_FEATURES)
    return res


@eqx.filter_jit
def _sensitivity(
    pose,
    points_body,
    pixels,
    camera,
    mask,
    sigma,
    segments_body,
    lines_img,
    line_mask,
    line_sigma,
    cfg,
) -> PoseSensitivity:
    has_lines = segments_body is not None
    pose_, prob, valid, lvalid, finite_input, lines_ok = _prepare(
        pose,
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
    dtype = prob.points.dtype
    zero = jnp.zeros(6, dtype)

    # Differentiate through _prepare (it only masks and normalises) so that the Jacobians are
    # with respect to the inputs as given.
    def grad_xi(P, u, cam, seg, lin):
        pose_i, prob_i, *_ = _prepare(pose, P, u, cam, mask, sigma, seg, lin, line_mask, line_sigma)
        return jax.grad(_tangent_cost)(zero, pose_i, prob_i, cfg)

    args = (
        as_float(points_body, dtype),
        as_float(pixels, dtype),
        camera,
        as_float(segments_body, dtype) if has_lines else None,
        as_float(lines_img, dtype) if has_lines else None,
    )
    B = jax.jacrev(grad_xi, argnums=(0, 1, 2, 3, 4) if has_lines else (0, 1, 2))(*args)
    H, _ = _implicit_parts(pose_, prob, cfg)
    singular = _hessian_singular(H)
    count = jnp.sum(valid) + jnp.sum(lvalid)
    status = jnp.select(
        [~finite_input, ~lines_ok, count < MIN_FEATURES, singular],
        [Status.NONFINITE_INPUT, Status.DEGENERATE_LINE, Status.TOO_FEW_POINTS, Status.SINGULAR],
        Status.OK,
    ).astype(jnp.int32)
    bad = status != Status.OK
    # A safe matrix in the failed branch, so that neither value nor gradient holds NaN.
    Hinv = jnp.linalg.inv(jnp.where(bad, jnp.eye(6, dtype=dtype), H))
    inf = jnp.asarray(jnp.inf, dtype)

    def solve(b):
        out = -jnp.tensordot(Hinv, jnp.where(jnp.isfinite(b), b, 0.0), axes=1)
        return jnp.where(bad, inf, out)

    dP, du, dcam, *dlines = jax.tree.map(solve, B)
    k = prob.segments.shape[0]
    return PoseSensitivity(
        d_pixels=du,
        d_points_body=dP,
        d_intrinsics=jnp.stack([dcam.fx, dcam.fy, dcam.cx, dcam.cy], axis=-1),
        d_dist=dcam.dist,
        d_segments_body=dlines[0] if has_lines else jnp.full((6, k, 2, 3), inf),
        d_lines_img=dlines[1] if has_lines else jnp.full((6, k, 3), inf),
        status=status,
    )
