"""Slanted-window stereo (`vision.stereo_slant`): the disparity's slope and the plane it fixes."""

import numpy as np
import pytest
from textures import random_texture

from jaxpose.core.camera import PinholeCamera
from jaxpose.vision.stereo_slant import plane_normals, slanted_disparity

F, CX, CY, W, H, BASE = 800.0, 330.0, 236.0, 640, 480, 0.3
CAM = PinholeCamera.from_K([[F, 0, CX], [0, F, CY], [0, 0, 1]], width=W, height=H)
#: A smooth random texture on the plane's own coordinates (metres); grey about 128.
_texture = random_texture(11, 60, 25.0, 10.0)


def _plane_pair(normal, point):
    """The rectified pair (left camera at the origin, right at ``x = BASE``) of the plane
    ``normal . (X - point) = 0`` textured in its own coordinates, ray-cast pixel by pixel."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    e1 = np.cross(n, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rays = np.stack([(u - CX) / F, (v - CY) / F, np.ones_like(u)], -1)
    images = []
    for centre in (np.zeros(3), np.array([BASE, 0.0, 0.0])):
        s = ((point - centre) @ n) / (rays @ n)
        X = centre + rays * s[..., None]
        images.append(_texture((X - point) @ e1, (X - point) @ e2).astype(np.float32))
    return images


def _true_disparity(normal, point, pixels):
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    rays = np.stack([(pixels[:, 0] - CX) / F, (pixels[:, 1] - CY) / F, np.ones(len(pixels))], 1)
    depth = (point @ n) / (rays @ n)
    return F * BASE / depth


@pytest.mark.parametrize("normal", [(0.0, 0.0, -1.0), (0.7, 0.0, -0.7), (-0.3, 0.6, -0.74)])
def test_the_slant_of_a_ray_cast_plane_gives_its_normal(normal):
    """A textured plane at 3 m, facing the camera or turned by 45 degrees about either axis:
    from a start 0.7 px off, the fitted disparity is the ray-cast one to 0.05 px and the
    plane's normal is the true normal to 2 degrees (for the turned planes, the normal of a
    window taken as facing the camera is about 45 degrees off)."""
    point = np.array([0.1, -0.05, 3.0])
    left, right = _plane_pair(normal, point)
    pixels = np.array([[300.0, 200.0], [360.5, 260.25], [280.0, 300.0], [400.0, 180.0]])
    truth = _true_disparity(normal, point, pixels)
    fit = slanted_disparity(left, right, pixels, truth + 0.7)
    assert fit.ok.all()
    assert (fit.zncc > 0.95).all()
    np.testing.assert_allclose(fit.disparity, truth, atol=0.05)
    n = plane_normals(CAM, pixels, fit.disparity, fit.slope)
    want = np.asarray(normal) / np.linalg.norm(normal)
    angle = np.degrees(np.arccos(np.clip(np.abs(n @ want), 0, 1)))
    assert angle.max() < 2.0, angle


def test_the_slope_covariance_matches_its_spread_under_noise():
    """Forty draws of Gaussian noise (3 grey levels) on the same turned plane: the spread of
    the fitted slopes is the one the fit's covariance predicts to within a factor of 2 above
    and 0.8 below (the covariance is optimistic: 1.1-1.6 times over three noise seeds when the
    test was written; the estimate takes the left window as exact)."""
    normal, point = (0.7, 0.0, -0.7), np.array([0.1, -0.05, 3.0])
    left, right = _plane_pair(normal, point)
    pixels = np.array([[300.0, 200.0]])
    truth = _true_disparity(normal, point, pixels)
    rng = np.random.default_rng(5)
    slopes, sds = [], []
    for _ in range(40):
        noisy = [im + rng.normal(0, 3.0, im.shape).astype(np.float32) for im in (left, right)]
        fit = slanted_disparity(*noisy, pixels, truth)
        assert fit.ok[0]
        slopes.append(fit.slope[0])
        sds.append(np.sqrt(np.diag(fit.slope_cov[0])))
    ratio = np.std(slopes, axis=0) / np.mean(sds, axis=0)
    assert np.all((ratio > 0.8) & (ratio < 2.0)), ratio


def test_plane_normals_of_an_exact_disparity_plane():
    """Disparities computed from a plane's depths at three pixels (finite differences for the
    slope) give that plane's normal, turned towards the camera."""
    normal = np.array([0.4, -0.5, -0.768])
    normal /= np.linalg.norm(normal)
    point = np.array([0.2, 0.1, 2.5])
    pixels = np.array([[250.0, 150.0], [251.0, 150.0], [250.0, 151.0]])
    d = _true_disparity(normal, point, pixels)
    slope = np.array([[d[1] - d[0], d[2] - d[0]]])  # exact: the disparity is affine in the pixel
    n = plane_normals(CAM, pixels[:1], d[:1], slope)
    np.testing.assert_allclose(n[0], normal, atol=1e-9)


def test_a_window_past_the_image_or_a_flat_one_is_not_ok():
    left, right = _plane_pair((0.0, 0.0, -1.0), np.array([0.0, 0.0, 3.0]))
    pixels = np.array([[5.0, 200.0], [320.0, 236.0]])
    fit = slanted_disparity(left, right, pixels, np.array([80.0, 80.0]))
    assert not fit.ok[0] and fit.ok[1]
    flat = np.full((H, W), 100.0, np.float32)
    fit = slanted_disparity(flat, flat, pixels[1:], np.array([80.0]))
    assert fit.zncc[0] == 0.0


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(pixels=np.zeros((3,))), "pixels"),
        (dict(disparity=np.zeros(2)), "disparity"),
        (dict(right=np.zeros((10, 10))), "same shape"),
        (dict(half=0), "half"),
    ],
)
def test_bad_slant_inputs_are_named(kwargs, name):
    args = dict(
        left=np.zeros((H, W)),
        right=np.zeros((H, W)),
        pixels=np.full((3, 2), 100.0),
        disparity=np.zeros(3),
    )
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        slanted_disparity(args.pop("left"), args.pop("right"), args.pop("pixels"), **args)
