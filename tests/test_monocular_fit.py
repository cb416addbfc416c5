"""Fast tests of the shortlist fit of the monocular search: bilinear lookup, the two-sided
chamfer fit (pulls a perturbed pose back to the one that made the edges, and leaves a wrong
hypothesis no worse), and the distinct-pose pick."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose import PinholeCamera, Pose
from jaxpose.core.geometry import euler_to_dcm, so3_exp
from jaxpose.pipelines.monocular.fit import _bilinear, _chamfer_fit
from jaxpose.pipelines.monocular.hypothesise import _distinct
from jaxpose.pipelines.monocular.scene import (
    _EdgeScene,
    _face_polygons,
    _ideal_params,
    _model_geometry,
)
from jaxpose.pipelines.monocular.score import _chamfer, _region_energy
from jaxpose.vision.image_maps import distance_map, region_grid, segment_samples
from jaxpose.vision.models import tango
from jaxpose.vision.render import BACKGROUND, render_layers, visible_edges

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
    pts, mask = (jnp.asarray(x) for x in segment_samples(segs))
    dt = jnp.asarray(distance_map(segs, (600, 800)))
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


def test_region_energy_matches_the_painter_buffer_and_rejects_a_wrong_pose():
    """Independent reference: the renderer's painter buffer labels the grid pixels; the energy of
    a noise-free image with one grey level per face is then about 0 at the true pose (only the
    pixels on face borders differ), and far larger at a pose turned by 40 degrees."""
    true, sc = _scene()
    model = tango()
    cam = PinholeCamera(1200.0, 1200.0, 400.0, 300.0, width=800, height=600)
    _, ids = render_layers(model, true, cam, shape=(600, 800), textures=None)
    levels = np.linspace(40.0, 250.0, len(model.faces))
    img = np.where(ids >= 0, levels[np.clip(ids, 0, None)], 30.0)
    img = np.where(ids == -2, 30.0, img)  # antennas: not a face; background grey
    vv, uu = np.nonzero(ids != BACKGROUND)
    roi = np.array([uu.min(), vv.min(), uu.max(), vv.max()], float)
    pts, val = (jnp.asarray(x) for x in region_grid(img.astype(np.uint8), roi))
    sc = sc._replace(grid_pts=pts, grid_val=val, face_poly=_face_polygons(model))
    # NumPy reference of SSE / SST with the buffer's labels on the unsmoothed image
    p = np.rint(np.asarray(pts)).astype(int)
    lab = ids[np.clip(p[:, 1], 0, 599), np.clip(p[:, 0], 0, 799)]
    raw = img[np.clip(p[:, 1], 0, 599), np.clip(p[:, 0], 0, 799)]
    sse = sum(((raw[lab == k] - raw[lab == k].mean()) ** 2).sum() for k in np.unique(lab))
    assert sse / ((raw - raw.mean()) ** 2).sum() < 0.03  # labels = faces: nothing left over
    e_true = float(_region_energy(true.R, true.t, sc))
    assert e_true < 0.08  # smoothing and the few antenna pixels only
    wrong = so3_exp(jnp.asarray([0.0, 0.7, 0.0])) @ true.R
    assert float(_region_energy(wrong, true.t, sc)) > 3 * e_true + 0.1


def test_fit_model_side_weight_and_length_weights():
    """The model side of the fit's residuals: scaled by the square root of its weight, and with
    ``by_length`` each edge's samples weighted by its length (antennas 0), checked against the
    distance map read by hand at the projected samples."""
    from jaxpose.pipelines.monocular.fit import _chamfer_residuals
    from jaxpose.pipelines.monocular.scene import _fit_sample_weights
    from jaxpose.pipelines.monocular.score import _visible_edges

    true, sc = _scene()
    model = tango()
    R = so3_exp(jnp.asarray([0.02, 0.01, -0.03])) @ true.R
    t = true.t + jnp.asarray([0.02, 0.01, 0.1])
    vis = _visible_edges(R, t, sc.geom)
    n_model = int(np.prod(sc.geom[1].shape[:2]))
    base = np.asarray(_chamfer_residuals(R, t, vis, sc))
    w4 = np.asarray(_chamfer_residuals(R, t, vis, sc._replace(fit_model_weight=4.0)))
    assert np.allclose(w4[:n_model], 2.0 * base[:n_model]) and np.any(base[:n_model] > 0)
    assert np.allclose(w4[n_model:], base[n_model:])

    w = np.asarray(_fit_sample_weights(model, True))
    lengths = np.linalg.norm(np.diff(model.vertices[model.edges], axis=1)[:, 0], axis=-1)
    E = len(model.edges)
    assert np.allclose(w[:E], lengths / lengths.mean()) and np.all(w[E:] == 0.0)
    assert _fit_sample_weights(model, False) is None

    # by hand: the weighted mean square of the truncated distances at the visible samples
    pts = np.asarray(sc.geom[1]) @ np.asarray(R).T + np.asarray(t)
    fx, fy, cx, cy = np.asarray(sc.cam4)
    uv = np.stack([fx * pts[..., 0] / pts[..., 2] + cx, fy * pts[..., 1] / pts[..., 2] + cy], -1)
    d = np.minimum(np.asarray(_bilinear(sc.dt, jnp.asarray(uv))), sc.tau)
    ws = np.where(np.asarray(vis)[:, None], w[:, None], 0.0) * np.ones(d.shape)
    ref = np.sum(ws * d * d) / np.sum(ws)
    r = np.asarray(_chamfer_residuals(R, t, vis, sc._replace(fit_sample_w=jnp.asarray(w))))
    assert np.isclose(np.sum(r[:n_model] ** 2), ref, rtol=1e-9)


def test_chamfer_fit_by_length_recovers_a_perturbed_pose():
    from jaxpose.pipelines.monocular.scene import _fit_sample_weights

    true, sc = _scene()
    sc = sc._replace(fit_sample_w=_fit_sample_weights(tango(), True), fit_model_weight=0.25)
    R0 = so3_exp(jnp.asarray([0.03, -0.04, 0.02])) @ true.R
    t0 = true.t + jnp.asarray([0.04, -0.03, 0.15])
    R, t = _chamfer_fit(R0, t0, sc, steps=12)
    assert _angle_deg(R, true.R) < 1.0
    assert float(jnp.linalg.norm(t - true.t)) < 0.05


def test_fit_model_weight_is_checked():
    import pytest

    from jaxpose.pipelines.monocular import InitOptions, initialise_pose

    img = np.zeros((64, 64), np.uint8)
    cam = PinholeCamera(100.0, 100.0, 32.0, 32.0, width=64, height=64)
    for bad in (0.0, -1.0, float("nan"), True):
        with pytest.raises(ValueError, match="fit_model_weight"):
            initialise_pose(img, cam, options=InitOptions(fit_model_weight=bad))
