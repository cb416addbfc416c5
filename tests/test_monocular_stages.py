"""Stages of the monocular search that work without a clean background: gradient-orientation
maps and the orientation term (LINE-2D-like), the attitude grid placed on the ROI, the margin,
and the stage diagnostics against a known pose."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxpose import PinholeCamera, Pose
from jaxpose.core.geometry import euler_to_dcm, so3_exp
from jaxpose.pipelines.monocular.diagnose import stage_breakdown, stage_counts, true_box
from jaxpose.pipelines.monocular.hypothesise import _place_on_roi
from jaxpose.pipelines.monocular.scene import _EdgeScene, _ideal_params, _model_geometry
from jaxpose.pipelines.monocular.score import _orientation_term
from jaxpose.vision.image_maps import ORIENTATION_BINS, ROD_SIDE, orientation_maps
from jaxpose.vision.models import tango
from jaxpose.vision.render import render

jax.config.update("jax_enable_x64", True)


def test_orientation_maps_of_a_rectangle():
    """A bright axis-aligned rectangle: its vertical sides have horizontal gradients (bin 0), its
    horizontal sides vertical ones (bin B/2); away from the sides nothing votes; the response of a
    neighbouring bin is |cos(180/B deg)|, of the perpendicular bin 0."""
    img = np.zeros((200, 300), np.uint8)
    cv2.rectangle(img, (100, 60), (200, 140), 200, -1)
    roi = np.array([100.0, 60.0, 200.0, 140.0])
    maps, frame = orientation_maps(img, roi)
    B = ORIENTATION_BINS
    assert maps.shape == (B, ROD_SIDE, ROD_SIDE) and frame[2] == 1.0  # the crop is small: no shrink

    def cell(u, v):
        return int(round((v - frame[1]) * frame[2])), int(round((u - frame[0]) * frame[2]))

    i, j = cell(100, 100)  # on the left side
    assert maps[0, i, j] == 1.0 and maps[B // 2, i, j] < 1e-6
    assert np.isclose(maps[1, i, j], np.cos(np.pi / B), atol=1e-6)
    i, j = cell(150, 60)  # on the top side
    assert maps[B // 2, i, j] == 1.0 and maps[0, i, j] < 1e-6
    i, j = cell(150, 100)  # the uniform inside
    assert maps[:, i, j].max() == 0.0


def _scene(earth: bool):
    cam = PinholeCamera(1500.0, 1500.0, 479.5, 299.5, width=960, height=600)
    pose = Pose(np.asarray(euler_to_dcm(jnp.array([0.7, -0.5, 1.9]))), np.array([0.1, 0.0, 6.0]))
    model = tango()
    r = render(model, pose, cam, rng=3, earth=earth)
    maps, frame = orientation_maps(r.image, r.roi)
    sc = _EdgeScene(
        _model_geometry(model),
        jnp.zeros((4, 2)),
        jnp.zeros(4, bool),
        jnp.zeros((600, 960)),
        0.05 * float(np.hypot(*(r.roi[2:] - r.roi[:2]))),
        _ideal_params(cam),
    )._replace(ori=jnp.asarray(maps), ori_frame=jnp.asarray(frame), orientation_weight=1.0)
    return model, cam, pose, r, sc


def test_orientation_term_prefers_the_true_pose_over_the_earth():
    """Over an Earth background the projected edges of the true pose agree with the image's
    gradient orientations far better than a pose turned by 90 degrees about the line of sight
    at the same place, or the true pose shifted off the target by a tenth of the ROI."""
    model, cam, pose, r, sc = _scene(earth=True)
    R, t = jnp.asarray(pose.R), jnp.asarray(pose.t)
    at_true = float(_orientation_term(R, t, sc))
    turned = so3_exp(jnp.asarray([0.0, 0.0, np.pi / 2]))
    c = R @ jnp.mean(sc.geom[1].reshape(-1, 3), axis=0) + t
    at_turned = float(_orientation_term(turned @ R, turned @ (t - c) + c, sc))
    shift = 0.1 * float(np.hypot(*(r.roi[2:] - r.roi[:2]))) / 1500.0 * float(t[2])
    at_shift = float(_orientation_term(R, t + jnp.asarray([shift, 0.0, 0.0]), sc))
    assert 0.0 <= at_true < 0.25
    assert at_turned > at_true + 0.25 and at_shift > at_true + 0.2


def test_place_on_roi_recovers_range_and_position():
    """The true attitude placed from a wrong range and offset lands on the ROI of the model's
    projected samples: box diagonal and centre equal to the ROI's to a small fraction."""
    model, cam, pose, r, sc = _scene(earth=False)
    R, t = jnp.asarray(pose.R), jnp.asarray(pose.t)
    pix = np.asarray(cam.project(np.asarray(sc.geom[1]).reshape(-1, 3) @ np.asarray(R).T + t))
    roi = jnp.asarray(np.r_[pix.min(0), pix.max(0)])
    t_new = _place_on_roi(R, t * 1.4 + jnp.asarray([0.3, -0.2, 0.0]), sc, roi)
    np.testing.assert_allclose(np.asarray(t_new), np.asarray(t), atol=0.03 * float(t[2]))
    # a pose behind the camera is returned unchanged
    t_back = jnp.asarray([0.0, 0.0, -5.0])
    assert np.array_equal(np.asarray(_place_on_roi(R, t_back, sc, roi)), np.asarray(t_back))


class _Result:
    """The fields of an InitResult that stage_breakdown reads."""

    def __init__(self, det, roi, pose, trace):
        self.detection, self.roi, self.pose, self.trace = det, roi, pose, trace


class _Det:
    def __init__(self, camera, shape):
        self.camera, self.image = camera, np.zeros(shape, np.uint8)


def test_stage_breakdown_counts_each_stage():
    model = tango()
    cam = PinholeCamera(1500.0, 1500.0, 479.5, 299.5, width=960, height=600)
    truth = Pose(np.asarray(euler_to_dcm(jnp.array([0.7, -0.5, 1.9]))), np.array([0.1, 0.0, 6.0]))
    det = _Det(cam, (600, 960))
    box = true_box(_Result(det, None, None, None), truth, model)
    near = Pose(
        np.asarray(so3_exp(jnp.asarray([0.0, 0.1, 0.0]))) @ truth.R, truth.t + 0.1
    )  # 5.7 deg
    far = Pose(np.asarray(so3_exp(jnp.asarray([0.0, 0.0, np.pi]))) @ truth.R, truth.t)  # a flip
    R = np.stack([far.R, near.R])
    t = np.stack([far.t, near.t])
    trace = {
        "hypotheses": (R, t, np.array([True, True])),
        "shortlist": (R[:1], t[:1]),  # the near one lost by the quick score
        "candidates": [far],
        "refined": [far],
        "chosen": 0,
    }
    rec = stage_breakdown(_Result(det, box, far, trace), truth, model)
    assert rec["roi_iou"] == 1.0 and rec["roi_ok"]
    assert rec["hypothesis_close"] and not rec["shortlist_close"] and not rec["success"]
    shifted = box + np.array([0.6, 0, 0.6, 0]) * (box[2] - box[0])  # IoU 0.25
    rec2 = stage_breakdown(_Result(det, shifted, near, dict(trace, refined=[near])), truth, model)
    assert not rec2["roi_ok"] and np.isclose(rec2["roi_iou"], 0.4 / 1.6)
    assert rec2["refined_close"] and rec2["first"] and rec2["success"]
    counts = stage_counts([rec, rec2])
    assert counts["hypothesis_close"] == 2 and counts["roi_ok"] == 1
    assert counts["success"] == 1 and counts["success_cumulative"] == 0


def test_classify_rule():
    from jaxpose.pipelines.monocular import CONFIDENCE, classify

    th = dict(
        CONFIDENCE, high_score=0.02, high_coverage=0.9, high_orientation=0.7, high_margin=0.01
    )
    good = dict(orientation=0.8, margin=0.05)
    assert classify(0.015, 0.95, th, **good) == "high"
    assert classify(0.015, 0.95, th, orientation=0.6, margin=0.05) == "low"  # edges disagree
    assert classify(0.015, 0.95, th, orientation=0.8, margin=0.001) == "low"  # a rival is close
    assert classify(0.015, 0.95, th, orientation=0.8, margin=float("inf")) == "high"  # no rival
    assert classify(0.015, 0.8, th, **good) == "low"
    assert classify(0.03, 0.95, th, **good) == "low"
    assert classify(th["low_score"] * 1.01, 0.95, th, **good) == "position-only"
    assert classify(float("inf"), 0.95, th, **good) == "position-only"
    assert classify(float("nan"), 0.95, th, **good) == "position-only"
    assert classify(0.015, 0.95, th) == "high"  # terms off: the score and coverage decide
