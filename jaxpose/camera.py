"""Camera models (pure JAX).

Pixels ``(u, v)`` have ``(0, 0)`` at the centre of the top-left pixel; the camera frame has x
right, y down, z along the boresight (OpenCV). Intrinsics ``K = [[fx, 0, cx], [0, fy, cy], [0, 0,
1]]`` in pixels. Distortion is OpenCV's 5-coefficient model ``(k1, k2, p1, p2, k3)``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .geometry import Pose

__all__ = ["PinholeCamera", "as_camera"]


def _scalar(x) -> Array:
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


class PinholeCamera(eqx.Module):
    """Pinhole camera with optional OpenCV distortion.

    Attributes:
        fx, fy: focal lengths in pixels.
        cx, cy: principal point in pixels.
        dist: ``(5,)`` OpenCV distortion ``(k1, k2, p1, p2, k3)``; zeros for an ideal pinhole.
        width, height: image size in pixels (static; 0 when unknown).

    Leaves are arrays, so a camera can be batched with ``vmap`` and differentiated (the
    sensitivity of a pose to ``fx`` is a gradient with respect to this module).
    """

    fx: Float[Array, ""]
    fy: Float[Array, ""]
    cx: Float[Array, ""]
    cy: Float[Array, ""]
    dist: Float[Array, "5"]
    width: int = eqx.field(static=True, default=0)
    height: int = eqx.field(static=True, default=0)

    def __init__(self, fx, fy, cx, cy, dist=None, *, width: int = 0, height: int = 0):
        self.fx, self.fy, self.cx, self.cy = (_scalar(v) for v in (fx, fy, cx, cy))
        if dist is None:
            dist = jnp.zeros(5, dtype=self.fx.dtype)
        dist = _scalar(dist)
        if dist.shape[-1:] != (5,):
            raise ValueError(
                f"dist must hold OpenCV's 5 coefficients (k1, k2, p1, p2, k3); got shape {dist.shape}"
            )
        self.dist = dist
        self.width, self.height = int(width), int(height)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_K(cls, K, dist=None, *, width: int = 0, height: int = 0) -> PinholeCamera:
        """From a ``3x3`` intrinsic matrix (pixels) and optional distortion coefficients."""
        K = jnp.asarray(K)
        if K.shape != (3, 3):
            raise ValueError(f"K must be 3x3; got shape {K.shape}")
        if isinstance(K, np.ndarray) or not isinstance(K, jax.core.Tracer):
            Kn = np.asarray(K, dtype=float)
            if not np.all(np.isfinite(Kn)) or Kn[0, 0] <= 0 or Kn[1, 1] <= 0:
                raise ValueError(f"K must be finite with positive fx, fy; got {Kn.tolist()}")
        if dist is not None:
            dist = np.asarray(dist, dtype=float).ravel()
            if dist.size not in (4, 5, 8, 12, 14):
                raise ValueError(f"dist must have 4 or 5 coefficients; got {dist.size}")
            if dist.size > 5 and np.any(dist[5:] != 0):
                raise ValueError("only OpenCV's (k1, k2, p1, p2, k3) distortion is supported")
            dist = np.concatenate([dist, np.zeros(max(0, 5 - dist.size))])[:5]
        return cls(K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist, width=width, height=height)

    @classmethod
    def from_focal_length(
        cls,
        focal_length_m: float,
        pixel_size_m: float | tuple[float, float],
        image_size: tuple[int, int],
        *,
        dist=None,
    ) -> PinholeCamera:
        """From a lens focal length (m), a pixel pitch (m, or ``(px, py)``) and ``(width, height)``.

        ``fx = focal_length / px`` and the principal point at the image centre
        ``((width - 1) / 2, (height - 1) / 2)`` (pixel-centre convention).
        """
        px, py = (pixel_size_m, pixel_size_m) if np.isscalar(pixel_size_m) else pixel_size_m
        if focal_length_m <= 0 or px <= 0 or py <= 0:
            raise ValueError(
                f"focal length and pixel size must be positive; got {focal_length_m}, {pixel_size_m}"
            )
        w, h = (int(v) for v in image_size)
        if w <= 0 or h <= 0:
            raise ValueError(f"image_size must be positive (width, height); got {image_size}")
        return cls(
            focal_length_m / px, focal_length_m / py, (w - 1) / 2.0, (h - 1) / 2.0, dist, width=w, height=h
        )

    # ------------------------------------------------------------------ properties
    @property
    def K(self) -> Float[Array, "3 3"]:
        zero, one = jnp.zeros_like(self.fx), jnp.ones_like(self.fx)
        return jnp.stack(
            [
                jnp.stack([self.fx, zero, self.cx]),
                jnp.stack([zero, self.fy, self.cy]),
                jnp.stack([zero, zero, one]),
            ]
        )

    @property
    def focal_px(self) -> Float[Array, ""]:
        """Mean focal length ``(fx + fy) / 2`` in pixels."""
        return 0.5 * (self.fx + self.fy)

    def has_distortion(self) -> bool:
        """True when any distortion coefficient is non-zero (eager only)."""
        return bool(np.any(np.asarray(self.dist) != 0))

    def without_distortion(self) -> PinholeCamera:
        return PinholeCamera(
            self.fx, self.fy, self.cx, self.cy, jnp.zeros_like(self.dist), width=self.width, height=self.height
        )

    # ------------------------------------------------------------------ distortion
    def distort(self, xy: Float[Array, "... 2"]) -> Float[Array, "... 2"]:
        """Apply OpenCV distortion to normalised image coordinates ``(x, y) = (X/Z, Y/Z)``."""
        k1, k2, p1, p2, k3 = (self.dist[..., i] for i in range(5))
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return jnp.stack([xd, yd], axis=-1)

    def undistort(self, xy_distorted: Float[Array, "... 2"], iterations: int = 8) -> Float[Array, "... 2"]:
        """Invert :meth:`distort` by Newton's method (fixed iteration count, jit-friendly)."""

        def one(xd):
            def step(x, _):
                r = self.distort(x) - xd
                J = jax.jacfwd(self.distort)(x)
                return x - jnp.linalg.solve(J, r), None

            x, _ = jax.lax.scan(step, xd, None, length=iterations)
            return x

        flat = xy_distorted.reshape(-1, 2)
        return jax.vmap(one)(flat).reshape(xy_distorted.shape)

    # ------------------------------------------------------------------ projection
    def project(self, points_cam: Float[Array, "... 3"]) -> Float[Array, "... 2"]:
        """Pixels of camera-frame points (with distortion).

        Points with ``z <= 0`` give finite but meaningless pixels (``z`` is guarded); use
        :meth:`in_front` to mask them. Gradients are NaN-free everywhere.
        """
        z = points_cam[..., 2]
        z_safe = jnp.where(z > 0, z, 1.0)
        xy = points_cam[..., :2] / z_safe[..., None]
        xy = self.distort(xy)
        return jnp.stack([self.fx * xy[..., 0] + self.cx, self.fy * xy[..., 1] + self.cy], axis=-1)

    def project_body(self, pose: Pose, points_body: Float[Array, "... n 3"]) -> Float[Array, "... n 2"]:
        """Pixels of body-frame points seen at ``pose``."""
        return self.project(pose.apply(points_body))

    @staticmethod
    def in_front(points_cam: Float[Array, "... 3"], min_depth: float = 1e-9) -> Bool[Array, "..."]:
        return points_cam[..., 2] > min_depth

    def normalize(self, pixels: Float[Array, "... 2"], undistort: bool = True) -> Float[Array, "... 2"]:
        """Pixels to normalised coordinates ``(X/Z, Y/Z)`` (undistorted unless told not to)."""
        xy = jnp.stack([(pixels[..., 0] - self.cx) / self.fx, (pixels[..., 1] - self.cy) / self.fy], -1)
        return self.undistort(xy) if undistort else xy

    def undistort_pixels(self, pixels: Float[Array, "... 2"]) -> Float[Array, "... 2"]:
        """Pixels of the same rays in the ideal (distortion-free) camera with the same ``K``."""
        xy = self.normalize(pixels)
        return jnp.stack([self.fx * xy[..., 0] + self.cx, self.fy * xy[..., 1] + self.cy], -1)

    def bearing(self, pixels: Float[Array, "... 2"]) -> Float[Array, "... 3"]:
        """Unit ray directions in the camera frame."""
        xy = self.normalize(pixels)
        v = jnp.concatenate([xy, jnp.ones_like(xy[..., :1])], -1)
        return v / jnp.linalg.norm(v, axis=-1, keepdims=True)


def as_camera(camera) -> PinholeCamera:
    """Accept a :class:`PinholeCamera` or a ``3x3`` ``K`` matrix."""
    if isinstance(camera, PinholeCamera):
        return camera
    K = np.asarray(camera) if not isinstance(camera, jax.Array) else camera
    if getattr(K, "shape", None) == (3, 3):
        return PinholeCamera.from_K(K)
    raise ValueError(f"camera must be a PinholeCamera or a 3x3 K matrix; got {type(camera).__name__}")
