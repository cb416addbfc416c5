"""Regions of interest of the target.

- :func:`roi_from_gradient`: the paper's (Sharma et al. 2018 Sec. III.A.1, Fig. 5): along each
  image axis, the positions where the CDF of the WGE-filtered gradient reaches 0.025 and 0.975.
- :func:`roi_from_segments`: over an Earth background, the box of the largest cluster of line
  segments meeting at corners.
- :func:`roi_from_silhouette`: against black space (an Earth in part of the image excluded),
  the box of the target's silhouette, faces in shadow included.
- :func:`silhouette_mask`: the target's silhouette itself, at a quarter of the resolution, for
  the silhouette term of the monocular ranking.
- :func:`silhouette_box`: the silhouette ROI grown to that finer silhouette (faces in shadow).
- :func:`box_iou`: the overlap of two boxes.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "box_iou",
    "roi_diagonal",
    "roi_from_gradient",
    "roi_from_segments",
    "roi_from_silhouette",
    "segment_distances",
    "silhouette_box",
    "silhouette_mask",
]


def _quantiles(weights: np.ndarray, lo: float, hi: float) -> tuple[float, float]:
    c = np.cumsum(weights, dtype=np.float64)
    c /= c[-1]
    return float(np.searchsorted(c, lo)), float(np.searchsorted(c, hi))


def roi_from_gradient(
    filtered: np.ndarray, *, lo: float = 0.025, hi: float = 0.975
) -> np.ndarray | None:
    """``[u0, v0, u1, v1]`` (pixels) or ``None`` when the filtered gradient is all zero."""
    if not 0 <= lo < hi <= 1:
        raise ValueError(f"need 0 <= lo < hi <= 1; got {lo}, {hi}")
    F = np.asarray(filtered, dtype=np.float64)
    total = F.sum()
    if not np.isfinite(total) or total <= 0:
        return None
    u0, u1 = _quantiles(F.sum(0), lo, hi)
    v0, v1 = _quantiles(F.sum(1), lo, hi)
    return np.array([u0, v0, u1, v1])


def box_iou(a, b) -> float:
    """Intersection over union of two boxes ``[u0, v0, u1, v1]`` (0 when they do not meet)."""
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - w * h
    return float(w * h / union) if union > 0 else 0.0


def roi_diagonal(roi) -> float:
    """``l_ROI``: the ROI's diagonal length in pixels."""
    u0, v0, u1, v1 = roi
    return float(np.hypot(u1 - u0, v1 - v0))


def segment_distances(S: np.ndarray, *, crossings: bool = True) -> np.ndarray:
    """``(N, N)`` smallest distances between the 2-D segments ``S (N, 2, 2)``: the least
    endpoint-to-segment distance both ways, and 0 where two segments cross (``crossings``)."""
    S = np.asarray(S, dtype=float)
    a, d = S[:, 0], S[:, 1] - S[:, 0]
    L2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-24)
    P = S.reshape(-1, 2)  # endpoints (2N, 2)
    r = P[:, None, :] - a[None]  # (2N, N, 2)
    t = np.clip(np.einsum("pnj,nj->pn", r, d) / L2[None], 0.0, 1.0)
    e = np.linalg.norm(r - t[..., None] * d[None], axis=-1).reshape(len(S), 2, len(S))
    D = e.min(1)  # endpoint of i to segment j
    D = np.minimum(D, D.T)
    np.fill_diagonal(D, 0.0)
    if not crossings:
        return D
    # crossings: the two endpoints of each segment on opposite sides of the other's line
    cross = d[:, None, 0] * (P[None, :, 1] - a[:, None, 1]) - d[:, None, 1] * (
        P[None, :, 0] - a[:, None, 0]
    )  # (N, 2N): side of endpoint q w.r.t. line i
    side = cross.reshape(len(S), len(S), 2)
    opp = side[..., 0] * side[..., 1] < 0
    D = np.where(opp & opp.T, 0.0, D)
    np.fill_diagonal(D, 0.0)
    return D


def roi_from_segments(
    segments: np.ndarray,
    *,
    gap_frac: float = 0.15,
    corner_deg: float = 20.0,
    outlier_shrink: float = 0.75,
    absorb_margin: float = 0.05,
    free_reach: float = 0.25,
) -> tuple[np.ndarray | None, np.ndarray]:
    """The target's ROI as the box of its largest cluster of line segments.

    A man-made target is a connected set of straight edges meeting at corners; an Earth
    background gives short isolated cloud segments and the limb, a long chain of nearly collinear
    segments. Two segments are linked when an endpoint of one is within ``gap_frac`` times the
    longer one's length of the other (corners and T-junctions, also across the gaps left by a
    weak edge broken into short pieces; a crossing alone is no link); a link is
    a *corner* when the directions differ by more than ``corner_deg``. The cluster with the
    largest total length of corner segments wins (a cluster without a corner scores nothing).

    A straight chain (segments linked without a corner) longer than the box of the rest of its
    cluster, that alone makes the cluster's box larger (removing it shrinks the box diagonal below
    ``outlier_shrink`` times), is a limb or other background line touching the target: it is
    dropped and the clusters are formed again. Last, the fragments of a target whose weak edges
    broke into pieces are taken in: every other cluster with a corner, no larger than the winning
    cluster's box, whose box meets the box so far grown by ``absorb_margin`` times its diagonal
    (repeated until none is left). The box is that of the *anchored* endpoints (within the link
    gap of another member segment) and of the free endpoints (antenna tips,
    truncated edges) that lie within ``free_reach`` times its diagonal of it; a background line
    touching the target leaves its far end out.
    Returns ``(roi [u0, v0, u1, v1] or None, member indices)``.
    """
    S = np.asarray(segments, dtype=float)
    if S.ndim != 3 or S.shape[1:] != (2, 2):
        raise ValueError(f"segments must have shape (N, 2, 2); got {S.shape}")
    n = len(S)
    none = (None, np.zeros(0, dtype=int))
    if n == 0:
        return none
    d = S[:, 1] - S[:, 0]
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-12)[:, None]
    D = segment_distances(S, crossings=False)
    link0 = D <= gap_frac * np.maximum(length[:, None], length[None])
    np.fill_diagonal(link0, False)
    corner0 = link0 & (np.abs(u @ u.T) < np.cos(np.deg2rad(corner_deg)))
    keep = np.ones(n, bool)
    for _ in range(n):
        link = link0 & keep[:, None] & keep[None]
        corner = (corner0 & link).any(1)
        roots = _components(link)
        score = np.bincount(roots, weights=length * corner, minlength=n)
        score[~keep] = 0.0
        best = int(np.argmax(score))
        if score[best] <= 0:
            return none
        idx = np.nonzero((roots == best) & keep)[0]
        chains = _components(link & ~corner0)  # runs of nearly collinear linked segments
        drop = _box_outlier(S, idx, chains, length, outlier_shrink)
        if drop is None:
            idx = _absorb_fragments(S, idx, roots, keep, corner, absorb_margin)
            return _anchored_box(S, idx, gap_frac, length, free_reach), idx
        keep[drop] = False
    return none


def _anchored_box(S, idx, gap_frac, length, reach):
    """Box of the anchored endpoints of ``idx`` (within the link gap of another member) and of
    the free ones near it (see :func:`roi_from_segments`); all endpoints when fewer than two are
    anchored or when that box is less than half the plain one."""
    ends = S[idx]  # (m, 2, 2)
    m = len(idx)
    a, d = ends[:, 0], ends[:, 1] - ends[:, 0]
    L2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-24)
    P = ends.reshape(-1, 2)
    r = P[:, None, :] - a[None]  # (2m, m, 2)
    t = np.clip(np.einsum("pnj,nj->pn", r, d) / L2[None], 0.0, 1.0)
    dist = np.linalg.norm(r - t[..., None] * d[None], axis=-1)  # endpoint to member segment
    own = np.repeat(np.arange(m), 2)
    dist[np.arange(2 * m), own] = np.inf
    gap = gap_frac * np.maximum(np.repeat(length[idx], 2)[:, None], length[idx][None])
    anchored = (dist <= gap).any(1).reshape(m, 2)
    if anchored.sum() < 2:
        return _box(ends)
    box = _box(ends[anchored])
    g = reach * roi_diagonal(box)
    lo, hi = box[:2] - g, box[2:] + g
    free = ends[~anchored]
    near = np.all((free >= lo) & (free <= hi), axis=1)
    out = _box(np.concatenate([ends[anchored], free[near]]))
    full = _box(ends)
    # a cluster whose anchored ends crowd in one spot: its box is the plain one
    return out if roi_diagonal(out) >= 0.5 * roi_diagonal(full) else full


def _box(P):
    P = P.reshape(-1, 2)
    return np.array([*P.min(0), *P.max(0)])


def _absorb_fragments(S, idx, roots, keep, corner, margin):
    """``idx`` plus the other clusters with a corner, no larger than the box of ``idx``, whose
    boxes meet the box so far grown by ``margin`` times its diagonal (repeated)."""
    members = set(idx.tolist())
    size = roi_diagonal(_box(S[idx]))
    others = {r for r in set(roots[keep & corner].tolist()) if r not in set(roots[idx].tolist())}
    changed = True
    while changed and others:
        changed = False
        box = _box(S[sorted(members)])
        g = margin * roi_diagonal(box)
        grown = box + np.array([-g, -g, g, g])
        for r in sorted(others):
            part = np.nonzero((roots == r) & keep)[0]
            b = _box(S[part])
            meets = b[0] <= grown[2] and b[2] >= grown[0] and b[1] <= grown[3] and b[3] >= grown[1]
            if meets and roi_diagonal(b) <= size:
                members.update(part.tolist())
                others.discard(r)
                changed = True
                break
    return np.array(sorted(members))


def _components(link: np.ndarray) -> np.ndarray:
    """Connected-component label (a root index) of every node of a boolean adjacency matrix."""
    n = len(link)
    parent = np.arange(n)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in zip(*np.nonzero(np.triu(link)), strict=True):
        parent[find(i)] = find(j)
    return np.array([find(i) for i in range(n)])


def _box_outlier(S, idx, chains, length, shrink):
    """The longest straight chain of the cluster ``idx`` (a limb is a chain of nearly collinear
    segments) that is longer than the diagonal of the box of the other members and whose removal
    shrinks the cluster box diagonal below ``shrink`` times; else ``None``. Returns the chain's
    indices."""
    if len(idx) < 3:
        return None
    labels = chains[idx]
    total = {c: float(length[idx[labels == c]].sum()) for c in set(labels.tolist())}
    full = S[idx].reshape(-1, 2)
    diag = roi_diagonal(_box(full))
    for c in sorted(total, key=total.get, reverse=True):
        rest = S[idx[labels != c]].reshape(-1, 2)
        if not len(rest):
            continue
        rest_diag = roi_diagonal(_box(rest))
        if total[c] > rest_diag and rest_diag < shrink * diag:
            return idx[labels == c]
    return None


def _sky_level(small: np.ndarray, max_noise: float) -> tuple[float, float, bool] | None:
    """Background level, its robust spread (1.4826 MAD) and whether the background is textured,
    of an area-shrunk image; ``None`` when no flat sky is left (see :func:`roi_from_silhouette`).

    When the spread exceeds ``max_noise`` the background is not flat (an Earth covers much of
    it): the level is then the histogram mode (the sky, when it covers more of the image than any
    one level of the Earth) and the spread that of the pixels darker than it (clouds lie on the
    bright side)."""
    med = float(np.median(small))
    spread = 1.4826 * float(np.median(np.abs(small - med)))
    if spread <= max_noise:
        return med, spread, False
    level = np.clip(np.rint(small), 0, 255).astype(np.int64).ravel()
    hist = np.convolve(np.bincount(level, minlength=256), [1, 2, 3, 2, 1], mode="same")
    med = float(np.argmax(hist))
    dark = small[small <= med]
    spread = 1.4826 * float(np.median(med - dark)) if dark.size else 0.0
    return None if spread > max_noise else (med, spread, True)


def roi_from_silhouette(
    image: np.ndarray,
    *,
    k_sigma: float = 4.0,
    short_side_px: int = 150,
    min_noise: float = 0.5,
    min_share: float = 0.5,
    max_noise: float = 3.0,
    min_sky: float = 1 / 3,
    gradient: np.ndarray | None = None,
) -> np.ndarray | None:
    """The target's ROI as the box of its silhouette against a dark background, or ``None``.

    The gradient ROI (:func:`roi_from_gradient`) sees the edges, and the faces turned away from
    the light have almost none: on the SPEED+ lightbox photographs it covered 55-79% of the
    projected model's diagonal. Those faces still differ from the background by a few grey levels
    (brighter where they reflect Earth albedo, darker where a black solar panel hides a faint
    background glow), which an average over many pixels separates from the sensor noise. The
    image is shrunk by area averaging to about ``short_side_px`` pixels on its short side; a pixel
    is foreground when it differs from the median (the background) by more than ``k_sigma``
    robust standard deviations (1.4826 MAD, at least ``min_noise`` grey levels), either way;
    gaps are closed by a 3x3 closing. Connected components touching two or more image sides are
    background (an Earth limb, a lit wall), not a target: a disc crossing the image leaves a
    convex cap, so the convex hull of those components, grown by two pixels, is the Earth, and
    the components meeting it (cloud fragments, or a target in front of the Earth) are no
    candidates; with less than ``min_sky`` of the image left as background outside it, ``None``.
    The largest remaining component is the target when it holds at least ``min_share`` of the
    area of the candidates (so a background with much structure of its own gives ``None``); the
    other components cut by one frame side do not count against it (pieces of an Earth whose
    limb crosses one side). Its box, back in full-resolution pixels, is returned.

    With ``gradient`` (an ``(H, W)`` map of the strong gradients, e.g. the WGE-filtered one of
    :func:`jaxpose.vision.wge.weak_gradient_elimination`), the target is the candidate holding
    the most gradient mass (on the component and a one-pixel border of it on the shrunk image),
    not the largest one: over a dim Earth whose limb crosses one side, the pieces of the Earth
    the threshold cuts off the limb are large, soft-edged areas, the lit target a smaller one
    with the image's sharpest edges (the area test below is unchanged). On 100 renders of the
    ``lightbox-earth`` domain (seed 2018) this chose the target instead of an Earth piece on 4
    and an Earth piece instead of declining on 1; on 60 of seed 7 the target on 2; on 100
    black-sky and Earth renders of the ``space`` domain and on the 24 SPEED+ development images
    it changed no ROI.

    A background whose robust spread on the shrunk image exceeds ``max_noise`` grey levels is not
    flat: the Earth covers much of it. The background level is then the histogram mode (the
    sky, when it covers more of the image than any one level of the Earth) and its spread that
    of the pixels darker than the mode (clouds lie on the bright side); when that spread too
    exceeds ``max_noise`` (no flat sky: the Earth fills the image), or no component touches two
    sides, ``None``: the caller then keeps the gradient or cluster ROI. (On the shrunk images
    the spread was 0.2 over rendered black space, 0.3-1.5 on the SPEED+ lightbox photographs and
    4.7-7.2 over the rendered Earth: development seed 7 of ``bench/monocular.py``; the Earth
    exclusion was developed on its ``lightbox-earth`` domain, seed 7.)
    """
    import cv2

    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image must be (H, W) grayscale; got shape {img.shape}")
    if gradient is not None and np.shape(gradient) != img.shape:
        raise ValueError(
            f"gradient must have the image's shape {img.shape}; got {np.shape(gradient)}"
        )
    H, W = img.shape
    f = max(1, min(H, W) // int(short_side_px))
    if min(H, W) // f < 8:
        return None
    small = cv2.resize(img.astype(np.float32), (W // f, H // f), interpolation=cv2.INTER_AREA)
    sky = _sky_level(small, max_noise)
    if sky is None:
        return None
    med, spread, textured = sky
    sigma = max(spread, float(min_noise))
    mask = (np.abs(small - med) > k_sigma * sigma).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return None
    x, y, w, h, area = (stats[1:, i] for i in range(5))
    hs, ws = small.shape
    sides = _sides_touched(stats[1:], small.shape)
    cand = sides < 2
    earth = np.nonzero(~cand)[0]
    if len(earth):
        # A disc crossing the image leaves a convex cap: the hull of the components touching
        # two sides, grown by two pixels, is the Earth, cloud fragments inside it included.
        pts = np.stack(np.nonzero(np.isin(labels, earth + 1))[::-1], 1).astype(np.int32)
        hull = np.zeros((hs, ws), np.uint8)
        cv2.fillConvexPoly(hull, cv2.convexHull(pts), 1)
        hull = cv2.dilate(hull, np.ones((5, 5), np.uint8))
        if ((mask == 0) & (hull == 0)).mean() < min_sky:
            return None
        cand &= np.bincount(labels[hull > 0].ravel(), minlength=n)[1:] == 0
    elif textured:
        return None
    cand = np.nonzero(cand)[0]
    if not len(cand):
        return None
    best = cand[np.argmax(area[cand])]
    if gradient is not None:
        # the target is where the strong gradients are, not the largest bright area
        mass = _component_gradient(gradient, labels, (ws, hs))[cand + 1]
        if mass.max() > 0:
            best = cand[np.argmax(mass)]
    # the other components cut by the frame are background too (pieces of an Earth whose
    # limb crosses one side), not rivals of the target
    rivals = cand[(sides[cand] == 0) | (cand == best)]
    if area[best] < 4 or area[best] < min_share * area[rivals].sum():
        return None
    box = np.array([x[best], y[best], x[best] + w[best], y[best] + h[best]], dtype=float) * f
    return np.minimum(box, [W, H, W, H])


def _component_gradient(gradient, labels, size):
    """Strong-gradient mass (``gradient``, full resolution) on each component of ``labels``
    (shrunk image of ``size (w, h)``) and its one-pixel border: index = label."""
    import cv2

    g = np.asarray(gradient, dtype=np.float32)
    small = cv2.resize(g, size, interpolation=cv2.INTER_AREA)
    grown = cv2.dilate(labels.astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.int64)
    grown = np.where(labels > 0, labels, grown)
    return np.bincount(grown.ravel(), weights=small.ravel(), minlength=int(labels.max()) + 1)


def _sides_touched(stats: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """How many image sides (0-4) each connected component touches, from the ``(k, 5)`` rows
    of ``cv2.connectedComponentsWithStats`` (x, y, width, height, area) in an image of ``shape
    (H, W)``: a component touching two is an Earth or a lit wall, not the target."""
    x, y, w, h = (stats[:, i] for i in range(4))
    hs, ws = shape
    return (x == 0).astype(int) + (y == 0) + (x + w >= ws) + (y + h >= hs)


def silhouette_mask(
    image: np.ndarray,
    box,
    *,
    factor: int = 4,
    k_sigma: float = 3.0,
    blur_px: float = 1.0,
    min_noise: float = 0.3,
    max_noise: float = 3.0,
    grow: float = 0.25,
) -> np.ndarray | None:
    """The target's silhouette near ``box`` (a silhouette ROI), ``(H // factor, W // factor)``
    uint8 in {0, 1}, or ``None`` when there is no flat sky or nothing near the box.

    :func:`roi_from_silhouette` finds the target on a ~150-pixel image with a 4-sigma threshold,
    enough for a box but not for the shape: faces in shadow a few grey levels off the background
    break into pieces there. Here the image is shrunk by area averaging by ``factor`` (a quarter:
    300 x 480 for SPEED+), smoothed by a Gaussian of ``blur_px`` (shrunk pixels), and a pixel is
    foreground when it differs from the sky level (:func:`_sky_level`) by more than ``k_sigma``
    robust standard deviations (at least ``min_noise`` grey levels), either way; a 3x3 opening
    removes isolated noise pixels and a 5x5 closing joins the faces across their edges. The
    components meeting ``box`` grown by ``grow`` of its size on each side are the target, except
    those touching two image sides (an Earth); their holes (a dark solar-cell grid on a face in
    shadow) are filled.

    The constants are round values, chosen once by looking at the SPEED+ photographs' contrast
    (shadowed faces 3-10 grey levels off a background with noise of 6-8): they were not tuned on
    any success rate. On the eight photographs of the sample, the silhouette of the labelled pose's
    projected model overlapped this mask with an IoU of 0.71-0.85 on the four whose target lies
    against the dark lightbox with its faces in shadow brighter than it (0.29 on the fifth, whose
    large face in shadow is as dark as the background); the three over the Earth have no mask.
    """
    import cv2

    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image must be (H, W) grayscale; got shape {img.shape}")
    if int(factor) < 1:
        raise ValueError(f"factor must be an integer >= 1; got {factor}")
    f = int(factor)
    H, W = img.shape
    if min(H, W) // f < 8:
        return None
    small = cv2.resize(img.astype(np.float32), (W // f, H // f), interpolation=cv2.INTER_AREA)
    if blur_px > 0:
        small = cv2.GaussianBlur(small, (0, 0), blur_px)
    sky = _sky_level(small, max_noise)
    if sky is None:
        return None
    med, spread, _ = sky
    mask = (np.abs(small - med) > k_sigma * max(spread, float(min_noise))).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    u0, v0, u1, v1 = np.asarray(box, dtype=float) / f
    gu, gv = grow * (u1 - u0), grow * (v1 - v0)
    hs, ws = mask.shape
    a0, b0 = int(max(np.floor(u0 - gu), 0)), int(max(np.floor(v0 - gv), 0))
    a1, b1 = int(min(np.ceil(u1 + gu) + 1, ws)), int(min(np.ceil(v1 + gv) + 1, hs))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    keep = np.unique(labels[b0:b1, a0:a1])
    keep = keep[keep > 0]
    # a component touching two image sides is an Earth or a lit wall (merged with the target, or
    # beside it), as in roi_from_silhouette: not the target's shape
    keep = keep[_sides_touched(stats[keep], (hs, ws)) < 2]
    if not len(keep):
        return None
    out = np.isin(labels, keep).astype(np.uint8)
    # fill holes: what the background flood from outside does not reach
    flood = np.pad(out, 1)
    cv2.floodFill(flood, np.zeros((hs + 4, ws + 4), np.uint8), (0, 0), 1)
    return out | (1 - flood[1:-1, 1:-1])


def silhouette_box(
    mask: np.ndarray, box, factor: int, *, min_share: float = 0.05, slack: float = 2.0
) -> np.ndarray:
    """``box`` (a silhouette ROI, full-resolution pixels) grown to the finer silhouette ``mask``
    (:func:`silhouette_mask`, shrunk by ``factor``): faces in shadow.

    :func:`roi_from_silhouette` thresholds at 4 robust standard deviations on a ~150-pixel image,
    where faces in shadow a few grey levels off the background drop out; the mask, at 3 on a
    quarter-resolution image, keeps more of them. Only its components that touch at most one
    image side (a component touching two is an Earth or a lit wall merged with the target) and
    hold at least ``min_share`` of the largest such component's area (not isolated noise) count.
    Each side of ``box`` moves out to their box where that lies more than ``slack`` mask pixels
    beyond it (the mask's blur and closing widen a silhouette by about one pixel: a side that the
    mask only reaches by that is kept). ``min_share`` and ``slack`` are round values, chosen
    before any measurement of them."""
    import cv2

    m = np.asarray(mask)
    if m.ndim != 2:
        raise ValueError(f"mask must be (H, W); got shape {m.shape}")
    if int(factor) < 1:
        raise ValueError(f"factor must be an integer >= 1; got {factor}")
    box = np.asarray(box, dtype=float)
    n, _, stats, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8), connectivity=8)
    if n <= 1:
        return box
    x, y, w, h, area = (stats[1:, i] for i in range(5))
    ok = _sides_touched(stats[1:], m.shape) < 2
    if not ok.any():
        return box
    ok &= area >= min_share * area[ok].max()
    f = int(factor)
    reach = np.array([x[ok].min(), y[ok].min(), (x + w)[ok].max(), (y + h)[ok].max()], float) * f
    beyond = np.r_[box[:2] - reach[:2], reach[2:] - box[2:]] > slack * f
    return np.where(beyond, reach, box)
