"""Shared by the windowed-adjustment tests (test_stereo_window.py, test_stereo_smooth.py): a
rigid point cloud seen by a rectified rig from frames that turn 3 degrees each, noise-free
pixels made by an independent NumPy projection, and poses as a tracker would have them."""

import numpy as np
from scipy.spatial.transform import Rotation

from jaxpose import PinholeCamera, StereoCamera
from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo.keyframes import observe_point_rays


def window_scene(n_frames=5, seed=0):
    rng = np.random.default_rng(seed)
    cam = PinholeCamera(800.0, 800.0, 319.5, 239.5, width=640, height=480)
    rig = StereoCamera.from_baseline(cam, 0.3)
    X = rng.uniform(-0.3, 0.3, (60, 3))
    poses = []
    for j in range(n_frames):  # the target turning 3 degrees a frame about its y axis, 2.5 m away
        R = Rotation.from_rotvec([0.1, np.radians(3.0 * j), 0.05]).as_matrix()
        poses.append((R, np.array([0.05, -0.02, 2.5])))
    return rig, X, poses


def pixels(rig, R, t, X):
    """Left and right pixels of body points (NumPy pinhole projection of the rectified rig)."""
    K = np.asarray(rig.left.K)
    out = []
    for shift in (np.zeros(3), np.asarray(rig.t_rl)):
        x = (X @ R.T + t + shift) @ K.T
        out.append(x[:, :2] / x[:, 2:])
    return out


def perturbed(rng, R, t):
    """The pose as a tracker would have it: off by up to about 0.5 degree and 1 cm."""
    Re = Rotation.from_rotvec(rng.normal(0, np.radians(0.3), 3)).as_matrix() @ R
    return Re, t + rng.normal(0, 0.006, 3)


def observe(m, rig, ids, R, t, X, estimate: Pose, rec):
    """The rays of both images of the true pose ``(R, t)``, placed at the ``estimate``."""
    left, right = pixels(rig, R, t, X)
    observe_point_rays(m, rig, ids, left, estimate, right=False, log=rec)
    observe_point_rays(m, rig, ids, right, estimate, right=True, log=rec)


def angle_deg(Ra, Rb):
    return np.degrees(Rotation.from_matrix(Ra @ Rb.T).magnitude())
