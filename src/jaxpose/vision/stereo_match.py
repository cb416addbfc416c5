"""Stereo correspondence by epipolar search with zero-mean NCC (Yang et al. 2024, Sec. 3).

The images must be rectified (epipolar lines are image rows: an ideal side-by-side rig such as
:meth:`jaxpose.core.camera.StereoCamera.from_baseline`, or images warped with
:func:`jaxpose.vision.stereo_rectify.rectify` and its ``rectified_camera()``). For a left
feature at ``(u, v)`` the right match is searched on row ``v`` over the integer disparities
``d_min..d_max`` (from the depth range, :func:`disparity_range`):

* eq. 4: zero-mean NCC between the ``w x w`` left patch and each right patch; the best score
  above ``ncc_threshold`` is the coarse match, refined to sub-pixel by a parabola through the
  scores at ``d - 1, d, d + 1``. All points of a frame are matched at once (one ``cv2.remap``
  gathers every patch with bilinear sampling at sub-pixel rows; NumPy does the correlation).
* lines: points sampled along the left segment are matched the same way; a total-least-squares
  line is fitted to the right matches and kept when (eq. 5) the mean distance of the matches to
  it is below ``eps_delta_px`` and its angle differs from the left segment's by less than
  ``eps_theta_deg``. Eq. 5 as printed bounds "the angle between the line and the horizontal"
  (the printed inequality sign cannot be right: a line near the rows has no defined match along
  a row). We apply it in the meaningful direction: left segments and fitted right lines within
  ``min_epipolar_angle_deg`` of the rows are dropped, and ``eps_theta_deg`` bounds the angle
  between the left segment and the right line (a 3-D line seen from two centres keeps nearly the
  same image direction when the baseline is small against the range; depth changing along the
  line tilts it a little, hence a loose default).
  The right segment is cut by the rows of the left endpoints (the "parallel lines through the
  left endpoints") and both endpoints triangulated.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from jaxpose.core._checks import check_fields, is_finite_number

__all__ = [
    "LineMatches",
    "PointMatches",
    "StereoMatchOptions",
    "disparity_range",
    "match_lines_stereo",
    "match_points_stereo",
    "match_stereo",
    "parabolic_offset",
    "steep_segments",
    "zncc",
]


@dataclass(frozen=True)
class StereoMatchOptions:
    """Hyper-parameters of the epipolar search.

    Attributes:
        window: NCC window width ``w`` (odd, pixels).
        window_rows: window height (odd; ``None``: square ``w x w`` as in eq. 4). A window
            shorter than wide tolerates the disparity gradient of surfaces receding along the
            columns (a face seen at a grazing angle from above or below), where a square window
            shears by several pixels; measured on the rendered tumbler, ``7 x 15`` cut the 90th
            percentile disparity error on such a face several-fold.
        ncc_threshold: minimum zero-mean NCC of an accepted match.
        min_texture: minimum standard deviation (grey levels) of the left patch.
        line_step_px: spacing of the samples along a left segment.
        line_max_samples: at most this many samples per segment.
        line_min_matches: fewest matched samples for a line fit (and at least half of them).
        eps_delta_px: eq. 5, largest mean distance of the matches to the fitted right line.
        eps_theta_deg: eq. 5, largest angle between the left segment and the fitted right line.
        min_epipolar_angle_deg: segments closer than this to the image rows are not matched.
        coarse_min_range: search features whose disparity range spans at least this many
            values coarse to fine (``None``: never): the whole range on the half-resolution
            images (:func:`cv2.pyrDown`, a ``coarse_window`` window, scores above
            ``coarse_ncc_threshold``), then the full-resolution search (as above, the same
            window and tests) within ``coarse_radius_px`` of twice the coarse disparity.
            Features without a coarse match are searched over their whole range.
        coarse_window, coarse_window_rows, coarse_ncc_threshold, coarse_radius_px: the
            coarse level's window, its acceptance score and the fine search's half-width.
        line_trim_px: ``None``: eq. 5 on every matched sample of a segment (the paper). A
            distance (pixels): the line is fitted again to the samples within three times this
            distance of the first fit, then again to those within this distance (a sample's
            ZNCC match on a neighbouring repeated edge is dropped instead of spoiling the fit),
            and eq. 5 and the counts above apply to the samples kept. Off by default: on the
            development scenes with blur or glints it lowered some errors and raised others
            (docs/stereo-evaluation.md, *More line features*).
        merge_px: points within this distance of each other (the same cell of a ``merge_px``
            grid) with the same disparity range are searched once, at the first of them, and
            the others take its match shifted by their own offset along the row (the same
            disparity; their rows are within ``merge_px``). ORB finds one corner at several
            pyramid levels and ``cornerSubPix`` pulls them to within its 0.01 px tolerance:
            about 40% of a near target's keypoints are such twins. ``None``: every point
            searched.
    """

    window: int = 15
    window_rows: int | None = 7
    ncc_threshold: float = 0.85
    min_texture: float = 2.0
    line_step_px: float = 8.0
    line_max_samples: int = 24
    line_min_matches: int = 5
    eps_delta_px: float = 1.0
    eps_theta_deg: float = 15.0
    min_epipolar_angle_deg: float = 12.0
    coarse_min_range: int | None = None
    coarse_window: int = 9
    coarse_window_rows: int = 5
    coarse_ncc_threshold: float = 0.7
    coarse_radius_px: int = 3
    line_trim_px: float | None = None
    merge_px: float | None = None

    def __post_init__(self):
        check_fields(
            self,
            integers={
                "window": 3,
                "window_rows": 3,
                "line_max_samples": 1,
                "line_min_matches": 1,
                "coarse_min_range": 1,
                "coarse_window": 3,
                "coarse_window_rows": 3,
                "coarse_radius_px": 0,
            },
            positive=(
                "line_step_px",
                "eps_delta_px",
                "eps_theta_deg",
                "line_trim_px",
                "merge_px",
            ),
            non_negative=("min_texture", "min_epipolar_angle_deg"),
            optional=("window_rows", "coarse_min_range", "line_trim_px", "merge_px"),
        )
        for name in ("window", "window_rows", "coarse_window", "coarse_window_rows"):
            w = getattr(self, name)
            if w is not None and w % 2 == 0:
                raise ValueError(f"StereoMatchOptions.{name} must be odd; got {w}")
        for name in ("ncc_threshold", "coarse_ncc_threshold"):
            c = getattr(self, name)
            if not (is_finite_number(c) and -1 <= c <= 1):
                raise ValueError(
                    f"StereoMatchOptions.{name} must be a number in [-1, 1]; got {c!r}"
                )


@dataclass
class PointMatches:
    """Right-image matches of left points: ``pixels_right (N, 2)``, ``score (N,)``, ``ok (N,)``."""

    pixels_right: np.ndarray
    score: np.ndarray
    ok: np.ndarray


@dataclass
class LineMatches:
    """Right-image segments of left segments, cut at the left endpoints' rows.

    ``segments_right (M, 2, 2)``, ``fit_error (M,)`` (eq. 5 ``delta``, pixels), ``n_matched (M,)``,
    ``ok (M,)``.
    """

    segments_right: np.ndarray
    fit_error: np.ndarray
    n_matched: np.ndarray
    ok: np.ndarray


def disparity_range(rig, depth_min_m: float, depth_max_m: float) -> tuple[int, int]:
    """Integer disparities ``(d_min, d_max)`` of depths in ``[depth_min_m, depth_max_m]`` for a
    rectified rig (``d = fx b / Z``), widened by one pixel each side for the parabola."""
    if not 0 < depth_min_m < depth_max_m:
        raise ValueError(f"need 0 < depth_min < depth_max; got {depth_min_m}, {depth_max_m}")
    fb = float(rig.left.fx) * float(rig.baseline)
    return max(0, int(np.floor(fb / depth_max_m)) - 1), int(np.ceil(fb / depth_min_m)) + 1


def zncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Zero-mean NCC (eq. 4) of patches ``a, b`` of shape ``(..., w, w)``; 0 for flat patches."""
    a = a - a.mean(axis=(-2, -1), keepdims=True)
    b = b - b.mean(axis=(-2, -1), keepdims=True)
    den = np.sqrt((a * a).sum(axis=(-2, -1)) * (b * b).sum(axis=(-2, -1)))
    num = (a * b).sum(axis=(-2, -1))
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)


def parabolic_offset(s_minus: np.ndarray, s_0: np.ndarray, s_plus: np.ndarray) -> np.ndarray:
    """Vertex offset in ``(-0.5, 0.5)`` of the parabola through ``(-1, s-), (0, s0), (1, s+)``."""
    den = s_minus - 2.0 * s_0 + s_plus
    off = 0.5 * (s_minus - s_plus) / np.where(den < 0, den, -1.0)
    return np.where(den < 0, np.clip(off, -0.5, 0.5), 0.0)


def _as_float(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.ndim != 2:
        raise ValueError(f"expected a grayscale image; got shape {np.shape(image)}")
    return img.astype(np.float32, copy=False)


def _gather(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` at float maps of any shape (one ``cv2.remap`` call)."""
    shape = map_x.shape
    mx = map_x.reshape(-1, shape[-1]).astype(np.float32)
    my = map_y.reshape(-1, shape[-1]).astype(np.float32)
    # cv2.remap needs fewer than 32768 rows per call
    rows = []
    for s in range(0, len(mx), 32000):
        rows.append(
            cv2.remap(
                image,
                mx[s : s + 32000],
                my[s : s + 32000],
                cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_REPLICATE,
            )
        )
    return np.concatenate(rows, 0).reshape(shape)


def _padded(image: np.ndarray, c0: np.ndarray, v: np.ndarray, width: int, hr: int):
    """``image`` with its edge replicated far enough for the strips of :func:`_strips`, and the
    padding ``(pad_x, pad_y)``."""
    H, W = image.shape
    vi = np.floor(v).astype(np.int64)
    pad_x = int(max(0, -c0.min(), c0.max() + width - W)) if len(c0) else 0
    pad_y = int(max(0, hr - vi.min(), vi.max() + hr + 2 - H)) if len(c0) else 0
    padded = cv2.copyMakeBorder(image, pad_y, pad_y, pad_x, pad_x, cv2.BORDER_REPLICATE)
    return padded, (pad_x, pad_y)


def _strips(padded, pads, c0: np.ndarray, v: np.ndarray, width: int, wr: int, hr: int):
    """``(N, wr, width)`` float32 strips of an image (``padded`` by :func:`_padded`): integer
    columns ``c0 .. c0 + width - 1``, rows ``v - hr .. v + hr`` at the sub-pixel ``v`` (linear
    interpolation between the two integer rows; the image edge replicated beyond the border).
    One fancy-indexed gather from the sliding-window view of the padded image: no per-sample
    interpolation along the row, which the parabola over integer disparities does not need."""
    vi = np.floor(v).astype(np.int64)
    frac = (v - vi).astype(np.float32)[:, None, None]
    out = sliding_window_view(padded, (wr + 1, width))[vi - hr + pads[1], c0 + pads[0]]
    low = out[:, :-1]
    strip = out[:, 1:] - low  # low + frac (high - low), in place
    strip *= frac
    strip += low
    return strip


def _per_feature(disparities, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(n,)`` integer ``d_min`` and ``d_max`` of each feature from one ``(d_min, d_max)`` pair
    or an ``(n, 2)`` array; each range must span at least 3 disparities."""
    d = np.asarray(disparities)
    if d.shape == (2,):
        if d[1] - d[0] < 2:
            raise ValueError(
                f"the disparity range must span at least 3 values; got {tuple(disparities)}"
            )
        d = np.broadcast_to(d, (n, 2))
    if d.shape != (n, 2):
        raise ValueError(
            f"disparities must be (d_min, d_max) or one pair per feature ({n}, 2); got "
            f"shape {d.shape}"
        )
    d_min, d_max = np.floor(d[:, 0]).astype(np.int64), np.ceil(d[:, 1]).astype(np.int64)
    if n and np.any(d_max - d_min < 2):
        bad = int(np.argmax(d_max - d_min < 2))
        raise ValueError(
            f"the disparity range must span at least 3 values; feature {bad} has "
            f"{tuple(d[bad].tolist())}"
        )
    return d_min, d_max


def match_points_stereo(
    left: np.ndarray,
    right: np.ndarray,
    pixels_left: np.ndarray,
    disparities,
    *,
    options: StereoMatchOptions = StereoMatchOptions(),
    executor=None,
) -> PointMatches:
    """Epipolar ZNCC search (eq. 4) with parabolic sub-pixel refinement, vectorised over points.

    Args:
        left, right: rectified grayscale images (same size).
        pixels_left: ``(N, 2)`` left pixels ``(u, v)`` (sub-pixel allowed).
        disparities: integer ``(d_min, d_max)`` searched (``u_right = u_left - d``), the same for
            every point, or ``(N, 2)``: one range a point (e.g. around the disparity predicted
            from a landmark map). Points with ranges of similar width are searched together.
        executor: a one-worker :class:`concurrent.futures.ThreadPoolExecutor` (or ``None``): the
            calling thread and the worker take the chunks of points in turn from one queue
            (:func:`_in_two_threads`; the same matches either way).
    """
    L, Rimg = _as_float(left), _as_float(right)
    if L.shape != Rimg.shape:
        raise ValueError(f"left and right images differ in size: {L.shape} vs {Rimg.shape}")
    p = np.asarray(pixels_left, dtype=np.float64).reshape(-1, 2)
    N = len(p)
    d_min, d_max = _per_feature(disparities, N)
    if N == 0:
        return PointMatches(np.zeros((0, 2)), np.zeros(0), np.zeros(0, bool))
    if options.merge_px is not None:
        return _merged(L, Rimg, p, d_min, d_max, options, executor)
    D = d_max - d_min + 1
    wide = D >= options.coarse_min_range if options.coarse_min_range else np.zeros(N, bool)
    if wide.any():
        d_min, d_max = _coarse_ranges(L, Rimg, p, d_min, d_max, wide, options, executor)
        D = d_max - d_min + 1
    out = PointMatches(np.zeros((N, 2)), np.full(N, -1.0), np.zeros(N, bool))
    w, hr = options.window, (options.window_rows or options.window) // 2
    c0 = np.floor(p[:, 0]).astype(np.int64) - d_max - w // 2  # first column of each strip
    padded = _padded(Rimg, np.r_[c0, c0 + D.max()], p[:, 1], w, hr)
    # widths rounded up to a power of two: a few groups, each searched at its largest width,
    # the widest (the longest chunks) first so that the two threads end together
    group = np.ceil(np.log2(D)).astype(np.int64)
    chunks = [
        group_sel[start : start + _CHUNK]
        for g in np.unique(group)[::-1]
        for group_sel in [np.nonzero(group == g)[0]]
        for start in range(0, len(group_sel), _CHUNK)
    ]

    def search(sel):
        uv_r, best, ok = _search_rows(L, padded, p[sel], d_max[sel], D[sel], options)
        out.pixels_right[sel], out.score[sel], out.ok[sel] = uv_r, best, ok

    _in_two_threads(search, chunks, executor)
    return out


def _merged(L, Rimg, p, d_min, d_max, options: StereoMatchOptions, executor) -> PointMatches:
    """:func:`match_points_stereo` with ``options.merge_px``: each group of points in one cell
    of the ``merge_px`` grid with one disparity range searched once, at its first point."""
    cell = np.floor(p / options.merge_px).astype(np.int64)
    _, first, group = np.unique(
        _row_keys(np.column_stack([cell, d_min, d_max])), return_index=True, return_inverse=True
    )
    once = match_points_stereo(
        L,
        Rimg,
        p[first],
        np.stack([d_min[first], d_max[first]], 1),
        options=replace(options, merge_px=None),
        executor=executor,
    )
    rep = first[group]  # each point's searched twin
    right = once.pixels_right[group].copy()
    right[:, 0] += p[:, 0] - p[rep, 0]  # the twin's disparity, at the point's own column
    right[:, 1] = p[:, 1]
    return PointMatches(right, once.score[group], once.ok[group])


def _row_keys(rows: np.ndarray) -> np.ndarray:
    """One integer per row of ``rows (n, k)`` (integers) in the rows' lexicographic order, equal
    for equal rows: ``np.unique`` of these is ``np.unique(rows, axis=0)`` (the same first indices
    and inverse) at a sixth of its time. Rows whose ranges do not fit 62 bits are ranked."""
    lo = rows.min(axis=0)
    # the spans in floating point first: max - min itself overflows for the widest int64 rows
    if np.prod(rows.max(axis=0).astype(float) - lo.astype(float) + 1.0) >= 2.0**62:
        return np.unique(rows, axis=0, return_inverse=True)[1].reshape(-1)
    span = rows.max(axis=0) - lo + 1
    key = np.zeros(len(rows), np.int64)
    for j in range(rows.shape[1]):
        key = key * span[j] + (rows[:, j] - lo[j])
    return key


def _in_two_threads(work, items, executor) -> None:
    """``work(item)`` for every item, in the calling thread and, with an ``executor``, in its
    worker too, each taking the next item from one shared iterator until none is left (the two
    threads end within one item of each other whatever the items cost). ``work`` must write
    disjoint outputs."""
    it = iter(items)
    lock = threading.Lock()

    def drain():
        while True:
            with lock:
                item = next(it, None)
            if item is None:
                return
            work(item)

    if executor is None or len(items) < 2:
        drain()
        return
    pending = executor.submit(drain)
    try:
        drain()
    finally:
        pending.result()


# points searched together: the (points x disparities) temporaries of a few hundred points stay
# in the processor's cache (about 1 MB); all of a 1.5 m frame's at once took 1.7 times as long
# (a point's match does not depend on the points searched with it)
_CHUNK = 256


def _coarse_ranges(L, Rimg, p, d_min, d_max, wide, options: StereoMatchOptions, executor=None):
    """The disparity ranges of the fine search (``coarse_min_range``): for the ``wide``
    features with a match on the half-resolution images, ``coarse_radius_px`` around twice the
    coarse disparity (within the feature's own range); the others keep their ranges."""
    L2, R2 = cv2.pyrDown(L), cv2.pyrDown(Rimg)
    idx = np.nonzero(wide)[0]
    p2 = (p[idx] + 0.5) / 2.0 - 0.5
    lo = np.maximum(d_min[idx] // 2 - 1, 0)
    hi = np.maximum(-(-d_max[idx] // 2) + 1, lo + 2)
    coarse = replace(
        options,
        window=options.coarse_window,
        window_rows=options.coarse_window_rows,
        ncc_threshold=options.coarse_ncc_threshold,
        min_texture=0.0,
        coarse_min_range=None,
    )
    c = match_points_stereo(L2, R2, p2, np.stack([lo, hi], 1), options=coarse, executor=executor)
    d = 2.0 * (p2[:, 0] - c.pixels_right[:, 0])
    r = options.coarse_radius_px
    new_lo = np.maximum(np.floor(d).astype(np.int64) - r, d_min[idx])
    new_hi = np.minimum(np.ceil(d).astype(np.int64) + r, d_max[idx])
    good = c.ok & (new_hi - new_lo >= 2)
    d_min, d_max = d_min.copy(), d_max.copy()
    d_min[idx[good]], d_max[idx[good]] = new_lo[good], new_hi[good]
    return d_min, d_max


def _search_rows(L, padded, p, d_max, widths, options: StereoMatchOptions):
    """ZNCC of each left patch against the right windows of disparities ``d_max - widths + 1 ..
    d_max`` (per point) on its row (the right image ``padded`` by :func:`_padded`), the best
    score, its parabolic sub-pixel column and the tests. The points are searched together over
    the largest width, the windows beyond a point's own range scored -1: a point's match does
    not depend on the points searched with it."""
    N = len(p)
    D = int(widths.max())
    w = options.window  # columns
    wr = options.window_rows or w  # rows
    h, hr = w // 2, wr // 2
    H, W = L.shape
    offs = np.arange(w, dtype=np.float64) - h
    offs_r = np.arange(wr, dtype=np.float64) - hr
    u, v = p[:, 0], p[:, 1]
    rows_y = v[:, None, None] + offs_r[None, :, None]  # (N, wr, 1)
    patch = _gather(
        L,
        np.broadcast_to(u[:, None, None] + offs[None, None, :], (N, wr, w)),
        np.broadcast_to(rows_y, (N, wr, w)),
    )
    c0 = np.floor(u).astype(np.int64) - d_max - h  # first column of each right strip
    strip = _strips(*padded, c0, v, D + w - 1, wr, hr)  # (N, wr, D + w - 1) float32
    a = patch.astype(np.float64)
    a = a - a.mean(axis=(1, 2), keepdims=True)
    aa = (a * a).sum(axis=(1, 2))
    # windowed sums of the strip along the row: column sums in float32 (at most wr * 255^2 a
    # column), the sums over w columns and the variance in float64. The sums over w columns are
    # OpenCV box filters (forward windows, anchor at the first column): NumPy's running sums
    # (np.cumsum) hold the GIL, which serialised the two threads of match_stereo
    col1 = strip.sum(axis=1)  # (N, D + w - 1)
    col2 = np.einsum("nij,nij->nj", strip, strip)
    s1 = _window_sums(col1, w)[:, :D]  # (N, D)
    bb = _window_sums(col2, w)[:, :D]  # the windows' sums of squares, then their variance
    s1 *= s1
    s1 /= w * wr
    bb -= s1
    np.maximum(bb, 0.0, out=bb)
    # cross term sum_ik a[n,i,k] strip[n,i,j+k], one window column at a time (no (N,w,D,w)
    # copy), in float32: 8-bit pixels times zero-mean patch values over wr * w terms keep about
    # six significant digits, and float32 is several times faster here than float64
    a32 = a.astype(np.float32)
    ab = np.zeros((N, D), np.float32)
    for k in range(w):
        ab += np.einsum("ni,nij->nj", a32[:, :, k], strip[:, :, k : k + D])
    bb *= aa[:, None]
    den = np.sqrt(bb, out=bb)
    score = np.full((N, D), -1.0)
    np.divide(ab, den, out=score, where=den > 1e-9)
    # candidates: the point's own disparities (j = d_max - disparity < width) whose window lies
    # inside the right image (window centre c0 + h + j within [h, W - 1 - h]); only the rows with
    # a candidate missing are masked
    j_lo = np.maximum(-c0, 0)
    j_hi = np.minimum(widths, W - 2 * h - c0)
    edge = np.nonzero((j_lo > 0) | (j_hi < D))[0]
    if len(edge):
        jj = np.arange(D)[None, :]
        masked = score[edge]
        masked[(jj < j_lo[edge, None]) | (jj >= j_hi[edge, None])] = -1.0
        score[edge] = masked
    j = np.argmax(score, axis=1)
    best = score[np.arange(N), j]
    inner = (j > 0) & (j < widths - 1)
    jm, jp = np.clip(j - 1, 0, D - 1), np.clip(j + 1, 0, D - 1)
    off = parabolic_offset(score[np.arange(N), jm], best, score[np.arange(N), jp])
    u_right = c0 + h + j + np.where(inner, off, 0.0)
    texture = np.sqrt(aa / (w * wr)) >= options.min_texture
    inside = (v - hr >= 0) & (v + hr <= H - 1) & (u - h >= 0) & (u + h <= W - 1)
    ok = inner & (best >= options.ncc_threshold) & texture & inside
    return np.stack([u_right, v], 1), best, ok


def _window_sums(rows: np.ndarray, w: int) -> np.ndarray:
    """``out[n, j] = sum_{k < w} rows[n, j + k]`` in float64 (the last ``w - 1`` columns of
    ``out`` sum past the end of the row and are not used)."""
    return cv2.boxFilter(
        rows.astype(np.float64),
        -1,
        (w, 1),
        anchor=(0, 0),
        normalize=False,
        borderType=cv2.BORDER_CONSTANT,
    )


def steep_segments(segments: np.ndarray, min_epipolar_angle_deg: float) -> np.ndarray:
    """``(M,)`` whether each left-image segment ``(M, 2, 2)`` (pixels) is steep enough for the
    row search: at least ``min_epipolar_angle_deg`` from the image rows (the epipolar lines of a
    rectified rig). The others are never matched in stereo."""
    segments = np.asarray(segments)  # (its dtype kept: the matcher's samples use the same)
    if segments.ndim != 3 or segments.shape[1:] != (2, 2):
        raise ValueError(f"segments must be (M, 2, 2) pixels; got shape {segments.shape}")
    d = segments[:, 1] - segments[:, 0]
    length = np.linalg.norm(d, axis=1)
    return np.abs(d[:, 1]) >= np.sin(np.radians(min_epipolar_angle_deg)) * np.maximum(length, 1e-12)


def _segment_sampling(segments: np.ndarray, options: StereoMatchOptions):
    """Of segments ``(M, 2, 2)``: their directions ``(M, 2)`` and lengths ``(M,)``, whether each
    is steep enough for the row search (:func:`steep_segments`) and how many samples it gets
    (``(M,)`` bool and int)."""
    d = segments[:, 1] - segments[:, 0]
    length = np.linalg.norm(d, axis=1)
    steep = steep_segments(segments, options.min_epipolar_angle_deg)
    n = np.clip((length / options.line_step_px).astype(int), 3, options.line_max_samples)
    return d, length, steep, n


def _line_samples(segments: np.ndarray, d: np.ndarray, n: np.ndarray):
    """Sample pixels along each segment (directions ``d``, ``n`` samples each): ``(S, 2)``
    points and the segment index of each."""
    owner = np.repeat(np.arange(len(segments)), n)
    if len(segments) == 0:
        return np.zeros((0, 2)), owner
    # fractions in [0.1, 0.9] (endpoints are uncertain, Sec. 3)
    start = np.concatenate([[0], np.cumsum(n)[:-1]])
    k = np.arange(n.sum()) - np.repeat(start, n)
    frac = 0.1 + 0.8 * (k + 0.5) / np.repeat(n, n)
    return segments[owner, 0] + frac[:, None] * d[owner], owner


def _tls_lines(owner, pts, use, M):
    """Total-least-squares line of the samples ``use`` of each of ``M`` segments, all at once:
    the centroid ``(M, 2)``, the direction and the normal ``(M, 2)`` (the principal axis of the
    2x2 scatter matrix, closed form), the mean distance of the samples to it ``(M,)`` and their
    count ``(M,)``."""
    who, p = owner[use], pts[use]
    n = np.bincount(who, minlength=M)
    count = np.maximum(n, 1)
    c = np.stack([np.bincount(who, p[:, k], M) for k in (0, 1)], 1) / count[:, None]
    q = p - c[who]
    sxx, sxy, syy = (np.bincount(who, q[:, a] * q[:, b], M) for a, b in ((0, 0), (0, 1), (1, 1)))
    theta = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    direction = np.stack([np.cos(theta), np.sin(theta)], 1)
    normal = np.stack([-direction[:, 1], direction[:, 0]], 1)
    delta = np.bincount(who, np.abs((q * normal[who]).sum(1)), M) / count
    return c, direction, normal, delta, n


def match_lines_stereo(
    left: np.ndarray,
    right: np.ndarray,
    segments_left: np.ndarray,
    disparities,
    *,
    options: StereoMatchOptions = StereoMatchOptions(),
    executor=None,
) -> LineMatches:
    """Right segments of left segments ``(M, 2, 2)`` by sampled ZNCC matches and eq. 5;
    ``disparities`` as in :func:`match_points_stereo`, one range for all or ``(M, 2)``, one range
    a segment for all its samples; ``executor`` as there.

    Returns the right segments cut at the rows of the left endpoints, so that
    ``segments_left[i, k]`` and ``segments_right[i, k]`` are the same 3-D point.
    """
    plan = _LineSamples.of(segments_left, disparities, options)
    pm = match_points_stereo(
        left, right, plan.samples, plan.ranges, options=options, executor=executor
    )
    return plan.fit(pm, options)


@dataclass
class _LineSamples:
    """The pixels sampled along the steep segments of a frame (``samples`` ``(S, 2)``, the
    segment of each ``owner`` ``(S,)`` and its disparity range ``ranges`` ``(S, 2)``), searched
    as points; :meth:`fit` turns their matches into right segments."""

    seg: np.ndarray
    d: np.ndarray
    length: np.ndarray
    steep: np.ndarray
    samples: np.ndarray
    owner: np.ndarray
    ranges: np.ndarray

    @classmethod
    def of(cls, segments_left, disparities, options: StereoMatchOptions) -> _LineSamples:
        seg = np.asarray(segments_left, dtype=np.float64).reshape(-1, 2, 2)
        M = len(seg)
        d_seg = np.stack(_per_feature(disparities, M), 1)
        d, length, steep, n = _segment_sampling(seg, options)
        idx = np.nonzero(steep)[0]
        samples, owner_local = _line_samples(seg[idx], d[idx], n[idx])
        owner = idx[owner_local]
        return cls(seg, d, length, steep, samples, owner, d_seg[owner].reshape(-1, 2))

    def fit(self, pm: PointMatches, options: StereoMatchOptions) -> LineMatches:
        """Eq. 5 on the matches ``pm`` of :attr:`samples`."""
        seg, d, length, steep, owner = self.seg, self.d, self.length, self.steep, self.owner
        M = len(seg)
        out = np.full((M, 2, 2), np.nan)
        if not steep.any():
            return LineMatches(out, np.full(M, np.inf), np.zeros(M, int), np.zeros(M, bool))
        n_samples = np.bincount(owner, minlength=M)
        n_matched = np.bincount(owner[pm.ok], minlength=M)
        cand = (n_matched >= options.line_min_matches) & (2 * n_matched >= n_samples) & steep
        cos_eps = np.cos(np.radians(options.eps_theta_deg))
        sin_min = np.sin(np.radians(options.min_epipolar_angle_deg))
        use = pm.ok & cand[owner]
        c, direction, normal, delta, count = _tls_lines(owner, pm.pixels_right, use, M)
        if options.line_trim_px is not None:
            for scale in (3.0, 1.0):  # refit to the samples near the previous fit
                q = pm.pixels_right - c[owner]
                use = use & (np.abs((q * normal[owner]).sum(1)) <= scale * options.line_trim_px)
                c, direction, normal, delta, count = _tls_lines(owner, pm.pixels_right, use, M)
            cand = cand & (count >= options.line_min_matches) & (2 * count >= n_samples)
        fit_error = np.where(cand, delta, np.inf)
        cos_angle = np.abs((direction * d).sum(1)) / np.maximum(length, 1e-12)
        ok = (
            cand
            & (delta < options.eps_delta_px)
            & (cos_angle >= cos_eps)
            & (np.abs(direction[:, 1]) >= sin_min)
        )
        rows = seg[ok, :, 1]  # (k, 2): the right segment cut at the left endpoints' rows
        dirs = direction[ok]
        u_cut = c[ok, :1] + (rows - c[ok, 1:]) * (dirs[:, :1] / dirs[:, 1:])
        out[ok] = np.stack([u_cut, rows], 2)
        return LineMatches(out, fit_error, n_matched, ok)


def match_stereo(
    left: np.ndarray,
    right: np.ndarray,
    pixels_left: np.ndarray,
    point_disparities,
    segments_left: np.ndarray,
    line_disparities,
    *,
    options: StereoMatchOptions = StereoMatchOptions(),
    executor=None,
) -> tuple[PointMatches, LineMatches]:
    """The points (:func:`match_points_stereo`) and segments (:func:`match_lines_stereo`) of one
    frame, disparities as there.

    The points and the segments' samples are searched as one set of points, so ``executor``
    (e.g. a one-worker :class:`concurrent.futures.ThreadPoolExecutor`) shares all of them
    between the calling thread and its worker (:func:`_in_two_threads`: NumPy and OpenCV
    release the GIL for most of the work, so two cores overlap). A point's match does not
    depend on the points searched with it: the matches are the same either way.
    """
    L, Rimg = _as_float(left), _as_float(right)  # converted once for every call below
    p = np.asarray(pixels_left, dtype=np.float64).reshape(-1, 2)
    N = len(p)
    d_min, d_max = _per_feature(point_disparities, N)
    plan = _LineSamples.of(segments_left, line_disparities, options)
    both = match_points_stereo(
        L,
        Rimg,
        np.concatenate([p, plan.samples]),
        np.concatenate([np.stack([d_min, d_max], 1), plan.ranges.astype(np.int64)]),
        options=options,
        executor=executor,
    )
    pm = PointMatches(both.pixels_right[:N], both.score[:N], both.ok[:N])
    samples = PointMatches(both.pixels_right[N:], both.score[N:], both.ok[N:])
    return pm, plan.fit(samples, options)
