"""The face-shading spread of the monocular scores (one light, near-uniform faces) and its place
in the confidence class."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import PinholeCamera, Pose
from jaxpose.core.geometry import euler_to_dcm, so3_exp
from jaxpose.pipelines.monocular.scene import (
    _EdgeScene,
    _face_polygons,
    _ideal_params,
    _model_geometry,
    _pool_shading,
)
from jaxpose.pipelines.monocular.score import SPREAD_BAND, _jit_face_spread
from jaxpose.vision.image_maps import SHADING_GRID, shading_grid
from jaxpose.vision.models import tango
from jaxpose.vision.render import render_layers

jax.config.update("jax_enable_x64", True)

CAM = PinholeCamera(1500.0, 1500.0, 479.5, 299.5, width=960, height=600)


@pytest.fixture(scope="module")
def scene():
    """Tango under one light with untextured faces on a black background, its ROI, the scene."""
    model = tango()
    pose = Pose(np.asarray(euler_to_dcm(jnp.array([0.7, -0.5, 1.9]))), np.array([0.1, 0.0, 6.0]))
    rad, ids = render_layers(model, pose, CAM)
    img = np.nan_to_num(rad, nan=0.0) * 200.0 + 20.0
    v, u = np.nonzero(ids != -1)
    roi = np.array([u.min(), v.min(), u.max(), v.max()], float)
    tau = 0.05 * float(np.hypot(*(roi[2:] - roi[:2])))
    sc = _EdgeScene(
        _model_geometry(model),
        jnp.zeros((4, 2)),
        jnp.zeros(4, bool),
        jnp.zeros((600, 960)),
        tau,
        _ideal_params(CAM),
        face_poly=_face_polygons(model),
    )
    cells = tuple(jnp.asarray(a) for a in shading_grid(img, roi))
    sc = sc._replace(shade_pts=cells[0], shade_val=cells[1], shade_sq=cells[2])
    return model, pose, img, roi, sc


def _face_spread(R, t, sc, coarse=False):
    return _jit_face_spread()(R, t, sc, coarse)


def _spread_brute_force(model, R, t, sc):
    """The spread by cell-by-cell loops and OpenCV's signed point-polygon distance."""
    pts, val, sq = (np.asarray(a) for a in (sc.shade_pts, sc.shade_val, sc.shade_sq))
    fx, fy, cx, cy = np.asarray(sc.cam4)
    V = model.vertices @ R.T + t
    faces = []
    for idx in model.faces:
        P = V[list(idx)]
        n = np.cross(P[1] - P[0], P[2] - P[0])
        c = model.vertices[list(idx)].mean(0) @ R.T + t
        if np.all(P[:, 2] > 1e-3) and np.dot(n, c) < 0:
            uv = np.stack([fx * P[:, 0] / P[:, 2] + cx, fy * P[:, 1] / P[:, 2] + cy], 1)
            faces.append((c[2], uv.astype(np.float32).reshape(-1, 1, 2)))
    labels = {}
    for p in range(len(pts)):
        hits = [
            (depth, k, cv2.pointPolygonTest(poly, tuple(map(float, pts[p])), True))
            for k, (depth, poly) in enumerate(faces)
        ]
        hits = [h for h in hits if h[2] >= 0]
        if hits:
            _, k, d = min(hits)
            if d >= SPREAD_BAND * sc.tau:
                labels.setdefault(k, []).append(p)
    dev, n = 0.0, 0
    for cells in labels.values():
        m = val[cells].mean()
        dev += float(np.sum(sq[cells] - 2 * m * val[cells] + m * m))
        n += len(cells)
    total = sq.mean() - val.mean() ** 2
    return np.sqrt(dev / n / total) if n >= 8 else 1.0


def test_face_spread_matches_brute_force(scene):
    model, pose, _, _, sc = scene
    for rv, dt in (([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]), ([0.1, -0.2, 0.05], [0.05, -0.03, 0.2])):
        R = np.asarray(so3_exp(jnp.asarray(rv))) @ np.asarray(pose.R)
        t = np.asarray(pose.t) + dt
        got = float(_face_spread(jnp.asarray(R), jnp.asarray(t), sc))
        assert np.isclose(got, _spread_brute_force(model, R, t, sc), rtol=1e-6, atol=1e-9)


def test_face_spread_is_low_only_at_the_true_pose(scene):
    """Untextured faces under one light: near zero at the truth, large 15 deg or 10 cm off."""
    _, pose, _, _, sc = scene
    R, t = jnp.asarray(pose.R), jnp.asarray(pose.t)
    at_truth = float(_face_spread(R, t, sc))
    turned = float(_face_spread(so3_exp(jnp.array([0.0, 0.26, 0.0])) @ R, t, sc))
    shifted = float(_face_spread(R, t + jnp.array([0.1, 0.0, 0.0]), sc))
    assert at_truth < 0.1
    assert turned > 3 * at_truth and shifted > 3 * at_truth
    # on the pooled grid of the quick score: the same ordering
    sc2 = sc._replace(shade_coarse=_pool_shading(sc.shade_pts, sc.shade_val, sc.shade_sq))
    assert float(_face_spread(R, t, sc2, coarse=True)) < float(
        _face_spread(so3_exp(jnp.array([0.0, 0.26, 0.0])) @ R, t, sc2, coarse=True)
    )


def test_shading_grid_moments(scene):
    """Mean of squares >= square of means in every cell (equal where the cell is uniform), and
    the pooled cells hold the means of their four cells."""
    _, _, img, roi, _ = scene
    pts, val, sq = shading_grid(img, roi)
    assert pts.shape == (SHADING_GRID**2, 2) and val.shape == sq.shape == (SHADING_GRID**2,)
    assert np.all(sq >= val**2 - 1e-6)
    p2, v2, s2 = _pool_shading(pts, val, sq)
    G = SHADING_GRID // 2
    assert v2.shape == (G * G,) and np.isclose(v2[0], val[[0, 1, 48, 49]].mean())
    assert np.isclose(s2[G + 1], sq[[98, 99, 146, 147]].mean())


def test_classify_reads_the_spread():
    from jaxpose.pipelines.monocular import CONFIDENCE, classify

    th = dict(CONFIDENCE, high_score=0.05, high_coverage=0.5, high_spread=0.4)
    assert classify(0.03, 0.9, th, spread=0.3) == "high"
    assert classify(0.03, 0.9, th, spread=0.5) == "low"  # faces straddle structure
    assert classify(0.03, 0.9, th) == "high"  # no faces: the spread does not count
