"""The result type of :func:`refine_pose`."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float, Int

from jaxpose.core.geometry import (
    Pose,
)


class RefineResult(eqx.Module):
    """Result of :func:`refine_pose` (leading batch axes under ``vmap``).

    Attributes:
        pose: refined pose (the initial pose, sanitised to be finite, when the input was bad).
        status: ``int32`` :class:`~jaxpose.core.status.Status`: ``OK``, ``NOT_CONVERGED``
            (iteration budget spent), ``SINGULAR`` (normal equations not invertible),
            ``BEHIND_CAMERA`` (a valid point at ``z <= 0`` at the result), ``NOT_A_ROTATION``
            (``pose0.R`` is not a rotation), ``TOO_FEW_POINTS`` (fewer than :data:`MIN_FEATURES`
            valid features), ``NONFINITE_INPUT``, ``DEGENERATE_LINE`` (a valid line of
            ``lines_img`` with ``l1 = l2 = 0``).
        rms_px: RMS reprojection error in pixels at the result, ``sqrt(mean |e|^2)`` over the
            valid points' 2-D errors (and the lines' 2-vectors of endpoint distances), unweighted;
            ``inf`` for bad input.
        num_steps: iterations taken.
        cost: final robust cost (Yang et al. 2024 eq. 10, dimensionless: residuals divided by
            sigma).
    """

    pose: Pose
    status: Int[Array, ""]
    rms_px: Float[Array, ""]
    num_steps: Int[Array, ""]
    cost: Float[Array, ""]
