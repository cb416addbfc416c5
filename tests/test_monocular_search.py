"""Fast tests of the monocular search components: segment distances, the segment-cluster ROI
(Earth-background rejection), and the hypothesis budget shared among group kinds."""

import numpy as np
import pytest

from jaxpose import PinholeCamera, Pose
from jaxpose.core.geometry import euler_to_dcm
from jaxpose.pipelines.monocular import InitOptions, initialise_pose
from jaxpose.pipelines.monocular.hypothesise import _allocate, _hypotheses
from jaxpose.vision.features import bright_background_share, detect
from jaxpose.vision.models import tango
from jaxpose.vision.render import render
from jaxpose.vision.roi import roi_diagonal, roi_from_segments, segment_distances


def _brute_distance(a, b):
    """Reference: dense sampling of both segments (independent of the closed form)."""
    s = np.linspace(0.0, 1.0, 501)[:, None]
    pa, pb = a[0] + s * (a[1] - a[0]), b[0] + s * (b[1] - b[0])
    # point-to-segment by sampling the other segment finely
    d = np.linalg.norm(pa[:, None] - pb[None], axis=-1)
    return d.min()


def test_segment_distances_against_sampling():
    rng = np.random.default_rng(3)
    S = rng.uniform(0, 100, (12, 2, 2))
    D = segment_distances(S)
    for i in range(12):
        for j in range(12):
            ref = 0.0 if i == j else _brute_distance(S[i], S[j])
            # sampling at 1/500 of a <=142 px segment: within 0.3 px
            assert abs(D[i, j] - ref) < 0.3, (i, j, D[i, j], ref)
    assert np.allclose(D, D.T)


def test_segment_distances_crossing():
    S = np.array([[[0, 0], [10, 10]], [[0, 10], [10, 0]]], float)  # an X
    assert segment_distances(S)[0, 1] == 0.0
    assert segment_distances(S, crossings=False)[0, 1] == pytest.approx(np.sqrt(50.0))


def _square(x0, y0, side):
    c = np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]], float)
    return np.stack([c, np.roll(c, -1, axis=0)], axis=1)


def test_cluster_roi_ignores_clutter_and_limb():
    target = _square(400, 300, 100)  # four edges meeting at corners
    clouds = np.array(
        [[[50, 50], [70, 58]], [[900, 100], [915, 130]], [[120, 700], [150, 690]]], float
    )
    # a limb: a chain of long, nearly collinear segments passing by the target's corner
    limb = np.array(
        [[[100, 0], [300, 250]], [[300, 250], [500, 400]], [[500, 400], [800, 600]]], float
    )
    S = np.concatenate([clouds, target, limb])
    box, idx = roi_from_segments(S)
    assert box is not None
    assert np.allclose(box, [400, 300, 500, 400])
    assert sorted(idx.tolist()) == [3, 4, 5, 6]


def test_cluster_roi_takes_in_fragments():
    """A weak edge broken into pieces splits the target into clusters: the smaller ones whose
    boxes meet the main one are taken in, a far one is not."""
    main = np.array([[[100, 100], [200, 100]], [[100, 100], [100, 200]]], float)  # an L
    piece = np.array([[[190, 180], [215, 180]], [[215, 180], [215, 205]]], float)  # not linked
    far = np.array([[[400, 400], [420, 400]], [[420, 400], [420, 420]]], float)
    box, idx = roi_from_segments(np.concatenate([main, piece, far]))
    assert np.allclose(box, [100, 100, 215, 205])
    assert sorted(idx.tolist()) == [0, 1, 2, 3]


def test_cluster_roi_needs_a_corner():
    lines = np.array([[[0, 0], [100, 0]], [[0, 5], [100, 5]], [[200, 0], [200, 50]]], float)
    box, idx = roi_from_segments(lines[:2])  # parallel only: no corner, no target
    assert box is None and len(idx) == 0
    assert roi_from_segments(np.zeros((0, 2, 2)))[0] is None
    with pytest.raises(ValueError):
        roi_from_segments(np.zeros((3, 2, 3)))


@pytest.mark.parametrize("weight", [-0.5, float("nan")])
def test_region_weight_is_checked_before_work(camera, weight):
    with pytest.raises(ValueError, match="region_weight"):
        initialise_pose(
            np.zeros((64, 64), np.uint8), camera, options=InitOptions(region_weight=weight)
        )


def test_allocate_water_filling():
    out = _allocate([96, 5000, 3000, 0], 4096)
    assert out.sum() <= 4096
    assert out[0] == 96 and out[3] == 0  # a small need is met in full
    assert out[1] == out[2] == (4096 - 96) // 2  # the rest split evenly
    assert list(_allocate([10, 20], 100)) == [10, 20]


@pytest.fixture(scope="module")
def camera():
    return PinholeCamera(747.0, 747.0, 239.5, 149.5, width=480, height=300)


def test_earth_background_roi():
    """With an Earth background the cluster ROI replaces the inflated gradient ROI (SPEED+
    resolution; the renderer's box of the visible model is the reference)."""
    camera = PinholeCamera(2988.6, 2988.3, 959.5, 599.5, width=1920, height=1200)
    model = tango()
    pose = Pose(np.asarray(euler_to_dcm(np.array([2.3, 0.4, 0.6]))), np.array([0.3, 0.1, 8.0]))
    r = render(model, pose, camera, rng=12, earth=True)
    true = r.roi
    det = detect(r.image, camera, model.characteristic_length)
    ratio_on = roi_diagonal(det.roi) / roi_diagonal(true)
    ratio_off = roi_diagonal(det.roi_gradient) / roi_diagonal(true)
    assert 0.8 < ratio_on < 1.2
    assert ratio_off > 1.5
    # against black space the bright share away from the target is about zero: no switch
    dark = render(model, pose, camera, rng=12, earth=False)
    assert bright_background_share(dark.image, true) < 0.01
    assert bright_background_share(r.image, true) > 0.1


def test_hypotheses_use_several_kinds(camera):
    model = tango()
    pose = Pose(np.asarray(euler_to_dcm(np.array([2.3, 0.4, 0.6]))), np.array([0.05, -0.03, 4.0]))
    r = render(model, pose, camera, rng=7)
    det = detect(r.image, camera, model.characteristic_length)
    P, Q, M, info, kinds = _hypotheses(det, model, InitOptions(max_hypotheses=1024))
    assert len(kinds) >= 2
    assert len(P) == len(Q) == len(M) == len(info)
    assert len(P) <= 1024 + 2000  # at most one extra image group of the last kind
    assert M.sum(1).min() >= 4
