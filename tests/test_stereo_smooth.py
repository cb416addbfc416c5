"""Offline smoothing of a tracked stereo sequence (jaxpose.pipelines.stereo.smooth): every
tracked frame adjusted at once. With noise-free pixels the reference is the geometry the pixels
were made from; on a rendered sequence, the tracker itself must be left as it was."""

import copy

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxpose import PinholeCamera, StereoCamera
from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo import LandmarkMap, StereoTracker, TrackerOptions, smooth_sequence
from jaxpose.pipelines.stereo.keyframes import observe_point_rays
from jaxpose.pipelines.stereo.smooth import adjust_sequence
from jaxpose.pipelines.stereo.window import WindowAdjuster


def _angle_deg(Ra, Rb):
    return np.degrees(Rotation.from_matrix(Ra @ Rb.T).magnitude())


def test_the_whole_sequence_returns_to_the_true_poses_a_short_window_cannot():
    """Eight frames seen through a 3-frame window that keeps its history: the frames that left
    the window keep their errors, the adjustment of the whole sequence (frame 0 the gauge)
    returns every frame's true pose and the true landmarks."""
    rng = np.random.default_rng(0)
    cam = PinholeCamera(800.0, 800.0, 319.5, 239.5, width=640, height=480)
    rig = StereoCamera.from_baseline(cam, 0.3)
    X = rng.uniform(-0.3, 0.3, (60, 3))
    poses = [
        (
            Rotation.from_rotvec([0.1, np.radians(3.0 * j), 0.05]).as_matrix(),
            np.r_[0.05, -0.02, 2.5],
        )
        for j in range(8)
    ]
    m = LandmarkMap()
    win = WindowAdjuster(rig, frames=3, iterations=4, max_points=60, history=True)
    ids = m.add("points", X + rng.normal(0, 0.01, X.shape), np.zeros((60, 32)), Pose(*poses[0]), 0)
    K = np.asarray(rig.left.K)
    for j, (R, t) in enumerate(poses):
        if j:  # the pose as a tracker would have it: off by about 0.5 degree and 1 cm
            Re = Rotation.from_rotvec(rng.normal(0, np.radians(0.3), 3)).as_matrix() @ R
            te = t + rng.normal(0, 0.006, 3)
        else:
            Re, te = R, t
        rec = win.start(Re, te, fixed=j == 0, index=j)
        for right, shift in ((False, np.zeros(3)), (True, np.asarray(rig.t_rl))):
            x = (X @ R.T + t + shift) @ K.T
            observe_point_rays(m, rig, ids, x[:, :2] / x[:, 2:], Pose(Re, te), right=right, log=rec)
    assert [fr.index for fr in win.history] == list(range(8))
    assert len(win.frames) == 3  # the window itself holds only the last three
    before = max(_angle_deg(fr.R, R) for fr, (R, _) in zip(win.history, poses, strict=True))
    assert before > 0.2
    assert adjust_sequence(m, rig, win.history, rounds=2, iterations=8, lines=False)
    for fr, (R, t) in zip(win.history, poses, strict=True):
        assert _angle_deg(fr.R, R) < 1e-4
        np.testing.assert_allclose(fr.t, t, atol=1e-6)
    np.testing.assert_allclose(m.points.X, X, atol=1e-6)
    with pytest.raises(ValueError, match="at least 2"):
        adjust_sequence(m, rig, win.history[:1])
    with pytest.raises(ValueError, match="rounds"):
        adjust_sequence(m, rig, win.history, rounds=0)


def test_smooth_sequence_of_a_tracker_leaves_the_tracker_as_it_was():
    from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence

    with pytest.raises(ValueError, match="keep_history"):
        TrackerOptions(keep_history=True, window_frames=0)
    rig = default_rig()
    frames = list(render_sequence(StereoScene(frames=3), rig))
    plain = StereoTracker(rig, frames[0].pose)
    with pytest.raises(ValueError, match="keep_history"):
        smooth_sequence(plain)
    tracker = StereoTracker(rig, frames[0].pose, options=TrackerOptions(keep_history=True))
    results = [tracker.process(fr.left, fr.right) for fr in frames]
    X_before = copy.deepcopy(tracker.map.points.X)
    R_records = [np.array(fr.R) for fr in tracker._window.history]
    smoothed = smooth_sequence(tracker)
    assert sorted(smoothed) == [r.index for r in results if r.status == 0]
    # frame 0 is the gauge: its given pose, unchanged
    np.testing.assert_array_equal(np.asarray(smoothed[0].R), np.asarray(frames[0].pose.R))
    for k, pose in smoothed.items():  # within a degree and a few cm of the causal poses
        assert _angle_deg(np.asarray(pose.R), results[k].R) < 1.0
        assert np.linalg.norm(np.asarray(pose.t) - np.asarray(results[k].pose.t)) < 0.05
    np.testing.assert_array_equal(tracker.map.points.X, X_before)  # the tracker is untouched
    for fr, R in zip(tracker._window.history, R_records, strict=True):
        np.testing.assert_array_equal(fr.R, R)
