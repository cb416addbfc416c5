"""Exact DOP-optimal feature subset by branch and bound (no full enumeration).

Problem (Ning, Zhang, Wang 2018, Sec. 4, "optimal method"): given per-point information blocks
``A_i = H_i^T H_i / sigma_i^2`` (``(n, 6, 6)``, :func:`jaxpose.core.dilution.information_blocks`),
find the ``m``-subset ``S`` minimising ``PDOP(S) = sqrt(trace(Q[:3, :3]))`` (or ``ADOP``,
``Q[3:, 3:]``) with ``Q = M_S^-1`` and ``M_S = sum_{i in S} A_i``. The exhaustive method visits all
``C(n, m)`` subsets (``C(60, 8) = 2.56e9``); this search visits a few dozen to a few hundred tree
nodes for the paper's scenario and returns the same subset.

Notation: ``phi(M) = trace(W M^-1)`` with ``W = E^T E`` the selector of the position (PDOP) or
attitude (ADOP) block, so ``DOP = sqrt(phi)``. ``phi`` is *decreasing* (``M <= M'`` in the PSD
order gives ``phi(M) >= phi(M')``: adding a point only adds a PSD term to ``H^T H``) and *convex*
on positive definite matrices (``M -> M^-1`` is operator convex and ``trace(W .)`` is linear and
monotone for ``W >= 0``).

Search tree
-----------
The points are put in a fixed order (below) and a node at depth ``k`` has decided points
``0..k-1``: a set ``C`` of chosen ones and ``R = {k, ..., n-1}`` still allowed; its completions are
the subsets ``S = C + (r of R)``, ``r = m - |C|``. Its two children decide point ``k`` (include
first, then exclude). A child with ``r = 0`` or ``r = |R|`` has a single completion and is a
leaf, evaluated exactly. Depth-first search with an incumbent ``phi*``; a child is dropped only
if its lower bound exceeds ``phi* (1 + rtol)``. ``rtol = sqrt(eps)`` is a margin for the rounding
of the bound, not an optimality gap: a dropped subtree's true bound still exceeds ``phi*`` when
the rounding error is below ``rtol``, so nothing better than the incumbent is lost and the answer
is exact.

Bounds (``bound=``), each valid for every completion ``S`` of a node
---------------------------------------------------------------------
``"monotone"`` (the classical Narendra-Fukunaga bound): ``phi(M_S) >= phi(M_U)`` with
``U = C + R``, because ``M_S <= M_U``.

``"linear"``, ``"relaxation"`` (default): for **any** positive definite ``M0``, convexity gives the
tangent-plane inequality ``phi(M) >= phi(M0) + <grad phi(M0), M - M0>``, with
``grad phi(M0) = -G0``, ``G0 = M0^-1 W M0^-1 >= 0`` and ``<G0, M0> = phi(M0)``, so

    ``phi(M_S) >= 2 phi(M0) - sum_{i in S} g_i``,   ``g_i = <G0, A_i> = trace(G0 A_i) >= 0``.

Applying it to ``c M0`` (``phi(cM0) = phi0 / c``, ``G(cM0) = G0 / c^2``) and maximising over
``c > 0`` (at ``c = T / phi0``) gives

    ``phi(M_S) >= phi0^2 / T``,   ``T = sum_{i in C} g_i + (sum of the r largest g_i, i in R)``,

since ``sum_{i in S} g_i <= T`` for every completion (all ``g_i >= 0``); a singular ``M_S`` has
``phi = inf`` and satisfies every bound. ``M0`` need not be feasible, so any positive definite
matrix gives a valid bound and only its quality depends on the choice. ``"linear"`` takes
``M0 = M_U``; as ``sum_{i in U} g_i = <G0, M_U> = phi(M_U) >= T`` it is never weaker than the
monotone bound, for the cost of one ``(n, 36) @ (36,)`` product and a sort. ``"relaxation"``
improves ``M0 = M(w) = M_C + sum_{i in R} w_i A_i`` over the continuous relaxation
``{0 <= w <= 1, sum w = r}`` (an A-optimal-design problem, convex in ``w``) by Frank-Wolfe: the
top-``r`` indicator that defines ``T`` is exactly Frank-Wolfe's linear-minimisation vertex, the step
is one Newton step on the convex 1-D restriction ``phi((1-gamma) M(w) + gamma M(s))`` (clipped to
``[0, 0.999]`` so ``M(w)`` stays positive definite), and every iterate's ``phi0^2 / T`` is a valid
bound (the best one is kept). At the relaxation's optimum the bound equals the relaxed optimum.
Iterations stop early once the bound exceeds the prune threshold, or once the relaxed primal value
``phi(M(w))`` is already below it (no bound from this relaxation can prune then), or after
``relax_iters`` iterations. An iterate whose ``M(w)`` is numerically singular contributes no bound,
except the first one (uniform ``w = r/|R|`` on ``R``, so ``M(w) >= min(1, r/|R|) M_U``): then
``M_U``, hence every completion, is singular, and the subtree is dropped (every subset in it has
``DOP = inf``).

Ordering and incumbent
----------------------
Points are sorted by decreasing contribution ``g_i`` at the full set (``M0 = sum A``), so the
include-first dive meets the strong points first (NumPy prototype, n = 60, m = 8, 5 cases: median
36 nodes ordered against 152 in the input order). The incumbent before the search is greedy
backward elimination on the DOP itself followed by steepest 1-swap local search (batched Cholesky
evaluations); it is already optimal in 80-100 % of the cases below, so the search is mostly a proof
of optimality. Without it the tree finds the optimum itself with 2-3x more nodes.

Implementation choice (measured)
--------------------------------
The tree walk is a ``lax.while_loop`` over an explicit fixed-size state: the depth ``k``, the
decisions and a phase per depth (no child tried / include tried / both tried); the stack of a binary
depth-first search is the depth index itself, and backtracking is ``k -> k - 1``. The node bound is
an inner ``while_loop`` (Frank-Wolfe with early exit). ``m``, the criterion, the bound kind and the
options are traced, so the search compiles once per ``(n, dtype)`` (~4 s of CPU time) and runs
under ``jit`` and ``vmap``. The alternative, a NumPy host loop with the same algorithm
(``branch_and_bound_numpy`` in ``tests/bnb_numpy.py``, the measured competitor and an independent
check in the tests: it visits exactly the same nodes and Frank-Wolfe iterations), pays Python and
NumPy-call overhead at every Frank-Wolfe iteration: at n = 60, m = 8, PDOP it takes 1.08 s median (5
cases) against 25 ms for the compiled loop, ~40x. ``vmap`` over 20 cases on CPU runs at 78 ms per
case (lanes wait for the slowest and ``cond`` becomes ``select``): on CPU call it per case.

Measurements
------------
``python bench/selection.py --skip kernel quasi table4 table4-f32`` (part (c)), 2-core CPU shared
with other jobs (load average ~13, so times are pessimistic), float64, m = 8, 20 cases per n of the
paper's scenario (features uniform in a 1 m square, fx = 3000 px, 10 m range, 20 deg per axis);
median / max over cases, per call after one compile per n:

==========  ===============  ================  ===============  ================
n           PDOP nodes       PDOP time         ADOP nodes       ADOP time
==========  ===============  ================  ===============  ================
24          20 / 29          6 / 29 ms         22 / 43          4 / 19 ms
30          23 / 47          5 / 30 ms         29 / 69          4 / 15 ms
40          23 / 37          9 / 46 ms         41 / 177         16 / 25 ms
60          43 / 165         25 / 87 ms        41 / 143         23 / 52 ms
==========  ===============  ================  ===============  ================

Targets: n = 40 at most 2 s and n = 60 at most 60 s per case (medians): met by ~200x and ~2000x.
The exhaustive search (:func:`jaxpose.core.select.exhaustive`) takes 310 ms per case at n = 24 and
agrees on all 20 cases, both criteria. What the bound buys (PDOP, nodes median / max): n = 24
``"monotone"`` 879 / 3391, ``"linear"`` 25 / 185; n = 40 ``"monotone"`` 127k / 453k (6.8 s / 24 s,
3 cases), ``"linear"`` 109 / 4333; n = 60 ``"linear"`` 2870 / 110k (0.15 s / 4.5 s), no heuristic
incumbent 111 / 469. The monotone bound alone would miss the n = 60 target (prototype: 1.9-3.9 M
nodes, 75-150 s per case).

Limits: the search is exponential in the worst case (exact ties, e.g. identical blocks, are all
explored); ``max_nodes`` bounds it and reports ``NOT_CONVERGED``. The answer is exact as long as a
bound's rounding error is below ``rtol`` (the blocks are Jacobi-scaled first so the 6x6 Cholesky
solves are well conditioned); subsets whose scaled Cholesky pivot falls below ``1e3 eps`` count as
singular (``DOP = inf``), as in :func:`jaxpose.core.dilution.dop_from_information`.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from jaxpose.core.dilution import dop_from_information
from jaxpose.core.select._kernel import check_m
from jaxpose.core.status import Status, check_throw, throw_for_status

__all__ = ["BnBResult", "branch_and_bound"]

_CRITERIA = {"pdop": slice(0, 3), "adop": slice(3, 6)}
_BOUNDS = ("relaxation", "linear", "monotone")


class BnBResult(eqx.Module):
    """Result of :func:`branch_and_bound` (leading batch axes under ``vmap``).

    Attributes:
        idx: ``(m,)`` indices of the optimal subset, sorted ascending.
        value: its PDOP or ADOP (the ``criterion``), from
        :func:`jaxpose.core.dilution.dop_from_information`;
            ``inf`` when the status is not OK.
        nodes: tree nodes whose bound (or exact value, for leaves) was evaluated, root included.
        iterations: Frank-Wolfe iterations summed over all bound evaluations.
        heuristic_value: DOP of the incumbent the search started from (greedy + 1-swap).
        status: ``int32`` :class:`~jaxpose.core.status.Status`: ``OK``; ``SINGULAR`` when every
            ``m``-subset is singular; ``NONFINITE_INPUT`` for NaN/inf blocks; ``NOT_CONVERGED`` when
            ``max_nodes`` ran out (then ``idx`` is the best subset found, not proven optimal).
    """

    idx: Int[Array, "... m"]
    value: Float[Array, " ..."]
    nodes: Int[Array, " ..."]
    iterations: Int[Array, " ..."]
    heuristic_value: Float[Array, " ..."]
    status: Int[Array, " ..."]


# ----------------------------------------------------------------------------- small linear algebra
def _tolerance(dtype) -> float:
    return 1e3 * float(jnp.finfo(dtype).eps)


def _phi(M: Float[Array, "... 6 6"], wsel: Float[Array, " 6"]):
    """``(phi, M^-1, ok)`` with ``phi = sum_j wsel_j (M^-1)_jj``; ``inf`` when ``M`` is singular.

    Singular means: a Cholesky pivot of the Jacobi-scaled ``D^-1/2 M D^-1/2`` with square at or
    below ``1e3 eps``, a non-positive diagonal, or a non-finite entry.
    """
    diag = jnp.diagonal(M, axis1=-2, axis2=-1)
    positive = jnp.all(diag > 0, axis=-1) & jnp.all(jnp.isfinite(M), axis=(-2, -1))
    s = 1.0 / jnp.sqrt(jnp.where(diag > 0, diag, 1.0))
    S = jnp.where(positive[..., None, None], M, jnp.eye(6, dtype=M.dtype))
    S = S * s[..., :, None] * s[..., None, :]
    L = jnp.linalg.cholesky(S)
    piv = jnp.diagonal(L, axis1=-2, axis2=-1)
    ok = positive & jnp.all(jnp.isfinite(piv), axis=-1)
    ok = ok & (jnp.min(jnp.where(jnp.isfinite(piv), piv, 0.0), axis=-1) ** 2 > _tolerance(M.dtype))
    eye = jnp.eye(6, dtype=M.dtype)
    L = jnp.where(ok[..., None, None], L, eye)
    Linv = jsl.solve_triangular(L, jnp.broadcast_to(eye, L.shape), lower=True)
    Sinv = jnp.swapaxes(Linv, -1, -2) @ Linv
    Minv = Sinv * s[..., :, None] * s[..., None, :]
    phi = jnp.sum(wsel * jnp.diagonal(Minv, axis1=-2, axis2=-1), axis=-1)
    return jnp.where(ok, phi, jnp.inf), Minv, ok


def _phi_batch(Ms, wsel):
    return _phi(Ms, wsel)[0]


# ----------------------------------------------------------------------------- the node bound
def _node_bound(A, Af, MC, R, r, wsel, threshold, bound, iters):
    """Lower bound on ``phi`` over the completions ``C + (r of R)`` of a node (``R`` a mask).

    ``bound`` is the (traced) index in :data:`_BOUNDS`. Returns ``(lb, exact, iterations)``;
    ``exact`` when the node has one completion (``lb`` is then its value).
    """
    dtype = A.dtype
    n = A.shape[0]
    r = jnp.asarray(r, jnp.int32)
    nR = jnp.sum(R, dtype=jnp.int32)
    exact = (r == 0) | (r == nR)
    relaxation = bound == _BOUNDS.index("relaxation")
    monotone = bound == _BOUNDS.index("monotone")
    uniform = jnp.where(R, r.astype(dtype) / jnp.maximum(nR, 1).astype(dtype), 0.0)
    w0 = jnp.where(relaxation & ~exact, uniform, (R & (r > 0)).astype(dtype))
    ranks_base = jnp.arange(n, dtype=jnp.int32)

    def evaluate(w):
        M = MC + jnp.tensordot(w, A, axes=1)
        phi, Minv, ok = _phi(M, wsel)
        G = (Minv * wsel[None, :]) @ Minv
        g = Af @ G.reshape(-1)
        gC = jnp.sum(G * MC)
        keyed = jnp.where(R, g, -jnp.inf)
        order = jnp.argsort(-keyed)
        top = jnp.zeros(n, dtype=bool).at[order].set(ranks_base < r)
        top = top & R
        T = gC + jnp.sum(jnp.where(top, g, 0.0))
        lb = jnp.where(T > 0, phi * phi / jnp.where(T > 0, T, 1.0), jnp.inf)
        lb = jnp.where(exact | monotone, phi, lb)
        return M, phi, Minv, ok, G, top, lb

    def cond(state):
        it, w, lb, done = state
        return ~done

    def body(state):
        it, w, lb, _ = state
        M, phi, Minv, ok, G, top, lb_it = evaluate(w)
        # A singular first iterate means M_U is singular: every completion has DOP = inf.
        lb_it = jnp.where(ok, lb_it, jnp.where(it == 0, jnp.inf, -jnp.inf))
        lb = jnp.maximum(lb, lb_it)
        # Newton step on gamma -> phi((1 - gamma) M + gamma M_s) along the Frank-Wolfe direction.
        Ms = MC + jnp.tensordot(top.astype(dtype), A, axes=1)
        D = Ms - M
        d1 = -jnp.sum(G * D)
        X = Minv @ D
        d2 = 2.0 * jnp.sum(wsel * jnp.diagonal(X @ X @ Minv))
        gamma = jnp.where(d2 > 0, -d1 / jnp.where(d2 > 0, d2, 1.0), 1.0)
        gamma = jnp.clip(gamma, 0.0, 0.999)
        w = (1.0 - gamma) * w + gamma * top.astype(dtype)
        it = it + 1
        done = exact | ~ok | (lb > threshold) | (phi <= threshold) | (it >= iters) | ~relaxation
        return it, w, lb, done

    init = (jnp.asarray(0, jnp.int32), w0, jnp.asarray(-jnp.inf, dtype), jnp.asarray(False))
    it, _, lb, _ = jax.lax.while_loop(cond, body, init)
    return lb, exact, it


# ----------------------------------------------------------------------------- incumbent heuristic
def _greedy_swap(A, m, wsel, rtol, max_swaps):
    """Greedy backward elimination on ``phi``, then steepest-descent 1-swap local search."""
    n = A.shape[0]
    dtype = A.dtype

    def drop_one(_, active):
        M = jnp.tensordot(active.astype(dtype), A, axes=1)
        vals = _phi_batch(M[None] - A, wsel)
        vals = jnp.where(active, vals, jnp.inf)
        i = jnp.argmin(vals)
        i = jnp.where(jnp.isinf(vals[i]), jnp.argmax(active), i)  # all singular: drop any
        return active.at[i].set(False)

    active = jax.lax.fori_loop(0, n - m, drop_one, jnp.ones(n, dtype=bool))

    def swap_cond(state):
        _, _, improved, passes = state
        return improved & (passes < max_swaps)

    def swap_body(state):
        chosen, val, _, passes = state
        M = jnp.tensordot(chosen.astype(dtype), A, axes=1)
        cand = M[None, None] - A[:, None] + A[None, :]  # swap out i, swap in j
        vals = _phi_batch(cand.reshape(n * n, 6, 6), wsel).reshape(n, n)
        vals = jnp.where(chosen[:, None] & ~chosen[None, :], vals, jnp.inf)
        k = jnp.argmin(vals)
        i, j = k // n, k % n
        better = vals[i, j] < val * (1.0 - rtol)
        chosen = jnp.where(better, chosen.at[i].set(False).at[j].set(True), chosen)
        return chosen, jnp.where(better, vals[i, j], val), better, passes + 1

    val = _phi(jnp.tensordot(active.astype(dtype), A, axes=1), wsel)[0]
    init = (active, val, m < n, jnp.asarray(0, jnp.int32))
    active, val, _, _ = jax.lax.while_loop(swap_cond, swap_body, init)
    return active, val


# ----------------------------------------------------------------------------- the search
@jax.jit
def _search(blocks, m, sel, rtol, relax_iters, max_nodes, bound, use_heuristic):
    """The search on one problem; every argument but the shape of ``blocks`` is traced.

    Compiles once per ``(n, dtype)``: ``m``, the criterion (``sel``, a ``(6,)`` mask), the bound
    kind and the options are data, so one compiled search serves them all. Returns the chosen mask
    (original order), the incumbent value before the search (``phi``), nodes, iterations, whether
    the search finished, and whether the input was finite.
    """
    n = blocks.shape[0]
    dtype = blocks.dtype
    m = jnp.asarray(m, jnp.int32)
    relax_iters = jnp.asarray(relax_iters, jnp.int32)
    max_nodes = jnp.asarray(max_nodes, jnp.int32)
    finite = jnp.all(jnp.isfinite(blocks))
    blocks = jnp.where(finite, blocks, jnp.broadcast_to(jnp.eye(6, dtype=dtype), blocks.shape))
    blocks = 0.5 * (blocks + jnp.swapaxes(blocks, -1, -2))
    # Global Jacobi scaling (a fixed congruence; DOP values are kept through wsel).
    dtot = jnp.diagonal(jnp.sum(blocks, axis=0))
    dtot = jnp.where(dtot > 0, dtot, 1.0)
    sc = 1.0 / jnp.sqrt(dtot)
    A = blocks * sc[None, :, None] * sc[None, None, :]
    wsel = jnp.where(sel, 1.0 / dtot, 0.0).astype(dtype)
    # Ordering: decreasing contribution g_i = <G, A_i> at the full set.
    _, Minv_all, ok_all = _phi(jnp.sum(A, axis=0), wsel)
    G_all = (Minv_all * wsel[None, :]) @ Minv_all
    contrib = jnp.where(ok_all, jnp.einsum("kij,ij->k", A, G_all), 0.0)
    perm = jnp.argsort(-contrib, stable=True)
    A = A[perm]
    Af = A.reshape(n, 36)
    positions = jnp.arange(n, dtype=jnp.int32)

    inc_mask, inc_val = jax.lax.cond(
        use_heuristic,
        lambda: _greedy_swap(A, m, wsel, rtol, 4 * n),
        lambda: (positions < m, jnp.asarray(jnp.inf, dtype)),
    )
    heuristic_val = inc_val

    def threshold(best):
        return best * (1.0 + rtol)

    # Root: one completion when m == n; otherwise its bound may already prove the incumbent.
    root_lb, root_exact, root_it = _node_bound(
        A,
        Af,
        jnp.zeros((6, 6), dtype),
        positions >= 0,
        m,
        wsel,
        threshold(inc_val),
        bound,
        relax_iters,
    )
    better = root_exact & (root_lb < inc_val)
    inc_mask = jnp.where(better, positions >= 0, inc_mask)
    inc_val = jnp.where(better, root_lb, inc_val)
    start = ~root_exact & ~(root_lb > threshold(inc_val)) & finite

    # Depth-first walk of the binary include/exclude tree. State: depth k (the node has decided
    # points 0..k-1), the decisions, the phase of each depth (0: no child tried, 1: include
    # tried, 2: both tried), the incumbent and counters. Backtracking is k -> k - 1.
    def cond(state):
        k, _, _, _, _, nodes, _ = state
        return (k >= 0) & (nodes < max_nodes)

    def body(state):
        k, chosen, phase, best, best_mask, nodes, iters = state
        p = phase[k]
        cur = chosen & (positions < k)
        c = jnp.sum(cur, dtype=jnp.int32)
        include = p == 0
        valid = jnp.where(include, c < m, (n - k - 1) >= (m - c)) & (p < 2)
        child = cur | ((positions == k) & include)
        R = positions > k
        r = m - c - include.astype(jnp.int32)

        def evaluate():
            MC = jnp.tensordot(child.astype(dtype), A, axes=1)
            return _node_bound(A, Af, MC, R, r, wsel, threshold(best), bound, relax_iters)

        def skip():
            return jnp.asarray(jnp.inf, dtype), jnp.asarray(False), jnp.asarray(0, jnp.int32)

        lb, exact, it = jax.lax.cond(valid, evaluate, skip)
        improve = valid & exact & (lb < best)  # a leaf (one completion) better than the incumbent
        best = jnp.where(improve, lb, best)
        best_mask = jnp.where(improve, child | (R & (r > 0)), best_mask)
        descend = valid & ~exact & ~(lb > threshold(best))
        nodes = nodes + valid.astype(jnp.int32)
        iters = iters + jnp.where(valid, it, 0)
        phase = phase.at[k].set(jnp.minimum(p + 1, 2))
        chosen = jnp.where(descend & (positions == k), include, chosen)
        phase = jnp.where(descend, phase.at[k + 1].set(0), phase)
        k = jnp.where(p >= 2, k - 1, jnp.where(descend, k + 1, k))
        return k, chosen, phase, best, best_mask, nodes, iters

    init = (
        jnp.where(start, 0, -1).astype(jnp.int32),
        jnp.zeros(n, dtype=bool),
        jnp.zeros(n + 1, dtype=jnp.int32),
        inc_val,
        inc_mask,
        jnp.asarray(1, jnp.int32),
        root_it.astype(jnp.int32),
    )
    k, _, _, _, best_mask, nodes, iters = jax.lax.while_loop(cond, body, init)
    mask = jnp.zeros(n, dtype=bool).at[perm].set(best_mask)
    return mask, heuristic_val, nodes, iters, k < 0, finite


_INT32_MAX = int(np.iinfo(np.int32).max)


def _check_count(value, name: str) -> int:
    """``relax_iters`` and ``max_nodes``: an integer (not a bool) in ``[1, 2^31 - 1]`` (they are
    ``int32`` counters; a float would be truncated, a bool taken as 1)."""
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | np.integer):
        raise ValueError(
            f"branch_and_bound: {name} must be an integer >= 1; got {type(value).__name__} "
            f"{value!r}"
        )
    if not 1 <= value <= _INT32_MAX:
        raise ValueError(
            f"branch_and_bound: {name} must be an integer in [1, {_INT32_MAX}]; got {value}"
        )
    return int(value)


def _check_rtol(rtol):
    """``rtol``: a finite number ``>= 0``. A negative margin prunes subtrees whose bound is below
    the incumbent, so the answer is no longer the optimum; a traced value is passed through."""
    if isinstance(rtol, jax.core.Tracer):
        return rtol
    bad = isinstance(rtol, bool | np.bool_ | str | bytes)
    if not bad:
        arr = np.asarray(rtol)
        bad = arr.ndim != 0 or arr.dtype.kind not in "iuf"
    if bad:
        raise ValueError(
            f"branch_and_bound: rtol must be one finite number >= 0; got {type(rtol).__name__} "
            f"{rtol!r}"
        )
    value = float(arr)
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(
            "branch_and_bound: rtol must be a finite number >= 0 (a pruning margin for rounding; "
            f"a negative one can prune the optimum); got {value}"
        )
    return value


def branch_and_bound(
    blocks: Float[ArrayLike, "n 6 6"],
    m: int,
    *,
    criterion: str = "pdop",
    bound: str = "relaxation",
    relax_iters: int = 16,
    max_nodes: int = 10_000_000,
    rtol: float | None = None,
    heuristic: bool = True,
    throw: bool = True,
) -> BnBResult:
    """The ``m``-subset of minimum PDOP (or ADOP), exactly, by branch and bound.

    Args:
        blocks: ``(n, 6, 6)`` per-point information ``A_i = H_i^T H_i / sigma_i^2`` from
            :func:`jaxpose.core.dilution.information_blocks` (state order ``(T, eps)``), line
            blocks (:func:`jaxpose.core.line_dop.line_information_blocks`) or a stack of both.
        m: subset size, ``4 <= m <= n`` (static).
        criterion: ``"pdop"`` or ``"adop"``.
        bound: ``"relaxation"`` (default; Frank-Wolfe on the continuous relaxation),
            ``"linear"`` (one tangent-plane bound at the node's full set) or ``"monotone"`` (the
            classical ``DOP(C + R)``); see the module docstring for the proofs.
        relax_iters: Frank-Wolfe iterations per node at most (``"relaxation"``), an integer
            ``>= 1``.
        max_nodes: node budget, an integer ``>= 1``; when it runs out the status is
            ``NOT_CONVERGED``.
        rtol: pruning margin for rounding (default ``sqrt(eps)`` of the dtype), a finite number
            ``>= 0``; a negative or NaN one is refused (``ValueError``): it would prune subtrees
            that hold the optimum. A larger one only prunes less (slower, still exact).
        heuristic: start from greedy elimination + 1-swap (otherwise from no incumbent); ``True``
            or ``False``.
        throw: raise ``ValueError`` (eager) or an Equinox runtime error (under jit) for a bad
            status; pass ``False`` under ``vmap`` to get ``inf`` and a status per problem.

    Returns:
        :class:`BnBResult`; ``value`` is the DOP (``sqrt`` of the trace) of ``idx``.

    Shapes and static arguments are checked at trace time (``ValueError``). The function takes one
    problem; batch with ``jax.vmap(lambda b: branch_and_bound(b, m, throw=False))``.
    """
    blocks = jnp.asarray(blocks)
    if not jnp.issubdtype(blocks.dtype, jnp.floating):
        blocks = blocks.astype(jnp.result_type(float))
    if blocks.ndim != 3 or blocks.shape[1:] != (6, 6):
        raise ValueError(
            f"blocks must have shape (n, 6, 6) (one problem; use jax.vmap for batches); got "
            f"{blocks.shape}"
        )
    n = blocks.shape[0]
    if criterion not in _CRITERIA:
        raise ValueError(f"criterion must be 'pdop' or 'adop'; got {criterion!r}")
    if bound not in _BOUNDS:
        raise ValueError(f"bound must be one of {_BOUNDS}; got {bound!r}")
    m = check_m(m, n, "branch_and_bound")
    relax_iters = _check_count(relax_iters, "relax_iters")
    max_nodes = _check_count(max_nodes, "max_nodes")
    if not isinstance(heuristic, bool | np.bool_):
        raise ValueError(
            f"branch_and_bound: heuristic must be True or False; got {type(heuristic).__name__} "
            f"{heuristic!r}"
        )
    if rtol is None:
        rtol = math.sqrt(float(jnp.finfo(blocks.dtype).eps))
    else:
        rtol = _check_rtol(rtol)
    sel = np.zeros(6, dtype=bool)
    sel[_CRITERIA[criterion]] = True
    mask, heuristic_phi, nodes, iters, converged, finite = _search(
        blocks,
        jnp.asarray(m, jnp.int32),
        jnp.asarray(sel),
        jnp.asarray(rtol, blocks.dtype),
        jnp.asarray(relax_iters, jnp.int32),
        jnp.asarray(max_nodes, jnp.int32),
        jnp.asarray(_BOUNDS.index(bound), jnp.int32),
        jnp.asarray(bool(heuristic)),
    )
    value, status, heuristic_value = _finish(
        blocks, mask, criterion == "pdop", heuristic_phi, nodes, iters, converged, finite
    )
    out = BnBResult(
        idx=jnp.nonzero(mask, size=m, fill_value=0)[0].astype(jnp.int32),
        value=value,
        nodes=nodes,
        iterations=iters,
        heuristic_value=heuristic_value,
        status=status,
    )
    if check_throw(throw):
        out = throw_for_status(out, "branch and bound", "value")
    return out


@jax.jit
def _finish(blocks, mask, is_pdop, heuristic_phi, nodes, iters, converged, finite):
    """DOP of the chosen subset (via :func:`dop_from_information`, as every selector) and status."""
    M = jnp.sum(jnp.where(finite & mask[:, None, None], blocks, 0.0), axis=0)
    res = dop_from_information(M)
    value = jnp.where(is_pdop, res.pdop, res.adop)
    status = jnp.select(
        [~finite, ~converged, res.status != Status.OK],
        [Status.NONFINITE_INPUT, Status.NOT_CONVERGED, Status.SINGULAR],
        Status.OK,
    ).astype(jnp.int32)
    value = jnp.where(finite & (res.status == Status.OK), value, jnp.inf)
    return value, status, jnp.sqrt(heuristic_phi)
