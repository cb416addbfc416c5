"""Pose and detection metrics against hand-computed values and under jit/vmap."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import PinholeCamera, Pose
from jaxpose.core.geometry import elementary_rotation, quat_to_dcm
from jaxpose.core.metrics import (
    endpoint_rates,
    esa_score,
    reprojection_error_2d,
    roi_rates,
    rotation_error,
    rotation_error_euler,
    success,
    translation_error,
)


def pose(angle_deg=0.0, t=(0.0, 0.0, 5.0), axis=2):
    return Pose(elementary_rotation(axis, jnp.deg2rad(angle_deg)), jnp.asarray(t, dtype=float))


def test_translation_and_rotation_errors():
    np.testing.assert_allclose(
        translation_error(jnp.array([1.0, -2, 3]), jnp.array([0.5, 0, 3])), [0.5, 2, 0]
    )
    e = rotation_error_euler(pose(7.0).R, pose(0.0).R)
    np.testing.assert_allclose(e, [0, 0, np.deg2rad(7.0)], atol=1e-12)
    e = rotation_error_euler(pose(-3.0, axis=0).R, pose(0.0).R)
    np.testing.assert_allclose(e, [np.deg2rad(-3.0), 0, 0], atol=1e-12)
    assert float(rotation_error(pose(12.0).R, pose(2.0).R)) == pytest.approx(np.deg2rad(10.0))


def test_success_thresholds():
    assert bool(success(pose(9.9, (0.29, 0, 5)), pose()))
    assert not bool(success(pose(10.1), pose()))
    assert not bool(success(pose(0.0, (0.0, 0.0, 5.31)), pose()))


def test_success_uses_norm():
    assert bool(success(pose(0.0, (0.2, 0.2, 5.0)), pose()))


def test_esa_score_matches_readme_definition(rng):
    q1 = rng.normal(size=4)
    q1 /= np.linalg.norm(q1)
    q2 = q1 + 0.05 * rng.normal(size=4)
    q2 /= np.linalg.norm(q2)
    t1, t2 = np.array([0.1, 0.2, 6.0]), np.array([0.2, 0.1, 6.3])
    s, eq, et = esa_score(Pose(quat_to_dcm(q2), t2), Pose(quat_to_dcm(q1), t1))
    assert float(eq) == pytest.approx(2 * np.arccos(abs(q1 @ q2)), abs=1e-7)
    assert float(et) == pytest.approx(np.linalg.norm(t1 - t2) / np.linalg.norm(t1))
    assert float(s) == pytest.approx(float(eq + et))
    # Batched under jit + vmap.
    P = Pose(jnp.stack([quat_to_dcm(q2)] * 3), jnp.stack([t2] * 3))
    T = Pose(jnp.stack([quat_to_dcm(q1)] * 3), jnp.stack([t1] * 3))
    s3 = jax.jit(jax.vmap(lambda a, b: esa_score(a, b)[0]))(P, T)
    np.testing.assert_allclose(s3, float(s), rtol=1e-6)


def test_reprojection_error_2d_eq22():
    cam = PinholeCamera(500.0, 500.0, 320.0, 240.0)
    p = pose()
    pts = jnp.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]])
    pix = cam.project(p.apply(pts))
    assert float(reprojection_error_2d(p, pts, pix, cam)) == pytest.approx(0.0, abs=1e-9)
    off = pix + jnp.array([[3.0, 4.0], [0.0, 0.0], [0.0, 0.0]])
    assert float(reprojection_error_2d(p, pts, off, cam)) == pytest.approx(5.0 / 3)
    mask = jnp.array([True, False, False])
    assert float(reprojection_error_2d(p, pts, off, cam, mask)) == pytest.approx(5.0)
    assert float(reprojection_error_2d(p, pts, off, cam, jnp.zeros(3, bool))) == np.inf


def test_endpoint_and_roi_rates():
    truth = jnp.array([[0.0, 0], [10, 0], [20, 0]])
    det = jnp.array([[1.0, 1], [50, 50]])
    tpr, ppv = endpoint_rates(det, truth)
    assert float(tpr) == pytest.approx(1 / 3) and float(ppv) == pytest.approx(0.5)
    assert endpoint_rates(jnp.zeros((0, 2)), truth)[0] == 0
    tpr, ppv = roi_rates(jnp.array([0.0, 0, 10, 10]), jnp.array([5.0, 0, 15, 10]))
    assert float(tpr) == pytest.approx(0.5) and float(ppv) == pytest.approx(0.5)
