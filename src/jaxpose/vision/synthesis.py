"""Feature synthesis: line segments organised into groups (Sharma et al. 2018, Sec. IV.B, Fig. 8).

The same rules serve the image (2-D segments, pixels) and the model (3-D edges, metres), so the
model's groups are "precomputed with the same conditions" as the paper asks:

* proximal pair: closest endpoints within ``d_max`` (eq. 14) and the segments not parallel; or,
  with ``corner_frac > 0`` (2-D only), the corner test: the segments' lines cross at an angle of
  at least ``corner_min_angle_deg`` and their intersection lies within ``corner_frac`` times each
  segment's own length of its nearer end (beyond it or inside it). Edges detected on a lit face
  often stop short of the corners by more than ``d_max`` while their lines still meet there;
  the junction point of a pair is always the lines' intersection;
* parallel pair: slope difference within ``theta_max`` (eq. 15) and the lines apart (not collinear);
* open polygonal triad: two proximal pairs sharing a segment, attached at its two ends, with the
  far endpoints on the same side of the shared segment (eq. 16). In 3-D "same side" means the parts
  of the two outer edges perpendicular to the middle edge do not point in opposite directions (a
  path whose outer edges are orthogonal can look like a U in some views, so it is kept);
* closed polygonal tetrad: four segments closing a loop (two triads sharing two segments);
* open polygonal tetrad: a chain of four segments (two triads sharing two segments) that is not
  closed;
* parallel triad: three mutually parallel segments (two parallel pairs sharing a segment).

Each group is stored as an ordered sequence of *points* used for correspondences: junctions
(line intersections in 2-D, the shared vertex in 3-D) and the free far endpoints. The permutations
under which a model group may correspond to an image group are :data:`PERMUTATIONS` (Table 1's
hypothesis counts: 8 for tetrads, 2 for chains, 4 for parallel pairs, 12 for parallel triads).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

__all__ = ["KINDS", "PERMUTATIONS", "POINTS_PER_GROUP", "FeatureGroups", "synthesize"]

#: Group kinds by decreasing geometric complexity (Sharma et al. 2018 Sec. IV.A ranking). The open
#: triad, absent from Table 1, is put before the parallel triad: its junctions are precise points,
#: while the six endpoints of a parallel triad move with every truncated edge (and the two-box
#: Tango model has 156 parallel triads against 96 open triads).
KINDS = (
    "closed_tetrad",
    "open_tetrad",
    "open_triad",
    "parallel_triad",
    "parallel_pair",
    "proximal_pair",
)
POINTS_PER_GROUP = {
    "closed_tetrad": 4,
    "open_tetrad": 5,
    "parallel_triad": 6,
    "open_triad": 4,
    "parallel_pair": 4,
    "proximal_pair": 3,
}


def _perms() -> dict[str, np.ndarray]:
    tet = [[(i + k) % 4 for i in range(4)] for k in range(4)]
    tet += [t[::-1] for t in tet]
    lines3 = []
    for order in itertools.permutations(range(3)):
        for flip in (False, True):
            seq = []
            for line in order:
                a, b = 2 * line, 2 * line + 1
                seq += [b, a] if flip else [a, b]
            lines3.append(seq)
    return {
        "closed_tetrad": np.array(tet),
        "open_tetrad": np.array([[0, 1, 2, 3, 4], [4, 3, 2, 1, 0]]),
        "parallel_triad": np.array(lines3),
        "open_triad": np.array([[0, 1, 2, 3], [3, 2, 1, 0]]),
        "parallel_pair": np.array([[0, 1, 2, 3], [2, 3, 0, 1], [1, 0, 3, 2], [3, 2, 1, 0]]),
        "proximal_pair": np.array([[0, 1, 2], [2, 1, 0]]),
    }


#: For each kind, the reorderings of a model group's points tried against an image group.
PERMUTATIONS = _perms()


@dataclass
class FeatureGroups:
    """Groups of one segment set.

    Attributes:
        points: kind -> ``(G, k, D)`` ordered correspondence points of each group.
        segments: kind -> ``(G, s)`` indices of the segments forming each group.
        antennas: indices of the segments classified as antennas (image only).
    """

    points: dict[str, np.ndarray] = field(default_factory=dict)
    segments: dict[str, np.ndarray] = field(default_factory=dict)
    antennas: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    def count(self, kind: str) -> int:
        return len(self.points.get(kind, ()))

    def most_complex(self) -> str | None:
        """The first kind of :data:`KINDS` with at least one group, or ``None``."""
        return next((k for k in KINDS if self.count(k)), None)

    def summary(self) -> dict[str, int]:
        return {k: self.count(k) for k in KINDS} | {"antennas": len(self.antennas)}


def _junction(a0, a1, b0, b1, fallback):
    """Intersection of the 2-D lines a and b (fallback point when near parallel); 3-D: fallback."""
    if len(a0) != 2:
        return fallback
    da, db = a1 - a0, b1 - b0
    den = da[0] * db[1] - da[1] * db[0]
    if abs(den) < 1e-9 * (np.linalg.norm(da) * np.linalg.norm(db) + 1e-300):
        return fallback
    s = ((b0[0] - a0[0]) * db[1] - (b0[1] - a0[1]) * db[0]) / den
    return a0 + s * da


def _corner_pairs(S: np.ndarray, frac: float, min_angle_deg: float):
    """Corner test for 2-D segments ``(N, 2, 2)``.

    Returns ``(ok, near)``: ``ok[i, j]`` when the lines of i and j cross at an angle of at least
    ``min_angle_deg`` and the intersection is within ``frac`` times each segment's length of its
    nearer end; ``near[i, j]`` the endpoint (0 or 1) of i nearer the intersection.
    """
    d = S[:, 1] - S[:, 0]
    length = np.linalg.norm(d, axis=1)
    w = S[None, :, 0, :] - S[:, None, 0, :]  # b0 - a0 for a = i (rows), b = j (columns)
    den = d[:, None, 0] * d[None, :, 1] - d[:, None, 1] * d[None, :, 0]
    sin = np.abs(den) / np.maximum(length[:, None] * length[None, :], 1e-300)
    ok = sin >= np.sin(np.deg2rad(min_angle_deg)) - 1e-12
    ok &= (length[:, None] > 0) & (length[None, :] > 0) & (np.abs(den) > 0)
    safe = np.where(ok, den, 1.0)
    # a0 + t d_a = b0 + s d_b: t = (w x d_b) / (d_a x d_b), parameter along i.
    t = (w[..., 0] * d[None, :, 1] - w[..., 1] * d[None, :, 0]) / safe
    near = (t >= 0.5).astype(int)
    off = np.minimum(np.abs(t), np.abs(t - 1.0))  # distance to the nearer end / own length
    ok &= (off <= frac) & (off.T <= frac)
    return ok, near


def synthesize(
    segments: np.ndarray,
    *,
    d_max: float,
    theta_max_deg: float = 5.0,
    min_separation: float = 0.0,
    max_groups: int = 64,
    corner_frac: float = 0.0,
    corner_min_angle_deg: float = 20.0,
) -> FeatureGroups:
    """Organise segments ``(N, 2, D)`` (D = 2 pixels or 3 metres) into :class:`FeatureGroups`.

    Args:
        d_max: proximal-pair endpoint distance threshold (eq. 14), in the segments' unit.
        theta_max_deg: parallel threshold (eq. 15) and the least angle of a proximal pair.
        min_separation: parallel segments must be farther apart than this (not collinear).
        max_groups: at most this many groups of each kind are kept (the longest, by summed
            segment length), to bound the number of hypotheses.
        corner_frac: scale-aware corner test for proximal pairs (2-D segments only; 0 turns it
            off): two segments also form a proximal pair when the intersection of their lines
            is within ``corner_frac`` times each segment's length of that segment's nearer end.
        corner_min_angle_deg: least angle between the two lines for the corner test.
    """
    if not (np.isfinite(corner_frac) and corner_frac >= 0.0):
        raise ValueError(f"corner_frac must be a finite number >= 0; got {corner_frac}")
    if not (0.0 <= corner_min_angle_deg <= 90.0):
        raise ValueError(f"corner_min_angle_deg must be in [0, 90]; got {corner_min_angle_deg}")
    S = np.asarray(segments, dtype=float)
    if S.ndim != 3 or S.shape[1] != 2 or S.shape[2] not in (2, 3):
        raise ValueError(f"segments must have shape (N, 2, 2) or (N, 2, 3); got {S.shape}")
    n = len(S)
    out = FeatureGroups()
    D = S.shape[2]
    if n == 0:
        for k in KINDS:
            out.points[k] = np.zeros((0, POINTS_PER_GROUP[k], D))
            out.segments[k] = np.zeros((0, 0), dtype=int)
        return out
    d = S[:, 1] - S[:, 0]
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-300)[:, None]
    cos = np.abs(u @ u.T)
    cos_max = np.cos(np.deg2rad(theta_max_deg))
    parallel = cos >= cos_max
    np.fill_diagonal(parallel, False)

    # Perpendicular separation of parallel segments (midpoint of j from the line of i).
    mid = S.mean(1)
    rel = mid[None, :, :] - S[:, None, 0, :]
    along = np.einsum("ijd,id->ij", rel, u)
    perp = np.linalg.norm(rel - along[..., None] * u[:, None, :], axis=-1)
    parallel &= np.minimum(perp, perp.T) > min_separation

    # Proximal pairs: for each ordered (i, j) the closest endpoints (ei, ej) and their distance.
    E = S.reshape(n * 2, D)
    dist = np.linalg.norm(E[:, None] - E[None], axis=-1).reshape(n, 2, n, 2)
    flat = dist.transpose(0, 2, 1, 3).reshape(n, n, 4)
    best = flat.argmin(-1)
    dmin = flat.min(-1)
    prox = (dmin <= d_max) & ~(cos >= cos_max)
    np.fill_diagonal(prox, False)
    end_i, end_j = best // 2, best % 2  # which endpoint of i (resp. j) is the near one
    if corner_frac > 0 and D == 2 and n > 1:
        corner, near = _corner_pairs(S, corner_frac, corner_min_angle_deg)
        corner &= ~prox & ~(cos >= cos_max)
        np.fill_diagonal(corner, False)
        # Pairs found by the corner test only: the near ends are those next to the intersection.
        end_i = np.where(corner, near, end_i)
        end_j = np.where(corner, near.T, end_j)
        prox |= corner

    J: dict[tuple[int, int], np.ndarray] = {}

    def junction(i, j):
        key = (min(i, j), max(i, j))
        if key not in J:
            a, b = key
            ea, eb = (end_i[a, b], end_j[a, b])
            J[key] = _junction(S[a, 0], S[a, 1], S[b, 0], S[b, 1], 0.5 * (S[a, ea] + S[b, eb]))
        return J[key]

    def keep(kind, pts, segs):
        pts = np.asarray(pts, dtype=float).reshape(-1, POINTS_PER_GROUP[kind], D)
        width = {"proximal_pair": 2, "parallel_pair": 2, "parallel_triad": 3, "open_triad": 3}
        segs = np.asarray(segs, dtype=int).reshape(len(pts), width.get(kind, 4))
        if len(pts) > max_groups:
            order = np.argsort(-length[segs].sum(1), kind="stable")[:max_groups]
            pts, segs = pts[order], segs[order]
        out.points[kind] = pts
        out.segments[kind] = segs

    # proximal pairs
    pp, ps = [], []
    for i, j in zip(*np.nonzero(np.triu(prox)), strict=True):
        pp.append([S[i, 1 - end_i[i, j]], junction(i, j), S[j, 1 - end_j[i, j]]])
        ps.append([i, j])
    keep("proximal_pair", pp, ps)

    # parallel pairs, each oriented like the first segment
    def oriented(j, ref):
        return S[j] if u[j] @ u[ref] >= 0 else S[j, ::-1]

    qp, qs = [], []
    for i, j in zip(*np.nonzero(np.triu(parallel)), strict=True):
        qp.append([S[i, 0], S[i, 1], *oriented(j, i)])
        qs.append([i, j])
    keep("parallel_pair", qp, qs)

    # parallel triads
    tp, ts = [], []
    for i, j in zip(*np.nonzero(np.triu(parallel)), strict=True):
        for k in np.nonzero(parallel[i] & parallel[j])[0]:
            if k > j:
                tp.append([S[i, 0], S[i, 1], *oriented(j, i), *oriented(k, i)])
                ts.append([i, j, k])
    keep("parallel_triad", tp, ts)

    # open triads (a - m - b), a attached at one end of m and b at the other
    attach = [[[], []] for _ in range(n)]  # attach[m][end] = segments proximal at that end of m
    for m in range(n):
        for a in np.nonzero(prox[m])[0]:
            attach[m][end_i[m, a]].append(int(a))

    def far(a, m):  # endpoint of a away from its junction with m
        return S[a, 1 - end_i[a, m]]

    def same_side(m, a, b):
        va, vb = far(a, m) - junction(a, m), far(b, m) - junction(b, m)
        va = va - (va @ u[m]) * u[m]
        vb = vb - (vb @ u[m]) * u[m]
        if D == 2:
            ca = u[m, 0] * va[1] - u[m, 1] * va[0]
            cb = u[m, 0] * vb[1] - u[m, 1] * vb[0]
            return ca * cb > 0  # eq. 16
        return va @ vb > -1e-9 * (np.linalg.norm(va) * np.linalg.norm(vb) + 1e-300)

    triads = []
    for m in range(n):
        for a in attach[m][0]:
            for b in attach[m][1]:
                if a != b and same_side(m, a, b):
                    triads.append((a, m, b))
    keep(
        "open_triad",
        [[far(a, m), junction(a, m), junction(m, b), far(b, m)] for a, m, b in triads],
        [list(t) for t in triads],
    )

    # tetrads: extend a triad (a, m, b) at b's far end by c
    closed, opened, seen_c, seen_o = [], [], set(), set()
    for a, m, b in triads:
        b_far_end = 1 - end_i[b, m]
        for c in attach[b][b_far_end]:
            if c in (a, m):
                continue
            if prox[c, a] and end_i[a, c] == 1 - end_i[a, m] and c != m:
                key = frozenset((a, m, b, c))
                if key not in seen_c:
                    seen_c.add(key)
                    closed.append((a, m, b, c))
            elif same_side(b, m, c):
                key = (a, m, b, c) if (a, m, b, c) < (c, b, m, a) else (c, b, m, a)
                if key not in seen_o:
                    seen_o.add(key)
                    opened.append((a, m, b, c))
    keep(
        "closed_tetrad",
        [[junction(c, a), junction(a, m), junction(m, b), junction(b, c)] for a, m, b, c in closed],
        [list(t) for t in closed],
    )
    keep(
        "open_tetrad",
        [
            [far(a, m), junction(a, m), junction(m, b), junction(b, c), far(c, b)]
            for a, m, b, c in opened
        ],
        [list(t) for t in opened],
    )
    return out
