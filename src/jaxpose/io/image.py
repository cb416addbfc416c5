"""Image files."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from jaxpose.vision.features import to_gray

__all__ = ["load_image"]


def load_image(path) -> np.ndarray:
    """Read an image file as grayscale uint8 ``(H, W)`` (16-bit files scaled as
    :func:`jaxpose.vision.features.to_gray` does, so they give the same pose as their 8-bit
    version); ``ValueError`` if missing or unreadable."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"image not found: {path}")
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
    if img is None:
        raise ValueError(f"cannot read image {path} (not an image OpenCV can decode)")
    return to_gray(img)
