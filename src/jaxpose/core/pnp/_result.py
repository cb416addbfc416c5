"""The result type of every PnP solver."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Bool, Float, Int

from jaxpose.core.geometry import Pose


class PnPResult(eqx.Module):
    """Pose from a PnP solver (leading batch axes under ``vmap``).

    Attributes:
        pose: :class:`~jaxpose.core.geometry.Pose` ``x_cam = R @ x_body + t``; identity rotation and
            zero translation where ``status != 0``.
        status: ``int32`` :class:`~jaxpose.core.status.Status`, 0 when solved.
        reprojection_error: RMS reprojection error in pixels over the points used (the valid
            points, or RANSAC's inliers); ``inf`` where ``status != 0``.
        inliers: ``(n,)`` bool, the points the pose was computed from.
        planar: bool, the points were treated as planar (three control points).
    """

    pose: Pose
    status: Int[Array, ...]
    reprojection_error: Float[Array, ...]
    inliers: Bool[Array, "... n"]
    planar: Bool[Array, ...]

    @property
    def R(self) -> Float[Array, "... 3 3"]:
        return self.pose.R

    @property
    def t(self) -> Float[Array, "... 3"]:
        return self.pose.t

    @property
    def rvec(self) -> Float[Array, "... 3"]:
        """Rotation vector of ``R`` (radians), OpenCV's ``rvec`` (``t`` is its ``tvec``)."""
        return self.pose.rotvec
