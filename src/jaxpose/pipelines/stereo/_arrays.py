"""Array helpers of the stereo tracker: padding, NumPy views of a pose, projection of body points
through :meth:`PinholeCamera.project` at padded sizes, the pinhole pixel Jacobian, homogeneous
image lines, sorted lookup."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.geometry import Pose, rotation_angle


def pad(a: np.ndarray, n: int, fill: float = 0.0) -> np.ndarray:
    """``a`` cut or padded with ``fill`` to ``n`` rows (float64)."""
    out = np.full((n, *a.shape[1:]), fill, dtype=np.float64)
    out[: min(n, len(a))] = a[:n]
    return out


def rt(pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` of a pose as float64 NumPy arrays (for the map's NumPy bookkeeping)."""
    return np.asarray(pose.R, np.float64), np.asarray(pose.t, np.float64)


def sym3_eigvalsh(M: np.ndarray) -> np.ndarray:
    """Ascending eigenvalues ``(k, 3)`` of symmetric ``3 x 3`` matrices ``M (k, 3, 3)``, closed
    form (the trigonometric solution of the characteristic cubic, Smith 1961): about a tenth of
    the time of ``np.linalg.eigvalsh`` on thousands of small matrices (one LAPACK call each).
    Each eigenvalue is within about ``1e-8`` of the largest one's magnitude of LAPACK's (the
    ``arccos`` near a double eigenvalue); tested against ``np.linalg.eigvalsh``."""
    M = np.asarray(M, np.float64)
    a, b, c = M[:, 0, 0], M[:, 1, 1], M[:, 2, 2]
    d, e, f = M[:, 0, 1], M[:, 0, 2], M[:, 1, 2]
    q = (a + b + c) / 3.0
    p1 = d * d + e * e + f * f
    p = np.sqrt(((a - q) ** 2 + (b - q) ** 2 + (c - q) ** 2 + 2.0 * p1) / 6.0)
    s = np.where(p > 0, p, 1.0)
    A, B, C, D, E, F = (a - q) / s, (b - q) / s, (c - q) / s, d / s, e / s, f / s
    r = 0.5 * (A * (B * C - F * F) - D * (D * C - F * E) + E * (D * F - B * E))
    phi = np.arccos(np.clip(r, -1.0, 1.0)) / 3.0
    hi = q + 2.0 * p * np.cos(phi)
    lo = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    return np.stack([lo, 3.0 * q - hi - lo, hi], -1)


@jax.jit
def _project(camera: PinholeCamera, pose: Pose, points):
    return camera.project(pose.apply(points))


# Pose operations of every frame, compiled once: eager, each would dispatch a dozen small ops.
@jax.jit
def compose(a: Pose, b: Pose) -> Pose:
    """``a @ b``: apply ``b``, then ``a``."""
    return a @ b


@jax.jit
def relative(a: Pose, b: Pose) -> Pose:
    """``a @ b^-1``: the motion from ``b`` to ``a``."""
    return a @ b.inverse()


@jax.jit
def nearest_rotation(pose: Pose) -> Pose:
    """The pose with ``R`` returned to the nearest rotation (a quaternion round trip)."""
    return Pose.from_quat(pose.quat, pose.t)


@jax.jit
def fraction(motion: Pose, steps) -> Pose:
    """A ``motion`` spread over ``steps`` frames: rotation vector and translation over steps."""
    return Pose.from_rotvec(motion.rotvec / steps, motion.t / steps)


@jax.jit
def angle_deg(R_a, R_b):
    """Angle between two rotations, degrees."""
    return jnp.degrees(rotation_angle(R_a, R_b))


def _padded_size(n: int) -> int:
    """The padded size of ``n`` projected points: a power of four, at least 64."""
    size = 64
    while size < n:
        size *= 4
    return size


def warm_up_projection(camera: PinholeCamera, largest: int = 16384) -> None:
    """Compile :func:`project` for every padded size up to ``largest`` points (one compilation
    a size, some 50 ms each, at the start rather than in the middle of a sequence)."""
    pose = Pose(jnp.eye(3), jnp.zeros(3))
    size = 64
    while size <= largest:
        _project(camera, pose, jnp.ones((size, 3))).block_until_ready()
        size *= 4


def project(camera: PinholeCamera, pose: Pose | None, points_body: np.ndarray) -> np.ndarray:
    """Pixels ``(..., 2)`` of body points ``(..., 3)`` seen at ``pose`` (``None``: the points are
    in the camera frame), by :meth:`PinholeCamera.project`. The points are padded to a power of
    four (at least 64) so that a sequence compiles a handful of sizes, not one a frame."""
    X = np.asarray(points_body, np.float64)
    flat = X.reshape(-1, 3)
    n = len(flat)
    if n == 0:
        return np.zeros((*X.shape[:-1], 2))
    size = _padded_size(n)
    pose = Pose(np.eye(3), np.zeros(3)) if pose is None else pose
    # NumPy straight into the compiled function: a jnp.asarray first cost 0.13 ms more a call
    uv = np.asarray(_project(camera, pose, pad(flat, size, 1.0)))[:n]
    return uv.reshape(*X.shape[:-1], 2)


def pixel_jacobian(x_cam: np.ndarray, fx: float, fy: float) -> np.ndarray:
    """``(n, 2, 3)`` derivatives of the undistorted pixels of camera-frame points ``x_cam``
    ``(n, 3)`` (metres) with respect to those points: ``[[fx/z, 0, -fx x/z^2], [0, fy/z,
    -fy y/z^2]]``."""
    iz = 1.0 / x_cam[:, 2]
    J = np.zeros((len(x_cam), 2, 3))
    J[:, 0, 0] = fx * iz
    J[:, 0, 2] = -fx * x_cam[:, 0] * iz**2
    J[:, 1, 1] = fy * iz
    J[:, 1, 2] = -fy * x_cam[:, 1] * iz**2
    return J


def unit_rows(v: np.ndarray) -> np.ndarray:
    """``v`` scaled to unit length along its last axis (a zero row stays zero)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def lines_from_segments(segments: np.ndarray) -> np.ndarray:
    """Homogeneous lines ``(s, 1) x (e, 1)`` of ``(k, 2, 2)`` segments (Yang et al. 2024, eq. 7;
    the NumPy twin of :func:`jaxpose.core.residuals.line_from_segment`, kept eager so that a
    varying ``k`` compiles nothing)."""
    one = np.ones((len(segments), 1))
    return np.cross(np.c_[segments[:, 0], one], np.c_[segments[:, 1], one])


def find(
    keys: np.ndarray, queries: np.ndarray, *, increasing: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``q`` of the ``queries`` present in the non-empty ``keys`` and, for each, its
    index in ``keys`` (sorted lookup). ``increasing``: the keys are already in increasing
    order (the map's stable ids, :attr:`LandmarkSet.ids`), so they are not sorted again."""
    order = None if increasing else np.argsort(keys)
    ranked = keys if order is None else keys[order]
    pos = np.searchsorted(ranked, queries)
    hit = (pos < len(keys)) & (ranked[np.minimum(pos, len(keys) - 1)] == queries)
    q = np.nonzero(hit)[0]
    return q, pos[q] if order is None else order[pos[q]]


def scatter_add(out: np.ndarray, idx: np.ndarray, values: np.ndarray) -> None:
    """``out[idx] += values`` in place, repeated indices summed (``np.add.at``): one
    ``np.bincount`` over the flattened trailing axes, about a third of ``np.add.at``'s time on
    tens of thousands of ``3 x 3`` rows. ``out``: ``(L, ...)`` float64, C-contiguous; ``idx``:
    ``(n,)``; ``values``: ``(n, ...)`` with ``out``'s trailing shape."""
    idx = np.asarray(idx, np.intp)
    if len(idx) == 0:
        return
    if not out.flags.c_contiguous:  # a reshape would write into a copy
        np.add.at(out, idx, values)
        return
    width = int(np.prod(out.shape[1:], dtype=np.int64))
    flat = (idx[:, None] * width + np.arange(width)).ravel()
    sums = np.bincount(flat, weights=np.asarray(values, np.float64).reshape(-1), minlength=out.size)
    out.reshape(-1)[...] += sums


def solve3(M: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solutions ``x (k, 3)`` of ``M x = b`` for ``(k, 3, 3)`` matrices by their adjugates
    (Cramer's rule): about two thirds of ``np.linalg.solve``'s time on thousands of ``3 x 3``
    systems (one LAPACK call each). For the well-conditioned systems of the map (its callers
    check the eigenvalue ratio first); a singular ``M`` gives non-finite rows."""
    c0 = np.cross(M[:, 1], M[:, 2])
    c1 = np.cross(M[:, 2], M[:, 0])
    c2 = np.cross(M[:, 0], M[:, 1])
    det = np.einsum("ki,ki->k", M[:, 0], c0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (c0 * b[:, 0:1] + c1 * b[:, 1:2] + c2 * b[:, 2:3]) / det[:, None]


def rows_times(v: np.ndarray, mats: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """``v[i] @ mats[frame[i]]`` for rows ``v (n, a)`` and matrices ``mats (f, a, b)``: one
    matrix product per frame when ``frame`` is non-decreasing (rows grouped by frame), else
    a gathered ``einsum``."""
    frame = np.asarray(frame)
    if len(frame) > 1 and np.any(frame[1:] < frame[:-1]):
        return np.einsum("na,nab->nb", v, mats[frame])
    out = np.empty((len(v), mats.shape[-1]))
    bounds = np.searchsorted(frame, np.arange(len(mats) + 1))
    for j in range(len(mats)):
        lo, hi = bounds[j], bounds[j + 1]
        if hi > lo:
            out[lo:hi] = v[lo:hi] @ mats[j]
    return out
