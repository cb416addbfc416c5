"""Point and line features of the stereo tracker (Yang et al. 2024, Sec. 2), with OpenCV.

* Points: ORB (``cv2.ORB_create``), matched frame to frame by Hamming KNN with a ratio test, the
  survivors screened by RANSAC on the fundamental matrix (a tumbling rigid target seen by a
  hovering chaser is a rigid relative motion, so inliers obey one epipolar geometry).
* Lines: LSD (``cv2.line_descriptor.LSDDetector``, von Gioi et al.'s detector), kept when
  ``L > mu min(W, H)`` (eq. 1); LBD descriptors (``cv2.line_descriptor.BinaryDescriptor``: the
  72-float LBD binarised to 256 bits, 32 bytes, as the paper does); Hamming KNN with ``k = 2``
  (eq. 2) and a ratio test (eq. 3).

Eq. 3 as printed keeps a match when ``d1 / d2 > eps_match``, which would keep *ambiguous* matches
(``d1 <= d2`` always); we read it as Lowe's test with the ratio the other way up, i.e. keep when
``d1 / d2 < ratio`` (equivalently the "confidence" ``d2 / d1 > 1 / ratio``).

Both detectors run on the whole image or inside an optional ``roi`` box ``(u0, v0, u1, v1)``,
which saves most of the LSD time on a dark-sky background: LSD on the box and 8 pixels around it,
ORB on the box and the margin its pyramid needs (:func:`_orb_margin`, 113 pixels at 8 levels).
Arrays handed on are float64 pixels ``(u, v)`` with the pixel-centre convention of
:mod:`jaxpose.core.camera`.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from fractions import Fraction

import cv2
import numpy as np
import numpy.typing as npt

from jaxpose.core._checks import check_fields

__all__ = [
    "DARK_LEVEL",
    "FeatureOptions",
    "FrameFeatures",
    "detect_lines",
    "detect_points",
    "extract",
    "knn_ratio_match",
    "knn_ratio_match_pairs",
    "match_lines",
    "match_points",
    "match_points_guided",
    "ransac_filter",
]


#: Grey level (0-255) below which a pixel is the dark sky a target is seen on (or deep shadow):
#: the stereo tracker's target box and area (``jaxpose.pipelines.stereo.target_roi``) and the
#: keypoints dropped by ``FeatureOptions.dark_margin_px``.
DARK_LEVEL = 10


@dataclass(frozen=True)
class FeatureOptions:
    """Hyper-parameters of the features (defaults tuned on the rendered stereo sequences).

    Attributes:
        n_points: ORB budget per image.
        orb_fast_threshold: FAST threshold of ORB (lower finds corners on dim panels).
        mu: eq. 1 length factor; lines shorter than ``mu min(W, H)`` are dropped. The stereo
            tracker's line stereo search (:func:`~jaxpose.vision.stereo_match.match_lines_stereo`)
            needs ``line_min_matches`` samples ``line_step_px`` apart, so it matches only segments
            of at least 40 px by default (30.7 px at ``mu = 0.04`` on a 768-row image): a lower
            ``mu`` alone adds segments that no line landmark is made of.
        point_ratio, line_ratio: ratio-test thresholds (eq. 3 read as Lowe's test).
        max_hamming_point, max_hamming_line: absolute Hamming caps on the best match (bits).
        ransac_px: RANSAC threshold of the fundamental-matrix screening (pixels).
        max_lines: keep at most this many lines (the longest).
        subpixel: ``True``: refine ORB keypoints with ``cv2.cornerSubPix``, half-window
            ``subpixel_half_window`` (5: an 11x11 window). The window moves the keypoints and
            pulls nearby corners and the same corner found on several pyramid levels to one
            point, and the points it finds move with the view in a way that biases the
            tracker's poses, the more the larger the window (``bench/stereo_frame_bias.py``:
            with 15x15, the default until 2026-11, the 3 m blurred development scene's frames
            were a median 4.2, 12.9, 10.1 times their bound off about x, y, z, 1.7, 5.7, 6.5
            with 11x11); a small one is noisy on blurred corners (7x7 missed the 5 m scene on
            both seeds tried). Chosen on the development scenes over noise seeds 0-5
            (docs/stereo-evaluation.md, *The corner refinement's window*). ``"peak"``: the
            sub-pixel peak of the Shi-Tomasi response (3 x 3 blocks) within half a pixel of the
            keypoint's nearest whole pixel (no keypoint moves to another corner; meant with few
            pyramid levels: the stereo tracker's default is three, ``TrackerOptions.features``).
            ``False``: the keypoints as ORB returns them.
        orb_levels: ORB's pyramid levels (``nlevels``, scale 1.2 between levels); 1 keeps the
            FAST corners of the full-resolution image only (whole-pixel positions without
            ``subpixel``).
        twin_px: in the stereo tracker's search by projection, keypoints closer than this
            (pixels) to the best candidate are the same corner found again, not rivals in the
            ratio test, and landmarks predicted that close to each other that claim one keypoint
            leave it to the nearest in Hamming distance instead of all losing it
            (:func:`knn_ratio_match_pairs`, ``twins``); 0: every candidate is a rival.
        lsd_scale: LSD runs on the image resampled by this factor (Gaussian blur then
            ``cv2.resize``; LSD's own default is 0.8); its time goes with the square of the
            scale. The segments are returned in full-resolution pixels either way.
        dark_margin_px: keypoints with a pixel darker than :data:`DARK_LEVEL` (the sky the
            target is seen on, or a face in deep shadow) within this many pixels (a square
            window of half-width ``dark_margin_px`` about the keypoint's nearest whole pixel,
            the corner refinement's window at the default 5) are dropped. Such a corner lies on
            the target's outline or a shadow's edge, not on a mark of the surface: its window
            holds sky (or shadow) whose appearance does not turn with the surface, so the point
            found there slides over the target as it turns. Measured with ray-cast ground truth
            (``bench/stereo_frame_bias.py``, ``by_surface``): at 4-5 m those observations of
            the first frame's landmarks err by a median 0.72-0.81 px against 0.43-0.58 px on
            the faces, with a mean of 0.14-0.39 px in one direction. ``None`` (the default):
            keep every keypoint. Not the stereo tracker's default: at 5, the worst axes of its
            4-5 m development scenes fall by 14% summed over three noise seeds, but those of
            the 1.5-3 m scenes rise by 33% (on 9 of 12 runs; ``docs/stereo-evaluation.md``,
            *Keypoints beside the dark sky*).
    """

    n_points: int = 1200
    orb_fast_threshold: int = 12
    mu: float = 0.04
    point_ratio: float = 0.8
    line_ratio: float = 0.8
    max_hamming_point: int = 64
    max_hamming_line: int = 80
    ransac_px: float = 1.5
    max_lines: int = 120
    subpixel: bool | str = True
    subpixel_half_window: int = 5
    orb_levels: int = 8
    twin_px: float = 0.0
    lsd_scale: float = 0.8
    dark_margin_px: int | None = None

    def __post_init__(self):
        check_fields(
            self,
            integers={
                "n_points": 1,
                "orb_fast_threshold": 1,
                "max_hamming_point": 0,
                "max_hamming_line": 0,
                "max_lines": 0,
                "subpixel_half_window": 1,
                "orb_levels": 1,
                "dark_margin_px": 0,
            },
            positive=("ransac_px", "lsd_scale"),
            non_negative=("mu", "twin_px"),
            fractions=("point_ratio", "line_ratio"),
            optional=("dark_margin_px",),
        )
        if self.subpixel not in (True, False, "peak"):
            raise ValueError(f'subpixel must be True, False or "peak"; got {self.subpixel!r}')
        if not self.orb_levels <= 16:
            raise ValueError(f"orb_levels must be an integer in [1, 16]; got {self.orb_levels!r}")
        if not 0.1 <= self.lsd_scale <= 1.0:
            raise ValueError(f"lsd_scale must be in [0.1, 1]; got {self.lsd_scale}")


@dataclass
class FrameFeatures:
    """Features of one (left) image.

    Attributes:
        points: ``(N, 2)`` keypoint pixels.
        point_desc: ``(N, 32)`` uint8 ORB descriptors.
        segments: ``(M, 2, 2)`` line segments (start, end) in pixels.
        line_desc: ``(M, 32)`` uint8 LBD descriptors (256 bits).
        point_response: ``(N,)`` ORB (Harris) responses of the keypoints, or ``None``.
    """

    points: np.ndarray
    point_desc: np.ndarray
    segments: np.ndarray
    line_desc: np.ndarray
    point_response: np.ndarray | None = None


def _gray(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.ndim != 2 or img.size == 0:
        raise ValueError(
            f"expected a non-empty grayscale or BGR image; got shape {np.shape(image)}"
        )
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    return img


def _roi_slice(shape, roi, pad: int = 8):
    H, W = shape
    if roi is None:
        return 0, 0, W, H
    u0, v0, u1, v1 = (float(x) for x in roi)
    if not np.all(np.isfinite([u0, v0, u1, v1])):
        return 0, 0, W, H
    u0, v0 = max(0, int(u0) - pad), max(0, int(v0) - pad)
    u1, v1 = min(W, int(np.ceil(u1)) + pad + 1), min(H, int(np.ceil(v1)) + pad + 1)
    if u1 - u0 < 16 or v1 - v0 < 16:
        return 0, 0, W, H
    return u0, v0, u1, v1


_ORB: dict = {}


def _orb_margin(orb) -> int:
    """Pixels of image kept around a region of interest for the detector ``orb``: ORB drops
    every keypoint within its edge threshold (31 pixels *of the keypoint's pyramid level*,
    ``31 * 1.2^level`` at full resolution, at OpenCV's defaults) of the image it is given, so a
    crop that hugs the target would lose the corners of its outline, and at range most of them
    (on the 5 m development scene 430-950 keypoints a frame with an 8-pixel margin, as the box
    happened to fall, against 1000 with this one). 113 pixels at 8 levels."""
    top = orb.getScaleFactor() ** (orb.getNLevels() - 1)
    return int(np.ceil(orb.getEdgeThreshold() * top)) + 1


_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.01)
_LBD: list = []


def detect_points(
    image: np.ndarray,
    *,
    options: FeatureOptions = FeatureOptions(),
    roi=None,
    response: bool = False,
):
    """ORB keypoints ``(N, 2)`` and descriptors ``(N, 32)`` uint8 of a grayscale image (and, with
    ``response=True``, their ORB responses ``(N,)``); with ``roi``, those ORB finds on the whole
    image that lie in the box (up to the coarse levels' pixel grid, which starts at the crop)."""
    img = _gray(image)
    key = (options.n_points, options.orb_fast_threshold, options.orb_levels)
    if key not in _ORB:
        _ORB[key] = cv2.ORB_create(
            nfeatures=options.n_points,
            fastThreshold=options.orb_fast_threshold,
            nlevels=options.orb_levels,
        )
    orb = _ORB[key]
    u0, v0, u1, v1 = _roi_slice(img.shape, roi, _orb_margin(orb))
    crop = np.ascontiguousarray(img[v0:v1, u0:u1])
    kps, desc = orb.detectAndCompute(crop, None)
    if desc is None or not kps:
        empty = np.zeros((0, 2)), np.zeros((0, 32), np.uint8)
        return (*empty, np.zeros(0)) if response else empty
    pts = np.array([k.pt for k in kps], dtype=np.float32).reshape(-1, 1, 2)
    if options.subpixel == "peak":
        pts = _response_peak(crop, pts)
    elif options.subpixel:
        # ORB keypoints sit on the FAST grid of their pyramid level (1.2^k px); refine at full
        # resolution (Foerstner corner) so that stereo depth and frame-to-frame pixels agree
        w = int(options.subpixel_half_window)
        pts = cv2.cornerSubPix(crop, pts, (w, w), (-1, -1), _SUBPIX_CRITERIA)
    pts = pts.reshape(-1, 2).astype(np.float64)
    keep = slice(None)  # every keypoint
    if options.dark_margin_px is not None:
        keep = ~_near_dark(crop, pts, options.dark_margin_px)
        pts, desc = pts[keep], desc[keep]
    pts += [u0, v0]
    if not response:
        return pts, desc
    return pts, desc, np.array([k.response for k in kps], np.float64)[keep]


def _near_dark(image: np.ndarray, pts: np.ndarray, margin: int) -> np.ndarray:
    """``(N,)`` whether a pixel darker than :data:`DARK_LEVEL` lies within ``margin`` pixels
    (a ``2 margin + 1`` square) of each keypoint's nearest whole pixel in ``image``."""
    H, W = image.shape
    u = np.clip(np.rint(pts[:, 0]).astype(np.int64), 0, W - 1)
    v = np.clip(np.rint(pts[:, 1]).astype(np.int64), 0, H - 1)
    # the window's minimum (a grey erosion; pixels beyond the border do not count)
    low = cv2.erode(image, np.ones((2 * margin + 1, 2 * margin + 1), np.uint8))
    return low[v, u] < DARK_LEVEL


def _response_peak(crop: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Keypoints ``(N, 1, 2)`` moved to the sub-pixel peak of the Shi-Tomasi corner response
    (3 x 3 blocks) around their nearest whole pixel (:func:`_parabola_peak`)."""
    return _parabola_peak(cv2.cornerMinEigenVal(crop, 3, 3), pts.reshape(-1, 2)).reshape(-1, 1, 2)


def _parabola_peak(r: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Sub-pixel peaks ``(N, 2)`` float32 of the map ``r (H, W)`` near the pixels ``p (N, 2)``:
    from the nearest whole pixel, along each axis the vertex of the parabola through the map
    there and at its two neighbours, kept within half a pixel (none where the parabola opens
    upward). Exact for a map that is quadratic in each axis."""
    H, W = r.shape
    u = np.clip(np.rint(p[:, 0]).astype(int), 1, W - 2)
    v = np.clip(np.rint(p[:, 1]).astype(int), 1, H - 2)
    out = np.stack([u, v], 1).astype(np.float64)
    for axis, (du, dv) in enumerate(((1, 0), (0, 1))):
        a, b, c = r[v - dv, u - du], r[v, u], r[v + dv, u + du]
        den = a - 2 * b + c
        with np.errstate(divide="ignore", invalid="ignore"):
            off = np.where(den < 0, 0.5 * (a - c) / den, 0.0)
        out[:, axis] += np.clip(np.nan_to_num(off), -0.5, 0.5)
    return out.astype(np.float32)


def _lsd(scale: float, log_eps: float = 0.0):
    """OpenCV's LSD at ``scale`` with detection threshold ``log_eps`` (``-log10 NFA`` a segment
    must exceed; LSD's default 0), made afresh (well under a microsecond), and the LBD
    descriptor."""
    param = cv2.line_descriptor.LSDParam()
    param.scale = scale
    param.log_eps = log_eps
    if not _LBD:
        _LBD.append(cv2.line_descriptor.BinaryDescriptor.createBinaryDescriptor())
    return cv2.line_descriptor.LSDDetector.createLSDDetectorWithParams(param)


def _lsd_box(shape, roi, scale: float) -> tuple[tuple[int, int, int, int], float]:
    """The crop ``(u0, v0, u1, v1)`` in which LSD at ``scale`` finds the segments it finds on
    the whole image (of ``shape``) within ``roi`` (padded by 16 pixels), and the detection
    threshold that makes it so. LSD's result depends on its image in two ways beyond the
    pixels near a segment. (1) It resamples by ``scale`` on a grid that starts at the image's
    corner: the crop's corner is snapped to a multiple of ``q`` pixels, ``scale``'s denominator
    (5 at 0.8), so that the crop's grid is the whole image's. (2) It accepts a segment whose
    number of false alarms is below 1 (``log_eps = 0``) with a number of tests that grows as
    ``(X Y)^(5/2)`` with the resampled image's size (Grompone von Gioi et al., *LSD: a Line
    Segment Detector*, IPOL 2012): on the crop, ``log_eps = 2.5 log10(X Y / (x y))`` keeps
    the whole image's test. On the suite's development frames the segments longer than eq. 1's
    minimum were those of the whole image, one in a few hundred missing or added, at 4-6 times
    less time where the target is small. No ``roi``: the whole image, ``log_eps = 0``."""
    H, W = shape
    u0, v0, u1, v1 = _roi_slice(shape, roi, pad=16)
    if (u0, v0, u1, v1) == (0, 0, W, H):
        return (0, 0, W, H), 0.0
    q = Fraction(scale).limit_denominator(1000).denominator
    if q <= 100:  # a coarser grid than that costs more than it keeps
        u0, v0 = u0 // q * q, v0 // q * q
        u1, v1 = min(W, -(-u1 // q) * q), min(H, -(-v1 // q) * q)

    def tests(w, h):  # log10 of the resampled image's pixel count, cv2.resize's rounding
        return np.log10(max(1, round(w * scale)) * max(1, round(h * scale)))

    return (u0, v0, u1, v1), 2.5 * float(tests(W, H) - tests(u1 - u0, v1 - v0))


def detect_lines(image: np.ndarray, *, options: FeatureOptions = FeatureOptions(), roi=None):
    """LSD segments ``(M, 2, 2)`` longer than ``mu min(W, H)`` (eq. 1) and their LBD descriptors.

    ``W, H`` are the full image's size whatever the ``roi``; with ``roi``, the segments LSD
    finds on the whole image within the box (padded by 16 pixels), found on a crop
    (:func:`_lsd_box`). LSD resamples the image by
    ``options.lsd_scale`` with ``cv2.resize`` (pixel centres aligned: the scaled pixel ``x_s``
    lies at ``(x_s + 0.5) / s - 0.5``) but maps its segments back by ``x_s / s`` alone, which
    shifts them by ``0.5 / s - 0.5`` pixels along both axes (-0.125 px at LSD's default 0.8);
    that shift is added back here.
    """
    img = _gray(image)
    scale = round(float(options.lsd_scale), 3)
    H, W = img.shape
    (u0, v0, u1, v1), log_eps = _lsd_box(img.shape, roi, scale)
    lsd = _lsd(scale, log_eps)
    crop = np.ascontiguousarray(img[v0:v1, u0:u1])
    keylines = lsd.detect(crop, 2, 1)
    min_len = options.mu * min(W, H)
    keylines = [k for k in keylines if k.octave == 0 and k.lineLength > min_len]
    keylines.sort(key=lambda k: -k.lineLength)
    keylines = keylines[: options.max_lines]
    for i, k in enumerate(keylines):
        k.class_id = i
    if not keylines:
        return np.zeros((0, 2, 2)), np.zeros((0, 32), np.uint8)
    keylines, desc = _LBD[0].compute(crop, keylines)
    if desc is None or not keylines:
        return np.zeros((0, 2, 2)), np.zeros((0, 32), np.uint8)
    seg = np.array(
        [[[k.startPointX, k.startPointY], [k.endPointX, k.endPointY]] for k in keylines],
        dtype=np.float64,
    )
    shift = 0.5 / scale - 0.5 if scale != 1.0 else 0.0
    return seg + [u0 + shift, v0 + shift], np.asarray(desc, np.uint8)


_POOL: list = []


def extract(
    image: np.ndarray,
    *,
    options: FeatureOptions = FeatureOptions(),
    roi=None,
    lines: bool = True,
    threads: bool = True,
    line_roi=None,
):
    """:class:`FrameFeatures` of one image (``lines=False`` for the points-only mode).

    ``threads``: detect the lines (LSD + LBD) in a second thread while the points (ORB +
    ``cornerSubPix``) are detected in this one. Both are OpenCV calls that release the GIL, so on
    two cores the two detectors' wall times overlap (about 20 ms each at 2 m); the features are
    the same either way. ``line_roi``: the lines' own box (default ``roi``)."""
    line_roi = roi if line_roi is None else line_roi
    if lines and threads:
        if not _POOL:
            _POOL.append(ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxpose-lsd"))
        pending = _POOL[0].submit(detect_lines, image, options=options, roi=line_roi)
        pts, pdesc, resp = detect_points(image, options=options, roi=roi, response=True)
        seg, ldesc = pending.result()
    elif lines:
        pts, pdesc, resp = detect_points(image, options=options, roi=roi, response=True)
        seg, ldesc = detect_lines(image, options=options, roi=line_roi)
    else:
        pts, pdesc, resp = detect_points(image, options=options, roi=roi, response=True)
        seg, ldesc = np.zeros((0, 2, 2)), np.zeros((0, 32), np.uint8)
    return FrameFeatures(pts, pdesc, seg, ldesc, resp)


_BF: list = []


def knn_ratio_match(
    desc_ref: np.ndarray, desc_cur: np.ndarray, *, ratio: float, max_distance: int, allowed=None
):
    """Hamming KNN (``k = 2``, eq. 2) with the ratio test (eq. 3), one-to-one.

    ``allowed`` (optional ``(n_ref, n_cur)`` bool) restricts the candidates of each reference
    descriptor (guided matching: only current features near the predicted position); a lone
    candidate passes the ratio test. Returns ``(i_ref, i_cur)`` int arrays of the kept pairs,
    each index used at most once.
    """
    if len(desc_ref) == 0 or len(desc_cur) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    if allowed is not None:
        pairs = _sparse_knn(desc_ref, desc_cur, np.asarray(allowed, bool), ratio, max_distance)
    else:
        if not _BF:
            _BF.append(cv2.BFMatcher(cv2.NORM_HAMMING))
        pairs = []
        for knn in _BF[0].knnMatch(desc_ref, desc_cur, k=2):
            if not knn:
                continue
            a = knn[0]
            if a.distance > max_distance:
                continue
            if len(knn) < 2 or a.distance < ratio * knn[1].distance:
                pairs.append((a.queryIdx, a.trainIdx))
        pairs = np.array(pairs, dtype=int).reshape(-1, 2)
    return _one_to_one(pairs)


_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.int32)


def _sparse_knn(desc_ref, desc_cur, allowed, ratio, max_distance) -> np.ndarray:
    """Best and second-best Hamming distance of each reference descriptor among its allowed
    candidates only (vectorised over the candidate pairs); the ratio test of eq. 3. ``(K, 2)``."""
    i_ref, i_cur = np.nonzero(allowed)
    return _pairs_knn(desc_ref, desc_cur, i_ref, i_cur, ratio, max_distance)[0]


def _hamming(desc_ref, desc_cur, i_ref, i_cur) -> np.ndarray:
    """Hamming distances ``(K,)`` between the descriptor pairs ``(i_ref[k], i_cur[k])``: XOR and
    popcount on 64-bit words (``np.bitwise_count``, NumPy >= 2) or a byte table. ``desc_ref``
    ``(M, 32)``, or ``(M, S, 32)``: ``S`` descriptors a reference feature (a landmark's recent
    observations), the distance then the smallest of its ``S``."""
    a, b = np.ascontiguousarray(desc_ref), np.ascontiguousarray(desc_cur)
    if a.ndim == 3:
        S = a.shape[1]
        pairs = np.arange(len(i_ref) * S)
        d = _hamming(
            a[np.asarray(i_ref, int)].reshape(-1, a.shape[2]),
            np.repeat(b[np.asarray(i_cur, int)], S, axis=0),
            pairs,
            pairs,
        )
        return d.reshape(-1, S).min(1)
    if (
        _BITWISE_COUNT is not None
        and a.dtype == b.dtype == np.uint8
        and a.shape[1] == b.shape[1]
        and a.shape[1] % 8 == 0
    ):
        x = np.bitwise_xor(a.view(np.uint64)[i_ref], b.view(np.uint64)[i_cur])
        return _BITWISE_COUNT(x).sum(1, dtype=np.int64)
    return _POPCOUNT[np.bitwise_xor(a[i_ref], b[i_cur])].sum(1, dtype=np.int64)


_BITWISE_COUNT = getattr(np, "bitwise_count", None)


def _pairs_knn(desc_ref, desc_cur, i_ref, i_cur, ratio, max_distance, twins=None):
    """Ratio test of each reference feature over its candidate pairs: the ``(K, 2)`` pairs kept
    and their ``(K,)`` Hamming distances. ``twins = (points_cur, radius)``: a
    candidate within ``radius`` pixels of the best one is the same corner found again (ORB's
    pyramid levels, the sub-pixel refinement), not a rival, and is left out of the second best."""
    if len(i_ref) == 0:
        return np.zeros((0, 2), int), np.zeros(0, int)
    dist = _hamming(desc_ref, desc_cur, i_ref, i_cur)
    # by reference feature, then distance (one stable integer sort; distances are <= 256)
    order = np.argsort(i_ref * 512 + dist, kind="stable")
    i_ref, i_cur, dist = i_ref[order], i_cur[order], dist[order]
    first = np.r_[True, i_ref[1:] != i_ref[:-1]]
    starts = np.nonzero(first)[0]
    if twins is None:
        has_second = np.r_[starts[1:] - starts[:-1] > 1, len(i_ref) - starts[-1] > 1]
        second = np.where(has_second, dist[np.minimum(starts + 1, len(dist) - 1)], np.inf)
    else:
        points_cur, radius = twins
        group = np.cumsum(first) - 1
        best_at = np.asarray(points_cur, float)[i_cur[starts]][group]
        apart = np.linalg.norm(np.asarray(points_cur, float)[i_cur] - best_at, axis=1) > radius
        second = np.minimum.reduceat(np.where(apart, dist, np.inf), starts)
    best = dist[starts]
    keep = (best <= max_distance) & (best < ratio * second)
    return np.stack([i_ref[starts][keep], i_cur[starts][keep]], 1), best[keep]


def knn_ratio_match_pairs(
    desc_ref: np.ndarray,
    desc_cur: np.ndarray,
    i_ref: npt.ArrayLike,
    i_cur: npt.ArrayLike,
    *,
    ratio: float,
    max_distance: int,
    twins: tuple[np.ndarray, np.ndarray, float] | None = None,
):
    """:func:`knn_ratio_match` over explicit candidate pairs ``(i_ref[j], i_cur[j])`` (e.g. from
    a k-d tree radius search) instead of a dense ``allowed`` matrix; one-to-one. ``desc_ref``
    ``(M, 32)`` or ``(M, S, 32)`` (``S`` descriptors a reference feature, the nearest counts).

    ``twins = (points_ref, points_cur, radius)``: pixels of the reference and current features
    and a radius within which two features are the same corner found twice. A candidate that
    close to the best is then no rival in the ratio test, and of several reference features that
    claim one current feature from within ``radius`` of each other the nearest in Hamming
    distance keeps it (else, and without ``twins``, all of them lose it)."""
    i_ref, i_cur = np.asarray(i_ref, int), np.asarray(i_cur, int)
    if len(i_ref) != len(i_cur):
        raise ValueError("i_ref and i_cur must have the same length")
    if twins is None:
        return _one_to_one(_pairs_knn(desc_ref, desc_cur, i_ref, i_cur, ratio, max_distance)[0])
    points_ref, points_cur, radius = twins
    pairs, dist = _pairs_knn(
        desc_ref, desc_cur, i_ref, i_cur, ratio, max_distance, (points_cur, radius)
    )
    return _one_to_one_twins(pairs, dist, np.asarray(points_ref, float), radius)


def _one_to_one_twins(pairs: np.ndarray, dist: np.ndarray, points_ref: np.ndarray, radius):
    """:func:`_one_to_one`, but a current feature claimed only by reference features within
    ``radius`` pixels of the nearest claimant (in Hamming distance) goes to that one."""
    if len(pairs) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    order = np.lexsort((dist, pairs[:, 1]))  # by current feature, then distance
    pairs, dist = pairs[order], dist[order]
    first = np.r_[True, pairs[1:, 1] != pairs[:-1, 1]]
    group = np.cumsum(first) - 1
    winner = np.nonzero(first)[0]
    off = np.linalg.norm(points_ref[pairs[:, 0]] - points_ref[pairs[winner[group], 0]], axis=1)
    rivals = np.zeros(len(winner), bool)
    np.logical_or.at(rivals, group, off > radius)
    kept = pairs[winner[~rivals]]
    kept = kept[np.argsort(kept[:, 0], kind="stable")]  # by reference feature, as _one_to_one
    return kept[:, 0], kept[:, 1]


def _one_to_one(pairs: np.ndarray):
    """Drop current features claimed by several reference features."""
    if len(pairs) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    _, first, counts = np.unique(pairs[:, 1], return_index=True, return_counts=True)
    keep = first[counts == 1]
    keep.sort()
    return pairs[keep, 0], pairs[keep, 1]


def match_points(
    points_ref: np.ndarray,
    desc_ref: np.ndarray,
    points_cur: np.ndarray,
    desc_cur: np.ndarray,
    *,
    options: FeatureOptions = FeatureOptions(),
    ransac: bool = True,
):
    """ORB matches frame to frame: ratio test, then RANSAC on the fundamental matrix.

    Returns ``(i_ref, i_cur)``. With fewer than 8 ratio-test survivors RANSAC is skipped.
    """
    i_ref, i_cur = knn_ratio_match(
        desc_ref, desc_cur, ratio=options.point_ratio, max_distance=options.max_hamming_point
    )
    if ransac:
        i_ref, i_cur = ransac_filter(points_ref, points_cur, i_ref, i_cur, options=options)
    return i_ref, i_cur


def ransac_filter(
    points_ref, points_cur, i_ref, i_cur, *, options: FeatureOptions = FeatureOptions()
):
    """Keep the matches consistent with one fundamental matrix (``cv2.FM_RANSAC``, threshold
    ``options.ransac_px``); fewer than 8 matches pass unchanged."""
    if len(i_ref) < 8:
        return i_ref, i_cur
    _, inl = cv2.findFundamentalMat(
        points_ref[i_ref], points_cur[i_cur], cv2.FM_RANSAC, options.ransac_px, 0.999
    )
    if inl is None:
        return i_ref, i_cur
    keep = inl.ravel().astype(bool)
    return i_ref[keep], i_cur[keep]


def match_points_guided(
    predicted_ref: np.ndarray,
    desc_ref: np.ndarray,
    points_cur: np.ndarray,
    desc_cur: np.ndarray,
    *,
    radius_px: float,
    options: FeatureOptions = FeatureOptions(),
):
    """ORB matches searched near the predicted pixels of the reference features (search by
    projection, as ORB-SLAM tracks): ratio test among the current keypoints within
    ``radius_px`` of each prediction. Follow with :func:`ransac_filter` on the reference pixels.
    Returns ``(i_ref, i_cur)``."""
    if len(predicted_ref) == 0 or len(points_cur) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    p = np.asarray(predicted_ref, np.float32)
    q = np.asarray(points_cur, np.float32)
    dx = np.abs(p[:, None, 0] - q[None, :, 0])
    dy = np.abs(p[:, None, 1] - q[None, :, 1])
    allowed = (dx < radius_px) & (dy < radius_px)
    allowed &= dx * dx + dy * dy < radius_px**2
    i_ref, i_cur = knn_ratio_match(
        desc_ref,
        desc_cur,
        ratio=options.point_ratio,
        max_distance=options.max_hamming_point,
        allowed=allowed,
    )
    return i_ref, i_cur


def match_lines(
    desc_ref: np.ndarray,
    desc_cur: np.ndarray,
    *,
    options: FeatureOptions = FeatureOptions(),
    allowed=None,
):
    """LBD matches frame to frame (eqs. 2-3), optionally gated by ``allowed`` (see
    :func:`knn_ratio_match`). Returns ``(i_ref, i_cur)``."""
    return knn_ratio_match(
        desc_ref,
        desc_cur,
        ratio=options.line_ratio,
        max_distance=options.max_hamming_line,
        allowed=allowed,
    )
