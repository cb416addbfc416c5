"""LSD line segments (``cv2.createLineSegmentDetector``), a selectable alternative to the two
Hough streams: segments shorter than ``kappa l_ROI`` or with midpoints outside the ROI dropped."""

from __future__ import annotations

import cv2
import numpy as np

from jaxpose.vision.hough import inside_roi
from jaxpose.vision.roi import roi_diagonal

__all__ = ["lsd_segments"]

_LSD = []


def lsd_segments(image: np.ndarray, roi=None, *, kappa: float = 0.04) -> np.ndarray:
    """``(N, 2, 2)`` LSD segments of a grayscale uint8 image."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    if not _LSD:
        _LSD.append(cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD))
    lines = _LSD[0].detect(img)[0]
    if lines is None:
        return np.zeros((0, 2, 2))
    seg = lines.reshape(-1, 2, 2).astype(float)
    if roi is not None:
        l_roi = roi_diagonal(roi)
        length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
        seg = seg[inside_roi(seg, roi) & (length >= kappa * l_roi)]
    return seg
