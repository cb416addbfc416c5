"""The windowed bundle adjustment of the core (jaxpose.core.refine.adjust_window): the autodiff
Jacobians of one observation against central finite differences, and one Gauss-Newton step
against the dense normal equations of a NumPy residual vector differentiated numerically (no
Schur complement, no JAX), on a small padded window with a fixed frame, a padded landmark,
unobserved pixels, line terms and ray priors; free line landmarks moved onto the true lines."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxpose import PinholeCamera, Pose, StereoCamera
from jaxpose.core.refine import (
    WindowLines,
    WindowObservations,
    WindowOptions,
    adjust_window,
    line_residual,
    motion_residual,
    point_residual,
)
from jaxpose.core.status import Status

CAM = PinholeCamera(800.0, 790.0, 320.5, 240.5, width=640, height=480)
RIG = StereoCamera.from_baseline(CAM, 0.3)
F, N, K = 3, 8, 2  # frames, landmarks (the last one padding), line rows a frame


def _stereo_pixels(Rs, ts, X):
    """Exact left and right pixels ``(F, N, 2, 2)`` of body points ``X`` at the poses ``(Rs,
    ts)`` (NumPy pinhole projection of the rectified rig)."""
    Kmat = np.asarray(CAM.K)
    x = np.einsum("fij,nj->fni", Rs, X) + ts[:, None]
    left = (x @ Kmat.T)[..., :2] / x[..., 2:]
    xr = x + np.asarray(RIG.t_rl)
    right = (xr @ Kmat.T)[..., :2] / xr[..., 2:]
    return np.stack([left, right], 2)


@pytest.fixture(scope="module")
def window():
    rng = np.random.default_rng(4)
    X = rng.uniform(-0.3, 0.3, (N, 3))
    Rs = np.stack([Rotation.from_rotvec([0.1, 0.05 * j, 0.02]).as_matrix() for j in range(F)])
    ts = np.array([0.02, -0.01, 2.0]) + rng.normal(0, 0.01, (F, 3))
    Kmat = np.asarray(CAM.K)
    pixels = _stereo_pixels(Rs, ts, X) + rng.normal(0, 0.7, (F, N, 2, 2))
    mask = rng.random((F, N, 2)) < 0.8
    mask[:, -1] = False  # the padded landmark
    A = rng.normal(size=(N, 3, 3)) * 0.05
    M = np.einsum("nij,nkj->nik", A, A) * 1e-2
    b = np.einsum("nij,nj->ni", M, X + rng.normal(0, 0.01, X.shape))
    Lpts = rng.uniform(-0.3, 0.3, (F, K, 3))
    q = np.einsum("fij,fkj->fki", Rs, Lpts) + ts[:, None]
    uv = (q @ Kmat.T)[..., :2] / q[..., 2:]
    ang = rng.uniform(0, np.pi, (F, K))
    L = np.stack([np.cos(ang), np.sin(ang), np.zeros((F, K))], -1)
    L[..., 2] = -(L[..., 0] * uv[..., 0] + L[..., 1] * uv[..., 1]) + rng.normal(0, 0.5, (F, K))
    Lw = np.full((F, K), 0.7)
    Lw[2, 1] = 0.0  # a padded line row
    obs = WindowObservations(
        pixels=jnp.asarray(pixels),
        mask=jnp.asarray(mask),
        prior_M=jnp.asarray(M),
        prior_b=jnp.asarray(b),
        points_mask=jnp.asarray(np.arange(N) < N - 1),
        line_points=jnp.asarray(Lpts),
        line_coeffs=jnp.asarray(L),
        line_weight=jnp.asarray(Lw),
        free=jnp.asarray([False, True, True]),
        motion_weight=jnp.zeros((F, 6)),
    )
    # the starting point: poses and landmarks off the ones the pixels were made from
    R0 = np.stack([Rotation.from_rotvec(rng.normal(0, 2e-3, 3)).as_matrix() @ R for R in Rs])
    R0[0] = Rs[0]
    t0 = ts + rng.normal(0, 3e-3, ts.shape) * np.array([[0], [1], [1]])
    X0 = X + rng.normal(0, 5e-3, X.shape)
    return obs, R0, t0, X0


def _residuals_numpy(obs, Rs, ts, X):
    """The whitened residual vector of the window (NumPy): observed pixels, line distances
    times sqrt(weight); Huber inactive (all residuals below the threshold used below)."""
    Kmat = np.asarray(CAM.K)
    x = np.einsum("fij,nj->fni", Rs, X) + ts[:, None]
    out = []
    for c, shift in enumerate((np.zeros(3), np.asarray(RIG.t_rl))):
        xc = x + shift
        uv = (xc @ Kmat.T)[..., :2] / xc[..., 2:]
        e = uv - np.asarray(obs.pixels)[:, :, c]
        out.append(e[np.asarray(obs.mask)[:, :, c]].ravel())
    q = np.einsum("fij,fkj->fki", Rs, np.asarray(obs.line_points)) + ts[:, None]
    uv = (q @ Kmat.T)[..., :2] / q[..., 2:]
    L = np.asarray(obs.line_coeffs)
    d = L[..., 0] * uv[..., 0] + L[..., 1] * uv[..., 1] + L[..., 2]
    out.append((np.sqrt(np.asarray(obs.line_weight)) * d).ravel())
    # the constant-twist prior: second differences of (t_rel, rotvec(R_rel))
    R_rel = np.einsum("fij,fkj->fik", Rs[1:], Rs[:-1])
    t_rel = ts[1:] - np.einsum("fij,fj->fi", R_rel, ts[:-1])
    v = np.concatenate([t_rel, Rotation.from_matrix(R_rel).as_rotvec()], 1)
    out.append((np.sqrt(np.asarray(obs.motion_weight)[1:-1]) * (v[1:] - v[:-1])).ravel())
    return np.concatenate(out)


@pytest.mark.parametrize("motion", [False, True])
def test_one_step_equals_the_dense_gauss_newton_step(window, motion):
    """damping 0, one iteration: the Schur-complement step equals the step of the dense normal
    equations ``(J^T J + s M) d = -(J^T e + s (M X - b))`` with ``J`` by central differences
    (with the constant-twist prior's rows in ``J``, ``e`` when ``motion``)."""
    obs, R0, t0, X0 = window
    if motion:  # 0.2 degree and 3 mm at the middle frame
        w = np.zeros((F, 6))
        w[1] = np.r_[np.full(3, 3e-3**-2), np.full(3, np.radians(0.2) ** -2)]
        obs = eqx.tree_at(lambda o: o.motion_weight, obs, jnp.asarray(w))
    free = np.asarray(obs.free)
    real = np.asarray(obs.points_mask)
    nf, nl = int(free.sum()), int(real.sum())

    def unpack(theta):
        Rs, ts, X = R0.copy(), t0.copy(), X0.copy()
        for q, j in enumerate(np.nonzero(free)[0]):
            d = theta[6 * q : 6 * q + 6]
            ts[j] = t0[j] + d[:3]
            Rs[j] = Rotation.from_rotvec(d[3:]).as_matrix() @ R0[j]
        X[:nl] = X0[:nl] + theta[6 * nf :].reshape(nl, 3)
        return Rs, ts, X

    size = 6 * nf + 3 * nl
    e0 = _residuals_numpy(obs, *unpack(np.zeros(size)))
    h = 1e-6
    J = np.stack(
        [
            (
                _residuals_numpy(obs, *unpack(h * np.eye(size)[i]))
                - _residuals_numpy(obs, *unpack(-h * np.eye(size)[i]))
            )
            / (2 * h)
            for i in range(size)
        ],
        1,
    )
    s = float(CAM.fx * CAM.fy)
    H = J.T @ J
    g = J.T @ e0
    M, b = np.asarray(obs.prior_M)[:nl], np.asarray(obs.prior_b)[:nl]
    for i in range(nl):
        sl = slice(6 * nf + 3 * i, 6 * nf + 3 * i + 3)
        H[sl, sl] += s * M[i]
        g[sl] += s * (M[i] @ X0[i] - b[i])
    step = -np.linalg.solve(H, g)
    R_ref, t_ref, X_ref = unpack(step)

    res = adjust_window(
        jnp.asarray(X0),
        obs,
        Pose(jnp.asarray(R0), jnp.asarray(t0)),
        RIG,
        options=WindowOptions(iterations=1, huber_px=1e6, damping=0.0, motion_prior=motion),
    )
    assert int(res.status) == Status.OK
    assert np.abs(X_ref - X0).max() > 1e-4  # the step moves things
    np.testing.assert_allclose(np.asarray(res.pose.t), t_ref, atol=1e-8)
    np.testing.assert_allclose(np.asarray(res.pose.R), R_ref, atol=1e-8)
    np.testing.assert_allclose(np.asarray(res.points_body)[:nl], X_ref[:nl], atol=1e-8)
    np.testing.assert_array_equal(np.asarray(res.pose.R)[0], R0[0])  # the fixed frame
    np.testing.assert_array_equal(np.asarray(res.points_body)[-1], X0[-1])  # padding


def test_jacobians_against_finite_differences(window):
    """jacfwd (what the adjustment uses) against jacrev and central differences."""
    obs, R0, t0, X0 = window
    pose = Pose(jnp.asarray(R0[1]), jnp.asarray(t0[1]))
    args = (pose, jnp.asarray(X0[2]), obs.pixels[1, 2], RIG)
    f = jax.jit(lambda v: point_residual(v[:6], v[6:], *args)[0].ravel())  # (xi, dX) stacked
    v0 = jnp.zeros(9)
    J = np.asarray(jax.jacfwd(f)(v0))
    np.testing.assert_allclose(J, np.asarray(jax.jacrev(f)(v0)), rtol=1e-12, atol=1e-9)
    h, eye = 1e-6, np.eye(9)
    fd = np.stack([(f(v0 + h * eye[i]) - f(v0 - h * eye[i])) / (2 * h) for i in range(9)], 1)
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-4)
    assert np.abs(J).min(where=J != 0, initial=np.inf) > 0 and np.abs(J).max() > 100
    line = (pose, obs.line_points[1, 0], obs.line_coeffs[1, 0], CAM)
    g = jax.jit(lambda xi: line_residual(xi, *line)[0])
    fd = np.array([(g(h * eye[i, :6]) - g(-h * eye[i, :6])) / (2 * h) for i in range(6)])
    np.testing.assert_allclose(np.asarray(jax.jacfwd(g)(v0[:6])), fd, rtol=1e-6, atol=1e-4)


def test_a_point_behind_a_camera_is_a_status_and_keeps_the_input(window):
    obs, R0, t0, X0 = window
    X = X0.copy()
    X[0] = [0.0, 0.0, -5.0]  # behind every camera, and observed
    obs = eqx.tree_at(lambda o: o.mask, obs, obs.mask.at[:, 0].set(True))
    res = adjust_window(jnp.asarray(X), obs, Pose(jnp.asarray(R0), jnp.asarray(t0)), RIG)
    assert int(res.status) == Status.BEHIND_CAMERA
    np.testing.assert_array_equal(np.asarray(res.points_body), X)
    np.testing.assert_array_equal(np.asarray(res.pose.t), t0)


def test_the_adjustment_runs_inside_the_callers_jit(window):
    """Under a caller's ``jax.jit`` (its own compiler options cannot nest there) the adjustment
    gives the eager call's landmarks and poses."""
    obs, R0, t0, X0 = window
    pose = Pose(jnp.asarray(R0), jnp.asarray(t0))
    eager = adjust_window(jnp.asarray(X0), obs, pose, RIG)
    jitted = jax.jit(lambda X: adjust_window(X, obs, pose, RIG))(jnp.asarray(X0))
    assert int(jitted.status) == int(eager.status) == Status.OK
    np.testing.assert_allclose(
        np.asarray(jitted.points_body), np.asarray(eager.points_body), rtol=0, atol=1e-12
    )
    np.testing.assert_allclose(
        np.asarray(jitted.pose.t), np.asarray(eager.pose.t), rtol=0, atol=1e-12
    )


@pytest.mark.typecheck_off
def test_shapes_and_options_are_checked(window):
    obs, R0, t0, X0 = window
    pose = Pose(jnp.asarray(R0), jnp.asarray(t0))
    with pytest.raises(ValueError, match="points_body"):
        adjust_window(jnp.asarray(X0[:, :2]), obs, pose, RIG)
    with pytest.raises(ValueError, match=r"observations.pixels must have shape \(3, 7, 2, 2\)"):
        adjust_window(jnp.asarray(X0[:-1]), obs, pose, RIG)
    with pytest.raises(ValueError, match="lines_body and observations.lines"):
        adjust_window(jnp.asarray(X0), obs, pose, RIG, lines_body=jnp.zeros((2, 2, 3)))
    with pytest.raises(ValueError, match="iterations"):
        WindowOptions(iterations=0)
    with pytest.raises(ValueError, match="huber_px"):
        WindowOptions(huber_px=0.0)


def test_motion_residual_is_zero_for_a_constant_twist_only():
    """A body spinning at a constant rate about a fixed axis (not through the camera) seen
    from a camera at rest: ``T_j = exp(j xi) T_0``, a constant twist; the second differences
    vanish, and one frame turned further shows in the three differences around it."""
    axis_point = np.array([0.1, -0.2, 4.0])
    step = Rotation.from_rotvec([0.0, np.radians(1.5), np.radians(0.4)]).as_matrix()
    R, t = [Rotation.from_rotvec([0.3, 0.1, -0.2]).as_matrix()], [axis_point + [0.05, 0.0, 0.1]]
    for _ in range(4):  # rotate about the fixed line through axis_point
        R.append(step @ R[-1])
        t.append(step @ (t[-1] - axis_point) + axis_point)
    pose = Pose(jnp.asarray(np.stack(R)), jnp.asarray(np.stack(t)))
    zero = jnp.zeros((5, 6))
    motion = jax.jit(motion_residual)
    np.testing.assert_allclose(np.asarray(motion(zero, pose)), 0.0, atol=1e-12)
    bump = zero.at[2, 4].set(np.radians(0.3))  # frame 2 turned 0.3 degree further about y
    r = np.asarray(motion(bump, pose))
    a = np.radians(0.3)  # the differences centred at frames 1, 2, 3: (1, -2, 1) a about y
    np.testing.assert_allclose(r[:, 4], [a, -2 * a, a], rtol=0.02)


def _planes(R, t, P):
    """The planes ``(n, d)`` (left camera frame) through the left and the right camera centre
    and the segment ``P`` (``(2, 3)``, body) seen at ``(R, t)``: ``(2, 4)``."""
    q = P @ R.T + t
    out = []
    for C in (np.zeros(3), -np.asarray(RIG.t_rl)):
        n = np.cross(q[0] - C, q[1] - C)
        n /= np.linalg.norm(n)
        out.append(np.r_[n, n @ C])
    return np.array(out)


def _distance_to_line(X, P):
    """Distances of points ``X`` (``(..., 3)``) to the infinite line through ``P`` (``(2, 3)``),
    and their positions along it (metres from ``P[0]``)."""
    u = (P[1] - P[0]) / np.linalg.norm(P[1] - P[0])
    r = X - P[0]
    along = r @ u
    return np.linalg.norm(r - along[..., None] * u, axis=-1), along


def test_free_lines_move_onto_the_true_lines(window):
    """Noise-free pixels and planes (left and right camera centre through the true segments at
    the true poses); the poses, points and line endpoints start off the truth (endpoints 1-2 cm
    across their lines). The adjustment brings the endpoints onto the true lines (the closed
    form: the lines the planes meet in) and the poses to the truth; a line seen in one window
    plane only is held by its prior (the planes of a frame outside the window); the positions
    along the lines stay (the gauge); a padded line is not moved."""
    obs, R0, t0, X0 = window
    rng = np.random.default_rng(7)
    Rs = np.stack([Rotation.from_rotvec([0.1, 0.05 * j, 0.02]).as_matrix() for j in range(F)])
    ts = np.array([0.02, -0.01, 2.0]) + np.random.default_rng(4).normal(0, 0.01, (F, 3))
    X = X0  # the fixture's landmarks; their pixels made exact at this test's (Rs, ts)
    m = 4  # the last one padding
    P_true = rng.uniform(-0.3, 0.3, (m, 2, 3))
    planes = np.zeros((F, m, 2, 4))
    weight = np.zeros((F, m, 2))
    for j in range(F):
        for i in range(m - 1):
            planes[j, i] = _planes(Rs[j], ts[j], P_true[i])
            weight[j, i] = 1.0 / (0.7**2 * 2.0**2)
    weight[:, 0] = 0.0  # line 0: one left plane in the window, the rest from its prior
    weight[1, 0, 0] = 1.0 / (0.7**2 * 2.0**2)
    R_out = Rotation.from_rotvec([0.1, -0.3, 0.05]).as_matrix()  # a frame outside the window
    pl = _planes(R_out, np.array([0.0, 0.0, 2.0]), P_true[0])
    n_b = pl[:, :3] @ R_out  # body-frame planes
    d_b = pl[:, 3] - pl[:, :3] @ np.array([0.0, 0.0, 2.0])
    w_out = 1.0 / (0.7**2 * 2.0**2)
    M = np.zeros((m, 3, 3))
    b = np.zeros((m, 3))
    M[0] = w_out * n_b.T @ n_b
    b[0] = w_out * n_b.T @ d_b
    # start: endpoints moved across (1-2 cm) and along (1 cm) their lines
    P0 = P_true + rng.normal(0, 0.012, P_true.shape)
    lines = WindowLines(
        planes=jnp.asarray(planes),
        weight=jnp.asarray(weight),
        prior_M=jnp.asarray(M),
        prior_b=jnp.asarray(b),
        mask=jnp.asarray(np.arange(m) < m - 1),
    )
    obs = eqx.tree_at(
        lambda o: (o.pixels, o.prior_M, o.prior_b, o.line_weight, o.lines),
        obs,
        (
            jnp.asarray(_stereo_pixels(Rs, ts, X)),
            jnp.zeros_like(obs.prior_M),
            jnp.zeros_like(obs.prior_b),
            jnp.zeros_like(obs.line_weight),
            lines,
        ),
        is_leaf=lambda v: v is None,
    )
    R_start = np.stack([Rotation.from_rotvec(rng.normal(0, 2e-3, 3)).as_matrix() @ R for R in Rs])
    R_start[0] = Rs[0]
    t_start = ts + rng.normal(0, 3e-3, ts.shape) * np.array([[0], [1], [1]])
    res = adjust_window(
        jnp.asarray(X + rng.normal(0, 5e-3, X.shape)),
        obs,
        Pose(jnp.asarray(R_start), jnp.asarray(t_start)),
        RIG,
        lines_body=jnp.asarray(P0),
        options=WindowOptions(iterations=5, damping=0.0),
    )
    assert int(res.status) == Status.OK
    E = np.asarray(res.lines_body)
    for i in range(m - 1):
        before, along0 = _distance_to_line(P0[i], P_true[i])
        after, along1 = _distance_to_line(E[i], P_true[i])
        assert before.min() > 1e-3  # the start is off the line
        assert after.max() < 1e-6 * before.max(), (i, before, after)
        np.testing.assert_allclose(along1, along0, atol=0.2 * before.max())
    np.testing.assert_array_equal(E[-1], P0[-1])  # padding
    np.testing.assert_allclose(np.asarray(res.pose.t), ts, atol=1e-8)
    np.testing.assert_allclose(np.asarray(res.pose.R), Rs, atol=1e-8)
