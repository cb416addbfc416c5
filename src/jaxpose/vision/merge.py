"""Merging segments (Sharma et al. 2018 Sec. III.A.3-4, Fig. 7).

* :func:`merge_truncated`: two segments with ``|theta1 - theta2| < theta_thresh``,
  ``|rho1 - rho2| < rho_thresh`` (polar forms, eqs. 11-12) and close ends are replaced by the
  segment joining their farthest endpoints (eq. 13). The paper's third test reads "the distance
  between the farthest pair of endpoints below ``d_thresh`` = half the mean segment length";
  read literally it would only merge tiny segments, so the *gap* between the nearest endpoints
  (zero when they overlap) is tested against ``d_thresh`` instead.
* :func:`remove_duplicates`: of two close and similar segments (midpoints closer than half the
  longer one) only the longer is kept.
* :func:`merge_streams`: the WGE and Sobel streams together, duplicates removed; a shorter segment
  that crosses a longer one of the other stream, cut into ``L1 < L2`` by it, is dropped when
  ``L1 / L2 > 0.25``.
* :func:`antenna_candidates`: WGE-only segments shorter than ``l_ROI / 3``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["antenna_candidates", "merge_streams", "merge_truncated", "remove_duplicates", "similar"]


def _unit(seg):
    d = seg[..., 1, :] - seg[..., 0, :]
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    return d / np.maximum(n, 1e-12), n[..., 0]


def _line_distance(seg_a, point):
    u, _ = _unit(seg_a)
    r = point - seg_a[0]
    return abs(u[0] * r[1] - u[1] * r[0])


def similar(a, b, theta_thresh_deg: float, rho_thresh: float) -> bool | np.bool_:
    """Same line within the angle and offset thresholds (polar-form test, eqs. 11-12)."""
    ua, _ = _unit(a)
    ub, _ = _unit(b)
    if abs(ua @ ub) < np.cos(np.deg2rad(theta_thresh_deg)):
        return False
    return max(_line_distance(a, b.mean(0)), _line_distance(b, a.mean(0))) < rho_thresh


def _gap(a, b):
    """Gap between two near-collinear segments along their common direction (0 if they overlap)."""
    u, _ = _unit(a)
    ta = np.sort(a @ u)
    tb = np.sort(b @ u)
    return max(0.0, max(ta[0], tb[0]) - min(ta[1], tb[1]))


def _farthest(a, b):
    """The farthest pair among all endpoints of ``a`` and ``b`` (any number of points each)."""
    P = np.concatenate([a, b])
    d = np.linalg.norm(P[:, None] - P[None], axis=-1)
    i, j = np.unravel_index(np.argmax(d), d.shape)
    return np.stack([P[i], P[j]])


def _pair_tests(S, theta_thresh_deg, rho_thresh):
    """``(N, N)`` bool: same line within the thresholds (vectorised :func:`similar`)."""
    d = S[:, 1] - S[:, 0]
    u = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    par = np.abs(u @ u.T) >= np.cos(np.deg2rad(theta_thresh_deg))
    mid = S.mean(1)
    rel = mid[None, :, :] - S[:, None, 0, :]  # midpoint of j relative to start of i
    dist = np.abs(u[:, None, 0] * rel[..., 1] - u[:, None, 1] * rel[..., 0])
    return par & (np.maximum(dist, dist.T) < rho_thresh), u


def merge_truncated(
    segments: np.ndarray,
    *,
    theta_thresh_deg: float = 2.0,
    rho_thresh: float = 3.0,
    d_thresh: float | None = None,
    max_rounds: int = 8,
) -> np.ndarray:
    """Merge truncated pieces of the same edge (eq. 13) until nothing changes.

    Pairs passing the tests are joined into connected groups, each replaced by its farthest pair
    of endpoints; repeated because a merged segment may now pass the tests with another.
    """
    S = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    if len(S) < 2:
        return S
    if d_thresh is None:
        d_thresh = 0.5 * float(np.linalg.norm(S[:, 1] - S[:, 0], axis=1).mean())
    for _ in range(max_rounds):
        same, u = _pair_tests(S, theta_thresh_deg, rho_thresh)
        # Gap along the direction of i between the projections of i and j.
        t = np.einsum("nkd,md->mnk", S, u)  # t[i, j, k]: endpoint k of j projected on u_i
        ti = np.sort(np.einsum("ikd,id->ik", S, u), axis=1)
        tj = np.sort(t, axis=2)
        gap = np.maximum(
            0.0, np.maximum(ti[:, None, 0], tj[..., 0]) - np.minimum(ti[:, None, 1], tj[..., 1])
        )
        link = same & (gap < d_thresh)
        np.fill_diagonal(link, False)
        if not link.any():
            return S
        label = np.arange(len(S))
        for i, j in zip(*np.nonzero(np.triu(link)), strict=True):
            a, b = label[i], label[j]
            if a != b:
                label[label == b] = a
        out = []
        for lab in np.unique(label):
            members = S[label == lab]
            out.append(
                members[0]
                if len(members) == 1
                else _farthest(members.reshape(-1, 2)[:2], members.reshape(-1, 2)[2:])
            )
        S = np.asarray(out).reshape(-1, 2, 2)
    return S


def _duplicate(a, b, theta_thresh_deg, rho_thresh):
    la, lb = np.linalg.norm(a[1] - a[0]), np.linalg.norm(b[1] - b[0])
    close = np.linalg.norm(a.mean(0) - b.mean(0)) < 0.5 * max(la, lb)
    return close and similar(a, b, theta_thresh_deg, rho_thresh)


def remove_duplicates(
    segments: np.ndarray, *, theta_thresh_deg: float = 3.0, rho_thresh: float = 4.0
):
    """Keep the longer of every pair of close, similar segments; returns the kept indices."""
    S = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    if len(S) == 0:
        return np.zeros(0, dtype=int)
    length = np.linalg.norm(S[:, 1] - S[:, 0], axis=1)
    same, _ = _pair_tests(S, theta_thresh_deg, rho_thresh)
    mid = S.mean(1)
    close = np.linalg.norm(mid[:, None] - mid[None], axis=-1) < 0.5 * np.maximum(
        length[:, None], length[None]
    )
    dup = same & close
    order = np.argsort(-length, kind="stable")
    kept: list[int] = []
    for i in order:
        if not kept or not dup[i, kept].any():
            kept.append(int(i))
    return np.array(sorted(kept), dtype=int)


def _cut(short, long):
    """Lengths ``(L1, L2)`` (``L1 <= L2``) of ``short`` cut by ``long``, or ``None`` if apart."""
    p, r = short[0], short[1] - short[0]
    q, s = long[0], long[1] - long[0]
    den = r[0] * s[1] - r[1] * s[0]
    if abs(den) < 1e-12:
        return None
    qp = q - p
    t = (qp[0] * s[1] - qp[1] * s[0]) / den
    w = (qp[0] * r[1] - qp[1] * r[0]) / den
    if not (0 <= t <= 1 and 0 <= w <= 1):
        return None
    L = np.linalg.norm(r)
    return sorted((t * L, (1 - t) * L))


def merge_streams(
    wge: np.ndarray, sobel: np.ndarray, *, theta_thresh_deg: float = 3.0, rho_thresh: float = 4.0
):
    """Merge the two streams. Returns ``(segments (N, 2, 2), from_wge (N,) bool)``."""
    W = np.asarray(wge, dtype=float).reshape(-1, 2, 2)
    S = np.asarray(sobel, dtype=float).reshape(-1, 2, 2)
    W = W[remove_duplicates(W, theta_thresh_deg=theta_thresh_deg, rho_thresh=rho_thresh)]
    S = S[remove_duplicates(S, theta_thresh_deg=theta_thresh_deg, rho_thresh=rho_thresh)]
    allseg = np.concatenate([S, W])
    src = np.concatenate([np.zeros(len(S), bool), np.ones(len(W), bool)])
    keep = remove_duplicates(allseg, theta_thresh_deg=theta_thresh_deg, rho_thresh=rho_thresh)
    allseg, src = allseg[keep], src[keep]
    length = np.linalg.norm(allseg[:, 1] - allseg[:, 0], axis=1)
    drop = np.zeros(len(allseg), bool)
    for i in range(len(allseg)):
        for j in range(len(allseg)):
            if src[i] == src[j] or length[i] >= length[j] or drop[j]:
                continue
            cut = _cut(allseg[i], allseg[j])
            if cut is not None and cut[0] / max(cut[1], 1e-12) > 0.25:
                drop[i] = True
                break
    return allseg[~drop], src[~drop]


def antenna_candidates(
    segments, from_wge, sobel, l_roi: float, *, theta_thresh_deg=3.0, rho_thresh=4.0
):
    """Indices of WGE segments not seen by the Sobel stream and shorter than ``l_ROI / 3``."""
    S = np.asarray(sobel, dtype=float).reshape(-1, 2, 2)
    out = []
    for i, (seg, w) in enumerate(zip(segments, from_wge, strict=True)):
        if not w or np.linalg.norm(seg[1] - seg[0]) >= l_roi / 3:
            continue
        if not any(_duplicate(seg, s, theta_thresh_deg, rho_thresh) for s in S):
            out.append(i)
    return np.array(out, dtype=int)
