"""Offline smoothing of a tracked stereo sequence (jaxpose.pipelines.stereo.smooth): every
tracked frame adjusted at once. With noise-free pixels the reference is the geometry the pixels
were made from; on a rendered sequence, the tracker itself must be left as it was."""

import copy

import numpy as np
import pytest
from window_scenes import angle_deg, observe, perturbed, window_scene

from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo import LandmarkMap, StereoTracker, TrackerOptions, smooth_sequence
from jaxpose.pipelines.stereo.smooth import adjust_sequence
from jaxpose.pipelines.stereo.window import WindowAdjuster


def test_the_whole_sequence_returns_to_the_true_poses_a_short_window_cannot():
    """Eight frames seen through a 3-frame window that keeps its history: the frames that left
    the window keep their errors, the adjustment of the whole sequence (frame 0 the gauge)
    returns every frame's true pose and the true landmarks."""
    rig, X, poses = window_scene(n_frames=8)
    rng = np.random.default_rng(0)
    m = LandmarkMap()
    win = WindowAdjuster(rig, frames=3, iterations=4, max_points=60, history=True)
    ids = m.add("points", X + rng.normal(0, 0.01, X.shape), np.zeros((60, 32)), Pose(*poses[0]), 0)
    for j, (R, t) in enumerate(poses):
        Re, te = perturbed(rng, R, t) if j else (R, t)  # as a tracker would have them
        rec = win.start(Re, te, fixed=j == 0, index=j)
        observe(m, rig, ids, R, t, X, Pose(Re, te), rec)
    assert [fr.index for fr in win.history] == list(range(8))
    assert len(win.frames) == 3  # the window itself holds only the last three
    before = max(angle_deg(fr.R, R) for fr, (R, _) in zip(win.history, poses, strict=True))
    assert before > 0.2
    assert adjust_sequence(m, rig, win.history, rounds=2, iterations=8, lines=False)
    for fr, (R, t) in zip(win.history, poses, strict=True):
        assert angle_deg(fr.R, R) < 1e-4
        np.testing.assert_allclose(fr.t, t, atol=1e-6)
    np.testing.assert_allclose(m.points.X, X, atol=1e-6)
    with pytest.raises(ValueError, match="at least 2"):
        adjust_sequence(m, rig, win.history[:1])
    with pytest.raises(ValueError, match="rounds"):
        adjust_sequence(m, rig, win.history, rounds=0)
    with pytest.raises(ValueError, match="max_points"):
        adjust_sequence(m, rig, win.history, max_points=0)


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
        assert angle_deg(np.asarray(pose.R), results[k].R) < 1.0
        assert np.linalg.norm(np.asarray(pose.t) - np.asarray(results[k].pose.t)) < 0.05
    np.testing.assert_array_equal(tracker.map.points.X, X_before)  # the tracker is untouched
    for fr, R in zip(tracker._window.history, R_records, strict=True):
        np.testing.assert_array_equal(fr.R, R)


def test_smooth_sequence_from_the_identity_reports_poses_in_the_given_frame():
    """Started from the identity, the map's origin moves to the first landmarks (map_origin);
    the smoothed poses are reported, as the tracker's results are, in the given frame: frame 0 is
    the identity and the others within a degree and a few cm of the causal results."""
    from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence

    rig = default_rig()
    frames = list(render_sequence(StereoScene(frames=3), rig))
    tracker = StereoTracker(rig, None, options=TrackerOptions(keep_history=True))
    results = [tracker.process(fr.left, fr.right) for fr in frames]
    assert np.linalg.norm(tracker.map_origin) > 1.5  # moved from the camera to the target
    smoothed = smooth_sequence(tracker)
    np.testing.assert_allclose(np.asarray(smoothed[0].R), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.asarray(smoothed[0].t), np.zeros(3), atol=1e-12)
    for k, pose in smoothed.items():
        assert angle_deg(np.asarray(pose.R), results[k].R) < 1.0
        assert np.linalg.norm(np.asarray(pose.t) - np.asarray(results[k].pose.t)) < 0.05
