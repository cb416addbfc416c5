"""A stereo frame's images and features, before the tracker's state comes in.

The checks of a pair (:func:`checked_pair`), the target's box and apparent area on a dark sky
(:func:`target_roi`, :func:`target_area`; :func:`lit_box`, the lines' box, which noise and
stars do not widen), the feature budget they set
(:func:`feature_options`) and the features stage itself (:func:`detect_features`: ORB points,
LSD segments with LBD descriptors). None of it depends on the poses or the map, only on the
images and the :class:`~jaxpose.pipelines.stereo.TrackerOptions`, so the next pair's features
may be extracted while this pair is tracked (:func:`~jaxpose.pipelines.stereo.track_stream`).
Beside them, the two rules that set the windowed adjustment by a depth the tracker measures, as
the feature budget is set by the measured area: its length (:func:`far_window`) and how often it
runs (:func:`window_cadence`); pure functions of that depth and the options.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from jaxpose.core.camera import StereoCamera
from jaxpose.pipelines.stereo.options import TrackerOptions
from jaxpose.vision.features import to_gray
from jaxpose.vision.stereo_features import DARK_LEVEL, FeatureOptions, FrameFeatures, extract
from jaxpose.vision.undistort import check_roi

__all__ = [
    "as_gray_uint8",
    "checked_pair",
    "detect_features",
    "feature_options",
    "fine_corners",
    "lit_box",
    "target_area",
    "target_roi",
    "window_cadence",
]


def target_roi(
    image: np.ndarray, *, threshold: int = DARK_LEVEL, step: int = 4
) -> np.ndarray | None:
    """Bounding box ``(u0, v0, u1, v1)`` of the pixels brighter than ``threshold`` (a target on a
    dark sky), from a ``step``-subsampled image; ``None`` when nothing is bright."""
    return _box(_grey(image)[::step, ::step] > threshold, step)


def _grey(image) -> np.ndarray:
    """``image`` as an array; ``ValueError`` naming it unless it is a grey ``(H, W)`` one."""
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image must be a grey (H, W) array; got shape {img.shape}")
    return img


def _box(lit: np.ndarray, step: int) -> np.ndarray | None:
    """Bounding box ``(u0, v0, u1, v1)``, pixels, of the true samples of ``lit`` (a
    ``step``-subsampled image's); ``None`` when fewer than four."""
    vv, uu = np.nonzero(lit)
    if len(uu) < 4:
        return None
    return np.array([uu.min(), vv.min(), uu.max() + 1, vv.max() + 1], float) * step


def lit_box(image: np.ndarray, *, threshold: int = DARK_LEVEL, step: int = 4) -> np.ndarray | None:
    """Bounding box ``(u0, v0, u1, v1)`` (pixels) of the target on a dark sky in a grey
    ``(H, W)`` image, one that sensor noise and stars do not widen: the ``step``-subsampled
    pixels brighter than ``threshold`` whose ``step x step`` block's mean is brighter too (not
    a lone noisy pixel) and which have a lit neighbour among their eight (not a star); ``None``
    when fewer than four remain. The tracker's lines are found in it
    (:func:`detect_features`); on the suite's noisy scenes :func:`target_roi` is the whole
    image."""
    img = _grey(image)
    h, w = img.shape[0] // step, img.shape[1] // step
    mean = cv2.resize(img[: h * step, : w * step], (w, h), interpolation=cv2.INTER_AREA)
    lit = (img[: h * step : step, : w * step : step] > threshold) & (mean > threshold)
    near = cv2.boxFilter(lit.astype(np.uint8), cv2.CV_16S, (3, 3), normalize=False)
    return _box(lit & (near >= 2), step)


def target_area(image: np.ndarray, *, threshold: int = DARK_LEVEL, step: int = 4) -> float:
    """Apparent area of the target, pixels: the pixels brighter than ``threshold`` (a target on a
    dark sky), counted on a ``step``-subsampled image."""
    small = _grey(image)[::step, ::step]
    return float(np.count_nonzero(small > threshold)) * step * step


def as_gray_uint8(image, name: str = "image") -> np.ndarray:
    """A 2-D ``uint8`` grayscale image by the library's one image convention
    (:func:`jaxpose.vision.features.to_gray`, as :func:`~jaxpose.initialise_pose` reads an
    image): ``(H, W)`` or BGR(A) ``(H, W, 3|4)``; ``uint8`` as is; ``uint16`` divided by 257;
    floats on the ``[0, 1]`` scale when their maximum is at most 1, otherwise on the 0-255 scale,
    non-finite pixels black. Raises ``ValueError`` naming ``name`` for another shape or a
    non-numeric image."""
    return to_gray(image, name)


def checked_pair(left, right, rig: StereoCamera) -> tuple[np.ndarray, np.ndarray]:
    """The pair as ``uint8`` grey images (:func:`as_gray_uint8`); ``ValueError`` naming the image
    for ``None`` (what ``cv2.imread`` returns for a file it cannot read) or a size other than
    the rig's."""
    for name, image in (("left", left), ("right", right)):
        if image is None:
            raise ValueError(f"the {name} image is None (a file that could not be read?)")
    left, right = np.asarray(left), np.asarray(right)
    H, W = rig.left.height, rig.left.width
    if left.shape[:2] != (H, W) or right.shape[:2] != (H, W):
        raise ValueError(
            f"images must be {W}x{H} (the rig's size); got {left.shape} and {right.shape}"
        )
    return as_gray_uint8(left, "left"), as_gray_uint8(right, "right")


def feature_options(
    options: TrackerOptions, target_area_px: float | None = None, *, fine: bool | None = None
) -> FeatureOptions:
    """The feature options of a frame whose target covers ``target_area_px`` pixels: the ORB
    budget at one keypoint per ``keypoint_spacing_px^2`` pixels of target (a constant keypoint
    density on the target, whatever its range and attitude), at least ``keypoint_floor`` (ORB's
    corners are repeatable from frame to frame only with a budget that keeps most of a small
    target's corners), and LSD's scale reduced by ``sqrt(lsd_area_px / target_area_px)`` on a
    target larger than ``lsd_area_px`` (at least 0.4). ``fine``: full-resolution corners at
    their response's sub-pixel peak (``None``: on a target of at least
    ``fine_corners_area_px``, :func:`fine_corners`)."""
    o = options
    if target_area_px is None:
        return o.features
    f = o.features
    if o.keypoint_spacing_px is not None:
        n = int(round(target_area_px / o.keypoint_spacing_px**2, -2))
        f = replace(f, n_points=min(f.n_points, max(o.keypoint_floor, n)))
    if o.lsd_area_px is not None and target_area_px > o.lsd_area_px:
        # LSD on about lsd_area_px pixels of target at the scale of the options: a near
        # target's edges are long, and LSD's time goes with the pixels it scans
        scale = f.lsd_scale * np.sqrt(o.lsd_area_px / target_area_px)
        f = replace(f, lsd_scale=round(float(max(scale, 0.4)), 2))
    if fine is None:
        fine = fine_corners(o, target_area_px)
    if fine:
        f = replace(f, orb_levels=1, subpixel="peak")
    return f


#: A sequence's keypoints leave the full-resolution corners (:func:`fine_corners`) only when the
#: target's apparent area falls below ``fine_corners_area_px`` divided by this. At one range
#: the area changes with the attitude by up to a fifth within a turn (1.2-1.23 times from the
#: smallest to the largest on the suite's scenes at 2-2.25 m), and each switch of kind costs:
#: the landmarks placed with one kind's pixels are then observed with the other's (a scene at
#: 2.25 m whose area grows through the threshold at frame 10: 6.0 mm worst axis against 3.4
#: with the pyramid and 2.1 with the full-resolution corners throughout). The band keeps a
#: sequence at one range from switching back and forth; the one switch stays.
FINE_CORNERS_BAND = 1.5
#: The far window (``TrackerOptions.window_frames_far``) is left only below ``window_far_m``
#: over this: the visible faces' median depth moves as the target turns (by up to its half-size,
#: a tenth of the range for the suite's 1 m target at 3 m), and a sequence at one range should
#: not switch back and forth.
WINDOW_FAR_BAND = 1.1


def fine_corners(
    options: TrackerOptions, target_area_px: float | None, previous: bool | None = None
) -> bool:
    """Whether a frame whose target covers ``target_area_px`` pixels takes full-resolution
    corners (``TrackerOptions.fine_corners_area_px``), with hysteresis: entered at the threshold,
    left below the threshold over :data:`FINE_CORNERS_BAND`, ``previous`` the last frame's
    choice (``None``: none yet)."""
    limit = options.fine_corners_area_px
    if limit is None or target_area_px is None:
        return False
    return bool(target_area_px >= (limit / FINE_CORNERS_BAND if previous else limit))


def detect_features(
    left: np.ndarray, options: TrackerOptions, *, roi=None, area=None, fine=None
) -> FrameFeatures:
    """The features of a left image (``uint8`` grey, as :func:`checked_pair` returns it): ORB
    points and, with ``options.use_lines``, LSD segments with LBD descriptors, within ``roi``
    (``[u0, v0, u1, v1]``, checked; default: :func:`target_roi` for the points, :func:`lit_box`
    for the lines, as LSD finds them on the whole image), at the budget of
    :func:`feature_options` for the image's :func:`target_area` (``area``, when measured
    already) and ``fine``."""
    line_roi = lit_box(left) if roi is None and options.use_lines else None
    roi = target_roi(left) if roi is None else check_roi(roi, left.shape)
    area = target_area(left) if area is None else area
    return extract(
        left,
        options=feature_options(options, area, fine=fine),
        roi=roi,
        line_roi=line_roi,
        lines=options.use_lines,
        threads=options.threads,
    )


def far_window(options: TrackerOptions, depth_m: float | None, previous: bool) -> bool:
    """Whether the window holds ``window_frames_far`` frames
    (``TrackerOptions.window_far_m``) after a frame whose inlier point landmarks lie at a
    median depth of ``depth_m`` metres, with hysteresis: entered at the threshold, left below
    it over :data:`WINDOW_FAR_BAND`, ``previous`` the choice so far; a frame without a
    measured depth (``None``, NaN) keeps it."""
    limit = options.window_far_m
    if limit is None:
        return False
    if depth_m is None or not np.isfinite(depth_m):
        return previous
    return bool(depth_m >= (limit / WINDOW_FAR_BAND if previous else limit))


def window_cadence(options: TrackerOptions, depth_m: float | None) -> int:
    """Frames between two windowed adjustments (``TrackerOptions.window_every``): ``floor(
    window_depth_m / depth_m)`` within ``[1, window_every]``, or ``window_every`` without
    ``window_depth_m`` or a positive ``depth_m`` (the depth of the map's origin at the last
    tracked frame: the target's centre from the truth, the first landmarks' median from the
    identity, :func:`~jaxpose.pipelines.stereo.landmarks.map_origin`). Near the target the
    single-frame poses are already good (many features, wide apparent size) and the adjustment
    is at its most expensive (the most landmarks). With a feature budget over the window
    (``budget_window``) every frame: the window is then the budgeted pose's estimator, and a
    small one (the budget's features)."""
    if options.feature_budget is not None and options.budget_window:
        return 1
    if options.window_depth_m is None or depth_m is None or not depth_m > 0:
        return options.window_every
    return int(min(options.window_every, max(1, np.floor(options.window_depth_m / depth_m))))
