"""Fast tests of the antenna term of the monocular ranking: the rod map responds to thin rods
(bright or dark) and not to faces, its pixel frame is right, and the term prefers the pose whose
antennas lie on the image's rods to the 180-degree flip that moves them."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import PinholeCamera, Pose
from jaxpose.core.geometry import euler_to_dcm, so3_exp
from jaxpose.pipelines.monocular import InitOptions, initialise_pose
from jaxpose.pipelines.monocular.scene import _EdgeScene, _ideal_params, _model_geometry
from jaxpose.pipelines.monocular.score import _antenna_term
from jaxpose.vision.image_maps import rod_map
from jaxpose.vision.models import tango

jax.config.update("jax_enable_x64", True)


def _lookup(rods, frame, uv):
    """Rod response at image pixels ``uv (N, 2)`` through the map's frame (nearest cell)."""
    ij = np.rint((np.asarray(uv, float) - np.asarray(frame)[:2]) * float(frame[2])).astype(int)
    return np.asarray(rods)[ij[:, 1], ij[:, 0]]


def test_rod_map_sees_thin_rods_and_not_faces():
    img = np.full((700, 900), 30, np.uint8)
    cv2.rectangle(img, (300, 200), (560, 460), 220, -1)  # a lit face
    cv2.line(img, (120, 150), (280, 330), 200, 5)  # a bright antenna against space
    cv2.line(img, (330, 420), (530, 230), 60, 5)  # a dark rod across the lit face
    roi = np.array([100.0, 140.0, 580.0, 480.0])
    rods, frame = rod_map(img, roi)
    assert rods.shape == (256, 256) and np.all((np.asarray(rods) >= 0) & (np.asarray(rods) <= 1))
    s = np.linspace(0.2, 0.8, 7)[:, None]
    bright = np.array([120, 150]) + s * np.array([160, 180])
    dark = np.array([330, 420]) + s * np.array([200, -190])
    assert _lookup(rods, frame, bright).min() > 0.5
    assert _lookup(rods, frame, dark).min() > 0.5
    face = np.array([[350, 250], [520, 420], [400, 260], [470, 410]])  # 60+ px off the dark rod
    assert _lookup(rods, frame, face).max() < 0.15
    space = np.array([[200, 420], [150, 460], [570, 170]])
    assert _lookup(rods, frame, space).max() < 0.15


def _flip_that_moves_the_antennas(model, pose, cam4):
    """Of the three 180-degree turns about body axes through the model's centre, the one that
    moves the projected antenna tips furthest (a test construct: the box outline lands near
    itself, the antennas elsewhere)."""
    c = jnp.asarray(np.asarray(model.vertices).mean(0))
    tips = jnp.asarray(model.antenna_points[:, 1])

    def proj(R, t):
        p = tips @ R.T + t
        return np.asarray(jnp.stack([cam4[0] * p[:, 0] / p[:, 2], cam4[1] * p[:, 1] / p[:, 2]], 1))

    best = None
    for axis in np.eye(3):
        Rf = pose.R @ so3_exp(jnp.asarray(np.pi * axis))
        tf = pose.t + pose.R @ c - Rf @ c
        moved = float(np.min(np.linalg.norm(proj(Rf, tf) - proj(pose.R, pose.t), axis=1)))
        if best is None or moved > best[0]:
            best = (moved, Pose(Rf, tf))
    return best[1]


def test_antenna_term_prefers_the_antennas_on_the_rods():
    """Independent image: the projected antennas drawn as 3-pixel rods with OpenCV on a dark
    background with the body as a filled grey box."""
    model = tango()
    cam = PinholeCamera(1200.0, 1200.0, 400.0, 300.0, width=800, height=600)
    R = np.asarray(euler_to_dcm(jnp.array([0.7, -0.4, 0.3])))
    true = Pose(jnp.asarray(R), jnp.asarray([0.1, -0.05, 5.0]))
    cam4 = _ideal_params(cam)

    def project(points):
        p = np.asarray(points) @ R.T + np.asarray(true.t)
        return np.c_[1200.0 * p[:, 0] / p[:, 2] + 400.0, 1200.0 * p[:, 1] / p[:, 2] + 300.0]

    img = np.full((600, 800), 25, np.uint8)
    hull = cv2.convexHull(np.round(project(model.vertices)).astype(np.int32))
    cv2.fillConvexPoly(img, hull, 120)
    for base, tip in model.antenna_points:
        a, b = project(np.stack([base, tip]))
        cv2.line(img, tuple(np.round(a).astype(int)), tuple(np.round(b).astype(int)), 230, 3)
    uv = project(model.vertices)
    roi = np.r_[uv.min(0), uv.max(0)]
    rods, frame = (jnp.asarray(x) for x in rod_map(img, roi))
    l_roi = float(np.hypot(*(roi[2:] - roi[:2])))
    sc = _EdgeScene(
        _model_geometry(model),
        jnp.zeros((1, 2)),
        jnp.zeros(1, bool),
        jnp.zeros((600, 800)),
        0.05 * l_roi,
        cam4,
    )._replace(rods=rods, rod_frame=frame, antenna_weight=1.0)
    tau = 0.05 * l_roi
    flip = _flip_that_moves_the_antennas(model, true, cam4)
    at_true = float(_antenna_term(true.R, true.t, sc))
    at_flip = float(_antenna_term(flip.R, flip.t, sc))
    assert 0.0 <= at_true < 0.3 * tau
    assert at_flip > 0.6 * tau
    # a model without antennas gets no rod map at all (the term is off)
    assert _EdgeScene(*sc[:6]).rods is None


@pytest.mark.parametrize("w", [-0.5, float("nan"), float("inf")])
def test_antenna_weight_must_be_finite_and_non_negative(w):
    cam = PinholeCamera(1200.0, 1200.0, 400.0, 300.0, width=800, height=600)
    with pytest.raises(ValueError, match="antenna_weight"):
        initialise_pose(np.zeros((600, 800), np.uint8), cam, options=InitOptions(antenna_weight=w))
