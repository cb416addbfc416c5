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
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxpose.core._checks import (
    as_float,
    as_image_size,
    check_real,
    check_rotation,
    intrinsic_matrix_problem,
)
from jaxpose.core._compile import small_jit
from jaxpose.core.geometry import Pose

__all__ = ["PinholeCamera", "StereoCamera", "as_camera"]


class PinholeCamera(eqx.Module):
    """Pinhole camera with optional OpenCV distortion.

    Attributes:
        fx, fy: focal lengths in pixels.
        cx, cy: principal point in pixels.
        dist: ``(5,)`` OpenCV distortion ``(k1, k2, p1, p2, k3)``; zeros for an ideal pinhole.
        width, height: image size in pixels (static; 0 when unknown).

    Leaves are arrays, so a camera can be batched with ``vmap`` and differentiated (the
    sensitivity of a pose to ``fx`` is a gradient with respect to this module). One camera per
    instance: ``fx, fy, cx, cy`` are single numbers (a batch of cameras comes from ``vmap``).

    Raises ``ValueError`` naming the field for an ``fx, fy, cx, cy`` that is not one real number
    (a bool, a string, an array of several), a known focal length that is not positive, and a
    ``width``/``height`` that is not an integer ``>= 0``.
    """

    fx: Float[Array, ""]
    fy: Float[Array, ""]
    cx: Float[Array, ""]
    cy: Float[Array, ""]
    dist: Float[Array, "5"]
    width: int = eqx.field(static=True, default=0)
    height: int = eqx.field(static=True, default=0)

    def __init__(self, fx, fy, cx, cy, dist=None, *, width: int = 0, height: int = 0):
        names = ("fx", "fy", "cx", "cy")
        for name, value in zip(names, (fx, fy, cx, cy), strict=True):
            check_real(value, name, prefix="PinholeCamera: ")
        self.fx, self.fy, self.cx, self.cy = (as_float(v) for v in (fx, fy, cx, cy))
        for name in names:  # shapes are static: checked under jit too
            shape = getattr(self, name).shape
            if shape != ():
                raise ValueError(
                    f"PinholeCamera: {name} must be one number (one camera; a batch of cameras "
                    f"comes from jax.vmap); got shape {shape}"
                )
        for name in ("fx", "fy"):
            value = getattr(self, name)
            if not isinstance(value, jax.core.Tracer) and np.any(np.asarray(value) <= 0):
                raise ValueError(
                    f"PinholeCamera: {name} (focal length in pixels) must be positive; got "
                    f"{np.asarray(value).tolist()} (a mirrored image is not a camera model)"
                )
        if dist is None:
            dist = jnp.zeros(5, dtype=self.fx.dtype)
        check_real(dist, "dist", prefix="PinholeCamera: ")
        dist = as_float(dist)
        if dist.shape[-1:] != (5,):
            raise ValueError(
                "dist must hold OpenCV's 5 coefficients (k1, k2, p1, p2, k3); "
                f"got shape {dist.shape}"
            )
        self.dist = dist
        self.width = as_image_size(width, "width", prefix="PinholeCamera: ")
        self.height = as_image_size(height, "height", prefix="PinholeCamera: ")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_K(cls, K, dist=None, *, width: int = 0, height: int = 0) -> PinholeCamera:
        """From a ``3x3`` intrinsic matrix (pixels) and optional distortion coefficients.

        ``K`` must be ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``: a known ``K`` with a skew
        ``K[0, 1]`` (above ``1e-9 fx``), a non-zero ``K[1, 0]`` or a last row other than
        ``(0, 0, 1)`` (to ``1e-12``) raises ``ValueError`` rather than being dropped.
        """
        check_real(K, "K")
        K = jnp.asarray(K)
        if K.shape != (3, 3):
            raise ValueError(f"K must be 3x3; got shape {K.shape}")
        if not isinstance(K, jax.core.Tracer):  # values can be checked
            Kn = np.asarray(K, dtype=float)
            if not np.all(np.isfinite(Kn)) or Kn[0, 0] <= 0 or Kn[1, 1] <= 0:
                raise ValueError(f"K must be finite with positive fx, fy; got {Kn.tolist()}")
            problem = intrinsic_matrix_problem(Kn)
            if problem is not None:
                raise ValueError(
                    f"K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]; got {problem} in "
                    f"{Kn.tolist()}"
                )
        if isinstance(dist, jax.core.Tracer):  # traced coefficients: shape checks only
            if dist.shape != (5,):
                raise ValueError(f"traced dist must have shape (5,); got {dist.shape}")
        elif dist is not None:
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
        ``((width - 1) / 2, (height - 1) / 2)`` (pixel-centre convention). ``ValueError`` naming
        the argument for a focal length or pixel size that is not a number (a string, a bool).
        """
        check_real(focal_length_m, "focal_length_m", prefix="from_focal_length: ")
        check_real(pixel_size_m, "pixel_size_m", prefix="from_focal_length: ")
        if np.ndim(focal_length_m) != 0:
            raise ValueError(
                f"from_focal_length: focal_length_m must be one number; got {focal_length_m!r}"
            )
        if np.ndim(pixel_size_m) == 0:
            px = py = pixel_size_m
        elif np.shape(pixel_size_m) == (2,):
            px, py = pixel_size_m
        else:
            raise ValueError(
                "from_focal_length: pixel_size_m must be one number or (px, py); got "
                f"{pixel_size_m!r}"
            )
        if focal_length_m <= 0 or px <= 0 or py <= 0:
            raise ValueError(
                "from_focal_length: focal_length_m and pixel_size_m (the focal length and pixel "
                f"size) must be positive; got {focal_length_m}, {pixel_size_m}"
            )
        if isinstance(image_size, str) or np.shape(image_size) != (2,):
            raise ValueError(f"image_size must be (width, height) in pixels; got {image_size!r}")
        w, h = (as_image_size(v, "image_size") for v in image_size)
        if w <= 0 or h <= 0:
            raise ValueError(f"image_size must be positive (width, height); got {image_size}")
        return cls(
            focal_length_m / px,
            focal_length_m / py,
            (w - 1) / 2.0,
            (h - 1) / 2.0,
            dist,
            width=w,
            height=h,
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
            self.fx,
            self.fy,
            self.cx,
            self.cy,
            jnp.zeros_like(self.dist),
            width=self.width,
            height=self.height,
        )

    # ------------------------------------------------------------------ distortion
    @small_jit
    def distort(self, xy: Float[ArrayLike, "... 2"]) -> Float[Array, "... 2"]:
        """Apply OpenCV distortion to normalised image coordinates ``(x, y) = (X/Z, Y/Z)``."""
        xy = _last_axis(xy, 2, "xy")
        k1, k2, p1, p2, k3 = (self.dist[..., i] for i in range(5))
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return jnp.stack([xd, yd], axis=-1)

    @small_jit(static_argnames=("iterations",))
    def undistort(
        self, xy_distorted: Float[ArrayLike, "... 2"], iterations: int = 8
    ) -> Float[Array, "... 2"]:
        """Invert :meth:`distort` by Newton's method (fixed iteration count, jit-friendly)."""
        xy_distorted = _last_axis(xy_distorted, 2, "xy_distorted")

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
    @small_jit(static_argnames=("min_depth",))
    def project(
        self, points_cam: Float[ArrayLike, "... 3"], *, min_depth: float | None = None
    ) -> Float[Array, "... 2"]:
        """Pixels of camera-frame points (with distortion).

        The one projection of the library: body points seen at a pose are
        ``camera.project(pose.apply(points_body))``. By default points with ``z <= 0`` give
        finite but meaningless pixels (``z`` is guarded); use :meth:`in_front` to mask them.
        With ``min_depth`` (metres), depths below it are raised to it instead, so points at or
        behind the camera land far off the image and drop out of any in-image test without a
        mask (what the monocular scores use). Gradients are NaN-free everywhere.
        """
        points_cam = _last_axis(points_cam, 3, "points_cam")
        z = points_cam[..., 2]
        if min_depth is None:
            z_safe = jnp.where(z > 0, z, 1.0)
        else:
            z_safe = jnp.where(z > min_depth, z, min_depth)
        xy = points_cam[..., :2] / z_safe[..., None]
        xy = self.distort(xy)
        return jnp.stack([self.fx * xy[..., 0] + self.cx, self.fy * xy[..., 1] + self.cy], axis=-1)

    @staticmethod
    def in_front(
        points_cam: Float[ArrayLike, "... 3"], min_depth: float = 1e-9
    ) -> Bool[Array, "..."] | Bool[np.ndarray, "..."]:
        """Whether each point is in front of the camera (depth above ``min_depth``, metres); a
        NumPy array for NumPy input."""
        return points_cam[..., 2] > min_depth

    @small_jit(static_argnames=("undistort",))
    def normalize(
        self, pixels: Float[ArrayLike, "... 2"], undistort: bool = True
    ) -> Float[Array, "... 2"]:
        """Pixels to normalised coordinates ``(X/Z, Y/Z)`` (undistorted unless told not to)."""
        pixels = _last_axis(pixels, 2, "pixels")
        xy = jnp.stack(
            [(pixels[..., 0] - self.cx) / self.fx, (pixels[..., 1] - self.cy) / self.fy], -1
        )
        return self.undistort(xy) if undistort else xy

    @small_jit
    def undistort_pixels(self, pixels: Float[ArrayLike, "... 2"]) -> Float[Array, "... 2"]:
        """Pixels of the same rays in the ideal (distortion-free) camera with the same ``K``."""
        xy = self.normalize(pixels)
        return jnp.stack([self.fx * xy[..., 0] + self.cx, self.fy * xy[..., 1] + self.cy], -1)

    @small_jit
    def bearing(self, pixels: Float[ArrayLike, "... 2"]) -> Float[Array, "... 3"]:
        """Unit ray directions in the camera frame."""
        xy = self.normalize(pixels)
        v = jnp.concatenate([xy, jnp.ones_like(xy[..., :1])], -1)
        return v / jnp.linalg.norm(v, axis=-1, keepdims=True)


def _last_axis(x, size: int, name: str):
    """``x`` (an array; lists become one) with ``size`` entries on its last axis, else a
    ``ValueError`` naming ``name`` (the shape is static, so this holds under ``jit`` too)."""
    if not hasattr(x, "shape"):
        x = jnp.asarray(x)
    if x.ndim < 1 or x.shape[-1] != size:
        raise ValueError(f"{name} must have shape (..., {size}); got {tuple(x.shape)}")
    return x


def as_camera(camera) -> PinholeCamera:
    """Accept a :class:`PinholeCamera` or a ``3x3`` ``K`` matrix."""
    if isinstance(camera, PinholeCamera):
        return camera
    K = np.asarray(camera) if not isinstance(camera, jax.Array) else camera
    if getattr(K, "shape", None) == (3, 3):
        return PinholeCamera.from_K(K)
    raise ValueError(
        f"camera must be a PinholeCamera or a 3x3 K matrix; got {type(camera).__name__}"
    )


# ============================================================================ stereo rig


class StereoCamera(eqx.Module):
    """A calibrated stereo rig: two :class:`PinholeCamera` and the pose of the right one.

    OpenCV's ``stereoCalibrate`` convention: a point ``x_left`` in the left camera frame is
    ``x_right = R_rl @ x_left + t_rl`` in the right camera frame. For a side-by-side rig with the
    right camera ``b`` metres to the right of the left one, ``R_rl = I`` and ``t_rl = (-b, 0, 0)``.
    The left camera frame is the rig frame: triangulated points are returned in it, and a pose
    estimated by the stereo tracker is the target pose in the left camera.

    Attributes:
        left, right: the two cameras (intrinsics, distortion, image size).
        R_rl: ``(3, 3)`` rotation from the left to the right camera frame.
        t_rl: ``(3,)`` left camera origin expressed in the right frame, metres.

    Known (not traced) values are checked: ``R_rl`` must be a finite rotation (``R^T R = I`` to
    ``max(1e-6, 1e3 eps)``, ``det = +1``) and ``t_rl`` finite and non-zero, else ``ValueError``
    naming the field. A rig built inside ``jit``, ``vmap`` or ``grad`` is checked for shapes only.

    Yang et al. 2024, Sec. 3: stereo correspondences are triangulated with the
    distortion-corrected stereo model (:meth:`triangulate`).
    """

    left: PinholeCamera
    right: PinholeCamera
    R_rl: Float[Array, "3 3"]
    t_rl: Float[Array, "3"]

    def __init__(self, left: PinholeCamera, right: PinholeCamera, R_rl=None, t_rl=None):
        if not isinstance(left, PinholeCamera) or not isinstance(right, PinholeCamera):
            raise ValueError("StereoCamera needs two PinholeCamera instances (left, right)")
        if R_rl is not None:
            check_real(R_rl, "R_rl", prefix="StereoCamera: ")
        R_rl = jnp.eye(3, dtype=left.fx.dtype) if R_rl is None else as_float(R_rl)
        if t_rl is None:
            raise ValueError("t_rl (left camera origin in the right frame, metres) is required")
        check_real(t_rl, "t_rl", prefix="StereoCamera: ")
        t_rl = as_float(t_rl)
        if R_rl.shape != (3, 3) or t_rl.shape != (3,):
            raise ValueError(
                f"R_rl must be 3x3 and t_rl of shape (3,); got {R_rl.shape}, {t_rl.shape}"
            )
        check_rotation(R_rl, "R_rl", prefix="StereoCamera: ")  # known values only
        if not isinstance(t_rl, jax.core.Tracer):
            tn = np.asarray(t_rl, dtype=float)
            if not np.all(np.isfinite(tn)):
                raise ValueError(
                    f"StereoCamera: t_rl (left camera origin in the right frame, metres) must be "
                    f"finite; got {tn.tolist()}"
                )
            if float(np.linalg.norm(tn)) <= 0.0:
                raise ValueError("the stereo baseline |t_rl| must be positive")
        self.left, self.right, self.R_rl, self.t_rl = left, right, R_rl, t_rl

    @classmethod
    def from_baseline(
        cls,
        camera: PinholeCamera,
        baseline_m: float | Float[ArrayLike, ""],
        right: PinholeCamera | None = None,
    ):
        """A rectified side-by-side rig: identical cameras (unless ``right`` is given), the right
        camera ``baseline_m`` metres along the left camera's +x axis.

        ``baseline_m`` is one positive, finite number (metres); it may be traced (a rig built
        inside ``jit`` or differentiated with respect to its baseline), and is then checked for
        its shape only."""
        if not isinstance(camera, PinholeCamera):
            raise ValueError(f"camera must be a PinholeCamera; got {type(camera).__name__}")
        what = "baseline_m must be one positive, finite number (metres)"
        if isinstance(baseline_m, bool | np.bool_ | str | bytes):
            raise ValueError(f"{what}; got {baseline_m!r}")
        check_real(baseline_m, "baseline_m")
        if np.ndim(baseline_m) != 0:
            raise ValueError(f"{what}; got shape {np.shape(baseline_m)}")
        if not isinstance(baseline_m, jax.core.Tracer):
            value = float(np.asarray(baseline_m))
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{what}; got {value}")
        zero = jnp.zeros_like(camera.fx)
        b = jnp.asarray(baseline_m).astype(zero.dtype)  # the camera's dtype
        return cls(camera, camera if right is None else right, None, jnp.stack([-b, zero, zero]))

    # ------------------------------------------------------------------ geometry
    @property
    def baseline(self) -> Float[Array, ""]:
        """Distance between the two optical centres, metres."""
        return jnp.linalg.norm(self.t_rl)

    @property
    def pose_right_left(self) -> Pose:
        """The right camera's pose of the left camera frame (``x_right = R_rl x_left + t_rl``)."""
        return Pose(self.R_rl, self.t_rl)

    @small_jit
    def to_right(self, points_left: Float[ArrayLike, "... 3"]) -> Float[Array, "... 3"]:
        """Left-camera-frame points expressed in the right camera frame."""
        return jnp.einsum("ij,...j->...i", self.R_rl, points_left) + self.t_rl

    @small_jit
    def project(
        self, points_left: Float[ArrayLike, "... 3"]
    ) -> tuple[Float[Array, "... 2"], Float[Array, "... 2"]]:
        """Pixels ``(left, right)`` of points given in the left camera frame (with distortion)."""
        return self.left.project(points_left), self.right.project(self.to_right(points_left))

    def projection_matrices(self) -> tuple[Float[Array, "3 4"], Float[Array, "3 4"]]:
        """OpenCV ``P_left = K_l [I | 0]`` and ``P_right = K_r [R_rl | t_rl]`` (ideal pinholes)."""
        eye = jnp.eye(3, dtype=self.R_rl.dtype)
        P_l = self.left.K @ jnp.concatenate([eye, jnp.zeros((3, 1), eye.dtype)], axis=1)
        P_r = self.right.K @ jnp.concatenate([self.R_rl, self.t_rl[:, None]], axis=1)
        return P_l, P_r

    # ------------------------------------------------------------------ triangulation
    def triangulate(
        self,
        pixels_left: Float[ArrayLike, "... 2"],
        pixels_right: Float[ArrayLike, "... 2"],
        *,
        method: str = "linear",
    ) -> Float[Array, "... 3"]:
        """Points in the left camera frame from their pixels in both images (distortion removed).

        ``method="linear"``: the homogeneous DLT of Hartley and Zisserman (Sec. 12.2, what
        ``cv2.triangulatePoints`` does) in normalised coordinates, solved by SVD.
        ``method="midpoint"``: the midpoint of the common perpendicular of the two rays.
        Both are exact for noise-free correspondences. Points at infinity (parallel rays) come
        out with a huge or infinite depth; mask them with :meth:`PinholeCamera.in_front` and a
        depth limit. A pair with a NaN or inf pixel gives ``inf`` (no point), never NaN.
        """
        pixels_left, pixels_right = as_float(pixels_left), as_float(pixels_right)
        if pixels_left.shape[-1:] != (2,) or pixels_left.shape != pixels_right.shape:
            raise ValueError(
                f"pixels_left and pixels_right must have the same shape (..., 2); got "
                f"{pixels_left.shape} and {pixels_right.shape}"
            )
        if method not in ("linear", "midpoint"):
            raise ValueError(f"method must be 'linear' or 'midpoint'; got {method!r}")
        shape = pixels_left.shape[:-1]
        undistort = _maybe_distorted(self.left) or _maybe_distorted(self.right)
        flat = _triangulate(
            self, pixels_left.reshape(-1, 2), pixels_right.reshape(-1, 2), method, undistort
        )
        return flat.reshape(*shape, 3)

    def triangulate_segments(
        self,
        segments_left: Float[ArrayLike, "... 2 2"],
        segments_right: Float[ArrayLike, "... 2 2"],
        *,
        method: str = "linear",
    ) -> Float[Array, "... 2 3"]:
        """3-D endpoints (left camera frame) of segments whose endpoints correspond in both images.

        ``segments_*[..., k, :]`` is endpoint ``k`` (start, end) in pixels; the right endpoints
        must already be cut to the left ones (Yang et al. 2024 Sec. 3: the right line is cut where
        it meets the epipolar lines of the left endpoints, see
        :func:`jaxpose.vision.stereo_match.match_lines`).
        """
        segments_left, segments_right = as_float(segments_left), as_float(segments_right)
        if segments_left.shape[-2:] != (2, 2) or segments_left.shape != segments_right.shape:
            raise ValueError(
                f"segments must have the same shape (..., 2, 2); got {segments_left.shape} and "
                f"{segments_right.shape}"
            )
        return self.triangulate(segments_left, segments_right, method=method)


def _maybe_distorted(camera: PinholeCamera) -> bool:
    """False only when the distortion is known (concrete) to be zero: no Newton undistortion."""
    if isinstance(camera.dist, jax.core.Tracer):
        return True
    return camera.has_distortion()


@eqx.filter_jit
def _triangulate(rig: StereoCamera, pixels_left, pixels_right, method: str, undistort: bool):
    # A pair with a NaN or inf pixel has no point: inf, never NaN (double-where: the solve sees a
    # finite stand-in, so gradients stay finite too). Parallel rays give inf as well.
    finite = jnp.all(jnp.isfinite(pixels_left), -1) & jnp.all(jnp.isfinite(pixels_right), -1)
    pixels_left = jnp.where(finite[:, None], pixels_left, 0.0)
    pixels_right = jnp.where(finite[:, None], pixels_right, 0.0)
    xl = rig.left.normalize(pixels_left, undistort=undistort)
    xr = rig.right.normalize(pixels_right, undistort=undistort)
    if method == "linear":
        points = _triangulate_dlt(xl, xr, rig.R_rl, rig.t_rl)
    else:
        points = _triangulate_midpoint(xl, xr, rig.R_rl, rig.t_rl)
    inf = jnp.asarray(jnp.inf, points.dtype)
    return jnp.where(finite[:, None] & ~jnp.isnan(points), points, inf)


def _triangulate_dlt(xl, xr, R, t):
    """Homogeneous DLT on normalised coordinates ``(n, 2)``; returns ``(n, 3)``."""
    eye = jnp.eye(3, dtype=R.dtype)
    P1 = jnp.concatenate([eye, jnp.zeros((3, 1), R.dtype)], axis=1)
    P2 = jnp.concatenate([R, t[:, None]], axis=1)

    def one(a, b):
        A = jnp.stack(
            [a[0] * P1[2] - P1[0], a[1] * P1[2] - P1[1], b[0] * P2[2] - P2[0], b[1] * P2[2] - P2[1]]
        )
        _, _, vt = jnp.linalg.svd(A)
        X = vt[-1]
        return X[:3] / X[3]

    return jax.vmap(one)(xl, xr)


def _triangulate_midpoint(xl, xr, R, t):
    """Midpoint of the common perpendicular of the two rays, in the left frame."""
    ones = jnp.ones_like(xl[..., :1])
    d1 = jnp.concatenate([xl, ones], -1)
    d2 = jnp.einsum("ji,...j->...i", R, jnp.concatenate([xr, ones], -1))  # right ray in left frame
    c2 = -R.T @ t  # right optical centre in the left frame
    # minimise |s d1 - (c2 + u d2)|^2 over (s, u)
    a, b, c = jnp.sum(d1 * d1, -1), jnp.sum(d1 * d2, -1), jnp.sum(d2 * d2, -1)
    d, e = jnp.sum(d1 * c2, -1), jnp.sum(d2 * c2, -1)
    den = a * c - b * b
    den = jnp.where(jnp.abs(den) > 0, den, jnp.finfo(den.dtype).tiny)
    s = (c * d - b * e) / den
    u = (b * d - a * e) / den
    return 0.5 * (s[..., None] * d1 + c2 + u[..., None] * d2)
