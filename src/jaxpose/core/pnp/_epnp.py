"""EPnP: the pose of one problem in closed form (pure JAX).

EPnP (Lepetit, Moreno-Noguer, Fua 2009; Sharma et al. 2018, eqs. 17-22)
    Body points are written as barycentric combinations of four control points (three when the
    points are planar, eq. 17); the projection equations (eqs. 18-21) are linear in the camera
    coordinates of the control points; the near-null space of that system gives up to four
    kernel vectors whose combination coefficients ``beta`` are fixed by the inter-control-point
    distances (linearised, then Gauss-Newton), exactly as in OpenCV's ``epnp.cpp``: three
    ``beta`` initialisations (OpenCV's ``approx_1/2/3``), five Gauss-Newton steps each, the pose
    of each by absolute orientation, and the candidate of lowest reprojection error is kept.

    Two implementation choices make it fast under ``vmap`` on a CPU, where LAPACK calls on tiny
    matrices dominate: (1) the ``12 x 12`` eigenproblem of ``M^T M`` is reduced to a ``4 x 4``
    one by eliminating the ``x`` and ``y`` camera coordinates of the control points (a Schur
    complement; the null space is the same, and its near-null vectors minimise the same algebraic
    error for a unit-norm depth part); (2) every small eigenproblem and solve (``<= 5 x 5``) is
    written out entry by entry (cyclic Jacobi, Cholesky), so that a batch runs as fused
    element-wise loops instead of one LAPACK call per problem. The absolute orientation uses
    Horn's quaternion method (always a proper rotation). The planar case is selected inside the
    compiled function from the spread of the centred points (``sqrt(l3 / l1) < planar_tol``):
    the fourth control point is then masked out (its barycentric weight, its distance
    constraints and its ``beta`` are zero), so both cases run in one code path.

    A planar target far away is two-fold ambiguous (the plane can tilt either way about the line
    of sight and project almost identically). :func:`planar_flip` gives the mirrored candidate;
    :func:`jaxpose.solve_pnp` refines both and keeps the one with the lower reprojection error.

"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxpose.core._compile import eager_jit
from jaxpose.core.camera import PinholeCamera, as_camera
from jaxpose.core.geometry import Pose
from jaxpose.core.pnp._linalg import (
    _argmin_onehot,
    _det3,
    _eigh_small,
    _horn_rotation,
    _mm,
    _mtm,
    _rms_px,
    _solve4,
    _spd_solve,
    _weighted_lstsq,
)
from jaxpose.core.pnp._problem import (
    MIN_POINTS,
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

_GAUSS_NEWTON_STEPS = 5  # OpenCV epnp.cpp
_PAIRS = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))  # control-point pairs, OpenCV order
# (b11, b12, b22, b13, b23, b33, b14, b24, b34, b44): OpenCV's compute_L_6x10 column order
_BETA_PRODUCTS = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2), (0, 3), (1, 3), (2, 3), (3, 3))
# the L columns of OpenCV's find_betas_approx_1/2/3, padded to five
_APPROX_COLUMNS = ((0, 1, 3, 6, 0), (0, 1, 2, 0, 0), (0, 1, 2, 3, 4))


def _epnp_core(points_body, xy, weights, fxy, planar_tol=PLANAR_TOL) -> _EPnPOut:
    """EPnP on sanitised inputs: ``xy`` normalised coordinates, ``weights`` 0/1 per point."""
    dtype = points_body.dtype
    count = jnp.sum(weights)
    c0, axes, scale, planar, degenerate = _control_frame(points_body, weights, planar_tol)
    ctrl_body = jnp.concatenate([c0[None], c0 + (axes * scale).T], axis=0)  # (4, 3)
    # Barycentric coordinates (eq. 17): the axes are orthonormal, so no 3x3 inverse is needed.
    a123 = _mm(points_body - c0, axes) / scale
    a123 = a123 * jnp.stack([1.0, 1.0, jnp.where(planar, 0.0, 1.0)]).astype(dtype)
    alphas = jnp.concatenate([1.0 - jnp.sum(a123, axis=1, keepdims=True), a123], axis=1)
    alphas = alphas * weights[:, None]
    on4 = jnp.stack([1.0, 1.0, 1.0, jnp.where(planar, 0.0, 1.0)]).astype(dtype)

    # Eqs. 20-21 in normalised coordinates: sum_j a_ij (c_jx - x_i c_jz) = 0, same for y.
    # Eliminating X and Y: G X = Gx Z, G Y = Gy Z; Z minimises Z^T S Z (Schur complement).
    x, y = xy[:, 0], xy[:, 1]
    moments = jnp.stack([jnp.ones_like(x), x, y, x * x + y * y], axis=1)  # (n, 4)
    Gs = jnp.einsum("ni,nmj->imj", alphas, moments[:, :, None] * alphas[:, None, :])  # one dot
    G = Gs[:, 0] + jnp.diag(1.0 - on4)
    Gx, Gy, Gq = Gs[:, 1], Gs[:, 2], Gs[:, 3]
    K = _spd_solve(G, jnp.concatenate([Gx, Gy], axis=1))  # (4, 8)
    Kx, Ky = K[:, :4], K[:, 4:]
    S = Gq - _mm(Gx, Kx) - _mm(Gy, Ky)
    S = 0.5 * (S + S.T)
    big = 10.0 * (S[0, 0] + S[1, 1] + S[2, 2] + S[3, 3]) + 1.0
    S = S + jnp.diag((1.0 - on4) * big)  # planar: the unused control point never enters the kernel
    _, Z = _eigh_small(S)  # columns: kernel vectors, smallest eigenvalue first
    # v[k, j] = camera-frame (X, Y, Z) of control point j in kernel vector k
    v = jnp.stack([_mm(Kx, Z), _mm(Ky, Z), Z], axis=-1).transpose(1, 0, 2)  # (4, 4, 3)
    # unit 12-vectors, as OpenCV's eigenvectors of M^T M (its beta approximations depend on it)
    v = v / jnp.sqrt(jnp.sum(v * v, axis=(1, 2), keepdims=True))

    # Distance constraints (OpenCV compute_L_6x10 / compute_rho).
    dv = jnp.stack([v[:, a] - v[:, b] for a, b in _PAIRS], axis=1)  # (4 vectors, 6 pairs, 3)
    dd = sum(dv[:, None, :, c] * dv[None, :, :, c] for c in range(3))  # (4, 4, 6)
    L = jnp.stack(
        [dd[a, b] * (1.0 if a == b else 2.0) for a, b in _BETA_PRODUCTS], axis=1
    )  # (6, 10)
    rho = jnp.stack([jnp.sum((ctrl_body[a] - ctrl_body[b]) ** 2) for a, b in _PAIRS])
    row_w = jnp.stack([on4[a] * on4[b] for a, b in _PAIRS])

    # OpenCV's find_betas_approx_1/2/3 (linearised least squares, one stacked solve), then its
    # gauss_newton (5 steps) from each of the three, all candidates at once.
    A_lin = jnp.stack([jnp.stack([L[:, c] for c in cols], axis=1) for cols in _APPROX_COLUMNS])
    one, zero = jnp.ones((), dtype), jnp.zeros((), dtype)
    on_lin = jnp.stack(
        [
            jnp.stack([one, one, one, on4[3], zero]),
            jnp.stack([one, one, one, zero, zero]),
            jnp.stack([one, one, one, one, one]),
        ]
    )
    rows = jnp.broadcast_to(row_w, (3, 6))
    sol = _weighted_lstsq(A_lin, jnp.broadcast_to(rho, (3, 6)), rows, on_lin)
    betas = jnp.stack([_betas_approx_1(sol[0]), _betas_approx_2(sol[1]), _betas_approx_3(sol[2])])
    betas = betas * on4

    def gauss_newton(_, beta):
        prods = jnp.stack([beta[:, a] * beta[:, b] for a, b in _BETA_PRODUCTS], axis=1)  # (3, 10)
        r = (rho - _mm(prods, L.T)) * row_w  # (3, 6)
        bb = [beta[:, k, None] for k in range(4)]
        J = jnp.stack(
            [
                2 * L[:, 0] * bb[0] + L[:, 1] * bb[1] + L[:, 3] * bb[2] + L[:, 6] * bb[3],
                L[:, 1] * bb[0] + 2 * L[:, 2] * bb[1] + L[:, 4] * bb[2] + L[:, 7] * bb[3],
                L[:, 3] * bb[0] + L[:, 4] * bb[1] + 2 * L[:, 5] * bb[2] + L[:, 8] * bb[3],
                L[:, 6] * bb[0] + L[:, 7] * bb[1] + L[:, 8] * bb[2] + 2 * L[:, 9] * bb[3],
            ],
            axis=-1,
        ) * (row_w[:, None] * on4)  # (3, 6, 4); a masked control point adds no row, no column
        N = _mtm(J, J) + jnp.diag(1.0 - on4)
        g = sum(J[:, k, :] * r[:, k, None] for k in range(6))
        return beta + _solve4(N, g)

    betas = lax.fori_loop(0, _GAUSS_NEWTON_STEPS, gauss_newton, betas)

    # Camera-frame points of each candidate (eq. 17), made to lie in front, a rigid pose fitted
    # to each (absolute orientation), and the candidate of lowest reprojection error kept
    # (OpenCV's compute_R_and_t; choosing before the rigid fit fails with few points, where a
    # non-rigid candidate can fit the image well).
    ctrl_cam = sum(betas[:, k, None, None] * v[None, k] for k in range(4))  # (3, 4, 3)
    pc = _mm(alphas, ctrl_cam)  # (3, n, 3)
    sign = jnp.where(jnp.sum(pc[..., 2] * weights, axis=1) < 0, -1.0, 1.0)
    pc = pc * sign[:, None, None]
    # A mirror image of the body (det of the cross-covariance < 0; few points, far away) is the
    # depth reversal about the centroid's fronto-parallel plane, which projects almost alike:
    # undo that reversal before the rigid fit (OpenCV negates the third row of R instead).
    mc = jnp.sum(pc * weights[:, None], axis=1) / jnp.maximum(count, 1.0)  # (3, 3)
    H = _mtm((points_body - c0) * weights[:, None], pc - mc[:, None, :])  # (3, 3, 3)
    mirror = (_det3(H) < 0) & ~planar
    flip = jnp.where(mirror[:, None], 2.0 * mc[:, 2:] - pc[..., 2], pc[..., 2])
    pc = jnp.concatenate([pc[..., :2], flip[..., None]], axis=-1)
    R3, t3 = jax.vmap(lambda q: _horn_rotation(points_body, q, weights))(pc)
    rms3 = _rms_px(_mm(points_body, jnp.swapaxes(R3, -1, -2)) + t3[:, None, :], xy, weights, fxy)
    rms3 = jnp.where(jnp.isfinite(rms3), rms3, jnp.inf)
    pick = _argmin_onehot(rms3)
    R = sum(pick[c] * R3[c] for c in range(3))
    t = sum(pick[c] * t3[c] for c in range(3))
    rms = sum(jnp.where(pick[c] > 0, rms3[c], 0.0) for c in range(3))

    return _EPnPOut(
        R,
        t,
        _solution_status(R, t, rms, points_body, weights, count < MIN_POINTS, degenerate),
        rms,
        planar,
        c0,
        axes[:, 2],
    )


def _sqrt_pos(a):
    return jnp.sqrt(jnp.maximum(a, 0.0))


def _betas_approx_1(b):
    """OpenCV find_betas_approx_1: betas from (b11, b12, b13, b14)."""
    neg = b[0] < 0
    b1 = _sqrt_pos(jnp.abs(b[0]))
    ratio = jnp.where(b1 > 0, b[1:4] / jnp.where(b1 > 0, b1, 1.0), 0.0)
    return jnp.where(neg, -1.0, 1.0) * jnp.concatenate([b1[None], ratio])


def _betas_from_quadratic(b11, b12, b22):
    """OpenCV's sign logic of ``find_betas_approx_2/3``: (beta1, beta2) from (b11, b12, b22)."""
    neg = b11 < 0
    beta1 = jnp.where(neg, _sqrt_pos(-b11), _sqrt_pos(b11))
    beta2 = jnp.where(
        neg, jnp.where(b22 < 0, _sqrt_pos(-b22), 0.0), jnp.where(b22 > 0, _sqrt_pos(b22), 0.0)
    )
    return jnp.where(b12 < 0, -beta1, beta1), beta2


def _betas_approx_2(b):
    """OpenCV find_betas_approx_2: betas from (b11, b12, b22)."""
    beta1, beta2 = _betas_from_quadratic(b[0], b[1], b[2])
    zero = jnp.zeros_like(beta1)
    return jnp.stack([beta1, beta2, zero, zero])


def _betas_approx_3(b):
    """OpenCV find_betas_approx_3: betas from (b11, b12, b22, b13, b23)."""
    beta1, beta2 = _betas_from_quadratic(b[0], b[1], b[2])
    beta3 = jnp.where(beta1 != 0, b[3] / jnp.where(beta1 != 0, beta1, 1.0), 0.0)
    return jnp.stack([beta1, beta2, beta3, jnp.zeros_like(beta1)])


def epnp(
    points_body: Float[ArrayLike, "n 3"],
    pixels: Float[ArrayLike, "n 2"],
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    mask: Bool[ArrayLike, " n"] | None = None,
    planar_tol: float = PLANAR_TOL,
    throw: bool = True,
) -> PnPResult:
    """EPnP pose of one problem (Lepetit et al. 2009; Sharma et al. 2018, eqs. 17-22).

    Args:
        points_body: ``(n, 3)`` points in the target body frame, metres (``n >= 4``).
        pixels: ``(n, 2)`` measured (distorted) pixels; undistorted with ``camera.normalize``.
        camera: :class:`~jaxpose.core.camera.PinholeCamera` or a ``3 x 3`` ``K``.
        mask: ``(n,)`` bool, the valid points of a padded set (default: all).
        planar_tol: planarity threshold on ``sqrt(l3 / l1)`` of the centred points' scatter.
        throw: raise for a status other than ``OK`` (``ValueError`` eagerly, an Equinox runtime
            error under ``jit``); pass ``False`` under ``vmap`` and read ``status``.

    Returns:
        :class:`PnPResult`; ``status`` is ``TOO_FEW_POINTS`` (fewer than 4 valid points),
        ``NONFINITE_INPUT``, ``DEGENERATE`` (collinear or coincident points), ``NO_SOLUTION``
        or ``BEHIND_CAMERA`` (a valid point at or behind the camera in the solution).
        ``reprojection_error`` is the RMS over the valid points, pixels.

    Pure JAX: ``jax.jit(jax.vmap(lambda p, u: epnp(p, u, camera, throw=False)))`` solves a
    batch. Not meant to
    be differentiated (the closed form has branches and repeated eigenvalues); derivatives of
    a pose come from :func:`jaxpose.core.refine.refine_pose` / :func:`jaxpose.solve_pnp` with
    refinement, by implicit differentiation at the optimum.
    """
    res = _epnp_eager(points_body, pixels, as_camera(camera), mask, check_planar_tol(planar_tol))
    if check_throw(throw):
        res = throw_for_status(res, "epnp", "reprojection_error", min_points=MIN_POINTS)
    return res


def planar_flip(pose: Pose, centroid: Float[Array, 3], normal: Float[Array, 3]) -> Pose:
    """The mirror pose of a planar target: the same image under weak perspective.

    The plane (through ``centroid`` with unit ``normal``, body frame) is reflected across the
    plane through its camera-frame centre perpendicular to the line of sight ``d``:
    ``R' = (I - 2 d d^T) R (I - 2 n n^T)`` (a proper rotation; the body-frame reflection leaves
    the plane's points in place) and ``t'`` keeps the centre where it was. At long range the two
    poses project almost identically; a refinement from each and the lower reprojection error
    resolve the ambiguity (:func:`jaxpose.solve_pnp` does this).
    """
    c = pose.R @ centroid + pose.t
    d = c / jnp.linalg.norm(c)
    eye = jnp.eye(3, dtype=pose.R.dtype)
    R = (eye - 2.0 * jnp.outer(d, d)) @ pose.R @ (eye - 2.0 * jnp.outer(normal, normal))
    return Pose(R, c - R @ centroid)


def _epnp_body(points_body, pixels, camera, mask, planar_tol) -> PnPResult:
    """The compiled body of :func:`epnp` (shape checks at trace time)."""
    prob = _problem(points_body, pixels, camera, mask, "epnp")
    weights = prob.valid.astype(prob.points_body.dtype)
    out = _epnp_core(prob.points_body, prob.xy, weights, prob.fxy, planar_tol)
    return _conclude(prob, out, MIN_POINTS)


_epnp_eager = eager_jit(_epnp_body, static_argnums=(4,))
