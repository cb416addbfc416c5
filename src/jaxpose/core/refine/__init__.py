"""Pose refinement, pose covariance and pose sensitivity (pure JAX: jit, vmap, grad).

Problem: minimise the joint robust cost of Yang et al. 2024 eq. 10 over the pose ``(R, t)``
(``x_cam = R p + t``),

    ``C(R, t) = sum_i rho(|e_pi|^2 / sigma_i^2) + sum_j rho(|e_lj|^2 / sigma_lj^2)``

with the point residuals ``e_p = proj(R p + t) - pixels`` and the line residuals (signed pixel
distances of projected segment endpoints to observed lines) of :mod:`jaxpose.core.residuals`.

Methods (``RefineOptions.method``):

* ``"newton-raphson"``: Sharma et al. 2018 eqs. 23-29: state ``x = [t, Euler angles]``
  (``RefineOptions.sequence``, default ``"XYZ"``), ``x_{k+1} = x_k - (J^T J)^-1 J^T E_s(x_k)``
  (eq. 25, an undamped Gauss-Newton step; the Jacobian of eqs. 26-29 by autodiff).
* ``"gauss-newton"``: the same undamped step in the tangent coordinates below (no gimbal lock).
* ``"lm"`` (default): Levenberg-Marquardt on the tangent, Marquardt's diagonal damping, the
  damping divided by 10 on an accepted step and multiplied by 10 on a rejected one.

**Tangent coordinates** (used by ``"lm"``, ``"gauss-newton"``, :func:`pose_covariance` and
:func:`sensitivity`): the library's one convention, :meth:`jaxpose.Pose.retract`: ``xi = (dt,
dw)``, ``t <- t + dt`` (metres, camera frame) and ``R <- exp([dw]_x) R`` (radians, a rotation
about camera-frame axes applied on the left). This is exactly ``parameterization="tangent"`` of
:mod:`jaxpose.core.dilution`, and the solver's point Jacobians are
:func:`jaxpose.core.dilution.point_jacobians` (line Jacobians follow by the chain rule through
the projected endpoints): one Jacobian for refinement, covariance and DOP.

Robust kernels enter as IRLS weights ``rho'(s)`` recomputed at every iterate; the LM
acceptance test uses the robust cost itself.

Two back-ends (``RefineOptions.backend``) solve the same problem:

* ``"native"`` (default): a ``lax.while_loop`` over closed-form ``6 x 6`` normal equations
  (a Jacobi-scaled Cholesky written out element by element, so that ``vmap`` turns it into plain
  vector arithmetic). Under ``vmap`` the loop runs until the slowest lane has converged; finished
  lanes are frozen.
* ``"optimistix"``: ``optimistix.least_squares`` with ``optimistix.LevenbergMarquardt`` or
  ``optimistix.GaussNewton`` on the chart ``(t, w) -> (t, exp([w]_x) R0)`` around the initial
  pose (Euler angles for ``"newton-raphson"``), robust kernels through the square-root residual
  ``sqrt(rho(s) / s) e`` whose squared norm is the robust cost. It is kept for generality (any
  optimistix solver, its ``ImplicitAdjoint``). The native path exists because it is much faster
  batched; the measurement is in ``bench/refine.py`` and in :data:`BACKEND_MEASUREMENT`.

Derivatives of the refined pose with respect to pixels, 3-D points, lines and camera
intrinsics come from the implicit function theorem at the optimum (``grad_xi C = 0``):
``d xi / d theta = -(d^2 C / d xi^2)^-1 d^2 C / (d xi d theta)`` with the exact Hessian (not the
Gauss-Newton one). The native back-end attaches this rule with ``jax.custom_jvp`` (so ``jax.grad``,
``jax.jacfwd`` and ``vmap`` of them work through :func:`refine_pose`); :func:`sensitivity`
returns the Jacobians themselves.
"""

from jaxpose.core.refine._optimistix import BACKEND_MEASUREMENT as BACKEND_MEASUREMENT
from jaxpose.core.refine._options import BACKENDS as BACKENDS
from jaxpose.core.refine._options import METHODS as METHODS
from jaxpose.core.refine._options import MIN_FEATURES as MIN_FEATURES
from jaxpose.core.refine._options import RefineOptions as RefineOptions
from jaxpose.core.refine._result import RefineResult as RefineResult
from jaxpose.core.refine._solve import refine_pose as refine_pose
from jaxpose.core.refine._uncertainty import PoseSensitivity as PoseSensitivity
from jaxpose.core.refine._uncertainty import pose_covariance as pose_covariance
from jaxpose.core.refine._uncertainty import sensitivity as sensitivity
from jaxpose.core.refine._window import WindowLines as WindowLines
from jaxpose.core.refine._window import WindowObservations as WindowObservations
from jaxpose.core.refine._window import WindowOptions as WindowOptions
from jaxpose.core.refine._window import WindowResult as WindowResult
from jaxpose.core.refine._window import adjust_window as adjust_window
from jaxpose.core.refine._window import line_residual as line_residual
from jaxpose.core.refine._window import motion_residual as motion_residual
from jaxpose.core.refine._window import plane_residual as plane_residual
from jaxpose.core.refine._window import point_residual as point_residual
