"""A fixed number of Gauss-Newton steps on the reprojection error of one PnP problem (pure JAX).

The fast refinement of :func:`jaxpose.solve_pnp` for pinhole cameras without distortion and no
robust kernel (the common case): it minimises the same cost as
:func:`jaxpose.core.refine.refine_pose` (the squared pixel reprojection errors of the valid
points), with three differences that make it cheap under ``vmap`` on a CPU:

* no convergence test in the loop: exactly :data:`GAUSS_NEWTON_STEPS` linearisations (a batched
  ``while_loop`` runs every lane until the slowest has converged; here the few slow problems
  are handed to the LM instead);
* the error is taken in normalised coordinates (``x = X / Z``, weighted by ``fx^2``, ``fy^2``:
  the same pixel error without the camera's distortion polynomial and its derivatives);
* the step acts on the whole pose from the left, ``R <- exp([w]_x) R``, ``t <- exp([w]_x) t +
  dt``, so that the ``2 x 6`` Jacobian of a point depends on its normalised coordinates and depth
  only (the classical interaction matrix): ``d(x, y) / d(dt, w) = [[1/Z, 0, -x/Z, -x y, 1 + x^2,
  -y], [0, 1/Z, -y/Z, -(1 + y^2), x y, x]]``.

The last linearisation decides convergence with the test of the native LM (an accepted step
``|dt| <= atol + rtol |t|`` and ``|w| <= atol + rtol``, or a predicted decrease at round-off
level); the step solved there is then taken unverified, as the LM does. A problem that does not
pass (or whose normal matrix is singular, or that ends with a point behind the camera) is left
to the Levenberg-Marquardt of :func:`~jaxpose.core.refine.refine_pose` by the caller.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxpose.core.geometry import Pose, so3_exp
from jaxpose.core.refine._native import _NEGLIGIBLE_DECREASE, _scaled_cholesky_solve

GAUSS_NEWTON_STEPS = 3
"""Linearisations of the fast refinement. From an EPnP pose (0.3 deg, 1.5% of the range off at
0.5 px noise) the third step is below the default tolerance for all but about 1 problem in
10 000 (measured with ``bench/pnp.py``'s scenes); those go to the LM."""

# upper triangle of the 6 x 6 normal matrix, row by row
_UPPER = tuple((i, j) for i in range(6) for j in range(i, 6))


def _normal_equations(R, t, points_body, xy, wu, wv):
    """``A = J^T W J`` (``6 x 6``), ``g = J^T W r`` and the cost ``r^T W r`` at ``(R, t)``.

    ``points_body (n, 3)``, ``xy (n, 2)`` normalised observed coordinates, ``wu``, ``wv (n,)``
    the weights of the two coordinates (``fx^2``, ``fy^2`` for a valid point, 0 otherwise), so
    that the cost is in squared pixels. Written coordinate by coordinate: under ``vmap`` it is
    one element-wise pass over ``(batch, n)`` and one reduction."""
    P = [points_body[:, 0], points_body[:, 1], points_body[:, 2]]
    X = [R[i, 0] * P[0] + R[i, 1] * P[1] + R[i, 2] * P[2] + t[i] for i in range(3)]
    z = X[2]
    iz = 1.0 / jnp.where(z > 0, z, 1.0)
    x, y = X[0] * iz, X[1] * iz
    ru, rv = x - xy[:, 0], y - xy[:, 1]
    # computed once: without the barrier XLA fuses them into each of the 28 reductions below
    # and recomputes the projection (a division among them) 28 times
    x, y, iz, ru, rv = jax.lax.optimization_barrier((x, y, iz, ru, rv))
    zero = jnp.zeros_like(x)
    Ju = (iz, zero, -x * iz, -x * y, 1.0 + x * x, -y)
    Jv = (zero, iz, -y * iz, -(1.0 + y * y), x * y, x)
    wJu = [wu * a for a in Ju]
    wJv = [wv * a for a in Jv]
    # One reduction per entry, each fused with the products it sums: stacking the products
    # first would write a (28, batch, n) array to memory, which costs 8x the arithmetic
    # (measured: 4.0 against 0.46 us a problem at n = 20).
    upper = {(i, j): jnp.sum(wJu[i] * Ju[j] + wJv[i] * Jv[j]) for i, j in _UPPER}
    A = jnp.stack([jnp.stack([upper[min(i, j), max(i, j)] for j in range(6)]) for i in range(6)])
    g = jnp.stack([jnp.sum(wJu[i] * ru + wJv[i] * rv) for i in range(6)])
    return A, g, jnp.sum(wu * ru * ru + wv * rv * rv)


def _squared_error(R, t, points_body, xy, wu, wv):
    """The cost ``r^T W r`` (squared pixels) and the depths ``Z`` of the points at ``(R, t)``."""
    P = [points_body[:, 0], points_body[:, 1], points_body[:, 2]]
    X = [R[i, 0] * P[0] + R[i, 1] * P[1] + R[i, 2] * P[2] + t[i] for i in range(3)]
    iz = 1.0 / jnp.where(X[2] > 0, X[2], 1.0)
    ru, rv = X[0] * iz - xy[:, 0], X[1] * iz - xy[:, 1]
    return jnp.sum(wu * ru * ru + wv * rv * rv), X[2]


def reprojection_rms(R, t, points_body, xy, weights, fxy):
    """The RMS reprojection error (pixels) over the valid points at ``(R, t)``, and the depths
    ``Z`` of the points; arguments as :func:`gauss_newton_pnp`'s."""
    cost, z = _squared_error(R, t, points_body, xy, weights * fxy[0] ** 2, weights * fxy[1] ** 2)
    return jnp.sqrt(cost / jnp.maximum(jnp.sum(weights), 1.0)), z


def _apply(R, t, delta):
    """``R <- exp([w]_x) R``, ``t <- exp([w]_x) t + dt`` for ``delta = (dt, w)``."""
    E = so3_exp(delta[3:])
    return E @ R, E @ t + delta[:3]


def gauss_newton_pnp(
    points_body: Float[Array, "n 3"],
    xy: Float[Array, "n 2"],
    weights: Float[Array, " n"],
    fxy: Float[Array, "2"],
    pose0: Pose,
    *,
    rtol: float,
    atol: float,
) -> tuple[Pose, Float[Array, ""], Bool[Array, ""]]:
    """:data:`GAUSS_NEWTON_STEPS` Gauss-Newton steps from ``pose0``.

    Args:
        points_body: ``(n, 3)`` body points (zero where invalid), metres.
        xy: ``(n, 2)`` observed normalised (undistorted) coordinates.
        weights: ``(n,)`` 1 for a valid point, 0 otherwise.
        fxy: ``(2,)`` focal lengths, pixels.
        pose0: the starting pose (EPnP's).
        rtol, atol: the convergence test of :class:`~jaxpose.core.refine.RefineOptions`.

    Returns:
        ``(pose, rms_px, ok)``: the pose after the last (unverified) step, its RMS reprojection
        error over the valid points (pixels), and whether the problem converged with a regular
        normal matrix, a finite pose and every valid point in front of the camera.
    """
    dtype = points_body.dtype
    eps = float(jnp.finfo(dtype).eps)
    wu, wv = weights * fxy[0] ** 2, weights * fxy[1] ** 2

    def step(_, state):
        R, t, _ = state
        A, g, cost = _normal_equations(R, t, points_body, xy, wu, wv)
        delta, singular = _scaled_cholesky_solve(A, -g)
        delta = jnp.where(jnp.all(jnp.isfinite(delta)), delta, 0.0)
        R_next, t_next = _apply(R, t, delta)
        small = (jnp.linalg.norm(t_next - t) <= atol + rtol * jnp.linalg.norm(t)) & (
            jnp.linalg.norm(delta[3:]) <= atol + rtol
        )
        flat = -0.5 * jnp.dot(g, delta) <= 1e3 * eps * cost + _NEGLIGIBLE_DECREASE
        return R_next, t_next, (small | flat) & ~singular & jnp.isfinite(cost)

    # a loop of fixed length (one copy of the step to compile; each trip costs about 0.1 us)
    R, t, converged = jax.lax.fori_loop(
        0, GAUSS_NEWTON_STEPS, step, (pose0.R, pose0.t, jnp.asarray(False))
    )
    # the reprojection error at the returned pose (and its depths)
    rms, z = reprojection_rms(R, t, points_body, xy, weights, fxy)
    front = jnp.all((z > 0) | (weights == 0))
    ok = converged & front & jnp.isfinite(rms) & jnp.all(jnp.isfinite(R)) & jnp.all(jnp.isfinite(t))
    return Pose(R, t), rms, ok


def _accepts(cfg) -> bool:
    """Whether a refinement configuration may use the fast path: the plain squared error (no
    robust kernel), Levenberg-Marquardt or Gauss-Newton on the tangent, the native back-end, and
    a budget of at least :data:`GAUSS_NEWTON_STEPS` steps."""
    return (
        cfg is not None
        and cfg.robust is None
        and cfg.method in ("lm", "gauss-newton")
        and cfg.backend == "native"
        and cfg.max_steps >= GAUSS_NEWTON_STEPS
    )
