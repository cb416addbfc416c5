"""Perspective-n-point solvers (pure JAX): EPnP, DLT and RANSAC over EPnP.

Every solver takes **one** problem, ``points_body (n, 3)`` (metres, target body frame) and the
``pixels (n, 2)`` where they are seen (distorted pixels, as measured), and returns a
:class:`PnPResult` whose pose satisfies ``x_cam = R @ x_body + t``. Batches come from
``jax.vmap``; point sets of different sizes share one compiled function through padding with a
``mask`` (``(n,)`` bool, ``True`` for the valid points). A solver never raises for bad values:
it returns a :class:`~jaxpose.core.status.Status` per problem (the eager, raising entry point is
:func:`jaxpose.solve_pnp`).

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

DLT
    The ``3 x 4`` projection matrix from ``>= 6`` non-coplanar points (Hartley normalisation of
    the 3-D points, SVD), then the closest rotation.

RANSAC
    Minimal samples of ``sample_size`` points drawn at random, EPnP on every hypothesis in one
    ``vmap``-ed call, inliers by reprojection error; the number of hypotheses is Sharma et al.
    eq. 35, ``k = log(1 - p) / log(1 - w^s)`` (:func:`ransac_iterations`), fixed before
    compilation from the largest outlier fraction to be handled.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Bool, Float, Int

from jaxpose.core.camera import PinholeCamera, as_camera
from jaxpose.core.geometry import Pose, quat_to_dcm
from jaxpose.core.status import Status

__all__ = [
    "DLT_MIN_POINTS",
    "MIN_POINTS",
    "PLANAR_TOL",
    "PnPResult",
    "dlt",
    "epnp",
    "planar_flip",
    "ransac_iterations",
    "ransac_pnp",
]

MIN_POINTS = 4
"""EPnP needs at least four points (planar or not)."""

DLT_MIN_POINTS = 6
"""The DLT needs at least six non-coplanar points."""

PLANAR_TOL = 1e-3
"""Points whose out-of-plane spread is below this fraction of their largest spread are planar
(``sqrt(l3 / l1)`` of the eigenvalues of their scatter matrix)."""

COLLINEAR_TOL = 1e-6
"""Points whose second spread is below this fraction of the largest (``sqrt(l2 / l1)``) are
collinear (or coincident): :attr:`Status.DEGENERATE`."""

_GAUSS_NEWTON_STEPS = 5  # OpenCV epnp.cpp
_JACOBI_SWEEPS = 6  # cyclic Jacobi on <= 4 x 4: converged to rounding well before this
_PAIRS = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))  # control-point pairs, OpenCV order


class PnPResult(eqx.Module):
    """Pose from a PnP solver (leading batch axes under ``vmap``).

    Attributes:
        pose: :class:`~jaxpose.core.geometry.Pose` ``x_cam = R @ x_body + t``; identity rotation and
            zero translation where ``status != 0``.
        status: ``int32`` :class:`~jaxpose.core.status.Status`, 0 when solved.
        reprojection_error: RMS reprojection error in pixels over the points used (the valid
            points, or RANSAC's inliers); ``inf`` where ``status != 0``.
        inliers: ``(n,)`` bool, the points the pose was computed from.
        planar: bool, the points were treated as planar (three control points).
    """

    pose: Pose
    status: Int[Array, ...]
    reprojection_error: Float[Array, ...]
    inliers: Bool[Array, "... n"]
    planar: Bool[Array, ...]

    @property
    def R(self) -> Float[Array, "... 3 3"]:
        return self.pose.R

    @property
    def t(self) -> Float[Array, "... 3"]:
        return self.pose.t


# ----------------------------------------------------------------------------- input handling


def _float_dtype(x) -> jnp.dtype:
    dtype = jnp.asarray(x).dtype
    return dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.result_type(float)


def _prepare(points_body, pixels, camera, mask, name: str):
    """Check shapes (trace time) and return arrays of one float dtype, the valid mask and camera."""
    camera = as_camera(camera)
    points_body = jnp.asarray(points_body)
    pixels = jnp.asarray(pixels)
    if points_body.ndim != 2 or points_body.shape[-1] != 3:
        raise ValueError(
            f"{name}: points_body must have shape (n, 3) (one problem; use jax.vmap or "
            f"jaxpose.solve_pnp for batches); got {points_body.shape}"
        )
    n = points_body.shape[0]
    if pixels.shape != (n, 2):
        raise ValueError(
            f"{name}: pixels must have shape ({n}, 2) to match points_body {points_body.shape}; "
            f"got {pixels.shape}"
        )
    dtype = _float_dtype(points_body)
    points_body = points_body.astype(dtype)
    pixels = pixels.astype(dtype)
    camera = jax.tree.map(lambda leaf: jnp.asarray(leaf).astype(dtype), camera)
    if mask is None:
        valid = jnp.ones(n, dtype=bool)
    else:
        valid = jnp.asarray(mask)
        if valid.shape != (n,):
            raise ValueError(f"{name}: mask must have shape ({n},); got {valid.shape}")
        valid = valid.astype(bool)
    return points_body, pixels, camera, valid


def _normalized(camera: PinholeCamera, pixels, undistort: bool | None = None):
    """Normalised, undistorted image coordinates; skips the Newton undistortion for a pinhole.

    ``undistort`` forces the choice; otherwise it is made at trace time for a concrete camera,
    and for a traced one (a camera passed through ``jit``) a ``lax.cond`` skips the undistortion
    at run time when every coefficient is zero.
    """
    if undistort is not None:
        return camera.normalize(pixels, undistort=undistort)
    dist = camera.dist
    if not isinstance(dist, jax.core.Tracer):
        return camera.normalize(pixels, undistort=bool(np.any(np.asarray(dist) != 0)))
    return lax.cond(
        jnp.any(dist != 0),
        lambda p: camera.normalize(p),
        lambda p: camera.normalize(p, undistort=False),
        pixels,
    )


def _sanitize(valid, points_body, xy):
    """Zero the invalid entries and report whether every valid entry is finite."""
    finite = jnp.all(
        (jnp.all(jnp.isfinite(points_body), axis=-1) & jnp.all(jnp.isfinite(xy), axis=-1)) | ~valid
    )
    use = valid & finite
    return (
        jnp.where(use[:, None], points_body, 0.0),
        jnp.where(use[:, None], xy, 0.0),
        finite,
    )


# ----------------------------------------------------------------------------- small dense algebra
# Tiny matrix products, eigenproblems and solves written as sums of broadcast products and
# element-wise updates. Under vmap they become fused element-wise loops over the batch; XLA's CPU
# dot and reduce kernels on 4 x 4 blocks (and one LAPACK call per problem for eigh/svd) are
# 5-20x slower here (measured in bench/pnp.py's history; see the module docstring).


def _mm(a, b):
    """``a @ b`` for small static shapes."""
    return sum(a[..., :, k, None] * b[..., None, k, :] for k in range(a.shape[-1]))


def _mtm(a, b):
    """``a^T @ b`` (contracting the second-to-last axes)."""
    return sum(a[..., k, :, None] * b[..., None, k, :] for k in range(a.shape[-2]))


def _mv(a, x):
    """``a @ x`` for a small matrix and vector."""
    return sum(a[..., :, k] * x[..., None, k] for k in range(a.shape[-1]))


# Circle-method round robin on four indices: rotate pairs (0, 1) and (2, 3), then move the last
# three positions cyclically; three rounds cover all six pairs and restore the order.
_ROUND_PERMUTATION = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [0, 1, 0, 0]], dtype=float)


def _jacobi4(A: Float[Array, "... 4 4"], sweeps: int = _JACOBI_SWEEPS):
    """Eigenvalues ``(..., 4)`` and eigenvectors (columns), unordered, of a symmetric ``4 x 4``.

    Cyclic Jacobi (Golub and Van Loan, Sec. 8.5) in the parallel ordering: each round rotates two
    disjoint index pairs at once and permutes the indices (circle method), so that one small loop
    body serves every round (``3 * sweeps`` rounds). Quadratic convergence: 5 sweeps reach
    rounding error on random matrices, and 6 are done (stopping early on convergence saved
    nothing measurable under ``vmap``).
    """
    dtype = A.dtype
    perm = jnp.asarray(_ROUND_PERMUTATION, dtype)

    def round_(_, AV):
        A, V = AV
        cs = []
        for p, q in ((0, 1), (2, 3)):
            apq, app, aqq = A[..., p, q], A[..., p, p], A[..., q, q]
            small = apq == 0
            tau = (aqq - app) / (2.0 * jnp.where(small, 1.0, apq))
            sgn = jnp.where(tau >= 0, 1.0, -1.0)
            t = jnp.where(small, 0.0, sgn / (jnp.abs(tau) + jnp.sqrt(1.0 + tau * tau)))
            c = 1.0 / jnp.sqrt(1.0 + t * t)
            cs += [c, t * c]
        c1, s1, c2, s2 = cs
        z = jnp.zeros_like(c1)
        J = jnp.stack(
            [
                jnp.stack([c1, s1, z, z], -1),
                jnp.stack([-s1, c1, z, z], -1),
                jnp.stack([z, z, c2, s2], -1),
                jnp.stack([z, z, -s2, c2], -1),
            ],
            -2,
        )
        J = _mm(J, perm)
        return _mm(_mtm(J, A), J), _mm(V, J)

    eye = jnp.broadcast_to(jnp.eye(4, dtype=dtype), A.shape)
    A, V = lax.fori_loop(0, 3 * sweeps, round_, (A, eye))
    return jnp.stack([A[..., i, i] for i in range(4)], axis=-1), V


def _sort_eig(evals, evecs, descending: bool = False):
    """Order eigenpairs without a sort: ranks from pairwise comparisons, then a one-hot product."""
    k = evals.shape[-1]
    key = -evals if descending else evals
    ki, kj = key[..., :, None], key[..., None, :]
    before = (kj < ki) | ((kj == ki) & (np.arange(k)[None, :] < np.arange(k)[:, None]))
    rank = sum(before[..., :, j].astype(jnp.int32) for j in range(k))  # position of pair i
    onehot = (rank[..., :, None] == np.arange(k, dtype=np.int32)).astype(
        evals.dtype
    )  # [i, position]
    return sum(evals[..., i, None] * onehot[..., i, :] for i in range(k)), _mm(evecs, onehot)


def _eigh_small(A, descending: bool = False):
    """Sorted eigenpairs of a symmetric ``3 x 3`` (padded to ``4 x 4``) or ``4 x 4`` matrix."""
    k = A.shape[-1]
    if k == 3:
        A = jnp.pad(A, [(0, 0)] * (A.ndim - 2) + [(0, 1), (0, 1)])
    evals, evecs = _jacobi4(A)
    return _sort_eig(evals[..., :k], evecs[..., :k, :k], descending)


def _spd_solve(N: Float[Array, "... k k"], b: Float[Array, "... k m"]) -> Float[Array, "... k m"]:
    """``N^-1 b`` for a small symmetric positive definite ``N`` (Gauss-Jordan, no pivoting,
    which is stable for SPD matrices; whole-row updates)."""
    k = N.shape[-1]
    M = jnp.concatenate([N, b], axis=-1)
    for p in range(k):
        row = M[..., p, :] / M[..., p, p, None]
        col = M[..., :, p] - jnp.asarray(
            np.eye(k)[p], M.dtype
        )  # row p becomes `row`; others lose column p
        M = M - col[..., :, None] * row[..., None, :]
    return M[..., :, k:]


def _solve4(N: Float[Array, "... 4 4"], b: Float[Array, "... 4"]) -> Float[Array, "... 4"]:
    """``N^-1 b`` for a symmetric positive (semi)definite ``4 x 4`` by the adjugate (Laplace
    expansion in 2 x 2 minors), after Jacobi scaling; element-wise throughout, so one fused
    kernel under ``vmap``. A singular ``N`` gives a zero step."""
    d = jnp.stack([N[..., i, i] for i in range(4)], axis=-1)
    d = jnp.where(d > 0, 1.0 / jnp.sqrt(jnp.where(d > 0, d, 1.0)), 1.0)
    m = N * d[..., :, None] * d[..., None, :]
    e = [[m[..., i, j] for j in range(4)] for i in range(4)]
    s0 = e[0][0] * e[1][1] - e[1][0] * e[0][1]
    s1 = e[0][0] * e[1][2] - e[1][0] * e[0][2]
    s2 = e[0][0] * e[1][3] - e[1][0] * e[0][3]
    s3 = e[0][1] * e[1][2] - e[1][1] * e[0][2]
    s4 = e[0][1] * e[1][3] - e[1][1] * e[0][3]
    s5 = e[0][2] * e[1][3] - e[1][2] * e[0][3]
    c5 = e[2][2] * e[3][3] - e[3][2] * e[2][3]
    c4 = e[2][1] * e[3][3] - e[3][1] * e[2][3]
    c3 = e[2][1] * e[3][2] - e[3][1] * e[2][2]
    c2 = e[2][0] * e[3][3] - e[3][0] * e[2][3]
    c1 = e[2][0] * e[3][2] - e[3][0] * e[2][2]
    c0 = e[2][0] * e[3][1] - e[3][0] * e[2][1]
    det = s0 * c5 - s1 * c4 + s2 * c3 + s3 * c2 - s4 * c1 + s5 * c0
    adj = [
        [
            e[1][1] * c5 - e[1][2] * c4 + e[1][3] * c3,
            -e[0][1] * c5 + e[0][2] * c4 - e[0][3] * c3,
            e[3][1] * s5 - e[3][2] * s4 + e[3][3] * s3,
            -e[2][1] * s5 + e[2][2] * s4 - e[2][3] * s3,
        ],
        [
            -e[1][0] * c5 + e[1][2] * c2 - e[1][3] * c1,
            e[0][0] * c5 - e[0][2] * c2 + e[0][3] * c1,
            -e[3][0] * s5 + e[3][2] * s2 - e[3][3] * s1,
            e[2][0] * s5 - e[2][2] * s2 + e[2][3] * s1,
        ],
        [
            e[1][0] * c4 - e[1][1] * c2 + e[1][3] * c0,
            -e[0][0] * c4 + e[0][1] * c2 - e[0][3] * c0,
            e[3][0] * s4 - e[3][1] * s2 + e[3][3] * s0,
            -e[2][0] * s4 + e[2][1] * s2 - e[2][3] * s0,
        ],
        [
            -e[1][0] * c3 + e[1][1] * c1 - e[1][2] * c0,
            e[0][0] * c3 - e[0][1] * c1 + e[0][2] * c0,
            -e[3][0] * s3 + e[3][1] * s1 - e[3][2] * s0,
            e[2][0] * s3 - e[2][1] * s1 + e[2][2] * s0,
        ],
    ]
    db = d * b
    x = [sum(adj[i][j] * db[..., j] for j in range(4)) for i in range(4)]
    ok = jnp.abs(det) > 0
    inv_det = jnp.where(ok, 1.0 / jnp.where(ok, det, 1.0), 0.0)
    return d * jnp.stack(x, axis=-1) * inv_det[..., None]


def _weighted_lstsq(A, b, row_w, col_on, ridge: float = 1e-12):
    """Least squares ``min |W^1/2 (A x - b)|`` over the columns in ``col_on`` (others are 0).

    Normal equations with a relative ridge (a near-minimum-norm answer when under-determined).
    ``A (..., r, c)``, ``b (..., r)``, ``row_w (..., r)``, ``col_on (..., c)``.
    """
    c = A.shape[-1]
    Aw = A * col_on[..., None, :]
    AwW = Aw * row_w[..., :, None]
    N = _mtm(AwW, Aw)
    rhs = sum(AwW[..., r, :] * b[..., r, None] for r in range(A.shape[-2]))
    scale = sum(N[..., i, i] for i in range(c))[..., None, None] / c
    eye = jnp.eye(c, dtype=A.dtype)
    N = N + eye * (ridge * scale + jnp.finfo(A.dtype).tiny) + eye * (1.0 - col_on)[..., None, :]
    return _spd_solve(N, rhs[..., None])[..., 0] * col_on


def _horn_rotation(points_a, points_b, weights):
    """Rotation ``R`` (proper) and translation ``t`` minimising ``sum w |R a + t - b|^2``.

    Horn (1987) closed form: the unit quaternion is the top eigenvector of a ``4 x 4`` symmetric
    matrix built from the cross-covariance. ``points_* (n, 3)``, ``weights (n,)``.
    """
    wsum = jnp.maximum(jnp.sum(weights), 1.0)
    ma = jnp.sum(points_a * weights[:, None], axis=0) / wsum
    mb = jnp.sum(points_b * weights[:, None], axis=0) / wsum
    da = (points_a - ma) * weights[:, None]
    db = points_b - mb
    S = jnp.sum(da[:, :, None] * db[:, None, :], axis=0)
    sxx, sxy, sxz = S[0, 0], S[0, 1], S[0, 2]
    syx, syy, syz = S[1, 0], S[1, 1], S[1, 2]
    szx, szy, szz = S[2, 0], S[2, 1], S[2, 2]
    N = jnp.stack(
        [
            jnp.stack([sxx + syy + szz, syz - szy, szx - sxz, sxy - syx]),
            jnp.stack([syz - szy, sxx - syy - szz, sxy + syx, szx + sxz]),
            jnp.stack([szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy]),
            jnp.stack([sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz]),
        ]
    )
    _, evecs = _eigh_small(N, descending=True)
    R = quat_to_dcm(evecs[:, 0])
    return R, mb - _mv(R, ma)


def _det3(A):
    """Determinant of ``(..., 3, 3)`` matrices (cofactor expansion)."""
    return (
        A[..., 0, 0] * (A[..., 1, 1] * A[..., 2, 2] - A[..., 1, 2] * A[..., 2, 1])
        - A[..., 0, 1] * (A[..., 1, 0] * A[..., 2, 2] - A[..., 1, 2] * A[..., 2, 0])
        + A[..., 0, 2] * (A[..., 1, 0] * A[..., 2, 1] - A[..., 1, 1] * A[..., 2, 0])
    )


def _rms_px(points_cam, xy, weights, fxy):
    """RMS reprojection error (pixels, in the undistorted image) of camera-frame points."""
    z = points_cam[..., 2]
    front = z > 0
    z_safe = jnp.where(front, z, 1.0)
    d = (points_cam[..., :2] / z_safe[..., None] - xy) * fxy
    e2 = jnp.where(front, d[..., 0] ** 2 + d[..., 1] ** 2, jnp.inf)
    ms = jnp.sum(jnp.where(weights > 0, e2 * weights, 0.0), axis=-1) / jnp.maximum(
        jnp.sum(weights), 1.0
    )
    return jnp.sqrt(ms)


# ----------------------------------------------------------------------------- EPnP


class _EPnPOut(eqx.Module):
    R: Array
    t: Array
    status: Array
    rms: Array  # pixels (undistorted), over the used points
    planar: Array
    centroid: Array  # (3,) body frame
    normal: Array  # (3,) body frame, least-spread direction


def _control_frame(points_body, weights, planar_tol):
    """Centroid, principal axes (columns, by decreasing spread), spreads and flags (OpenCV's
    ``choose_control_points``: ``c_k = c_0 + sqrt(l_k / n) e_k``)."""
    count = jnp.maximum(jnp.sum(weights), 1.0)
    c0 = jnp.sum(points_body * weights[:, None], axis=0) / count
    d = (points_body - c0) * weights[:, None]
    evals, evecs = _eigh_small(jnp.einsum("na,nb->ab", d, d), descending=True)
    evals = jnp.maximum(evals, 0.0)
    l1 = evals[0]
    degenerate = ~(evals[1] > COLLINEAR_TOL**2 * l1)  # also catches l1 == 0 and NaN
    planar = evals[2] <= planar_tol**2 * l1
    scale = jnp.sqrt(evals / count)
    scale = jnp.stack([scale[0], scale[1], jnp.where(planar, scale[0], scale[2])])
    scale = jnp.where(scale > 0, scale, 1.0)
    return c0, evecs, scale, planar, degenerate


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


def _solution_status(R, t, rms, points_body, weights, too_few, degenerate):
    """Status of a closed-form solution: input checks first, then the solution's own."""
    depth = _mv(points_body, R[2]) + t[2]
    behind = jnp.any((weights > 0) & ~(depth > 0))
    finite_out = jnp.all(jnp.isfinite(R)) & jnp.all(jnp.isfinite(t))
    return jnp.select(
        [too_few, degenerate, ~finite_out, behind, ~jnp.isfinite(rms)],
        [
            Status.TOO_FEW_POINTS,
            Status.DEGENERATE,
            Status.NO_SOLUTION,
            Status.BEHIND_CAMERA,
            Status.NO_SOLUTION,
        ],
        Status.OK,
    ).astype(jnp.int32)


def _argmin_onehot(x):
    """One-hot (float) of the first minimum of a short vector (no gather under vmap)."""
    k = x.shape[-1]
    cols = []
    for i in range(k):
        first = jnp.ones(x.shape[:-1], dtype=bool)
        for j in range(k):
            if j != i:
                first = first & ((x[..., i] < x[..., j]) if j < i else (x[..., i] <= x[..., j]))
        cols.append(first)
    return jnp.stack(cols, axis=-1).astype(x.dtype)


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


def _kept(status):
    """Statuses whose pose is returned (``NOT_CONVERGED``: the refinement's last iterate)."""
    return (status == Status.OK) | (status == Status.NOT_CONVERGED)


def _finish(out: _EPnPOut, status, inliers, points_body, pixels, camera) -> PnPResult:
    """Pixel-space RMS (with distortion) for solved problems; identity/zero/inf elsewhere."""
    ok = _kept(status)
    dtype = out.R.dtype
    pose = Pose(jnp.where(ok, out.R, jnp.eye(3, dtype=dtype)), jnp.where(ok, out.t, 0.0))
    rms = out.rms
    if isinstance(camera.dist, jax.core.Tracer) or camera.has_distortion():
        d = camera.project_body(pose, points_body) - pixels
        e2 = jnp.where(inliers, jnp.sum(d * d, axis=-1), 0.0)
        rms = jnp.sqrt(jnp.sum(e2) / jnp.maximum(jnp.sum(inliers), 1).astype(dtype))
    rms = jnp.where(ok, rms, jnp.inf)
    return PnPResult(
        pose=pose, status=status, reprojection_error=rms, inliers=inliers, planar=out.planar
    )


def _input_status(status, finite, valid_count, min_points):
    return jnp.select(
        [~finite, valid_count < min_points], [Status.NONFINITE_INPUT, Status.TOO_FEW_POINTS], status
    ).astype(jnp.int32)


class _Problem(eqx.Module):
    """One problem ready for a solver core: finite, masked, normalised."""

    points_body: Array  # (n, 3), zero where invalid
    pixels: Array  # (n, 2) as given
    xy: Array  # (n, 2) normalised undistorted coordinates, zero where invalid
    valid: Array  # (n,) bool
    finite: Array  # bool: every valid entry is finite
    fxy: Array  # (2,) focal lengths
    camera: PinholeCamera


def _problem(points_body, pixels, camera, mask, name, undistort=None) -> _Problem:
    points_body, pixels, camera, valid = _prepare(points_body, pixels, camera, mask, name)
    xy = _normalized(camera, pixels, undistort)
    pw, xy, finite = _sanitize(valid, points_body, xy)
    return _Problem(pw, pixels, xy, valid, finite, jnp.stack([camera.fx, camera.fy]), camera)


def _solve(prob: _Problem, method: str, planar_tol: float, key=None, ransac=None):
    """Run a solver core; returns the :class:`PnPResult` and the core's output (plane etc.)."""
    weights = prob.valid.astype(prob.points_body.dtype)
    inliers = prob.valid
    if method == "epnp":
        out = _epnp_core(prob.points_body, prob.xy, weights, prob.fxy, planar_tol)
        min_points = MIN_POINTS
    elif method == "dlt":
        out = _dlt_core(prob.points_body, prob.xy, weights, prob.fxy, planar_tol)
        min_points = DLT_MIN_POINTS
    else:
        out, inliers = _ransac_core(prob, key, planar_tol=planar_tol, **ransac)
        min_points = ransac["sample_size"]
    status = _input_status(out.status, prob.finite, jnp.sum(prob.valid), min_points)
    res = _finish(out, status, inliers, prob.points_body, prob.pixels, prob.camera)
    return res, out


def epnp(
    points_body: Float[Array, "n 3"],
    pixels: Float[Array, "n 2"],
    camera: PinholeCamera | Float[Array, "3 3"],
    *,
    mask: Bool[Array, " n"] | None = None,
    planar_tol: float = PLANAR_TOL,
) -> PnPResult:
    """EPnP pose of one problem (Lepetit et al. 2009; Sharma et al. 2018, eqs. 17-22).

    Args:
        points_body: ``(n, 3)`` points in the target body frame, metres (``n >= 4``).
        pixels: ``(n, 2)`` measured (distorted) pixels; undistorted with ``camera.normalize``.
        camera: :class:`~jaxpose.core.camera.PinholeCamera` or a ``3 x 3`` ``K``.
        mask: ``(n,)`` bool, the valid points of a padded set (default: all).
        planar_tol: planarity threshold on ``sqrt(l3 / l1)`` of the centred points' scatter.

    Returns:
        :class:`PnPResult`; ``status`` is ``TOO_FEW_POINTS`` (fewer than 4 valid points),
        ``NONFINITE_INPUT``, ``DEGENERATE`` (collinear or coincident points), ``NO_SOLUTION``
        or ``BEHIND_CAMERA`` (a valid point at or behind the camera in the solution).
        ``reprojection_error`` is the RMS over the valid points, pixels.

    Pure JAX: ``jax.jit(jax.vmap(epnp, in_axes=(0, 0, None)))`` solves a batch. Not meant to
    be differentiated (the closed form has branches and repeated eigenvalues); derivatives of
    a pose come from :func:`jaxpose.core.refine.refine_pose` / :func:`jaxpose.solve_pnp` with
    refinement, by implicit differentiation at the optimum.
    """
    prob = _problem(points_body, pixels, camera, mask, "epnp")
    return _solve(prob, "epnp", planar_tol)[0]


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


# ----------------------------------------------------------------------------- DLT


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
    points_body: Float[Array, "n 3"],
    pixels: Float[Array, "n 2"],
    camera: PinholeCamera | Float[Array, "3 3"],
    *,
    mask: Bool[Array, " n"] | None = None,
    planar_tol: float = PLANAR_TOL,
) -> PnPResult:
    """Direct linear transform for ``>= 6`` non-coplanar points (one problem).

    The ``3 x 4`` matrix ``P ~ [R | t]`` in normalised image coordinates is the right singular
    vector of the ``2n x 12`` system (3-D points centred and scaled first, Hartley); ``R`` is the
    closest rotation to its left ``3 x 3`` block (SVD), ``t`` its last column over the mean
    singular value. Coplanar points give ``DEGENERATE`` (use :func:`epnp`), fewer than six valid
    points ``TOO_FEW_POINTS``.
    """
    prob = _problem(points_body, pixels, camera, mask, "dlt")
    return _solve(prob, "dlt", planar_tol)[0]


# ----------------------------------------------------------------------------- RANSAC


def ransac_iterations(confidence: float, inlier_fraction: float, sample_size: int = 6) -> int:
    """Number of random hypotheses of Sharma et al. 2018, eq. 35: ``log(1-p) / log(1-w^s)``.

    ``confidence`` is ``p``, the probability that at least one sample is outlier-free;
    ``inlier_fraction`` is eq. 35's ``w / (m n)`` (with known correspondences, the fraction of
    correct ones); ``sample_size`` is the exponent (6 in the paper: EPnP on six points).
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1); got {confidence}")
    if not 0.0 < inlier_fraction <= 1.0:
        raise ValueError(f"inlier_fraction must be in (0, 1]; got {inlier_fraction}")
    if sample_size < 1:
        raise ValueError(f"sample_size must be positive; got {sample_size}")
    good = inlier_fraction**sample_size
    if good >= 1.0:
        return 1
    return max(1, math.ceil(math.log(1.0 - confidence) / math.log1p(-good)))


def _ransac_options(threshold_px, confidence, max_outlier_fraction, sample_size, num_hypotheses):
    """Validated static RANSAC options (``ValueError`` at trace time)."""
    if not threshold_px > 0:
        raise ValueError(f"threshold_px must be positive; got {threshold_px}")
    if not 0.0 <= max_outlier_fraction < 1.0:
        raise ValueError(f"max_outlier_fraction must be in [0, 1); got {max_outlier_fraction}")
    if sample_size < MIN_POINTS:
        raise ValueError(f"sample_size must be at least {MIN_POINTS}; got {sample_size}")
    if num_hypotheses is None:
        num_hypotheses = ransac_iterations(confidence, 1.0 - max_outlier_fraction, sample_size)
    if int(num_hypotheses) < 1:
        raise ValueError(f"num_hypotheses must be positive; got {num_hypotheses}")
    return {
        "threshold_px": float(threshold_px),
        "sample_size": int(sample_size),
        "num_hypotheses": int(num_hypotheses),
    }


def _ransac_core(prob: _Problem, key, *, threshold_px, sample_size, num_hypotheses, planar_tol):
    pw, xy, valid, fxy = prob.points_body, prob.xy, prob.valid, prob.fxy
    n = pw.shape[0]
    if n < sample_size:
        raise ValueError(f"ransac_pnp needs at least sample_size={sample_size} points; got n={n}")
    dtype = pw.dtype
    u = jax.random.uniform(key, (num_hypotheses, n), dtype=dtype)
    u = jnp.where(valid, u, 2.0)
    _, idx = lax.top_k(-u, sample_size)  # (k, s): samples without replacement among the valid
    sw = valid[idx].astype(dtype)
    hyp = jax.vmap(lambda i, w: _epnp_core(pw[i], xy[i], w, fxy, planar_tol))(idx, sw)
    thr2 = jnp.asarray(threshold_px, dtype) ** 2

    def score(R, t):
        cam = _mm(pw, R.T) + t
        z = cam[:, 2]
        front = z > 0
        d = (cam[:, :2] / jnp.where(front, z, 1.0)[:, None] - xy) * fxy
        e2 = d[:, 0] ** 2 + d[:, 1] ** 2
        inl = valid & front & (e2 < thr2)
        # MSAC's truncated cost, scaled below 1 so that it only breaks ties of the inlier count
        cost = jnp.sum(jnp.where(valid, jnp.where(inl, e2, thr2), 0.0)) / (n * thr2 + 1.0)
        return inl, jnp.sum(inl), cost

    inl, cnt, cost = jax.vmap(score)(hyp.R, hyp.t)
    ok_h = hyp.status == Status.OK
    best = jnp.argmax(jnp.where(ok_h, cnt.astype(dtype) - cost, -1.0))
    inl_best, cnt_best = inl[best], cnt[best]
    final = _epnp_core(pw, xy, inl_best.astype(dtype), fxy, planar_tol)
    inl_f, cnt_f, _ = score(final.R, final.t)
    use_final = (final.status == Status.OK) & (cnt_f >= cnt_best)
    chosen = jax.tree.map(lambda a, b: jnp.where(use_final, a, b[best]), final, hyp)
    inliers = jnp.where(use_final, inl_f, inl_best)
    rms = _rms_px(_mm(pw, chosen.R.T) + chosen.t, xy, inliers.astype(dtype), fxy)
    enough = jnp.any(ok_h) & (jnp.sum(inliers) >= sample_size)
    status = jnp.where(enough, chosen.status, Status.NO_SOLUTION).astype(jnp.int32)
    return eqx.tree_at(lambda o: (o.status, o.rms), chosen, (status, rms)), inliers


def ransac_pnp(
    points_body: Float[Array, "n 3"],
    pixels: Float[Array, "n 2"],
    camera: PinholeCamera | Float[Array, "3 3"],
    *,
    key: Array,
    mask: Bool[Array, " n"] | None = None,
    threshold_px: float = 8.0,
    confidence: float = 0.999,
    max_outlier_fraction: float = 0.5,
    sample_size: int = 6,
    num_hypotheses: int | None = None,
    planar_tol: float = PLANAR_TOL,
) -> PnPResult:
    """RANSAC over EPnP for one problem whose correspondences hold outliers.

    ``num_hypotheses`` (default: :func:`ransac_iterations` of ``confidence`` and
    ``1 - max_outlier_fraction``: 439 for 50% outliers, ``p = 0.999`` and 6-point samples)
    minimal samples are drawn among the valid points, EPnP solves all of them in one
    ``vmap``-ed call, and each hypothesis is scored by its inliers (reprojection error below
    ``threshold_px``, in front of the camera), ties broken by the truncated squared error (MSAC).
    EPnP on the inliers of the best hypothesis gives the pose, kept if it has at least as many
    inliers. ``inliers`` of the result marks them and ``reprojection_error`` is their RMS;
    ``NO_SOLUTION`` when fewer than ``sample_size`` inliers remain.
    """
    opts = _ransac_options(
        threshold_px, confidence, max_outlier_fraction, sample_size, num_hypotheses
    )
    prob = _problem(points_body, pixels, camera, mask, "ransac_pnp")
    return _solve(prob, "ransac", planar_tol, key=key, ransac=opts)[0]
