"""The longer window at range (``TrackerOptions.window_frames_far``, ``window_far_m``): the
window adjuster resized in the middle of a run still adjusts to the truth (noise-free pixels, the
geometry they were made from as the reference), frames leave it oldest first, and the tracker
switches by the depth it measures, with hysteresis."""

import numpy as np
import pytest
from window_scenes import angle_deg, observe, perturbed, window_scene

from jaxpose.core.geometry import Pose
from jaxpose.core.status import Status
from jaxpose.pipelines.stereo import LandmarkMap, StereoTracker, TrackerOptions
from jaxpose.pipelines.stereo.frames import WINDOW_FAR_BAND, far_window, window_cadence
from jaxpose.pipelines.stereo.window import WindowAdjuster
from jaxpose.vision.stereo_match import disparity_range


def _run(win, rig, X, poses, true_frames, resize_at=None, size=None, fixed_first=True):
    """Feed the frames to the window (those not in ``true_frames`` off by up to 0.5 degree),
    resizing it to ``size`` before frame ``resize_at``; returns the map."""
    rng = np.random.default_rng(5)
    m = LandmarkMap()
    ids = m.add("points", X + rng.normal(0, 0.01, X.shape), np.zeros((60, 32)), Pose(*poses[0]), 0)
    for j, (R, t) in enumerate(poses):
        if j == resize_at:
            win.resize(size)
        Re, te = (R, t) if j in true_frames else perturbed(rng, R, t)
        rec = win.start(Re, te, fixed=fixed_first and j == 0, index=j)
        observe(m, rig, ids, R, t, X, Pose(Re, te), rec)
    return m


def _assert_true(win, m, poses, X):
    assert win.adjust(m)
    for fr in win.frames:
        R, t = poses[fr.index]
        assert angle_deg(fr.R, R) < 1e-5
        np.testing.assert_allclose(fr.t, t, atol=1e-7)
    np.testing.assert_allclose(m.points.X, X, atol=1e-6)


def test_a_grown_window_holds_more_frames_and_adjusts_them_to_the_truth():
    rig, X, poses = window_scene(n_frames=6)
    win = WindowAdjuster(rig, frames=3, iterations=8, max_points=60)
    win.warm_up((5,))
    # frame 0 (the gauge) leaves at frame 5; frame 1, then the oldest, fixes the gauge
    m = _run(win, rig, X, poses, true_frames={0, 1}, resize_at=3, size=5)
    assert win.frames.maxlen == 5 and [fr.index for fr in win.frames] == [1, 2, 3, 4, 5]
    assert max(angle_deg(fr.R, poses[fr.index][0]) for fr in win.frames) > 0.1
    _assert_true(win, m, poses, X)


def test_a_shrunk_window_lets_its_oldest_frames_go_as_they_would_leave():
    rig, X, poses = window_scene(n_frames=5)
    win = WindowAdjuster(rig, frames=5, iterations=8, max_points=60, anchors=4)
    m = _run(win, rig, X, poses, true_frames={0, 1, 2})
    assert [fr.index for fr in win.frames] == [0, 1, 2, 3, 4] and win.kept == []
    win.resize(3)
    assert win.frames.maxlen == 3 and [fr.index for fr in win.frames] == [2, 3, 4]
    # kept for the global adjustment as when they leave one by one: the fixed first, then 1
    assert [fr.index for fr in win.kept] == [0, 1]
    _assert_true(win, m, poses, X)  # frame 2, now the oldest, fixes the gauge
    win.resize(3)  # the same size: nothing moves
    assert [fr.index for fr in win.frames] == [2, 3, 4]
    with pytest.raises(ValueError, match="window frames must be >= 2"):
        win.resize(1)


def test_far_window_enters_at_the_threshold_and_leaves_below_it_over_the_band():
    o = TrackerOptions(window_far_m=3.3)
    low = 3.3 / WINDOW_FAR_BAND
    assert not far_window(o, 3.29, False) and far_window(o, 3.3, False)
    assert far_window(o, low + 0.01, True) and not far_window(o, low - 0.01, True)
    assert not far_window(o, 3.2, False)  # inside the band, from near: stays near
    # no measured depth keeps the choice; the option off is never far
    assert far_window(o, None, True) and not far_window(o, float("nan"), False)
    assert not far_window(TrackerOptions(window_far_m=None), 10.0, False)


def test_far_window_options_are_checked():
    with pytest.raises(ValueError, match="window_frames_far"):
        TrackerOptions(window_frames_far=1)
    with pytest.raises(ValueError, match="window_far_m"):
        TrackerOptions(window_far_m=0.0)


def test_a_far_window_shorter_than_window_frames_does_not_shorten_it():
    """``window_frames=16`` asked for: the far window is never the shorter one."""
    from jaxpose.vision.stereo_render import default_rig

    tracker = StereoTracker(
        default_rig(), None, options=TrackerOptions(window_frames=16, window_every=10)
    )
    assert tracker._far_frames == 16 and tracker._window.frames.maxlen == 16


@pytest.mark.parametrize("range_m, frames", [(2.0, 8), (4.5, 12)])
def test_the_tracker_takes_the_far_window_by_the_depth_it_measures(range_m, frames):
    """Started from the identity (the target frame the first camera frame: its pose's ``t_z``
    says nothing of the range), the landmarks' measured depth decides the window's size, its
    cadence (every frame beyond 3 m, every 3rd at 2 m: ``floor(window_depth_m / depth)`` at the
    depth of the map's origin, moved to the first landmarks, 1.75-2 m), and the depths searched
    when the map has no landmark in view."""
    from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence

    rig = default_rig()
    seq = list(render_sequence(StereoScene(frames=3, range_m=range_m), rig))
    tracker = StereoTracker(rig, None, options=TrackerOptions(depth_range_m=(0.3, 12.0)))
    for fr in seq:
        res = tracker.process(fr.left, fr.right)
    assert res.status == int(Status.OK)
    assert tracker._window.frames.maxlen == frames
    assert window_cadence(tracker.options, tracker._last_depth) == (1 if range_m > 3 else 3)
    d_lo, d_hi = tracker._disparities()  # no prediction: around the map origin's depth
    d_true = float(rig.left.fx) * float(rig.baseline) / range_m  # the target's centre
    full_lo, full_hi = disparity_range(rig, 0.3, 12.0)  # the tracker's whole depth range
    assert d_lo < d_true < d_hi and d_hi - d_lo < 0.5 * (full_hi - full_lo)
