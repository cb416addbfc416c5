"""Quasi-optimal feature-point selection (Ning, Zhang, Wang 2018, Sec. 4).

The rule needs only the directions of the points from the camera, not the DOP:

* unit vectors ``e_i = rho_i / |rho_i|`` of the camera-frame points ``rho_i``;
* cost ``c_ij = cos^2(theta_ij) = (e_i . e_j)^2`` (Park and How's cost, the sum of squares of a row
  of ``E^T E``; the paper says only "a function of the angle", see ``docs/selection.md``);
* redundancy ``r_i = sum_j c_ij`` (the ``j = i`` term adds 1 to every ``r_i`` and changes
  nothing);
* remove the point of largest redundancy ``k``, update ``r_i <- r_i - c_ik``, and repeat until
  ``m`` points remain (:func:`quasi_optimal`); or remove the ``n - m`` largest initial
  redundancies at once (:func:`one_step`).

Ties are broken deterministically: among equal redundancies the lowest index is removed first.
The selection depends only on the directions, so it does not change with focal length, pixel size
or a common scale of the scene.

Masked-out points (``mask=False``, padding of a variable-size set) are never selected: they are
removed first. If fewer than ``m`` points are valid, the remaining slots are filled with masked
points; :func:`selection_status` reports ``TOO_FEW_POINTS`` then (and the other statuses of bad
input), so batched code can tell. The eager entry point
:func:`jaxpose.core.select.select_features` raises instead.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from jaxpose.core.select._kernel import check_m, check_mask, too_few_valid
from jaxpose.core.status import Status, raise_for_status

__all__ = ["one_step", "quasi_optimal", "redundancies", "selection_status"]


def _check_points(points_cam, what: str) -> Array:
    points_cam = jnp.asarray(points_cam)
    if not jnp.issubdtype(points_cam.dtype, jnp.floating):
        points_cam = points_cam.astype(jnp.result_type(float))
    if points_cam.ndim != 2 or points_cam.shape[-1] != 3:
        raise ValueError(
            f"{what}: points_cam must have shape (n, 3) (camera-frame points of one problem; use "
            f"jax.vmap for batches); got {points_cam.shape}"
        )
    return points_cam


def _valid(mask, n: int, what: str) -> Array:
    mask = check_mask(mask, (n,), what)
    return jnp.ones((n,), bool) if mask is None else mask


def _eager_check(points_cam, valid, m: int, what: str) -> None:
    """Raise ``ValueError`` for bad values when called eagerly (no-op under tracing)."""
    if isinstance(points_cam, jax.core.Tracer) or isinstance(valid, jax.core.Tracer):
        return
    raise_for_selection_status(_status(points_cam, valid, m), valid, m, what)


def raise_for_selection_status(status, valid, m: int, what: str) -> None:
    """:func:`~jaxpose.core.status.raise_for_status`, with a message naming ``mask`` and ``m``
    (and the counts) for ``TOO_FEW_POINTS``."""
    if int(status) == Status.TOO_FEW_POINTS:
        raise too_few_valid(valid, m, what)
    raise_for_status(status, what)


def _status(points_cam, valid, m: int) -> Array:
    finite = jnp.all(jnp.isfinite(points_cam) | ~valid[:, None])
    behind = jnp.any(valid & ~(points_cam[:, 2] > 0))
    return jnp.select(
        [~finite, jnp.sum(valid) < m, behind],
        [Status.NONFINITE_INPUT, Status.TOO_FEW_POINTS, Status.BEHIND_CAMERA],
        Status.OK,
    ).astype(jnp.int32)


def selection_status(
    points_cam: Float[ArrayLike, "n 3"], m: int, *, mask: Bool[ArrayLike, " n"] | None = None
) -> Int[Array, ""]:
    """``int32`` :class:`~jaxpose.core.status.Status` of a selection problem (0 when fine).

    ``NONFINITE_INPUT`` for NaN/inf in a valid point, ``TOO_FEW_POINTS`` when fewer than ``m``
    points are valid, ``BEHIND_CAMERA`` when a valid point has ``z <= 0``.
    """
    points_cam = _check_points(points_cam, "selection_status")
    n = points_cam.shape[0]
    m = check_m(m, n, "selection_status")
    return _status(points_cam, _valid(mask, n, "selection_status"), m)


def _costs(points_cam: Array, valid: Array) -> Array:
    """``c_ij = (e_i . e_j)^2`` between valid points (0 where either is masked or degenerate)."""
    norm = jnp.linalg.norm(jnp.where(valid[:, None], points_cam, 1.0), axis=-1)
    safe = valid & (norm > 0)
    e = jnp.where(safe[:, None], points_cam, 0.0) / jnp.where(safe, norm, 1.0)[:, None]
    c = (e @ e.T) ** 2
    return jnp.where(safe[:, None] & safe[None, :], c, 0.0)


def redundancies(
    points_cam: Float[ArrayLike, "n 3"], mask: Bool[ArrayLike, " n"] | None = None
) -> Float[Array, " n"]:
    """Initial redundancies ``r_i = sum_j cos^2(theta_ij)`` over the valid points (``j = i``
    included); 0 for masked-out points."""
    points_cam = _check_points(points_cam, "redundancies")
    valid = _valid(mask, points_cam.shape[0], "redundancies")
    return jnp.sum(_costs(points_cam, valid), axis=1)


def _priority(r: Array, valid: Array) -> Array:
    """Removal key: masked points first (``+inf``), then the largest redundancy."""
    return jnp.where(valid, r, jnp.inf)


def _keep_to_indices(keep: Array, m: int) -> Array:
    return jnp.nonzero(keep, size=m, fill_value=0)[0].astype(jnp.int32)


def quasi_optimal(
    points_cam: Float[ArrayLike, "n 3"], m: int, *, mask: Bool[ArrayLike, " n"] | None = None
) -> Int[Array, " m"]:
    """Quasi-optimal ``m`` of ``n`` points (iterative removal with the incremental update).

    Args:
        points_cam: ``(n, 3)`` feature points in the camera frame (``rho_i = R p_i + T``).
        m: number of points to keep (static), ``4 <= m <= n``.
        mask: ``(n,)`` bool, valid points of a padded set (never selected when ``False``).

    Returns:
        ``(m,)`` ``int32`` indices, ascending.

    Pure JAX (``jit``, ``vmap``); ``O(n^2)`` for the costs and ``n - m`` steps of ``O(n)``. Eager
    calls raise ``ValueError`` for NaN input, too few valid points or points behind the camera;
    traced calls return deterministic indices and :func:`selection_status` tells what went wrong.
    """
    points_cam = _check_points(points_cam, "quasi_optimal")
    n = points_cam.shape[0]
    m = check_m(m, n, "quasi_optimal")
    valid = _valid(mask, n, "quasi_optimal")
    _eager_check(points_cam, valid, m, "quasi_optimal")
    return _quasi(points_cam, valid, m)


@functools.partial(jax.jit, static_argnums=2)
def _quasi(points_cam, valid, m: int):
    n = points_cam.shape[0]
    c = _costs(points_cam, valid)

    def remove_one(_, state):
        r, keep = state
        k = jnp.argmax(jnp.where(keep, _priority(r, valid), -jnp.inf))
        return r - c[:, k], keep.at[k].set(False)

    init = (jnp.sum(c, axis=1), jnp.ones((n,), bool))
    _, keep = jax.lax.fori_loop(0, n - m, remove_one, init)
    return _keep_to_indices(keep, m)


def one_step(
    points_cam: Float[ArrayLike, "n 3"], m: int, *, mask: Bool[ArrayLike, " n"] | None = None
) -> Int[Array, " m"]:
    """One-step selection: drop the ``n - m`` points of largest *initial* redundancy at once.

    Same arguments, return value and error behaviour as :func:`quasi_optimal`; ties remove the
    lowest index first.
    """
    points_cam = _check_points(points_cam, "one_step")
    n = points_cam.shape[0]
    m = check_m(m, n, "one_step")
    valid = _valid(mask, n, "one_step")
    _eager_check(points_cam, valid, m, "one_step")
    return _one_step(points_cam, valid, m)


@functools.partial(jax.jit, static_argnums=2)
def _one_step(points_cam, valid, m: int):
    n = points_cam.shape[0]
    key = _priority(jnp.sum(_costs(points_cam, valid), axis=1), valid)
    order = jnp.argsort(-key, stable=True)
    keep = jnp.ones((n,), bool).at[order[: n - m]].set(False)
    return _keep_to_indices(keep, m)
