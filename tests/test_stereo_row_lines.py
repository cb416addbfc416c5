"""Segments along the rows get their depth from the keypoints beside them
(:mod:`jaxpose.pipelines.stereo.row_lines`). References: the disparity of a 3-D point on a
known plane, by intersecting its pixel's ray with the plane (closed form)."""

import numpy as np
import pytest

from jaxpose.pipelines.stereo.row_lines import row_segment_disparities

F, B, C = 1000.0, 0.3, np.array([512.0, 384.0])  # focal (px), baseline (m), principal point


def plane_disparity(pixels, normal, offset):
    """Disparity ``F B / Z`` of the points of plane ``normal . X = offset`` seen at ``pixels``
    (the ray ``Z (u - cx, v - cy, F) / F`` meets the plane at ``Z = F offset / (normal . r)``)."""
    r = np.concatenate([pixels - C, np.full((len(pixels), 1), F)], 1)
    Z = F * offset / (r @ normal)
    return F * B / Z


def keypoints(rng, lo, hi, n):
    return rng.uniform(lo, hi, size=(n, 2))


@pytest.mark.parametrize("noise", [0.0, 0.2])
def test_a_crease_gets_the_disparity_where_its_two_faces_meet(noise):
    rng = np.random.default_rng(1)
    # two faces of a box meeting along a crease through Xc, slanted in depth and across the rows
    n_top = np.array([0.25, -0.6, -0.8])  # tilted back above the crease
    n_bot = np.array([0.25, 0.5, -0.866])
    Xc = np.array([0.0, 0.05, 3.0])
    e = np.cross(n_top, n_bot)  # the crease's direction
    ends = np.array([Xc - 0.25 * e / np.linalg.norm(e), Xc + 0.25 * e / np.linalg.norm(e)])
    seg = (F * ends[:, :2] / ends[:, 2:] + C)[None]  # its image: within a few degrees of a row
    assert abs(np.diff(seg[0, :, 1])[0]) < 0.2 * abs(np.diff(seg[0, :, 0])[0])
    lo, hi = seg[0].min(0), seg[0].max(0)
    top = keypoints(rng, (lo[0], lo[1] - 30), (hi[0], lo[1] - 1), 40)
    bot = keypoints(rng, (lo[0], hi[1] + 1), (hi[0], hi[1] + 30), 40)
    d = np.concatenate(
        [plane_disparity(top, n_top, n_top @ Xc), plane_disparity(bot, n_bot, n_bot @ Xc)]
    )
    d += noise * rng.standard_normal(len(d))
    out, ok = row_segment_disparities(seg, np.concatenate([top, bot]), d)
    assert ok.all()
    want = F * B / ends[:, 2]  # the crease's endpoints
    tol = 0.01 if noise == 0 else 0.2
    assert np.allclose(out[0], want, atol=tol)


def test_an_edge_against_the_sky_takes_the_one_side_it_has():
    rng = np.random.default_rng(2)
    n = np.array([0.1, -0.2, -1.0])
    below = keypoints(rng, (300, 301), (500, 330), 30)
    d = plane_disparity(below, n, n @ np.array([0.0, 0.0, 4.0]))
    seg = np.array([[[310.0, 300.0], [490.0, 297.0]]])
    out, ok = row_segment_disparities(seg, below, d)
    assert ok.all()
    want = plane_disparity(seg[0], n, n @ np.array([0.0, 0.0, 4.0]))
    assert np.allclose(out[0], want, atol=0.01)


def test_one_part_in_front_of_another_gives_no_depth():
    rng = np.random.default_rng(3)
    facing = np.array([0.0, 0.0, -1.0])  # fronto-parallel: Z = 2 m above, 4 m below
    above = keypoints(rng, (300, 270), (500, 299), 30)
    below = keypoints(rng, (300, 301), (500, 330), 30)
    d = np.concatenate([plane_disparity(above, facing, -2.0), plane_disparity(below, facing, -4.0)])
    # 150 px above, 75 px below: the boundary belongs to one of them, which is not known
    seg = np.array([[[310.0, 300.0], [490.0, 300.0]]])
    _, ok = row_segment_disparities(seg, np.concatenate([above, below]), d)
    assert not ok.any()


def test_too_few_or_bunched_keypoints_give_no_depth():
    rng = np.random.default_rng(4)
    n = np.array([0.0, 0.0, -1.0])
    few = keypoints(rng, (300, 301), (500, 320), 3)
    seg = np.array([[[300.0, 300.0], [500.0, 300.0]]])
    _, ok = row_segment_disparities(seg, few, plane_disparity(few, n, -3.0))
    assert not ok.any()
    bunched = keypoints(rng, (300, 301), (330, 320), 30)  # all near one end of the segment
    _, ok = row_segment_disparities(seg, bunched, plane_disparity(bunched, n, -3.0))
    assert not ok.any()
    out, ok = row_segment_disparities(np.zeros((0, 2, 2)), bunched, np.ones(30))
    assert out.shape == (0, 2) and ok.shape == (0,)


def test_a_row_lines_depth_plane_fixes_the_line_its_two_image_planes_cannot():
    """A segment along the rows: its left and right observation planes coincide (the baseline
    lies in both), so they leave a landmark line placed at a wrong depth where it is; the plane
    across the line of sight that carries the keypoints' depth moves it onto the true line."""
    import jax.numpy as jnp

    from jaxpose.core.geometry import Pose
    from jaxpose.pipelines.stereo.keyframes import observe_line_planes
    from jaxpose.pipelines.stereo.landmarks import LandmarkMap
    from jaxpose.vision.stereo_render import default_rig

    rig = default_rig()
    pose = Pose(jnp.eye(3), jnp.zeros(3))
    S = np.array([[[-0.3, 0.1, 3.0], [0.3, 0.1, 3.2]]])  # along the rows, slanted in depth
    placed = S * 1.02  # on the same rays, 2% too far
    for right, moves in ((None, False), (np.array([False]), True)):
        m = LandmarkMap()
        idx = m.add("lines", placed, np.zeros((1, 32), np.uint8), pose, 0)
        observe_line_planes(m, rig, idx, S, pose, right=right)
        X = m.lines.X[0]
        # distance of the landmark's endpoints from the true line
        d = S[0, 1] - S[0, 0]
        off = X - S[0, 0]
        dist = np.linalg.norm(off - np.outer(off @ d / (d @ d), d), axis=1)
        if moves:
            assert dist.max() < 1e-9
        else:
            assert dist.min() > 0.05  # the coinciding planes do not meet: left as placed


def test_the_tracker_maps_segments_along_the_rows_onto_the_target():
    """``row_lines``: a rendered sequence tracks, its map holds line landmarks along the image
    rows that no stereo match made, and they lie on the model's faces (independent reference:
    the model's geometry)."""
    from jaxpose.core.status import Status
    from jaxpose.pipelines.stereo import StereoTracker, TrackerOptions
    from jaxpose.pipelines.stereo._arrays import project
    from jaxpose.vision.stereo_render import (
        StereoScene,
        default_rig,
        render_sequence,
        tumbler_model,
    )

    rig = default_rig()
    frames = list(render_sequence(StereoScene(frames=4), rig))
    tracker = StereoTracker(rig, frames[0].pose, options=TrackerOptions(row_lines=True))
    for fr in frames:
        res = tracker.process(fr.left, fr.right)
        assert res.status == Status.OK
        R, t = np.asarray(fr.pose.R), np.asarray(fr.pose.t)
        assert np.degrees(np.arccos(np.clip((np.trace(res.R @ R.T) - 1) / 2, -1, 1))) < 1.0
        assert np.linalg.norm(res.t - t) < 0.02
    X = tracker.map.lines.X
    uv = np.asarray(project(rig.left, frames[-1].pose, X))
    d = uv[:, 1] - uv[:, 0]
    rows = np.abs(d[:, 1]) < np.sin(np.radians(10)) * np.linalg.norm(d, axis=1)
    assert rows.sum() >= 3
    half = np.abs(tumbler_model().vertices[:8]).max(0)
    Xr = X[rows].reshape(-1, 3)
    on_body = np.all(np.abs(Xr) < half + 0.01, axis=1)
    assert on_body.mean() > 0.7
    assert np.median(np.min(np.abs(np.abs(Xr[on_body]) - half), axis=1)) < 0.005


def test_wrong_shapes_are_named():
    seg = np.zeros((1, 2, 2))
    with pytest.raises(ValueError, match="segments must be"):
        row_segment_disparities(np.zeros((1, 4)), np.zeros((3, 2)), np.zeros(3))
    with pytest.raises(ValueError, match="disparities"):
        row_segment_disparities(seg, np.zeros((3, 2)), np.zeros(4))


def test_steep_segments_follow_the_angle_to_the_rows():
    from jaxpose.vision.stereo_match import steep_segments

    ang = np.radians([0.0, 5.0, 11.9, 12.1, 45.0, 90.0, 170.0])
    seg = np.stack([np.zeros((len(ang), 2)), 50 * np.c_[np.cos(ang), np.sin(ang)]], 1)
    assert steep_segments(seg, 12.0).tolist() == [False, False, False, True, True, True, False]
    with pytest.raises(ValueError, match="segments must be"):
        steep_segments(np.zeros((3, 4)), 12.0)
