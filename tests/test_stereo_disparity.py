"""The stereo search's disparity windows (:mod:`jaxpose.pipelines.stereo.disparity`) against
closed forms: a point at depth ``Z`` has disparity ``fx b / Z``."""

from types import SimpleNamespace

import numpy as np

from jaxpose.core.geometry import Pose
from jaxpose.pipelines.stereo import TrackerOptions
from jaxpose.pipelines.stereo.disparity import feature_windows, measured_margin
from jaxpose.pipelines.stereo.keyframes import FrameStereo
from jaxpose.pipelines.stereo.landmarks import LandmarkMap
from jaxpose.vision.stereo_render import default_rig

RIG = default_rig()
FB = float(RIG.left.fx) * float(RIG.baseline)


def _scene():
    """Four point landmarks at 2-2.6 m ahead of an identity pose, their pixels, and a fifth
    keypoint beside them with no landmark."""
    X = np.array([[0.0, 0.0, 2.0], [0.02, 0.0, 2.2], [0.0, 0.02, 2.4], [0.02, 0.02, 2.6]])
    m = LandmarkMap()
    pose = Pose(np.eye(3), np.zeros(3))
    m.add("points", X, np.zeros((4, 32), np.uint8), pose, 0)
    fx, cx, cy = float(RIG.left.fx), float(RIG.left.cx), float(RIG.left.cy)
    px = np.c_[fx * X[:, 0] / X[:, 2] + cx, fx * X[:, 1] / X[:, 2] + cy]
    feats = SimpleNamespace(points=np.vstack([px, px[0] + 5.0]), segments=np.zeros((0, 2, 2)))
    return m, pose, feats


def test_matched_points_search_their_predicted_disparity_and_neighbours_theirs():
    m, pose, feats = _scene()
    base = np.array([10, 400])
    matches = (np.arange(4), np.arange(4), np.zeros(0, int), np.zeros(0, int))
    o = TrackerOptions()
    dp, dl, (idx, d) = feature_windows(m, RIG, o, feats, pose, matches, base, 3.0, warm=True)
    want = FB / np.array([2.0, 2.2, 2.4, 2.6])
    assert np.allclose(d, want)
    assert (dp[:4, 0] == np.floor(want - 3.0)).all() and (dp[:4, 1] == np.ceil(want + 3.0)).all()
    # the fifth keypoint: its neighbours' range (all four within neighbour_px), widened by the
    # margin and by that range again
    lo, hi = want.min(), want.max()
    assert dp[4, 0] == np.floor(lo - 3.0 - (hi - lo)) and dp[4, 1] == np.ceil(hi + 3.0 + (hi - lo))
    assert dl.shape == (0, 2)
    # not warm yet: every feature keeps the base window, the predictions still returned
    dp, _, pred = feature_windows(m, RIG, o, feats, pose, matches, base, 3.0, warm=False)
    assert (dp == base).all() and np.allclose(pred[1], want)
    dp, _, pred = feature_windows(m, RIG, o, feats, pose, None, base, 3.0, warm=True)
    assert (dp == base).all() and pred is None


def test_the_margin_is_four_robust_sigmas_of_the_measured_minus_predicted_disparities():
    rng = np.random.default_rng(0)
    n = 400
    pixels = np.c_[rng.uniform(300, 700, n), rng.uniform(200, 500, n)]
    d_pred = rng.uniform(100, 120, n)
    err = rng.normal(scale=1.5, size=n)
    stereo = FrameStereo(
        point_idx=np.arange(n),
        points=np.zeros((n, 3)),
        pixels_right=np.c_[pixels[:, 0] - (d_pred + err), pixels[:, 1]],
        line_idx=np.zeros(0, int),
        segments=np.zeros((0, 2, 3)),
    )
    feats = SimpleNamespace(points=pixels)
    got = measured_margin(feats, stereo, (np.arange(n), d_pred))
    sigma = np.median(np.abs(err)) / 0.6745
    assert np.isclose(got, 4 * sigma + 2)
    assert 7.0 < got < 9.0  # about 4 x 1.5 + 2
    assert measured_margin(feats, stereo, None) is None
    assert measured_margin(feats, stereo, (np.arange(5), d_pred[:5])) is None  # too few
