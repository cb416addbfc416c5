"""Every tracked frame's left-image plane of a matched line (``TrackerOptions.frame_planes``,
:func:`jaxpose.pipelines.stereo.keyframes.observe_left_planes`). References: the plane through a
camera centre and two 3-D points (a cross product in the body frame), and the true line a
rotating target's views share."""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo.keyframes import observe_left_planes, observe_line_planes
from jaxpose.pipelines.stereo.landmarks import LandmarkMap
from jaxpose.pipelines.stereo.window import FrameRays
from jaxpose.vision.stereo_render import default_rig


def rot(axis, deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    th = np.radians(deg)
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def pixels(rig, R, t, X):
    """Left-image pixels ``(n, 2)`` of body points ``X`` at pose ``(R, t)``."""
    p = X @ R.T + t
    c = rig.left
    return np.stack([c.fx * p[:, 0] / p[:, 2] + c.cx, c.fy * p[:, 1] / p[:, 2] + c.cy], 1)


def dist_to_line(X, A, B):
    d = B - A
    off = X - A
    return np.linalg.norm(off - np.outer(off @ d / (d @ d), d), axis=1)


LINE = np.array([[-0.2, 0.1, 0.3], [0.25, -0.15, -0.2]])  # body frame, slanted in depth


def test_the_left_plane_passes_through_the_camera_centre_and_the_segment():
    rig = default_rig()
    R, t = rot([0.3, 1.0, 0.2], 25.0), np.array([0.05, -0.02, 2.5])
    m = LandmarkMap()
    pose = Pose(jnp.asarray(R), jnp.asarray(t))
    idx = m.add("lines", LINE[None], np.zeros((1, 32), np.uint8), pose, 0)
    log = FrameRays(R, t)
    observe_left_planes(m, rig, idx, pixels(rig, R, t, LINE)[None], pose, log=log)
    ids, n_cam, d_cam, cam, w = log.plane_arrays()
    assert cam.tolist() == [0] and d_cam.tolist() == [0.0] and ids.tolist() == m.lines.ids.tolist()
    # body frame: the plane through the centre C = -R^T t and the two endpoints
    C = -R.T @ t
    n_ref = np.cross(LINE[0] - C, LINE[1] - C)
    n_ref /= np.linalg.norm(n_ref)
    n_body = n_cam[0] @ R
    assert abs(abs(n_body @ n_ref) - 1.0) < 1e-9
    depth = (LINE @ R.T + t)[:, 2].mean()
    assert w[0] == pytest.approx(1.0 / depth**2, rel=1e-12)
    M_ref = w[0] * np.outer(n_ref, n_ref)
    assert np.allclose(m.lines.M[0], M_ref, atol=1e-12)
    assert np.allclose(m.lines.b[0], w[0] * (n_ref @ C) * n_ref, atol=1e-12)


def test_a_line_placed_askew_moves_onto_the_true_line_with_its_later_views():
    """A line landmark whose first triangulation tilted it in depth (one endpoint 5% too far
    along its ray): the left planes of three views of the turning target meet at the true line
    and move it there; a map without them leaves it as placed."""
    rig = default_rig()
    t = np.array([0.0, 0.0, 2.5])
    R0 = np.eye(3)
    placed = LINE.copy()
    C0 = -R0.T @ t
    placed[1] = C0 + 1.05 * (LINE[1] - C0)  # on its first view's ray, 5% too far
    for views, moves in ((0, False), (3, True)):
        m = LandmarkMap()
        pose0 = Pose(jnp.asarray(R0), jnp.asarray(t))
        m.add("lines", placed[None], np.zeros((1, 32), np.uint8), pose0, 0)
        for k in range(views):
            R = rot([0.2, 1.0, 0.1], 6.0 * k)
            pose = Pose(jnp.asarray(R), jnp.asarray(t))
            observe_left_planes(m, rig, [0], pixels(rig, R, t, LINE)[None], pose)
        dist = dist_to_line(m.lines.X[0], *LINE)
        if moves:
            assert dist.max() < 1e-9
        else:
            assert dist.max() > 0.01


def test_the_right_plane_alone_when_the_frame_adds_the_left_one():
    """``left=False`` (a keyframe's matched line when ``frame_planes`` adds the left plane):
    one plane, the one through the right camera centre."""
    rig = default_rig()
    R, t = np.eye(3), np.array([0.0, 0.0, 2.5])
    pose = Pose(jnp.asarray(R), jnp.asarray(t))
    S = LINE[None] + t  # camera frame
    m = LandmarkMap()
    idx = m.add("lines", LINE[None], np.zeros((1, 32), np.uint8), pose, 0)
    log = FrameRays(R, t)
    observe_line_planes(m, rig, idx, S, pose, log=log, left=False)
    _, n_cam, d_cam, cam, _ = log.plane_arrays()
    assert cam.tolist() == [1]
    C_r = -np.asarray(rig.t_rl, float)  # the right camera's centre in the left camera frame
    assert n_cam[0] @ C_r == pytest.approx(d_cam[0], abs=1e-12)
    assert np.allclose(n_cam[0] @ S[0].T, d_cam[0], atol=1e-12)
    assert np.linalg.matrix_rank(m.lines.M[0], tol=1e-12) == 1


def test_segments_of_the_wrong_shape_are_named():
    rig = default_rig()
    m = LandmarkMap()
    pose = Pose(jnp.eye(3), jnp.array([0.0, 0.0, 2.5]))
    m.add("lines", LINE[None], np.zeros((1, 32), np.uint8), pose, 0)
    with pytest.raises(ValueError, match="segments"):
        observe_left_planes(m, rig, [0], np.zeros((1, 4)), pose)


def test_the_tracker_adds_each_frames_left_plane_of_its_lines():
    """``frame_planes``: on a rendered sequence every tracked frame records the left plane of
    each line its pose solve kept (those the windowed adjustment takes), and the line landmarks
    stay on the model (independent reference: the model's box)."""
    from jaxpose.core.status import Status
    from jaxpose.pipelines.stereo import StereoTracker, TrackerOptions
    from jaxpose.vision.stereo_render import StereoScene, render_sequence, tumbler_model

    rig = default_rig()
    frames = list(render_sequence(StereoScene(frames=5), rig))
    tracker = StereoTracker(rig, frames[0].pose, options=TrackerOptions(frame_planes=True))
    for fr in frames:
        assert tracker.process(fr.left, fr.right).status == Status.OK
    tracked = [fr for fr in tracker._window.frames if fr.index > 0]
    assert len(tracked) >= 3
    for fr in tracked:
        ids, _, _, cam, _ = fr.plane_arrays()
        assert len(fr.line_ids) > 0
        assert set(fr.line_ids.tolist()) <= set(ids[cam == 0].tolist())
    half = np.abs(tumbler_model().vertices[:8]).max(0)
    X = tracker.map.lines.X.reshape(-1, 3)
    assert np.mean(np.all(np.abs(X) < half + 0.02, axis=1)) > 0.8
