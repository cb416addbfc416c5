"""Undistortion of a whole image with the camera of ``camera.json`` (Sharma et al. 2018 assume
a rectified input). The maps are cached per camera, so a sequence pays for them once."""

from __future__ import annotations

import cv2
import numpy as np

from jaxpose.core.camera import PinholeCamera

__all__ = ["undistort_image"]

_MAPS: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}


def undistort_image(image: np.ndarray, camera: PinholeCamera) -> tuple[np.ndarray, PinholeCamera]:
    """The image seen by the ideal camera with the same ``K`` (no distortion), and that camera.

    Without distortion the image is returned as is.
    """
    image = np.asarray(image)
    if image.ndim not in (2, 3):
        raise ValueError(f"image must be (H, W) or (H, W, C); got shape {image.shape}")
    ideal = camera.without_distortion()
    if not camera.has_distortion():
        return image, ideal
    H, W = image.shape[:2]
    K = np.asarray(camera.K, dtype=float)
    dist = np.asarray(camera.dist, dtype=float)
    key = (H, W, *K.ravel().tolist(), *dist.tolist())
    if key not in _MAPS:
        if len(_MAPS) > 8:
            _MAPS.clear()
        _MAPS[key] = cv2.initUndistortRectifyMap(K, dist, None, K, (W, H), cv2.CV_16SC2)
    m1, m2 = _MAPS[key]
    return cv2.remap(image, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), ideal
