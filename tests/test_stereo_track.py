"""Stereo sequence renderer, tracker and the stereo-track command on small rendered sequences."""

import json
from dataclasses import replace

import numpy as np
import pytest

from jaxpose.core.status import Status
from jaxpose.pipelines.stereo import STAGES, StereoTracker, TrackerOptions, target_roi
from jaxpose.vision.stereo_features import extract
from jaxpose.vision.stereo_match import disparity_range, match_points_stereo
from jaxpose.vision.stereo_render import (
    StereoScene,
    default_rig,
    render_sequence,
    render_stereo_frame,
    scene_pose,
    tumbler_model,
)

RIG = default_rig()


@pytest.fixture(scope="module")
def frames():
    return list(render_sequence(StereoScene(frames=6), RIG))


def test_scene_motion_and_two_turns():
    scene = StereoScene()
    assert scene.n_frames() == int(np.ceil(720 / 10.2 * 5.0)) + 1
    R0, t0 = scene_pose(scene, 0.0)
    R1, _ = scene_pose(scene, 1.0)
    # one second spins 10.2 degrees about the body z axis
    angle = np.degrees(np.arccos((np.trace(R1 @ R0.T) - 1) / 2))
    assert angle == pytest.approx(10.2, abs=1e-9)
    np.testing.assert_allclose(R0 @ [0, 0, 1.0], R1 @ [0, 0, 1.0], atol=1e-12)
    assert t0[2] == 2.0
    with pytest.raises(ValueError):
        StereoScene(frames=1).n_frames()


def test_rendered_stereo_points_lie_on_the_model(frames):
    fr = frames[0]
    assert fr.left.shape == fr.right.shape == (768, 1024) and fr.left.dtype == np.uint8
    f = extract(fr.left, roi=target_roi(fr.left), lines=False)
    pm = match_points_stereo(fr.left, fr.right, f.points, disparity_range(RIG, 1.3, 2.7))
    assert pm.ok.sum() > 100
    X = np.asarray(RIG.triangulate(f.points[pm.ok], pm.pixels_right[pm.ok]))
    Pb = (X - np.asarray(fr.pose.t)) @ np.asarray(fr.pose.R)  # body frame
    m = tumbler_model()
    body_half = np.abs(m.vertices[:8]).max(0)
    on_body = np.all(np.abs(Pb) < body_half + 0.01, axis=1)
    wing = m.vertices[8:16]
    on_wing = np.all((Pb > wing.min(0) - 0.01) & (Pb < wing.max(0) + 0.01), axis=1)
    on_rod = np.zeros(len(Pb), bool)
    for a, b in (m.vertices[16:18], m.vertices[18:20]):  # the antennas: 2 cm of their segments
        s = np.clip((Pb - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
        on_rod |= np.linalg.norm(Pb - (a + s[:, None] * (b - a)), axis=1) < 0.02
    # nearly all on the model (the outline's corners include the wing's and the antennas'; the
    # few others are windows across the outline), those on the body's faces close to one plane
    assert (on_body | on_wing | on_rod).mean() > 0.93
    assert on_body.mean() > 0.85
    gap = np.min(np.abs(np.abs(Pb[on_body]) - body_half), axis=1)
    assert np.median(gap) < 0.005


def test_glints_and_blur_change_the_image():
    base = render_stereo_frame(StereoScene(frames=2, noise_sigma=0.0), RIG, 1)
    glint = render_stereo_frame(
        StereoScene(frames=2, noise_sigma=0.0, glints=3.0, shininess=50.0), RIG, 1
    )
    blur = render_stereo_frame(StereoScene(frames=2, noise_sigma=0.0, blur=1.0), RIG, 1)
    assert glint.left.astype(int).sum() > base.left.astype(int).sum()
    assert np.abs(blur.left.astype(int) - base.left.astype(int)).mean() > 0.2
    # blur smooths: less high-frequency energy
    lap = lambda im: np.abs(np.diff(im.astype(float), axis=1)).mean()  # noqa: E731
    assert lap(blur.left) < lap(base.left)
    np.testing.assert_allclose(np.asarray(blur.pose.R), np.asarray(base.pose.R))


@pytest.mark.parametrize("use_lines", [True, False])
def test_tracker_follows_a_short_sequence(frames, use_lines):
    tracker = StereoTracker(RIG, frames[0].pose, options=TrackerOptions(use_lines=use_lines))
    for fr in frames:
        res = tracker.process(fr.left, fr.right)
        assert res.status == Status.OK
        R, t = np.asarray(fr.pose.R), np.asarray(fr.pose.t)
        angle = np.degrees(np.arccos(np.clip((np.trace(res.R @ R.T) - 1) / 2, -1, 1)))
        assert angle < 1.0
        assert np.linalg.norm(res.t - t) < 0.02
        stages = set(STAGES)  # features, match, stereo, triangulate, budget, pose, map
        assert set(res.timings) == stages and set(res.cpu_timings) == stages
        assert all(v >= 0 for v in res.cpu_timings.values())
    if use_lines:
        assert res.n_lines > 0


def test_tracking_does_not_depend_on_the_callers_precision(frames):
    """Built and run with ``jax_enable_x64`` off outside, the tracker still solves in float64:
    the same poses to the last bit as with it on; a rig made while it is off (float32) tracks
    to the poses of its values within float32 rounding."""
    import jax

    runs = []
    for x64 in (True, False):
        with jax.enable_x64(x64):
            tracker = StereoTracker(RIG, frames[0].pose)
            runs.append([tracker.process(fr.left, fr.right) for fr in frames[:3]])
    for a, b in zip(*runs, strict=True):
        assert a.status == b.status == Status.OK
        np.testing.assert_array_equal(a.R, b.R)
        np.testing.assert_array_equal(a.t, b.t)
    with jax.enable_x64(False):
        rig32 = default_rig()
        assert rig32.left.fx.dtype == np.float32
        tracker = StereoTracker(rig32, frames[0].pose)
        near = [tracker.process(fr.left, fr.right) for fr in frames[:3]]
    for a, b in zip(runs[0], near, strict=True):
        assert b.status == Status.OK and b.t.dtype == np.float64
        np.testing.assert_allclose(b.R, a.R, atol=1e-5)
        np.testing.assert_allclose(b.t, a.t, atol=1e-5)


def test_tracker_reports_lost_instead_of_a_pose(frames):
    tracker = StereoTracker(RIG, frames[0].pose)
    tracker.process(frames[0].left, frames[0].right)
    black = np.zeros_like(frames[0].left)
    res = tracker.process(black, black)
    assert res.status == Status.LOST and np.all(np.isnan(res.R)) and np.all(np.isnan(res.t))
    # the keyframe survives: the target reappears and tracking resumes
    res = tracker.process(frames[2].left, frames[2].right)
    assert res.status == Status.OK
    with pytest.raises(ValueError, match="images must be"):
        tracker.process(black[:10], black[:10])


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_an_image_that_could_not_be_read_is_named(frames):
    tracker = StereoTracker(RIG, frames[0].pose)
    with pytest.raises(ValueError, match="right image is None"):  # what cv2.imread returns
        tracker.process(frames[0].left, None)


def test_images_of_any_depth_track_as_their_8_bit_version(frames):
    """Float images on the [0, 1] scale, float on the 0-255 scale, 16-bit images and BGR(A)
    colour images give the poses of the 8-bit grey frames (the library's one image convention,
    as initialise_pose reads an image): [0, 1] floats were read on the 0-255 scale and lost every
    feature, colour frames were refused."""
    ref = StereoTracker(RIG, frames[0].pose)
    want = [ref.process(fr.left, fr.right) for fr in frames[:2]]
    for convert in (
        lambda im: im / 255.0,
        lambda im: im.astype(np.float32),
        lambda im: im.astype(np.uint16) * 257,
        lambda im: np.stack([im] * 3, -1),
        lambda im: np.stack([im] * 3 + [np.full_like(im, 255)], -1),
    ):
        tracker = StereoTracker(RIG, frames[0].pose)
        for fr, w in zip(frames[:2], want, strict=True):
            got = tracker.process(convert(fr.left), convert(fr.right))
            assert got.status == w.status == Status.OK
            np.testing.assert_array_equal(got.t, w.t)


def test_tracker_rejects_unrectified_rigs():
    from jaxpose import PinholeCamera, StereoCamera

    cam = PinholeCamera(500.0, 500.0, 319.5, 239.5, width=640, height=480)
    with pytest.raises(ValueError, match="rectified"):
        StereoTracker(StereoCamera(cam, cam, np.eye(3), np.array([-0.3, 0.05, 0.0])))


def test_keypoint_budget_follows_the_target_area():
    """One keypoint per spacing^2 pixels of target (rounded to 100, within [keypoint_floor,
    n_points]); the apparent area is the count of bright pixels (checked on a drawn disc)."""
    from jaxpose.pipelines.stereo.tracker import target_area

    tracker = StereoTracker(RIG, None)
    assert tracker.feature_options(8.0**2 * 1234).n_points == 1200
    assert tracker.feature_options(8.0**2 * 5000).n_points == 2000  # never above the budget
    assert tracker.feature_options(10.0).n_points == 1000  # the floor on a small target
    assert tracker.feature_options(8.0**2 * 640).n_points == 1000
    assert tracker.feature_options(None).n_points == 2000
    opts = TrackerOptions(keypoint_spacing_px=16.0, keypoint_floor=100)
    wide = StereoTracker(RIG, None, options=opts)
    assert wide.feature_options(8.0**2 * 1234).n_points == 300
    assert wide.feature_options(10.0).n_points == 100
    fixed = StereoTracker(RIG, None, options=TrackerOptions(keypoint_spacing_px=None))
    assert fixed.feature_options(8.0**2 * 1234).n_points == 2000
    img = np.zeros((768, 1024), np.uint8)
    vv, uu = np.mgrid[:768, :1024]
    img[(uu - 500) ** 2 + (vv - 400) ** 2 < 200**2] = 120
    assert target_area(img) == pytest.approx(np.pi * 200**2, rel=0.02)
    # LSD's scale: sqrt(lsd_area_px / area) of the options' on a larger target, at least 0.4
    assert tracker.feature_options(100_000.0).lsd_scale == 0.8
    assert tracker.feature_options(120_000.0 * 1.5625).lsd_scale == pytest.approx(0.64)
    assert tracker.feature_options(120_000.0 * 9).lsd_scale == 0.4
    with pytest.raises(ValueError, match="keypoint_spacing_px"):
        TrackerOptions(keypoint_spacing_px=0.0)
    with pytest.raises(ValueError, match="lsd_area_px"):
        TrackerOptions(lsd_area_px=-1.0)
    with pytest.raises(ValueError, match="keypoint_floor"):
        TrackerOptions(keypoint_floor=0)


def test_a_near_target_can_get_full_resolution_corners_at_their_response_peak():
    """With ``fine_corners_area_px``, from that apparent area up one ORB level and the
    response's sub-pixel peak; below it (and with the option off) the tracker's default, three
    pyramid levels at the response's peak."""
    from jaxpose.vision.stereo_features import detect_points

    limit = 100_000.0
    assert TrackerOptions().fine_corners_area_px is None  # off by default
    tracker = StereoTracker(RIG, None, options=TrackerOptions(fine_corners_area_px=limit))
    near, far = tracker.feature_options(limit), tracker.feature_options(0.99 * limit)
    assert (near.orb_levels, near.subpixel) == (1, "peak")
    assert (far.orb_levels, far.subpixel) == (3, "peak")
    assert near.n_points == round(limit / 8.0**2, -2)  # the budget still follows the area
    off = StereoTracker(RIG, None, options=TrackerOptions(fine_corners_area_px=None))
    assert off.feature_options(10 * limit).orb_levels == 3
    with pytest.raises(ValueError, match="fine_corners_area_px"):
        TrackerOptions(fine_corners_area_px=0.0)
    # hysteresis: entered at the threshold, left below threshold / FINE_CORNERS_BAND
    from jaxpose.pipelines.stereo.frames import FINE_CORNERS_BAND, fine_corners

    o, low = tracker.options, limit / FINE_CORNERS_BAND
    areas = [0.9 * limit, limit, 0.9 * limit, 1.01 * low, 0.99 * low, 0.9 * limit, 2 * limit]
    kinds, previous = [], None
    for a in areas:
        previous = fine_corners(o, a, previous)
        kinds.append(previous)
    assert kinds == [False, True, True, True, False, False, True]
    assert fine_corners(off.options, 10 * limit) is False
    # the tracker keeps the last frame's kind: a frame within the band stays as the one before

    def disc(area):
        img = np.zeros((768, 1024), np.uint8)
        vv, uu = np.mgrid[:768, :1024]
        img[(uu - 512) ** 2 + (vv - 384) ** 2 < area / np.pi] = 120
        return img

    seq = StereoTracker(RIG, None, options=tracker.options)
    seq.detect(disc(1.2 * limit))
    assert seq._fine is True
    seq.detect(disc(0.85 * limit))
    assert seq._fine is True
    fresh = StereoTracker(RIG, None, options=tracker.options)
    fresh.detect(disc(0.85 * limit))
    assert fresh._fine is False
    # the near options' keypoints are ORB's full-resolution corners, each moved by at most half
    # a pixel on each axis from its whole pixel (cornerSubPix moves them by pixels)
    img = render_stereo_frame(StereoScene(range_m=1.5), RIG, 0).left
    roi = target_roi(img)
    pts, _ = detect_points(img, options=near, roi=roi)
    raw, _ = detect_points(img, options=replace(near, subpixel=False), roi=roi)
    assert len(pts) == len(raw) > 200
    moved = pts - np.rint(raw)
    assert np.abs(moved).max() <= 0.5 + 1e-6 and np.mean(np.abs(moved) > 0.01) > 0.5
    refined, _ = detect_points(img, options=replace(near, subpixel=True), roi=roi)
    assert np.abs(refined - np.rint(raw)).max() > 1.0


def test_search_radius_follows_the_measured_prediction_error(frames):
    """After a tracked frame the radius is 3 x the 90th percentile of the landmarks' predicted
    vs fitted pixel distance + 3 sigma (clipped to [r0 / 2, 4 r0]), recomputed here by hand."""
    from jaxpose.core.geometry import Pose

    tracker = StereoTracker(RIG, frames[0].pose)
    X = np.random.default_rng(0).uniform(-0.3, 0.3, (50, 3))
    pose = Pose(np.asarray(frames[0].pose.R), np.asarray(frames[0].pose.t))
    shifted = Pose(np.asarray(pose.R), np.asarray(pose.t) + np.array([0.004, 0.0, 0.0]))
    tracker._update_radius(X, shifted, pose)
    fx = float(RIG.left.fx)
    z = (X @ np.asarray(pose.R).T + np.asarray(pose.t))[:, 2]
    expected = 3 * np.percentile(fx * 0.004 / z, 90) + 3.0
    assert tracker._radius == pytest.approx(expected, rel=1e-6)
    tracker._update_radius(X, pose, pose)  # a perfect prediction: the floor r0 / 2
    assert tracker._radius == pytest.approx(6.0)
    far = Pose(np.asarray(pose.R), np.asarray(pose.t) + np.array([0.2, 0.0, 0.0]))
    tracker._update_radius(X, far, pose)  # the ceiling 4 r0
    assert tracker._radius == pytest.approx(48.0)


def test_stereo_track_command_json(tmp_path, capsys):
    from jaxpose.cli import main

    code = main(
        [
            "stereo-track",
            "--frames",
            "4",
            "--image-size",
            "640x480",
            "--json",
            "--out",
            str(tmp_path),
        ]
    )
    assert code == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    summary = json.loads(last)
    assert set(summary) == {
        "frames",
        "rms_position_mm",
        "rms_attitude_deg",
        "lost_frames",
        "fps",
        "start_s",
    }
    assert summary["frames"] == 4 and summary["lost_frames"] == 0
    assert summary["fps"] > 0 and summary["start_s"] > 0
    assert len(summary["rms_position_mm"]) == 3 and len(summary["rms_attitude_deg"]) == 3
    for name in (
        "trajectory.csv",
        "fig3_position_track.png",
        "fig4_position.png",
        "fig5_attitude.png",
    ):
        assert (tmp_path / name).is_file()
    assert main(["stereo-track", "--blur", "2", "--out", str(tmp_path)]) == 2


def test_tracker_map_lies_on_the_target(frames):
    """The landmarks are in the body frame: after a few frames they lie on the model's faces
    (independent reference: the model geometry), and the map has grown from the first frame."""
    tracker = StereoTracker(RIG, frames[0].pose)
    for fr in frames:
        assert tracker.process(fr.left, fr.right).status == Status.OK
    X = tracker.map.points.X
    half = np.abs(tumbler_model().vertices[:8]).max(0)
    on_body = np.all(np.abs(X) < half + 0.01, axis=1)
    assert on_body.mean() > 0.8
    assert np.median(np.min(np.abs(np.abs(X[on_body]) - half), axis=1)) < 0.003
    assert len(tracker.map.lines) > 0


def test_line_gate_uses_the_landmark_disparity_at_the_endpoint_rows():
    """The gate of the line-plane refinement: a segment triangulated at the landmark line agrees;
    one whose depth gives 1.5 px more disparity at an endpoint does not (disparity fx b / Z of the
    rig, computed here by hand)."""
    from jaxpose.core.geometry import Pose
    from jaxpose.pipelines.stereo import LandmarkMap
    from jaxpose.pipelines.stereo.keyframes import line_disparity_agrees

    landmarks = LandmarkMap()
    fx, b = float(RIG.left.fx), float(RIG.baseline)
    pose = Pose(np.eye(3), np.zeros(3))  # body = left camera
    line = np.array([[[-0.1, -0.2, 2.0], [0.05, 0.25, 2.3]]])
    landmarks.add("lines", line, np.zeros((1, 32), np.uint8), pose, 0)
    # a shorter segment on the same 3-D line: agrees
    s = 0.2
    same = np.stack([line[0, 0] + s * (line[0, 1] - line[0, 0]), line[0, 1]])[None]
    # far endpoint pushed along its ray to 1.5 px more disparity
    Z = line[0, 1, 2]
    Z_off = fx * b / (fx * b / Z + 1.5)
    off = same.copy()
    off[0, 1] *= Z_off / Z
    # 0.5 px more: still agrees
    near = same.copy()
    near[0, 1] *= fx * b / (fx * b / Z + 0.5) / Z
    idx = np.zeros(1, int)
    agrees = lambda S: line_disparity_agrees(landmarks, RIG, idx, S, pose, 1.0).tolist()  # noqa: E731
    assert agrees(same) == [True]
    assert agrees(near) == [True]
    assert agrees(off) == [False]


def test_measured_line_sigma_is_the_ratio_of_the_residual_scales():
    """Point residuals: 2-D distances of Gaussian pixel noise sigma 0.8; line residuals: the larger
    of two endpoint distances with sigma 0.4 (sampled here): the measured line weight is their
    ratio, 0.5, within the sampling error; the running average moves towards it."""
    rng = np.random.default_rng(3)
    e_p = np.linalg.norm(rng.normal(0.0, 0.8, (20000, 2)), axis=1)
    e_l = np.abs(rng.normal(0.0, 0.4, (20000, 2))).max(1)
    tracker = StereoTracker(RIG, None, options=TrackerOptions(line_scale_memory=0.0))
    tracker.update_line_scale(e_p, e_l)
    assert tracker.line_scale == pytest.approx(0.5, rel=0.03)
    slow = StereoTracker(RIG, None, options=TrackerOptions(line_scale_memory=0.9))
    slow.update_line_scale(e_p, e_l)
    assert slow.line_scale == pytest.approx(0.9 + 0.1 * 0.5, rel=0.01)
    slow.update_line_scale(e_p, e_l[:2])  # too few lines: unchanged
    assert slow.line_scale == pytest.approx(0.9 + 0.1 * 0.5, rel=0.01)
    with pytest.raises(ValueError, match="line_scale_memory"):
        StereoTracker(RIG, None, options=TrackerOptions(line_scale_memory=1.0))


def test_an_all_nan_first_frame_is_a_status_and_the_map_starts_later(frames):
    tracker = StereoTracker(RIG, frames[0].pose)
    nan = np.full(frames[0].left.shape, np.nan)
    res = tracker.process(nan, nan)
    assert res.status == Status.TOO_FEW_POINTS
    assert np.all(np.isnan(res.R)) and np.all(np.isnan(res.t))
    assert len(tracker.map.points) == 0
    res = tracker.process(frames[0].left, frames[0].right)
    assert res.status == Status.OK and len(tracker.map.points) > 100
    res = tracker.process(frames[1].left, frames[1].right)
    assert res.status == Status.OK


def test_identity_start_tracks_the_motion_relative_to_the_first_frame(frames):
    """Started at the identity (target frame = first left camera frame), the pose at frame k is
    T_k T_0^-1 of the true poses; stereo-track's summary aligns it back on the first frame."""
    from jaxpose.core.geometry import Pose
    from jaxpose.studies.stereo_track import summarize

    tracker = StereoTracker(RIG, None)
    results = [tracker.process(fr.left, fr.right) for fr in frames]
    T0_inv = frames[0].pose.inverse()
    for fr, res in zip(frames, results, strict=True):
        assert res.status == Status.OK
        rel = fr.pose @ T0_inv
        R = np.asarray(rel.R)
        angle = np.degrees(np.arccos(np.clip((np.trace(res.R @ R.T) - 1) / 2, -1, 1)))
        assert angle < 0.5
        assert np.linalg.norm(res.t - np.asarray(rel.t)) < 0.02
    np.testing.assert_allclose(results[0].R, np.eye(3))
    rep = summarize(results, [fr.pose for fr in frames], [0.1] * len(frames))["summary"]
    assert max(rep["rms_position_mm"]) < 20.0 and max(rep["rms_attitude_deg"]) < 0.5
    # a wrong first truth moves every aligned estimate: the alignment is really applied
    shifted = [Pose(np.asarray(frames[0].pose.R), np.asarray(frames[0].pose.t) + 0.1)]
    rep2 = summarize(results, shifted + [fr.pose for fr in frames[1:]], [0.1] * len(frames))
    assert max(rep2["summary"]["rms_position_mm"]) > 50.0


def test_the_map_origin_moves_to_the_landmarks_only_from_outside_the_target():
    """map_origin: a given origin within the first landmarks (a body centre) is kept; one far
    outside them (the first camera's, a start at the identity) moves to their median."""
    from jaxpose.core.geometry import Pose
    from jaxpose.pipelines.stereo.landmarks import map_origin

    rng = np.random.default_rng(3)
    X = rng.uniform(-0.3, 0.3, (200, 3))  # body frame, origin at the centre
    truth = Pose(scene_pose(StereoScene(), 0.0)[0], np.array([0.1, -0.2, 4.0]))
    Xc = X @ np.asarray(truth.R).T + np.asarray(truth.t)
    np.testing.assert_array_equal(map_origin(truth, Xc), np.zeros(3))
    np.testing.assert_allclose(map_origin(Pose.identity(), Xc), np.median(Xc, axis=0))
    np.testing.assert_array_equal(map_origin(Pose.identity(), Xc[:9]), np.zeros(3))  # too few


@pytest.mark.slow
def test_an_identity_start_at_5_m_tracks_as_well_as_the_truth():
    """At 5 m the map's origin decides the aligned errors: kept at the first camera (an identity
    start) they were twice a truth start's in x on these 10 frames (31.0 against 15.2 mm);
    moved to the first landmarks (map_origin) they are the truth start's."""
    from jaxpose.core.geometry import Pose
    from jaxpose.studies.stereo_track import summarize, track_sequence

    scene = StereoScene(frames=10, range_m=5.0, rate_deg_s=5.0, blur=0.5)
    seq = list(render_sequence(scene, RIG))
    rms = {}
    for name, start in (("truth", None), ("identity", lambda fr: Pose.identity())):
        results, truths, seconds = track_sequence(seq, RIG, initial_pose=start)
        rep = summarize(results, truths, seconds)["summary"]
        assert rep["lost_frames"] == 0
        rms[name] = np.array(rep["rms_position_mm"] + rep["rms_attitude_deg"])
    slack = np.r_[1.0, 1.0, 1.0, 0.02, 0.02, 0.02]  # mm, degree
    assert (rms["identity"] <= 1.2 * rms["truth"] + slack).all(), rms


def test_young_landmarks_are_matched_but_left_out_of_the_pose_solve():
    """fit_pose on a synthetic map: 120 mature landmarks observed exactly, 120 young ones whose
    map positions are 2.5 mm off (about 1.4 px at 2 m). With mature_obs the fit is the true pose
    and the young landmarks' residuals are still measured; without it they pull the pose."""
    from types import SimpleNamespace

    from jaxpose.core.geometry import Pose
    from jaxpose.pipelines.stereo import LandmarkMap
    from jaxpose.pipelines.stereo.frame_pose import fit_pose

    rng = np.random.default_rng(5)
    truth = Pose(scene_pose(StereoScene(), 0.0)[0], np.array([0.0, 0.0, 2.0]))
    X = rng.uniform(-0.25, 0.25, (240, 3))
    Xc = X @ np.asarray(truth.R).T + np.asarray(truth.t)
    fx, cx, cy = float(RIG.left.fx), float(RIG.left.cx), float(RIG.left.cy)
    pixels = np.stack([fx * Xc[:, 0] / Xc[:, 2] + cx, fx * Xc[:, 1] / Xc[:, 2] + cy], 1)
    landmarks = LandmarkMap()
    stored = X.copy()
    stored[120:] += np.array([0.0025, 0.0, 0.0])  # young landmarks, consistently off
    landmarks.add("points", stored, np.zeros((240, 32), np.uint8), truth, 0)
    landmarks.points.n_obs[:120] = 5
    feats = SimpleNamespace(
        points=pixels, segments=np.zeros((0, 2, 2)), line_desc=np.zeros((0, 32), np.uint8)
    )
    idx = np.arange(240)
    matches = (idx, idx, np.zeros(0, int), np.zeros(0, int))
    start = Pose(np.asarray(truth.R), np.asarray(truth.t) + np.array([0.003, -0.002, 0.01]))
    fits = {}
    for mature in (0, 3):
        opts = TrackerOptions(mature_obs=mature)
        fits[mature] = fit_pose(landmarks, feats, None, matches, start, RIG, opts, 1.0)
    err = {m: np.linalg.norm(np.asarray(f.pose.t) - np.asarray(truth.t)) for m, f in fits.items()}
    assert err[3] < 1e-6 < 1e-4 < err[0]
    young = fits[3].e_points[120:]
    assert np.all(young > 0.5) and np.all(young < 2.0)  # measured at the fitted pose
    # those below reject_px get rays, the others not
    np.testing.assert_array_equal(fits[3].kept_points[120:], young < 1.5)
    assert fits[3].kept_points[:120].all()


def test_monocular_start_feeds_the_tracker_and_falls_back_to_the_identity(frames, monkeypatch):
    """--init monocular: the first left image goes to jaxpose.initialise_pose with the rendered
    target's model and the rig's left camera; its pose starts the tracker, whose errors after
    aligning the first frame are those of a start at the truth. With no full pose the start is
    the identity. (initialise_pose itself is replaced by a stand-in here: its own tests cover
    it, and its compilation would take half a minute.)"""
    from types import SimpleNamespace

    import jaxpose
    from jaxpose.core.geometry import Pose
    from jaxpose.studies.stereo_track import monocular_start, summarize, track_sequence

    truth0 = frames[0].pose
    off = Pose.from_rotvec(np.radians([4.0, -6.0, 3.0]), np.array([0.03, -0.02, 0.05]))
    guess = off @ truth0
    calls = []

    def fake(image, camera, model, options=None):
        calls.append((image, camera, model))
        return SimpleNamespace(pose=guess, confidence="low", message="")

    monkeypatch.setattr(jaxpose, "initialise_pose", fake)
    model = tumbler_model()
    info = {}
    start = monocular_start(frames[0].left, RIG, model, info=info)
    assert calls[0][0] is frames[0].left and calls[0][1] is RIG.left and calls[0][2] is model
    np.testing.assert_allclose(np.asarray(start.R), np.asarray(guess.R), atol=1e-12)
    assert info["init"] == "monocular" and info["confidence"] == "low"

    truths = [fr.pose for fr in frames]
    runs = {}
    for name, initial in (("truth", None), ("monocular", lambda fr: start)):
        results, _, seconds = track_sequence(frames, RIG, initial_pose=initial)
        assert all(r.status == Status.OK for r in results)
        runs[name] = (results, summarize(results, truths, seconds)["summary"])
    np.testing.assert_allclose(runs["monocular"][0][0].R, np.asarray(guess.R), atol=1e-9)
    a, b = runs["truth"][1], runs["monocular"][1]
    assert max(b["rms_position_mm"]) < 20.0 and max(b["rms_attitude_deg"]) < 0.5
    np.testing.assert_allclose(b["rms_position_mm"], a["rms_position_mm"], atol=3.0)
    np.testing.assert_allclose(b["rms_attitude_deg"], a["rms_attitude_deg"], atol=0.1)

    # no full pose: the identity, and the summary says so
    monkeypatch.setattr(
        jaxpose,
        "initialise_pose",
        lambda *a, **k: SimpleNamespace(pose=None, confidence="none", message="no target"),
    )
    info = {}
    start = monocular_start(frames[0].left, RIG, model, info=info)
    np.testing.assert_allclose(np.asarray(start.R), np.eye(3))
    np.testing.assert_allclose(np.asarray(start.t), np.zeros(3))
    assert info["init"].startswith("identity") and info["message"] == "no target"


def test_the_frame_rate_leaves_the_start_and_the_compilation_out():
    """fps is the rate of the frames after the first two (the map's start, the solver's
    compilation), whose seconds are start_s; with fewer than four frames, after the first."""
    from jaxpose.core.geometry import Pose
    from jaxpose.pipelines.stereo import FrameResult
    from jaxpose.studies.stereo_track import summarize

    def tracked(n):
        pose = Pose(np.eye(3), np.array([0.0, 0.0, 2.0]))
        return [FrameResult(k, pose, int(Status.OK), 1, 0, 1, 0.5, True) for k in range(n)]

    s = summarize(tracked(5), [None] * 5, [5.0, 2.0, 0.1, 0.1, 0.2])["summary"]
    assert s["fps"] == pytest.approx(3 / 0.4) and s["start_s"] == pytest.approx(7.0)
    s = summarize(tracked(3), [None] * 3, [5.0, 0.5, 0.5])["summary"]
    assert s["fps"] == pytest.approx(2.0) and s["start_s"] == pytest.approx(5.0)


@pytest.mark.typecheck_off  # as a user runs it: the annotation says tuple, the checks accept more
def test_option_pairs_take_lists_and_numpy_arrays():
    """``depth_range_m`` and ``window_motion_sigma`` given as a list or a NumPy array are kept as
    the documented tuples (a NumPy array had been refused, a list left the options unhashable)."""
    for pair in (np.array([0.5, 6.0]), [0.5, 6.0]):
        o = TrackerOptions(depth_range_m=pair, window_motion_sigma=np.array([0.3, 5.0]))
        assert o.depth_range_m == (0.5, 6.0) and isinstance(o.depth_range_m, tuple)
        assert o.window_motion_sigma == (0.3, 5.0)
        assert hash(o) == hash(TrackerOptions(depth_range_m=(0.5, 6.0)))


def test_predicted_disparity_windows_narrow_after_the_warm_up(frames):
    """With ``predicted_disparity`` and ``predicted_disparity_after=3`` the first three tracked
    frames search every feature over the map's depth window (one range for all, as with the
    option off) while the margin is measured; from the fourth on, the matched points get their
    own windows, narrower than the depth window."""
    opts = TrackerOptions(predicted_disparity=True, predicted_disparity_after=3)
    tracker = StereoTracker(RIG, frames[0].pose, options=opts)
    seen = []
    inner = tracker.feature_disparities

    def spy(feats, pose_pred, matches=None):
        out = inner(feats, pose_pred, matches)
        if matches is not None:
            seen.append((tracker._run, tracker._disparity_margin, out))
        return out

    tracker.feature_disparities = spy
    for fr in frames:
        assert tracker.process(fr.left, fr.right).status == Status.OK
    assert [run for run, _, _ in seen] == [0, 1, 2, 3, 4]
    base_width = None
    for _, _, (dp, dl, predicted) in seen[:3]:
        assert predicted is not None and len(predicted[0]) > 50
        assert len(np.unique(dp, axis=0)) == 1 and len(np.unique(dl, axis=0)) <= 1
        base_width = dp[0, 1] - dp[0, 0]
    assert seen[1][1] != opts.disparity_margin_px  # measured on the first tracked frame
    for _, margin, (dp, _, (i_cur, _)) in seen[3:]:
        widths = dp[i_cur, 1] - dp[i_cur, 0]
        assert np.all(widths <= 2 * margin + 2) and np.median(widths) < base_width / 2
    # without the warm-up the windows narrow from the first tracked frame
    tracker0 = StereoTracker(
        RIG,
        frames[0].pose,
        options=TrackerOptions(predicted_disparity=True, predicted_disparity_after=0),
    )
    tracker0.process(frames[0].left, frames[0].right)
    feats = tracker0.detect(frames[1].left)
    dp, _, predicted = tracker0.feature_disparities(
        feats, tracker0._pose_prev, _matches(tracker0, feats)
    )
    assert predicted is not None and len(np.unique(dp, axis=0)) > 1


def _matches(tracker, feats):
    """The search by projection of ``feats`` at the tracker's last pose, as ``process`` calls it."""
    from jaxpose.pipelines.stereo.guided import match_by_projection

    (i_m, i_cur, _), (l_m, l_cur, _) = match_by_projection(
        tracker.map,
        feats,
        tracker._pose_prev,
        tracker.rig.left,
        tracker._radius,
        use_lines=True,
        line_angle_deg=tracker.options.line_angle_deg,
        options=tracker.options.features,
    )
    return i_m, i_cur, l_m, l_cur
