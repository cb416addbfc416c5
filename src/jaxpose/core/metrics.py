"""Pose and detection metrics (pure JAX; broadcast over leading batch axes).

Sharma, Ventura, D'Amico 2018, Sec. V: ``E_T = |t_true - t_est|`` per axis (eq. 30), ``E_R`` the
Euler angles of ``R_diff = R_est R_true^T`` (eqs. 31-32), ``E_2D`` the mean reprojection distance
(eq. 22), success ``||t_true - t_est|| < 0.30 m`` and rotation error ``< 10 deg``, endpoint and ROI
true-positive rate and positive predictive value (eqs. 33-34, 5-pixel radius for endpoints). The
ESA / Kelvins score of SPEED+ (Park et al. 2022; the SPEED+ challenge rules):
``e_t = ||t_true - t_est|| / ||t_true||``, ``e_q = 2 arccos |<q_est, q_true>|``, score
``e_q + e_t``.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.geometry import (
    DEFAULT_EULER_SEQUENCE,
    Pose,
    dcm_to_euler,
    dcm_to_quat,
    rotation_angle,
)

__all__ = [
    "SUCCESS_ROTATION_DEG",
    "SUCCESS_TRANSLATION_M",
    "endpoint_rates",
    "esa_score",
    "reprojection_error_2d",
    "roi_rates",
    "rotation_error",
    "rotation_error_euler",
    "success",
    "translation_error",
]

SUCCESS_TRANSLATION_M = 0.30
SUCCESS_ROTATION_DEG = 10.0


def translation_error(
    t_est: Float[ArrayLike, "... 3"], t_true: Float[ArrayLike, "... 3"]
) -> Float[Array, "... 3"]:
    """``E_T`` (eq. 30): element-wise ``|t_true - t_est|``, metres."""
    return jnp.abs(jnp.asarray(t_true) - jnp.asarray(t_est))


def rotation_error_euler(
    R_est: Float[ArrayLike, "... 3 3"],
    R_true: Float[ArrayLike, "... 3 3"],
    sequence: str = DEFAULT_EULER_SEQUENCE,
) -> Float[Array, "... 3"]:
    """``E_R`` (eqs. 31-32): Euler angles (radians) of ``R_est @ R_true.T`` (camera axes)."""
    R_diff = jnp.asarray(R_est) @ jnp.swapaxes(jnp.asarray(R_true), -1, -2)
    return dcm_to_euler(R_diff, sequence)


def rotation_error(
    R_est: Float[ArrayLike, "... 3 3"], R_true: Float[ArrayLike, "... 3 3"]
) -> Float[Array, ...]:
    """Geodesic angle (radians) between the two attitudes."""
    return rotation_angle(jnp.asarray(R_est), jnp.asarray(R_true))


def success(
    pose_est: Pose,
    pose_true: Pose,
    *,
    translation_m: float = SUCCESS_TRANSLATION_M,
    rotation_deg: float = SUCCESS_ROTATION_DEG,
) -> Bool[Array, ...]:
    """``||t_true - t_est|| < 0.30 m`` and rotation error ``< 10 deg`` (Sharma et al. 2018)."""
    dt = jnp.linalg.norm(jnp.asarray(pose_true.t) - jnp.asarray(pose_est.t), axis=-1)
    return (dt < translation_m) & (
        rotation_error(pose_est.R, pose_true.R) < jnp.deg2rad(rotation_deg)
    )


def esa_score(
    pose_est: Pose, pose_true: Pose
) -> tuple[Float[Array, ...], Float[Array, ...], Float[Array, ...]]:
    """ESA / Kelvins score per image: ``(score, e_q, e_t)`` with ``score = e_q + e_t`` (radians +
    relative translation error)."""
    t_true, t_est = jnp.asarray(pose_true.t), jnp.asarray(pose_est.t)
    e_t = jnp.linalg.norm(t_true - t_est, axis=-1) / jnp.linalg.norm(t_true, axis=-1)
    q_est, q_true = dcm_to_quat(pose_est.R), dcm_to_quat(pose_true.R)
    dot = jnp.clip(jnp.abs(jnp.sum(q_est * q_true, axis=-1)), 0.0, 1.0)
    e_q = 2.0 * jnp.arccos(dot)
    return e_q + e_t, e_q, e_t


def reprojection_error_2d(
    pose: Pose,
    points_body: Float[ArrayLike, "... n 3"],
    pixels: Float[ArrayLike, "... n 2"],
    camera: PinholeCamera,
    mask: Bool[ArrayLike, "... n"] | None = None,
) -> Float[Array, ...]:
    """``E_2D`` (eq. 22): mean pixel distance between image points and projected model points
    over the valid points (``inf`` when none is valid)."""
    d = jnp.linalg.norm(camera.project(pose.apply(points_body)) - pixels, axis=-1)
    if mask is None:
        return jnp.mean(d, axis=-1)
    mask = jnp.asarray(mask)
    n = jnp.sum(mask, axis=-1).astype(d.dtype)
    total = jnp.sum(jnp.where(mask, d, 0.0), axis=-1)
    return jnp.where(n > 0, total / jnp.maximum(n, 1.0), jnp.inf)


def endpoint_rates(
    detected: Float[ArrayLike, "m 2"], truth: Float[ArrayLike, "k 2"], radius_px: float = 5.0
) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """Endpoint ``(TPR, PPV)`` (eqs. 33-34): a true endpoint is found when a detected one lies
    within ``radius_px``; a detection is a true positive when a true endpoint lies that close.
    Empty sets give 0."""
    detected, truth = jnp.asarray(detected).reshape(-1, 2), jnp.asarray(truth).reshape(-1, 2)
    if detected.shape[0] == 0 or truth.shape[0] == 0:
        zero = jnp.zeros((), dtype=jnp.result_type(float))
        return zero, zero
    d = jnp.linalg.norm(detected[:, None] - truth[None], axis=-1)
    close = d <= radius_px
    tpr = jnp.mean(jnp.any(close, axis=0).astype(d.dtype))
    ppv = jnp.mean(jnp.any(close, axis=1).astype(d.dtype))
    return tpr, ppv


def roi_rates(
    roi_est: Float[ArrayLike, "... 4"], roi_true: Float[ArrayLike, "... 4"]
) -> tuple[Float[Array, ...], Float[Array, ...]]:
    """ROI ``(TPR, PPV)`` by area: ``|est & true| / |true|`` and ``|est & true| / |est|`` of boxes
    ``[u0, v0, u1, v1]``."""
    a, b = jnp.asarray(roi_est), jnp.asarray(roi_true)
    w = jnp.clip(jnp.minimum(a[..., 2], b[..., 2]) - jnp.maximum(a[..., 0], b[..., 0]), 0.0)
    h = jnp.clip(jnp.minimum(a[..., 3], b[..., 3]) - jnp.maximum(a[..., 1], b[..., 1]), 0.0)
    inter = w * h
    area = lambda r: jnp.clip(r[..., 2] - r[..., 0], 0.0) * jnp.clip(r[..., 3] - r[..., 1], 0.0)  # noqa: E731
    tiny = jnp.finfo(inter.dtype).tiny
    return inter / jnp.maximum(area(b), tiny), inter / jnp.maximum(area(a), tiny)
