"""Rotations and poses against SciPy and closed forms; NaN-safety at singular points."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jaxpose import geometry as g

SEQUENCES = ["xyz", "xzy", "yxz", "yzx", "zxy", "zyx"]
angles3 = st.lists(st.floats(-1.5, 1.5), min_size=3, max_size=3)


@settings(max_examples=40, deadline=None)
@given(angles=angles3, seq=st.sampled_from(SEQUENCES))
def test_euler_matches_scipy_intrinsic_and_round_trips(angles, seq):
    angles = np.asarray(angles)
    R = np.asarray(g.euler_to_dcm(angles, seq))
    R_ref = Rotation.from_euler(seq.upper(), angles).as_matrix()  # upper case = intrinsic
    np.testing.assert_allclose(R, R_ref, atol=1e-12)
    np.testing.assert_allclose(np.asarray(g.dcm_to_euler(R, seq)), angles, atol=1e-9)


def test_bad_euler_sequence_and_shapes():
    with pytest.raises(ValueError, match="Tait-Bryan"):
        g.euler_to_dcm(np.zeros(3), "xyx")
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        g.euler_to_dcm(np.zeros(4))
    with pytest.raises(ValueError, match=r"3, 3"):
        g.so3_log(np.eye(4))


@settings(max_examples=40, deadline=None)
@given(
    q=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1)
)
def test_quaternion_matches_scipy_and_round_trips(q):
    q = np.asarray(q) / np.linalg.norm(q)
    R = np.asarray(g.quat_to_dcm(q))
    np.testing.assert_allclose(R, Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix(), atol=1e-12)
    q_back = np.asarray(g.dcm_to_quat(R))
    assert q_back[0] >= 0
    np.testing.assert_allclose(abs(q_back @ q), 1.0, atol=1e-12)


def test_quat_multiply_composes_rotations(rng):
    p, q = rng.normal(size=(2, 4))
    lhs = g.quat_to_dcm(g.quat_multiply(p, q))
    np.testing.assert_allclose(lhs, g.quat_to_dcm(p) @ g.quat_to_dcm(q), atol=1e-12)
    np.testing.assert_allclose(
        g.quat_to_dcm(g.quat_conjugate(p)), np.asarray(g.quat_to_dcm(p)).T, atol=1e-12
    )


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.5, 2.0, np.pi - 1e-6, np.pi - 1e-10])
def test_so3_exp_log_against_scipy(rng, angle):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    w = angle * axis
    R = np.asarray(g.so3_exp(w))
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
    w_back = np.array(g.so3_log(R))
    # near pi the sign of the axis is ambiguous: compare rotations
    np.testing.assert_allclose(Rotation.from_rotvec(w_back).as_matrix(), R, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(w_back), angle, atol=1e-8)


@pytest.mark.parametrize(
    "w0", [np.zeros(3), np.array([np.pi - 1e-7, 0.0, 0.0]), np.array([0, 0, 1e-12])]
)
def test_jit_grad_finite_at_singular_points(w0):
    f = jax.jit(jax.grad(lambda w: jnp.sum(g.so3_log(g.so3_exp(w)) ** 2)))
    grad = np.asarray(f(jnp.asarray(w0)))
    assert np.all(np.isfinite(grad))
    # d/dw |log(exp(w))|^2 = 2 w away from the cut
    if np.linalg.norm(w0) < 1:
        np.testing.assert_allclose(grad, 2 * w0, atol=1e-9)
    g2 = jax.jit(jax.grad(lambda w: jnp.sum(g.se3_exp(w)[1])))(jnp.zeros(6))
    assert np.all(np.isfinite(np.asarray(g2)))


def test_se3_exp_matches_matrix_exponential(rng):
    xi = rng.normal(size=6)
    T = np.zeros((4, 4))
    T[:3, :3] = np.asarray(g.hat(xi[3:]))
    T[:3, 3] = xi[:3]
    E = scipy.linalg.expm(T)
    R, t = g.se3_exp(xi)
    np.testing.assert_allclose(R, E[:3, :3], atol=1e-12)
    np.testing.assert_allclose(t, E[:3, 3], atol=1e-12)


def test_hat_vee_and_batching(rng):
    a, b = rng.normal(size=(2, 5, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", g.hat(a), b), np.cross(a, b), atol=1e-12)
    np.testing.assert_allclose(g.vee(g.hat(a)), a, atol=1e-15)
    R = g.so3_exp(a)
    assert R.shape == (5, 3, 3)
    np.testing.assert_allclose(jax.vmap(g.so3_exp)(a), R, atol=1e-15)


def test_pose_apply_inverse_compose(rng):
    p1 = g.Pose.from_rotvec(rng.normal(size=3), rng.normal(size=3))
    p2 = g.Pose.from_quat(rng.normal(size=4), rng.normal(size=3))
    x = rng.normal(size=(7, 3))
    np.testing.assert_allclose(p1.inverse().apply(p1.apply(x)), x, atol=1e-12)
    np.testing.assert_allclose((p1 @ p2).apply(x), p1.apply(p2.apply(x)), atol=1e-12)
    np.testing.assert_allclose(p1.apply(x), x @ np.asarray(p1.R).T + np.asarray(p1.t), atol=1e-12)
    xi = rng.normal(size=6) * 0.1
    p3 = p1.retract(xi)
    dR, dt = g.se3_exp(xi)
    np.testing.assert_allclose(
        p3.apply(x), p1.apply(x) @ np.asarray(dR).T + np.asarray(dt), atol=1e-12
    )
    with pytest.raises(ValueError, match="Pose needs"):
        g.Pose(np.eye(3), np.zeros(2))


def test_rotation_angle(rng):
    R = g.so3_exp(np.array([0.0, 0.3, 0.0]))
    np.testing.assert_allclose(g.rotation_angle(R, np.eye(3)), 0.3, atol=1e-12)
    np.testing.assert_allclose(g.rotation_angle(np.eye(3), np.eye(3)), 0.0, atol=1e-12)
