"""The Cramer-Rao bound of ``bench/stereo_bound.py``: its Jacobians against finite differences,
and its Schur-complement covariance against the inverse of the whole information matrix."""

import numpy as np
from bench_module import load_bench
from scipy.spatial.transform import Rotation

bench = load_bench("stereo_bound")

FOCAL = (800.0, 790.0)
OFFSET = np.array([-0.3, 0.0, 0.0])  # the right camera of a 0.3 m rig


def _pixel(R, t, X, offset):
    xc = R @ X + t + offset
    return np.asarray(FOCAL) * xc[:2] / xc[2]


def _pose(rng):
    R = Rotation.from_rotvec(rng.normal(scale=0.5, size=3)).as_matrix()
    return R, np.array([0.1, -0.2, 3.0]) + rng.normal(scale=0.1, size=3)


def _pose_derivative(f, R, t, h=1e-6):
    """Central differences of ``f(R, t)`` over the pose perturbation ``(dtheta, dt)`` (``R <-
    exp(dtheta) R``, ``t <- t + dt``): ``(len(f), 6)``."""
    cols = []
    for d in np.eye(6) * h:
        Rp = Rotation.from_rotvec(d[:3]).as_matrix() @ R
        Rm = Rotation.from_rotvec(-d[:3]).as_matrix() @ R
        cols.append((f(Rp, t + d[3:]) - f(Rm, t - d[3:])) / (2 * h))
    return np.stack(cols, 1)


def test_observation_jacobians_match_finite_differences():
    rng = np.random.default_rng(0)
    R, t = _pose(rng)
    X = rng.normal(scale=0.4, size=3)
    h = 1e-6
    for offset in (np.zeros(3), OFFSET):
        Jp, Jl = bench.observation_jacobians(R, t, X, offset, FOCAL)
        num_p = _pose_derivative(lambda R_, t_, o=offset: _pixel(R_, t_, X, o), R, t)
        num_l = np.stack(
            [
                (_pixel(R, t, X + h * e, offset) - _pixel(R, t, X - h * e, offset)) / (2 * h)
                for e in np.eye(3)
            ],
            1,
        )
        np.testing.assert_allclose(Jp, num_p, rtol=1e-6, atol=1e-4)
        np.testing.assert_allclose(Jl, num_l, rtol=1e-6, atol=1e-4)


def test_chaser_jacobian_matches_finite_differences():
    R, t = _pose(np.random.default_rng(1))
    num = _pose_derivative(lambda R_, t_: -R_.T @ t_, R, t)
    np.testing.assert_allclose(bench.chaser_jacobian(R, t), num, atol=1e-8)


def test_schur_covariance_equals_the_inverse_of_the_whole_information():
    rng = np.random.default_rng(2)
    poses = {k: _pose(rng) for k in range(3)}
    points = {j: rng.normal(scale=0.4, size=3) for j in range(10)}
    observations = [
        (k, j, off)
        for k in range(3)
        for j in range(10)
        for off in (np.zeros(3), OFFSET)
        if rng.random() < 0.8 or k == 0
    ]
    free, sigma = [1, 2], 0.4
    C = bench.pose_covariance(observations, poses, points, free, FOCAL, sigma)
    # the whole Jacobian: 6 per free pose, then 3 per point; the inverse's pose block
    n = 6 * len(free) + 3 * len(points)
    rows = []
    for k, j, off in observations:
        Jp, Jl = bench.observation_jacobians(*poses[k], points[j], off, FOCAL)
        J = np.zeros((2, n))
        if k in free:
            J[:, 6 * free.index(k) : 6 * free.index(k) + 6] = Jp
        J[:, 6 * len(free) + 3 * j : 6 * len(free) + 3 * j + 3] = Jl
        rows.append(J)
    J = np.concatenate(rows)
    full = sigma**2 * np.linalg.inv(J.T @ J)
    np.testing.assert_allclose(C, full[: 6 * len(free), : 6 * len(free)], rtol=1e-6, atol=1e-12)


def test_an_unknown_scene_is_a_usage_error_that_names_the_choices(capsys):
    """``check_scenes`` (shared by the stereo diagnostics through ``_scene_by_name``) refuses a
    name that is neither a suite scene, an ``hNN`` of the held-out draw nor ``NAME=JSON``."""
    import argparse

    import pytest

    parser = argparse.ArgumentParser(prog="stereo_bound.py")
    bench.check_scenes(parser, ["d1-clean-2m", "h03"])  # both known: no error
    with pytest.raises(SystemExit):
        bench.check_scenes(parser, ["d1-clean-2m", "nosuch"])
    err = capsys.readouterr().err
    assert "unknown scene 'nosuch'" in err and "d6-blur-5m-slow" in err and "h12" in err
