"""StereoCamera: projection, triangulation against OpenCV, rectification maps, transforms."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import PinholeCamera, StereoCamera
from jaxpose.core.geometry import so3_exp
from jaxpose.vision.stereo_rectify import rectify

DIST = np.array([-0.05, 0.02, 0.0005, -0.0003, 0.0])


def _rig(dist=None, rotated=True):
    K = np.array([[800.0, 0, 511.5], [0, 805.0, 383.5], [0, 0, 1]])
    left = PinholeCamera.from_K(K, dist, width=1024, height=768)
    right = PinholeCamera.from_K(K + np.diag([3.0, -2.0, 0]), dist, width=1024, height=768)
    R = np.asarray(so3_exp(np.array([0.01, -0.03, 0.005]))) if rotated else np.eye(3)
    return StereoCamera(left, right, R, np.array([-0.25, 0.004, 0.002]))


def _points(rng, n=40):
    return np.c_[rng.uniform(-0.6, 0.6, (n, 2)), rng.uniform(1.5, 3.0, n)]


@pytest.mark.parametrize("method", ["linear", "midpoint"])
def test_triangulation_recovers_points_exactly(rng, method):
    rig = _rig(DIST)
    X = _points(rng)
    uv_l, uv_r = rig.project(X)
    np.testing.assert_allclose(rig.triangulate(uv_l, uv_r, method=method), X, atol=1e-7)


def test_linear_triangulation_matches_opencv_with_noise(rng):
    rig = _rig(DIST * 0)
    X = _points(rng)
    uv_l, uv_r = (np.asarray(u) + rng.normal(0, 0.5, (len(X), 2)) for u in rig.project(X))
    P_l, P_r = (np.asarray(P) for P in rig.projection_matrices())
    # OpenCV's DLT on normalised coordinates: the same linear system as ours
    xl = np.asarray(rig.left.normalize(uv_l))
    xr = np.asarray(rig.right.normalize(uv_r))
    P1 = np.c_[np.eye(3), np.zeros(3)]
    P2 = np.c_[np.asarray(rig.R_rl), np.asarray(rig.t_rl)]
    Xh = cv2.triangulatePoints(P1, P2, xl.T.copy(), xr.T.copy())
    ref = (Xh[:3] / Xh[3]).T
    ours = np.asarray(rig.triangulate(uv_l, uv_r))
    np.testing.assert_allclose(ours, ref, atol=1e-9)
    # in pixel form, within a millimetre of OpenCV's pixel DLT (another algebraic weighting)
    Xh = cv2.triangulatePoints(P_l, P_r, uv_l.T.copy(), uv_r.T.copy())
    np.testing.assert_allclose(ours, (Xh[:3] / Xh[3]).T, atol=2e-3)
    # midpoint agrees with the DLT to within the noise
    np.testing.assert_allclose(rig.triangulate(uv_l, uv_r, method="midpoint"), ours, atol=2e-2)


def test_segments_and_batch_shapes(rng):
    rig = _rig(DIST)
    seg = _points(rng).reshape(20, 2, 3)
    l, r = rig.project(seg)
    out = rig.triangulate_segments(l, r)
    assert out.shape == (20, 2, 3)
    np.testing.assert_allclose(out, seg, atol=1e-7)
    with pytest.raises(ValueError, match="same shape"):
        rig.triangulate_segments(l, r[:3])
    with pytest.raises(ValueError, match="method"):
        rig.triangulate(l, r, method="nope")


def test_baseline_constructor_and_projection_matrices(rng):
    cam = PinholeCamera(700.0, 700.0, 320.0, 240.0, width=640, height=480)
    rig = StereoCamera.from_baseline(cam, 0.3)
    assert float(rig.baseline) == pytest.approx(0.3)
    X = _points(rng, 5)
    l, r = rig.project(X)
    # rectified rig: same rows, disparity f b / Z
    np.testing.assert_allclose(l[:, 1], r[:, 1], atol=1e-9)
    np.testing.assert_allclose(l[:, 0] - r[:, 0], 700.0 * 0.3 / X[:, 2], rtol=1e-12)
    P_l, P_r = rig.projection_matrices()
    Xh = np.c_[X, np.ones(5)]
    pr = Xh @ np.asarray(P_r).T
    np.testing.assert_allclose(pr[:, :2] / pr[:, 2:], r, atol=1e-9)
    with pytest.raises(ValueError, match="baseline"):
        StereoCamera.from_baseline(cam, 0.0)
    with pytest.raises(ValueError):
        StereoCamera(cam, cam, np.eye(3), np.zeros(2))


def test_transforms_jit_vmap_grad(rng):
    rig = _rig(DIST)
    X = _points(rng)
    l, r = rig.project(X)
    f = jax.jit(lambda rig, a, b: rig.triangulate(a, b))
    np.testing.assert_allclose(f(rig, l, r), X, atol=1e-7)
    batched = jax.vmap(lambda a, b: rig.triangulate(a, b, method="midpoint"))(
        l[:4, None], r[:4, None]
    )
    np.testing.assert_allclose(batched[:, 0], X[:4], atol=1e-7)
    # depth sensitivity to the right u: dZ/du_r = Z^2 / (f b) for a rectified rig
    flat = StereoCamera.from_baseline(PinholeCamera(700.0, 700.0, 320.0, 240.0), 0.3)
    ul, ur = jnp.array([355.0, 240.0]), jnp.array([250.0, 240.0])  # (0.1, 0, 2) seen by both
    g = jax.jit(
        jax.grad(lambda u: flat.triangulate(ul, jnp.stack([u, ur[1]]), method="midpoint")[2])
    )
    assert float(g(ur[0])) == pytest.approx(2.0**2 / (700.0 * 0.3), rel=1e-9)


def test_rectify_maps_make_rows_epipolar(rng):
    rig = _rig(DIST)
    rect = rectify(rig)
    assert rect.map_left[0].shape == (768, 1024)
    X = _points(rng) * [0.5, 0.5, 1.0]
    l, r = (np.asarray(u) for u in rig.project(X))
    K1, K2 = np.asarray(rig.left.K), np.asarray(rig.right.K)
    d = np.asarray(rig.left.dist)
    lr = cv2.undistortPoints(l[:, None], K1, d, R=rect.R1, P=rect.P1)[:, 0]
    rr = cv2.undistortPoints(r[:, None], K2, d, R=rect.R2, P=rect.P2)[:, 0]
    np.testing.assert_allclose(lr[:, 1], rr[:, 1], atol=1e-3)
    # the rectified rig triangulates the rectified pixels back to the points (rotated by R1)
    rc = rect.rectified_camera()
    Xr = np.asarray(rc.triangulate(lr, rr))
    np.testing.assert_allclose(Xr, X @ rect.R1.T, atol=1e-3)
    img = np.zeros((768, 1024), np.uint8)
    a, b = rect.remap(img, img)
    assert a.shape == b.shape == (768, 1024)
    with pytest.raises(ValueError, match="image size"):
        rectify(StereoCamera.from_baseline(PinholeCamera(1.0, 1.0, 0.0, 0.0), 0.1))
