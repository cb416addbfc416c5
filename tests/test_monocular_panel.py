"""Fast tests of the panel term of the monocular ranking: the texture maps peak at the normal of
parallel lines and stay flat on noise, and the term prefers the pose that puts the solar panel on
the image's cell lines to the 180-degree turn about an axis in the panel's plane."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import PinholeCamera, Pose
from jaxpose.core.geometry import euler_to_dcm, so3_exp
from jaxpose.pipelines.monocular import InitOptions, initialise_pose
from jaxpose.pipelines.monocular.scene import (
    _EdgeScene,
    _ideal_params,
    _model_geometry,
    _panel_geometry,
)
from jaxpose.pipelines.monocular.score import _panel_term
from jaxpose.vision.image_maps import ORIENTATION_BINS, texture_maps
from jaxpose.vision.models import tango

jax.config.update("jax_enable_x64", True)


def _at(maps, frame, uv):
    ij = np.rint((np.asarray(uv, float) - np.asarray(frame)[:2]) * float(frame[2])).astype(int)
    return np.asarray(maps)[:, ij[:, 1], ij[:, 0]]


def test_texture_maps_peak_at_the_normal_of_parallel_lines():
    rng = np.random.default_rng(0)
    img = rng.normal(40, 4, (600, 800)).clip(0, 255).astype(np.uint8)
    for x in range(220, 420, 12):  # vertical lines: horizontal gradients (bin 0)
        cv2.line(img, (x, 150), (x, 450), 140, 2)
    roi = np.array([200.0, 140.0, 600.0, 460.0])
    maps, frame = texture_maps(img, roi)
    assert maps.shape == (ORIENTATION_BINS, 256, 256)
    lines = _at(maps, frame, [[300, 300], [260, 250], [380, 400]])
    noise = _at(maps, frame, [[520, 300], [560, 200]])
    share = lines[0] + lines[1] + lines[-1]  # the bins within 22.5 deg of horizontal
    assert share.min() > 0.8 * lines.sum(0).min()
    # noise: no bin stands out (a flat histogram)
    assert np.all(noise.max(0) < 2.5 * noise.mean(0) + 1e-6)


def _scene(model, img, roi, cam4):
    l_roi = float(np.hypot(*(roi[2:] - roi[:2])))
    tex, frame = (jnp.asarray(x) for x in texture_maps(img, roi))
    return _EdgeScene(
        _model_geometry(model),
        jnp.zeros((1, 2)),
        jnp.zeros(1, bool),
        jnp.zeros(img.shape),
        0.05 * l_roi,
        cam4,
    )._replace(tex=tex, tex_frame=frame, panel=_panel_geometry(model), panel_weight=1.0)


def test_panel_term_prefers_the_panel_on_its_cell_lines():
    """Independent image: the body as a filled grey polygon, the panel's cell lines (parallel to
    one side, as photographs show them) drawn with OpenCV at the true pose."""
    model = tango()
    cam = PinholeCamera(1200.0, 1200.0, 400.0, 300.0, width=800, height=600)
    R = np.asarray(euler_to_dcm(jnp.array([2.6, -0.5, 0.4])))
    true = Pose(jnp.asarray(R), jnp.asarray([0.05, 0.0, 4.0]))
    V = np.asarray(model.vertices)
    assert (R @ np.array([0.0, 0.0, 1.0])) @ (R @ V[:4].mean(0) + np.asarray(true.t)) < 0

    def project(points):
        p = np.asarray(points) @ R.T + np.asarray(true.t)
        return np.c_[1200.0 * p[:, 0] / p[:, 2] + 400.0, 1200.0 * p[:, 1] / p[:, 2] + 300.0]

    rng = np.random.default_rng(1)
    img = rng.normal(30, 3, (600, 800)).clip(0, 255).astype(np.uint8)
    hull = cv2.convexHull(np.round(project(V)).astype(np.int32))
    cv2.fillConvexPoly(img, hull, 150)
    o, u, v = V[0], V[3] - V[0], V[1] - V[0]
    for a in np.linspace(0.0, 1.0, 11):
        p, q = project(np.stack([o + a * u, o + a * u + v]))
        cv2.line(img, tuple(np.round(p).astype(int)), tuple(np.round(q).astype(int)), 60, 2)
    uv = project(V)
    roi = np.r_[uv.min(0), uv.max(0)]
    sc = _scene(model, img, roi, _ideal_params(cam))
    c = jnp.asarray(V.mean(0))
    at_true = float(_panel_term(true.R, true.t, sc))
    for axis in ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]):  # turns that hide the panel
        Rf = true.R @ so3_exp(jnp.asarray(np.pi * np.asarray(axis)))
        tf = true.t + true.R @ c - Rf @ c
        assert float(_panel_term(Rf, tf, sc)) == pytest.approx(0.5, abs=1e-9)
    assert at_true < 0.3
    # the same pose over the image without cell lines pays (no evidence on a visible panel)
    plain = rng.normal(30, 3, (600, 800)).clip(0, 255).astype(np.uint8)
    cv2.fillConvexPoly(plain, hull, 150)
    assert float(_panel_term(true.R, true.t, _scene(model, plain, roi, _ideal_params(cam)))) > 0.8


def test_panel_geometry_only_for_tango():
    model = tango()
    g = np.asarray(_panel_geometry(model))
    assert g.shape == (6 * 6 + 3, 3)
    assert np.allclose(g[:-3, 2], model.vertices[0][2])  # inside face 0, the panel's top


@pytest.mark.parametrize("w", [-0.5, float("nan")])
def test_panel_weight_must_be_finite_and_non_negative(w):
    cam = PinholeCamera(1200.0, 1200.0, 400.0, 300.0, width=800, height=600)
    with pytest.raises(ValueError, match="panel_weight"):
        initialise_pose(np.zeros((600, 800), np.uint8), cam, options=InitOptions(panel_weight=w))
