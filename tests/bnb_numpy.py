"""A test oracle: the branch and bound of :mod:`jaxpose.core.select.bnb` as a NumPy host loop."""

import math

import numpy as np

from jaxpose.core.select.bnb import _CRITERIA, _tolerance


def branch_and_bound_numpy(
    blocks, m: int, *, criterion: str = "pdop", relax_iters: int = 16, rtol: float | None = None
):
    """The same search as :func:`branch_and_bound` as a recursive NumPy host loop (float64).

    The measured alternative of the implementation choice (``bench/selection.py``) and an
    independent check in the tests. Returns ``(idx, dop, nodes, iterations)``.
    """
    A = np.asarray(blocks, dtype=np.float64)
    n = A.shape[0]
    rtol = math.sqrt(np.finfo(np.float64).eps) if rtol is None else rtol
    A = 0.5 * (A + np.swapaxes(A, -1, -2))
    dtot = np.diagonal(A.sum(0)).copy()
    dtot[dtot <= 0] = 1.0
    sc = 1.0 / np.sqrt(dtot)
    A = A * sc[None, :, None] * sc[None, None, :]
    wsel = np.zeros(6)
    wsel[_CRITERIA[criterion]] = 1.0 / dtot[_CRITERIA[criterion]]
    tol = _tolerance(np.float64)

    def phi(M):
        d = np.diagonal(M, axis1=-2, axis2=-1)
        positive = np.all(d > 0, axis=-1)
        s = 1.0 / np.sqrt(np.where(d > 0, d, 1.0))
        S = np.where(positive[..., None, None], M, np.eye(6)) * s[..., :, None] * s[..., None, :]
        try:
            L = np.linalg.cholesky(S)
            ok = positive & (np.min(np.diagonal(L, axis1=-2, axis2=-1), axis=-1) ** 2 > tol)
        except np.linalg.LinAlgError:
            if S.ndim == 2:
                return np.inf, None, False
            out = [phi(Mi) for Mi in M]
            return np.array([o[0] for o in out]), None, np.array([o[2] for o in out])
        L = np.where(ok[..., None, None], L, np.eye(6))
        Linv = np.linalg.inv(L)
        Minv = (np.swapaxes(Linv, -1, -2) @ Linv) * s[..., :, None] * s[..., None, :]
        val = np.sum(wsel * np.diagonal(Minv, axis1=-2, axis2=-1), axis=-1)
        return np.where(ok, val, np.inf), Minv, ok

    _, Minv, ok = phi(A.sum(0))
    contrib = np.einsum("kij,ij->k", A, (Minv * wsel) @ Minv) if ok else np.zeros(n)
    perm = np.argsort(-contrib, kind="stable")
    A = A[perm]
    Af = A.reshape(n, 36)

    # Incumbent: greedy backward elimination, then steepest 1-swap.
    active = np.ones(n, dtype=bool)
    for _ in range(n - m):
        vals = np.where(active, phi(A[active].sum(0)[None] - A)[0], np.inf)
        i = int(np.argmin(vals))
        active[i if np.isfinite(vals[i]) else int(np.argmax(active))] = False
    best = float(phi(A[active].sum(0))[0])
    for _ in range(4 * n if m < n else 0):
        M = A[active].sum(0)
        vals = phi((M[None, None] - A[:, None] + A[None, :]).reshape(-1, 6, 6))[0].reshape(n, n)
        vals = np.where(active[:, None] & ~active[None, :], vals, np.inf)
        i, j = divmod(int(np.argmin(vals)), n)
        if not vals[i, j] < best * (1.0 - rtol):
            break
        active[i], active[j], best = False, True, float(vals[i, j])
    best_mask = active.copy()
    counters = {"nodes": 0, "iters": 0}

    def node_bound(MC, k_next, r, threshold):
        R = np.arange(n) >= k_next
        nR = int(R.sum())
        exact = r == 0 or r == nR
        w = np.where(R, 1.0 if r == nR else r / max(nR, 1), 0.0) if r > 0 else np.zeros(n)
        lb = -np.inf
        for it in range(relax_iters):
            counters["iters"] += 1
            M = MC + (w @ Af).reshape(6, 6)
            val, Minv, ok = phi(M)
            if not ok:
                return (np.inf if it == 0 else lb), exact
            if exact:
                return float(val), True
            G = (Minv * wsel) @ Minv
            g = Af @ G.ravel()
            top = np.zeros(n, dtype=bool)
            top[np.argsort(-np.where(R, g, -np.inf), kind="stable")[:r]] = True
            T = np.sum(G * MC) + g[top].sum()
            lb = max(lb, val * val / T if T > 0 else np.inf)
            if lb > threshold or val <= threshold:
                break
            D = MC + (top.astype(float) @ Af).reshape(6, 6) - M
            X = Minv @ D
            d2 = 2.0 * np.sum(wsel * np.diagonal(X @ X @ Minv))
            gamma = float(np.clip(np.sum(G * D) / d2 if d2 > 0 else 1.0, 0.0, 0.999))
            w = (1.0 - gamma) * w + gamma * top
        return lb, exact

    def visit(chosen, k):
        nonlocal best, best_mask
        c = int(chosen.sum())
        for include in (True, False):
            if include and not c < m or not include and not n - k - 1 >= m - c:
                continue
            child = chosen.copy()
            child[k] = include
            r = m - c - int(include)
            counters["nodes"] += 1
            lb, exact = node_bound(A[child].sum(0), k + 1, r, best * (1.0 + rtol))
            if exact:
                if lb < best:
                    best, best_mask = lb, child | ((np.arange(n) > k) & (r > 0))
            elif not lb > best * (1.0 + rtol):
                visit(child, k + 1)

    counters["nodes"] += 1
    root_lb, root_exact = node_bound(np.zeros((6, 6)), 0, m, best * (1.0 + rtol))
    if root_exact:
        if root_lb < best:
            best, best_mask = root_lb, np.ones(n, dtype=bool)
    elif not root_lb > best * (1.0 + rtol):
        visit(np.zeros(n, dtype=bool), 0)
    idx = np.sort(perm[best_mask])
    return idx, math.sqrt(best), counters["nodes"], counters["iters"]
