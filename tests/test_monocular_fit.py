"""Fast tests of the shortlist fit of the monocular search: bilinear lookup, the two-sided
chamfer fit (pulls a perturbed pose back to the one that made the edges, and leaves a wrong
hypothesis no worse), and the distinct-pose pick."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose import PinholeCamera, Pose
from jaxpose.geometry import euler_to_dcm, so3_exp
from jaxpose.models import tango
from jaxpose.pipelines.monocular import (
    _bilinear,
    _chamfer,
    _chamfer_fit,
    _distance_map,
    _distinct,
    _EdgeScene,
    _ideal_params,
    _image_samples,
    _model_geometry,
)
from jaxpose.vision.render import visible_edges

jax.config.update("jax_enable_x64", True)


def _angle_deg(Ra, Rb):
    c = (np.trace(np.asarray(Ra) @ np.asarray(Rb).T) - 1.0) / 2.0
    return float(np.rad2deg(np.arccos(np.clip(c, -1.0, 1.0))))


def test_bilinear_exact_on_a_plane():
    v, u = np.mgrid[0:40, 0:50]
    img = jnp.asarray(3.0 * u - 2.0 * v + 7.0)
    uv = jnp.asarray([[10.25, 5.5], [0.0, 0.0], [48.9, 38.1], [20.75, 30.125]])
    ref = 3.0 * uv[:, 0] - 2.0 * uv[:, 1] + 7.0
    assert np.allclose(np.asarray(_bilinear(img, uv)), np.asarray(ref), atol=1e-9)


def _scene():
    model = tango()
    cam = PinholeCamera(1200.0, 1200.0, 400.0, 300.0, width=800, height=600)
    R = np.asarray(euler_to_dcm(jnp.array([0.7, -0.4, 0.3])))
    true = Pose(jnp.asarray(R), jnp.asarray([0.1, -0.05, 5.0]))
    segs = np.asarray(visible_edges(model, true, cam, shape=(600, 800)).segments)
    geom = _model_geometry(model)
    pts, mask = _image_samples(segs)
    dt = jnp.asarray(_distance_map(segs, (600, 800)))
    l_roi = float(np.linalg.norm(segs.reshape(-1, 2).max(0) - segs.reshape(-1, 2).min(0)))
    return true, _EdgeScene(geom, pts, mask, dt, 0.05 * l_roi, _ideal_params(cam))


def test_chamfer_fit_recovers_a_perturbed_pose():
    true, sc = _scene()
    R0 = so3_exp(jnp.asarray([0.03, -0.04, 0.02])) @ true.R  # about 3 deg off
    t0 = true.t + jnp.asarray([0.04, -0.03, 0.15])
    assert _angle_deg(R0, true.R) > 2.5
    R, t = _chamfer_fit(R0, t0, sc, steps=12)
    # a cheap fit for ranking, not the final refinement: it must close most of the gap (the
    # points-and-lines refinement after it does the rest)
    assert _angle_deg(R, true.R) < 0.5 * _angle_deg(R0, true.R)
    assert float(jnp.linalg.norm(t - true.t)) < 0.05
    s0, _ = _chamfer(R0, t0, sc)
    s1, _ = _chamfer(R, t, sc)
    s_true, _ = _chamfer(true.R, true.t, sc)
    assert float(s1) < 0.3 * float(s0)
    assert float(s1) < 1.5 * float(s_true)


def test_chamfer_fit_never_worsens_a_wrong_hypothesis():
    true, sc = _scene()
    R0 = so3_exp(jnp.asarray([0.0, np.pi, 0.0])) @ true.R  # turned half a turn
    t0 = true.t + jnp.asarray([0.3, 0.0, 1.0])
    R, t = _chamfer_fit(R0, t0, sc)
    s0, _ = _chamfer(R0, t0, sc)
    s1, _ = _chamfer(R, t, sc)
    assert float(s1) <= float(s0) + 1e-9
    assert np.all(np.isfinite(np.asarray(R))) and np.all(np.isfinite(np.asarray(t)))


def test_distinct_skips_near_duplicates():
    eye = np.eye(3)
    R = np.stack(
        [
            eye,
            np.asarray(so3_exp(jnp.asarray([0.02, 0.0, 0.0]))),
            eye,
            np.asarray(euler_to_dcm(jnp.array([0.0, 0.0, 0.5]))),
        ]
    )
    t = np.array([[0, 0, 5.0], [0, 0, 5.05], [0, 0, 6.0], [0, 0, 5.0]])
    # 1 is 1.1 deg and 5 cm (1%) from 0: a duplicate; 2 is 1 m away; 3 is 29 deg turned
    assert _distinct(R, t, np.arange(4), 3).tolist() == [0, 2, 3]
    assert _distinct(R, t, np.arange(4), 2).tolist() == [0, 2]
    assert _distinct(R, t, np.array([1, 0, 3]), 5).tolist() == [1, 3]
