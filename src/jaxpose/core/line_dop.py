"""Information of image-line observations in the DOP state (points and lines together).

Ning, Zhang, Wang (2018) define the DOP of a set of feature *points* (eqs. 7, 14-15); the stereo
tracker of Yang et al. (2024) also observes straight edges. A 3-D segment with body-frame endpoints
``P_1, P_2`` (metres) is observed as an image line ``l = (p_1, 1) x (p_2, 1)`` (Yang et al. eq. 7)
and contributes the two signed distances, in pixels, of its projected endpoints to that line
(eq. 9)::

    d_k(x) = (l_1 u_k(x) + l_2 v_k(x) + l_3) / sqrt(l_1^2 + l_2^2),    k = 1, 2,

where ``(u_k, v_k)(x)`` is the pixel of ``P_k`` at the state ``x = (T, eps)`` of
:mod:`jaxpose.core.dilution` and the observed line ``l`` is held fixed at its value at the true
pose (the projected endpoints lie on it there, so ``d_k = 0``). Its ``2 x 6`` Jacobian ``L`` at the
true pose gives the information block ``A = L^T L / sigma^2`` in the same state, the same units
and the same attitude parameterisation as the point blocks of
:func:`jaxpose.core.dilution.information_blocks`, so point and line blocks add:
``Q = (sum_points A_i + sum_lines A_j)^-1`` and ``PDOP``, ``ADOP`` as in Ning et al. eq. 15
(:func:`jaxpose.core.dilution.dop_from_information`); every DOP-based selection method of
:mod:`jaxpose.core.select` takes a stack of both kinds.

In closed form, with ``n`` the unit normal of the image line and ``H_k = d(u_k, v_k) / dx`` the
point Jacobian of endpoint ``k`` (Ning et al. eq. 7), row ``k`` of ``L`` is ``n^T H_k``; hence
``A_line <= A_point(P_1) + A_point(P_2)`` in the PSD order. Here ``L`` is computed by forward-mode
autodiff of ``d_k`` (``jax.jacfwd``), like the point blocks. A line block has rank at most 2 and
annihilates every motion that keeps the 3-D line on itself: a slide along the line (``dT = R u``
for a body-frame direction ``u``) and a rotation about it.

A segment seen end-on (both endpoints on one pixel) has no line; its block is zero (NaN-free, also
in gradients). A valid segment of zero length (both endpoints equal) is not a segment:
:func:`line_information_blocks` refuses it when its values are known (a traced one gives a zero
block). As for the point blocks, nothing here checks that the endpoints are in front of
the camera.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxpose.core._checks import check_mask, check_pose, check_rotation, check_rows
from jaxpose.core.camera import PinholeCamera, as_camera
from jaxpose.core.dilution import PARAMETERIZATIONS, _check_sigma, _state_to_pixels
from jaxpose.core.geometry import DEFAULT_EULER_SEQUENCE, Pose, parse_euler_sequence
from jaxpose.core.residuals import line_from_segment

__all__ = ["line_information_blocks", "line_jacobians"]


def _segment_jacobian(x0, pixels, segment: Float[Array, "2 3"]) -> Float[Array, "2 6"]:
    """``d(d_1, d_2) / dx`` at ``x0`` with the observed line fixed at its value there."""
    ends = jax.vmap(lambda p: pixels(x0, p))(segment)  # (2, 2) observed endpoints
    line = line_from_segment(ends[0], ends[1])  # a constant inside distances(x)
    norm2 = jnp.sum(line[:2] ** 2)
    # Double-where: an end-on segment (no image line) gives zero rows and NaN-free gradients.
    ok = norm2 > 0
    inv_norm = jnp.where(ok, 1.0 / jnp.sqrt(jnp.where(ok, norm2, 1.0)), 0.0)

    def distances(x):
        pix = jax.vmap(lambda p: pixels(x, p))(segment)
        return (pix @ line[:2] + line[2]) * inv_norm

    return jax.jacfwd(distances)(x0)


def line_jacobians(
    segments_body: Float[ArrayLike, "n 2 3"],
    pose: Pose,
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    sequence: str = DEFAULT_EULER_SEQUENCE,
    parameterization: str = "euler",
) -> Float[Array, "n 2 6"]:
    """Per-segment Jacobians ``L_j = d(d_1, d_2) / d(T, eps)`` of the endpoint-to-line distances.

    Yang et al. (2024) eq. 9 at the true pose, differentiated by ``jax.jacfwd``; row ``k`` equals
    ``n^T H_k`` (``n`` the unit normal of the image line, ``H_k`` the point Jacobian of endpoint
    ``k``, Ning et al. eq. 7). Units: pixels per metre (``T``) and pixels per radian (``eps``).

    Args:
        segments_body: ``(n, 2, 3)`` segment endpoints in the target body frame, metres.
        pose: true relative pose (``x_cam = R p + t``).
        camera: :class:`~jaxpose.core.camera.PinholeCamera` or ``3x3`` ``K``.
        sequence, parameterization: attitude state, as in :func:`jaxpose.core.dilution.dop`.

    Returns:
        ``(n, 2, 6)``; zero rows for a segment seen end-on.
    """
    check_pose(pose)
    segments_body = check_rows(segments_body, (2, 3), "segments_body")
    _check_options(sequence, parameterization)
    return _jacobians(segments_body, pose, as_camera(camera), sequence, parameterization)


def _check_options(sequence: str, parameterization: str) -> None:
    if parameterization not in PARAMETERIZATIONS:
        raise ValueError(
            f"parameterization must be one of {PARAMETERIZATIONS}; got {parameterization!r}"
        )
    parse_euler_sequence(sequence)


@eqx.filter_jit
def _jacobians(segments_body, pose, camera, sequence, parameterization):
    x0, pixels = _state_to_pixels(pose, camera, sequence, parameterization)
    return jax.vmap(lambda s: _segment_jacobian(x0, pixels, s))(segments_body)


def line_information_blocks(
    segments_body: Float[ArrayLike, "n 2 3"],
    pose: Pose,
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    sigma: Float[ArrayLike, " n"] | Float[ArrayLike, ""] | float | None = None,
    mask: Bool[ArrayLike, " n"] | None = None,
    sequence: str = DEFAULT_EULER_SEQUENCE,
    parameterization: str = "euler",
) -> Float[Array, "n 6 6"]:
    """Per-segment information ``A_j = L_j^T L_j / sigma_j^2`` (zero for masked-out segments).

    The blocks live in the state of :func:`jaxpose.core.dilution.information_blocks` (``(T, eps)``,
    metres and radians, the same ``sequence`` and ``parameterization``), so point and line
    blocks add, and a stack of both is the input of :func:`jaxpose.core.select.greedy`,
    :func:`~jaxpose.core.select.exhaustive` and :func:`~jaxpose.core.select.branch_and_bound`;
    ``dop_from_information(sum of blocks)`` gives the PDOP and ADOP of a mixed set.

    Args:
        segments_body: ``(n, 2, 3)`` segment endpoints in the target body frame, metres.
        pose: true relative pose (``x_cam = R p + t``).
        camera: :class:`~jaxpose.core.camera.PinholeCamera` or ``3x3`` ``K``.
        sigma: noise (pixels, positive) of each endpoint-to-line distance, one per segment or
            shared; ``None`` for unit weights (the plain DOP).
        mask: ``(n,)`` bool, valid segments of a padded set; masked-out ones give zero blocks
            whatever they hold (NaN included).
        sequence, parameterization: attitude state, as in :func:`jaxpose.core.dilution.dop`.

    Returns:
        ``(n, 6, 6)`` symmetric positive semi-definite blocks of rank at most 2, state order
        ``(T, eps)``.

    Raises:
        ValueError: wrong shapes or options; when known (not traced), a ``pose.R`` that is not a
            rotation or a valid segment of zero length (both endpoints equal: no line).
    """
    check_pose(pose)
    check_rotation(pose.R, "pose.R", nonfinite_ok=True, prefix="line_information_blocks: ")
    segments_body = check_rows(segments_body, (2, 3), "segments_body")
    _check_options(sequence, parameterization)
    n = segments_body.shape[0]
    valid = None if mask is None else check_mask(mask, n)
    _check_lengths(segments_body, valid)
    sigma = _check_sigma(sigma, n, segments_body.dtype)  # (n,) or None
    return _blocks(segments_body, pose, as_camera(camera), sigma, valid, sequence, parameterization)


def _check_lengths(segments_body, valid) -> None:
    """``ValueError`` naming ``segments_body`` and the index of the first valid segment whose two
    endpoints are equal, when both are known (a zero-length segment has no image line)."""
    if isinstance(segments_body, jax.core.Tracer) or isinstance(valid, jax.core.Tracer):
        return
    s = np.asarray(segments_body)
    zero = np.all(s[:, 0] == s[:, 1], axis=-1)
    if valid is not None:
        zero &= np.asarray(valid)
    if zero.any():
        i = int(np.flatnonzero(zero)[0])
        raise ValueError(
            f"line_information_blocks: segments_body[{i}] has zero length (both endpoints at "
            f"{s[i, 0].tolist()}; {int(zero.sum())} such segment(s)): a segment needs two "
            "distinct endpoints (mask it out with mask=)"
        )


@eqx.filter_jit
def _blocks(segments_body, pose, camera, sigma, valid, sequence, parameterization):
    n = segments_body.shape[0]
    if valid is not None:
        # Masked-out segments are replaced by a harmless one in front of the camera (values and
        # gradients stay finite whatever they held), then their blocks are zeroed.
        dummy = (
            jnp.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]], segments_body.dtype) - pose.t
        ) @ pose.R
        segments_body = jnp.where(valid[:, None, None], segments_body, dummy)
    L = _jacobians(segments_body, pose, camera, sequence, parameterization)
    w = jnp.ones(n, dtype=L.dtype)
    if sigma is not None:
        w = w / sigma.astype(L.dtype) ** 2
    blocks = jnp.einsum("nki,nkj,n->nij", L, L, w)
    if valid is not None:
        blocks = jnp.where(valid[:, None, None], blocks, 0.0)
    return blocks
