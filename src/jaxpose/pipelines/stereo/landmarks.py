"""Body-frame landmark map of the stereo tracker (points and line segments with descriptors).

The tracker of :mod:`jaxpose.pipelines.stereo` does not chain frame-to-keyframe increments: it
tracks every frame against a map of 3-D landmarks fixed in the *target* (body) frame, as
feature-based visual odometry does (ORB-SLAM's local map). A landmark is created from a stereo
triangulation of a keyframe, transformed to the body frame with that keyframe's estimated pose, and
refined at later keyframes by a running mean of its body-frame triangulations. Because the map is
attached to the body, a face that rotates away and back (the target turns twice) is tracked against
the landmarks seen the first time instead of a chain of new increments, so the error stays bounded
rather than growing as a random walk.

Visibility: a landmark keeps the mean direction from which it was observed (body frame); it is a
candidate only when the current viewing direction is within ``max_view_deg`` of it (a face seen
from behind, or at grazing incidence, is not searched) and it projects inside the image. Landmarks
that are predicted visible but rarely found (ORB-SLAM's found/visible ratio) are culled.

Pure NumPy (application side); the pose solve stays in :func:`jaxpose.core.refine.refine_pose`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo._arrays import rt, scatter_add, solve3, sym3_eigvalsh, unit_rows

__all__ = ["LandmarkMap", "LandmarkSet", "map_origin"]

#: The map's origin is moved to its first landmarks when the given one lies farther from their
#: median than this many times their median distance from it (outside the target).
ORIGIN_SPREADS = 3.0


def map_origin(pose: Pose, points_cam: np.ndarray) -> np.ndarray:
    """``(3,)`` where the tracker puts its map's origin, in the given target frame (metres):
    ``0`` (the given origin) when it lies within the first frame's landmarks ``points_cam``
    (``(p, 3)``, left camera, metres; ``pose`` the given first pose), else their median.

    The tracker adjusts poses by turning them about the map's origin: an origin far from the
    landmarks (the first camera's, for a start at the identity) couples the turn with a sideways
    shift as large as the range times the angle, which the few Gauss-Newton iterations of each
    frame and window do not undo (at 5 m the aligned errors of an identity start were twice a
    truth start's, ``docs/stereo-evaluation.md``, *The map's origin*). The rule depends on the
    landmarks, not on how the start was made: a body origin within the target (the truth, the
    monocular initialisation) is kept."""
    R, t = rt(pose)
    X = (np.asarray(points_cam, float) - t) @ R  # R^T (x - t): the given target frame
    if len(X) < 10:
        return np.zeros(3)
    m = np.median(X, axis=0)
    spread = float(np.median(np.linalg.norm(X - m, axis=1)))
    return m if np.linalg.norm(m) > ORIGIN_SPREADS * spread else np.zeros(3)


@dataclass
class LandmarkSet:
    """One kind of landmark (``points``: ``X`` is ``(M, 3)``; ``lines``: ``(M, 2, 3)``).

    Attributes:
        X: body-frame positions (point or segment endpoints), metres.
        desc: ``(M, 32)`` uint8 binary descriptors (ORB or LBD), the latest observation's.
        memory: ``(M, S, 32)`` the descriptors of the latest ``S`` observations (the map's
            ``descriptor_memory``; slots not yet filled hold the first), which the search by
            projection matches by the nearest.
        view: ``(M, 3)`` unit mean viewing direction (from the landmark towards the camera, body
            frame).
        n_obs: keyframe observations (stereo pairs) of the landmark.
        ids: stable identifiers (increasing; indices change when landmarks are culled).
        M, b: normal equations of the multi-view triangulation of a point (``X = M^-1 b``, the
            point nearest to all its observation rays in the weighted least-squares sense).
        visible, found: times predicted visible / matched as an inlier (culling).
        last_seen: frame index of the last inlier match.
    """

    X: np.ndarray
    desc: np.ndarray = field(default_factory=lambda: np.zeros((0, 32), np.uint8))
    memory: np.ndarray = field(default_factory=lambda: np.zeros((0, 1, 32), np.uint8))
    view: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    n_obs: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    visible: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    found: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    last_seen: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    M: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    b: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def __len__(self) -> int:
        return len(self.X)

    def centres(self) -> np.ndarray:
        """``(M, 3)`` points, or segment midpoints."""
        return self.X if self.X.ndim == 2 else self.X.mean(axis=1)

    def _keep(self, keep: np.ndarray) -> None:
        for name in (
            "X",
            "desc",
            "memory",
            "view",
            "n_obs",
            "visible",
            "found",
            "last_seen",
            "M",
            "b",
            "ids",
        ):
            setattr(self, name, getattr(self, name)[keep])


def rays_meet(M: np.ndarray) -> np.ndarray:
    """Whether point landmarks' observation rays meet in a point, from their summed normal
    matrices ``M (k, 3, 3)`` (``sum w (I - d d^T)``, :meth:`LandmarkMap.observe`): the smallest
    eigenvalue at least ``1e-4`` of the largest (nearly parallel rays leave the depth
    undetermined). ``(k,)`` bool."""
    ev = sym3_eigvalsh(M)
    return ev[:, 0] > 1e-4 * ev[:, 2]


def planes_meet(ev: np.ndarray) -> np.ndarray:
    """Whether a line landmark's observation planes meet in a line, from the ascending
    eigenvalues ``ev (k, 3)`` of their summed ``sum w n n^T``: the second at least ``1e-4`` of
    the largest (nearly parallel planes leave the line undetermined)."""
    return ev[:, 1] > 1e-4 * ev[:, 2]


def surface_normals(X: np.ndarray, idx, k: int = 40, max_flatness: float = 0.3) -> np.ndarray:
    """Unit surface normals ``(len(idx), 3)`` at the point landmarks ``X[idx]`` (body frame),
    from their ``k`` nearest landmarks (themselves among them): the direction of least spread
    of those points (principal components), kept where they lie on a plane, the least spread
    at most ``max_flatness`` of the middle one (in standard deviations); a NaN row elsewhere
    (an edge or corner of the target, where two faces meet, or too few points)."""
    X = np.asarray(X, float)
    idx = np.asarray(idx, int)
    out = np.full((len(idx), 3), np.nan)
    if len(idx) == 0 or len(X) < max(int(k), 4):
        return out
    _, nb = cKDTree(X).query(X[idx], k=int(k))
    P = X[nb] - X[nb].mean(axis=1, keepdims=True)  # (n, k, 3)
    ev, V = np.linalg.eigh(np.einsum("nki,nkj->nij", P, P))
    flat = np.sqrt(np.maximum(ev[:, 0], 0)) <= max_flatness * np.sqrt(np.maximum(ev[:, 1], 0))
    out[flat] = V[flat, :, 0]
    return out


class LandmarkMap:
    """Points and line segments in the body frame (module docstring).

    Args:
        max_view_deg: a landmark is searched only within this angle of its mean viewing direction.
        max_obs: cap of the running mean (later triangulations keep a weight ``1 / max_obs``).
        cull_after, cull_ratio: a landmark predicted visible at least ``cull_after`` times and
            found in fewer than ``cull_ratio`` of them is removed, unless it was triangulated
            ``keep_obs`` times or more (such a landmark is kept for the next turn of the target:
            ORB finds a given corner again only in a fraction of the frames that see it).
        max_points, max_lines: map sizes; beyond them the least recently seen are removed.
        descriptor_memory: ORB descriptors a point landmark keeps (its latest observations',
            :attr:`LandmarkSet.memory`); the line landmarks keep their latest LBD descriptor.
    """

    def __init__(
        self,
        *,
        max_view_deg: float = 60.0,
        max_obs: int = 10,
        cull_after: int = 8,
        cull_ratio: float = 0.25,
        keep_obs: int = 3,
        max_points: int = 20000,
        max_lines: int = 2000,
        descriptor_memory: int = 1,
    ):
        if not 0 < max_view_deg <= 180:
            raise ValueError(f"max_view_deg must be in (0, 180]; got {max_view_deg}")
        if max_obs < 1 or cull_after < 1 or not 0 <= cull_ratio <= 1:
            raise ValueError("max_obs and cull_after must be >= 1 and cull_ratio in [0, 1]")
        if int(descriptor_memory) != descriptor_memory or descriptor_memory < 1:
            raise ValueError(
                f"descriptor_memory must be an integer >= 1; got {descriptor_memory!r}"
            )
        self.cos_view = float(np.cos(np.radians(max_view_deg)))
        self.max_obs, self.cull_after, self.cull_ratio = int(max_obs), int(cull_after), cull_ratio
        self.keep_obs = int(keep_obs)
        self.max_size = {"points": int(max_points), "lines": int(max_lines)}
        self._next_id = {"points": 0, "lines": 0}
        self.sets = {
            "points": LandmarkSet(
                np.zeros((0, 3)), memory=np.zeros((0, int(descriptor_memory), 32), np.uint8)
            ),
            "lines": LandmarkSet(np.zeros((0, 2, 3))),
        }

    @property
    def points(self) -> LandmarkSet:
        return self.sets["points"]

    @property
    def lines(self) -> LandmarkSet:
        return self.sets["lines"]

    # ------------------------------------------------------------------ queries
    def candidates(self, kind: str, pose: Pose) -> np.ndarray:
        """Indices of the ``kind`` landmarks in front of the camera at ``pose`` (body to camera)
        and seen from within ``max_view_deg`` of their mean viewing direction."""
        R, t = rt(pose)
        s = self.sets[kind]
        if len(s) == 0:
            return np.zeros(0, int)
        c = s.centres()
        centre_body = -R.T @ t  # camera centre in the body frame
        d = unit_rows(centre_body[None] - c)
        z = c @ R[2] + t[2]
        return np.nonzero((np.einsum("ij,ij->i", d, s.view) >= self.cos_view) & (z > 1e-3))[0]

    # ------------------------------------------------------------------ updates
    def add(self, kind: str, X_body, desc, pose: Pose, frame: int) -> np.ndarray:
        """Append landmarks observed from the camera at ``pose``; returns their indices."""
        R, t = rt(pose)
        s = self.sets[kind]
        X_body = np.asarray(X_body, float)
        n = len(X_body)
        if n == 0:
            return np.zeros(0, int)
        c = X_body if X_body.ndim == 2 else X_body.mean(axis=1)
        view = unit_rows((-R.T @ t)[None] - c)
        start = len(s)
        s.X = np.concatenate([s.X, X_body])
        desc = np.asarray(desc, np.uint8).reshape(n, -1)
        s.desc = np.concatenate([s.desc, desc])
        s.memory = np.concatenate([s.memory, np.repeat(desc[:, None], s.memory.shape[1], 1)])
        s.view = np.concatenate([s.view, view])
        s.n_obs = np.concatenate([s.n_obs, np.ones(n, np.int64)])
        s.visible = np.concatenate([s.visible, np.zeros(n, np.int64)])
        s.found = np.concatenate([s.found, np.zeros(n, np.int64)])
        s.last_seen = np.concatenate([s.last_seen, np.full(n, frame, np.int64)])
        s.M = np.concatenate([s.M, np.zeros((n, 3, 3))])
        s.b = np.concatenate([s.b, np.zeros((n, 3))])
        s.ids = np.concatenate([s.ids, self._next_id[kind] + np.arange(n, dtype=np.int64)])
        self._next_id[kind] += n
        return np.arange(start, start + n)

    def observe(self, idx, origins, directions, weights=None) -> None:
        """Add observation rays of points ``idx`` (body frame: camera centres ``origins`` and
        directions, ``(n, 3)`` each) to their triangulations and re-solve them: ``X`` becomes the
        weighted least-squares point nearest to all the rays seen so far, ``sum w (I - d d^T)
        (X - c) = 0``. The rays of a stereo pair alone give the stereo triangulation; the rays of
        later frames add the parallax of the target's rotation, far wider than the stereo
        baseline. A point whose rays are still too close to parallel keeps its position.
        ``weights``: ``(n,)``, e.g. ``1 / depth^2`` to weight by the pixel error."""
        s = self.points
        idx = np.asarray(idx, int)
        if len(idx) == 0:
            return
        d = unit_rows(np.asarray(directions, float))
        c = np.asarray(origins, float)
        w = np.ones(len(idx)) if weights is None else np.asarray(weights, float)
        P = w[:, None, None] * (np.eye(3)[None] - d[:, :, None] * d[:, None, :])
        scatter_add(s.M, idx, P)
        scatter_add(s.b, idx, np.einsum("nij,nj->ni", P, c))
        u = np.unique(idx)
        u = u[rays_meet(s.M[u])]
        if len(u):
            s.X[u] = solve3(s.M[u], s.b[u])

    def observe_lines(self, idx, normals, offsets, weights=None) -> None:
        """Add observation planes ``normals . X = offsets`` (body frame; ``(n, 3)`` and ``(n,)``:
        the plane through a camera centre and an image segment) of line landmarks ``idx`` and
        re-solve them: the line is the weighted least-squares intersection of all its planes
        (``sum w n n^T``, ``sum w d n`` kept in ``M``, ``b``), and each endpoint moves
        perpendicularly to that line onto it (the planes say nothing of where a segment ends).
        A line whose planes are still nearly parallel (:func:`planes_meet`) keeps its
        endpoints."""
        s = self.lines
        idx = np.asarray(idx, int)
        if len(idx) == 0:
            return
        n = np.asarray(normals, float)
        norm = np.linalg.norm(n, axis=1)
        norm = np.where(norm > 0, norm, 1.0)
        n, d = n / norm[:, None], np.asarray(offsets, float) / norm
        w = np.ones(len(idx)) if weights is None else np.asarray(weights, float)
        scatter_add(s.M, idx, w[:, None, None] * n[:, :, None] * n[:, None, :])
        scatter_add(s.b, idx, (w * d)[:, None] * n)
        u = np.unique(idx)
        ev, V = np.linalg.eigh(s.M[u])
        ok = planes_meet(ev)
        u, ev, V = u[ok], ev[ok], V[ok]
        if len(u):
            V2 = V[:, :, 1:]  # the two directions across the line
            X = s.X[u]  # (k, 2, 3)
            r = s.b[u][:, None] - np.einsum("kij,kej->kei", s.M[u], X)  # (k, 2, 3)
            y = np.einsum("kia,kei->kea", V2, r) / ev[:, None, 1:]
            s.X[u] = X + np.einsum("kia,kea->kei", V2, y)

    def refine(self, kind: str, idx, X_body, desc, pose: Pose, frame: int) -> None:
        """Fold new body-frame triangulations ``X_body`` of landmarks ``idx`` into their running
        means (``X_body=None``: keep the positions, update descriptor and viewing direction; the
        tracker does so for segments, whose endpoints differ from one detection to the next, and
        for points, whose positions come from :meth:`observe`)."""
        s = self.sets[kind]
        idx = np.asarray(idx, int)
        if len(idx) == 0:
            return
        w = 1.0 / (np.minimum(s.n_obs[idx], self.max_obs - 1) + 1.0)
        if X_body is not None:
            X_body = np.asarray(X_body, float)
            s.X[idx] = s.X[idx] + w.reshape((-1,) + (1,) * (X_body.ndim - 1)) * (X_body - s.X[idx])
        R, t = rt(pose)
        c = s.centres()[idx]
        v = unit_rows((-R.T @ t)[None] - c)
        s.view[idx] = unit_rows(s.view[idx] + w[:, None] * (v - s.view[idx]))
        s.desc[idx] = np.asarray(desc, np.uint8).reshape(len(idx), -1)
        s.memory[idx, s.n_obs[idx] % s.memory.shape[1]] = s.desc[idx]
        np.add.at(s.n_obs, idx, 1)
        s.last_seen[idx] = frame

    def record(self, kind: str, searched, found, frame: int) -> None:
        """Count the landmarks ``searched`` (predicted visible) and those ``found`` (inliers)."""
        s = self.sets[kind]
        s.visible[np.asarray(searched, int)] += 1
        found = np.asarray(found, int)
        s.found[found] += 1
        s.last_seen[found] = frame

    def cull(self) -> None:
        """Remove the landmarks rarely found when predicted visible, then the least recently seen
        beyond the size caps."""
        for kind, s in self.sets.items():
            bad = (
                (s.visible >= self.cull_after)
                & (s.found < self.cull_ratio * s.visible)
                & (s.n_obs < self.keep_obs)
            )
            keep = ~bad
            if keep.sum() > self.max_size[kind]:
                order = np.argsort(-s.last_seen[keep], kind="stable")
                sel = np.nonzero(keep)[0][order[: self.max_size[kind]]]
                keep = np.zeros(len(s), bool)
                keep[sel] = True
            if not keep.all():
                s._keep(keep)
