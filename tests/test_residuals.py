"""Point and line residuals, robust kernels and the joint cost (Yang et al. 2024, eqs. 7-10)."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import PinholeCamera, Pose
from jaxpose.core.geometry import so3_exp
from jaxpose.core.residuals import (
    DEFAULT_ROBUST_SCALE,
    isotropic_information,
    joint_cost,
    line_from_segment,
    line_residuals,
    point_residuals,
    robust_rho,
    robust_weight,
)

CAM = PinholeCamera(800.0, 810.0, 320.0, 240.0)
KINDS = ["huber", "cauchy", "tukey"]


def _pose(rng):
    return Pose(so3_exp(jnp.asarray(rng.normal(size=3) * 0.4)), jnp.array([0.1, -0.2, 4.0]))


def test_point_residuals_match_opencv(rng):
    pose = _pose(rng)
    P = rng.uniform(-0.5, 0.5, (12, 3))
    observed = rng.uniform(0, 600, (12, 2))
    rvec = np.asarray(pose.rotvec)
    proj, _ = cv2.projectPoints(P, rvec, np.asarray(pose.t), np.asarray(CAM.K), None)
    e = point_residuals(P, observed, pose, CAM)
    np.testing.assert_allclose(e, proj[:, 0] - observed, atol=1e-9)


def test_line_from_segment_passes_through_endpoints_and_gives_pixel_distances():
    s, e = jnp.array([10.0, 20.0]), jnp.array([110.0, 70.0])
    line = line_from_segment(s, e)
    assert abs(float(line @ jnp.array([10.0, 20.0, 1.0]))) < 1e-9
    assert abs(float(line @ jnp.array([110.0, 70.0, 1.0]))) < 1e-9
    # A point 5 px off the line along its normal is at signed distance +-5.
    d = (e - s) / jnp.linalg.norm(e - s)
    normal = jnp.array([-d[1], d[0]])
    q = 0.5 * (s + e) + 5.0 * normal
    dist = (line[:2] @ q + line[2]) / jnp.linalg.norm(line[:2])
    assert abs(abs(float(dist)) - 5.0) < 1e-9


def test_line_residuals_zero_on_the_line_and_signed_off_it(rng):
    pose = _pose(rng)
    seg = jnp.asarray(rng.uniform(-0.5, 0.5, (4, 2, 3)))
    ends = CAM.project(pose.apply(seg.reshape(-1, 3))).reshape(4, 2, 2)
    # Observed segments: sub-segments of the projected ones (same lines, other endpoints).
    s_obs = ends[:, 0] + 0.2 * (ends[:, 1] - ends[:, 0])
    e_obs = ends[:, 0] + 0.7 * (ends[:, 1] - ends[:, 0])
    lines = line_from_segment(s_obs, e_obs)
    np.testing.assert_allclose(line_residuals(seg, lines, pose, CAM), 0.0, atol=1e-9)
    # Shift the observation 3 px along the normal: both endpoints are 3 px away, same sign.
    d = (e_obs - s_obs) / jnp.linalg.norm(e_obs - s_obs, axis=-1, keepdims=True)
    normal = jnp.stack([-d[:, 1], d[:, 0]], -1)
    shifted = line_from_segment(s_obs + 3 * normal, e_obs + 3 * normal)
    r = line_residuals(seg, shifted, pose, CAM)
    np.testing.assert_allclose(jnp.abs(r), 3.0, atol=1e-9)
    assert np.all(np.sign(r[:, 0]) == np.sign(r[:, 1]))
    # The line's scale does not matter; a reversed line flips the sign.
    np.testing.assert_allclose(line_residuals(seg, 7.0 * shifted, pose, CAM), r, atol=1e-9)
    np.testing.assert_allclose(line_residuals(seg, -shifted, pose, CAM), -r, atol=1e-9)


@pytest.mark.parametrize("kind", KINDS)
def test_irls_weight_is_derivative_of_rho(kind):
    r = jnp.linspace(0.0, 8.0, 161)
    d_rho = jax.vmap(jax.grad(lambda s: robust_rho(kind, s)))(r**2)
    np.testing.assert_allclose(robust_weight(kind, r), d_rho, atol=1e-12)


@pytest.mark.parametrize("kind", KINDS)
def test_weights_match_closed_forms(kind):
    c = 2.0
    r = jnp.array([0.0, 0.5, 1.9, 2.0, 2.5, 10.0])
    w = robust_weight(kind, r, c)
    if kind == "huber":
        expected = np.minimum(1.0, c / np.maximum(np.asarray(r), 1e-300))
    elif kind == "cauchy":
        expected = 1.0 / (1.0 + np.asarray(r) ** 2 / c**2)
    else:
        expected = np.where(np.asarray(r) < c, (1 - np.asarray(r) ** 2 / c**2) ** 2, 0.0)
    np.testing.assert_allclose(w, expected, atol=1e-12)
    # Outliers are down-weighted, inliers (r << c) keep weight ~1.
    assert float(w[-1]) < 0.25 and float(w[1]) > 0.85
    # rho(s) ~ s near zero; non-decreasing.
    s = jnp.linspace(0.0, 50.0, 101)
    rho = robust_rho(kind, s, c)
    assert np.all(np.diff(np.asarray(rho)) >= -1e-12)
    np.testing.assert_allclose(robust_rho(kind, jnp.array(1e-6), c), 1e-6, rtol=1e-5)


@pytest.mark.parametrize("kind", [None, *KINDS])
def test_kernels_nan_free_gradients_at_zero(kind):
    g = jax.jit(jax.grad(lambda s: robust_rho(kind, s)))(0.0)
    assert np.isfinite(float(g)) and abs(float(g) - 1.0) < 1e-12
    g2 = jax.jit(jax.grad(lambda r: robust_weight(kind, r)))(0.0)
    assert np.isfinite(float(g2))


def test_defaults_and_bad_kernel():
    assert set(DEFAULT_ROBUST_SCALE) == set(KINDS)
    with pytest.raises(ValueError, match="robust kernel"):
        robust_rho("welsch", jnp.array(1.0))
    with pytest.raises(ValueError, match="robust kernel"):
        robust_weight("l1", jnp.array(1.0))


def test_joint_cost_plain_and_masked(rng):
    pose = _pose(rng)
    P = rng.uniform(-0.5, 0.5, (10, 3))
    pix = np.asarray(CAM.project(pose.apply(jnp.asarray(P)))) + rng.normal(size=(10, 2))
    sigma = 0.7
    info = isotropic_information(sigma, 10)
    e = point_residuals(P, pix, pose, CAM)
    expected = float(jnp.sum(e**2)) / sigma**2
    assert abs(float(joint_cost(P, pix, pose, CAM, point_information=info)) - expected) < 1e-9
    # Masked-out entries (even NaN) change nothing.
    P2 = np.concatenate([P, np.full((3, 3), np.nan)])
    pix2 = np.concatenate([pix, np.full((3, 2), np.nan)])
    mask = np.arange(13) < 10
    c2 = joint_cost(
        P2, pix2, pose, CAM, point_information=isotropic_information(sigma, 13), mask=mask
    )
    assert abs(float(c2) - expected) < 1e-9
    g = jax.grad(lambda p: joint_cost(P2, pix2, p, CAM, mask=mask))(pose)
    assert np.all(np.isfinite(np.asarray(g.t)))


def test_joint_cost_points_and_lines_with_kernel(rng):
    pose = _pose(rng)
    P = rng.uniform(-0.5, 0.5, (6, 3))
    pix = np.asarray(CAM.project(pose.apply(jnp.asarray(P)))) + 4.0
    seg = rng.uniform(-0.5, 0.5, (3, 2, 3))
    ends = np.asarray(CAM.project(pose.apply(jnp.asarray(seg.reshape(-1, 3))))).reshape(3, 2, 2)
    lines = line_from_segment(jnp.asarray(ends[:, 0] + 2.0), jnp.asarray(ends[:, 1] + 2.0))
    c = joint_cost(P, pix, pose, CAM, segments_body=seg, lines_img=lines, robust="huber")
    s_p = jnp.sum(point_residuals(P, pix, pose, CAM) ** 2, -1)
    s_l = jnp.sum(line_residuals(seg, lines, pose, CAM) ** 2, -1)
    expected = jnp.sum(robust_rho("huber", s_p)) + jnp.sum(robust_rho("huber", s_l))
    assert abs(float(c) - float(expected)) < 1e-9


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_bad_shapes_raise(rng):
    pose = _pose(rng)
    with pytest.raises(ValueError, match="points_body"):
        point_residuals(np.zeros((4, 2)), np.zeros((4, 2)), pose, CAM)
    with pytest.raises(ValueError, match="same length"):
        point_residuals(np.zeros((4, 3)), np.zeros((5, 2)), pose, CAM)
    with pytest.raises(ValueError, match="segments_body"):
        line_residuals(np.zeros((4, 3)), np.zeros((4, 3)), pose, CAM)
    with pytest.raises(ValueError, match="one rotation"):
        point_residuals(
            np.zeros((4, 3)), np.zeros((4, 2)), Pose(jnp.zeros((2, 3, 3)), jnp.zeros((2, 3))), CAM
        )
