"""Windowed bundle adjustment: the poses of a few frames and the point landmarks they observe,
adjusted jointly (pure JAX; one compiled function per padded size).

Cost (Triggs et al. 2000, a bundle adjustment; the point and line terms of Yang et al. 2024):

    ``C = sum_o rho(|e_o|) + sum_l w_l rho(|d_l|) + s sum_i (X_i^T M_i X_i - 2 b_i^T X_i)``

* ``e_o = proj_c(R_j X_i + t_j) - u_o``: the pixel residual (eq. 8) of observation ``o`` of
  landmark ``i`` in frame ``j``, in the left image or, through the rig, the right one
  (``x_right = R_rl x_left + t_rl``);
* ``d_l = l . proj(R_j P_l + t_j)``: the signed distance (pixels; ``l`` with a unit normal) of a
  fixed line landmark's endpoint ``P_l`` to the line observed in frame ``j`` (eq. 9), weighted by
  ``w_l = 1 / sigma_l^2``;
* free line landmarks (:class:`WindowLines`, optional): both endpoints ``P`` of a segment are
  variables, observed as the planes ``n . x = d`` through a camera centre and an image segment
  (left camera frame of frame ``j``); the term ``s w (n . (R_j P + t_j) - d)^2`` is eq. 9 in
  the plane's form (``s w`` turns metres into pixels: ``w = 1 / (sigma^2 z^2)``), and each
  endpoint keeps the planes from outside the window as a prior ``s (P^T M P - 2 b^T P)``
  (rank 2 across the line); the position along the line, which no plane sees, is held by a
  gauge term on the step (``tr(H) (u . dP)^2``, ``u`` the segment's direction);
* the landmark prior: the normal equations ``M_i = sum w (I - d d^T)``, ``b_i = sum w (I - d
  d^T) o`` of the landmark's observation rays outside the window (angular units), scaled to
  pixels by ``s = f_x f_y``;
* ``rho``: Huber's kernel at ``huber_px``, entered as IRLS weights.

Gauss-Newton on the tangent of each free frame (:meth:`jaxpose.Pose.retract`: ``t <- t + rho``,
``R <- exp([omega]_x) R``) and on the landmarks' positions, with Marquardt's diagonal damping;
the landmarks are eliminated by their ``3 x 3`` blocks (the Schur complement) and the reduced
``6F x 6F`` system of the poses solved by Cholesky (a free line's endpoints are two more
``3 x 3`` blocks). The Jacobians of one observation's residual are ``jax.jacfwd`` of
:func:`point_residual` (:func:`line_residual`, :func:`plane_residual`) at zero increments,
under ``vmap``; the observations form a visibility grid (frames x landmarks x the two images)
and the normal-equation blocks are sums along its axes (no scatter).

Variable sizes are padded: unseen grid cells and lines with a mask, landmarks with
``points_mask``, frames with ``free`` (a fixed or padded frame is not moved). A caller that pads
to one grid size compiles one program.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxpose.core._compile import eager_jit
from jaxpose.core.camera import StereoCamera
from jaxpose.core.geometry import Pose, so3_log
from jaxpose.core.residuals import robust_weight
from jaxpose.core.status import Status

__all__ = [
    "WindowLines",
    "WindowObservations",
    "WindowOptions",
    "WindowResult",
    "adjust_window",
    "line_residual",
    "motion_residual",
    "plane_residual",
    "point_residual",
]

_MIN_DEPTH = 1e-6
"""Depth (metres) at or below which an observed point counts as behind its camera."""


@dataclasses.dataclass(frozen=True)
class WindowOptions:
    """How :func:`adjust_window` solves (hashable: static under ``jit``).

    Attributes:
        iterations: Gauss-Newton iterations (at least 1).
        huber_px: Huber threshold of the pixel residuals and line distances, pixels.
        damping: Marquardt's damping, relative to each normal matrix's diagonal.
        motion_prior: add the constant-twist prior of ``observations.motion_weight``
            (:func:`motion_residual`); off, the weights are not read and the prior is not in
            the compiled function.

    Raises:
        ValueError: a non-positive iteration count or threshold, a negative damping.
    """

    iterations: int = 2
    huber_px: float = 1.5
    damping: float = 1e-3
    motion_prior: bool = False

    def __post_init__(self):
        if not (isinstance(self.iterations, int) and self.iterations >= 1):
            raise ValueError(f"WindowOptions.iterations must be >= 1; got {self.iterations!r}")
        if not self.huber_px > 0:
            raise ValueError(f"WindowOptions.huber_px must be positive; got {self.huber_px}")
        if not self.damping >= 0:
            raise ValueError(f"WindowOptions.damping must be >= 0; got {self.damping}")


class WindowLines(eqx.Module):
    """The free line landmarks of a window: ``m`` segments whose two endpoints are adjusted, each
    seen in frame ``j`` as up to ``c`` planes through a camera centre and its image segment
    (the left and right image of a stereo pair: Yang et al. 2024 eq. 9 in the plane's form).

    Attributes:
        planes: ``(f, m, c, 4)`` ``(n, d)``: unit normal and offset of the plane ``n . x = d``,
            left camera frame of frame ``j``, metres.
        weight: ``(f, m, c)`` ``1 / (sigma^2 z^2)`` (``sigma``: the line's pixel noise, ``z``:
            its depth, metres; the cost is ``f_x f_y`` times the weight times the squared plane
            distance, so about the squared pixel distance over ``sigma^2``); 0: not observed.
        prior_M, prior_b: ``(m, 3, 3)``, ``(m, 3)`` the normal equations ``sum w n n^T``,
            ``sum w d n`` of the line's planes from outside the window, body frame (the same
            units as ``weight``; zero for none), applied to each endpoint.
        mask: ``(m,)`` the line is real.
    """

    planes: Float[Array, "f m c 4"]
    weight: Float[Array, "f m c"]
    prior_M: Float[Array, "m 3 3"]
    prior_b: Float[Array, "m 3"]
    mask: Bool[Array, " m"]


class WindowObservations(eqx.Module):
    """The observations of one window of ``f`` frames and ``n`` landmarks, as a visibility grid
    (a landmark is seen at most once in each image of a frame), with ``k`` line-endpoint rows a
    frame. Padding: ``mask``, ``points_mask`` and ``line_weight`` say what is real.

    Attributes:
        pixels: ``(f, n, 2, 2)`` the pixel of landmark ``i`` in frame ``j``, left image
            (``[j, i, 0]``) and right image (``[j, i, 1]``).
        mask: ``(f, n, 2)`` the pixel is observed.
        prior_M, prior_b: ``(n, 3, 3)``, ``(n, 3)`` each landmark's ray normal equations from
            outside the window (body frame, angular units; zero for none).
        points_mask: ``(n,)`` the landmark is real.
        line_points: ``(f, k, 3)`` fixed line-landmark endpoints, body frame, metres.
        line_coeffs: ``(f, k, 3)`` the line observed in the left image of the frame, ``(a, b,
            c)`` with ``a^2 + b^2 = 1``.
        line_weight: ``(f, k)`` ``1 / sigma_l^2`` (padding: 0).
        free: ``(f,)`` the frame's pose is adjusted (a gauge anchor or a padded frame: ``False``).
        motion_weight: ``(f, 6)`` the weight ``1 / sigma^2`` (per metre^2 and radian^2, against
            the pixel residuals' unit weight) of the constant-twist prior centred at each frame
            (:func:`motion_residual`; zero: none, and always for the first and last frame).
        lines: the free line landmarks (:class:`WindowLines`; ``None``: none).
    """

    pixels: Float[Array, "f n 2 2"]
    mask: Bool[Array, "f n 2"]
    prior_M: Float[Array, "n 3 3"]
    prior_b: Float[Array, "n 3"]
    points_mask: Bool[Array, " n"]
    line_points: Float[Array, "f k 3"]
    line_coeffs: Float[Array, "f k 3"]
    line_weight: Float[Array, "f k"]
    free: Bool[Array, " f"]
    motion_weight: Float[Array, "f 6"]
    lines: WindowLines | None = None


class WindowResult(eqx.Module):
    """Result of :func:`adjust_window`.

    Attributes:
        pose: the adjusted poses (batched ``Pose``, ``(f, 3, 3)`` and ``(f, 3)``); the given ones
            when the status is not ``OK``.
        points_body: ``(n, 3)`` the adjusted landmarks (the given ones when not ``OK``).
        status: ``int32`` :class:`~jaxpose.core.status.Status`: ``OK``, ``BEHIND_CAMERA`` (an
            observed point or free line endpoint at depth ``<= 1e-6`` m at an iterate),
            ``SINGULAR`` (a landmark's or endpoint's ``3 x 3`` block or the reduced pose system
            not invertible, or a non-finite step).
        lines_body: ``(m, 2, 3)`` the adjusted free line landmarks' endpoints (the given ones
            when not ``OK``; ``None`` without free lines).
    """

    pose: Pose
    points_body: Float[Array, "n 3"]
    status: Int[Array, ""]
    lines_body: Float[Array, "m 2 3"] | None = None


def point_residual(xi, dX, pose: Pose, point_body, pixels, rig: StereoCamera):
    """Pixel residuals ``(2, 2)`` of one landmark seen in both images of one frame, at the
    increments ``xi`` (``(6,)``, the pose's tangent, :meth:`jaxpose.Pose.retract`) and ``dX``
    (``(3,)``, metres), and the point's depths ``(2,)`` in the two cameras (Yang et al. 2024
    eq. 8; the right image through the rig, ``x_right = R_rl x_left + t_rl``). ``pixels``:
    ``(2, 2)``, left then right."""
    p = pose.retract(xi)
    x = p.R @ (point_body + dX) + p.t
    xr = rig.to_right(x)
    uv = jnp.stack([rig.left.project(x), rig.right.project(xr)])
    return uv - pixels, jnp.stack([x[2], xr[2]])


def line_residual(xi, pose: Pose, point_body, line, camera):
    """Signed pixel distance of a body point projected at ``pose.retract(xi)`` to the image line
    ``line`` (``(3,)``, unit normal), and its depth (Yang et al. 2024 eq. 9)."""
    p = pose.retract(xi)
    x = p.R @ point_body + p.t
    uv = camera.project(x)
    return line[0] * uv[0] + line[1] * uv[1] + line[2], x[2]


def plane_residual(xi, dP, pose: Pose, point_body, plane):
    """Signed distance (metres) of a body point moved by ``dP`` (``(3,)``), at
    ``pose.retract(xi)``, to the plane ``plane = (n, d)`` (``n . x = d``, camera frame, unit
    ``n``), and its depth."""
    p = pose.retract(xi)
    x = p.R @ (point_body + dP) + p.t
    return jnp.dot(plane[:3], x) - plane[3], x[2]


def _with_value(fn):
    """``fn`` returning ``(residual, (residual, depth))``: for ``jacfwd(..., has_aux=True)``."""

    def wrapped(*args):
        r, depth = fn(*args)
        return r, (r, depth)

    return wrapped


def _inv3(A):
    """Inverses ``(n, 3, 3)`` by adjugates, and the determinants."""
    c0 = jnp.cross(A[:, 1], A[:, 2])
    c1 = jnp.cross(A[:, 2], A[:, 0])
    c2 = jnp.cross(A[:, 0], A[:, 1])
    det = jnp.sum(A[:, 0] * c0, -1)
    safe = jnp.where(det != 0, det, 1.0)
    return jnp.stack([c0, c1, c2], 2) / safe[:, None, None], det


def _normal_equations(R, t, X, obs: WindowObservations, rig: StereoCamera, cfg: WindowOptions):
    """The blocks ``H_pp (f, 6, 6), g_p (f, 6), H_pl (f, n, 6, 3), H_ll (n, 3, 3), g_l (n, 3)``
    at the poses ``(R, t)`` and landmarks ``X``, and whether every observed depth is positive.
    Sums over the visibility grid's axes (no scatter)."""
    dtype = X.dtype
    zero6, zero3 = jnp.zeros(6, dtype), jnp.zeros(3, dtype)
    pose = Pose(R, t)
    jac = jax.jacfwd(_with_value(point_residual), argnums=(0, 1), has_aux=True)
    one = jax.vmap(jac, in_axes=(None, None, None, 0, 0, None))  # the landmarks
    grid = jax.vmap(one, in_axes=(None, None, 0, None, 0, None))  # the frames
    (J_pose, J_point), (r, z) = grid(zero6, zero3, pose, X, obs.pixels, rig)
    # J_pose (f, n, 2, 2, 6), J_point (f, n, 2, 2, 3), r (f, n, 2, 2), z (f, n, 2)
    depth_ok = jnp.all(jnp.where(obs.mask, z > _MIN_DEPTH, True))
    w = jnp.where(obs.mask, robust_weight("huber", jnp.linalg.norm(r, axis=-1), cfg.huber_px), 0.0)
    wp = jnp.where(obs.free[:, None, None], w, 0.0)
    Jw_point = w[..., None, None] * J_point
    Jw_pose = wp[..., None, None] * J_pose
    # (products and sums written out: XLA fuses them; as einsums they are thousands of tiny
    # batched matrix products)
    outer = lambda a, b: jnp.sum(a[..., :, None] * b[..., None, :], axis=(2, 3))  # noqa: E731
    H_pl = outer(Jw_pose, J_point)  # (f, n, 6, 3)
    H_ll = jnp.sum(outer(J_point, Jw_point), axis=0)
    g_l = jnp.sum(Jw_point * r[..., None], axis=(0, 2, 3))
    H_pp = jnp.sum(outer(J_pose, Jw_pose), axis=1)
    g_p = jnp.sum(Jw_pose * r[..., None], axis=(1, 2, 3))
    # the landmark prior s (X^T M X - 2 b^T X), beside the squared residuals' normal equations
    # (J^T W J, J^T W e: half the cost's Hessian and gradient): s M and s (M X - b)
    s = rig.left.fx * rig.left.fy
    H_ll = H_ll + s * obs.prior_M
    g_l = g_l + s * (jnp.einsum("nab,nb->na", obs.prior_M, X) - obs.prior_b)
    # the fixed line landmarks' endpoint distances, pose blocks only
    if obs.line_points.shape[1]:
        ljac = jax.jacfwd(_with_value(line_residual), has_aux=True)
        lgrid = jax.vmap(jax.vmap(ljac, in_axes=(None, None, 0, 0, None)), (None, 0, 0, 0, None))
        J_line, (d, zl) = lgrid(zero6, pose, obs.line_points, obs.line_coeffs, rig.left)
        live = obs.line_weight > 0
        depth_ok = depth_ok & jnp.all(jnp.where(live, zl > _MIN_DEPTH, True))
        wl = jnp.where(obs.free[:, None], obs.line_weight, 0.0)
        wl = wl * robust_weight("huber", d, cfg.huber_px)
        H_pp = H_pp + jnp.einsum("fka,fkb->fab", J_line, wl[..., None] * J_line)
        g_p = g_p + jnp.einsum("fka,fk->fa", J_line, wl * d)
    return H_pp, g_p, H_pl, H_ll, g_l, depth_ok


def _line_equations(R, t, E, lines: WindowLines, free, rig: StereoCamera, cfg: WindowOptions):
    """The free line endpoints' blocks (the points' of :func:`_normal_equations`, ``2m``
    endpoints ``E``, line ``i``'s at ``2i, 2i + 1``): ``H_pp, g_p`` to add, ``H_pe (f, 2m, 6,
    3)``, ``H_ee (2m, 3, 3)`` (with the prior and the along-line gauge), ``g_e (2m, 3)``, and
    whether every observed depth is positive."""
    dtype = E.dtype
    zero6, zero3 = jnp.zeros(6, dtype), jnp.zeros(3, dtype)
    pose = Pose(R, t)
    planes = jnp.repeat(lines.planes, 2, axis=1)  # (f, 2m, c, 4)
    weight = jnp.repeat(lines.weight, 2, axis=1)  # (f, 2m, c)
    jac = jax.jacfwd(_with_value(plane_residual), argnums=(0, 1), has_aux=True)
    cams = jax.vmap(jac, in_axes=(None, None, None, None, 0))
    one = jax.vmap(cams, in_axes=(None, None, None, 0, 0))  # the endpoints
    grid = jax.vmap(one, in_axes=(None, None, 0, None, 0))  # the frames
    (J_pose, J_pt), (r, z) = grid(zero6, zero3, pose, E, planes)
    # J_pose (f, 2m, c, 6), J_pt (f, 2m, c, 3), r, z (f, 2m, c)
    seen = weight > 0
    depth_ok = jnp.all(jnp.where(seen, z > _MIN_DEPTH, True))
    s = rig.left.fx * rig.left.fy
    sw = s * weight
    px = jnp.sqrt(sw) * jnp.abs(r)  # about the pixel distance over sigma
    w = jnp.where(seen, sw * robust_weight("huber", px, cfg.huber_px), 0.0)
    wp = jnp.where(free[:, None, None], w, 0.0)
    outer = lambda a, b: a[..., :, None] * b[..., None, :]  # noqa: E731
    H_pe = jnp.sum(outer(wp[..., None] * J_pose, J_pt), axis=2)  # (f, 2m, 6, 3)
    H_ee = jnp.sum(outer(w[..., None] * J_pt, J_pt), axis=(0, 2))
    g_e = jnp.sum((w * r)[..., None] * J_pt, axis=(0, 2))
    H_pp = jnp.sum(outer(wp[..., None] * J_pose, J_pose), axis=(1, 2))
    g_p = jnp.sum((wp * r)[..., None] * J_pose, axis=(1, 2))
    M = jnp.repeat(lines.prior_M, 2, axis=0)
    b = jnp.repeat(lines.prior_b, 2, axis=0)
    H_ee = H_ee + s * M
    g_e = g_e + s * (jnp.einsum("nab,nb->na", M, E) - b)
    # the gauge: the step along the segment held with the block's own scale
    P = E.reshape(-1, 2, 3)
    u = P[:, 1] - P[:, 0]
    u = u / jnp.maximum(jnp.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
    u = jnp.repeat(u, 2, axis=0)
    tr = jnp.trace(H_ee, axis1=1, axis2=2)
    H_ee = H_ee + tr[:, None, None] * outer(u, u)
    return H_pp, g_p, H_pe, H_ee, g_e, depth_ok


def motion_residual(xi, pose: Pose):
    """Second differences ``(f - 2, 6)`` of the frames' relative motions ``T_j T_{j-1}^-1``
    (translation, rotation vector; metres, radians) at the increments ``xi`` (``(f, 6)``): zero
    for a constant twist, a rigid body spinning about a fixed axis at a constant rate seen from
    a camera at rest (torque-free tumbling without nutation)."""
    p = pose.retract(xi)
    R_rel = p.R[1:] @ jnp.swapaxes(p.R[:-1], -1, -2)
    t_rel = p.t[1:] - jnp.einsum("fij,fj->fi", R_rel, p.t[:-1])
    v = jnp.concatenate([t_rel, so3_log(R_rel)], -1)
    return v[1:] - v[:-1]


def _motion_equations(R, t, obs: WindowObservations):
    """Normal equations ``(6f, 6f)``, ``(6f,)`` of the constant-twist prior (``motion_weight``:
    the whitening ``1 / sigma^2`` of the second difference centred at each frame)."""
    f = R.shape[0]
    pose = Pose(R, t)
    xi = jnp.zeros((f, 6), R.dtype)
    r = motion_residual(xi, pose)  # (f - 2, 6)
    J = jax.jacfwd(motion_residual)(xi, pose).reshape(f - 2, 6, 6 * f)
    J = jnp.where(jnp.repeat(obs.free, 6)[None, None, :], J, 0.0)
    w = obs.motion_weight[1:-1]
    H = jnp.einsum("kai,ka,kaj->ij", J, w, J)
    g = jnp.einsum("kai,ka->i", J, w * r)
    return H, g


def _step(R, t, X, obs: WindowObservations, rig: StereoCamera, cfg: WindowOptions):
    """One damped Gauss-Newton step, landmarks eliminated (Schur complement); ``ok`` flags.
    ``X``: ``(n + 2m, 3)``, the points then the free lines' endpoints."""
    f, n = R.shape[0], X.shape[0]
    dtype = X.dtype
    n_pts = obs.points_mask.shape[0]
    H_pp, g_p, H_pl, H_ll, g_l, depth_ok = _normal_equations(R, t, X[:n_pts], obs, rig, cfg)
    real = obs.points_mask
    if obs.lines is not None:
        Hp, gp, H_pe, H_ee, g_e, d_ok = _line_equations(
            R, t, X[n_pts:], obs.lines, obs.free, rig, cfg
        )
        H_pp, g_p, depth_ok = H_pp + Hp, g_p + gp, depth_ok & d_ok
        H_pl = jnp.concatenate([H_pl, H_pe], 1)
        H_ll = jnp.concatenate([H_ll, H_ee], 0)
        g_l = jnp.concatenate([g_l, g_e], 0)
        real = jnp.concatenate([real, jnp.repeat(obs.lines.mask, 2)])
    lam = cfg.damping
    eye3 = jnp.eye(3, dtype=dtype)
    pad = jnp.where(real[:, None, None], 0.0, eye3)  # a padded landmark: identity
    H_ll_d = H_ll + lam * jnp.diagonal(H_ll, axis1=1, axis2=2)[:, :, None] * eye3 + pad
    L_inv, det = _inv3(H_ll_d + 1e-9 * eye3)
    blocks_ok = jnp.all(jnp.isfinite(det) & (det != 0))
    # S = H_pp - H_pl H_ll^-1 H_pl^T as one (6f, 3n) x (3n, 6f) product
    A = jnp.einsum("fnab,nbc->fanc", H_pl, L_inv).reshape(6 * f, 3 * n)
    B = H_pl.transpose(0, 2, 1, 3).reshape(6 * f, 3 * n)
    S = -(A @ B.T)
    idx = jnp.arange(f)
    S = S.reshape(f, 6, f, 6).at[idx, :, idx, :].add(H_pp).reshape(6 * f, 6 * f)
    rhs = g_p.reshape(-1) - A @ g_l.reshape(-1)
    if cfg.motion_prior and f >= 3:  # the constant-twist prior couples neighbouring frames
        H_m, g_m = _motion_equations(R, t, obs)
        S, rhs = S + H_m, rhs + g_m
    fixed = jnp.where(jnp.repeat(obs.free, 6), 0.0, 1.0)  # a fixed frame's rows are zero
    S = S + jnp.diag(lam * jnp.diagonal(S) + fixed + 1e-9)
    chol = jnp.linalg.cholesky(S)
    dxi = -jax.scipy.linalg.cho_solve((chol, True), rhs)
    dX = -jnp.einsum("nab,nb->na", L_inv, g_l + (B.T @ dxi).reshape(n, 3))
    dX = jnp.where(real[:, None], dX, 0.0)
    d = jnp.where(obs.free[:, None], dxi.reshape(f, 6), 0.0)
    stepped = Pose(R, t).retract(d)
    finite = jnp.all(jnp.isfinite(dxi)) & jnp.all(jnp.isfinite(dX))
    return stepped.R, stepped.t, X + dX, depth_ok, blocks_ok & finite


_COMPILER_OPTIONS_CPU = {"xla_cpu_use_fusion_emitters": False}
"""XLA options of the adjustment's compilation on a CPU: measured on a window of 8 frames and
300 landmarks (``bench/stereo.py``'s window), the compilation takes about half the time of
the default one and the compiled step is no slower."""


def _adjust(points_body, lines_body, obs: WindowObservations, pose: Pose, rig: StereoCamera, cfg):
    n = points_body.shape[0]
    if lines_body is not None:
        points_body = jnp.concatenate([points_body, lines_body.reshape(-1, 3)], 0)

    def body(_, state):
        R, t, X, depth_ok, solve_ok = state
        R1, t1, X1, d_ok, s_ok = _step(R, t, X, obs, rig, cfg)
        return R1, t1, X1, depth_ok & d_ok, solve_ok & s_ok

    true = jnp.asarray(True)
    R, t, X, depth_ok, solve_ok = jax.lax.fori_loop(
        0, cfg.iterations, body, (pose.R, pose.t, points_body, true, true)
    )
    status = jnp.where(
        depth_ok,
        jnp.where(solve_ok, Status.OK, Status.SINGULAR),
        Status.BEHIND_CAMERA,
    ).astype(jnp.int32)
    good = status == Status.OK
    keep = lambda new, old: jnp.where(good, new, old)  # noqa: E731
    X = keep(X, points_body)
    lines = None if lines_body is None else X[n:].reshape(lines_body.shape)
    return WindowResult(Pose(keep(R, pose.R), keep(t, pose.t)), X[:n], status, lines)


def adjust_window(
    points_body: Float[Array, "n 3"],
    observations: WindowObservations,
    pose: Pose,
    rig: StereoCamera,
    *,
    lines_body: Float[Array, "m 2 3"] | None = None,
    options: WindowOptions = WindowOptions(),
) -> WindowResult:
    """Adjust the poses of a window of frames and the point landmarks they observe (module
    docstring: the cost, the step, the padding).

    Args:
        points_body: ``(n, 3)`` the landmarks' positions, body frame, metres.
        observations: the window's :class:`WindowObservations` (padded).
        pose: the frames' poses, a batched ``Pose`` (``(f, 3, 3)``, ``(f, 3)``), body to left
            camera.
        rig: the stereo rig (the right image's pixels through ``R_rl, t_rl``).
        lines_body: ``(m, 2, 3)`` the free line landmarks' endpoints, body frame, metres (with
            ``observations.lines``; ``None`` without).
        options: :class:`WindowOptions`.

    Returns:
        :class:`WindowResult` (a status, never an exception, for a bad window).

    Raises:
        ValueError: inconsistent shapes (at trace time).
    """
    X = jnp.asarray(points_body)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"points_body must have shape (n, 3); got {X.shape}")
    n = X.shape[0]
    R, t = jnp.asarray(pose.R), jnp.asarray(pose.t)
    if R.ndim != 3 or t.shape != (R.shape[0], 3):
        raise ValueError(
            f"pose must be a batch of f poses, R (f, 3, 3) and t (f, 3); got {R.shape}, {t.shape}"
        )
    f = R.shape[0]
    o = observations
    k = o.line_points.shape[1] if o.line_points.ndim == 3 else -1
    shapes = {
        "pixels": (o.pixels.shape, (f, n, 2, 2)),
        "mask": (o.mask.shape, (f, n, 2)),
        "prior_M": (o.prior_M.shape, (n, 3, 3)),
        "prior_b": (o.prior_b.shape, (n, 3)),
        "points_mask": (o.points_mask.shape, (n,)),
        "line_points": (o.line_points.shape, (f, k, 3)),
        "line_coeffs": (o.line_coeffs.shape, (f, k, 3)),
        "line_weight": (o.line_weight.shape, (f, k)),
        "free": (o.free.shape, (f,)),
        "motion_weight": (o.motion_weight.shape, (f, 6)),
    }
    E = None
    if (lines_body is None) != (o.lines is None):
        raise ValueError("lines_body and observations.lines must be given together")
    if o.lines is not None:
        E = jnp.asarray(lines_body)
        m = E.shape[0] if E.ndim == 3 else -1
        if E.shape != (m, 2, 3):
            raise ValueError(f"lines_body must have shape (m, 2, 3); got {E.shape}")
        c = o.lines.planes.shape[2] if o.lines.planes.ndim == 4 else -1
        shapes |= {
            "lines.planes": (o.lines.planes.shape, (f, m, c, 4)),
            "lines.weight": (o.lines.weight.shape, (f, m, c)),
            "lines.prior_M": (o.lines.prior_M.shape, (m, 3, 3)),
            "lines.prior_b": (o.lines.prior_b.shape, (m, 3)),
            "lines.mask": (o.lines.mask.shape, (m,)),
        }
    for name, (got, want) in shapes.items():
        if tuple(got) != want:
            raise ValueError(f"observations.{name} must have shape {want}; got {tuple(got)}")
    return _adjust_eager(X, E, o, Pose(R, t), rig, options)


_adjust_eager = eager_jit(_adjust, static_argnums=(5,), cpu_options=_COMPILER_OPTIONS_CPU)
