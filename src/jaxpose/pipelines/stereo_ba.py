"""Windowed bundle adjustment of the stereo tracker: keyframe poses and landmark points jointly.

The tracker of :mod:`jaxpose.pipelines.stereo` estimates each pose from the map and then refines
the map with that pose; a small error of one can leak into the other. Over a window of recent
keyframes this module minimises the reprojection errors of every landmark observation, in the left
and (for stereo matches) the right image, over the poses of the keyframes that are not held fixed
and the body-frame positions of the landmarks, as local bundle adjustment does in visual odometry.

Levenberg-Marquardt on the normal equations with the landmarks eliminated by the Schur complement
(each landmark couples only to the poses that see it, so the reduced system is ``6 W`` square for
``W`` free keyframes), Huber weights refreshed at every iteration, left-multiplicative pose
updates ``T <- exp(xi) T`` with ``xi = (omega, v)``. Pure NumPy: sizes change every call (a JAX
version would recompile each time) and the problems are small (a few keyframes, a few thousand
observations).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BAResult", "bundle_adjust"]


@dataclass
class BAResult:
    """``poses`` ``(W, 4, 4)`` and ``points`` ``(M, 3)`` after the adjustment; ``cost`` before and
    after (robust, pixels squared); ``iterations``; ``inlier_rms_px`` of the residuals below the
    Huber threshold after the adjustment."""

    poses: np.ndarray
    points: np.ndarray
    cost0: float
    cost: float
    iterations: int
    inlier_rms_px: float


def _skew(p: np.ndarray) -> np.ndarray:
    z = np.zeros(len(p))
    return np.stack(
        [
            np.stack([z, -p[:, 2], p[:, 1]], -1),
            np.stack([p[:, 2], z, -p[:, 0]], -1),
            np.stack([-p[:, 1], p[:, 0], z], -1),
        ],
        1,
    )


def _exp_se3(xi: np.ndarray) -> np.ndarray:
    """``(W, 6)`` twists ``(omega, v)`` to 4x4 left updates (rotation by Rodrigues, translation
    ``v`` added after the rotation: ``T' = [R_w R, R_w t + v]``)."""
    W = len(xi)
    out = np.tile(np.eye(4), (W, 1, 1))
    w = xi[:, :3]
    th = np.linalg.norm(w, axis=1)
    K = _skew(w / np.where(th > 0, th, 1.0)[:, None])
    s, c = np.sin(th)[:, None, None], np.cos(th)[:, None, None]
    out[:, :3, :3] = np.eye(3) + s * K + (1 - c) * (K @ K)
    out[:, :3, 3] = xi[:, 3:]
    return out


def _residuals(poses, points, pose_idx, point_idx, uv, right, K, t_rl):
    fx, fy, cx, cy = K
    R = poses[pose_idx, :3, :3]
    p = np.einsum("nij,nj->ni", R, points[point_idx]) + poses[pose_idx, :3, 3]
    x = p + np.where(right[:, None], t_rl[None], 0.0)
    z = np.where(x[:, 2] > 1e-6, x[:, 2], 1e-6)
    proj = np.stack([fx * x[:, 0] / z + cx, fy * x[:, 1] / z + cy], 1)
    return proj - uv, p, x, z, R


def _robust_cost(r: np.ndarray, k: float) -> float:
    n = np.linalg.norm(r, axis=1)
    return float(np.sum(np.where(n <= k, n * n, 2 * k * n - k * k)))


def bundle_adjust(
    poses: np.ndarray,
    fixed: np.ndarray,
    points: np.ndarray,
    pose_idx: np.ndarray,
    point_idx: np.ndarray,
    uv: np.ndarray,
    right: np.ndarray,
    K: tuple[float, float, float, float],
    t_rl: np.ndarray,
    *,
    huber_px: float = 1.0,
    iterations: int = 8,
    lam: float = 1e-3,
    prior_info: np.ndarray | None = None,
) -> BAResult:
    """Jointly refine keyframe poses and landmark points (module docstring).

    Args:
        poses: ``(W, 4, 4)`` body-to-left-camera poses; ``fixed``: ``(W,)`` bool, held fixed
            (at least one: the gauge).
        points: ``(M, 3)`` body-frame points.
        pose_idx, point_idx: ``(n,)`` the keyframe and point of each observation.
        uv: ``(n, 2)`` observed pixels; ``right``: ``(n,)`` bool, observed in the right image
            (rectified rig: ``x_right = x_left + t_rl``, same intrinsics ``K = (fx, fy, cx,
            cy)``).
        prior_info: optional ``(M, 3, 3)`` information matrices (pixels^2 per metre^2, the
            units of the reprojection cost) of a Gaussian prior on each point at its input
            position, e.g. what is known of the point from observations outside the window;
            adds ``(X - X_in)^T I (X - X_in)`` to the cost.
    """
    poses = np.array(poses, float)
    points = np.array(points, float)
    fixed = np.asarray(fixed, bool)
    pose_idx, point_idx = np.asarray(pose_idx, int), np.asarray(point_idx, int)
    uv, right = np.asarray(uv, float), np.asarray(right, bool)
    t_rl = np.asarray(t_rl, float)
    W, M, n = len(poses), len(points), len(uv)
    if poses.shape != (W, 4, 4) or fixed.shape != (W,) or points.shape != (M, 3):
        raise ValueError("poses must be (W, 4, 4), fixed (W,) and points (M, 3)")
    if not (len(pose_idx) == len(point_idx) == len(right) == n and uv.shape == (n, 2)):
        raise ValueError("pose_idx, point_idx, uv (n, 2) and right must have one row each")
    if not fixed.any():
        raise ValueError("at least one pose must be fixed (the gauge)")
    if n and (
        pose_idx.min() < 0 or pose_idx.max() >= W or point_idx.min() < 0 or point_idx.max() >= M
    ):
        raise ValueError("observation indices out of range")
    free = np.nonzero(~fixed)[0]
    slot = np.full(W, -1)
    slot[free] = np.arange(len(free))
    F = len(free)
    fx, fy = float(K[0]), float(K[1])

    X_in = points.copy()
    if prior_info is None:
        prior_info = np.zeros((M, 3, 3))
    prior_info = np.asarray(prior_info, float)
    if prior_info.shape != (M, 3, 3):
        raise ValueError("prior_info must be (M, 3, 3)")

    def prior_cost(X):
        d = X - X_in
        return float(np.einsum("mi,mij,mj->", d, prior_info, d))

    r, *_ = _residuals(poses, points, pose_idx, point_idx, uv, right, K, t_rl)
    cost0 = cost = _robust_cost(r, huber_px) + prior_cost(points)
    done = 0
    for _ in range(iterations):
        done += 1
        r, p, x, z, R = _residuals(poses, points, pose_idx, point_idx, uv, right, K, t_rl)
        nr = np.linalg.norm(r, axis=1)
        w = np.where(nr <= huber_px, 1.0, huber_px / np.maximum(nr, 1e-12))
        D = np.zeros((n, 2, 3))
        D[:, 0, 0], D[:, 0, 2] = fx / z, -fx * x[:, 0] / z**2
        D[:, 1, 1], D[:, 1, 2] = fy / z, -fy * x[:, 1] / z**2
        Jp = np.concatenate([D @ -_skew(p), D], axis=2)  # (n, 2, 6)
        Jl = D @ R  # (n, 2, 3)
        wJp, wJl = w[:, None, None] * Jp, w[:, None, None] * Jl
        Hll = np.zeros((M, 3, 3))
        gl = np.zeros((M, 3))
        np.add.at(Hll, point_idx, np.einsum("nki,nkj->nij", wJl, Jl))
        np.add.at(gl, point_idx, np.einsum("nki,nk->ni", wJl, r))
        Hll += prior_info
        gl += np.einsum("mij,mj->mi", prior_info, points - X_in)
        Hpp = np.zeros((F, 6, 6))
        gp = np.zeros((F, 6))
        Bfull = np.zeros((F, M, 6, 3))
        on = slot[pose_idx] >= 0
        s_on = slot[pose_idx[on]]
        np.add.at(Hpp, s_on, np.einsum("nki,nkj->nij", wJp[on], Jp[on]))
        np.add.at(gp, s_on, np.einsum("nki,nk->ni", wJp[on], r[on]))
        np.add.at(Bfull, (s_on, point_idx[on]), np.einsum("nki,nkj->nij", wJp[on], Jl[on]))
        # LM damping on the diagonals; landmarks seen from too few directions stay regular
        Hll_d = Hll + (lam * np.einsum("mii->mi", Hll) + 1e-9)[:, :, None] * np.eye(3)
        Hinv = np.linalg.inv(Hll_d)
        S = np.zeros((F, 6, F, 6))
        S[np.arange(F), :, np.arange(F), :] = Hpp + lam * np.einsum("fii->fi", Hpp)[
            :, :, None
        ] * np.eye(6)
        S -= np.einsum("jmab,mbc,kmdc->jakd", Bfull, Hinv, Bfull)
        g_red = gp - np.einsum("jmab,mbc,mc->ja", Bfull, Hinv, gl)
        if F:
            dp = np.linalg.solve(S.reshape(6 * F, 6 * F), -g_red.reshape(-1)).reshape(F, 6)
        else:
            dp = np.zeros((0, 6))
        dl = -np.einsum("mab,mb->ma", Hinv, gl + np.einsum("jmba,jb->ma", Bfull, dp))
        new_poses = poses.copy()
        if F:
            new_poses[free] = _exp_se3(dp) @ poses[free]
        new_points = points + dl
        r_new, *_ = _residuals(new_poses, new_points, pose_idx, point_idx, uv, right, K, t_rl)
        new_cost = _robust_cost(r_new, huber_px) + prior_cost(new_points)
        if new_cost < cost:
            step = cost - new_cost
            poses, points, cost = new_poses, new_points, new_cost
            lam = max(lam / 3, 1e-7)
            if step < 1e-6 * cost0:
                break
        else:
            lam *= 10
            if lam > 1e4:
                break
    r, *_ = _residuals(poses, points, pose_idx, point_idx, uv, right, K, t_rl)
    nr = np.linalg.norm(r, axis=1)
    inl = nr[nr <= huber_px]
    rms = float(np.sqrt(np.mean(inl**2))) if len(inl) else float("nan")
    return BAResult(poses, points, cost0, cost, done, rms)
