"""Coarse relative position from the ROI (Sharma et al. 2018 eqs. 6-9, Fig. 6).

Range (eq. 6): ``||t|| = ((fx + fy) / 2) L_C / l_ROI``. Direction (eqs. 7-9): the azimuth and
elevation of the ROI centre. Eq. 9 composes two rotations of ``[0, 0, ||t||]``; here the unit ray
through the ROI centre of the (undistorted) camera is used instead: the same direction to first
order, exact for any angle, and with the sign of an x-right camera (eq. 9 as printed gives
``x = -sin(alpha) ...``, which points the wrong way for ``B_x > C_x`` in OpenCV's frame).
"""

from __future__ import annotations

import numpy as np

from jaxpose.core.camera import PinholeCamera
from jaxpose.vision.roi import roi_diagonal

__all__ = ["coarse_position"]


def coarse_position(roi, camera: PinholeCamera, characteristic_length_m: float) -> np.ndarray:
    """``t_cam`` (3,) metres from an ROI ``[u0, v0, u1, v1]`` of an *undistorted* image."""
    l_roi = roi_diagonal(roi)
    if not l_roi > 0:
        raise ValueError(f"the ROI is empty: {list(roi)}")
    fx, fy, cx, cy = (float(v) for v in (camera.fx, camera.fy, camera.cx, camera.cy))
    rng = 0.5 * (fx + fy) * characteristic_length_m / l_roi  # eq. 6
    bx, by = 0.5 * (roi[0] + roi[2]), 0.5 * (roi[1] + roi[3])
    tan_a, tan_b = (bx - cx) / fx, (by - cy) / fy  # eqs. 7-8
    ray = np.array([tan_a, tan_b, 1.0])
    return rng * ray / np.linalg.norm(ray)  # eq. 9 (see module docstring)
