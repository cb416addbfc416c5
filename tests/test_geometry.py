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

TAIT_BRYAN = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"]
PROPER = ["XYX", "XZX", "YXY", "YZY", "ZXZ", "ZYZ"]
SEQUENCES = [s for seq in TAIT_BRYAN + PROPER for s in (seq, seq.lower())]  # 24: SciPy's naming
angles3 = st.lists(st.floats(-1.5, 1.5), min_size=3, max_size=3)


@settings(max_examples=200, deadline=None)
@given(angles=angles3, seq=st.sampled_from(SEQUENCES))
def test_euler_matches_scipy_both_ways(angles, seq):
    """All 12 sequences, intrinsic (upper case) and extrinsic (lower case), as SciPy names them."""
    angles = np.asarray(angles)
    if seq.upper() in PROPER:  # SciPy's ranges: middle angle in [0, pi] for proper Euler
        angles[1] = abs(angles[1]) + 0.05
    R = np.asarray(g.euler_to_dcm(angles, seq))
    np.testing.assert_allclose(R, Rotation.from_euler(seq, angles).as_matrix(), atol=1e-12)
    back = np.asarray(g.dcm_to_euler(R, seq))
    np.testing.assert_allclose(back, angles, atol=1e-9)
    np.testing.assert_allclose(back, Rotation.from_matrix(R).as_euler(seq), atol=1e-9)


@pytest.mark.parametrize("seq", TAIT_BRYAN + PROPER)
def test_every_sequence_against_scipy_on_a_grid(seq):
    """Away from gimbal lock, every rotation of a grid converts both ways like SciPy."""
    rng = np.random.default_rng(7)
    R = Rotation.random(200, random_state=rng)
    for s in (seq, seq.lower()):
        ref = R.as_euler(s)
        middle = ref[:, 1] if seq in TAIT_BRYAN else ref[:, 1] - np.pi / 2
        keep = np.abs(np.abs(middle) - np.pi / 2) > 1e-3  # not at gimbal lock
        np.testing.assert_allclose(
            np.asarray(g.dcm_to_euler(R.as_matrix(), s))[keep], ref[keep], atol=1e-9
        )
        np.testing.assert_allclose(g.euler_to_dcm(ref, s), R.as_matrix(), atol=1e-12)


def test_default_sequence_is_intrinsic_xyz():
    """The default rotation did not change: roll about x, then the new y, then the new z."""
    a = np.array([0.1, -0.2, 0.3])
    assert g.DEFAULT_EULER_SEQUENCE == "XYZ"
    Rx, Ry, Rz = (np.asarray(g.elementary_rotation(k, a[k])) for k in range(3))
    np.testing.assert_allclose(g.euler_to_dcm(a), Rx @ Ry @ Rz, atol=1e-15)
    np.testing.assert_allclose(g.euler_to_dcm(a, "xyz"), Rz @ Ry @ Rx, atol=1e-15)
    np.testing.assert_allclose(g.Pose.from_euler(a, np.zeros(3)).euler(), a, atol=1e-12)


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_bad_euler_sequence_and_shapes():
    for bad in ("xxy", "XyZ", "xyzz", "abc", "XX", 3):
        with pytest.raises(ValueError, match="upper case for intrinsic"):
            g.euler_to_dcm(np.zeros(3), bad)
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


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_pose_apply_inverse_compose(rng):
    p1 = g.Pose.from_rotvec(rng.normal(size=3), rng.normal(size=3))
    p2 = g.Pose.from_quat(rng.normal(size=4), rng.normal(size=3))
    x = rng.normal(size=(7, 3))
    np.testing.assert_allclose(p1.inverse().apply(p1.apply(x)), x, atol=1e-12)
    np.testing.assert_allclose((p1 @ p2).apply(x), p1.apply(p2.apply(x)), atol=1e-12)
    np.testing.assert_allclose(p1.apply(x), x @ np.asarray(p1.R).T + np.asarray(p1.t), atol=1e-12)
    xi = rng.normal(size=6) * 0.1
    p3 = p1.retract(xi)  # the tangent convention: R <- exp([omega]_x) R, t <- t + rho
    dR = scipy.linalg.expm(np.asarray(g.hat(xi[3:])))
    np.testing.assert_allclose(p3.R, dR @ np.asarray(p1.R), atol=1e-12)
    np.testing.assert_allclose(p3.t, np.asarray(p1.t) + xi[:3], atol=1e-15)
    # properties: quat, rotvec; euler a method (it takes a sequence)
    np.testing.assert_allclose(p1.rotvec, Rotation.from_matrix(p1.R).as_rotvec(), atol=1e-12)
    q = np.asarray(p2.quat)
    ref = Rotation.from_matrix(p2.R).as_quat()[[3, 0, 1, 2]]
    np.testing.assert_allclose(q * np.sign(q[0]), ref * np.sign(ref[0]), atol=1e-12)
    with pytest.raises(ValueError, match="Pose needs"):
        g.Pose(np.eye(3), np.zeros(2))


def test_rotation_angle(rng):
    R = g.so3_exp(np.array([0.0, 0.3, 0.0]))
    np.testing.assert_allclose(g.rotation_angle(R, np.eye(3)), 0.3, atol=1e-12)
    np.testing.assert_allclose(g.rotation_angle(np.eye(3), np.eye(3)), 0.0, atol=1e-12)


@pytest.mark.typecheck_off  # as a user runs it: the annotation says arrays
def test_a_pose_of_lists_is_a_pose_of_arrays():
    """``Pose`` given nested lists holds float arrays, and every function takes it as the same
    pose given as arrays (lists had been kept and failed later, in whatever used them, with
    a TypeError that did not name the pose)."""
    import jaxpose as jp

    Pose = g.Pose
    R = np.asarray(g.euler_to_dcm(jnp.array([0.3, -0.2, 0.5])))
    listed = Pose(R.tolist(), [0.1, -0.2, 10])
    assert isinstance(listed.R, np.ndarray) and listed.R.dtype == np.float64
    assert isinstance(listed.t, np.ndarray) and listed.t.dtype == np.float64
    cam = jp.PinholeCamera(1000.0, 1000.0, 511.5, 383.5, width=1024, height=768)
    P = np.random.default_rng(1).uniform(-0.5, 0.5, (12, 3))
    want = jp.dop(P, Pose(R, np.array([0.1, -0.2, 10.0])), cam)
    got = jp.dop(P, listed, cam)
    np.testing.assert_array_equal(np.asarray(got.pdop), np.asarray(want.pdop))
    np.testing.assert_array_equal(np.asarray(got.adop), np.asarray(want.adop))
