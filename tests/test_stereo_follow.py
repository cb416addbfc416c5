"""Point landmarks followed by their patch where ORB does not match them (stereo `follow`)."""

import numpy as np
from test_stereo_anchor import _turned_plane_views

from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo.anchor import PatchAnchors
from jaxpose.pipelines.stereo.follow import follow
from jaxpose.pipelines.stereo.landmarks import LandmarkSet
from jaxpose.vision.stereo_features import FrameFeatures


def _scene(predicted_off_px=(1.6, -1.2)):
    """One landmark (id 7) on a textured plane turned 45 degrees from its reference view, seen
    after a 10 degree turn; its patch captured with the plane's normal; the pose predicted so
    that the landmark projects ``predicted_off_px`` from its true pixel."""
    cam, ref, cur, X, n, uv_ref, uv_cur, R_cur, t_cur = _turned_plane_views(45.0, 10.0)
    anchors = PatchAnchors(background=None)
    anchors.capture(ref, [7], uv_ref[None], np.eye(3), np.zeros(3), normals=n[None])
    # a shift of the predicted pose along x and y moves the projection by f dt / z
    z = (R_cur @ X + t_cur)[2]
    t_pred = t_cur + np.array([*predicted_off_px, 0.0]) * z / 800.0
    desc = np.full((1, 32), 9, np.uint8)
    points = LandmarkSet(X=X[None], desc=desc, n_obs=np.array([3]), ids=np.array([7], np.int64))
    return cam, cur, anchors, points, Pose(R_cur, t_pred), uv_cur


def _features(pixels):
    pixels = np.asarray(pixels, float).reshape(-1, 2)
    return FrameFeatures(
        points=pixels,
        point_desc=np.arange(len(pixels) * 32, dtype=np.uint8).reshape(-1, 32),
        segments=np.zeros((0, 2, 2)),
        line_desc=np.zeros((0, 32), np.uint8),
        point_response=np.ones(len(pixels), np.float32),
    )


def _follow(feats, cam, cur, anchors, points, pose, **kw):
    args = dict(search_px=3, duplicate_px=2.0, limit=100)
    args.update(kw)
    matches = args.pop("matches", (np.zeros(0, int), np.zeros(0, int)))
    followed = args.pop("followed", np.array([7]))
    visible = args.pop("visible", np.array([0]))
    return follow(anchors, points, cam, cur, feats, matches, followed, visible, pose, **args)


def test_a_landmark_without_a_keypoint_is_observed_at_its_true_pixel():
    """No keypoint near the landmark: one is added where its patch aligns, the landmark's own
    pixel to 0.05 px (ray-cast), from a prediction 2 px off, with the landmark's descriptor."""
    cam, cur, anchors, points, pose, uv = _scene()
    feats = _features([[20.0, 20.0], [600.0, 400.0]])
    out, i_m, i_cur = _follow(feats, cam, cur, anchors, points, pose)
    assert list(i_m) == [0] and list(i_cur) == [2]
    assert np.abs(out.points[2] - uv).max() < 0.05
    np.testing.assert_array_equal(out.point_desc[2], points.desc[0])
    np.testing.assert_array_equal(out.points[:2], feats.points)
    assert len(out.point_response) == 3


def test_an_unmatched_keypoint_at_the_aligned_pixel_becomes_the_landmark_s():
    """A keypoint 1 px from the landmark's pixel that ORB left unmatched is the landmark's: it
    moves to the aligned pixel and keeps its own descriptor; nothing is added."""
    cam, cur, anchors, points, pose, uv = _scene()
    feats = _features([[20.0, 20.0], uv + [0.7, -0.7]])
    out, i_m, i_cur = _follow(feats, cam, cur, anchors, points, pose)
    assert list(i_m) == [0] and list(i_cur) == [1]
    assert len(out.points) == 2 and np.abs(out.points[1] - uv).max() < 0.05
    np.testing.assert_array_equal(out.point_desc, feats.point_desc)
    # a keypoint ORB did match (to another landmark) is not taken
    out, i_m, i_cur = _follow(
        feats, cam, cur, anchors, points, pose, matches=(np.array([5]), np.array([1]))
    )
    assert list(i_m) == [5, 0] and list(i_cur) == [1, 2] and len(out.points) == 3


def test_only_unmatched_visible_followed_landmarks_are_followed_within_the_limit():
    cam, cur, anchors, points, pose, _ = _scene()
    feats = _features([[20.0, 20.0]])
    cases = [
        dict(followed=np.array([3])),  # not in the last solve
        dict(visible=np.zeros(0, int)),  # not predicted visible
        dict(matches=(np.array([0]), np.array([0]))),  # ORB matched it
        dict(limit=0),  # no room
    ]
    for case in cases:
        out, i_m, _ = _follow(feats, cam, cur, anchors, points, pose, **case)
        assert len(out.points) == 1 and len(i_m) == len(case.get("matches", [[]])[0])


def test_a_patch_that_does_not_align_adds_nothing():
    """Over noise the patch correlates nowhere: no keypoint is added."""
    cam, cur, anchors, points, pose, _ = _scene()
    noise = np.random.default_rng(1).uniform(0, 255, cur.shape).astype(np.float32)
    feats = _features([[20.0, 20.0]])
    out, i_m, i_cur = _follow(feats, cam, noise, anchors, points, pose)
    assert len(out.points) == 1 and len(i_m) == 0 and len(i_cur) == 0


def test_following_keeps_more_landmarks_in_each_frame_s_solve():
    """On a short rendered run at 3 m turning 3 degrees a frame, following keeps more point
    landmarks in the solves (the fit's inliers) than ORB's matches alone, and every frame is
    tracked to within 3 cm."""
    from jaxpose.core.status import Status
    from jaxpose.pipelines.stereo import StereoTracker, TrackerOptions
    from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence

    rig = default_rig(512, 384)
    scene = StereoScene(frames=6, size_m=1.0, range_m=3.0, rate_deg_s=30.0, frame_rate_hz=10.0)
    frames = list(render_sequence(scene, rig))
    inliers = {}
    for px in (0, 3):
        tracker = StereoTracker(rig, frames[0].pose, options=TrackerOptions(anchor_follow_px=px))
        results = [tracker.process(fr.left, fr.right) for fr in frames]
        for r, fr in zip(results, frames, strict=True):
            assert r.status == Status.OK
            assert np.linalg.norm(r.t - np.asarray(fr.pose.t)) < 0.03
        inliers[px] = sum(r.inliers for r in results[1:])
    assert inliers[3] > 1.1 * inliers[0], inliers


def test_a_followed_patch_needs_a_closer_correlation_than_a_matched_keypoint():
    """Sensor noise that leaves the patch's ZNCC between the anchors' 0.8 and
    ``FOLLOW_MIN_ZNCC``: the alignment from a detection keeps it, following does not."""
    cam, cur, anchors, points, pose, uv = _scene()
    rng = np.random.default_rng(3)
    noisy = cur + rng.normal(0.0, 20.0, cur.shape).astype(np.float32)
    R, t = np.asarray(pose.R), np.asarray(pose.t)
    _, ok = anchors.align(noisy, cam, np.array([7]), points.X, uv[None], R, t)
    assert ok[0]  # a keypoint ORB matched there would be aligned
    out, i_m, _ = _follow(_features([[20.0, 20.0]]), cam, noisy, anchors, points, pose)
    assert len(i_m) == 0 and len(out.points) == 1
    out, i_m, _ = _follow(_features([[20.0, 20.0]]), cam, cur, anchors, points, pose)
    assert len(i_m) == 1  # without the noise it is followed
