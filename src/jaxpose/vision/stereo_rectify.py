"""Stereo rectification with OpenCV (``cv2.stereoRectify`` + ``cv2.initUndistortRectifyMap``).

It turns a :class:`jaxpose.core.camera.StereoCamera` into the maps that warp both images so that
epipolar lines become image rows, as the epipolar search of Yang et al. 2024 (Sec. 3) assumes when
it scans along a row.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from jaxpose.core.camera import PinholeCamera, StereoCamera

__all__ = ["Rectification", "rectify"]


@dataclass(frozen=True)
class Rectification:
    """Output of :func:`rectify` (OpenCV's names and meanings).

    ``R1, R2``: rotations from the unrectified to the rectified left/right camera frames;
    ``P1, P2``: ``3x4`` projection matrices of the rectified cameras
    (``P2[0, 3] = -fx * baseline``);
    ``Q``: ``4x4`` disparity-to-depth matrix; ``map_left``/``map_right``: ``(map_x, map_y)`` float32
    maps for ``cv2.remap``; ``size``: ``(width, height)``.
    """

    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    map_left: tuple[np.ndarray, np.ndarray]
    map_right: tuple[np.ndarray, np.ndarray]
    size: tuple[int, int]

    def remap(
        self, image_left: np.ndarray, image_right: np.ndarray, interpolation=cv2.INTER_LINEAR
    ):
        """Both images rectified with :func:`cv2.remap`."""
        return (
            cv2.remap(image_left, *self.map_left, interpolation),
            cv2.remap(image_right, *self.map_right, interpolation),
        )

    def rectified_camera(self) -> StereoCamera:
        """The ideal rig the rectified images come from (no distortion, pure x baseline)."""
        K = self.P1[:, :3]
        w, h = self.size
        cam = PinholeCamera.from_K(K, width=w, height=h)
        baseline = -self.P2[0, 3] / self.P2[0, 0]
        return StereoCamera.from_baseline(cam, float(baseline))


def _cv(camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(camera.K, dtype=np.float64), np.asarray(camera.dist, dtype=np.float64)


def rectify(rig: StereoCamera, *, alpha: float = 0.0) -> Rectification:
    """Rectification of ``rig`` for its image size (``left.width x left.height``).

    ``alpha`` is OpenCV's free scaling parameter (0: only valid pixels, 1: all source pixels).
    Raises ``ValueError`` when the image size is unknown.
    """
    w, h = rig.left.width, rig.left.height
    if w <= 0 or h <= 0:
        raise ValueError("rectify needs the image size: build the cameras with width and height")
    K1, d1 = _cv(rig.left)
    K2, d2 = _cv(rig.right)
    R = np.asarray(rig.R_rl, dtype=np.float64)
    T = np.asarray(rig.t_rl, dtype=np.float64).reshape(3, 1)
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        K1, d1, K2, d2, (w, h), R, T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha
    )
    map_l = cv2.initUndistortRectifyMap(K1, d1, R1, P1, (w, h), cv2.CV_32FC1)
    map_r = cv2.initUndistortRectifyMap(K2, d2, R2, P2, (w, h), cv2.CV_32FC1)
    return Rectification(R1, R2, P1, P2, Q, map_l, map_r, (w, h))
