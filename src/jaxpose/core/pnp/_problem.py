"""Input preparation shared by the PnP solvers: checks, masks, normalised coordinates, statuses."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array

from jaxpose.core._checks import check_mask, float_dtype, real_array
from jaxpose.core.camera import PinholeCamera, as_camera
from jaxpose.core.geometry import Pose
from jaxpose.core.pnp._linalg import _eigh_small, _mv
from jaxpose.core.pnp._result import PnPResult
from jaxpose.core.status import Status

MIN_POINTS = 4
"""EPnP needs at least four points (planar or not)."""

DLT_MIN_POINTS = 6
"""The DLT needs at least six non-coplanar points."""

PLANAR_TOL = 1e-3
"""Points whose out-of-plane spread is below this fraction of their largest spread are planar
(``sqrt(l3 / l1)`` of the eigenvalues of their scatter matrix)."""

COLLINEAR_TOL = 1e-6
"""Points whose second spread is below this fraction of the largest (``sqrt(l2 / l1)``) are
collinear (or coincident): :attr:`Status.DEGENERATE`."""


def _prepare(points_body, pixels, camera, mask, name: str):
    """Check shapes (trace time) and return arrays of one float dtype, the valid mask and camera."""
    camera = as_camera(camera)
    points_body = jnp.asarray(real_array(points_body, f"{name}: points_body"))
    pixels = jnp.asarray(real_array(pixels, f"{name}: pixels"))
    if points_body.ndim != 2 or points_body.shape[-1] != 3:
        raise ValueError(
            f"{name}: points_body must have shape (n, 3) (one problem; use jax.vmap or "
            f"jaxpose.solve_pnp for batches); got {points_body.shape}"
        )
    n = points_body.shape[0]
    if pixels.shape != (n, 2):
        raise ValueError(
            f"{name}: pixels must have shape ({n}, 2) to match points_body {points_body.shape}; "
            f"got {pixels.shape}"
        )
    dtype = float_dtype(points_body)
    points_body = points_body.astype(dtype)
    pixels = pixels.astype(dtype)
    camera = jax.tree.map(lambda leaf: jnp.asarray(leaf).astype(dtype), camera)
    valid = check_mask(mask, n, prefix=f"{name}: ")
    return points_body, pixels, camera, valid


def _normalized(camera: PinholeCamera, pixels, undistort: bool | None = None):
    """Normalised, undistorted image coordinates; skips the Newton undistortion for a pinhole.

    ``undistort`` forces the choice; otherwise it is made at trace time for a concrete camera,
    and for a traced one (a camera passed through ``jit``) a ``lax.cond`` skips the undistortion
    at run time when every coefficient is zero.
    """
    if undistort is not None:
        return camera.normalize(pixels, undistort=undistort)
    dist = camera.dist
    if not isinstance(dist, jax.core.Tracer):
        return camera.normalize(pixels, undistort=bool(np.any(np.asarray(dist) != 0)))
    return lax.cond(
        jnp.any(dist != 0),
        lambda p: camera.normalize(p),
        lambda p: camera.normalize(p, undistort=False),
        pixels,
    )


def _sanitize(valid, points_body, xy):
    """Zero the invalid entries and report whether every valid entry is finite."""
    finite = jnp.all(
        (jnp.all(jnp.isfinite(points_body), axis=-1) & jnp.all(jnp.isfinite(xy), axis=-1)) | ~valid
    )
    use = valid & finite
    return (
        jnp.where(use[:, None], points_body, 0.0),
        jnp.where(use[:, None], xy, 0.0),
        finite,
    )


class _EPnPOut(eqx.Module):
    R: Array
    t: Array
    status: Array
    rms: Array  # pixels (undistorted), over the used points
    planar: Array
    centroid: Array  # (3,) body frame
    normal: Array  # (3,) body frame, least-spread direction


def check_planar_tol(value, name: str = "planar_tol") -> float:
    """``value`` as a float in ``(0, 1)`` (EPnP's planarity threshold on ``sqrt(l3 / l1)``), or
    a ``ValueError`` naming ``name``: a number outside it made EPnP take a general scene for a
    plane (or the reverse) and answer OK with a pose off."""
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not ok or not 0.0 < float(value) < 1.0:
        raise ValueError(f"{name} must be a number in (0, 1); got {value!r}")
    return float(value)


def _control_frame(points_body, weights, planar_tol):
    """Centroid, principal axes (columns, by decreasing spread), spreads and flags (OpenCV's
    ``choose_control_points``: ``c_k = c_0 + sqrt(l_k / n) e_k``)."""
    count = jnp.maximum(jnp.sum(weights), 1.0)
    c0 = jnp.sum(points_body * weights[:, None], axis=0) / count
    d = (points_body - c0) * weights[:, None]
    evals, evecs = _eigh_small(jnp.einsum("na,nb->ab", d, d), descending=True)
    evals = jnp.maximum(evals, 0.0)
    l1 = evals[0]
    degenerate = ~(evals[1] > COLLINEAR_TOL**2 * l1)  # also catches l1 == 0 and NaN
    planar = evals[2] <= planar_tol**2 * l1
    scale = jnp.sqrt(evals / count)
    scale = jnp.stack([scale[0], scale[1], jnp.where(planar, scale[0], scale[2])])
    scale = jnp.where(scale > 0, scale, 1.0)
    return c0, evecs, scale, planar, degenerate


def _solution_status(R, t, rms, points_body, weights, too_few, degenerate):
    """Status of a closed-form solution: input checks first, then the solution's own."""
    depth = _mv(points_body, R[2]) + t[2]
    behind = jnp.any((weights > 0) & ~(depth > 0))
    finite_out = jnp.all(jnp.isfinite(R)) & jnp.all(jnp.isfinite(t))
    return jnp.select(
        [too_few, degenerate, ~finite_out, behind, ~jnp.isfinite(rms)],
        [
            Status.TOO_FEW_POINTS,
            Status.DEGENERATE,
            Status.NO_SOLUTION,
            Status.BEHIND_CAMERA,
            Status.NO_SOLUTION,
        ],
        Status.OK,
    ).astype(jnp.int32)


def _kept(status):
    """Statuses whose pose is returned (``NOT_CONVERGED``: the refinement's last iterate)."""
    return (status == Status.OK) | (status == Status.NOT_CONVERGED)


def _finish(out: _EPnPOut, status, inliers, points_body, pixels, camera) -> PnPResult:
    """Pixel-space RMS (with distortion) for solved problems; identity/zero/inf elsewhere."""
    ok = _kept(status)
    dtype = out.R.dtype
    pose = Pose(jnp.where(ok, out.R, jnp.eye(3, dtype=dtype)), jnp.where(ok, out.t, 0.0))
    rms = out.rms
    if isinstance(camera.dist, jax.core.Tracer) or camera.has_distortion():
        d = camera.project(pose.apply(points_body)) - pixels
        e2 = jnp.where(inliers, jnp.sum(d * d, axis=-1), 0.0)
        rms = jnp.sqrt(jnp.sum(e2) / jnp.maximum(jnp.sum(inliers), 1).astype(dtype))
    rms = jnp.where(ok, rms, jnp.inf)
    return PnPResult(
        pose=pose, status=status, reprojection_error=rms, inliers=inliers, planar=out.planar
    )


def _input_status(status, finite, valid_count, min_points):
    return jnp.select(
        [~finite, valid_count < min_points], [Status.NONFINITE_INPUT, Status.TOO_FEW_POINTS], status
    ).astype(jnp.int32)


class _Problem(eqx.Module):
    """One problem ready for a solver core: finite, masked, normalised."""

    points_body: Array  # (n, 3), zero where invalid
    pixels: Array  # (n, 2) as given
    xy: Array  # (n, 2) normalised undistorted coordinates, zero where invalid
    valid: Array  # (n,) bool
    finite: Array  # bool: every valid entry is finite
    fxy: Array  # (2,) focal lengths
    camera: PinholeCamera


def _problem(points_body, pixels, camera, mask, name, undistort=None) -> _Problem:
    points_body, pixels, camera, valid = _prepare(points_body, pixels, camera, mask, name)
    xy = _normalized(camera, pixels, undistort)
    pw, xy, finite = _sanitize(valid, points_body, xy)
    return _Problem(pw, pixels, xy, valid, finite, jnp.stack([camera.fx, camera.fy]), camera)


def _conclude(prob: _Problem, out: _EPnPOut, min_points: int, inliers=None) -> PnPResult:
    """The :class:`PnPResult` of a solver core's output: input statuses first, then the core's."""
    inliers = prob.valid if inliers is None else inliers
    status = _input_status(out.status, prob.finite, jnp.sum(prob.valid), min_points)
    return _finish(out, status, inliers, prob.points_body, prob.pixels, prob.camera)
