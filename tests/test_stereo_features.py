"""Stereo tracker features: LSD segments on drawn edges at every detection scale, and the
ratio-test matching over candidate pairs against a brute-force reference."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from jaxpose.vision.stereo_features import FeatureOptions, detect_lines, knn_ratio_match_pairs

H = W = 320
#: a convex quadrilateral, pixel-centre coordinates (pixel (0, 0) covers [-0.5, 0.5]^2)
QUAD = np.array([[62.3, 71.7], [251.6, 58.2], [268.9, 247.4], [80.2, 262.8]])


@pytest.fixture(scope="module")
def quad_image():
    """The quadrilateral (200) on a dark background (20), each pixel the area average of 8 x 8
    sub-samples; and the four edge lines ``(n, c)``, ``n . x + c = 0``, ``|n| = 1``."""
    s = 8
    sub = (np.arange(W * s) + 0.5) / s - 0.5
    x, y = np.meshgrid(sub, sub)
    inside = np.ones_like(x, bool)
    edges = []
    for i in range(4):
        a, b = QUAD[i], QUAD[(i + 1) % 4]
        n = np.array([b[1] - a[1], a[0] - b[0]]) / np.linalg.norm(b - a)
        inside &= x * n[0] + y * n[1] - n @ a <= 0
        edges.append((n, -n @ a))
    img = 20.0 + 180.0 * inside.reshape(H, s, W, s).mean((1, 3))
    return np.round(img).astype(np.uint8), edges


@pytest.mark.parametrize("scale", [1.0, 0.8, 0.5])
def test_lsd_segments_lie_on_the_edges_at_every_scale(quad_image, scale):
    """LSD maps its segments back from the resampled image without the half-pixel term; the
    segments returned lie on the true edges (the shift 0.5 / s - 0.5 would be 0.125 px at 0.8,
    0.5 px at 0.5)."""
    img, edges = quad_image
    seg, desc = detect_lines(img, options=FeatureOptions(mu=0.1, lsd_scale=scale))
    assert len(seg) == 4 and desc.shape == (4, 32)
    for s in seg:
        for p in (s.mean(0), 0.75 * s[0] + 0.25 * s[1], 0.25 * s[0] + 0.75 * s[1]):
            d = [abs(n @ p + c) for n, c in edges]
            assert min(d) < 0.05, (scale, min(d))
    with pytest.raises(ValueError, match="lsd_scale"):
        FeatureOptions(lsd_scale=0.0)


def _brute_force(desc_ref, desc_cur, i_ref, i_cur, ratio, max_distance):
    bits = np.unpackbits(desc_ref[:, None] ^ desc_cur[None], axis=-1).sum(-1)
    pairs = []
    for r in np.unique(i_ref):
        cand = i_cur[i_ref == r]
        d = bits[r, cand]
        j = int(np.argmin(d))  # the first of equal distances, in the given order
        second = np.sort(d)[1] if len(d) > 1 else np.inf
        if d[j] <= max_distance and d[j] < ratio * second:
            pairs.append((r, cand[j]))
    pairs = np.array(pairs, int).reshape(-1, 2)
    once = [c for c in pairs[:, 1] if (pairs[:, 1] == c).sum() == 1]
    keep = np.isin(pairs[:, 1], once)
    return pairs[keep, 0], pairs[keep, 1]


def test_knn_ratio_match_pairs_equals_brute_force():
    rng = np.random.default_rng(3)
    # near-copies of a few descriptors: ties and close second-best distances
    base = rng.integers(0, 256, (30, 32), dtype=np.uint8)
    desc_ref = base[rng.integers(0, 30, 80)] ^ (rng.random((80, 32)) < 0.03).astype(np.uint8)
    desc_cur = base[rng.integers(0, 30, 90)] ^ (rng.random((90, 32)) < 0.03).astype(np.uint8)
    i_ref = rng.integers(0, 80, 700)
    i_cur = rng.integers(0, 90, 700)
    for ratio, max_distance in ((0.8, 64), (1.0, 256), (0.5, 20)):
        got = knn_ratio_match_pairs(
            desc_ref, desc_cur, i_ref, i_cur, ratio=ratio, max_distance=max_distance
        )
        want = _brute_force(desc_ref, desc_cur, i_ref, i_cur, ratio, max_distance)
        assert len(want[0]) > 3
        np.testing.assert_array_equal(np.sort(got[0]), np.sort(want[0]))
        order_got, order_want = np.argsort(got[0]), np.argsort(want[0])
        np.testing.assert_array_equal(got[1][order_got], want[1][order_want])


def test_one_orb_level_gives_the_full_resolution_fast_corners():
    """With one pyramid level and no sub-pixel refinement every keypoint is a FAST corner of the
    full-resolution image (whole-pixel coordinates); with eight, the coarser levels' corners
    come back scaled by powers of 1.2 (not whole pixels); cornerSubPix moves them off the grid."""
    from jaxpose.vision.stereo_features import detect_points

    rng = np.random.default_rng(0)
    blocks = (rng.random((24, 32)) > 0.5).astype(np.uint8) * 200 + 20
    img = cv2.resize(blocks, (320, 240), interpolation=cv2.INTER_NEAREST)
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    one, _ = detect_points(img, options=FeatureOptions(orb_levels=1, subpixel=False))
    eight, _ = detect_points(img, options=FeatureOptions(orb_levels=8, subpixel=False))
    refined, _ = detect_points(img, options=FeatureOptions(orb_levels=1))
    assert len(one) > 50 and len(eight) > len(one)
    np.testing.assert_array_equal(one, np.round(one))
    assert np.any(np.abs(eight - np.round(eight)) > 0.05)
    assert np.any(np.abs(refined - np.round(refined)) > 0.05)
    for bad in (0, 17):
        with pytest.raises(ValueError, match="orb_levels"):
            FeatureOptions(orb_levels=bad)


def _brute_force_twins(desc_ref, desc_cur, i_ref, i_cur, ratio, max_distance, p_ref, p_cur, r_px):
    """The ratio test without the best candidate's twins as rivals, then one current feature to
    the nearest (Hamming) of claimants that lie within ``r_px`` of it, by plain loops."""
    bits = np.unpackbits(desc_ref[:, None] ^ desc_cur[None], axis=-1).sum(-1)
    claims = {}
    for r in np.unique(i_ref):
        cand = i_cur[i_ref == r]
        d = bits[r, cand]
        j = int(np.argmin(d))
        rival = np.linalg.norm(p_cur[cand] - p_cur[cand[j]], axis=1) > r_px
        second = d[rival].min() if rival.any() else np.inf
        if d[j] <= max_distance and d[j] < ratio * second:
            claims.setdefault(int(cand[j]), []).append((int(d[j]), int(r)))
    out = []
    for c, who in claims.items():
        d_win, r_win = min(who)  # nearest, then the lower reference index
        if all(np.linalg.norm(p_ref[r] - p_ref[r_win]) <= r_px for _, r in who):
            out.append((r_win, c))
    out = np.array(sorted(out), int).reshape(-1, 2)
    return out[:, 0], out[:, 1]


def test_twin_aware_matching_equals_brute_force_and_keeps_a_corner_found_twice():
    rng = np.random.default_rng(5)
    base = rng.integers(0, 256, (30, 32), dtype=np.uint8)
    desc_ref = base[rng.integers(0, 30, 80)] ^ (rng.random((80, 32)) < 0.03).astype(np.uint8)
    desc_cur = base[rng.integers(0, 30, 90)] ^ (rng.random((90, 32)) < 0.03).astype(np.uint8)
    p_ref = rng.uniform(0, 40, (80, 2))
    p_cur = rng.uniform(0, 40, (90, 2))
    i_ref, i_cur = rng.integers(0, 80, 700), rng.integers(0, 90, 700)
    for radius in (1.5, 4.0):
        got = knn_ratio_match_pairs(
            desc_ref,
            desc_cur,
            i_ref,
            i_cur,
            ratio=0.8,
            max_distance=64,
            twins=(p_ref, p_cur, radius),
        )
        want = _brute_force_twins(desc_ref, desc_cur, i_ref, i_cur, 0.8, 64, p_ref, p_cur, radius)
        assert len(want[0]) > 3
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
    # one corner found twice in each image (0.4 px apart): the plain ratio test sees two equal
    # candidates and one-to-one drops the keypoint both landmarks claim; the twin-aware test
    # matches it
    d = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    desc2 = np.repeat(d, 2, axis=0)
    pts = np.array([[10.0, 10.0], [10.4, 10.0]])
    pairs = (np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1]))
    plain = knn_ratio_match_pairs(desc2, desc2, *pairs, ratio=0.8, max_distance=64)
    assert len(plain[0]) == 0
    twin = knn_ratio_match_pairs(
        desc2, desc2, *pairs, ratio=0.8, max_distance=64, twins=(pts, pts, 1.5)
    )
    assert len(twin[0]) == 1
    # the same twins 6 px apart are rivals again
    apart = np.array([[10.0, 10.0], [16.0, 10.0]])
    far = knn_ratio_match_pairs(
        desc2, desc2, *pairs, ratio=0.8, max_distance=64, twins=(apart, apart, 1.5)
    )
    assert len(far[0]) == 0
    with pytest.raises(ValueError, match="twin_px"):
        FeatureOptions(twin_px=-1.0)


def test_parabola_peak_finds_the_vertex_of_a_quadratic_within_half_a_pixel():
    """The vertex of a map quadratic in each axis, from the nearest whole pixel (closed form);
    a vertex farther than half a pixel is clipped there."""
    from jaxpose.vision.stereo_features import _parabola_peak

    vv, uu = np.mgrid[0:40, 0:40].astype(float)
    r = -((uu - 10.3) ** 2) - 2.0 * (vv - 20.7) ** 2
    got = _parabola_peak(r, np.array([[10.4, 20.6], [9.8, 21.2], [12.0, 20.0]]))
    np.testing.assert_allclose(got[:2], [[10.3, 20.7], [10.3, 20.7]], atol=1e-5)
    np.testing.assert_allclose(got[2], [11.5, 20.5], atol=1e-6)  # 1.7 px away: clipped


def test_peak_refinement_stays_within_half_a_pixel_of_the_corners():
    from jaxpose.vision.stereo_features import detect_points

    rng = np.random.default_rng(0)
    blocks = (rng.random((24, 32)) > 0.5).astype(np.uint8) * 200 + 20
    img = cv2.GaussianBlur(
        cv2.resize(blocks, (320, 240), interpolation=cv2.INTER_NEAREST), (0, 0), 1.0
    )
    raw, _ = detect_points(img, options=FeatureOptions(orb_levels=1, subpixel=False))
    peak, _ = detect_points(img, options=FeatureOptions(orb_levels=1, subpixel="peak"))
    assert raw.shape == peak.shape and len(raw) > 50
    assert np.abs(peak - raw).max() <= 0.5 + 1e-6
    assert np.mean(np.abs(peak - np.round(peak)) > 0.01) > 0.3  # most moved off the grid
    with pytest.raises(ValueError, match="subpixel"):
        FeatureOptions(subpixel="harris")
    for bad in (0, -2):  # (a float is refused by the type check under the tests' hook)
        with pytest.raises(ValueError, match="subpixel_half_window"):
            FeatureOptions(subpixel_half_window=bad)


def _target_on_sky(seed: int, shape, box, blocks) -> np.ndarray:
    """A ``shape`` image, black but for a target of random grey blocks (``blocks`` rows and
    columns) in ``box`` ``(u, v, width, height)``, blurred by a Gaussian of 1 px."""
    rng = np.random.default_rng(seed)
    img = np.zeros(shape, np.uint8)
    grid = (rng.random(blocks) > 0.5).astype(np.uint8) * 180 + 40
    u, v, w, h = box
    img[v : v + h, u : u + w] = cv2.resize(grid, (w, h), interpolation=cv2.INTER_NEAREST)
    return cv2.GaussianBlur(img, (0, 0), 1.0)


def test_a_region_of_interest_keeps_the_keypoints_orb_finds_on_the_whole_image():
    """A textured target on a dark sky, the region of interest its tight box: ORB drops
    keypoints within 31 pixels of its level of the image it is given, so the crop must keep that
    much sky around the box. Reference: OpenCV's ORB on the whole image (the budget not reached,
    so both keep every corner they find)."""
    from jaxpose.pipelines.stereo import target_roi
    from jaxpose.vision.stereo_features import detect_points

    img = _target_on_sky(3, (480, 640), (260, 200, 128, 96), (12, 16))
    opts = FeatureOptions(n_points=5000, subpixel=False)
    roi = target_roi(img)
    assert roi is not None and roi[0] >= 250 and roi[2] <= 400  # the box hugs the target
    cropped, _ = detect_points(img, options=opts, roi=roi)
    orb = cv2.ORB_create(nfeatures=5000, fastThreshold=opts.orb_fast_threshold, nlevels=8)
    kps = orb.detect(img, None)
    whole = np.array([k.pt for k in kps])
    assert len(whole) > 100
    level0 = whole[np.array([k.octave for k in kps]) == 0]
    assert np.linalg.norm(level0[:, None] - cropped[None], axis=-1).min(1).max() < 1e-3
    assert 0.9 < len(cropped) / len(whole) < 1.1, (len(cropped), len(whole))
    # the keypoints of the whole image are found in the crop: those of the full-resolution level
    # exactly, the coarser levels' within 2 px (the crop's corner is not on their pixel grid)
    d = np.linalg.norm(whole[:, None] - cropped[None], axis=-1).min(1)
    assert np.mean(d < 2.0) > 0.9, np.mean(d < 2.0)


def test_dark_margin_drops_the_keypoints_beside_the_dark_sky_and_only_those():
    """A textured target on a dark sky: with ``dark_margin_px`` the keypoints whose window of
    that half-width holds a pixel below ``DARK_LEVEL`` (checked here pixel by pixel) are dropped,
    the others kept as they were, descriptors and responses with them."""
    from jaxpose.vision.stereo_features import DARK_LEVEL, detect_points

    img = _target_on_sky(4, (240, 320), (76, 60, 168, 120), (10, 14))
    base = FeatureOptions(n_points=3000, subpixel=False)
    pts, desc, resp = detect_points(img, options=base, response=True)
    m = 5
    near = np.array(
        [
            (img[max(v - m, 0) : v + m + 1, max(u - m, 0) : u + m + 1] < DARK_LEVEL).any()
            for u, v in np.rint(pts).astype(int)
        ]
    )
    assert 10 < near.sum() < len(pts) - 10  # both kinds present
    got, got_desc, got_resp = detect_points(
        img, options=replace(base, dark_margin_px=m), response=True
    )
    np.testing.assert_array_equal(got, pts[~near])
    np.testing.assert_array_equal(got_desc, desc[~near])
    np.testing.assert_array_equal(got_resp, resp[~near])
    on_dark = np.array([img[v, u] < DARK_LEVEL for u, v in np.rint(pts).astype(int)])
    at_zero, _ = detect_points(img, options=replace(base, dark_margin_px=0))
    np.testing.assert_array_equal(at_zero, pts[~on_dark])  # the keypoint's own pixel only
    for bad in (-1, True):  # (a float is refused by the type check under the tests' hook)
        with pytest.raises(ValueError, match="dark_margin_px"):
            FeatureOptions(dark_margin_px=bad)


def _noisy_sky_with_stars(seed: int, shape, box, blocks, sigma: float) -> np.ndarray:
    """:func:`_target_on_sky` with Gaussian sensor noise of ``sigma`` grey levels and 30 stars
    (single pixels of grey 120-255) scattered over the sky."""
    rng = np.random.default_rng(seed)
    img = _target_on_sky(seed, shape, box, blocks).astype(float)
    img += rng.normal(0.0, sigma, shape)
    v, u = rng.integers(0, shape[0], 30), rng.integers(0, shape[1], 30)
    keep = (u < box[0] - 40) | (u > box[0] + box[2] + 40)  # on the sky, not on the target
    img[v[keep], u[keep]] = rng.integers(120, 256, keep.sum())
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("scale", [0.8, 0.55, 1.0])
def test_lines_in_a_box_are_the_lines_lsd_finds_on_the_whole_image(scale):
    """A noisy textured target on a sky with stars: the segments of ``detect_lines`` within a
    box, found on a crop, are those OpenCV's LSD finds on the whole image near the target, to
    float precision. Without the crop's snapped corner (the resampling grid) and raised
    threshold (the number of tests), some move by a fraction of a pixel or appear and vanish:
    the reference is the whole image's LSD through the same function without a box."""
    from jaxpose.pipelines.stereo.frames import lit_box

    img = _noisy_sky_with_stars(5, (480, 640), (241, 187, 150, 110), (9, 12), 5.0)
    opts = FeatureOptions(mu=0.04, lsd_scale=scale, max_lines=500)
    whole, _ = detect_lines(img, options=opts)
    box = lit_box(img)
    got, _ = detect_lines(img, options=opts, roi=box)
    near = (whole.min(1) > box[:2] - 16).all(1) & (whole.max(1) < box[2:] + 16).all(1)
    assert near.sum() >= 10
    d = np.abs(whole[:, None] - got[None]).max(axis=(2, 3))  # (whole, got)
    assert d[near].min(1).max() < 1e-4, d[near].min(1).max()  # every one near the box found
    assert d.min(0).max() < 1e-4, d.min(0).max()  # and nothing the whole image lacks
    # a plain crop of the box (LSD's own grid and threshold) does not find the same segments
    crop = img[int(box[1]) - 19 : int(box[3]) + 16, int(box[0]) - 18 : int(box[2]) + 16]
    plain, _ = detect_lines(crop, options=replace(opts, mu=0.04 * 480 / crop.shape[0]))
    plain = plain + [int(box[0]) - 18, int(box[1]) - 19]
    if scale != 1.0:  # (at scale 1 only the threshold differs)
        e = np.abs(whole[near][:, None] - plain[None]).max(axis=(2, 3)).min(1)
        assert (e > 1e-3).sum() >= 1 or len(plain) != near.sum()


def test_lit_box_holds_the_target_whatever_the_noise_and_stars():
    """Sensor noise of 5 grey levels makes the bright-sample box (``target_roi``) the whole
    image; the lit box (``lit_box``) is the target's box within a sample step, stars and
    noise aside, and ``None`` on a black image."""
    from jaxpose.pipelines.stereo import target_roi
    from jaxpose.pipelines.stereo.frames import lit_box, target_area

    u, v, w, h = 241, 187, 150, 110
    img = _noisy_sky_with_stars(6, (480, 640), (u, v, w, h), (9, 12), 5.0)
    roi = target_roi(img)
    assert roi[2] - roi[0] > 600 and roi[3] - roi[1] > 440  # the noise widens it to the image
    box = lit_box(img)
    np.testing.assert_allclose(box, [u, v, u + w, v + h], atol=8)
    assert lit_box(np.zeros((480, 640), np.uint8)) is None
    for box in (lit_box, target_roi, target_area):  # colour: an error that names the image
        with pytest.raises(ValueError, match="image must be a grey"):
            box(np.dstack([img] * 3))
