"""DOP: autodiff H against the closed form and finite differences; invariants; bad geometry."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxpose import PinholeCamera, Pose, Status, dop, observation_jacobian
from jaxpose.core.dilution import dop_from_information, information_blocks
from jaxpose.core.geometry import elementary_rotation

AXIS = {"x": 0, "y": 1, "z": 2}
GEN = [
    np.array([[0, 0, 0], [0, 0, -1], [0, 1, 0.0]]),
    np.array([[0, 0, 1], [0, 0, 0], [-1, 0, 0.0]]),
    np.array([[0, -1, 0], [1, 0, 0], [0, 0, 0.0]]),
]


def scene(rng, n=10, deg=20.0, z=10.0):
    points = np.c_[rng.uniform(-0.5, 0.5, (n, 2)), np.zeros(n)]
    pose = Pose.from_euler(np.deg2rad([deg, -deg, deg]), np.array([0.1, -0.2, z]))
    cam = PinholeCamera.from_focal_length(0.05, 5e-6, (2048, 2048))
    return points, pose, cam


def closed_form_H(points, angles, t, fx, fy, seq):
    """H of Ning et al. eq. 7 written out by hand: d(u,v)/d(rho) @ d(rho)/d(T, eps) (intrinsic
    ``seq``, SciPy's upper case)."""
    seq = seq.lower()
    Rs = [np.asarray(elementary_rotation(AXIS[c], a)) for c, a in zip(seq, angles, strict=True)]
    R = Rs[0] @ Rs[1] @ Rs[2]
    dR = [
        GEN[AXIS[seq[0]]] @ R,
        Rs[0] @ GEN[AXIS[seq[1]]] @ Rs[1] @ Rs[2],
        Rs[0] @ Rs[1] @ GEN[AXIS[seq[2]]] @ Rs[2],
    ]
    rows = []
    for p in points:
        X, Y, Z = R @ p + t
        duv = np.array([[fx / Z, 0, -fx * X / Z**2], [0, fy / Z, -fy * Y / Z**2]])
        drho = np.c_[np.eye(3), np.stack([d @ p for d in dR], axis=1)]
        rows.append(duv @ drho)
    return np.concatenate(rows)


@pytest.mark.parametrize("seq", ["XYZ", "ZYX", "XZY"])
def test_autodiff_H_matches_closed_form_and_finite_differences(rng, seq):
    points, _, cam = scene(rng)
    points[:, 2] = rng.uniform(-0.2, 0.2, len(points))  # non-planar too
    angles, t = np.array([0.3, -0.2, 0.5]), np.array([0.1, -0.2, 8.0])
    pose = Pose.from_euler(angles, t, seq)
    H = np.asarray(observation_jacobian(points, pose, cam, sequence=seq))
    np.testing.assert_allclose(
        H,
        closed_form_H(points, angles, t, float(cam.fx), float(cam.fy), seq),
        rtol=1e-10,
        atol=1e-6,
    )

    def pixels(x):
        return cam.project(Pose.from_euler(x[3:], x[:3], seq).apply(points)).reshape(-1)

    x0 = np.r_[t, angles]
    h = 1e-6
    fd = np.stack([(pixels(x0 + h * e) - pixels(x0 - h * e)) / (2 * h) for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(H, fd, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(jax.jacrev(pixels)(x0), jax.jacfwd(pixels)(x0), atol=1e-8)


def test_dop_equals_direct_inverse_and_sigma_weighting(rng):
    points, pose, cam = scene(rng)
    H = np.asarray(observation_jacobian(points, pose, cam))
    Q = np.linalg.inv(H.T @ H)
    res = dop(points, pose, cam)
    np.testing.assert_allclose(res.pdop, np.sqrt(np.trace(Q[:3, :3])), rtol=1e-9)
    np.testing.assert_allclose(res.adop, np.sqrt(np.trace(Q[3:, 3:])), rtol=1e-9)
    np.testing.assert_allclose(res.Q, Q, rtol=1e-7, atol=1e-14)
    sigma = rng.uniform(0.5, 2.0, len(points))
    W = np.repeat(1 / sigma**2, 2)
    Qw = np.linalg.inv(H.T @ (W[:, None] * H))
    np.testing.assert_allclose(
        dop(points, pose, cam, sigma=sigma).pdop, np.sqrt(np.trace(Qw[:3, :3])), rtol=1e-9
    )
    np.testing.assert_allclose(dop(points, pose, cam, sigma=2.0).pdop, 2 * res.pdop, rtol=1e-12)


def test_pdop_independent_of_parameterisation_adop_not(rng):
    points, _, cam = scene(rng)
    R_pose = Pose.from_euler(np.deg2rad([20, 20, 20.0]), np.array([0.0, 0.0, 10.0]), "XYZ")
    results = [dop(points, R_pose, cam, sequence=s) for s in ("XYZ", "ZYX", "yzx", "ZXZ")]
    results.append(dop(points, R_pose, cam, parameterization="tangent"))
    for r in results[1:]:
        np.testing.assert_allclose(r.pdop, results[0].pdop, rtol=1e-9)
    assert abs(float(results[1].adop) - float(results[0].adop)) > 1e-6 * float(results[0].adop)


@settings(max_examples=20, deadline=None)
@given(focal_mm=st.floats(10, 200), pixel_um=st.floats(2, 20), seed=st.integers(0, 10_000))
def test_dop_scales_with_pixel_size_over_focal_length(focal_mm, pixel_um, seed):
    rng = np.random.default_rng(seed)
    points, pose, _ = scene(rng)
    ref = dop(points, pose, PinholeCamera(1.0, 1.0, 0.0, 0.0))
    cam = PinholeCamera.from_focal_length(focal_mm * 1e-3, pixel_um * 1e-6, (1000, 1000))
    cam = PinholeCamera(cam.fx, cam.fy, 0.0, 0.0)
    res = dop(points, pose, cam)
    scale = pixel_um * 1e-6 / (focal_mm * 1e-3)
    np.testing.assert_allclose(res.pdop, ref.pdop * scale, rtol=1e-8)
    np.testing.assert_allclose(res.adop, ref.adop * scale, rtol=1e-8)


_masked_dop = jax.jit(lambda p, mask, pose, cam: dop(p, pose, cam, mask=mask, throw=False))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(5, 12))
def test_adding_a_point_never_increases_dop(seed, n):
    rng = np.random.default_rng(seed)
    points, pose, cam = scene(rng, n=12)  # one compiled function: n points of 12 via the mask
    mask = np.arange(12) < n
    full = _masked_dop(points, mask, pose, cam)
    fewer = _masked_dop(points, mask & (np.arange(12) != n - 1), pose, cam)
    assert float(full.pdop) <= float(fewer.pdop) * (1 + 1e-9)
    assert float(full.adop) <= float(fewer.adop) * (1 + 1e-9)


def test_gradient_of_pdop_wrt_points_matches_finite_differences(rng):
    points, pose, cam = scene(rng, n=6)
    f = jax.jit(lambda p: dop(p, pose, cam, throw=False).pdop)
    grad = np.asarray(jax.grad(f)(jnp.asarray(points)))
    h = 1e-6
    fd = np.zeros_like(points)
    for i in range(points.shape[0]):
        for k in range(3):
            e = np.zeros_like(points)
            e[i, k] = h
            fd[i, k] = (f(points + e) - f(points - e)) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-9 * np.abs(fd).max())


def test_jit_vmap_and_mask_padding(rng):
    points, pose, cam = scene(rng, n=8)
    batch = np.stack([points, points * 1.5, points * 0.5])
    res = jax.jit(jax.vmap(lambda p: dop(p, pose, cam, throw=False)))(batch)
    for b in range(3):
        np.testing.assert_allclose(res.pdop[b], dop(batch[b], pose, cam).pdop, rtol=1e-12)
    padded = np.r_[points, np.full((4, 3), 123.0)]
    mask = np.r_[np.ones(8, bool), np.zeros(4, bool)]
    np.testing.assert_allclose(
        dop(padded, pose, cam, mask=mask).pdop, dop(points, pose, cam).pdop, rtol=1e-12
    )


BAD = {
    "too few": (lambda p: p[:3], Status.TOO_FEW_POINTS, "too few"),
    "collinear": (
        lambda p: np.c_[p[:, 0], np.zeros(len(p)), np.zeros(len(p))],
        Status.SINGULAR,
        "singular",
    ),
    "behind": (lambda p: p + np.array([0, 0, -20.0]), Status.BEHIND_CAMERA, "behind the camera"),
    "nan": (
        lambda p: np.where(np.arange(len(p))[:, None] == 2, np.nan, p),
        Status.NONFINITE_INPUT,
        "NaN",
    ),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_geometry_raises_eagerly_and_gives_status_in_batches(rng, case):
    points, pose, cam = scene(rng, n=8)
    make, status, message = BAD[case]
    bad = make(points)
    with pytest.raises(ValueError, match=message):
        dop(bad, pose, cam)
    if bad.shape == points.shape:
        res = jax.vmap(lambda p: dop(p, pose, cam, throw=False))(np.stack([points, bad]))
        assert int(res.status[0]) == Status.OK and np.isfinite(res.pdop[0])
        assert int(res.status[1]) == status
        assert np.isinf(res.pdop[1]) and np.isinf(res.adop[1]) and not np.any(np.isnan(res.Q[1]))
        grad = jax.grad(
            lambda p: jnp.sum(
                jnp.where(jnp.isfinite(r := dop(p, pose, cam, throw=False).pdop), r, 0.0)
            )
        )(bad)
        assert not np.any(np.isnan(np.asarray(grad)))


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_wrong_shapes_raise_value_error(rng):
    points, pose, cam = scene(rng)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        dop(points[:, :2], pose, cam)
    with pytest.raises(ValueError, match="one rotation"):
        dop(points, Pose(np.stack([np.eye(3)] * 2), np.zeros((2, 3))), cam)
    with pytest.raises(ValueError, match="parameterization"):
        dop(points, pose, cam, parameterization="quaternion")
    with pytest.raises(ValueError, match=r"\(6, 6\)"):
        dop_from_information(np.eye(5))
    with pytest.raises(ValueError, match="mask"):
        information_blocks(points, pose, cam, mask=np.ones(3, bool))


def test_error_under_jit_with_throw():
    points = np.zeros((5, 3))
    pose = Pose.from_euler(np.zeros(3), np.array([0.0, 0.0, 5.0]))
    cam = PinholeCamera(1000.0, 1000.0, 0.0, 0.0)
    with pytest.raises(Exception, match="singular"):
        jax.jit(lambda p: dop(p, pose, cam).pdop)(points).block_until_ready()
