"""Small dense algebra for the PnP solvers, written out entry by entry (pure JAX).

Tiny matrix products, eigenproblems and solves as sums of broadcast products and element-wise
updates. Under ``vmap`` they become fused element-wise loops over the batch; XLA's CPU dot and
reduce kernels on 4 x 4 blocks (and one LAPACK call per problem for ``eigh``/``svd``) are 5-20x
slower here (measured with ``bench/pnp.py``).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Float

from jaxpose.core.geometry import quat_to_dcm

_JACOBI_SWEEPS = 5  # cyclic Jacobi on <= 4 x 4: converged to rounding (see _jacobi4)
_SQUARINGS = 32  # repeated squaring for a top eigenvector (see _top_eigenvector)


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
    body serves every round (``3 * sweeps`` rounds). Quadratic convergence: on 2000 random
    symmetric matrices the largest residual ``|A v - l v| / (1 + |A|)`` is 2.6e-11 after 4
    sweeps and 1.4e-15 after 5, which are done (stopping early on convergence saved nothing
    measurable under ``vmap``).
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


def _top_eigenvector(A: Float[Array, "... k k"], squarings: int = _SQUARINGS):
    """Unit eigenvector of the largest eigenvalue of a small symmetric matrix.

    Power iteration by repeated squaring: ``M = A + |A|_F I`` is positive semidefinite with the
    same eigenvectors, and ``M^(2^s)`` (scaled to unit trace after each squaring) tends to
    ``v v^T``; its column of largest diagonal entry, normalised, is ``v``. The error falls as
    ``r^(2^s)`` with ``r = (l2 + c) / (l1 + c)`` the ratio of the two largest shifted
    eigenvalues: 32 squarings (``M^(2^32)``) reach the accuracy of a Jacobi eigensolver down to a
    relative gap of about ``1e-7`` (Horn's matrix of points spread a thousand times less across
    than along; measured against the Jacobi solver). Without square roots or divisions per
    entry it costs about a quarter of the Jacobi solver under ``vmap``.
    A zero matrix gives the first axis.
    """
    k = A.shape[-1]
    eye = jnp.eye(k, dtype=A.dtype)
    M = A + jnp.sqrt(jnp.sum(A * A, axis=(-2, -1)))[..., None, None] * eye

    def square(_, M):
        M = _mm(M, M)
        trace = sum(M[..., i, i] for i in range(k))
        return M / jnp.where(trace > 0, trace, 1.0)[..., None, None]

    M = lax.fori_loop(0, squarings, square, M)
    pick = _argmin_onehot(-jnp.stack([M[..., i, i] for i in range(k)], axis=-1))
    v = sum(pick[..., j, None] * M[..., :, j] for j in range(k))
    norm = jnp.sqrt(jnp.sum(v * v, axis=-1, keepdims=True))
    return jnp.where(norm > 0, v / jnp.where(norm > 0, norm, 1.0), eye[0])


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
    R = quat_to_dcm(_top_eigenvector(N))
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
