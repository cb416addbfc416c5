"""Windowed joint adjustment of the stereo tracker (jaxpose.pipelines.stereo.window): with
noise-free pixels and the first pose fixed, the adjustment must return the true poses and
landmarks (the reference is the geometry the pixels were made from)."""

import numpy as np
import pytest
from window_scenes import angle_deg, observe, perturbed, window_scene

from jaxpose import PinholeCamera, StereoCamera
from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo import LandmarkMap
from jaxpose.pipelines.stereo.keyframes import observe_line_planes
from jaxpose.pipelines.stereo.window import WindowAdjuster


def _assert_adjusts_to_truth(win, m, poses, X):
    """The adjustment runs and returns the window's true poses; the rays moved to the adjusted
    poses, so the landmarks are the true points."""
    assert win.adjust(m)
    for fr, (R, t) in zip(win.frames, poses, strict=True):
        assert angle_deg(fr.R, R) < 1e-5
        np.testing.assert_allclose(fr.t, t, atol=1e-7)
    np.testing.assert_allclose(m.points.X, X, atol=1e-6)


def test_adjustment_recovers_the_true_poses_and_landmarks():
    iterations = 8
    rig, X, poses = window_scene()
    rng = np.random.default_rng(1)
    m = LandmarkMap()
    win = WindowAdjuster(rig, frames=5, iterations=iterations, max_points=60)
    ids = None
    for j, (R, t) in enumerate(poses):
        # the frames' poses as a tracker would have them: off by up to 0.5 degree and 1 cm
        Re, te = (R, t) if j == 0 else perturbed(rng, R, t)
        pose = Pose(Re, te)
        if ids is None:
            ids = m.add("points", X + rng.normal(0, 0.01, X.shape), np.zeros((60, 32)), pose, 0)
        rec = win.start(Re, te, fixed=j == 0)
        observe(m, rig, ids, R, t, X, pose, rec)
    before = max(angle_deg(fr.R, R) for fr, (R, _) in zip(win.frames, poses, strict=True))
    err_X_before = np.abs(m.points.X - X).max()
    assert before > 0.2 and err_X_before > 1e-3
    _assert_adjusts_to_truth(win, m, poses, X)


def _window_without_a_fixed_frame(gauge=None, prior_frames=3):
    """Six frames of the window scene through a 3-frame window; the first ``prior_frames`` at
    their true poses (their rays stay as the landmarks' priors when they leave), the later ones
    off by up to 0.5 degree; no frame fixed (``gauge=None``: the adjuster's default). With
    ``prior_frames=0`` the landmarks are made (and first observed) by the window's oldest frame,
    so no ray from outside it exists. Returns the adjuster, the map, the window's true poses
    and the true points."""
    rig, X, poses = window_scene(n_frames=6)
    m = LandmarkMap()
    kw = {} if gauge is None else {"gauge": gauge}
    win = WindowAdjuster(rig, frames=3, iterations=8, max_points=60, **kw)
    rng = np.random.default_rng(2)
    start = 3 - prior_frames
    ids = None
    for j, (R, t) in enumerate(poses[start:], start):
        Re, te = perturbed(rng, R, t) if j >= 3 else (R, t)
        if ids is None:
            ids = m.add("points", X, np.zeros((60, 32)), Pose(Re, te), 0)
        rec = win.start(Re, te)
        observe(m, rig, ids, R, t, X, Pose(Re, te), rec)
    return win, m, poses[3:], X


def test_older_rays_are_a_prior_that_holds_the_landmarks():
    """A landmark's rays from frames that left the window stay in its triangulation: with the
    older frames at the true poses, a window whose only fixed information is those rays (no
    fixed frame; the default gauge, ``"rays"``, leaves the oldest frame free) returns the true
    poses, the oldest one's too."""
    win, m, poses, X = _window_without_a_fixed_frame()
    assert win.gauge == "rays"
    assert [fr.fixed for fr in win.frames] == [False] * 3
    assert win.adjust(m)
    for fr, (R, t) in zip(win.frames, poses, strict=True):
        assert angle_deg(fr.R, R) < 1e-4
        np.testing.assert_allclose(fr.t, t, atol=1e-6)
    np.testing.assert_allclose(m.points.X, X, atol=1e-6)


def test_the_oldest_gauge_holds_the_oldest_frame_where_it_is():
    """``gauge="oldest"``: the oldest frame's pose is held as it is even where the rays of
    the frames that left the window would correct it (the gauge of before 2026-12-02)."""
    win, m, poses, _ = _window_without_a_fixed_frame("oldest")
    R0, t0 = win.frames[0].R.copy(), win.frames[0].t.copy()
    assert angle_deg(R0, poses[0][0]) > 0.05  # it starts off the truth
    assert win.adjust(m)
    np.testing.assert_array_equal(win.frames[0].R, R0)
    np.testing.assert_array_equal(win.frames[0].t, t0)


def test_the_rays_gauge_falls_back_to_the_oldest_frame_without_rays_from_outside():
    """``gauge="rays"`` with no landmark seen outside the window: nothing would fix the
    window's gauge, so the oldest frame holds it (its pose unchanged) and the adjustment
    still runs; the same window with the rays of three earlier frames frees it."""
    win, m, _, _ = _window_without_a_fixed_frame("rays", prior_frames=0)
    R0, t0 = win.frames[0].R.copy(), win.frames[0].t.copy()
    assert win.adjust(m)
    np.testing.assert_array_equal(win.frames[0].R, R0)
    np.testing.assert_array_equal(win.frames[0].t, t0)
    assert np.all(np.isfinite(m.points.X))
    win, m, poses, _ = _window_without_a_fixed_frame("rays")
    assert win.adjust(m)
    assert angle_deg(win.frames[0].R, poses[0][0]) < 1e-4


def test_an_unknown_gauge_is_refused_by_name():
    rig, _, _ = window_scene()
    with pytest.raises(ValueError, match="gauge must be one of"):
        WindowAdjuster(rig, frames=3, gauge="first")
    from jaxpose.pipelines.stereo import TrackerOptions

    with pytest.raises(ValueError, match="window_gauge must be one of"):
        TrackerOptions(window_gauge="frozen")
    assert TrackerOptions().window_gauge == "rays"


def test_anchors_keep_past_frames_spread_over_the_run_and_adjust_them():
    """``anchors``: a frame leaving the recent window is kept when it is ``spacing`` frames
    after the last kept one (the fixed first frame always), every other one dropped and the
    spacing doubled beyond ``anchors``; the global adjustment (``spanning=True``) returns the
    kept frames' true poses with the recent ones', the ordinary one leaves the kept frames."""
    rig, X, poses = window_scene(n_frames=9)
    rng = np.random.default_rng(4)
    m = LandmarkMap()
    win = WindowAdjuster(rig, frames=3, iterations=8, max_points=60, anchors=3, anchor_points=60)
    ids = m.add("points", X + rng.normal(0, 0.01, X.shape), np.zeros((60, 32)), Pose(*poses[0]), 0)
    for j, (R, t) in enumerate(poses):
        # off: the frames that will be in the global window (not the dropped 2-4)
        Re, te = perturbed(rng, R, t) if j in (1, 5, 6, 7, 8) else (R, t)
        rec = win.start(Re, te, fixed=j == 0, index=j)
        observe(m, rig, ids, R, t, X, Pose(Re, te), rec)
    # left the window: 0-5; kept 0, 1, 2, 3 -> 0, 1, 3 (spacing 2), 5 -> 0, 1, 5 (spacing 4)
    assert [fr.index for fr in win.kept] == [0, 1, 5]
    kept_before = [fr.R.copy() for fr in win.kept]
    assert win.adjust(m)  # the recent window only
    for fr, R in zip(win.kept, kept_before, strict=True):
        np.testing.assert_array_equal(fr.R, R)
    assert angle_deg(win.kept[1].R, poses[1][0]) > 0.05
    assert win.adjust(m, spanning=True)
    for fr in [*win.kept, *win.frames]:
        R, t = poses[fr.index]
        assert angle_deg(fr.R, R) < 1e-5
        np.testing.assert_allclose(fr.t, t, atol=1e-7)
    np.testing.assert_allclose(m.points.X, X, atol=1e-6)


def test_window_frames_option_is_checked():
    from jaxpose.pipelines.stereo import TrackerOptions

    with pytest.raises(ValueError, match="window_frames"):
        TrackerOptions(window_frames=1)
    with pytest.raises(ValueError, match="window frames"):
        WindowAdjuster(StereoCamera.from_baseline(PinholeCamera(800.0, 800.0, 1.0, 1.0), 0.3), 1)


def test_landmark_cap_still_recovers_poses_and_moves_every_landmark():
    """``max_points`` (``TrackerOptions.window_points``): 20 of the 60 landmarks in the solve;
    the poses are still the true ones and the rays of the other 40 move with them."""
    rig, X, poses = window_scene()
    rng = np.random.default_rng(3)
    m = LandmarkMap()
    win = WindowAdjuster(rig, frames=5, iterations=8, max_points=20)
    ids = m.add("points", X + rng.normal(0, 0.01, X.shape), np.zeros((60, 32)), Pose(*poses[0]), 0)
    for j, (R, t) in enumerate(poses):
        Re, te = perturbed(rng, R, t) if j else (R, t)
        rec = win.start(Re, te, fixed=j == 0)
        observe(m, rig, ids, R, t, X, Pose(Re, te), rec)
    _assert_adjusts_to_truth(win, m, poses, X)


def test_window_every_and_points_options():
    from jaxpose.pipelines.stereo import StereoTracker, TrackerOptions
    from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence

    for bad in (
        dict(window_every=0),
        dict(window_points=0),
        dict(window_anchors=-1),
        dict(window_anchor_every=0),
    ):
        with pytest.raises(ValueError, match=next(iter(bad))):
            TrackerOptions(**bad)
    with pytest.raises(ValueError, match="at most window_frames"):
        TrackerOptions(window_frames=4, window_every=5)
    with pytest.raises(ValueError, match="window_depth_m"):
        TrackerOptions(window_depth_m=0.0)
    # behaviour: the adjustment runs on every window_every-th tracked frame (adjust counted)
    rig = default_rig()
    frames = list(render_sequence(StereoScene(frames=3), rig))
    calls = {}
    for every in (1, 2):
        options = TrackerOptions(window_every=every, window_depth_m=None)
        tracker = StereoTracker(rig, frames[0].pose, options=options)
        tracker._window.adjust = lambda m, e=every, **_: calls.__setitem__(e, calls.get(e, 0) + 1)
        for fr in frames:
            tracker.process(fr.left, fr.right)
    assert calls == {1: 2, 2: 1}  # the 2 tracked frames after the first (map start)
    # the depth rule: floor(window_depth_m / depth) within [1, window_every]
    from jaxpose.pipelines.stereo.frames import window_cadence

    o = TrackerOptions(window_every=3, window_depth_m=6.0)
    ks = [window_cadence(o, z) for z in (1.0, 1.5, 2.5, 3.0, 3.5, 5.0)]
    assert ks == [3, 3, 2, 2, 1, 1]
    assert window_cadence(o, None) == 3  # no depth measured yet: window_every


def test_a_budget_over_the_window_adjusts_every_frame():
    """``budget_window`` (on by default) with a ``feature_budget``: the window is the budgeted
    pose's estimator and runs on every tracked frame, whatever ``window_every`` and the depth
    rule; off, or without a budget, the cadence is ``window_every``."""
    from jaxpose.pipelines.stereo import StereoTracker, TrackerOptions
    from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence

    assert TrackerOptions().budget_window
    rig = default_rig()
    frames = list(render_sequence(StereoScene(frames=4), rig))
    calls = {}
    cases = {
        "budget, window": dict(feature_budget=20),
        "budget, no window": dict(feature_budget=20, budget_window=False),
        "no budget": dict(),
    }
    for name, extra in cases.items():
        options = TrackerOptions(window_every=3, window_depth_m=None, **extra)
        tracker = StereoTracker(rig, frames[0].pose, options=options)
        tracker._window.adjust = lambda m, n=name, **_: calls.__setitem__(n, calls.get(n, 0) + 1)
        for fr in frames:
            tracker.process(fr.left, fr.right)
    # 3 tracked frames after the first (map start): every one, or the third
    assert calls == {"budget, window": 3, "budget, no window": 1, "no budget": 1}
    # the depth rule gives way to the budget's window at every depth
    o = TrackerOptions(feature_budget=20, window_every=3, window_depth_m=6.0)
    from jaxpose.pipelines.stereo.frames import window_cadence

    assert [window_cadence(o, z) for z in (1.0, 2.5, 5.0, None)] == [1, 1, 1, 1]


def test_motion_prior_weights_only_frames_between_their_neighbours():
    """``window_motion_sigma``: the constant-twist prior is weighted at a window frame only when
    the frames before and after it are its neighbours in the sequence (no frame lost between),
    ``1 / sigma^2`` per metre^2 and radian^2."""
    from jaxpose.pipelines.stereo import TrackerOptions

    rig = StereoCamera.from_baseline(PinholeCamera(800.0, 800.0, 319.5, 239.5), 0.3)
    win = WindowAdjuster(rig, frames=6, motion_sigma=(0.5, 4.0))
    for k in (0, 1, 2, 4, 5):  # frame 3 lost
        win.start(np.eye(3), np.zeros(3), index=k)
    w = win._motion_weight(6)
    np.testing.assert_allclose(w[1], [1 / 0.004**2] * 3 + [1 / np.radians(0.5) ** 2] * 3)
    assert not w[[0, 2, 3, 4, 5]].any()
    assert not WindowAdjuster(rig, frames=6)._motion_weight(6).any()
    with pytest.raises(ValueError, match="window_motion_sigma"):
        TrackerOptions(window_motion_sigma=(0.5, 0.0))


@pytest.mark.parametrize("free_lines", [True, False])
def test_free_lines_are_moved_onto_the_true_lines(free_lines):
    """Line landmarks placed 1 cm off and observed by noise-free stereo planes at the frames'
    (wrong) poses: with the lines free, the adjustment moves the window's planes to the true
    poses and the map's lines onto the true lines (the lines all the planes meet in); held
    (``free_lines=False``), the lines keep the planes of the wrong poses."""
    rig, X, poses = window_scene()
    rng = np.random.default_rng(5)
    P = rng.uniform(-0.3, 0.3, (6, 2, 3))
    m = LandmarkMap()
    win = WindowAdjuster(
        rig, frames=5, iterations=8, max_points=60, max_lines=4, free_lines=free_lines
    )
    ids = m.add("points", X + rng.normal(0, 0.01, X.shape), np.zeros((60, 32)), Pose(*poses[0]), 0)
    lids = m.add("lines", P + rng.normal(0, 0.01, P.shape), np.zeros((6, 32)), Pose(*poses[0]), 0)
    for j, (R, t) in enumerate(poses):
        Re, te = perturbed(rng, R, t) if j else (R, t)
        rec = win.start(Re, te, fixed=j == 0)
        observe(m, rig, ids, R, t, X, Pose(Re, te), rec)
        observe_line_planes(m, rig, lids, P @ R.T + t, Pose(Re, te), log=rec)  # true segments
    _assert_adjusts_to_truth(win, m, poses, X)
    u = (P[:, 1] - P[:, 0]) / np.linalg.norm(P[:, 1] - P[:, 0], axis=1, keepdims=True)
    r = m.lines.X - P[:, :1]
    across = np.linalg.norm(r - np.einsum("kei,ki->ke", r, u)[..., None] * u[:, None], axis=-1)
    if free_lines:
        assert across.max() < 1e-6
    else:
        assert across.max() > 1e-3


@pytest.mark.parametrize("held_lines", [False, True])
def test_a_line_with_no_plane_in_the_window_is_left_out_unless_held(held_lines):
    """A line landmark placed askew (one endpoint 5 cm off its true line) and matched in every
    frame's left image, with no observation plane in the window: left out (the default), the
    adjustment returns the true poses from the exact points; held where the map has it
    (``held_lines=True``), it pulls the poses off (its true image lines no longer fit)."""
    from window_scenes import pixels

    from jaxpose.pipelines.stereo._arrays import lines_from_segments

    rig, X, poses = window_scene()
    rng = np.random.default_rng(7)
    P = np.array([[-0.25, 0.2, 0.1], [0.2, -0.25, -0.15]])  # the true line, body frame
    placed = P.copy()
    placed[1] += np.array([0.0, 0.05, 0.0])
    m = LandmarkMap()
    win = WindowAdjuster(rig, frames=5, iterations=8, max_points=60, held_lines=held_lines)
    ids = m.add("points", X + rng.normal(0, 0.01, X.shape), np.zeros((60, 32)), Pose(*poses[0]), 0)
    lid = m.add("lines", placed[None], np.zeros((1, 32)), Pose(*poses[0]), 0)
    for j, (R, t) in enumerate(poses):
        Re, te = perturbed(rng, R, t) if j else (R, t)
        rec = win.start(Re, te, fixed=j == 0)
        observe(m, rig, ids, R, t, X, Pose(Re, te), rec)
        seg = pixels(rig, R, t, P)[0][None]  # the true line's left image
        rec.line_ids = m.lines.ids[lid]
        rec.lines = lines_from_segments(seg)
        rec.line_weight = 1.0
    if not held_lines:
        _assert_adjusts_to_truth(win, m, poses, X)
    else:
        assert win.adjust(m)
        off = max(angle_deg(fr.R, R) for fr, (R, _) in zip(win.frames, poses, strict=True))
        assert off > 1e-3
