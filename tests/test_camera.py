"""Camera model against OpenCV (projection, distortion, undistortion) and I/O of camera files."""

import json

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import PinholeCamera, Pose
from jaxpose.core.camera import as_camera
from jaxpose.io import load_camera, load_speed_labels, save_camera

SPEED_DIST = np.array([-0.2238, 0.5141, -0.000665, -0.000214, -0.1312])


def _camera(dist=SPEED_DIST):
    K = np.array([[2988.58, 0, 960.0], [0, 2988.34, 600.0], [0, 0, 1]])
    return PinholeCamera.from_K(K, dist, width=1920, height=1200), K


def test_projection_matches_opencv(rng):
    cam, K = _camera()
    pts = np.c_[rng.uniform(-1, 1, (50, 2)), rng.uniform(4, 10, 50)]
    rvec, tvec = rng.normal(size=3) * 0.2, np.array([0.1, -0.2, 1.0])
    pose = Pose.from_rotvec(rvec, tvec)
    ref, _ = cv2.projectPoints(pts, rvec, tvec, K, SPEED_DIST)
    np.testing.assert_allclose(cam.project(pose.apply(pts)), ref[:, 0], atol=1e-8)


def test_undistort_matches_opencv_and_inverts_distort(rng):
    cam, K = _camera()
    pixels = np.c_[rng.uniform(0, 1919, 200), rng.uniform(0, 1199, 200)]
    ref = cv2.undistortPoints(
        pixels[:, None],
        K,
        SPEED_DIST,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14),
    )[:, 0]
    xy = np.asarray(cam.normalize(pixels))
    np.testing.assert_allclose(xy, ref, atol=1e-9)
    np.testing.assert_allclose(
        cam.distort(xy), (pixels - [960, 600]) / [2988.58, 2988.34], atol=1e-11
    )


def test_from_focal_length():
    cam = PinholeCamera.from_focal_length(0.05, 5e-6, (1024, 768))
    np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], [1e4, 1e4, 511.5, 383.5])
    assert (cam.width, cam.height) == (1024, 768)
    with pytest.raises(ValueError, match="positive"):
        PinholeCamera.from_focal_length(-0.05, 5e-6, (1024, 768))


def test_bad_cameras():
    with pytest.raises(ValueError, match="3x3"):
        PinholeCamera.from_K(np.eye(2))
    with pytest.raises(ValueError, match="positive fx"):
        PinholeCamera.from_K(np.diag([0.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="PinholeCamera or a 3x3"):
        as_camera("not a camera")
    with pytest.raises(ValueError, match="5 coefficients"):
        PinholeCamera(1.0, 1.0, 0.0, 0.0, np.zeros(3))


def test_gradient_wrt_focal_length_matches_finite_difference():
    cam, _ = _camera()
    p = np.array([0.3, -0.2, 5.0])

    def u(fx):
        c = PinholeCamera(fx, cam.fy, cam.cx, cam.cy, cam.dist)
        return c.project(p)[0]

    h = 1e-3
    fd = (u(cam.fx + h) - u(cam.fx - h)) / (2 * h)
    np.testing.assert_allclose(jax.grad(u)(cam.fx), fd, rtol=1e-7)


def test_behind_camera_is_finite_and_flagged():
    cam, _ = _camera()
    pts = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [0.1, 0.0, 2.0]])
    assert np.all(np.isfinite(cam.project(pts)))
    np.testing.assert_array_equal(cam.in_front(pts), [False, False, True])
    grad = jax.grad(lambda x: cam.project(x).sum())(pts[1])
    assert np.all(np.isfinite(grad))


def test_min_depth_throws_points_behind_far_off_the_image():
    """With ``min_depth`` a point in front projects as without it (to rounding), a point at or
    behind the camera as if it sat at that depth: ``fx X / min_depth + cx``, far off the image."""
    cam, _ = _camera(dist=np.zeros(5))
    pts = jnp.array([[0.3, -0.2, 5.0], [0.5, 0.4, -2.0], [0.5, 0.4, 0.0]])
    uv = np.asarray(cam.project(pts, min_depth=1e-6))
    np.testing.assert_allclose(uv[0], np.asarray(cam.project(pts[:1]))[0], rtol=1e-12)
    for row, p in zip(uv[1:], np.asarray(pts[1:]), strict=True):
        expected = [2988.58 * p[0] / 1e-6 + 960.0, 2988.34 * p[1] / 1e-6 + 600.0]
        np.testing.assert_allclose(row, expected, rtol=1e-9)
    assert np.all(np.abs(uv[1:]) > 1e8)
    g = jax.grad(lambda q: cam.project(q, min_depth=1e-6).sum())(pts)
    assert np.all(np.isfinite(np.asarray(g)))


def test_camera_file_round_trip_and_errors(tmp_path):
    cam, _ = _camera()
    path = tmp_path / "camera.json"
    save_camera(cam, path)
    back = load_camera(path)
    np.testing.assert_allclose(back.K, cam.K)
    np.testing.assert_allclose(back.dist, cam.dist)
    with pytest.raises(ValueError, match="not found"):
        load_camera(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ValueError, match="cannot read"):
        load_camera(tmp_path / "bad.json")
    (tmp_path / "nokey.json").write_text(json.dumps({"Nu": 3}))
    with pytest.raises(ValueError, match="cameraMatrix"):
        load_camera(tmp_path / "nokey.json")


@pytest.mark.speedplus
def test_speedplus_keypoints_project_inside_image(speedplus_dir):
    """The documented convention puts the Tango keypoints in front of the camera, on the image."""
    cam = load_camera(speedplus_dir / "camera.json")
    assert (cam.width, cam.height) == (1920, 1200)
    kp = np.loadtxt(
        speedplus_dir / "tango_keypoints.csv", delimiter=",", skiprows=1, usecols=(1, 2, 3)
    )
    for label in load_speed_labels(speedplus_dir):
        px = np.asarray(cam.project(label.pose.apply(kp)))
        assert np.all(np.asarray(label.pose.apply(kp))[:, 2] > 0)
        inside = np.all((px >= 0) & (px < [1920, 1200]), axis=1)
        assert inside.sum() >= 8, label.image  # lightbox_img000001 has an antenna cut by the frame


def test_from_K_accepts_traced_distortion_for_gradients():
    """d(u + v)/d k1 = (fx x_n + fy y_n) r^2 (OpenCV's radial model, first order)."""
    K = jnp.array([[800.0, 0.0, 320.0], [0.0, 900.0, 240.0], [0.0, 0.0, 1.0]])
    X = jnp.array([[0.1, 0.2, 2.0]])

    def total(dist):
        return PinholeCamera.from_K(K, dist).project(X).sum()

    xn, yn = 0.05, 0.1
    grad = jax.grad(total)(jnp.zeros(5))
    np.testing.assert_allclose(grad[0], (800.0 * xn + 900.0 * yn) * (xn**2 + yn**2), rtol=1e-9)
    with pytest.raises(ValueError, match="shape"):
        jax.jit(lambda d: PinholeCamera.from_K(K, d).fx)(jnp.zeros(4))
