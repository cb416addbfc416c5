"""Shared pieces of the selection methods: argument checks, the packed 21-entry layout of a
symmetric ``6 x 6`` information matrix, and a LAPACK-free kernel for the two DOP traces.

The kernel works on *structure-of-arrays* data: each of the 21 unique entries of ``A = H^T W H``
is an array over a batch (subsets x cases), so XLA evaluates one fused elementwise program over
the whole batch instead of calling LAPACK once per ``6 x 6`` matrix.

With ``A = [[P, B], [B^T, C]]`` (``P`` position, ``C`` attitude, each ``3 x 3``) and ``Q = A^-1``:

* ``Q_aa = (C - B^T P^-1 B)^-1``: with ``adj(P)`` and ``det P`` this is ``det(P) T^-1`` where
  ``T = det(P) C - B^T adj(P) B``, so ``trace(Q_aa) = det(P) trace(adj T) / det T``;
* ``Q_pp = P^-1 + G Q_aa G^T`` with ``G = P^-1 B``, so ``trace(Q_pp) = trace(adj P) / det P +
  <G'^T G', adj T> / (det P det T)`` with ``G' = adj(P) B``.

Both traces are sums of positive terms (no cancellation in the last step); only two divisions
per matrix. Inputs are scaled first by one factor for the position rows and one for the attitude
rows (:func:`block_scales`) so that every entry is of order one whatever the units, which keeps
the determinants (degree up to 12 in the entries) far from overflow.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from jaxpose.core._checks import as_bool_mask
from jaxpose.core.dilution import MIN_POINTS, dop_from_information

__all__ = [
    "PAIRS",
    "block_scales",
    "check_blocks",
    "check_m",
    "too_few_valid",
    "pack",
    "subset_dop",
    "traces",
]

PAIRS: tuple[tuple[int, int], ...] = tuple((i, j) for i in range(6) for j in range(i, 6))
"""The 21 upper-triangular ``(row, column)`` pairs of a symmetric ``6 x 6``, in packed order."""

_ROWS = np.array([p[0] for p in PAIRS])
_COLS = np.array([p[1] for p in PAIRS])


def check_m(m, n: int, what: str = "selection") -> int:
    """``m`` must be a Python int with ``MIN_POINTS <= m <= n`` (it fixes output shapes)."""
    if isinstance(m, bool) or not isinstance(m, int | np.integer):
        raise ValueError(f"{what}: m must be a Python int (it is static); got {type(m).__name__}")
    m = int(m)
    if m < MIN_POINTS:
        raise ValueError(
            f"{what}: m = {m}, but at least {MIN_POINTS} points are needed for a non-singular H^T H"
        )
    if m > n:
        raise ValueError(f"{what}: cannot select m = {m} of only n = {n} points")
    return m


def too_few_valid(valid, m: int, what: str) -> ValueError:
    """The ``ValueError`` of an eager selection whose ``mask`` leaves fewer than ``m`` valid
    points (``valid`` concrete): it names ``mask`` and ``m`` and gives the counts."""
    valid = np.asarray(valid)
    return ValueError(
        f"{what}: too few valid points: mask leaves {int(valid.sum())} of the n = {valid.size} "
        f"points valid, fewer than m = {m} (unmask more points or lower m)"
    )


def check_blocks(blocks, what: str, *, batched: bool = False) -> Array:
    """Information blocks ``(n, 6, 6)`` (or ``(C, n, 6, 6)`` when ``batched``), floating."""
    blocks = jnp.asarray(blocks)
    if not jnp.issubdtype(blocks.dtype, jnp.floating):
        blocks = blocks.astype(jnp.result_type(float))
    want = "(C, n, 6, 6)" if batched else "(n, 6, 6)"
    if blocks.ndim != (4 if batched else 3) or blocks.shape[-2:] != (6, 6):
        hint = "" if batched else " (one problem; use jax.vmap or exhaustive_batch for batches)"
        raise ValueError(
            f"{what}: information blocks must have shape {want}{hint}; got {blocks.shape}"
        )
    return blocks


def check_mask(mask, shape: tuple[int, ...], what: str) -> Array | None:
    if mask is None:
        return None
    if jnp.shape(mask) != shape:
        raise ValueError(f"{what}: mask must have shape {shape}; got {jnp.shape(mask)}")
    return as_bool_mask(mask, f"{what}: mask")


def pack(A: Float[Array, "... 6 6"]) -> Float[Array, "... 21"]:
    """The 21 unique entries of symmetric ``6 x 6`` matrices, in :data:`PAIRS` order."""
    return A[..., _ROWS, _COLS]


def block_scales(A: Float[Array, "... 6 6"]) -> tuple[Array, Array]:
    """Mean diagonal of the position and of the attitude block (one positive scale each).

    Dividing the position rows and columns by ``sqrt(s_p)`` and the attitude ones by ``sqrt(s_a)``
    makes the entries of order one; then ``trace(Q_pp) = trace(Q'_pp) / s_p`` exactly.
    """
    d = jnp.diagonal(A, axis1=-2, axis2=-1)
    tiny = jnp.finfo(A.dtype).tiny
    s_p = jnp.sum(d[..., :3], axis=-1) / 3.0
    s_a = jnp.sum(d[..., 3:], axis=-1) / 3.0
    ok = jnp.isfinite(s_p) & jnp.isfinite(s_a) & (s_p > tiny) & (s_a > tiny)
    one = jnp.ones_like(s_p)
    return jnp.where(ok, s_p, one), jnp.where(ok, s_a, one)


def scale_packed(packed: Float[Array, "... 21"], s_p: Array, s_a: Array) -> Float[Array, "... 21"]:
    """Apply :func:`block_scales` to packed entries (``s_p``, ``s_a`` broadcast over ``...``)."""
    r_p, r_a = 1.0 / jnp.sqrt(s_p), 1.0 / jnp.sqrt(s_a)
    factors = [(r_p if i < 3 else r_a) * (r_p if j < 3 else r_a) for i, j in PAIRS]
    return packed * jnp.stack(factors, axis=-1)


def singular_tolerance(dtype) -> float:
    """Relative eigenvalue threshold of a singular matrix (as in ``dop_from_information``)."""
    return 1e3 * float(jnp.finfo(dtype).eps)


def traces(
    a: list[Array] | tuple[Array, ...], *, tol: float | None = None
) -> tuple[Array, Array, Array]:
    """``trace(Q_pp)``, ``trace(Q_aa)`` and a validity flag from the 21 packed entries.

    ``a`` holds 21 same-shaped arrays (:data:`PAIRS` order), ideally scaled to order one. The flag
    is false for a singular or numerically indefinite matrix: ``det P <= 0``, ``det T <= 0``, a
    non-finite or non-positive trace, or ``trace(Q) trace(A) >= 1 / tol`` (since ``trace(Q) >=
    1 / lambda_min`` and ``trace(A) >= lambda_max``, every matrix with ``lambda_min <= tol
    lambda_max`` is flagged). The traces are meaningless where the flag is false.
    """
    e = dict(zip(PAIRS, a, strict=True))

    def g(i, j):
        return e[(i, j)] if i <= j else e[(j, i)]

    P = [[g(i, j) for j in range(3)] for i in range(3)]
    C = [[g(i + 3, j + 3) for j in range(3)] for i in range(3)]
    B = [[g(i, j + 3) for j in range(3)] for i in range(3)]  # B[i][j] = A[i, 3 + j]

    def adj_sym(M):
        a00 = M[1][1] * M[2][2] - M[1][2] * M[1][2]
        a01 = M[0][2] * M[1][2] - M[0][1] * M[2][2]
        a02 = M[0][1] * M[1][2] - M[0][2] * M[1][1]
        a11 = M[0][0] * M[2][2] - M[0][2] * M[0][2]
        a12 = M[0][1] * M[0][2] - M[0][0] * M[1][2]
        a22 = M[0][0] * M[1][1] - M[0][1] * M[0][1]
        det = M[0][0] * a00 + M[0][1] * a01 + M[0][2] * a02
        return [[a00, a01, a02], [a01, a11, a12], [a02, a12, a22]], det

    Pa, detP = adj_sym(P)
    G = [
        [Pa[i][0] * B[0][j] + Pa[i][1] * B[1][j] + Pa[i][2] * B[2][j] for j in range(3)]
        for i in range(3)
    ]
    T = [[None] * 3 for _ in range(3)]
    for i in range(3):
        for j in range(i, 3):
            T[i][j] = T[j][i] = detP * C[i][j] - (
                B[0][i] * G[0][j] + B[1][i] * G[1][j] + B[2][i] * G[2][j]
            )
    Ta, detT = adj_sym(T)
    inv_detP = 1.0 / detP
    inv_detT = 1.0 / detT
    t_aa = detP * (Ta[0][0] + Ta[1][1] + Ta[2][2]) * inv_detT

    def gg(i, j):
        return G[0][i] * G[0][j] + G[1][i] * G[1][j] + G[2][i] * G[2][j]

    quad = (
        gg(0, 0) * Ta[0][0]
        + gg(1, 1) * Ta[1][1]
        + gg(2, 2) * Ta[2][2]
        + 2.0 * (gg(0, 1) * Ta[0][1] + gg(0, 2) * Ta[0][2] + gg(1, 2) * Ta[1][2])
    )
    t_pp = (Pa[0][0] + Pa[1][1] + Pa[2][2]) * inv_detP + quad * (inv_detP * inv_detT)
    trace_A = P[0][0] + P[1][1] + P[2][2] + C[0][0] + C[1][1] + C[2][2]
    if tol is None:
        tol = singular_tolerance(detP.dtype)
    total = t_pp + t_aa
    ok = (
        (detP > 0)
        & (detT > 0)
        & (t_pp > 0)
        & (t_aa > 0)
        & jnp.isfinite(total)
        & (total * trace_A < 1.0 / tol)
    )
    return t_pp, t_aa, ok


def subset_dop(blocks: Float[ArrayLike, "n 6 6"], idx) -> tuple[Array, Array]:
    """PDOP and ADOP of the subset ``idx`` of points (``inf`` when singular).

    Args:
        blocks: ``(n, 6, 6)`` per-point information blocks from
            :func:`jaxpose.core.dilution.information_blocks`.
        idx: ``(m,)`` integer indices into the ``n`` points.

    Returns:
        ``(pdop, adop)`` of ``sum_i blocks[idx_i]`` by
        :func:`jaxpose.core.dilution.dop_from_information` (metres and radians per pixel of noise).

    Raises:
        ValueError: ``idx`` not 1-D integers or of fewer than 4 indices (a DOP needs at least 4
        points, as :func:`jaxpose.core.dilution.dop`, whose status is ``TOO_FEW_POINTS`` then;
        ``subset_dop`` has no status, and the length is known when it is traced, so this holds
        under ``jit`` too), or (eager) an index outside ``[0, n)`` or repeated (a repeated point
        would count twice); under ``jit`` such indices give ``inf``.
    """
    blocks = check_blocks(blocks, "subset_dop")
    idx = jnp.asarray(idx)
    if idx.ndim != 1 or not jnp.issubdtype(idx.dtype, jnp.integer):
        raise ValueError(f"subset_dop: idx must be a 1-D integer array; got {idx.dtype}{idx.shape}")
    if idx.shape[0] < MIN_POINTS:
        raise ValueError(
            f"subset_dop: idx must hold at least {MIN_POINTS} indices (a DOP needs at least "
            f"{MIN_POINTS} points); got {idx.shape[0]}"
        )
    n = blocks.shape[0]
    inside = (idx >= 0) & (idx < n)
    ordered = jnp.sort(idx)
    distinct = jnp.all(ordered[1:] != ordered[:-1])
    if not isinstance(idx, jax.core.Tracer):
        if not bool(jnp.all(inside)):
            raise ValueError(
                f"subset_dop: idx must hold indices in [0, {n}); got {np.asarray(idx).tolist()}"
            )
        if not bool(distinct):
            values, counts = np.unique(np.asarray(idx), return_counts=True)
            raise ValueError(
                "subset_dop: idx must hold distinct indices (a repeated point would count "
                f"twice); got {np.asarray(idx).tolist()}, repeating {values[counts > 1].tolist()}"
            )
    # Traced: an index out of range or repeated makes the subset's figures inf (never a clamped
    # index, never a point counted twice).
    res = dop_from_information(jnp.sum(blocks[jnp.where(inside, idx, 0)], axis=0))
    ok = jnp.all(inside) & distinct
    inf = jnp.asarray(jnp.inf, res.pdop.dtype)
    return jnp.where(ok, res.pdop, inf), jnp.where(ok, res.adop, inf)


def n_subsets(n: int, m: int) -> int:
    return math.comb(n, m)
