"""Windowed joint adjustment of the last keyframes' poses and the point landmarks they see.

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
observations (anchors), and the gauge is fixed by the first frame's pose while it is in the
window, else by the oldest frame's. Gauss-Newton with a small Levenberg damping and the Schur
complement on the ``3 x 3`` landmark blocks; analytic Jacobians (``x_cam = R X + t``, the
rotation perturbed on the left, ``R <- exp(w) R``).

After the adjustment the rays of the window's frames are moved to the adjusted poses (removed at
the old pose, added at the new one) and the landmarks re-solved from their rays, so the map stays
the least-squares intersection of all its rays.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from jaxpose.core.camera import StereoCamera
from jaxpose.pipelines.stereo._arrays import find, pixel_jacobian
from jaxpose.pipelines.stereo.landmarks import LandmarkMap

__all__ = ["FrameRays", "WindowAdjuster"]


@dataclass
class FrameRays:
    """The point rays one frame added to the map, and the pose they were placed at.

    Attributes:
        R, t: the frame's pose (body to left camera), NumPy.
        ids: ``(n,)`` stable landmark ids (:attr:`LandmarkSet.ids`).
        pixels: ``(n, 2)`` observed pixels; ``right``: ``(n,)`` bool, right-image pixel.
        weights: ``(n,)`` the rays' weights (``1 / depth^2``).
        fixed: the frame's pose is a gauge anchor (the given first pose).
        index: the frame's number.
        line_ids, lines: stable ids of the line landmarks matched in the left image and the
            observed homogeneous image lines ``(k, 3)``; ``line_weight``: ``1 / line_sigma^2``.
    """

    R: np.ndarray
    t: np.ndarray
    ids: list = field(default_factory=list)
    pixels: list = field(default_factory=list)
    right: list = field(default_factory=list)
    weights: list = field(default_factory=list)
    fixed: bool = False
    index: int = -1
    line_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    lines: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    line_weight: float = 1.0

    def add(self, ids, pixels, right: bool, weights) -> None:
        n = len(ids)
        if n:
            self.ids.append(np.asarray(ids, np.int64))
            self.pixels.append(np.asarray(pixels, float).reshape(n, 2))
            self.right.append(np.full(n, bool(right)))
            self.weights.append(np.asarray(weights, float))

    def arrays(self):
        if not self.ids:
            return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0, bool), np.zeros(0)
        return (
            np.concatenate(self.ids),
            np.concatenate(self.pixels),
            np.concatenate(self.right),
            np.concatenate(self.weights),
        )


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
    """

    anchor_oldest = True

    def __init__(
        self,
        rig: StereoCamera,
        frames: int = 6,
        iterations: int = 3,
        huber_px: float = 1.5,
        max_points: int = 600,
    ):
        if frames < 2:
            raise ValueError(f"window frames must be >= 2; got {frames}")
        self.rig = rig
        self.frames: deque[FrameRays] = deque(maxlen=int(frames))
        self.iterations = int(iterations)
        self.huber_px = float(huber_px)
        self.max_points = int(max_points)
        c = rig.left
        self.f = (float(c.fx), float(c.fy))
        self.c = (float(c.cx), float(c.cy))
        self.t_rl = np.asarray(rig.t_rl, float)

    def start(self, R, t, *, fixed: bool = False, index: int = -1) -> FrameRays:
        """Open the ray record of frame ``index`` (the oldest leaves the window when it is full)."""
        fr = FrameRays(np.array(R, float), np.array(t, float), fixed=fixed, index=index)
        self.frames.append(fr)
        return fr

    # ------------------------------------------------------------------ the adjustment
    def adjust(self, landmarks: LandmarkMap) -> bool:
        """Adjust the window's poses and landmarks; move the rays. Returns whether it ran."""
        frames = list(self.frames)
        if len(frames) < 2:
            return False
        s = landmarks.points
        if len(s) == 0:
            return False
        obs = []
        for j, fr in enumerate(frames):
            ids, px, right, w = fr.arrays()
            q, at = find(s.ids, ids)  # the rays whose landmark is still in the map
            obs.append((j, at, px[q], right[q], w[q]))
        jj = np.concatenate([np.full(len(o[1]), o[0]) for o in obs])
        if len(jj) < 20:
            return False
        idx = np.concatenate([o[1] for o in obs])
        px = np.concatenate([o[2] for o in obs])
        right = np.concatenate([o[3] for o in obs])
        w = np.concatenate([o[4] for o in obs])
        lm, li = np.unique(idx, return_inverse=True)  # landmarks of the window
        # priors: each landmark's rays outside the window (all its rays minus the window's)
        Rs = np.stack([fr.R for fr in frames])
        ts = np.stack([fr.t for fr in frames])
        M_out, b_out = s.M[lm].copy(), s.b[lm].copy()
        o_old, d_old = self._rays(Rs[jj], ts[jj], px, right)
        P = w[:, None, None] * (np.eye(3)[None] - d_old[:, :, None] * d_old[:, None, :])
        np.subtract.at(M_out, li, P)
        np.subtract.at(b_out, li, np.einsum("nij,nj->ni", P, o_old))
        free = np.array([not fr.fixed for fr in frames])
        if free.all() and self.anchor_oldest:
            free[0] = False  # the oldest frame fixes the gauge
        # at most max_points landmarks in the solve: those observed most often in the window
        # (the long tracks that tie its frames together); the others' rays move all the same
        sj, sli, spx, sright = jj, li, px, right
        if len(lm) > self.max_points:
            count = np.bincount(li, minlength=len(lm))
            sel = np.sort(np.lexsort((lm, -count))[: self.max_points])
            new_index = np.full(len(lm), -1)
            new_index[sel] = np.arange(len(sel))
            keep = new_index[li] >= 0
            sj, sli, spx, sright = jj[keep], new_index[li[keep]], px[keep], right[keep]
            lm, M_out, b_out = lm[sel], M_out[sel], b_out[sel]
        X = s.X[lm].copy()
        lines = self._line_terms(landmarks, frames)
        Rs_new, ts_new, X = self._solve(Rs, ts, X, sj, sli, spx, sright, M_out, b_out, free, lines)
        if Rs_new is None:
            return False
        # move the window's rays to the adjusted poses and re-solve the landmarks from all rays
        o_new, d_new = self._rays(Rs_new[jj], ts_new[jj], px, right)
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
    def _line_terms(landmarks: LandmarkMap, frames):
        """The window's line observations: frame, the landmark segment's endpoints (fixed in
        the adjustment), the unit-normal image line and the weight, one row per endpoint."""
        s = landmarks.lines
        if len(s) == 0:
            return None
        rows = []
        for j, fr in enumerate(frames):
            if len(fr.line_ids) == 0:
                continue
            q, at = find(s.ids, np.asarray(fr.line_ids))
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

    def _rays(self, R, t, px, right):
        fx, fy = self.f
        cx, cy = self.c
        d = np.stack([(px[:, 0] - cx) / fx, (px[:, 1] - cy) / fy, np.ones(len(px))], 1)
        centre = np.where(right[:, None], -self.t_rl[None], 0.0)
        origin = np.einsum("nj,nji->ni", centre - t, R)
        d = np.einsum("nj,nji->ni", d, R)
        return origin, d / np.linalg.norm(d, axis=1, keepdims=True)

    def _solve(self, Rs, ts, X, jj, li, px, right, M_out, b_out, free, lines=None):
        """Gauss-Newton on the window (module docstring); ``None`` poses when it fails."""
        fx, fy = self.f
        cx, cy = self.c
        N = len(X)
        nf = int(free.sum())
        fidx = np.cumsum(free) - 1  # column block of each free frame
        prior_w = fx * fy  # rays' angular units to pixels^2
        shift = np.where(right[:, None], self.t_rl[None], 0.0)
        Rs, ts, X = Rs.copy(), ts.copy(), X.copy()
        fo = free[jj]
        jf, lf = fidx[jj[fo]], li[fo]
        pair = jf * N + lf  # (free frame, landmark) of each observation of a free frame
        lam = 1e-3
        for _ in range(self.iterations):
            Rj = Rs[jj]
            Xi = X[li]
            RX = (Rj * Xi[:, None, :]).sum(2)
            p = RX + ts[jj] + shift
            z = p[:, 2]
            if np.any(z <= 1e-6):
                return None, None, None
            iz = 1.0 / z
            r = np.stack([fx * p[:, 0] * iz + cx - px[:, 0], fy * p[:, 1] * iz + cy - px[:, 1]], 1)
            e = np.sqrt(r[:, 0] ** 2 + r[:, 1] ** 2)
            hw = np.where(e > self.huber_px, self.huber_px / np.maximum(e, 1e-12), 1.0)
            Jp = pixel_jacobian(p, fx, fy)
            # Jp R, row by row (Jp has two non-zeros a row)
            JX = np.stack(
                [
                    Jp[:, 0, 0:1] * Rj[:, 0] + Jp[:, 0, 2:3] * Rj[:, 2],
                    Jp[:, 1, 1:2] * Rj[:, 1] + Jp[:, 1, 2:3] * Rj[:, 2],
                ],
                1,
            )  # (n, 2, 3)
            # -Jp [RX]x, the rotation part of the pose Jacobian, column by column
            Jw = np.stack(
                [
                    Jp[:, :, 2] * RX[:, 1:2] - Jp[:, :, 1] * RX[:, 2:3],
                    Jp[:, :, 0] * RX[:, 2:3] - Jp[:, :, 2] * RX[:, 0:1],
                    Jp[:, :, 1] * RX[:, 0:1] - Jp[:, :, 0] * RX[:, 1:2],
                ],
                2,
            )
            Jxi = np.concatenate([Jw, Jp], 2)  # (n, 2, 6): rotation, translation
            JXw = JX * hw[:, None, None]
            H_ll = _sum_by(li, _inner(JX, JXw), N)
            g_l = _sum_by(li, (JXw * r[:, :, None]).sum(1), N)
            H_ll += prior_w * M_out
            g_l += prior_w * ((M_out * X[:, None, :]).sum(2) - b_out)
            Jxf = Jxi[fo]
            Jxw = Jxf * hw[fo][:, None, None]
            H_pp = _sum_by(jf, _inner(Jxf, Jxw), nf)
            g_p = _sum_by(jf, (Jxw * r[fo][:, :, None]).sum(1), nf)
            H_pl = _sum_by(pair, _inner(Jxw, JX[fo]), nf * N)
            H_pl = H_pl.reshape(nf, N, 6, 3)
            if lines is not None:  # point-to-line distances of the fixed line landmarks
                Hl, gl_ = _line_blocks(self, Rs, ts, lines, free, fidx, nf)
                H_pp += Hl
                g_p += gl_
            H_ll_d = H_ll + lam * np.einsum("nii->ni", H_ll)[:, :, None] * np.eye(3)[None]
            Linv = _inv3(H_ll_d + 1e-9 * np.eye(3)[None])
            if Linv is None:
                return None, None, None
            # the Schur complement S = H_pp - H_pl H_ll^-1 H_pl^T as one stack of (6, 3N) x
            # (3N, 6) products, a frame pair each: small enough that BLAS runs each on one
            # thread (one (6F, 3N) product would wake its threads, which spin on a loaded
            # machine), and 50-70x less CPU time than the same sum by np.einsum
            Y = np.matmul(H_pl, Linv[None])  # (F, N, 6, 3)
            A = Y.transpose(0, 2, 1, 3).reshape(nf, 6, 3 * N)
            B = H_pl.transpose(0, 2, 1, 3).reshape(nf, 6, 3 * N)
            S = -np.matmul(A[:, None], B[None].transpose(0, 1, 3, 2))  # (F, F, 6, 6)
            S[np.arange(nf), np.arange(nf)] += H_pp
            S = S.transpose(0, 2, 1, 3).reshape(6 * nf, 6 * nf)
            S += lam * np.diag(np.diag(S)) + 1e-9 * np.eye(6 * nf)
            rhs = g_p.reshape(-1) - np.matmul(A, g_l.reshape(-1)).reshape(-1)
            try:
                dxi = -np.linalg.solve(S, rhs)
            except np.linalg.LinAlgError:
                return None, None, None
            d = dxi.reshape(nf, 6)
            back = np.matmul(d[:, None, :], B)[:, 0].sum(0).reshape(N, 3)
            dX = -(Linv * (g_l + back)[:, None, :]).sum(2)
            dR = Rotation.from_rotvec(d[:, :3]).as_matrix()
            fi = np.nonzero(free)[0]
            Rs[fi] = dR @ Rs[fi]
            ts[fi] = ts[fi] + d[:, 3:]
            X = X + dX
        if not (np.all(np.isfinite(Rs)) and np.all(np.isfinite(ts)) and np.all(np.isfinite(X))):
            return None, None, None
        return Rs, ts, X


def _line_blocks(self, Rs, ts, lines, free, fidx, nf):
    """Pose blocks ``(nf, 6, 6)``, ``(nf, 6)`` of the endpoint-to-line distances (Yang et al.
    2024, eq. 9) of the window's line observations, landmarks held fixed, Huber-weighted."""
    fx, fy = self.f
    cx, cy = self.c
    jl, Xl, L, wl = lines
    keep = free[jl]
    jl, Xl, L, wl = jl[keep], Xl[keep], L[keep], wl[keep]
    H = np.zeros((nf, 6, 6))
    g = np.zeros((nf, 6))
    if len(jl) == 0:
        return H, g
    RX = np.matmul(Rs[jl], Xl[:, :, None])[:, :, 0]
    p = RX + ts[jl]
    iz = 1.0 / p[:, 2]
    u = fx * p[:, 0] * iz + cx
    v = fy * p[:, 1] * iz + cy
    r = L[:, 0] * u + L[:, 1] * v + L[:, 2]
    hw = np.where(np.abs(r) > self.huber_px, self.huber_px / np.maximum(np.abs(r), 1e-12), 1.0)
    # d r / d p: the line normal times the projection Jacobian
    Jp = np.stack(
        [
            L[:, 0] * fx * iz,
            L[:, 1] * fy * iz,
            -(L[:, 0] * fx * p[:, 0] + L[:, 1] * fy * p[:, 1]) * iz**2,
        ],
        1,
    )
    Jw = np.cross(RX, Jp)  # d r / d w for R <- exp(w) R: -Jp . (RX x .) = (RX x Jp) . w
    J = np.concatenate([Jw, Jp], 1)  # (n, 6)
    wt = wl * hw
    H = _sum_by(fidx[jl], J[:, :, None] * J[:, None, :] * wt[:, None, None], nf)
    g = _sum_by(fidx[jl], J * (wt * r)[:, None], nf)
    return H, g


def _inner(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A^T B`` of stacks of ``(n, 2, a)`` and ``(n, 2, b)`` Jacobians: ``(n, a, b)``."""
    return A[:, 0, :, None] * B[:, 0, None, :] + A[:, 1, :, None] * B[:, 1, None, :]


def _sum_by(keys: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """``(n, ...)`` sums of ``values`` (``(m, ...)``) grouped by ``keys`` (``(m,)`` in
    ``[0, n)``), one ``np.bincount`` per component."""
    flat = values.reshape(len(values), -1)
    out = np.stack(
        [np.bincount(keys, weights=flat[:, c], minlength=n) for c in range(flat.shape[1])], 1
    )
    return out.reshape((n, *values.shape[1:]))


def _inv3(A: np.ndarray) -> np.ndarray | None:
    """Inverses of ``(n, 3, 3)`` matrices by their adjugates; ``None`` when one is singular."""
    c0 = np.cross(A[:, 1], A[:, 2])
    c1 = np.cross(A[:, 2], A[:, 0])
    c2 = np.cross(A[:, 0], A[:, 1])
    det = np.einsum("ni,ni->n", A[:, 0], c0)
    if not np.all(np.abs(det) > 0) or not np.all(np.isfinite(det)):
        return None
    return np.stack([c0, c1, c2], 2) / det[:, None, None]
