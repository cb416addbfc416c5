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
    """

    R: np.ndarray
    t: np.ndarray
    ids: list = field(default_factory=list)
    pixels: list = field(default_factory=list)
    right: list = field(default_factory=list)
    weights: list = field(default_factory=list)
    fixed: bool = False
    index: int = -1

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
    d = np.stack(
        [(pixels[:, 0] - cx) / fx, (pixels[:, 1] - cy) / fy, np.ones(len(pixels))], 1
    )
    centre = np.where(right[:, None], -np.asarray(rig.t_rl, float)[None], 0.0)
    return (centre - t) @ R, d @ R


class WindowAdjuster:
    """The last ``frames`` frames' rays and poses, and their joint adjustment (module docstring).

    Args:
        rig: the rectified rig of the tracker.
        frames: window size ``K`` (poses adjusted; at least 2).
        iterations: Gauss-Newton iterations per adjustment.
        huber_px: Huber threshold of the pixel residuals.
    """

    def __init__(
        self, rig: StereoCamera, frames: int = 6, iterations: int = 3, huber_px: float = 1.5
    ):
        if frames < 2:
            raise ValueError(f"window frames must be >= 2; got {frames}")
        self.rig = rig
        self.frames: deque[FrameRays] = deque(maxlen=int(frames))
        self.iterations = int(iterations)
        self.huber_px = float(huber_px)
        c = rig.left
        self.f = (float(c.fx), float(c.fy))
        self.c = (float(c.cx), float(c.cy))
        self.t_rl = np.asarray(rig.t_rl, float)

    def start(self, R, t, *, fixed: bool = False) -> FrameRays:
        """Open a frame's ray record (the oldest leaves the window when it is full)."""
        fr = FrameRays(np.array(R, float), np.array(t, float), fixed=fixed)
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
        order = np.argsort(s.ids)
        obs = []
        for j, fr in enumerate(frames):
            ids, px, right, w = fr.arrays()
            pos = np.searchsorted(s.ids[order], ids)
            pos = np.minimum(pos, len(order) - 1)
            hit = s.ids[order][pos] == ids
            obs.append((j, order[pos[hit]], px[hit], right[hit], w[hit]))
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
        if free.all():
            free[0] = False  # the oldest frame fixes the gauge
        X = s.X[lm].copy()
        Rs_new, ts_new, X = self._solve(Rs, ts, X, jj, li, px, right, M_out, b_out, free)
        if Rs_new is None:
            return False
        # move the window's rays to the adjusted poses and re-solve the landmarks from all rays
        o_new, d_new = self._rays(Rs_new[jj], ts_new[jj], px, right)
        landmarks.observe(idx, o_old, d_old, -w)
        landmarks.observe(idx, o_new, d_new, w)
        for fr, R, t in zip(frames, Rs_new, ts_new, strict=True):
            fr.R, fr.t = R, t
        return True

    def _rays(self, R, t, px, right):
        fx, fy = self.f
        cx, cy = self.c
        d = np.stack([(px[:, 0] - cx) / fx, (px[:, 1] - cy) / fy, np.ones(len(px))], 1)
        centre = np.where(right[:, None], -self.t_rl[None], 0.0)
        origin = np.einsum("nj,nji->ni", centre - t, R)
        d = np.einsum("nj,nji->ni", d, R)
        return origin, d / np.linalg.norm(d, axis=1, keepdims=True)

    def _solve(self, Rs, ts, X, jj, li, px, right, M_out, b_out, free):
        """Gauss-Newton on the window (module docstring); ``None`` poses when it fails."""
        fx, fy = self.f
        cx, cy = self.c
        K, N = len(Rs), len(X)
        nf = int(free.sum())
        fidx = np.cumsum(free) - 1  # column block of each free frame
        prior_w = fx * fy  # rays' angular units to pixels^2
        shift = np.where(right[:, None], self.t_rl[None], 0.0)
        Rs, ts, X = Rs.copy(), ts.copy(), X.copy()
        lam = 1e-3
        for _ in range(self.iterations):
            RX = np.einsum("nij,nj->ni", Rs[jj], X[li])
            p = RX + ts[jj] + shift
            z = p[:, 2]
            if np.any(z <= 1e-6):
                return None, None, None
            r = np.stack([fx * p[:, 0] / z + cx - px[:, 0], fy * p[:, 1] / z + cy - px[:, 1]], 1)
            e = np.linalg.norm(r, axis=1)
            hw = np.where(e > self.huber_px, self.huber_px / np.maximum(e, 1e-12), 1.0)
            Jp = np.zeros((len(p), 2, 3))
            Jp[:, 0, 0] = fx / z
            Jp[:, 0, 2] = -fx * p[:, 0] / z**2
            Jp[:, 1, 1] = fy / z
            Jp[:, 1, 2] = -fy * p[:, 1] / z**2
            JX = Jp @ Rs[jj]  # (n, 2, 3)
            hatRX = np.zeros((len(p), 3, 3))
            hatRX[:, 0, 1], hatRX[:, 0, 2] = -RX[:, 2], RX[:, 1]
            hatRX[:, 1, 0], hatRX[:, 1, 2] = RX[:, 2], -RX[:, 0]
            hatRX[:, 2, 0], hatRX[:, 2, 1] = -RX[:, 1], RX[:, 0]
            Jxi = np.concatenate([-Jp @ hatRX, Jp], 2)  # (n, 2, 6): rotation, translation
            Hll = np.einsum("nki,n,nkj->nij", JX, hw, JX)
            gl = np.einsum("nki,n,nk->ni", JX, hw, r)
            H_ll = np.zeros((N, 3, 3))
            g_l = np.zeros((N, 3))
            np.add.at(H_ll, li, Hll)
            np.add.at(g_l, li, gl)
            H_ll += prior_w * M_out
            g_l += prior_w * (np.einsum("nij,nj->ni", M_out, X) - b_out)
            fo = free[jj]
            H_pp = np.zeros((nf, 6, 6))
            g_p = np.zeros((nf, 6))
            np.add.at(H_pp, fidx[jj[fo]], np.einsum("nki,n,nkj->nij", Jxi[fo], hw[fo], Jxi[fo]))
            np.add.at(g_p, fidx[jj[fo]], np.einsum("nki,n,nk->ni", Jxi[fo], hw[fo], r[fo]))
            H_pl = np.zeros((nf, N, 6, 3))
            np.add.at(
                H_pl,
                (fidx[jj[fo]], li[fo]),
                np.einsum("nki,n,nkj->nij", Jxi[fo], hw[fo], JX[fo]),
            )
            # damping
            H_ll_d = H_ll + lam * np.einsum("nii->ni", H_ll)[:, :, None] * np.eye(3)[None]
            H_ll_d += 1e-9 * np.eye(3)[None]
            try:
                Linv = np.linalg.inv(H_ll_d)
            except np.linalg.LinAlgError:
                return None, None, None
            A = H_pl.transpose(0, 2, 1, 3).reshape(6 * nf, N * 3)  # (6F, 3N)
            Y = np.einsum("fnij,njk->fnik", H_pl, Linv)  # (F, N, 6, 3)
            Yf = Y.transpose(0, 2, 1, 3).reshape(6 * nf, N * 3)
            S = np.zeros((6 * nf, 6 * nf))
            for a in range(nf):
                S[6 * a : 6 * a + 6, 6 * a : 6 * a + 6] = H_pp[a]
            S -= Yf @ A.T
            S += lam * np.diag(np.diag(S)) + 1e-9 * np.eye(6 * nf)
            rhs = g_p.reshape(-1) - Yf @ g_l.reshape(-1)
            try:
                dxi = -np.linalg.solve(S, rhs)
            except np.linalg.LinAlgError:
                return None, None, None
            dX = -np.einsum("nij,nj->ni", Linv, g_l + np.einsum("fnij,fi->nj", H_pl, dxi.reshape(nf, 6)))
            d = dxi.reshape(nf, 6)
            dR = Rotation.from_rotvec(d[:, :3]).as_matrix()
            fi = np.nonzero(free)[0]
            Rs[fi] = dR @ Rs[fi]
            ts[fi] = ts[fi] + d[:, 3:]
            X = X + dX
        if not (np.all(np.isfinite(Rs)) and np.all(np.isfinite(ts))):
            return None, None, None
        return Rs, ts, X
