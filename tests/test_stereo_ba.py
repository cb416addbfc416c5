"""Windowed bundle adjustment (jaxpose.pipelines.stereo_ba) on synthetic stereo keyframes: the
reference is the geometry the observations were generated from."""

import numpy as np
import pytest

from jaxpose.pipelines.stereo_ba import _exp_se3, bundle_adjust

K = (800.0, 800.0, 319.5, 239.5)
T_RL = np.array([-0.3, 0.0, 0.0])


def _pose(angle_deg, t):
    a = np.radians(angle_deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    T[:3, 3] = t
    return T


def _problem(rng, W=5, M=80):
    poses = np.stack([_pose(4.0 * j, [0.01 * j, 0.0, 2.0]) for j in range(W)])
    X = rng.uniform(-0.3, 0.3, (M, 3))
    pi, qi, uv, right = [], [], [], []
    for j in range(W):
        for side in (False, True):
            x = X @ poses[j, :3, :3].T + poses[j, :3, 3] + (T_RL if side else 0.0)
            u = np.stack([K[0] * x[:, 0] / x[:, 2] + K[2], K[1] * x[:, 1] / x[:, 2] + K[3]], 1)
            pi += [j] * M
            qi += list(range(M))
            uv.append(u)
            right += [side] * M
    return poses, X, np.array(pi), np.array(qi), np.concatenate(uv), np.array(right)


def test_bundle_adjust_recovers_the_geometry_from_perturbed_start():
    rng = np.random.default_rng(0)
    poses, X, pi, qi, uv, right = _problem(rng)
    fixed = np.zeros(len(poses), bool)
    fixed[0] = True
    start = poses.copy()
    xi = np.c_[rng.normal(0, 0.004, (len(poses), 3)), rng.normal(0, 0.005, (len(poses), 3))]
    start[1:] = _exp_se3(xi[1:]) @ poses[1:]
    X0 = X + rng.normal(0, 0.01, X.shape)
    res = bundle_adjust(start, fixed, X0, pi, qi, uv, right, K, T_RL, iterations=20)
    assert res.cost < 1e-6 * res.cost0
    np.testing.assert_allclose(res.poses, poses, atol=1e-6)
    np.testing.assert_allclose(res.points, X, atol=1e-6)
    np.testing.assert_array_equal(res.poses[0], start[0])  # the fixed pose does not move


def test_bundle_adjust_downweights_an_outlier_and_checks_inputs():
    rng = np.random.default_rng(1)
    poses, X, pi, qi, uv, right = _problem(rng)
    noisy = uv + rng.normal(0, 0.3, uv.shape)
    noisy[5] += [40.0, -25.0]  # one gross mismatch
    fixed = np.zeros(len(poses), bool)
    fixed[:2] = True
    res = bundle_adjust(poses, fixed, X, pi, qi, noisy, right, K, T_RL, huber_px=1.0)
    # the estimate stays near the truth (the Huber kernel bounds the mismatch's pull)
    ang = [
        np.degrees(np.arccos(np.clip((np.trace(a[:3, :3] @ b[:3, :3].T) - 1) / 2, -1, 1)))
        for a, b in zip(res.poses, poses, strict=True)
    ]
    assert max(ang) < 0.05
    assert np.median(np.linalg.norm(res.points - X, axis=1)) < 0.003
    assert res.inlier_rms_px < 0.6
    with pytest.raises(ValueError, match="fixed"):
        bundle_adjust(poses, np.zeros(len(poses), bool), X, pi, qi, uv, right, K, T_RL)
    with pytest.raises(ValueError, match="out of range"):
        bundle_adjust(poses, fixed, X, pi, qi + 1, uv, right, K, T_RL)


def test_bundle_adjust_prior_holds_points_where_the_window_says_little():
    rng = np.random.default_rng(2)
    poses, X, pi, qi, uv, right = _problem(rng, W=3, M=30)
    fixed = np.array([True, False, False])
    X0 = X + rng.normal(0, 0.005, X.shape)
    # a very strong prior at the perturbed points: they stay put, the free poses adapt to them
    strong = np.broadcast_to(np.eye(3) * 1e12, (len(X), 3, 3))
    res = bundle_adjust(poses, fixed, X0, pi, qi, uv, right, K, T_RL, prior_info=strong)
    np.testing.assert_allclose(res.points, X0, atol=1e-6)
    # no prior: the exact points again
    res = bundle_adjust(poses, fixed, X0, pi, qi, uv, right, K, T_RL, iterations=20)
    np.testing.assert_allclose(res.points, X, atol=1e-6)
    with pytest.raises(ValueError, match="prior_info"):
        bundle_adjust(poses, fixed, X0, pi, qi, uv, right, K, T_RL, prior_info=np.eye(3))
