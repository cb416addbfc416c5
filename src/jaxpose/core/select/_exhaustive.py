"""Exhaustive DOP-optimal subsets (Ning, Zhang, Wang 2018, Sec. 4, "optimal method").

Every ``C(n, m)`` subset of the points is scored; the one of minimum PDOP and, separately, the one
of minimum ADOP are returned. The subsets are visited in lexicographic order
(``itertools.combinations``) by a ``lax.scan`` over chunks of ranks; each chunk is *unranked*
in-kernel (combinatorial number system), so memory stays bounded for any ``n, m`` and no table
of combinations is ever stored.

How one chunk is scored (see :mod:`jaxpose.core.select._kernel`):

1. the 21 unique entries of every per-point block are packed and scaled (one factor for position,
   one for attitude) so that they are of order one;
2. the subset sums are a single matrix product: the ``(chunk, n)`` 0/1 membership matrix of the
   chunk against the ``(21 C, n)`` packed blocks of all ``C`` cases at once;
3. ``trace(Q_pp)`` and ``trace(Q_aa)`` follow from closed-form ``3 x 3`` adjugates (two Schur
   complements, two divisions per subset, no LAPACK), evaluated as one fused elementwise program
   on structure-of-arrays data.

The winners are re-scored with :func:`jaxpose.core.select.subset_dop` (i.e.
:func:`jaxpose.core.dilution.dop_from_information`) so their DOP is exactly what every other method
reports for the same subset. Singular subsets score ``inf`` and never win; ties go to the subset
first in lexicographic order.

``kernel_dtype=jnp.float32`` scores in single precision and keeps, per case and criterion, the
winner and the runner-up score; the winner is re-scored in float64 and certified when it beats the
float32 runner-up by more than the float32 error margin (:data:`FLOAT32_MARGIN`). Cases that are
not certified (near-ties) are searched again in float64, so the answer is the float64 optimum
either way.
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_batching import custom_vmap
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from jaxpose.core.select._kernel import (
    block_scales,
    check_blocks,
    check_m,
    check_mask,
    pack,
    scale_packed,
    singular_tolerance,
    subset_dop,
    traces,
)
from jaxpose.core.status import Status, check_throw, throw_for_status

__all__ = [
    "ExhaustiveResult",
    "exhaustive",
    "exhaustive_batch",
    "MAX_SUBSETS",
    "subsets_count",
    "unrank_combinations",
]

MAX_SUBSETS = 1_000_000_000
"""Most subsets per case that :func:`exhaustive` and :func:`exhaustive_batch` score unless told
otherwise (``max_subsets=``): the kernel scores 1-2 x 10^7 subsets per CPU-second, so a case at
the limit takes about a minute; ``C(40, 20) = 1.4e11`` would take hours. Above it they raise
``ValueError`` and point to :func:`~jaxpose.core.select.branch_and_bound`, which finds the same
optimum without enumerating every subset."""

_TARGET_ELEMENTS = 1 << 15
"""Default work per scan step: ``chunk x C`` subset evaluations (tuned in bench/selection.py)."""


class ExhaustiveResult(eqx.Module):
    """Result of :func:`exhaustive` (leading batch axes under ``vmap`` / :func:`exhaustive_batch`).

    Attributes:
        pdop_idx: ``(m,)`` indices (ascending) of the minimum-PDOP subset.
        pdop: its PDOP (metres per pixel), ``inf`` when the status is not OK.
        adop_idx: ``(m,)`` indices (ascending) of the minimum-ADOP subset.
        adop: its ADOP (radians per pixel), ``inf`` when the status is not OK.
        status: ``int32`` :class:`~jaxpose.core.status.Status`: ``OK``; ``NONFINITE_INPUT``
            for NaN/inf in a valid block; ``TOO_FEW_POINTS`` when fewer than ``m`` points are valid;
            ``SINGULAR`` when every subset is singular.
    """

    pdop_idx: Int[Array, "... m"]
    pdop: Float[Array, " ..."]
    adop_idx: Int[Array, "... m"]
    adop: Float[Array, " ..."]
    status: Int[Array, " ..."]


def subsets_count(n: int, m: int) -> int:
    """``C(n, m)``: how many subsets the exhaustive search scores."""
    return math.comb(n, m)


def check_subsets(n: int, m: int, max_subsets: int | None, what: str = "exhaustive") -> None:
    """Refuse a search over more than ``max_subsets`` subsets (``None``: no limit)."""
    count = math.comb(n, m)
    if max_subsets is not None and count > max_subsets:
        raise ValueError(
            f"{what}: n = {n}, m = {m} gives C({n}, {m}) = {count:.3g} subsets, above the "
            f"limit max_subsets = {max_subsets:.3g} (hours of work); use branch_and_bound "
            f"(the same optimum without enumerating every subset), a smaller n or an m nearer "
            f"to 4 or n, or raise max_subsets"
        )


def _rank_dtype():
    return jnp.int64 if jax.config.jax_enable_x64 else jnp.int32


def unrank_combinations(ranks: Int[ArrayLike, " ..."], n: int, m: int) -> Int[Array, "... m"]:
    """The ``m``-subsets of ``range(n)`` of the given lexicographic ranks (ascending indices).

    Rank ``r`` is the position of the subset in ``itertools.combinations(range(n), m)``. Uses the
    combinatorial number system: the lexicographic rank ``r`` of ``c`` is the colexicographic rank
    ``C(n, m) - 1 - r`` of ``d = {n - 1 - c_i}``, and ``d`` is unranked greedily from its largest
    element (``d_k`` is the largest ``d`` with ``C(d, k + 1) <= rest``). ``O(m n)`` comparisons
    per rank, all vectorised.
    """
    if not 1 <= m <= n:
        raise ValueError(f"unrank_combinations needs 1 <= m <= n; got n = {n}, m = {m}")
    idt = _rank_dtype()
    total = math.comb(n, m)
    rest = (total - 1) - jnp.asarray(ranks, dtype=idt)
    out = []
    for k in range(m, 0, -1):
        table = jnp.asarray([math.comb(c, k) for c in range(n)], dtype=idt)
        d = jnp.sum(table <= rest[..., None], axis=-1, dtype=idt) - 1
        rest = rest - table[d]
        out.append((n - 1) - d)
    return jnp.stack(out, axis=-1).astype(jnp.int32)


def _chunk(C: int, K: int, chunk_size: int | None) -> int:
    if chunk_size is not None:
        if int(chunk_size) < 1:
            raise ValueError(f"chunk_size must be positive; got {chunk_size}")
        chunk = int(chunk_size)
    else:
        want = max(1, _TARGET_ELEMENTS // max(C, 1))
        chunk = 1 << max(4, min(14, (want - 1).bit_length()))
    return max(1, min(chunk, -(-K // 8) * 8))


def _prepare(blocks, valid, kdt):
    """Scaled, packed, transposed blocks ``(21, C, n)`` and per-case scales and checks."""
    finite = jnp.all(jnp.isfinite(blocks) | ~valid[..., None, None], axis=(1, 2, 3))
    use = valid & finite[:, None]
    blocks = jnp.where(use[..., None, None], blocks, 0.0)
    s_p, s_a = block_scales(jnp.sum(blocks, axis=1))
    packed = scale_packed(pack(blocks), s_p[:, None], s_a[:, None])
    return jnp.transpose(packed, (2, 0, 1)).astype(kdt), finite


def _score_chunk(Fl, invalid, start, chunk, n, m, K, tol):
    """Scaled ``trace(Q_pp)``, ``trace(Q_aa)`` of the ``chunk`` ranks from ``start`` (inf: bad)."""
    idt = _rank_dtype()
    kdt = Fl.dtype
    ranks = start + jnp.arange(chunk, dtype=idt)
    in_range = ranks < K
    combos = unrank_combinations(jnp.minimum(ranks, K - 1), n, m)
    member = jnp.any(combos[:, :, None] == jnp.arange(n, dtype=jnp.int32), axis=1).astype(kdt)
    sums = jnp.einsum("kcn,sn->kcs", Fl, member)
    t_pp, t_aa, ok = traces([sums[k] for k in range(21)], tol=tol)
    good = ok & in_range[None, :]
    if invalid is not None:
        good = good & (jnp.einsum("cn,sn->cs", invalid.astype(kdt), member) == 0)
    inf = jnp.asarray(jnp.inf, kdt)
    return jnp.where(good, t_pp, inf), jnp.where(good, t_aa, inf), ranks


def _scan(Fl, invalid, n, m, K, chunk, tol, runner_up: bool):
    """Score every subset: per case and criterion, the minimum and its lexicographic rank (ties:
    lowest rank) and, with ``runner_up``, the second-lowest score (of a different subset)."""
    idt = _rank_dtype()
    C = Fl.shape[1]

    def update(carry, values, ranks):
        best, rank = carry[:2]
        j = jnp.argmin(values, axis=1)
        v = jnp.take_along_axis(values, j[:, None], axis=1)[:, 0]
        better = v < best
        new = (jnp.where(better, v, best), jnp.where(better, ranks[j], rank))
        if not runner_up:
            return new
        second = jnp.min(jnp.where(jnp.arange(values.shape[1]) == j[:, None], jnp.inf, values), 1)
        return (*new, jnp.where(better, jnp.minimum(best, second), jnp.minimum(carry[2], v)))

    def body(carry, step):
        p, a, ranks = _score_chunk(Fl, invalid, step * chunk, chunk, n, m, K, tol)
        return (update(carry[0], p, ranks), update(carry[1], a, ranks)), None

    init = (jnp.full((C,), jnp.inf, Fl.dtype), jnp.zeros((C,), idt))
    if runner_up:
        init = (*init, init[0])
    steps = -(-K // chunk)
    (cp, ca), _ = jax.lax.scan(body, (init, init), jnp.arange(steps, dtype=idt))
    return cp, ca


FLOAT32_MARGIN = 1e-4
"""Relative error margin of float32 scores used to certify the float64 optimum.

Measured by ``bench_float32_error`` in bench/selection.py (``n = 14, m = 8``, every subset, ranges
3-300 m): float32 scores within about 1e-4 of float64 in the worst subset and within about 1e-6
for the optimal ones, which are well conditioned."""


def _recheck(F64, invalid, rank, runner_up, n, m, which):
    """Full-precision score of the float32 winner, and whether it is certified optimal.

    Every other subset scored at least ``runner_up`` in float32, hence at least ``runner_up / (1
    + margin)`` in full precision; the winner is certified when its own full-precision score is
    below that. An infinite runner-up certifies nothing: subsets that float32 flags as singular
    may be merely ill-conditioned in float64, so such cases are searched again.
    """
    member = jnp.any(
        unrank_combinations(rank, n, m)[..., None] == jnp.arange(n, dtype=jnp.int32), axis=-2
    )
    sums = jnp.einsum("lcn,cn->lc", F64, member.astype(F64.dtype))
    t_pp, t_aa, ok = traces([sums[i] for i in range(21)])
    if invalid is not None:
        ok = ok & ~jnp.any(invalid & member, axis=-1)
    best = jnp.where(ok, (t_pp, t_aa)[which], jnp.inf)
    runner_up = runner_up.astype(F64.dtype)
    return (best * (1.0 + FLOAT32_MARGIN) < runner_up) & jnp.isfinite(runner_up)


def _search(blocks, valid, invalid, n, m, K, chunk_size, kdt):
    """Lexicographic ranks of the minimum-PDOP and minimum-ADOP subsets of each case."""
    dtype = blocks.dtype
    C = blocks.shape[0]
    Fl, finite = _prepare(blocks, valid, kdt)
    tol = singular_tolerance(dtype)
    if jnp.finfo(kdt).bits >= jnp.finfo(dtype).bits:
        (_, rank_p), (_, rank_a) = _scan(Fl, invalid, n, m, K, _chunk(C, K, chunk_size), tol, False)
        return rank_p, rank_a, finite

    (_, rank_p, second_p), (_, rank_a, second_a) = _scan(
        Fl, invalid, n, m, K, _chunk(C, K, chunk_size), tol, True
    )
    F64, _ = _prepare(blocks, valid, dtype)
    sure = _recheck(F64, invalid, rank_p, second_p, n, m, 0)
    sure = sure & _recheck(F64, invalid, rank_a, second_a, n, m, 1)
    # Uncertified cases are searched again in full precision: up to U of them gathered into a
    # small batch, or the whole batch when more need it.
    count = jnp.sum(~sure)
    U = max(1, -(-C // 8))

    def redo_some(_):
        (which,) = jnp.nonzero(~sure, size=U, fill_value=0)
        sub_invalid = None if invalid is None else invalid[which]
        (_, fp), (_, fa) = _scan(
            F64[:, which], sub_invalid, n, m, K, _chunk(U, K, chunk_size), tol, False
        )
        which = jnp.where(jnp.arange(U) < count, which, C)  # unused slots: dropped
        return rank_p.at[which].set(fp, mode="drop"), rank_a.at[which].set(fa, mode="drop")

    def redo_all(_):
        (_, fp), (_, fa) = _scan(F64, invalid, n, m, K, _chunk(C, K, chunk_size), tol, False)
        return jnp.where(sure, rank_p, fp), jnp.where(sure, rank_a, fa)

    def keep(_):
        return rank_p, rank_a

    branch = jnp.where(count == 0, 0, jnp.where(count <= U, 1, 2))
    rank_p, rank_a = jax.lax.switch(branch, (keep, redo_some, redo_all), None)
    return rank_p, rank_a, finite


def exhaustive_batch(
    blocks: Float[ArrayLike, "C n 6 6"],
    m: int,
    *,
    mask: Bool[ArrayLike, "C n"] | None = None,
    chunk_size: int | None = None,
    kernel_dtype=None,
    max_subsets: int | None = MAX_SUBSETS,
    throw: bool = True,
) -> ExhaustiveResult:
    """:func:`exhaustive` for a batch of ``C`` cases at once (the fast path for studies).

    All cases share each chunk's membership matrix, so one ``(21 C, n) x (n, chunk)`` product
    forms every subset sum of the chunk. ``jax.vmap(exhaustive, ...)`` dispatches here.

    Args:
        blocks: ``(C, n, 6, 6)`` per-point information blocks of each case.
        m: subset size (static), ``4 <= m <= n``.
        mask: ``(C, n)`` or ``(n,)`` bool, valid points (subsets with an invalid point are
            skipped).
        chunk_size: subsets per scan step (default: about ``2^15 / C``, at least 16).
        kernel_dtype: dtype of the scoring kernel; default the blocks' dtype. ``jnp.float32`` with
            float64 blocks scores in single precision and re-checks in float64 (module docstring).
        max_subsets: refuse (``ValueError``) more than this many subsets per case
            (:data:`MAX_SUBSETS`; ``None`` for no limit).
        throw: raise for a bad status (``ValueError`` when eager, an Equinox runtime error under
            jit); pass ``False`` to get ``inf`` and a status per case instead.
    """
    blocks = check_blocks(blocks, "exhaustive_batch", batched=True)
    C, n = blocks.shape[:2]
    m = check_m(m, n, "exhaustive")
    check_subsets(n, m, max_subsets, "exhaustive_batch")
    use_mask = mask is not None
    if use_mask:
        mask = jnp.asarray(mask)
        if mask.shape == (n,):
            mask = jnp.broadcast_to(mask, (C, n))
        mask = check_mask(mask, (C, n), "exhaustive")
    else:
        mask = jnp.ones((C, n), bool)
    res = _batch_fn(m, use_mask, chunk_size, _dtype_name(kernel_dtype))(blocks, mask)
    if check_throw(throw):
        res = throw_for_status(res, "exhaustive selection", "pdop")
    return res


def _dtype_name(dtype) -> str | None:
    return None if dtype is None else jnp.dtype(dtype).name


@functools.cache
def _batch_fn(m: int, use_mask: bool, chunk_size: int | None, kernel_dtype: str | None):
    """The compiled batched search for these static options (``mask`` ignored unless used)."""

    def run(blocks, mask):
        return _exhaustive_batch(blocks, m, mask if use_mask else None, chunk_size, kernel_dtype)

    return jax.jit(run)


def _exhaustive_batch(blocks, m, mask, chunk_size, kernel_dtype):
    C, n = blocks.shape[:2]
    K = math.comb(n, m)
    idt = _rank_dtype()
    if K - 1 > np.iinfo(np.dtype(idt)).max:
        raise ValueError(
            f"exhaustive: C({n}, {m}) = {K} subsets do not fit in {np.dtype(idt).name} ranks "
            "(enable jax_enable_x64, or use branch_and_bound)"
        )
    kdt = jnp.dtype(blocks.dtype if kernel_dtype is None else kernel_dtype)
    if not jnp.issubdtype(kdt, jnp.floating):
        raise ValueError(f"kernel_dtype must be a floating dtype; got {kdt}")
    valid = jnp.ones((C, n), bool) if mask is None else mask
    invalid = None if mask is None else ~valid
    rank_p, rank_a, finite = _search(blocks, valid, invalid, n, m, K, chunk_size, kdt)
    pdop_idx = unrank_combinations(rank_p, n, m)
    adop_idx = unrank_combinations(rank_a, n, m)
    pdop, _ = jax.vmap(subset_dop)(blocks, pdop_idx)
    _, adop = jax.vmap(subset_dop)(blocks, adop_idx)
    count = jnp.sum(valid, axis=1)
    status = jnp.select(
        [~finite, count < m, ~(jnp.isfinite(pdop) & jnp.isfinite(adop))],
        [Status.NONFINITE_INPUT, Status.TOO_FEW_POINTS, Status.SINGULAR],
        Status.OK,
    ).astype(jnp.int32)
    bad = status != Status.OK
    inf = jnp.asarray(jnp.inf, pdop.dtype)
    return ExhaustiveResult(
        pdop_idx=pdop_idx,
        pdop=jnp.where(bad, inf, pdop),
        adop_idx=adop_idx,
        adop=jnp.where(bad, inf, adop),
        status=status,
    )


@functools.cache
def _single(m: int, use_mask: bool, chunk_size, kernel_dtype):
    """One-case exhaustive search whose ``vmap`` is :func:`exhaustive_batch` on the batch."""

    batch = _batch_fn(m, use_mask, chunk_size, kernel_dtype)

    @custom_vmap
    def one(blocks, mask):
        return jax.tree.map(lambda x: x[0], batch(blocks[None], mask[None]))

    @one.def_vmap
    def _rule(axis_size, in_batched, blocks, mask):
        b_batched, m_batched = in_batched
        if not b_batched:
            blocks = jnp.broadcast_to(blocks, (axis_size, *blocks.shape))
        if not m_batched:
            mask = jnp.broadcast_to(mask, (axis_size, *mask.shape))
        res = batch(blocks, mask)
        return res, jax.tree.map(lambda _: True, res)

    return jax.jit(one)


def exhaustive(
    blocks: Float[ArrayLike, "n 6 6"],
    m: int,
    *,
    mask: Bool[ArrayLike, " n"] | None = None,
    chunk_size: int | None = None,
    kernel_dtype=None,
    max_subsets: int | None = MAX_SUBSETS,
    throw: bool = True,
) -> ExhaustiveResult:
    """Minimum-PDOP and minimum-ADOP ``m``-subsets by scoring all ``C(n, m)`` of them.

    Args:
        blocks: ``(n, 6, 6)`` per-point information blocks
            (:func:`jaxpose.core.dilution.information_blocks`), line blocks
            (:func:`jaxpose.core.line_dop.line_information_blocks`) or a stack of both.
        m: subset size (static), ``4 <= m <= n``.
        mask: ``(n,)`` bool, valid points of a padded set (subsets with an invalid point are
            skipped).
        chunk_size: subsets per scan step (memory is ``O(chunk_size)``; default automatic).
        kernel_dtype: scoring dtype (default the blocks' dtype; see the module docstring).
        max_subsets: refuse (``ValueError``) a search over more than this many subsets
            (:data:`MAX_SUBSETS`, about a minute of work; ``None`` for no limit).
        throw: raise for a bad status (``ValueError`` when eager, an Equinox runtime error under
            jit); pass ``throw=False`` under ``vmap`` to get ``inf`` and a status per case.

    Returns:
        :class:`ExhaustiveResult`.

    ``jax.vmap(lambda b: exhaustive(b, m, throw=False))`` runs :func:`exhaustive_batch` on the
    whole batch (a custom batching rule), which shares the subset enumeration across cases.
    """
    blocks = check_blocks(blocks, "exhaustive")
    n = blocks.shape[0]
    m = check_m(m, n, "exhaustive")
    check_subsets(n, m, max_subsets)
    mask_arr = check_mask(mask, (n,), "exhaustive")
    if mask_arr is None:
        mask_arr = jnp.ones((n,), bool)
    res = _single(m, mask is not None, chunk_size, _dtype_name(kernel_dtype))(blocks, mask_arr)
    if check_throw(throw):
        res = throw_for_status(res, "exhaustive selection", "pdop")
    return res
