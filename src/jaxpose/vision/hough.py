"""Line segments by the probabilistic Hough transform, with hyper-parameters scaled by the ROI
(Sharma et al. 2018 eqs. 5 and 10): ``l_min = kappa_a l_ROI``, ``gap = kappa_b l_ROI``.

* WGE stream (:func:`wge_hough`): Hough on the binary WGE image (short features, antennas).
* Sobel stream (:func:`sobel_hough`): Sobel edges (Canny's non-maximum suppression of the Sobel
  gradient, thresholds from the gradient's percentiles, MATLAB's ``edge(I, 'sobel')`` also thins),
  then Hough; segments whose midpoint is outside the ROI are dropped.

Segments are ``(N, 2, 2)`` float arrays of pixel endpoints.
"""

from __future__ import annotations

import cv2
import numpy as np

from jaxpose.vision.roi import roi_diagonal

__all__ = ["hough_segments", "inside_roi", "sobel_hough", "wge_hough"]


def hough_segments(
    binary: np.ndarray, *, min_length: float, max_gap: float, votes: int | None = None
):
    """``cv2.HoughLinesP`` on a binary uint8 image (1 px, 1 deg resolution)."""
    min_length = max(float(min_length), 3.0)
    votes = int(votes if votes is not None else max(8, 0.5 * min_length))
    lines = cv2.HoughLinesP(
        binary, 1, np.pi / 180, votes, minLineLength=min_length, maxLineGap=max(float(max_gap), 1.0)
    )
    if lines is None:
        return np.zeros((0, 2, 2))
    return lines.reshape(-1, 2, 2).astype(float)


def inside_roi(segments: np.ndarray, roi, margin: float = 0.0) -> np.ndarray:
    """Mask of segments whose midpoint lies inside the ROI grown by ``margin`` pixels."""
    mid = segments.mean(1)
    u0, v0, u1, v1 = roi
    return (
        (mid[:, 0] >= u0 - margin)
        & (mid[:, 0] <= u1 + margin)
        & (mid[:, 1] >= v0 - margin)
        & (mid[:, 1] <= v1 + margin)
    )


def _crop(roi, shape, grow):
    H, W = shape
    u0, v0, u1, v1 = roi
    a, b = max(int(u0 - grow), 0), max(int(v0 - grow), 0)
    return a, b, min(int(u1 + grow) + 1, W), min(int(v1 + grow) + 1, H)


def wge_hough(
    binary: np.ndarray, roi, *, kappa1: float = 0.04, kappa2: float = 0.006, max_segments: int = 300
):
    """WGE stream (eq. 5) on the ROI grown by 5%. The WGE mask is thinned to one pixel
    (``cv2.ximgproc.thinning``) first: a thick gradient band otherwise gives many parallel
    copies of each edge."""
    l_roi = roi_diagonal(roi)
    a, b, c, d = _crop(roi, binary.shape, 0.05 * l_roi)
    crop = np.ascontiguousarray(binary[b:d, a:c])
    if crop.size == 0:
        return np.zeros((0, 2, 2))
    thin = cv2.ximgproc.thinning(crop) if hasattr(cv2, "ximgproc") else crop
    seg = hough_segments(thin, min_length=kappa1 * l_roi, max_gap=kappa2 * l_roi) + [a, b]
    return _longest(seg, max_segments)


def _longest(seg, n):
    length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
    return seg[np.argsort(-length, kind="stable")[:n]]


def sobel_hough(
    image: np.ndarray, roi, *, kappa3: float = 0.08, kappa4: float = 0.01, max_segments: int = 300
) -> np.ndarray:
    """Sobel stream (eq. 10): thinned Sobel edges, Hough, midpoints inside the ROI."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)
    mag = cv2.magnitude(gx, gy)
    u0, v0, u1, v1 = (int(round(x)) for x in roi)
    inner = mag[max(v0, 0) : v1 + 1, max(u0, 0) : u1 + 1]
    hi = float(np.percentile(inner, 90)) if inner.size else float(mag.max())
    hi = max(hi, 20.0)
    edges = cv2.Canny(gx.astype(np.int16), gy.astype(np.int16), 0.5 * hi, hi, L2gradient=True)
    l_roi = roi_diagonal(roi)
    a, b, c, d = _crop(roi, edges.shape, 0.05 * l_roi)
    seg = hough_segments(
        np.ascontiguousarray(edges[b:d, a:c]), min_length=kappa3 * l_roi, max_gap=kappa4 * l_roi
    )
    seg = seg + [a, b]
    return _longest(seg[inside_roi(seg, roi)], max_segments)
