"""Undistortion of a whole image with the camera of ``camera.json`` (Sharma et al. 2018 assume
a rectified input). The maps are cached per camera, so a sequence pays for them once."""

from __future__ import annotations

import cv2
import numpy as np

from jaxpose.core.camera import PinholeCamera

__all__ = ["check_roi", "undistort_box", "undistort_image"]

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


def check_roi(box, shape: tuple[int, ...]) -> np.ndarray:
    """The box ``[u0, v0, u1, v1]`` (pixels of an image of ``shape (H, W, ...)``) as four floats;
    ``ValueError`` naming ``roi`` when it is not four finite numbers with ``u0 < u1`` and
    ``v0 < v1``, or when it lies outside the image."""
    try:
        b = np.asarray(box, dtype=float)
    except (TypeError, ValueError):
        b = np.full(0, np.nan)
    if b.shape != (4,) or not np.all(np.isfinite(b)):
        raise ValueError(f"roi must be four finite numbers [u0, v0, u1, v1]; got {box!r}")
    u0, v0, u1, v1 = b
    if not (u0 < u1 and v0 < v1):
        raise ValueError(f"roi must have u0 < u1 and v0 < v1 (pixels); got {b.tolist()}")
    H, W = int(shape[0]), int(shape[1])
    if u1 <= 0 or v1 <= 0 or u0 >= W - 1 or v0 >= H - 1:
        raise ValueError(f"roi {b.tolist()} lies outside the {W}x{H} image")
    return b


def undistort_box(box, camera: PinholeCamera, shape: tuple[int, int]) -> np.ndarray:
    """The box ``[u0, v0, u1, v1]`` (pixels of the *distorted* image of ``shape (H, W)``) as the
    ideal camera of :func:`undistort_image` sees it: the bounding box of its outline (16 points a
    side) mapped through ``cv2.undistortPoints`` with ``P = K``, clipped to the image. Without
    distortion, the box clipped to the image.

    Raises ``ValueError`` naming ``roi`` as :func:`check_roi` does."""
    u0, v0, u1, v1 = check_roi(box, shape)
    H, W = int(shape[0]), int(shape[1])
    if camera.has_distortion():
        s = np.linspace(0.0, 1.0, 16)
        us, vs = u0 + s * (u1 - u0), v0 + s * (v1 - v0)
        pts = np.concatenate(
            [
                np.stack([us, np.full(16, v0)], 1),
                np.stack([us, np.full(16, v1)], 1),
                np.stack([np.full(16, u0), vs], 1),
                np.stack([np.full(16, u1), vs], 1),
            ]
        )
        K = np.asarray(camera.K, dtype=float)
        dist = np.asarray(camera.dist, dtype=float)
        ideal = cv2.undistortPoints(pts[:, None], K, dist, P=K)[:, 0]
        u0, v0 = ideal.min(0)
        u1, v1 = ideal.max(0)
    return np.array([max(u0, 0.0), max(v0, 0.0), min(u1, W - 1.0), min(v1, H - 1.0)], dtype=float)
