"""Slanted-window stereo: a feature's disparity and its slope, hence the surface plane through it.

A window matched at one disparity assumes the surface faces the camera. On a surface turned from
the view the disparity changes across the window, and for a plane it changes linearly in the
pixel: with a rectified rig (focal ``f_x``, baseline ``B``) the plane ``n . X = c`` (left camera
frame) has the disparity ``d(u, v) = (f_x B / c) n . K^-1 (u, v, 1)``. So the disparity's value
``d0`` at a feature and its slope ``(a, b)`` along the columns and rows fix the plane's normal
(:func:`plane_normals`)::

    n  ~  (a f_x,  b f_y,  d0 - a (u0 - c_x) - b (v0 - c_y))

:func:`slanted_disparity` fits ``d0, a, b``, with a gain and a bias between the images, by
Gauss-Newton on a window about each feature: the left window's pixels ``(u0 + du, v0 + dv)``
are compared with the right image at ``(u0 + du - d0 - a du - b dv, v0 + dv)``. These are the
slanted support windows of PatchMatch stereo (Bleyer, Rhemann and Rother 2011), fitted by
Gauss-Newton as Lucas-Kanade fits a shift. A wide window gives the slope its lever: on the
first frame of a development scene at 3.7 m, half-widths of 7, 10, 15 and 20 pixels put the
median normal 31, 18, 12 and 7 degrees from the true face (``docs/stereo-evaluation.md``,
*Surface normals from the stereo slant*).

NumPy and OpenCV (one ``cv2.remap`` gathers every window), vectorised over the features.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxpose.core.camera import PinholeCamera
from jaxpose.vision.stereo_match import _as_float, _gather, zncc

__all__ = ["SlantedDisparity", "plane_normals", "slanted_disparity"]


class SlantedDisparity(NamedTuple):
    """The fit of :func:`slanted_disparity`, one row per feature."""

    disparity: np.ndarray  #: ``(n,)`` pixels
    slope: np.ndarray  #: ``(n, 2)`` pixels of disparity per pixel along ``u`` and ``v``
    zncc: np.ndarray  #: ``(n,)`` zero-mean NCC of the fitted windows
    ok: np.ndarray  #: ``(n,)`` the fit holds (:func:`slanted_disparity`)
    slope_cov: np.ndarray  #: ``(n, 2, 2)`` the slope's covariance (from the fit's residuals)


def slanted_disparity(
    left: np.ndarray,
    right: np.ndarray,
    pixels: np.ndarray,
    disparity: np.ndarray,
    *,
    half: int = 20,
    stride: int = 2,
    iterations: int = 8,
) -> SlantedDisparity:
    """Disparity and its slope across a window about each left pixel (module docstring).

    Args:
        left, right: rectified grayscale images ``(h, w)`` (the same shape).
        pixels: ``(n, 2)`` left pixels ``(u, v)``.
        disparity: ``(n,)`` their disparities ``u_left - u_right`` (pixels), the start.
        half: the window reaches ``half`` pixels each side of the pixel.
        stride: the window is sampled every ``stride`` pixels (its lever stays ``half``).
        iterations: Gauss-Newton steps.

    Returns:
        :class:`SlantedDisparity`: the disparity at each pixel ``(n,)``, its slope ``(n, 2)``
        (pixels of disparity per pixel along ``u`` and ``v``), the zero-mean NCC of the fitted
        windows ``(n,)``, ``ok (n,)``: the window lies inside both images and the last step
        moved the disparity by less than 0.02 pixel, and the slope's covariance ``(n, 2, 2)``
        (the residuals' variance times the inverse normal matrix's slope block; it takes the left
        window as exact, and under noise on both images the slopes spread 1.1-1.6
        times its prediction in the tests).
    """
    L, R = _as_float(left), _as_float(right)
    if L.shape != R.shape:
        raise ValueError(f"left and right must have the same shape; got {L.shape} and {R.shape}")
    uv = np.asarray(pixels, float)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise ValueError(f"pixels must be (n, 2); got shape {uv.shape}")
    d0 = np.asarray(disparity, float)
    if d0.shape != (len(uv),):
        raise ValueError(f"disparity must be ({len(uv)},); got shape {d0.shape}")
    if half < 1 or stride < 1 or iterations < 1:
        raise ValueError(
            f"half, stride and iterations must be at least 1; got {half}, {stride}, {iterations}"
        )
    n = len(uv)
    if not n:
        z = np.zeros(0)
        return SlantedDisparity(z, np.zeros((0, 2)), z, np.zeros(0, bool), np.zeros((0, 2, 2)))
    h, w = L.shape
    g = np.arange(-half, half + 1, stride, dtype=float)
    du, dv = (a.ravel() for a in np.meshgrid(g, g))  # (k,)
    xs, ys = uv[:, :1] + du, uv[:, 1:] + dv  # (n, k): the left window
    T = _gather(L, xs, ys)
    Rx = np.zeros_like(R)
    Rx[:, 1:-1] = 0.5 * (R[:, 2:] - R[:, :-2])
    p = np.stack([np.where(np.isfinite(d0), d0, 0.0), np.zeros(n), np.zeros(n)], 1)
    ones = np.ones_like(T)
    step = np.zeros(n)
    for it in range(iterations + 1):
        xr = xs - (p[:, :1] + p[:, 1:2] * du + p[:, 2:] * dv)
        S, Sx = _gather(R, xr, ys), _gather(Rx, xr, ys)
        # residual S - gain T - bias; the gain and bias enter linearly
        J = np.stack([-Sx, -Sx * du, -Sx * dv, -T, -ones], 1)  # (n, 5, k)
        A = np.einsum("nik,njk->nij", J, J) + 1e-6 * np.eye(5)
        sol = np.linalg.solve(A, -np.einsum("nik,nk->ni", J, S)[..., None])[..., 0]
        if it == iterations:  # at the fit: its residuals and the slope's covariance
            r = S + np.einsum("nik,ni->nk", J, sol)
            var = (r * r).sum(1) / max(len(du) - 5, 1)
            cov = var[:, None, None] * np.linalg.inv(A)[:, 1:3, 1:3]
            break
        step = np.clip(sol[:, 0], -1.0, 1.0)
        p[:, 0] += step
        p[:, 1:] += np.clip(sol[:, 1:3], -0.05, 0.05)
    zn = zncc(S[:, None], T[:, None])  # (each window's samples as a 1 x k patch)
    ok = (xs.min(1) >= 0) & (xs.max(1) <= w - 1) & (ys.min(1) >= 0) & (ys.max(1) <= h - 1)
    ok &= (xr.min(1) >= 1) & (xr.max(1) <= w - 2) & (np.abs(step) < 0.02) & np.isfinite(d0)
    return SlantedDisparity(p[:, 0], p[:, 1:].copy(), zn, ok, cov)


def plane_normals(
    camera: PinholeCamera, pixels: np.ndarray, disparity: np.ndarray, slope: np.ndarray
) -> np.ndarray:
    """Unit normals ``(n, 3)`` (left camera frame, turned towards the camera) of the planes whose
    disparity is ``disparity (n,)`` at ``pixels (n, 2)`` with the slope ``slope (n, 2)``
    (:func:`slanted_disparity`; module docstring). ``camera``: the rectified left camera."""
    uv = np.asarray(pixels, float).reshape(-1, 2)
    d = np.asarray(disparity, float).reshape(-1)
    s = np.asarray(slope, float).reshape(-1, 2)
    if not len(uv) == len(d) == len(s):
        raise ValueError(
            f"pixels, disparity and slope must have one row each per feature; got {len(uv)}, "
            f"{len(d)} and {len(s)}"
        )
    fx, fy = float(camera.fx), float(camera.fy)
    cx, cy = float(camera.cx), float(camera.cy)
    nz = d - s[:, 0] * (uv[:, 0] - cx) - s[:, 1] * (uv[:, 1] - cy)
    n = np.stack([s[:, 0] * fx, s[:, 1] * fy, nz], 1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    ray = np.stack([(uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy, np.ones(len(uv))], 1)
    return np.where((np.einsum("ni,ni->n", n, ray) > 0)[:, None], -n, n)
