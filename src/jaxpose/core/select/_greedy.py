"""Greedy backward elimination on the DOP itself.

Start from all points; at each of the ``n - m`` steps remove the point whose removal raises the
criterion (PDOP or ADOP) least. Each step scores the ``n`` candidate removals at once: their
information sums are one ``(n, n) x (n, 21)`` product of 0/1 membership rows against the packed
blocks, and the traces come from the LAPACK-free kernel of :mod:`jaxpose.core.select._kernel`. It is
a heuristic: it never beats :func:`jaxpose.core.select.exhaustive` and usually comes close.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from jaxpose.core.select._kernel import (
    block_scales,
    check_blocks,
    check_m,
    check_mask,
    pack,
    scale_packed,
    too_few_valid,
    traces,
)
from jaxpose.core.status import Status, raise_for_status

__all__ = ["CRITERIA", "check_criterion", "greedy"]

CRITERIA = ("pdop", "adop")


def check_criterion(criterion: str) -> int:
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be 'pdop' or 'adop'; got {criterion!r}")
    return CRITERIA.index(criterion)


def greedy(
    blocks: Float[ArrayLike, "n 6 6"],
    m: int,
    *,
    criterion: str = "pdop",
    mask: Bool[ArrayLike, " n"] | None = None,
) -> Int[Array, " m"]:
    """Backward elimination: ``m`` of ``n`` points, removing the least useful one at a time.

    Args:
        blocks: ``(n, 6, 6)`` per-point information blocks
            (:func:`jaxpose.core.dilution.information_blocks`), line blocks
            (:func:`jaxpose.core.line_dop.line_information_blocks`) or a stack of both.
        m: number of points to keep (static), ``4 <= m <= n``.
        criterion: ``"pdop"`` or ``"adop"``.
        mask: ``(n,)`` bool, valid points (masked ones are removed first, never kept). An
            eager call raises ``ValueError`` when fewer than ``m`` are valid; a traced one (where
            the mask cannot be looked at) then fills the remaining slots with masked points, as
            :func:`jaxpose.core.select.quasi_optimal` does.

    Returns:
        ``(m,)`` ``int32`` indices, ascending. Ties (including "every removal is singular") go to
        the lowest index. Eager calls raise ``ValueError`` for NaN/inf blocks or too few valid
        points; traced calls return deterministic indices.
    """
    blocks = check_blocks(blocks, "greedy")
    n = blocks.shape[0]
    m = check_m(m, n, "greedy")
    which = check_criterion(criterion)
    valid = check_mask(mask, (n,), "greedy")
    if valid is not None and not isinstance(valid, jax.core.Tracer) and int(jnp.sum(valid)) < m:
        raise too_few_valid(valid, m, "greedy")
    valid = jnp.ones((n,), bool) if valid is None else valid
    finite = jnp.all(jnp.isfinite(blocks) | ~valid[:, None, None])
    if not isinstance(finite, jax.core.Tracer):
        raise_for_status(jnp.where(finite, Status.OK, Status.NONFINITE_INPUT), "greedy")
    return _greedy(blocks, valid, finite, m, which)


@functools.partial(jax.jit, static_argnums=(3, 4))
def _greedy(blocks, valid, finite, m: int, which: int):
    n = blocks.shape[0]
    use = valid & finite
    blocks = jnp.where(use[:, None, None], blocks, 0.0)
    s_p, s_a = block_scales(jnp.sum(blocks, axis=0))
    packed = scale_packed(pack(blocks), s_p, s_a)  # (n, 21)
    others = ~jnp.eye(n, dtype=bool)

    def remove_one(_, keep):
        rows = (keep[None, :] & others).astype(packed.dtype)  # row k: keep without k
        t_pp, t_aa, ok = traces(list((rows @ packed).T))
        score = jnp.where(ok, (t_pp, t_aa)[which], jnp.inf)
        score = jnp.where(keep, score, jnp.inf)
        best = jnp.argmin(score)
        # Masked points go first; if every removal scores inf take the lowest kept index.
        masked_left = keep & ~valid
        k = jnp.where(
            jnp.any(masked_left),
            jnp.argmax(masked_left),
            jnp.where(keep[best], best, jnp.argmax(keep)),
        )
        return keep.at[k].set(False)

    keep = jax.lax.fori_loop(0, n - m, remove_one, jnp.ones((n,), bool))
    return jnp.nonzero(keep, size=m, fill_value=0)[0].astype(jnp.int32)
