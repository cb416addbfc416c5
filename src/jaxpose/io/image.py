"""Image files."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

__all__ = ["load_image"]


def load_image(path) -> np.ndarray:
    """Read an image file as grayscale uint8; ``ValueError`` if missing or unreadable."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"image not found: {path}")
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise ValueError(f"cannot read image {path} (not an image OpenCV can decode)")
    return img
