"""Stereo correspondence (eq. 4-5) and frame-to-frame features (eqs. 1-3) on images drawn here."""

import cv2
import numpy as np
import pytest

from jaxpose import PinholeCamera, StereoCamera
from jaxpose.vision.stereo_features import (
    FeatureOptions,
    detect_lines,
    extract,
    match_lines,
    match_points,
)
from jaxpose.vision.stereo_match import (
    StereoMatchOptions,
    disparity_range,
    match_lines_stereo,
    match_points_stereo,
    match_stereo,
    parabolic_offset,
    zncc,
)

H, W = 384, 512


def _scene(rng, shift=(0.0, 0.0), angle_deg=0.0):
    """Smooth random texture with thick bright segments, optionally rotated/shifted (float32)."""
    tex = cv2.GaussianBlur((rng.random((H, W)) * 255).astype(np.float32), (0, 0), 2.0)
    tex = cv2.normalize(tex, None, 20, 200, cv2.NORM_MINMAX)
    for _ in range(12):
        p = rng.uniform([60, 60], [W - 60, H - 60], (2, 2))
        cv2.line(tex, tuple(map(int, p[0])), tuple(map(int, p[1])), 250, 3, cv2.LINE_AA)
    return tex


def _shift(img, dx, dy=0.0, angle_deg=0.0):
    M = cv2.getRotationMatrix2D((W / 2, H / 2), angle_deg, 1.0)
    M[:, 2] += [dx, dy]
    out = cv2.warpAffine(img, M, (W, H), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    return np.clip(out, 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def pair():
    rng = np.random.default_rng(7)
    left = _scene(rng)
    return np.clip(left, 0, 255).astype(np.uint8), _shift(left, -23.4), 23.4


def test_zncc_and_parabola():
    rng = np.random.default_rng(0)
    a = rng.random((4, 7, 7))
    np.testing.assert_allclose(zncc(a, 3.0 * a + 5.0), 1.0)
    np.testing.assert_allclose(zncc(a, -a), -1.0)
    assert zncc(a, np.ones_like(a)).tolist() == [0.0] * 4
    x0 = 0.3
    s = lambda x: 1.0 - (x - x0) ** 2  # noqa: E731
    assert parabolic_offset(np.array(s(-1)), np.array(s(0)), np.array(s(1))) == pytest.approx(x0)


def test_point_epipolar_search_subpixel(pair):
    left, right, d = pair
    pts = extract(left, lines=False).points
    pm = match_points_stereo(left, right, pts, (5, 60))
    assert pm.ok.mean() > 0.8
    err = pts[pm.ok, 0] - pm.pixels_right[pm.ok, 0] - d
    assert np.median(np.abs(err)) < 0.1 and np.percentile(np.abs(err), 95) < 0.3
    np.testing.assert_array_equal(pm.pixels_right[:, 1], pts[:, 1])
    # a disparity range that excludes the truth gives no match at the border of the range
    assert match_points_stereo(left, right, pts, (30, 60)).ok.mean() < 0.05
    with pytest.raises(ValueError, match="disparity"):
        match_points_stereo(left, right, pts, (5, 6))
    with pytest.raises(ValueError, match="odd"):
        StereoMatchOptions(window=4)


def test_coarse_to_fine_search_equals_the_full_search(pair):
    """The coarse-to-fine search (coarse_min_range) finds the full search's sub-pixel matches,
    and a range that excludes the truth still gives no match."""
    left, right, d = pair
    pts = extract(left, lines=False).points
    full = match_points_stereo(left, right, pts, (5, 200))
    c2f = match_points_stereo(
        left, right, pts, (5, 200), options=StereoMatchOptions(coarse_min_range=64)
    )
    both = full.ok & c2f.ok
    assert full.ok.mean() > 0.8 and both.sum() >= 0.97 * full.ok.sum()
    same = np.abs(c2f.pixels_right[both] - full.pixels_right[both]).max(1) < 1e-9
    assert same.mean() >= 0.99  # where the two differ, a second peak of the texture
    for m in (full, c2f):
        err = np.abs(pts[m.ok, 0] - m.pixels_right[m.ok, 0] - d)
        assert np.percentile(err, 95) < 0.3
    # a range that excludes the truth: no more (false) matches than the full search's
    far = [
        match_points_stereo(left, right, pts, (30, 200), options=StereoMatchOptions(**kw)).ok
        for kw in ({}, {"coarse_min_range": 64})
    ]
    assert far[1].mean() <= far[0].mean() + 0.01, (far[0].mean(), far[1].mean())


def test_per_point_disparity_ranges(pair):
    left, right, d = pair
    pts = extract(left, lines=False).points
    wide = match_points_stereo(left, right, pts, (5, 60))
    # a narrow range a point around the truth: the same matches as the wide search
    rng = np.random.default_rng(1)
    lo = np.floor(d - rng.uniform(2, 6, len(pts))).astype(int)
    hi = np.ceil(d + rng.uniform(2, 6, len(pts))).astype(int)
    narrow = match_points_stereo(left, right, pts, np.stack([lo, hi], 1))
    assert narrow.ok.sum() >= 0.95 * wide.ok.sum()
    both = narrow.ok & wide.ok
    np.testing.assert_allclose(narrow.pixels_right[both], wide.pixels_right[both], atol=1e-4)
    # half the points get a range beside the truth: those give no match, the others are kept
    beside = np.arange(len(pts)) % 2 == 0
    ranges = np.stack([lo, hi], 1)
    ranges[beside] = [int(d) + 4, int(d) + 20]
    mixed = match_points_stereo(left, right, pts, ranges)
    assert mixed.ok[beside].mean() < 0.05
    np.testing.assert_array_equal(mixed.ok[~beside], narrow.ok[~beside])
    with pytest.raises(ValueError, match="feature 3"):
        bad = np.stack([lo, hi], 1)
        bad[3] = [10, 11]
        match_points_stereo(left, right, pts, bad)
    with pytest.raises(ValueError, match="one pair per feature"):
        match_points_stereo(left, right, pts, np.zeros((len(pts) + 1, 2)))


def test_match_stereo_in_two_threads_equals_one(pair):
    """A point's match does not depend on the points searched with it (ranges of mixed widths,
    some coarse to fine): the two-thread split of match_stereo returns the one-thread matches,
    and its segments (their samples searched among the points) those found alone."""
    from concurrent.futures import ThreadPoolExecutor

    left, right, d = pair
    feats = extract(left)
    rng = np.random.default_rng(2)
    n = len(feats.points)
    lo = rng.integers(0, 20, n)
    ranges = np.stack([lo, lo + rng.choice([8, 40, 150], n)], 1)
    opts = StereoMatchOptions(coarse_min_range=64)
    one = match_stereo(left, right, feats.points, ranges, feats.segments, (5, 60), options=opts)
    with ThreadPoolExecutor(max_workers=1) as pool:
        two = match_stereo(
            left,
            right,
            feats.points,
            ranges,
            feats.segments,
            (5, 60),
            options=opts,
            executor=pool,
        )
    assert one[0].ok.sum() > 0.5 * n and one[1].ok.sum() >= 5
    for a, b in zip(one, two, strict=True):
        for name in a.__dataclass_fields__:
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    # the segments' samples searched among the points: the segments found alone
    alone = match_lines_stereo(left, right, feats.segments, (5, 60), options=opts)
    for name in alone.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(alone, name), getattr(one[1], name))
    # and each point alone finds what it found among the others
    for i in np.nonzero(one[0].ok)[0][:5]:
        alone = match_points_stereo(
            left, right, feats.points[i : i + 1], ranges[i : i + 1], options=opts
        )
        np.testing.assert_array_equal(alone.pixels_right[0], one[0].pixels_right[i])


def test_line_stereo_match_and_cut(pair):
    left, right, d = pair
    seg, desc = detect_lines(left)
    assert desc.shape == (len(seg), 32) and desc.dtype == np.uint8  # 256-bit LBD
    lm = match_lines_stereo(left, right, seg, (5, 60))
    assert lm.ok.sum() >= 5
    # cut at the left endpoints' rows: same rows, shifted by the disparity
    np.testing.assert_allclose(lm.segments_right[lm.ok, :, 1], seg[lm.ok, :, 1])
    np.testing.assert_allclose(seg[lm.ok, :, 0] - lm.segments_right[lm.ok, :, 0], d, atol=0.4)
    assert np.all(lm.fit_error[lm.ok] < StereoMatchOptions().eps_delta_px)
    # horizontal segments are never matched along the rows
    flat = np.array([[[100.0, 200.0], [300.0, 201.0]]])
    assert not match_lines_stereo(left, right, flat, (5, 60)).ok.any()


def test_eq1_length_filter(pair):
    left, _, _ = pair
    short = detect_lines(left, options=FeatureOptions(mu=0.02))[0]
    long_ = detect_lines(left, options=FeatureOptions(mu=0.15))[0]
    assert len(long_) < len(short)
    assert np.all(np.linalg.norm(long_[:, 1] - long_[:, 0], axis=1) > 0.15 * min(H, W) - 1e-6)


def test_frame_to_frame_matching_rotated_view():
    rng = np.random.default_rng(3)
    img = _scene(rng)
    a, b = np.clip(img, 0, 255).astype(np.uint8), _shift(img, 6.0, -4.0, angle_deg=8.0)
    fa, fb = extract(a), extract(b)
    M = cv2.getRotationMatrix2D((W / 2, H / 2), 8.0, 1.0)
    M[:, 2] += [6.0, -4.0]
    ia, ib = match_points(fa.points, fa.point_desc, fb.points, fb.point_desc)
    assert len(ia) > 100
    pred = fa.points[ia] @ M[:, :2].T + M[:, 2]
    dist = np.linalg.norm(pred - fb.points[ib], axis=1)
    assert np.median(dist) < 1.0 and np.mean(dist < 3.0) > 0.85
    la, lb = match_lines(fa.line_desc, fb.line_desc)
    assert len(la) >= 5
    mid_a = fa.segments[la].mean(1) @ M[:, :2].T + M[:, 2]
    assert np.mean(np.linalg.norm(mid_a - fb.segments[lb].mean(1), axis=1) < 15.0) > 0.8


def test_disparity_range_of_rig():
    rig = StereoCamera.from_baseline(PinholeCamera(1000.0, 1000.0, 511.5, 383.5), 0.2)
    lo, hi = disparity_range(rig, 1.0, 4.0)
    assert lo <= 50 and hi >= 200
    with pytest.raises(ValueError):
        disparity_range(rig, 4.0, 1.0)


def test_line_trim_drops_samples_matched_on_a_neighbouring_edge(monkeypatch):
    """A steep segment whose sample matches lie on its right image line (disparity 20 px) but
    for three that matched 6-9 px off (a repeated edge): the paper's fit fails eq. 5, the
    trimmed fit keeps the segment and cuts it where the true right line is."""
    import jaxpose.vision.stereo_match as sm

    seg = np.array([[[200.0, 100.0], [230.0, 300.0]]])
    img = np.zeros((H, W), np.uint8)

    def fake_points(left, right, samples, disparities, *, options, executor=None):
        right_px = samples - [20.0, 0.0]
        right_px[[2, 7, 11], 0] += [6.0, -9.0, 7.0]
        return sm.PointMatches(right_px, np.ones(len(samples)), np.ones(len(samples), bool))

    monkeypatch.setattr(sm, "match_points_stereo", fake_points)
    plain = sm.match_lines_stereo(img, img, seg, (5, 60))
    assert not plain.ok[0] and plain.fit_error[0] > StereoMatchOptions().eps_delta_px
    trimmed = sm.match_lines_stereo(
        img, img, seg, (5, 60), options=StereoMatchOptions(line_trim_px=1.5)
    )
    assert trimmed.ok[0] and trimmed.fit_error[0] < 1e-9
    np.testing.assert_allclose(trimmed.segments_right[0], seg[0] - [20.0, 0.0], atol=1e-9)
    with pytest.raises(ValueError, match="line_trim_px"):
        StereoMatchOptions(line_trim_px=0.0)


def test_the_search_scores_each_window_by_its_zncc_in_chunks_of_any_size(pair, monkeypatch):
    """The best score of each point is the largest ZNCC of its left window against the right
    windows of its disparities, computed here window by window; the points searched in chunks
    of 7 give the same matches as all at once (a point's match does not depend on its chunk)."""
    import jaxpose.vision.stereo_match as sm

    left, right, _ = pair
    rng = np.random.default_rng(3)
    pts = np.stack([rng.integers(120, W - 40, 40), rng.integers(20, H - 20, 40)], 1).astype(float)
    o = StereoMatchOptions()
    pm = match_points_stereo(left, right, pts, (5, 60), options=o)
    h, hr = o.window // 2, o.window_rows // 2
    L, R = left.astype(float), right.astype(float)
    for (u, v), best in zip(pts.astype(int), pm.score, strict=True):
        a = L[v - hr : v + hr + 1, u - h : u + h + 1]
        scores = [
            zncc(a[None], R[None, v - hr : v + hr + 1, u - d - h : u - d + h + 1])[0]
            for d in range(5, 61)
        ]
        assert best == pytest.approx(max(scores), abs=1e-5)
    monkeypatch.setattr(sm, "_CHUNK", 7)
    chunked = match_points_stereo(left, right, pts, (5, 60), options=o)
    np.testing.assert_array_equal(chunked.pixels_right, pm.pixels_right)
    np.testing.assert_array_equal(chunked.ok, pm.ok)


def test_twins_are_searched_once_and_keep_their_own_column(pair, monkeypatch):
    """merge_px: points within one cell of its grid (ORB's one corner at several levels) are
    searched once; each keeps the searched twin's disparity at its own pixel, and the matches
    are those of every point searched, to the sub-pixel peak's wobble (0.2 px)."""
    import jaxpose.vision.stereo_match as sm

    left, right, d = pair
    pts = np.floor(extract(left).points[:60] / 0.01) * 0.01 + 0.004  # inside their 0.01 cells
    twins = pts[:20] + [0.003, -0.002]  # in the cells of their originals
    grid_apart = pts[20:30] + [0.5, 0.0]  # other cells: searched apart
    allp = np.concatenate([pts, twins, grid_apart])
    ranges = (5, 60)
    plain = match_points_stereo(left, right, allp, ranges)
    searched = []
    real = sm._search_rows

    def counting(L, padded, p, *args):
        searched.append(len(p))
        return real(L, padded, p, *args)

    monkeypatch.setattr(sm, "_search_rows", counting)
    merged = match_points_stereo(
        left, right, allp, ranges, options=StereoMatchOptions(merge_px=0.01)
    )
    assert plain.ok.sum() > 40
    np.testing.assert_array_equal(merged.ok, plain.ok)
    ok = plain.ok
    assert np.abs(merged.pixels_right[ok] - plain.pixels_right[ok]).max() < 0.2
    n_cells = len(np.unique(np.floor(allp / 0.01), axis=0))
    assert sum(searched) == n_cells < len(allp)
    # a twin takes its original's disparity, at its own pixel
    disparity = allp[:, 0] - merged.pixels_right[:, 0]
    np.testing.assert_allclose(disparity[60:80], disparity[:20])
    np.testing.assert_array_equal(merged.pixels_right[:, 1], allp[:, 1])
    with pytest.raises(ValueError, match="merge_px"):
        StereoMatchOptions(merge_px=-0.01)


@pytest.mark.parametrize(
    ("scale", "high", "k"),
    [(1, 5, 4), (2**40, 5, 4), (2**61, 2, 3)],
    ids=["packed", "too-wide-to-pack", "span-beyond-int64"],
)
def test_row_keys_rank_rows_as_numpys_unique_along_axis_0(scale, high, k):
    """The twins' grouping key: ``np.unique`` of the keys gives the same first indices and
    inverse as ``np.unique(rows, axis=0)``, rows of negative values and repeats included, and
    when the rows' ranges do not fit one 64-bit integer (nor, at +-2^62, does max - min)."""
    from jaxpose.vision.stereo_match import _row_keys

    rng = np.random.default_rng(3)
    rows = rng.integers(-high, high + 1, (400, k)) * scale
    rows[::7] = rows[3]  # repeats of one row
    _, first, inverse = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    _, first_k, inverse_k = np.unique(_row_keys(rows), return_index=True, return_inverse=True)
    np.testing.assert_array_equal(first_k, first)
    np.testing.assert_array_equal(inverse_k, inverse.reshape(-1))
