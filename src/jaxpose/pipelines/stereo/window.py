"""Windowed joint adjustment of the last keyframes' poses and the landmarks they see.

The tracker solves each frame's pose against the landmark map and then places the frame's rays
in the body frame at that pose (:func:`~jaxpose.pipelines.stereo.keyframes.observe_point_rays`),
so a frame's pose error enters every landmark it observes and every later pose that leans on
them. At range the first frames' poses are the weakest (their landmarks hold only the depth of
one stereo pair), and their spin-phase error is then kept by the whole map: on the 3 m and 5 m
development scenes the error about the spin axis appears within the first few frames and stays
constant afterwards.

This module re-estimates the poses of the last ``K`` frames together with the point landmarks
they observed: a bundle adjustment (Triggs et al. 2000) of the left and right pixel residuals
(the point cost of Yang et al. 2024, eq. 8, with a Huber kernel), where each landmark also keeps
the information of its observation rays from frames outside the window as a Gaussian prior
(the normal equations ``M, b`` of :meth:`~jaxpose.pipelines.stereo.LandmarkMap.observe`, in
pixels: ``f^2 (X^T M X - 2 b^T X)``). Long-lived landmarks are therefore held by all their past
observations (anchors). The gauge is fixed by the first frame's pose while it is in the
window, then by those priors (``gauge="rays"``, the default since 2026-12-02; the oldest frame's
pose held where it is when fewer than ten of the window's landmarks have rays from outside it
that meet), or by the oldest frame's pose (``gauge="oldest"``, before). Holding the oldest pose
fixed takes it as exact, so the error it carries stays in the window's frames; the priors are
the information the frames that left gathered. The line landmarks are adjusted the same way
(``free_lines``): each line seen by the window's stereo planes (the planes through a camera
centre and an image segment, :func:`~jaxpose.pipelines.stereo.keyframes.observe_line_planes`)
has its two endpoints free, observed by those planes (Yang et al. 2024 eq. 9 in the plane's
form, left and right image), and keeps the planes of the frames outside the window as a prior
(the line's plane normal equations less the window's planes). The window's other matched lines
(no plane in the window, or planes that do not meet) are left out, as the points beyond the
cap are: held where the map has them (``held_lines``, the default until 2026-12-02) they were
taken as exact, and one placed askew by its only stereo pair tilted a window. The solver is
:func:`jaxpose.core.refine.adjust_window` (Gauss-Newton with a small Levenberg damping, the Schur
complement on the ``3 x 3`` landmark and endpoint blocks, Jacobians by ``jax.jacfwd`` of one
observation's residual; compiled once): this module gathers the window's observations, priors
and line terms into its padded visibility grid (``frames`` x ``max_points`` landmarks x two
images; ``max_lines`` free lines x two planes; held line rows a frame: ``2 max_lines`` without
free lines, else a sixth of that, as few lines are held then).

After the adjustment the rays and line planes of the window's frames are moved to the adjusted
poses (removed at the old pose, added at the new one) and the landmarks re-solved from them, so
the map stays the least-squares intersection of all its rays and planes.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np

from jaxpose.core.camera import StereoCamera
from jaxpose.core.geometry import Pose
from jaxpose.core.refine import WindowLines, WindowObservations, WindowOptions, adjust_window
from jaxpose.core.status import Status
from jaxpose.pipelines.stereo._arrays import find, rows_times, scatter_add, sym3_eigvalsh
from jaxpose.pipelines.stereo.landmarks import LandmarkMap, planes_meet, rays_meet
from jaxpose.pipelines.stereo.options import WINDOW_GAUGES

__all__ = ["FrameRays", "WindowAdjuster"]

#: Landmarks whose rays from outside the window must meet for those rays to hold the gauge
#: (``gauge="rays"``); with fewer the oldest frame holds it.
GAUGE_POINTS = 10


@dataclass
class FrameRays:
    """The point rays and line planes one frame added to the map, and the pose they were placed at.

    Attributes:
        R, t: the frame's pose (body to left camera), NumPy.
        rays: the point rays, one chunk per :meth:`add` (stable landmark ids
            :attr:`LandmarkSet.ids` ``(n,)``, observed pixels ``(n, 2)``, right-image flags
            ``(n,)``, weights ``1 / depth^2`` ``(n,)``); :meth:`arrays` concatenates them.
        fixed: the frame's pose is a gauge anchor (the given first pose).
        index: the frame's number.
        line_ids, lines: stable ids of the line landmarks matched in the left image and the
            observed homogeneous image lines ``(k, 3)``; ``line_weight``: ``1 / line_sigma^2``.
        planes: the line landmarks' observation planes the frame added to the map, one chunk per
            :meth:`add_planes` (stable ids, unit normals ``(k, 3)`` and offsets ``(k,)`` in the
            left camera frame, the camera ``0`` left or ``1`` right, weights ``1 / depth^2``);
            :meth:`plane_arrays` concatenates them.
    """

    R: np.ndarray
    t: np.ndarray
    rays: list = field(default_factory=list)
    fixed: bool = False
    index: int = -1
    line_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    lines: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    line_weight: float = 1.0
    planes: list = field(default_factory=list)

    def add(self, ids, pixels, right: bool, weights) -> None:
        n = len(ids)
        if n:
            self.rays.append(
                (
                    np.asarray(ids, np.int64),
                    np.asarray(pixels, float).reshape(n, 2),
                    np.full(n, bool(right)),
                    np.asarray(weights, float).reshape(n),
                )
            )

    def arrays(self):
        """``(ids, pixels, right, weights)`` of all the frame's rays."""
        empty = (np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0, bool), np.zeros(0))
        return _columns(self.rays, empty)

    def add_planes(self, ids, normals, offsets, cam: int, weights) -> None:
        n = len(ids)
        if n:
            self.planes.append(
                (
                    np.asarray(ids, np.int64),
                    np.asarray(normals, float).reshape(n, 3),
                    np.asarray(offsets, float).reshape(n),
                    np.full(n, int(cam)),
                    np.asarray(weights, float).reshape(n),
                )
            )

    def plane_arrays(self):
        """``(ids, normals, offsets, cameras, weights)`` of all the frame's line planes."""
        empty = (
            np.zeros(0, np.int64),
            np.zeros((0, 3)),
            np.zeros(0),
            np.zeros(0, int),
            np.zeros(0),
        )
        return _columns(self.planes, empty)


def _columns(chunks: list, empty: tuple) -> tuple:
    """The columns of ``chunks`` (equal-length tuples of arrays) concatenated; ``empty`` when
    there is none."""
    if not chunks:
        return empty
    return tuple(np.concatenate(c) for c in zip(*chunks, strict=True))


def ray_geometry(rig: StereoCamera, R, t, pixels, right):
    """Body-frame origins and directions of the rays of ``pixels`` seen at pose ``(R, t)``."""
    cam = rig.left
    fx, fy, cx, cy = (float(v) for v in (cam.fx, cam.fy, cam.cx, cam.cy))
    d = np.stack([(pixels[:, 0] - cx) / fx, (pixels[:, 1] - cy) / fy, np.ones(len(pixels))], 1)
    centre = np.where(right[:, None], -np.asarray(rig.t_rl, float)[None], 0.0)
    return (centre - t) @ R, d @ R


class WindowAdjuster:
    """The last ``frames`` frames' rays and poses, and their joint adjustment (module docstring).

    Args:
        rig: the rectified rig of the tracker.
        frames: window size ``K`` (poses adjusted; at least 2).
        iterations: Gauss-Newton iterations per adjustment.
        huber_px: Huber threshold of the pixel residuals.
        max_points: most landmarks in the solve (those with the most observations in the
            window; the cost grows with the observations: at 1.5 m a window holds thousands).
        max_lines: most line observations a frame (the tracker's ``max_lines``).
        motion_sigma: ``(deg, mm)`` of the constant-twist prior on consecutive frames
            (:func:`jaxpose.core.refine.motion_residual`), or ``None`` (no prior).
        free_lines: the line landmarks observed by the window's stereo planes are adjusted
            with the poses (:class:`jaxpose.core.refine.WindowLines`: their endpoints free,
            the planes from outside the window as a prior; at most ``max_lines``, those with
            the most planes in the window; five development scenes had at most 85 of 96); off,
            the lines' endpoints are held where the map has them (at most ``2 max_lines``
            endpoint rows a frame; a frame with more keeps its first ones).
        anchors: most past frames kept for the global adjustment (:meth:`adjust` with
            ``spanning=True``): the fixed first frame and frames spread over the run (a frame
            leaving the recent window is kept when it is at least ``spacing`` frames after
            the last one kept; when more than ``anchors`` are kept every other one is dropped
            and the spacing doubled). ``0``: none.
        anchor_points: most landmarks in the global adjustment.
        history: keep every frame's ray record (:attr:`history`) for the offline smoothing of
            :mod:`jaxpose.pipelines.stereo.smooth`; memory grows with the sequence.
        lines: ``False``: no line term at all, held or free (the poses from the points' rays
            alone; a diagnosis of what the lines do).
        held_lines: with ``free_lines``, also hold the window's other matched lines (no
            observation plane in the window, or planes that do not meet) where the map has them,
            their left-image lines in the pose blocks (``2 ceil(max_lines / 6)`` endpoint rows a
            frame); off (the default), they are left out of the adjustment, as the points
            beyond ``max_points`` are. A line held so is taken as exact: one placed askew by
            its only stereo pair moved a 2.5 m window's last pose by 5 mm
            (``docs/stereo-evaluation.md``, *Lines held in the window*).
        gauge: what holds the gauge once no frame of the window is fixed
            (:data:`~jaxpose.pipelines.stereo.options.WINDOW_GAUGES`):
            ``"rays"`` the rays of the frames that left the window (the landmarks' priors;
            the oldest frame's pose where fewer than :data:`GAUGE_POINTS` of the window's
            landmarks have such rays that meet), ``"oldest"`` the oldest frame's pose.
    """

    def __init__(
        self,
        rig: StereoCamera,
        frames: int = 6,
        iterations: int = 3,
        huber_px: float = 1.5,
        max_points: int = 600,
        max_lines: int = 96,
        motion_sigma: tuple[float, float] | None = None,
        free_lines: bool = True,
        anchors: int = 0,
        anchor_points: int = 1000,
        history: bool = False,
        lines: bool = True,
        held_lines: bool = False,
        gauge: str = "rays",
    ):
        if gauge not in WINDOW_GAUGES:
            raise ValueError(f"gauge must be one of {WINDOW_GAUGES}; got {gauge!r}")
        if frames < 2:
            raise ValueError(f"window frames must be >= 2; got {frames}")
        if anchors < 0:
            raise ValueError(f"anchors must be >= 0; got {anchors}")
        self.rig = rig
        self.frames: deque[FrameRays] = deque(maxlen=int(frames))
        self.anchors = int(anchors)
        self.anchor_points = int(anchor_points)
        self.kept: list[FrameRays] = []  # past frames of the global adjustment
        self.history: list[FrameRays] | None = [] if history else None  # every frame's record
        self.lines = bool(lines)
        self._spacing = 1
        self.options = WindowOptions(
            iterations=int(iterations),
            huber_px=float(huber_px),
            motion_prior=motion_sigma is not None,
        )
        self.max_points = int(max_points)
        self.max_lines = int(max_lines)
        self.free_lines = bool(free_lines) and bool(lines)
        self.held_lines = bool(held_lines)
        self.gauge = gauge
        # endpoint rows of held lines a frame: all of a frame's lines without free lines; with
        # them only the lines whose planes do not yet meet (a sixth of the lines is ample)
        if not self.free_lines:
            self._held_rows = 2 * self.max_lines
        else:  # a padding row a frame when none is held
            self._held_rows = 2 * -(-self.max_lines // 6) if self.held_lines else 1
        self.motion_sigma = motion_sigma  # (deg, mm), or None
        c = rig.left
        self.f = (float(c.fx), float(c.fy))
        self.c = (float(c.cx), float(c.cy))
        self.t_rl = np.asarray(rig.t_rl, float)

    def start(self, R, t, *, fixed: bool = False, index: int = -1) -> FrameRays:
        """Open the ray record of frame ``index`` (the oldest leaves the window when it is full)."""
        fr = FrameRays(np.array(R, float), np.array(t, float), fixed=fixed, index=index)
        if len(self.frames) == self.frames.maxlen:
            self._keep(self.frames[0])
        self.frames.append(fr)
        if self.history is not None:
            self.history.append(fr)
        return fr

    def resize(self, frames: int) -> None:
        """Hold the last ``frames`` frames from now on (at least 2; the tracker's far window,
        ``TrackerOptions.window_frames_far``). A smaller window lets its oldest frames go as
        they would leave one by one (kept for the global adjustment, ``anchors``); the
        adjustment's padded size follows (compiled once per size, :meth:`warm_up`)."""
        frames = int(frames)
        if frames < 2:
            raise ValueError(f"window frames must be >= 2; got {frames}")
        if frames == self.frames.maxlen:
            return
        while len(self.frames) > frames:
            self._keep(self.frames.popleft())
        self.frames = deque(self.frames, maxlen=frames)

    def _keep(self, fr: FrameRays) -> None:
        """Keep a frame leaving the recent window for the global adjustment (``anchors``)."""
        if not self.anchors:
            return
        if not (fr.fixed or not self.kept or fr.index - self.kept[-1].index >= self._spacing):
            return
        self.kept.append(fr)
        if len(self.kept) > self.anchors:
            fixed = [k for k in self.kept if k.fixed]
            rest = [k for k in self.kept if not k.fixed]
            self.kept = fixed + rest[(len(rest) - 1) % 2 :: 2]  # the newest stays
            self._spacing *= 2

    def _motion_weight(self, f: int, frames=None) -> np.ndarray:
        """``(f, 6)`` weights of the constant-twist prior: ``1 / sigma^2`` at each frame whose
        neighbours in the window are the frames just before and after it (no frame lost
        between), zero elsewhere and without ``motion_sigma``."""
        w = np.zeros((f, 6))
        if self.motion_sigma is None:
            return w
        deg, mm = self.motion_sigma
        row = np.r_[np.full(3, (1e3 / mm) ** 2), np.full(3, np.degrees(1.0 / deg) ** 2)]
        idx = [fr.index for fr in (self.frames if frames is None else frames)]
        for j in range(1, len(idx) - 1):
            if idx[j - 1] + 1 == idx[j] == idx[j + 1] - 1:
                w[j] = row
        return w

    def warm_up(self, sizes=()) -> None:
        """Compile the adjustment for this window's padded size and the window ``sizes`` it may
        be given later (:meth:`resize`; about 2 s of CPU, once per process and size; with
        ``anchors``, the global adjustment's sizes too) before the first frame rather than in
        the middle of a sequence."""
        for size in sorted({self.frames.maxlen, *map(int, sizes)}):
            for spanning in (False, True) if self.anchors else (False,):
                self._warm_up(spanning, size)

    def _warm_up(self, spanning: bool, size: int | None = None) -> None:
        R, t = np.eye(3)[None], np.array([[0.0, 0.0, 2.0]])
        one = np.zeros(1, np.int64)
        self._solve(
            R,
            t,
            np.zeros((1, 3)),
            one,
            one,
            np.zeros((1, 2)),
            np.zeros(1, bool),
            np.eye(3)[None],
            np.zeros((1, 3)),
            np.zeros(1, bool),
            spanning=spanning,
            size=size,
        )

    # ------------------------------------------------------------------ the adjustment
    def adjust(self, landmarks: LandmarkMap, *, spanning: bool = False) -> bool:
        """Adjust the window's poses and landmarks; move the rays. Returns whether it ran.
        ``spanning``: the global adjustment, the kept past frames (``anchors``) with the
        recent window, at most ``anchor_points`` landmarks."""
        spanning = spanning and bool(self.anchors)
        frames = (self.kept if spanning else []) + list(self.frames)
        if len(frames) < 2:
            return False
        s = landmarks.points
        if len(s) == 0:
            return False
        cols = [fr.arrays() for fr in frames]
        jj = np.repeat(np.arange(len(frames)), [len(c[0]) for c in cols])  # (non-decreasing)
        ids, px, right, w = (np.concatenate(c) for c in zip(*cols, strict=True))
        q, idx = find(s.ids, ids, increasing=True)  # the rays whose landmark is still in the map
        jj, px, right, w = jj[q], px[q], right[q], w[q]
        if len(jj) < 20:
            return False
        lm, li = np.unique(idx, return_inverse=True)  # landmarks of the window
        # priors: each landmark's rays outside the window (all its rays minus the window's)
        Rs = np.stack([fr.R for fr in frames])
        ts = np.stack([fr.t for fr in frames])
        M_out, b_out = s.M[lm].copy(), s.b[lm].copy()
        o_old, d_old = self._rays(Rs, ts, jj, px, right)
        P = w[:, None, None] * (np.eye(3)[None] - d_old[:, :, None] * d_old[:, None, :])
        scatter_add(M_out, li, -P)
        scatter_add(b_out, li, -np.einsum("nij,nj->ni", P, o_old))
        # at most max_points landmarks in the solve: those observed most often in the window
        # (the long tracks that tie its frames together); the others' rays move all the same
        sj, sli, spx, sright = jj, li, px, right
        max_points = self._points_cap(spanning)
        if len(lm) > max_points:
            count = np.bincount(li, minlength=len(lm))
            sel = np.sort(np.lexsort((lm, -count))[:max_points])
            new_index = np.full(len(lm), -1)
            new_index[sel] = np.arange(len(sel))
            keep = new_index[li] >= 0
            sj, sli, spx, sright = jj[keep], new_index[li[keep]], px[keep], right[keep]
            lm, M_out, b_out = lm[sel], M_out[sel], b_out[sel]
        free = np.array([not fr.fixed for fr in frames])
        if free.all() and not (self.gauge == "rays" and self._rays_hold(M_out)):
            free[0] = False  # the oldest frame fixes the gauge
        X = s.X[lm].copy()
        free_lines = self._free_line_terms(landmarks, frames) if self.free_lines else None
        held = None if free_lines is None else free_lines["ids"]
        hold = self.lines and (self.held_lines or not self.free_lines)
        lines = self._line_terms(landmarks, frames, held) if hold else None
        Rs_new, ts_new, X = self._solve(
            Rs,
            ts,
            X,
            sj,
            sli,
            spx,
            sright,
            M_out,
            b_out,
            free,
            lines,
            free_lines,
            frames,
            spanning=spanning,
        )
        if Rs_new is None:
            return False
        if self.free_lines:
            self._move_planes(landmarks, frames, Rs_new, ts_new)
        # move the window's rays to the adjusted poses and re-solve the landmarks from all rays
        o_new, d_new = self._rays(Rs_new, ts_new, jj, px, right)
        # (one call: each landmark is re-solved once)
        landmarks.observe(
            np.concatenate([idx, idx]),
            np.concatenate([o_old, o_new]),
            np.concatenate([d_old, d_new]),
            np.concatenate([-w, w]),
        )
        for fr, R, t in zip(frames, Rs_new, ts_new, strict=True):
            fr.R, fr.t = R, t
        return True

    @staticmethod
    def _rays_hold(M_out: np.ndarray) -> bool:
        """Whether the rays of frames outside the window fix the gauge: at least
        :data:`GAUGE_POINTS` of the window's landmarks have such rays that meet in a point."""
        return int(rays_meet(M_out).sum()) >= GAUGE_POINTS  # none for an empty window

    def _free_line_terms(self, landmarks: LandmarkMap, frames):
        """The free line landmarks of the window: those with observation planes in the window's
        frames whose planes in the map cross at a line (the map's own test,
        :meth:`LandmarkMap.observe_lines`), at most ``max_lines`` (the most planes in the
        window first). A dict of the plane rows (frame, line, camera-frame plane, weight), the
        lines' stable ids and endpoints, and their priors: the map's plane normal equations
        less the window's planes at the poses they were placed at; ``None`` without any."""
        s = landmarks.lines
        if len(s) == 0:
            return None
        rows = []
        for j, fr in enumerate(frames):
            ids, n, d, cam, w = fr.plane_arrays()
            q, at = find(s.ids, ids, increasing=True)
            if len(q):
                rows.append((np.full(len(q), j), at, n[q], d[q], cam[q], w[q]))
        if not rows:
            return None
        jj, at, n, d, cam, w = (np.concatenate(c) for c in zip(*rows, strict=True))
        lu, li = np.unique(at, return_inverse=True)
        ev = sym3_eigvalsh(s.M[lu])
        count = np.bincount(li, minlength=len(lu))
        ok = planes_meet(ev)
        order = np.lexsort((lu, -count))
        sel = np.sort(order[ok[order]][: self.max_lines])
        if len(sel) == 0:
            return None
        new_index = np.full(len(lu), -1)
        new_index[sel] = np.arange(len(sel))
        keep = new_index[li] >= 0
        jj, li, n, d, cam, w = jj[keep], new_index[li[keep]], n[keep], d[keep], cam[keep], w[keep]
        lu = lu[sel]
        Rs = np.stack([fr.R for fr in frames])
        ts = np.stack([fr.t for fr in frames])
        n_b = np.einsum("ki,kij->kj", n, Rs[jj])  # body-frame planes at the frames' poses
        d_b = d - np.einsum("ki,ki->k", n, ts[jj])
        M_out, b_out = s.M[lu].copy(), s.b[lu].copy()
        scatter_add(M_out, li, -w[:, None, None] * n_b[:, :, None] * n_b[:, None, :])
        scatter_add(b_out, li, -(w * d_b)[:, None] * n_b)
        return {
            "ids": s.ids[lu],
            "X": s.X[lu].copy(),
            "rows": (jj, li, np.concatenate([n, d[:, None]], 1), cam, w),
            "M": M_out,
            "b": b_out,
            "weight": float(frames[-1].line_weight),
        }

    @staticmethod
    def _move_planes(landmarks: LandmarkMap, frames, Rs_new, ts_new) -> None:
        """Move the window's line planes to the adjusted poses (removed at the old pose, added
        at the new one) and re-solve the lines from all their planes."""
        s = landmarks.lines
        if len(s) == 0:
            return
        idx, normals, offsets, weights = [], [], [], []
        for fr, R, t in zip(frames, Rs_new, ts_new, strict=True):
            ids, n, d, _, w = fr.plane_arrays()
            q, at = find(s.ids, ids, increasing=True)
            if len(q) == 0:
                continue
            n, d, w = n[q], d[q], w[q]
            for RR, tt, sign in ((fr.R, fr.t, -1.0), (R, t, 1.0)):
                idx.append(at)
                normals.append(n @ RR)
                offsets.append(d - n @ tt)
                weights.append(sign * w)
        if idx:
            landmarks.observe_lines(
                np.concatenate(idx),
                np.concatenate(normals),
                np.concatenate(offsets),
                np.concatenate(weights),
            )

    @staticmethod
    def _line_terms(landmarks: LandmarkMap, frames, held=None):
        """The window's line observations: frame, the landmark segment's endpoints (fixed in
        the adjustment), the unit-normal image line and the weight, one row per endpoint; the
        free lines (stable ids ``held``) are left out."""
        s = landmarks.lines
        if len(s) == 0:
            return None
        rows = []
        for j, fr in enumerate(frames):
            if len(fr.line_ids) == 0:
                continue
            line_ids = np.asarray(fr.line_ids)
            q, at = find(s.ids, line_ids, increasing=True)
            if held is not None and len(q):
                fixed = ~np.isin(line_ids[q], held)
                q, at = q[fixed], at[fixed]
            if len(q) == 0:
                continue
            Xl = s.X[at]  # (k, 2, 3)
            L = fr.lines[q]
            L = L / np.linalg.norm(L[:, :2], axis=1, keepdims=True)
            k = len(L)
            rows.append(
                (
                    np.full(2 * k, j),
                    Xl.reshape(-1, 3),
                    np.repeat(L, 2, axis=0),
                    np.full(2 * k, fr.line_weight),
                )
            )
        if not rows:
            return None
        return tuple(np.concatenate(c) for c in zip(*rows, strict=True))

    def _rays(self, Rs, ts, jj, px, right):
        """Body-frame origins and unit directions ``(n, 3)`` of the rays of pixels ``px`` seen
        in frames ``jj`` (non-decreasing: rows grouped by frame) at the poses ``Rs, ts``."""
        fx, fy = self.f
        cx, cy = self.c
        d = np.stack([(px[:, 0] - cx) / fx, (px[:, 1] - cy) / fy, np.ones(len(px))], 1)
        centre = np.where(right[:, None], -self.t_rl[None], 0.0)
        origin = rows_times(centre - ts[jj], Rs, jj)
        d = rows_times(d, Rs, jj)
        return origin, d / np.linalg.norm(d, axis=1, keepdims=True)

    def _points_cap(self, spanning: bool) -> int:
        """Most landmarks in a solve: ``anchor_points`` in the global adjustment, else
        ``max_points``."""
        return self.anchor_points if spanning else self.max_points

    def _solve(
        self,
        Rs,
        ts,
        X,
        jj,
        li,
        px,
        right,
        M_out,
        b_out,
        free,
        lines=None,
        free_lines=None,
        frames=(),
        *,
        spanning: bool = False,
        size: int | None = None,
    ):
        """The adjustment (:func:`jaxpose.core.refine.adjust_window`) on the visibility grid,
        padded to the window's ``frames`` frames (``size`` if given; plus ``anchors`` in the
        global adjustment, ``spanning``), ``max_points`` (``anchor_points``) landmarks and
        ``max_lines`` lines a frame (one compiled size each); ``None`` poses when it fails."""
        n, K = len(X), len(Rs)
        f = (self.frames.maxlen if size is None else size) + (self.anchors if spanning else 0)
        max_points = self._points_cap(spanning)
        n_pad, k_pad = max(max_points, n), self._held_rows
        Rp = np.broadcast_to(np.eye(3), (f, 3, 3)).copy()
        tp = np.zeros((f, 3))
        tp[:, 2] = 1.0
        Rp[:K], tp[:K] = Rs, ts
        free_p = np.zeros(f, bool)
        free_p[:K] = free
        pixels = np.zeros((f, n_pad, 2, 2))
        mask = np.zeros((f, n_pad, 2), bool)
        cam = np.asarray(right, int)
        pixels[jj, li, cam] = px  # (a repeated observation: one of them)
        mask[jj, li, cam] = True
        Lp, Lc, Lw = np.zeros((f, k_pad, 3)), np.zeros((f, k_pad, 3)), np.zeros((f, k_pad))
        Lp[..., 2] = 1.0
        if lines is not None:
            jl, Xl, L, wl = lines
            slot = np.arange(len(jl)) - np.searchsorted(jl, jl)  # rank within the frame
            keep = slot < k_pad  # (more lines in a frame: the first ones)
            jl, slot = jl[keep], slot[keep]
            Lp[jl, slot], Lc[jl, slot], Lw[jl, slot] = Xl[keep], L[keep], wl[keep]
        X_pad = np.zeros((n_pad, 3))
        X_pad[:, 2] = 1.0
        X_pad[:n] = X
        grid, E = self._free_line_grid(f, free_lines) if self.free_lines else (None, None)
        obs = WindowObservations(
            pixels=jnp.asarray(pixels),
            mask=jnp.asarray(mask),
            prior_M=jnp.asarray(_pad(M_out, n_pad)),
            prior_b=jnp.asarray(_pad(b_out, n_pad)),
            points_mask=jnp.asarray(np.arange(n_pad) < n),
            line_points=jnp.asarray(Lp),
            line_coeffs=jnp.asarray(Lc),
            line_weight=jnp.asarray(Lw),
            free=jnp.asarray(free_p),
            motion_weight=jnp.asarray(self._motion_weight(f, frames)),
            lines=grid,
        )
        res = adjust_window(
            jnp.asarray(X_pad),
            obs,
            Pose(jnp.asarray(Rp), jnp.asarray(tp)),
            self.rig,
            lines_body=E,
            options=self.options,
        )
        if int(res.status) != Status.OK:
            return None, None, None
        return (
            np.asarray(res.pose.R)[:K],
            np.asarray(res.pose.t)[:K],
            np.asarray(res.points_body)[:n],
        )

    def _free_line_grid(self, f: int, free_lines):
        """The free lines padded to ``max_lines`` lines and ``f`` frames (two planes a frame:
        left and right), weights times the line weight ``1 / line_sigma^2``: the
        :class:`WindowLines` and the endpoints ``(max_lines, 2, 3)`` (padded lines: a 0.1 m
        segment 1 m ahead)."""
        m_pad = self.max_lines
        planes = np.zeros((f, m_pad, 2, 4))
        planes[..., 2] = 1.0
        weight = np.zeros((f, m_pad, 2))
        M, b = np.zeros((m_pad, 3, 3)), np.zeros((m_pad, 3))
        E = np.zeros((m_pad, 2, 3))
        E[:, :, 2] = 1.0
        E[:, 1, 0] = 0.1
        m = 0
        if free_lines is not None:
            E[: len(free_lines["X"])] = free_lines["X"]
            jj, li, nd, cam, w = free_lines["rows"]
            lw = free_lines["weight"]
            planes[jj, li, cam] = nd  # (a repeated observation: one of them)
            weight[jj, li, cam] = lw * w
            m = len(free_lines["X"])
            M[:m], b[:m] = lw * free_lines["M"], lw * free_lines["b"]
        lines = WindowLines(
            planes=jnp.asarray(planes),
            weight=jnp.asarray(weight),
            prior_M=jnp.asarray(M),
            prior_b=jnp.asarray(b),
            mask=jnp.asarray(np.arange(m_pad) < m),
        )
        return lines, jnp.asarray(E)


def _pad(a: np.ndarray, n: int) -> np.ndarray:
    out = np.zeros((n, *a.shape[1:]))
    out[: len(a)] = a
    return out
