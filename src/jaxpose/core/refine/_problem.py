"""Input checks of the refinement: one finite problem with masks folded into weights."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from jaxpose.core._checks import as_float, check_line_inputs, check_mask, check_pose
from jaxpose.core._compile import small_jit
from jaxpose.core.camera import PinholeCamera, as_camera
from jaxpose.core.geometry import (
    Pose,
)


class _Problem(eqx.Module):
    """One problem with masks folded into weights (``w = mask / sigma^2``; finite data)."""

    points: Array  # (n, 3)
    pixels: Array  # (n, 2)
    w_points: Array  # (n,)
    segments: Array  # (k, 2, 3)
    lines: Array  # (k, 3), normalised so that (l1, l2) is a unit vector
    w_lines: Array  # (k,)
    camera: PinholeCamera


# ----------------------------------------------------------------------------- problem setup


def _shape_error(name, want, got):
    return ValueError(
        f"{name} must have shape {want} (one problem; use jax.vmap for batches); got {got}"
    )


def _prepare(
    pose0, points_body, pixels, camera, mask, sigma, segments_body, lines_img, line_mask, line_sigma
):
    """Validate shapes (``ValueError`` at trace time) and build a finite :class:`_Problem`.

    Returns ``(pose0, problem, valid_points, valid_lines, finite_input, lines_ok)``;
    ``lines_ok`` is false when a valid line of ``lines_img`` has no direction (``l1 = l2 = 0``,
    :attr:`Status.DEGENERATE_LINE`), and the problem is then empty, as for non-finite input.
    The checks run here; the arithmetic is :func:`_assemble`, one compiled program when called
    eagerly.
    """
    check_pose(pose0, "pose0")
    camera = as_camera(camera)
    points_body = as_float(points_body, name="points_body")
    dtype = points_body.dtype
    pixels = as_float(pixels, dtype, name="pixels")
    if points_body.ndim != 2 or points_body.shape[1] != 3:
        raise _shape_error("points_body", "(n, 3)", points_body.shape)
    n = points_body.shape[0]
    if pixels.shape != (n, 2):
        raise _shape_error("pixels", f"({n}, 2) like points_body", pixels.shape)
    pose0 = Pose(as_float(pose0.R, dtype), as_float(pose0.t, dtype))

    def _sigma(s, count, name):  # None (1 pixel), a scalar or one value per feature
        if s is None:
            return None
        s = as_float(s, dtype)
        if s.ndim > 1 or (s.ndim == 1 and s.shape[0] != count):
            raise _shape_error(name, f"() or ({count},)", s.shape)
        return s

    valid = None if mask is None else check_mask(mask, n, "mask")
    sig = _sigma(sigma, n, "sigma")
    segments = lines = lvalid = lsig = None
    if check_line_inputs(segments_body, lines_img, line_mask=line_mask, line_sigma=line_sigma):
        segments = as_float(segments_body, dtype)
        lines = as_float(lines_img, dtype)
        if segments.ndim != 3 or segments.shape[1:] != (2, 3):
            raise _shape_error("segments_body", "(k, 2, 3)", segments.shape)
        k = segments.shape[0]
        if lines.shape != (k, 3):
            raise _shape_error("lines_img", f"({k}, 3) like segments_body", lines.shape)
        lvalid = None if line_mask is None else check_mask(line_mask, k, "line_mask")
        lsig = _sigma(
            sigma
            if line_sigma is None and sigma is not None and jnp.ndim(sigma) == 0
            else line_sigma,
            k,
            "line_sigma",
        )
    return _assemble(pose0, points_body, pixels, camera, valid, sig, segments, lines, lvalid, lsig)


@small_jit
def _assemble(pose0, points_body, pixels, camera, valid, sig, segments, lines, lvalid, lsig):
    """:func:`_prepare`'s problem from checked inputs (``None``: every feature valid, one pixel
    of noise, no lines)."""
    dtype = points_body.dtype
    n = points_body.shape[0]
    R0, t0 = pose0.R, pose0.t
    valid = jnp.ones((n,), bool) if valid is None else valid
    sig = jnp.ones((n,), dtype) if sig is None else jnp.broadcast_to(sig, (n,))
    finite_pts = jnp.all(jnp.isfinite(points_body), -1) & jnp.all(jnp.isfinite(pixels), -1)
    finite_pts = finite_pts & jnp.isfinite(sig) & (sig > 0)
    if segments is None:
        segments = jnp.zeros((0, 2, 3), dtype)
        lines = jnp.zeros((0, 3), dtype)
    k = segments.shape[0]
    lvalid = jnp.ones((k,), bool) if lvalid is None else lvalid
    lsig = jnp.ones((k,), dtype) if lsig is None else jnp.broadcast_to(lsig, (k,))
    l12 = jnp.sum(lines[:, :2] ** 2, -1)
    finite_lines = (
        jnp.all(jnp.isfinite(segments), (-1, -2))
        & jnp.all(jnp.isfinite(lines), -1)
        & jnp.isfinite(lsig)
        & (lsig > 0)
    )
    lines_ok = jnp.all((l12 > 0) | ~lvalid | ~finite_lines)  # a non-finite line is said so
    finite_pose = jnp.all(jnp.isfinite(R0)) & jnp.all(jnp.isfinite(t0))
    finite_cam = jnp.all(jnp.isfinite(jnp.stack([camera.fx, camera.fy, camera.cx, camera.cy])))
    finite_input = (
        finite_pose & finite_cam & jnp.all(finite_pts | ~valid) & jnp.all(finite_lines | ~lvalid)
    )
    use = valid & finite_pts & finite_input & lines_ok
    luse = lvalid & finite_lines & (l12 > 0) & finite_input & lines_ok
    l12_safe = jnp.where(luse, l12, 1.0)
    lines_n = jnp.where(
        luse[:, None], lines / jnp.sqrt(l12_safe)[:, None], jnp.array([1.0, 0, 0], dtype)
    )
    problem = _Problem(
        points=jnp.where(use[:, None], points_body, 0.0),
        pixels=jnp.where(use[:, None], pixels, 0.0),
        w_points=jnp.where(use, 1.0 / jnp.where(use, sig, 1.0) ** 2, 0.0),
        segments=jnp.where(luse[:, None, None], segments, 0.0),
        lines=lines_n,
        w_lines=jnp.where(luse, 1.0 / jnp.where(luse, lsig, 1.0) ** 2, 0.0),
        camera=camera,
    )
    pose0 = Pose(
        jnp.where(finite_pose, R0, jnp.eye(3, dtype=dtype)),
        jnp.where(finite_pose, t0, jnp.array([0.0, 0.0, 1.0], dtype)),
    )
    return pose0, problem, valid, lvalid, finite_input, lines_ok
