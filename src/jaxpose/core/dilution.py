"""Dilution of precision (DOP) of a vision navigation system (Ning, Zhang, Wang 2018, Sec. 3).

Feature ``i`` at ``p_i`` (body frame, metres) is seen at ``rho_i = R(eps) p_i + T`` (eq. 1) and
measured as the pixel ``(u_i, v_i)`` of the camera model (eq. 3, plus the principal point and, if
the camera has one, OpenCV distortion). The state is ``x = (T, eps)`` with ``T`` in metres and the
attitude ``eps`` in radians, so that

* ``H`` (``2n x 6``) is the Jacobian of all pixels with respect to ``x`` at the true pose (eq. 7),
  computed here by forward-mode autodiff;
* ``Q = (H^T W H)^-1`` (eq. 14) with ``W = diag(1 / sigma_i^2)``; with unit weights ``Q`` is the
  DOP matrix and ``sigma^2 Q`` the covariance of the least-squares estimate (eq. 13);
* ``PDOP = sqrt(trace(Q[:3, :3]))`` (metres per pixel) and ``ADOP = sqrt(trace(Q[3:, 3:]))``
  (radians per pixel): the square-root-of-trace of the GNSS convention (eq. 15, whose exact form
  is lost; see ``docs/selection.md``).

The attitude ``eps`` is parameterised by Euler angles in a chosen ``sequence``
(``parameterization="euler"``, the paper's choice; ADOP depends on it) or by a small rotation
vector ``delta`` in the camera frame, ``R = exp([delta]_x) R_true`` (``"tangent"``, the natural
choice for covariance propagation). PDOP does not depend on the choice.

A DOP is computed from the sum of per-point ``6 x 6`` information blocks ``A_i = H_i^T H_i /
sigma_i^2``; this is what makes subset search cheap (:mod:`jaxpose.core.select`).

Bad geometry never gives a silent NaN: the figures are ``inf`` and a
:class:`~jaxpose.core.status.Status` says why (fewer than 4 points, a point behind the camera, a
singular ``H^T H``, NaN input, a pose whose ``R`` is not a rotation). Eager calls with
``throw=True`` (the default) raise ``ValueError`` instead; wrong shapes, a non-positive ``sigma``
and unknown options raise ``ValueError`` always.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from jaxpose.core._checks import (
    check_mask,
    check_pose,
    check_positive,
    check_rotation,
    check_rows,
    is_rotation,
)
from jaxpose.core._compile import eager_jit
from jaxpose.core.camera import PinholeCamera, as_camera
from jaxpose.core.geometry import (
    DEFAULT_EULER_SEQUENCE,
    Pose,
    dcm_to_euler,
    euler_to_dcm,
    parse_euler_sequence,
    so3_exp,
)
from jaxpose.core.status import Status, check_throw, throw_for_status

__all__ = [
    "DOPResult",
    "MIN_POINTS",
    "dop",
    "dop_from_information",
    "information_blocks",
    "observation_jacobian",
    "point_jacobians",
]

PARAMETERIZATIONS = ("euler", "tangent")

MIN_POINTS = 4
"""At least four coplanar points make ``H^T H`` non-singular (Ning et al., Sec. 5.1.2)."""


class DOPResult(eqx.Module):
    """DOP of one geometry (leading batch axes under ``vmap``).

    Attributes:
        pdop: position DOP, metres per pixel of measurement noise (``inf`` when not computable).
        adop: attitude DOP, radians per pixel.
        Q: ``(6, 6)`` ``(H^T W H)^-1``, state order ``(T, eps)``; ``inf`` when not computable.
        status: ``int32`` :class:`~jaxpose.core.status.Status` code, 0 when fine.
    """

    pdop: Float[Array, ...]
    adop: Float[Array, ...]
    Q: Float[Array, "... 6 6"]
    status: Int[Array, ...]


def _validate(points_body, pose: Pose) -> Array:
    check_pose(pose)
    return check_rows(points_body, (3,), "points_body")


def _state_to_pixels(pose: Pose, camera: PinholeCamera, sequence: str, parameterization: str):
    """Return ``(x0, f)`` with ``f(x, p)`` the pixel of body point ``p`` at state ``x``."""
    if parameterization == "euler":
        eps0 = dcm_to_euler(pose.R, sequence)

        def rotation(eps):
            return euler_to_dcm(eps, sequence)

    elif parameterization == "tangent":
        eps0 = jnp.zeros(3, dtype=pose.R.dtype)

        def rotation(eps):
            return so3_exp(eps) @ pose.R

    else:
        raise ValueError(
            f"parameterization must be one of {PARAMETERIZATIONS}; got {parameterization!r}"
        )

    def pixels(x, p):
        rho = rotation(x[3:]) @ p + x[:3]
        return camera.project(rho)

    return jnp.concatenate([pose.t, eps0]), pixels


def point_jacobians(
    points_body: Float[ArrayLike, "n 3"],
    pose: Pose,
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    sequence: str = DEFAULT_EULER_SEQUENCE,
    parameterization: str = "euler",
) -> Float[Array, "n 2 6"]:
    """Per-point blocks ``H_i = d(u_i, v_i) / d(T, eps)`` (pixels per metre, pixels per radian)."""
    points_body = _validate(points_body, pose)
    camera = as_camera(camera)
    x0, pixels = _state_to_pixels(pose, camera, sequence, parameterization)
    return jax.vmap(lambda p: jax.jacfwd(pixels)(x0, p))(points_body)


def observation_jacobian(
    points_body: Float[ArrayLike, "n 3"],
    pose: Pose,
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    sequence: str = DEFAULT_EULER_SEQUENCE,
    parameterization: str = "euler",
) -> Float[Array, "2*n 6"]:
    """The ``2n x 6`` observation matrix ``H`` of Ning et al. eq. 7, rows ``(u_1, v_1, ...)``."""
    H = point_jacobians(
        points_body, pose, camera, sequence=sequence, parameterization=parameterization
    )
    return H.reshape(-1, 6)


def information_blocks(
    points_body: Float[ArrayLike, "n 3"],
    pose: Pose,
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    sigma: Float[ArrayLike, " n"] | Float[ArrayLike, ""] | float | None = None,
    mask: Bool[ArrayLike, " n"] | None = None,
    sequence: str = DEFAULT_EULER_SEQUENCE,
    parameterization: str = "euler",
) -> Float[Array, "n 6 6"]:
    """Per-point information ``A_i = H_i^T H_i / sigma_i^2`` (zero for masked-out points).

    ``sigma`` is the pixel noise per axis, one per point or shared; ``None`` means unit weights
    (the plain DOP). ``mask`` (``(n,)`` bool) marks valid points of a padded set. A known (not
    traced) ``pose.R`` that is not a rotation raises ``ValueError`` (:func:`dop` reports it as
    ``Status.NOT_A_ROTATION``); a traced one is not looked at.
    """
    check_pose(pose)
    check_rotation(pose.R, "pose.R", nonfinite_ok=True, prefix="information_blocks: ")
    check_positive(sigma, "sigma (pixel noise)")
    H = point_jacobians(
        points_body, pose, camera, sequence=sequence, parameterization=parameterization
    )
    sigma = _check_sigma(sigma, H.shape[0], H.dtype)
    w = _weights(points_body.shape[0], H.dtype, sigma, mask)
    return jnp.einsum("nki,nkj,n->nij", H, H, w)


def _check_sigma(sigma, n: int, dtype):
    """``sigma`` as ``(n,)`` (or ``None``); a ``ValueError`` for a wrong shape and, when its values
    are known (not traced), for a value that is not positive and finite."""
    if sigma is None:
        return None
    check_positive(sigma, "sigma (pixel noise)")
    sigma = jnp.asarray(sigma, dtype=dtype)
    if sigma.ndim > 1 or (sigma.ndim == 1 and sigma.shape[0] != n):
        raise ValueError(f"sigma must be a scalar or have shape ({n},); got {sigma.shape}")
    return jnp.broadcast_to(sigma, (n,))


def _weights(n, dtype, sigma, mask):
    w = jnp.ones(n, dtype=dtype)
    if sigma is not None:
        sigma = jnp.broadcast_to(jnp.asarray(sigma, dtype=dtype), (n,))
        w = w / sigma**2
    if mask is not None:
        w = jnp.where(check_mask(mask, n), w, 0.0)
    return w


def _singular_tolerance(dtype) -> float:
    return 1e3 * float(jnp.finfo(dtype).eps)


def _check_symmetric(A) -> None:
    """``ValueError`` naming ``A`` when a concrete ``A`` is not symmetric beyond rounding (NaN and
    inf entries are left to the status)."""
    if isinstance(A, jax.core.Tracer):
        return
    a = np.asarray(A, dtype=float)
    finite = np.isfinite(a)
    if not finite.any():
        return
    scale = float(np.max(np.abs(a[finite])))
    with np.errstate(invalid="ignore"):
        gap = np.abs(a - np.swapaxes(a, -1, -2))
    worst = float(np.max(np.where(np.isfinite(gap), gap, 0.0)))
    if worst > 1e-6 * scale:
        raise ValueError(
            "dop_from_information: A (the information matrix H^T W H) must be symmetric; got "
            f"|A - A^T| up to {worst:.3g} for max |A| = {scale:.3g}"
        )


def dop_from_information(A: Float[ArrayLike, "6 6"]) -> DOPResult:
    """PDOP, ADOP and ``Q`` of an information matrix ``A = H^T W H`` (Ning et al. eqs. 14-15).

    Singularity is judged on the Jacobi-scaled matrix ``D^-1/2 A D^-1/2`` (metres and radians have
    different scales): the smallest eigenvalue below ``1e3 * eps(dtype)`` times the largest gives
    ``Status.SINGULAR`` and ``inf``. The status cannot tell why a sum of blocks is singular: points
    behind the camera (whose blocks hold no depth information) give ``SINGULAR`` here, while
    :func:`dop`, which sees the points, reports ``BEHIND_CAMERA``.

    A known (not traced) ``A`` that is not symmetric (``|A - A^T|`` above ``1e-6 max |A|``: not
    an information matrix) raises ``ValueError``; a traced one is not looked at (its lower
    triangle is used).
    """
    A = jnp.asarray(A)
    if A.shape[-2:] != (6, 6):
        raise ValueError(f"information matrix must be (6, 6); got {A.shape}")
    _check_symmetric(A)
    diag = jnp.diagonal(A)
    positive = jnp.all(diag > 0)
    d = jnp.sqrt(jnp.where(diag > 0, diag, 1.0))
    S = A / (d[:, None] * d[None, :])
    evals = jnp.linalg.eigvalsh(S)
    finite = jnp.all(jnp.isfinite(A))
    singular = ~finite | ~positive | (evals[0] <= _singular_tolerance(A.dtype) * evals[-1])
    # A safe matrix and scale for the solve so that the singular branch produces no NaN, not even
    # in gradients (double-where: the unselected branch must itself be finite).
    S_safe = jnp.where(singular, jnp.eye(6, dtype=A.dtype), S)
    d_safe = jnp.where(singular, 1.0, d)
    Qs = jnp.linalg.inv(S_safe)
    Qs = 0.5 * (Qs + Qs.T)
    Q = Qs / (d_safe[:, None] * d_safe[None, :])
    pdop = jnp.sqrt(jnp.trace(Q[:3, :3]))
    adop = jnp.sqrt(jnp.trace(Q[3:, 3:]))
    inf = jnp.asarray(jnp.inf, dtype=A.dtype)
    status = jnp.where(
        finite, jnp.where(singular, Status.SINGULAR, Status.OK), Status.NONFINITE_INPUT
    ).astype(jnp.int32)
    return DOPResult(
        pdop=jnp.where(singular, inf, pdop),
        adop=jnp.where(singular, inf, adop),
        Q=jnp.where(singular, inf, Q),
        status=status,
    )


def dop(
    points_body: Float[ArrayLike, "n 3"],
    pose: Pose,
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    sigma: Float[ArrayLike, " n"] | Float[ArrayLike, ""] | float | None = None,
    mask: Bool[ArrayLike, " n"] | None = None,
    sequence: str = DEFAULT_EULER_SEQUENCE,
    parameterization: str = "euler",
    throw: bool = True,
) -> DOPResult:
    """DOP of a set of feature points seen at ``pose`` by ``camera``.

    Args:
        points_body: ``(n, 3)`` feature points in the target body frame, metres.
        pose: true relative pose (``x_cam = R p + t``).
        camera: :class:`PinholeCamera` or ``3x3`` ``K``.
        sigma: pixel noise per point (weighted DOP, Won et al.) or shared; ``None`` for unit.
        mask: ``(n,)`` bool, valid points of a padded set.
        sequence: Euler sequence of the attitude state (see :mod:`jaxpose.core.geometry`).
        parameterization: ``"euler"`` (the paper's) or ``"tangent"``.
        throw: raise ``ValueError`` (eager) or an ``EquinoxRuntimeError`` (under jit) for bad
            geometry. Pass ``throw=False`` under ``vmap`` to get ``inf`` and a status per problem.

    Returns:
        :class:`DOPResult`. Units: PDOP in metres per pixel, ADOP in radians per pixel.
    """
    points_body = _validate(points_body, pose)
    camera = as_camera(camera)
    n = points_body.shape[0]
    parse_euler_sequence(sequence)
    if parameterization not in PARAMETERIZATIONS:
        raise ValueError(
            f"parameterization must be one of {PARAMETERIZATIONS}; got {parameterization!r}"
        )
    valid = check_mask(mask, n)
    sigma = _check_sigma(sigma, n, points_body.dtype)
    res = _dop(points_body, pose, camera, sigma, valid, sequence, parameterization)
    if check_throw(throw):
        res = throw_for_status(res, "dop", "pdop", min_points=MIN_POINTS)
    return res


@eqx.filter_jit
def _gimbal_lock(res: DOPResult, points, pose, camera, sigma, use, sequence) -> DOPResult:
    """At gimbal lock of the Euler state the Euler information is singular but the geometry is
    not: the PDOP (the position block of ``Q``, a Schur complement that does not depend on how the
    attitude is parameterised) is the tangent one, the ADOP in Euler angles is infinite, and the
    status says :attr:`Status.GIMBAL_LOCK` instead of blaming the points."""
    tangent = dop_from_information(
        jnp.sum(
            information_blocks(points, pose, camera, sigma=sigma, mask=use,
                               parameterization="tangent"),
            axis=0,
        )
    )  # fmt: skip
    locked = (res.status == Status.SINGULAR) & (tangent.status == Status.OK)
    inf = jnp.asarray(jnp.inf, res.pdop.dtype)
    return DOPResult(
        pdop=jnp.where(locked, tangent.pdop, res.pdop),
        adop=jnp.where(locked, inf, res.adop),
        Q=jnp.where(locked, inf, res.Q),
        status=jnp.where(locked, Status.GIMBAL_LOCK, res.status).astype(jnp.int32),
    )


def _dop_body(points_body, pose, camera, sigma, valid, sequence, parameterization) -> DOPResult:
    """The compiled body of :func:`dop` (one compilation per shape, dtype and option set)."""
    dtype = points_body.dtype
    finite_in = (
        jnp.all(jnp.isfinite(points_body) | ~valid[:, None])
        & jnp.all(jnp.isfinite(pose.R))
        & jnp.all(jnp.isfinite(pose.t))
        & jnp.all(jnp.isfinite(jnp.stack([camera.fx, camera.fy, camera.cx, camera.cy])))
        & jnp.all(jnp.isfinite(camera.dist))
    )
    points_safe = jnp.where(valid[:, None] & finite_in, points_body, 0.0)
    pose_safe = Pose(
        jnp.where(finite_in, pose.R, jnp.eye(3, dtype=dtype)),
        jnp.where(finite_in, pose.t, jnp.array([0.0, 0.0, 1.0], dtype=dtype)),
    )
    depth = (points_safe @ pose_safe.R.T + pose_safe.t)[:, 2]
    behind = jnp.any(valid & (depth <= 0))
    # Points behind the camera are removed from the sum (their projection is meaningless).
    use = valid & (depth > 0)
    A = jnp.sum(
        information_blocks(
            points_safe,
            pose_safe,
            camera,
            sigma=sigma,
            mask=use,
            sequence=sequence,
            parameterization=parameterization,
        ),
        axis=0,
    )
    res = dop_from_information(A)
    if parameterization == "euler":
        res = _gimbal_lock(res, points_safe, pose_safe, camera, sigma, use, sequence)
    count = jnp.sum(valid)
    status = jnp.select(
        [~finite_in, ~is_rotation(pose_safe.R), count < MIN_POINTS, behind],
        [
            Status.NONFINITE_INPUT,
            Status.NOT_A_ROTATION,
            Status.TOO_FEW_POINTS,
            Status.BEHIND_CAMERA,
        ],
        res.status,
    ).astype(jnp.int32)
    bad = status != Status.OK
    inf = jnp.asarray(jnp.inf, dtype=res.pdop.dtype)
    res = DOPResult(
        pdop=jnp.where(bad & (status != Status.GIMBAL_LOCK), inf, res.pdop),
        adop=jnp.where(bad, inf, res.adop),
        Q=jnp.where(bad, inf, res.Q),
        status=status,
    )
    return res


_dop = eager_jit(_dop_body, static_argnums=(5, 6))
