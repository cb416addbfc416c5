"""Coarse relative position from the ROI (Sharma et al. 2018 eqs. 6-9, Fig. 6).

Range (eq. 6): ``||t|| = ((fx + fy) / 2) L_C / l_ROI``. Direction (eqs. 7-9): the azimuth and
elevation of the ROI centre. Eq. 9 composes two rotations of ``[0, 0, ||t||]``; here the unit ray
through the ROI centre of the (undistorted) camera is used instead: the same direction to first
order, exact for any angle, and with the sign of an x-right camera (eq. 9 as printed gives
``x = -sin(alpha) ...``, which points the wrong way for ``B_x > C_x`` in OpenCV's frame).

Eq. 6 assumes the whole target is seen. A ROI cut by the frame on one axis shows the target's
whole extent across that axis and only part of it along it: :func:`cut_diagonal` then estimates
the whole box's diagonal from the uncut side, the visible part of the cut one and the model's
projected boxes over uniform attitudes (:func:`projected_extents`).
"""

from __future__ import annotations

import numpy as np

from jaxpose.core.camera import PinholeCamera
from jaxpose.vision.roi import roi_diagonal

__all__ = ["coarse_position", "cut_diagonal", "model_extents", "projected_extents"]


def projected_extents(points_body, *, samples: int = 4000, seed: int = 0) -> np.ndarray:
    """``(samples, 2)`` widths and heights (metres) of the box of ``points_body (N, 3)`` under
    orthographic projection at ``samples`` attitudes drawn uniformly over SO(3) (normalised
    Gaussian quaternions, a fixed ``seed``): the prior of the projected box's shape."""
    P = np.asarray(points_body, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 2:
        raise ValueError(f"points_body must have shape (N >= 2, 3); got {P.shape}")
    if int(samples) < 1:
        raise ValueError(f"samples must be >= 1; got {samples}")
    q = np.random.default_rng(seed).normal(size=(int(samples), 4))
    w, x, y, z = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    # first two rows of the rotation matrix of each unit quaternion
    r0 = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], 1)
    r1 = np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], 1)
    u, v = r0 @ P.T, r1 @ P.T  # (S, N)
    return np.stack([np.ptp(u, axis=1), np.ptp(v, axis=1)], axis=1)


def model_extents(model) -> np.ndarray:
    """:func:`projected_extents` of a wireframe model's vertices and antenna tips (the points
    whose box is the target's box)."""
    pts = np.asarray(model.vertices, dtype=float)
    if len(model.antennas):
        pts = np.concatenate([pts, np.asarray(model.antenna_points, dtype=float).reshape(-1, 3)])
    return projected_extents(pts)


def cut_diagonal(roi, cut, extents, *, min_samples: int = 20) -> float:
    """The diagonal (pixels) of the whole projected target of a ROI ``[u0, v0, u1, v1]`` cut by
    the frame on the sides ``cut`` (left, top, right, bottom;
    :func:`jaxpose.vision.features.roi_cut`).

    Uncut, or cut on both axes: the ROI's own diagonal (a lower bound when cut). Cut on one axis:
    the uncut side ``a`` is the whole extent across, the cut side ``b`` at least the visible one.
    Among the model's projected boxes ``extents (S, 2)`` (:func:`projected_extents`) whose cut
    side over their uncut side is at least ``b / a`` (those that would show at least what is
    seen), the median of diagonal over uncut side, times ``a``; never less than the ROI's own
    diagonal, and the ROI's own diagonal when fewer than ``min_samples`` boxes qualify.
    """
    u0, v0, u1, v1 = (float(x) for x in roi)
    seen = roi_diagonal(roi)
    cut_u, cut_v = bool(cut[0] or cut[2]), bool(cut[1] or cut[3])
    if cut_u == cut_v:
        return seen
    E = np.asarray(extents, dtype=float).reshape(-1, 2)
    a, b = (u1 - u0, v1 - v0) if cut_v else (v1 - v0, u1 - u0)
    ea, eb = (E[:, 0], E[:, 1]) if cut_v else (E[:, 1], E[:, 0])
    ok = (ea > 0) & (eb >= (b / a) * ea) if a > 0 else np.zeros(len(E), bool)
    if ok.sum() < min_samples:
        return seen
    return max(seen, a * float(np.median(np.hypot(ea[ok], eb[ok]) / ea[ok])))


def coarse_position(
    roi,
    camera: PinholeCamera,
    characteristic_length_m: float,
    *,
    cut=None,
    extents=None,
) -> np.ndarray:
    """``t_cam`` (3,) metres from an ROI ``[u0, v0, u1, v1]`` of an *undistorted* image.

    With ``cut`` (the sides the ROI reaches) and ``extents`` (the model's projected boxes,
    :func:`projected_extents`), a ROI cut by the frame on one axis is read with the whole
    target's estimated diagonal (:func:`cut_diagonal`) instead of its own."""
    l_roi = roi_diagonal(roi)
    if not l_roi > 0:
        raise ValueError(f"the ROI is empty: {list(roi)}")
    if cut is not None and extents is not None:
        l_roi = cut_diagonal(roi, cut, extents)
    fx, fy, cx, cy = (float(v) for v in (camera.fx, camera.fy, camera.cx, camera.cy))
    rng = 0.5 * (fx + fy) * characteristic_length_m / l_roi  # eq. 6
    bx, by = 0.5 * (roi[0] + roi[2]), 0.5 * (roi[1] + roi[3])
    tan_a, tan_b = (bx - cx) / fx, (by - cy) / fy  # eqs. 7-8
    ray = np.array([tan_a, tan_b, 1.0])
    return rng * ray / np.linalg.norm(ray)  # eq. 9 (see module docstring)
