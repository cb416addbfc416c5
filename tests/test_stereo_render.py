"""Tumbling-target motion and the sweeping light of the stereo renderer, against the kinematics
they stand for (closed-form angles, SciPy rotations)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxpose.vision.stereo_render import (
    StereoScene,
    default_rig,
    render_stereo_frame,
    scene_pose,
)


def test_spin_about_an_off_principal_axis_keeps_that_axis_fixed():
    axis = np.array([0.3, -0.2, 1.0])
    axis /= np.linalg.norm(axis)
    scene = StereoScene(spin_axis_body=tuple(axis), rate_deg_s=12.0)
    R0, _ = scene_pose(scene, 0.0)
    R1, _ = scene_pose(scene, 2.5)
    np.testing.assert_allclose(R0 @ axis, R1 @ axis, atol=1e-12)  # the spin axis stays put
    rel = Rotation.from_matrix(R1 @ R0.T)
    assert np.degrees(rel.magnitude()) == pytest.approx(30.0, abs=1e-9)
    np.testing.assert_allclose(rel.as_rotvec() / rel.magnitude(), R0 @ axis, atol=1e-9)
    # the default motion is unchanged: a flat spin about body z
    R, t = scene_pose(StereoScene(), 1.0)
    R_ref, _ = scene_pose(StereoScene(spin_axis_body=(0.0, 0.0, 2.0)), 1.0)
    np.testing.assert_allclose(R, R_ref, atol=1e-12)
    with pytest.raises(ValueError, match="spin_axis_body"):
        scene_pose(StereoScene(spin_axis_body=(0.0, 0.0, 0.0)), 0.0)


def test_nutation_keeps_a_constant_cone_angle_and_precesses():
    scene = StereoScene(nutation_deg=15.0, precession_deg_s=6.0, rate_deg_s=10.0)
    z = np.array([0.0, 0.0, 1.0])
    R0, _ = scene_pose(scene, 0.0)
    # the precession axis: the spin axis' rest direction (the flat-spin scene's body z)
    p = scene_pose(StereoScene(), 0.0)[0] @ z
    dirs = [scene_pose(scene, s)[0] @ z for s in np.linspace(0.0, 30.0, 7)]
    cone = [np.degrees(np.arccos(np.clip(d @ p, -1, 1))) for d in dirs]
    np.testing.assert_allclose(cone, 15.0, atol=1e-9)
    # after 30 s the spin axis went 180 degrees round the cone
    assert np.degrees(np.arccos(np.clip(dirs[0] @ dirs[-1], -1, 1))) == pytest.approx(
        30.0, abs=1e-6
    )
    for R in (scene_pose(scene, s)[0] for s in (0.0, 7.0)):
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


def test_the_light_sweep_changes_the_shading_over_the_sequence():
    rig = default_rig(320, 240)
    still = StereoScene(frames=5, noise_sigma=0.0, sun_rate_deg_s=0.0, rate_deg_s=0.0)
    sweep = StereoScene(
        frames=5, noise_sigma=0.0, sun_rate_deg_s=0.0, rate_deg_s=0.0, sun_sweep_deg=60.0
    )
    a0, a4 = (render_stereo_frame(still, rig, k).left.astype(int) for k in (0, 4))
    b0, b4 = (render_stereo_frame(sweep, rig, k).left.astype(int) for k in (0, 4))
    np.testing.assert_array_equal(a0, a4)  # nothing moves
    np.testing.assert_array_equal(a0, b0)  # the sweep starts where the still light is
    assert np.abs(b4 - b0).mean() > 1.0  # and has moved the shading by the last frame
