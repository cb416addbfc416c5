"""Image-processing steps one by one: undistortion, WGE, ROI, coarse position, Hough, LSD, merging,
synthesis, and the chained detector on a rendered image."""

from dataclasses import replace

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import PinholeCamera, Pose
from jaxpose.core.geometry import euler_to_dcm
from jaxpose.vision.coarse import coarse_position
from jaxpose.vision.features import (
    DetectionOptions,
    detect,
    lsd_cluster_box,
    segment_support,
    texture_families,
    to_gray,
)
from jaxpose.vision.lsd import lsd_segments
from jaxpose.vision.merge import merge_streams, merge_truncated, remove_duplicates
from jaxpose.vision.models import tango
from jaxpose.vision.render import project_points, render
from jaxpose.vision.roi import roi_diagonal, roi_from_gradient, roi_from_silhouette
from jaxpose.vision.synthesis import synthesize
from jaxpose.vision.undistort import undistort_image
from jaxpose.vision.wge import prewitt_magnitude, weak_gradient_elimination


@pytest.fixture
def camera():
    return PinholeCamera(
        1000.0, 1000.0, 399.5, 299.5, [-0.15, 0.05, 0.0, 0.0, 0.0], width=800, height=600
    )


def oblique_pose(z=6.0):
    R = np.asarray(euler_to_dcm(jnp.array([2.4, 0.3, 0.5])))
    return Pose(R, np.array([0.1, -0.05, z]))


def test_undistort_straightens_lines(camera):
    # A rendered image undistorted must show the ideal projection of the corners.
    r = render(tango(), oblique_pose(), camera, rng=0, noise_sigma=0.0, blur_sigma_px=0.0)
    und, ideal = undistort_image(r.image, camera)
    assert not ideal.has_distortion() and und.shape == r.image.shape
    pts = np.asarray(oblique_pose().apply(jnp.asarray(tango().vertices[:8])))
    uv = project_points(ideal, pts)
    # The target pixels of the undistorted image sit where the ideal camera projects them.
    mask = und > 20
    inside = [
        mask[int(round(v)), int(round(u))]
        or mask[max(int(v) - 2, 0) : int(v) + 3, max(int(u) - 2, 0) : int(u) + 3].any()
        for u, v in uv
    ]
    assert np.mean(inside) >= 0.75
    same, _ = undistort_image(r.image, camera.without_distortion())
    assert same is r.image


def test_prewitt_and_wge_thresholds():
    img = np.zeros((64, 64), np.uint8)
    img[:, 32:] = 200
    G = prewitt_magnitude(img)
    assert G[10, 31] == pytest.approx(600.0) and G[10, 5] == 0.0
    res = weak_gradient_elimination(img)
    assert np.all(res.filtered[:, 30:34].max(1) > 0) and res.filtered[:, :28].max() == 0
    black = weak_gradient_elimination(np.zeros((32, 32), np.uint8))
    assert black.filtered.max() == 0 and roi_from_gradient(black.filtered) is None


def test_wge_cdf_matches_exponential_fit(rng):
    g = rng.exponential(0.05, size=(200, 200)).astype(np.float32)
    res = weak_gradient_elimination(None, magnitude=g)
    kept = (res.filtered > 0).mean()
    # The fitted CDF reaches 0.99 near the 0.99 quantile; whole bins are kept.
    assert 0.003 < kept < 0.03


def test_roi_quantiles():
    F = np.zeros((100, 200))
    F[20:60, 50:150] = 1.0
    u0, v0, u1, v1 = roi_from_gradient(F)
    assert u0 == pytest.approx(52, abs=1) and u1 == pytest.approx(147, abs=1)
    assert v0 == pytest.approx(21, abs=1) and v1 == pytest.approx(58, abs=1)
    assert roi_diagonal([0, 0, 3, 4]) == 5.0


def _dark_scene(rng, level=30.0, noise=4.0):
    return level + noise * rng.standard_normal((600, 800))


def test_roi_silhouette_includes_faint_faces(rng):
    img = _dark_scene(rng)
    img[300:400, 200:300] = 200.0  # the lit face
    img[300:400, 300:420] += 6.0  # a face in shadow: 6 grey levels over the background
    img[250:300, 200:420] -= 8.0  # a black panel hiding a faint background glow
    box = roi_from_silhouette(np.clip(img, 0, 255).astype(np.uint8))
    f = 600 // 150  # the shrink factor
    np.testing.assert_allclose(box, [200, 250, 420, 400], atol=2 * f)
    # The gradient ROI of the same image sees the lit face's edges only.
    gy, gx = np.gradient(img)
    g = np.hypot(gx, gy)
    assert roi_diagonal(roi_from_gradient(np.where(g > 60, g, 0))) < 0.75 * roi_diagonal(box)


def ndimage_blur(x, sigma):
    import cv2

    return cv2.GaussianBlur(x, (0, 0), sigma)


def _cloudy_cap(rng, shape, centre, radius, level=30.0):
    """Sky at ``level`` and an Earth cap (a disc crossing the frame) of bright, sharp-edged,
    fragmented clouds over a ground a few levels above the sky; the cap mask."""
    H, W = shape
    vv, uu = np.mgrid[:H, :W]
    cap = (uu - centre[0]) ** 2 + (vv - centre[1]) ** 2 < radius**2
    field = ndimage_blur(rng.standard_normal((H, W)), 6.0)
    clouds = np.clip((field / field.std() - 0.3) * 150.0, 0.0, 200.0)  # about 40% cloud cover
    return np.where(cap, level + 10.0 + clouds, level), cap


def test_roi_silhouette_beside_an_earth_in_a_corner(rng):
    # A small, faint target against a dark sky, clouds in a corner (SPEED+ lightbox image 3):
    # the components touching two sides and their hull are the Earth, the target is the rest.
    img, cap = _cloudy_cap(rng, (600, 800), (900.0, 800.0), 600.0)
    assert cap.mean() > 0.25
    img[100:160, 100:180] += 25.0  # the target, far from the Earth
    img[160:200, 140:150] += 15.0  # a fainter antenna below it
    img += 6.0 * rng.standard_normal(img.shape)  # strong sensor noise as in the photographs
    box = roi_from_silhouette(np.clip(img, 0, 255).astype(np.uint8))
    f = 600 // 150
    np.testing.assert_allclose(box, [100, 100, 180, 200], atol=2 * f)
    # The same with the clouds bright enough that the image's overall spread says "texture":
    # the sky level is then the histogram mode, its noise the spread of the darker pixels.
    big, _ = _cloudy_cap(rng, (600, 800), (1000.0, 900.0), 800.0)
    big[100:160, 100:180] += 25.0
    big += 6.0 * rng.standard_normal(big.shape)
    box = roi_from_silhouette(np.clip(big, 0, 255).astype(np.uint8))
    np.testing.assert_allclose(box, [100, 100, 180, 160], atol=2 * f)


def test_roi_silhouette_prefers_the_sharp_target_to_a_soft_earth_piece(rng):
    # A dim Earth whose limb crosses the top: the threshold keeps a large soft-edged piece of it
    # touching one side, larger than the small lit target with sharp edges.
    img = _dark_scene(rng)
    vv, uu = np.mgrid[:600, :800]
    piece = ((uu - 250.0) / 200.0) ** 2 + ((vv + 40.0) / 190.0) ** 2 < 1.0
    img += ndimage_blur(piece * 40.0, 12.0)  # soft edges
    img[380:440, 560:640] = 220.0  # the target
    img = np.clip(img, 0, 255).astype(np.uint8)
    # the strong gradients: the 1% largest central-difference magnitudes (independent of WGE)
    gy, gx = np.gradient(img.astype(float))
    g = np.hypot(gx, gy)
    strong = np.where(g > np.percentile(g, 99), g, 0.0)
    f = 600 // 150
    by_area = roi_from_silhouette(img)
    assert by_area is not None and by_area[1] == 0  # the Earth piece, cut by the top side
    box = roi_from_silhouette(img, gradient=strong)
    np.testing.assert_allclose(box, [560, 380, 640, 440], atol=2 * f)
    with pytest.raises(ValueError, match="gradient"):
        roi_from_silhouette(img, gradient=strong[:-1])


def _target_over_clouds(rng, blur):
    """A dark man-made target (a tilted face and a lit side) in front of sharp-edged clouds
    filling the image (SPEED+ lightbox image 6); its box by construction."""
    import cv2

    field = ndimage_blur(rng.standard_normal((600, 800)), blur)
    img = 70.0 + np.clip((field / field.std() - 0.3) * 150.0, 0.0, 180.0)
    body = np.array([[300, 200], [480, 170], [520, 330], [340, 370]], np.int32)
    side = np.array([[480, 170], [540, 190], [575, 340], [520, 330]], np.int32)
    cv2.fillPoly(img, [body], 15.0)
    cv2.fillPoly(img, [side], 110.0)
    img = np.clip(img + 3.0 * rng.standard_normal(img.shape), 0, 255).astype(np.uint8)
    return img, [300, 170, 575, 370]


def test_lsd_cluster_box_over_a_full_earth():
    # Small clouds: the target's straight edges meeting at corners are the largest cluster of
    # LSD segments (a scene drawn with 10 seeds: a rare cloud edge may still join the target).
    ratios = []
    for seed in range(10):
        img, truth = _target_over_clouds(np.random.default_rng(seed), 6.0)
        box = lsd_cluster_box(img)
        ratios.append(np.inf if box is None else roi_diagonal(box) / roi_diagonal(truth))
    assert sum(abs(r - 1) < 0.2 for r in ratios) >= 8, ratios
    # Large smooth clouds: their curved edges, cut by LSD into polylines, form big clusters
    # with "corners", but none spanned by a long straight edge: no box rather than a wrong one.
    for seed in range(3):
        img, truth = _target_over_clouds(np.random.default_rng(seed), 16.0)
        box = lsd_cluster_box(img)
        assert box is None or roi_diagonal(box) < 1.3 * roi_diagonal(truth)
    assert lsd_cluster_box(np.full((600, 800), 40, np.uint8)) is None  # no edges
    assert lsd_cluster_box(np.zeros((20, 20), np.uint8)) is None  # too small


def test_roi_silhouette_declines_without_a_clean_dark_background(rng):
    img = _dark_scene(rng)
    vv, uu = np.mgrid[:600, :800]
    img[(uu - 900.0) ** 2 + (vv - 800.0) ** 2 < 600.0**2] = 150.0  # an Earth disc in a corner
    img[380:460, 380:470] = 200.0  # a target in front of the Earth's edge: one component
    assert (
        (uu[380:460, 380:470] - 900.0) ** 2 + (vv[380:460, 380:470] - 800.0) ** 2
    ).min() < 600.0**2
    assert roi_from_silhouette(np.clip(img, 0, 255).astype(np.uint8)) is None
    # Clouds over the whole image (no flat sky, the Earth fills the frame): no silhouette.
    full, _ = _cloudy_cap(rng, (600, 800), (400.0, 300.0), 2000.0)
    full[250:350, 300:450] = 15.0  # a dark target in front of it (SPEED+ lightbox image 6)
    assert roi_from_silhouette(np.clip(full, 0, 255).astype(np.uint8)) is None
    clouds = 60.0 + 400.0 * ndimage_blur(rng.standard_normal((600, 800)), 12.0)
    clouds[250:350, 300:450] = 200.0  # the target
    clouds[330:450, 430:600] = 150.0  # a bright cloud touching it: its silhouette would merge
    assert roi_from_silhouette(np.clip(clouds, 0, 255).astype(np.uint8)) is None
    assert roi_from_silhouette(np.zeros((600, 800), np.uint8)) is None
    assert roi_from_silhouette(np.full((600, 800), 255, np.uint8)) is None
    with pytest.raises(ValueError, match="grayscale"):
        roi_from_silhouette(np.zeros((60, 80, 3), np.uint8))


def test_coarse_position_eqs_6_to_9(camera):
    ideal = camera.without_distortion()
    roi = np.array([399.5 - 50, 299.5 - 50, 399.5 + 50, 299.5 + 50])
    t = coarse_position(roi, ideal, 1.0)
    np.testing.assert_allclose(t, [0, 0, 1000.0 / np.hypot(100, 100)], atol=1e-9)
    t = coarse_position(roi + [200, 0, 200, 0], ideal, 1.0)
    assert t[0] > 0 and t[1] == pytest.approx(0.0)  # right of centre -> +x (OpenCV)
    with pytest.raises(ValueError):
        coarse_position([5, 5, 5, 5], ideal, 1.0)


def test_merge_truncated_and_duplicates():
    a = np.array([[0.0, 0.0], [40.0, 0.0]])
    b = np.array([[45.0, 0.5], [90.0, 0.5]])
    c = np.array([[0.0, 30.0], [90.0, 30.0]])
    out = merge_truncated(np.stack([a, b, c]))
    assert len(out) == 2
    longest = out[np.argmax(np.linalg.norm(out[:, 1] - out[:, 0], axis=1))]
    assert np.linalg.norm(longest[1] - longest[0]) == pytest.approx(90.0, abs=0.1)
    keep = remove_duplicates(np.stack([c, c + [1.0, 1.0], c * [0.5, 1]]))
    assert len(keep) == 1
    # Streams: a short WGE segment crossing a long Sobel one in its middle is dropped.
    sob = np.array([[[0.0, 50.0], [100.0, 50.0]]])
    wge = np.array([[[50.0, 40.0], [50.0, 60.0]], [[0.0, 0.0], [0.0, 20.0]]])
    segs, from_wge = merge_streams(wge, sob)
    assert len(segs) == 2 and from_wge.sum() == 1


def test_synthesis_of_a_square_and_a_u():
    sq = np.array(
        [[[0, 0], [100, 0]], [[100, 0], [100, 100]], [[100, 100], [0, 100]], [[0, 100], [0, 0]]],
        float,
    )
    g = synthesize(sq, d_max=5.0)
    assert g.count("closed_tetrad") == 1 and g.most_complex() == "closed_tetrad"
    assert g.count("parallel_pair") == 2 and g.count("proximal_pair") == 4
    corners = {tuple(np.round(p).astype(int)) for p in g.points["closed_tetrad"][0]}
    assert corners == {(0, 0), (100, 0), (100, 100), (0, 100)}
    # A "Z" (far ends on opposite sides) is not an open triad (eq. 16); a "U" is.
    z = np.array([[[0, 0], [0, 50]], [[0, 50], [100, 50]], [[100, 50], [100, 100]]], float)
    u = np.array([[[0, 0], [0, 50]], [[0, 50], [100, 50]], [[100, 50], [100, 0]]], float)
    assert synthesize(z, d_max=3.0).count("open_triad") == 0
    assert synthesize(u, d_max=3.0).count("open_triad") == 1
    assert synthesize(np.zeros((0, 2, 2)), d_max=1.0).most_complex() is None


def test_corner_test_for_proximal_pairs():
    # l_ROI = 100, so d_max = 0.04 l_ROI = 4. Two edges of a 60-degree corner at (10, 20), each
    # stopping 8 short of it (8% of their length 100): the endpoint gap is 8 (an equilateral
    # triangle with the corner), 0.08 l_ROI, too far for the endpoint test.
    c = np.array([10.0, 20.0])
    ua, ub = np.array([1.0, 0.0]), np.array([0.5, np.sqrt(3.0) / 2.0])
    pair = np.array([[c + 8 * ua, c + 108 * ua], [c + 8 * ub, c + 108 * ub]])
    assert np.isclose(np.linalg.norm(pair[0, 0] - pair[1, 0]), 8.0)
    assert synthesize(pair, d_max=4.0).count("proximal_pair") == 0  # the old rule alone
    g = synthesize(pair, d_max=4.0, corner_frac=0.1)
    assert g.count("proximal_pair") == 1
    far_a, corner, far_b = g.points["proximal_pair"][0]
    np.testing.assert_allclose(corner, [10.0, 20.0], atol=1e-9)
    np.testing.assert_allclose(far_a, [118.0, 20.0], atol=1e-9)
    np.testing.assert_allclose(far_b, [10.0 + 54.0, 20.0 + 54.0 * np.sqrt(3.0)], atol=1e-9)
    # Too narrow an angle: lines 10 degrees apart meeting at the same kind of gap.
    un = np.array([np.cos(np.deg2rad(10.0)), np.sin(np.deg2rad(10.0))])
    narrow = np.array([[c - 8 * ua, c - 108 * ua], [c + 8 * un, c + 108 * un]])
    assert synthesize(narrow, d_max=4.0, corner_frac=0.1).count("proximal_pair") == 0
    assert (
        synthesize(narrow, d_max=4.0, corner_frac=0.1, corner_min_angle_deg=5.0).count(
            "proximal_pair"
        )
        == 1
    )
    # Far apart: the lines meet at (300, 0), 2 lengths beyond the first segment's end.
    far = np.array([[[0.0, 0.0], [100.0, 0.0]], [[300.0, 50.0], [300.0, 150.0]]])
    assert synthesize(far, d_max=4.0, corner_frac=0.25).count("proximal_pair") == 0
    # Within 0.1 of the first segment's length but half the second's: each segment's own share.
    one_sided = np.array([[[0.0, 0.0], [100.0, 0.0]], [[110.0, 50.0], [110.0, 150.0]]])
    assert synthesize(one_sided, d_max=4.0, corner_frac=0.25).count("proximal_pair") == 0
    assert synthesize(one_sided, d_max=4.0, corner_frac=0.6).count("proximal_pair") == 1
    # A square whose sides all stop 8 short of the corners closes a tetrad at the true corners.
    sq = np.array(
        [[[8, 0], [92, 0]], [[100, 8], [100, 92]], [[92, 100], [8, 100]], [[0, 92], [0, 8]]],
        float,
    )
    assert synthesize(sq, d_max=4.0).count("closed_tetrad") == 0
    g = synthesize(sq, d_max=4.0, corner_frac=0.1)
    assert g.count("closed_tetrad") == 1
    corners = {tuple(np.round(p, 9)) for p in g.points["closed_tetrad"][0]}
    assert corners == {(0, 0), (100, 0), (100, 100), (0, 100)}
    with pytest.raises(ValueError):
        synthesize(sq, d_max=4.0, corner_frac=-0.1)


def test_detect_on_a_rendering(camera):
    m = tango()
    pose = oblique_pose()
    r = render(m, pose, camera, rng=3)
    for detector in ("hough", "lsd"):
        det = detect(r.image, camera, m.characteristic_length, DetectionOptions(detector=detector))
        assert det.roi is not None and len(det.segments) >= 4
        # ROI inside the true box grown by 10%; coarse range within 35%.
        grow = 0.1 * roi_diagonal(r.roi)
        assert det.roi[0] >= r.roi[0] - grow and det.roi[2] <= r.roi[2] + grow
        rng_true = float(np.linalg.norm(np.asarray(pose.t)))
        assert abs(np.linalg.norm(det.coarse_t_cam) / rng_true - 1) < 0.35
        assert det.groups.most_complex() is not None


def test_segment_support_on_a_drawn_square():
    # A bright square (OpenCV-drawn) on a noisy dark background: a segment on its side is fully
    # supported, one through the background not at all, one that leaves the side halfway (the
    # supported half is known from the geometry: the side ends at x = 300) about half.
    img = np.full((400, 400), 30, np.uint8)
    cv2.rectangle(img, (100, 100), (300, 300), 200, -1)
    noise = np.random.default_rng(0).normal(0.0, 4.0, img.shape)
    img = np.clip(img + noise, 0, 255).astype(np.uint8)
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    segs = np.array(
        [
            [[110.0, 100.0], [290.0, 100.0]],  # on the top side
            [[20.0, 350.0], [380.0, 360.0]],  # background below the square
            [[140.0, 300.0], [460.0, 300.0]],  # bottom side, x 140-300 of 140-460: 0.5 on it
            [[200.0, 150.0], [200.0, 250.0]],  # inside the flat square
        ]
    )
    s = segment_support(img, segs, [90, 90, 310, 310])
    assert s[0] == pytest.approx(1.0)
    assert s[1] <= 0.05 and s[3] <= 0.05
    # samples at 5-95% of the segment: 0.05 + 0.9 t = 0.5 -> a share of 0.5 of the samples
    assert s[2] == pytest.approx(0.5, abs=0.07)
    assert segment_support(img, np.zeros((0, 2, 2)), [0, 0, 10, 10]).shape == (0,)
    with pytest.raises(ValueError, match="image must be"):
        segment_support(img[..., None], segs, [0, 0, 10, 10])


def test_texture_families_keep_the_outermost_members():
    # A cell grid drawn by hand: 8 lines 12 px apart (the 5th missing), rotated by 30 deg, with
    # a little jitter; its first and last lines are the panel's sides. A box's three parallel
    # edges (steps 40 and 95 px) and a lone segment are no family.
    rng = np.random.default_rng(1)
    c, s_ = np.cos(np.radians(30)), np.sin(np.radians(30))
    rot = np.array([[c, -s_], [s_, c]])
    grid = [
        [[0.0, 12.0 * k + rng.normal(0, 0.3)], [150.0 + rng.normal(0, 3), 12.0 * k]]
        for k in range(8)
        if k != 4
    ]
    grid = np.array(grid) @ rot.T + [300.0, 100.0]
    box = np.array([[[0, 400], [200, 400]], [[0, 440], [200, 441]], [[0, 535], [200, 535]]], float)
    lone = np.array([[[500.0, 50.0], [520.0, 300.0]]])
    segs = np.concatenate([grid, box, lone])
    inner = texture_families(segs)
    expected = np.zeros(len(segs), bool)
    expected[1:6] = True  # grid lines 1, 2, 3, 5, 6 (of 0-7, 4 missing); 0 and 7 stay
    np.testing.assert_array_equal(inner, expected)
    # evenly spaced but staggered along their direction (no overlap): not one face's texture
    staggered = np.array([[[100.0 * k, 10.0 * k], [100.0 * k + 60, 10.0 * k]] for k in range(6)])
    assert not texture_families(staggered).any()
    # with min_members=6 the 7-line grid is still a family, with 8 it is not
    assert texture_families(grid, min_members=6)[1:6].all()
    assert not texture_families(grid, min_members=8).any()
    with pytest.raises(ValueError, match="min_members"):
        texture_families(segs, min_members=2)


def test_detect_min_support_keeps_supported_segments(camera):
    m = tango()
    r = render(m, oblique_pose(), camera, rng=3)
    opts = DetectionOptions(min_support=0.3, max_segments=1000)
    det = detect(r.image, camera, m.characteristic_length, opts)
    raw = detect(r.image, camera, m.characteristic_length, replace(opts, min_support=0.0))
    assert 4 <= len(det.segments) <= len(raw.segments)
    assert (segment_support(det.image, det.segments, det.roi) >= 0.3).all()


def test_detect_bad_images(camera):
    m = tango()
    black = detect(np.zeros((600, 800), np.uint8), camera, 1.0)
    assert black.roi is None and black.groups is None
    sat = detect(np.full((600, 800), 255, np.uint8), camera, 1.0)
    assert sat.roi is None
    noise = detect(
        np.random.default_rng(0).integers(0, 255, (600, 800)).astype(np.uint8),
        camera,
        m.characteristic_length,
    )
    assert noise.roi_silhouette is None  # uniform noise has no silhouette
    with pytest.raises(ValueError, match="too small"):
        detect(np.zeros((8, 8), np.uint8), camera, 1.0)
    with pytest.raises(ValueError, match="image must be"):
        to_gray(np.zeros((4, 4, 4, 4)))
    assert lsd_segments(np.zeros((50, 50), np.uint8)).shape[1:] == (2, 2)


@pytest.mark.parametrize(
    "bad", [dict(min_support=float("nan")), dict(min_support=-0.1), dict(min_support=1.5)]
)
def test_detect_rejects_bad_min_support(camera, bad):
    with pytest.raises(ValueError, match="min_support"):
        detect(np.zeros((64, 64), np.uint8), camera, 1.0, DetectionOptions(**bad))


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
@pytest.mark.parametrize("family", [1, 2, 4.5, -3])
def test_detect_rejects_bad_texture_family(camera, family):
    with pytest.raises(ValueError, match="texture_family"):
        detect(np.zeros((64, 64), np.uint8), camera, 1.0, DetectionOptions(texture_family=family))
