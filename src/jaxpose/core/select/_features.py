"""The eager entry point: choose ``m`` feature points of a target seen at a pose by a camera."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from jaxpose.core._checks import is_rotation
from jaxpose.core.camera import PinholeCamera, as_camera
from jaxpose.core.dilution import information_blocks
from jaxpose.core.geometry import DEFAULT_EULER_SEQUENCE, Pose
from jaxpose.core.select._exhaustive import exhaustive
from jaxpose.core.select._greedy import check_criterion, greedy
from jaxpose.core.select._kernel import check_m, subset_dop
from jaxpose.core.select._quasi import (
    _check_points,
    _status,
    _valid,
    one_step,
    quasi_optimal,
    raise_for_selection_status,
)
from jaxpose.core.status import Status

__all__ = ["METHODS", "select_features"]

METHODS = ("quasi", "one-step", "greedy", "exhaustive", "bnb")


def select_features(
    points_body: Float[ArrayLike, "n 3"],
    pose: Pose,
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    m: int,
    *,
    method: str = "quasi",
    criterion: str = "pdop",
    sequence: str = DEFAULT_EULER_SEQUENCE,
    parameterization: str = "euler",
    sigma: Float[ArrayLike, " n"] | Float[ArrayLike, ""] | float | None = None,
    mask: Bool[ArrayLike, " n"] | None = None,
) -> Int[Array, " m"]:
    """Indices (ascending) of the ``m`` feature points to use, by the chosen method.

    Args:
        points_body: ``(n, 3)`` feature points in the target body frame, metres.
        pose: relative pose (``x_cam = R p + t``).
        camera: :class:`~jaxpose.core.camera.PinholeCamera` or ``3x3`` ``K``.
        m: number of points to keep, ``4 <= m <= n``.
        method: ``"quasi"`` (Ning et al.'s quasi-optimal rule), ``"one-step"``, ``"greedy"``
            (backward elimination on the DOP), ``"exhaustive"`` (all ``C(n, m)`` subsets) or
            ``"bnb"`` (exact branch and bound, :mod:`jaxpose.core.select.bnb`).
        criterion: ``"pdop"`` or ``"adop"``: what the DOP-based methods minimise (the quasi rules
            use geometry only and ignore it).
        sequence, parameterization: attitude state of the DOP (:func:`jaxpose.core.dilution.dop`).
        sigma: pixel noise per point or shared (weighted DOP); the quasi rules ignore it.
        mask: ``(n,)`` bool, valid points.

    Raises:
        ValueError: wrong shapes, ``m`` out of range, an unknown method or criterion, NaN/inf
            input, fewer than ``m`` valid points, a valid point at or behind the camera, or
            (DOP-based methods) no non-singular subset.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}; got {method!r}")
    check_criterion(criterion)
    points_body = _check_points(points_body, "select_features")
    n = points_body.shape[0]
    m = check_m(m, n, "select_features")
    if jnp.shape(pose.R) != (3, 3) or jnp.shape(pose.t) != (3,):
        raise ValueError(
            f"select_features: pose must hold one rotation (3, 3) and one translation (3,); got "
            f"{jnp.shape(pose.R)} and {jnp.shape(pose.t)}"
        )
    camera = as_camera(camera)
    valid = _valid(mask, n, "select_features")
    if not (jnp.all(jnp.isfinite(pose.R)) and jnp.all(jnp.isfinite(pose.t))):
        raise ValueError("select_features: the pose holds NaN or inf")
    if not bool(is_rotation(pose.R)):
        raise ValueError(f"select_features: {Status.NOT_A_ROTATION.message}")
    if sigma is not None and not isinstance(sigma, jax.core.Tracer):
        known = np.asarray(sigma, dtype=float)
        if not np.all((known > 0) & np.isfinite(known)):
            raise ValueError(
                f"select_features: sigma (pixel noise) must be positive and finite; got "
                f"{known.tolist()}"
            )
    rows = np.flatnonzero(np.asarray(valid) & ~np.all(np.isfinite(np.asarray(points_body)), -1))
    if rows.size:
        raise ValueError(
            f"select_features: points_body holds NaN or inf (rows {rows[:5].tolist()}); mask "
            f"them out with mask="
        )
    points_cam = pose.apply(points_body)
    raise_for_selection_status(_status(points_cam, valid, m), valid, m, "select_features")
    if method == "quasi":
        return quasi_optimal(points_cam, m, mask=mask)
    if method == "one-step":
        return one_step(points_cam, m, mask=mask)
    blocks = eqx.filter_jit(information_blocks)(
        points_body,
        pose,
        camera,
        sigma=sigma,
        mask=valid,
        sequence=sequence,
        parameterization=parameterization,
    )
    if method == "greedy":
        idx = greedy(blocks, m, criterion=criterion, mask=mask)
        if not np.isfinite(float(subset_dop(blocks, idx)[0])):
            raise ValueError(
                f"select_features: {Status.SINGULAR.message} for every subset greedy reached"
            )
        return idx
    if method == "exhaustive":
        res = exhaustive(blocks, m, mask=mask, throw=True)
        return res.pdop_idx if criterion == "pdop" else res.adop_idx
    from jaxpose.core.select.bnb import branch_and_bound

    keep = jnp.flatnonzero(valid)  # eager: the search runs on the valid points only
    return keep[branch_and_bound(blocks[keep], m, criterion=criterion).idx].astype(jnp.int32)
