"""The confidence class's second route to ``high`` (the silhouette, the face shading and the
coarse range agree with the pose) and the range agreement it reads
(:func:`jaxpose.pipelines.monocular.classify.classify`)."""

import math

import numpy as np
import pytest

from jaxpose.pipelines.monocular.classify import check_thresholds, classify
from jaxpose.pipelines.monocular.options import CONFIDENCE
from jaxpose.pipelines.monocular.pipeline import _range_agreement

TH = {
    "high_score": 0.03,
    "high_coverage": 0.95,
    "high_orientation": 0.6,
    "high_margin": 0.005,
    "high_spread": 0.6,
    "silhouette_iou": 0.7,
    "silhouette_spread": 0.8,
    "silhouette_range": 0.05,
    "low_score": 0.1,
}


def test_silhouette_route_needs_every_one_of_its_quantities():
    # a photograph's right pose: the edges fit loosely (score, coverage, orientation fail the
    # first route) but the silhouette, the shading and the size agree
    photo = dict(orientation=0.4, margin=0.002, spread=0.7, silhouette=0.75, range_agreement=0.03)
    assert classify(0.04, 0.7, TH, **photo) == "high"
    for key, bad in (("silhouette", 0.69), ("spread", 0.81), ("range_agreement", 0.06)):
        assert classify(0.04, 0.7, TH, **(photo | {key: bad})) == "low"
    assert classify(0.11, 0.7, TH, **photo) == "position-only"  # no fit to the edges at all
    # no silhouette (an Earth behind the target) or no coarse range: only the first route
    assert classify(0.04, 0.7, TH, **(photo | {"silhouette": None})) == "low"
    assert classify(0.04, 0.7, TH, **(photo | {"range_agreement": None})) == "low"
    # thresholds without the second route: as before
    first_only = {k: v for k, v in TH.items() if not k.startswith("silhouette_")}
    assert classify(0.04, 0.7, first_only, **photo) == "low"
    # the first route alone still gives high without a silhouette
    edges = dict(orientation=0.8, margin=0.01, spread=0.3, silhouette=None, range_agreement=None)
    assert classify(0.02, 1.0, TH, **edges) == "high"
    assert classify(math.inf, 1.0, TH, **edges) == "position-only"


def test_range_agreement_is_the_absolute_log_ratio_of_the_ranges():
    t = np.array([0.0, 0.0, 10.0])
    assert _range_agreement(t, np.array([3.0, 4.0, 12.0])) == pytest.approx(abs(np.log(10 / 13)))
    assert _range_agreement(t, np.array([0.0, 0.0, 5.0])) == pytest.approx(np.log(2))
    assert _range_agreement(t, None) is None
    assert _range_agreement(np.zeros(3), t) is None


@pytest.mark.parametrize(
    "rule, match",
    [
        ([0.1], "dict of thresholds"),
        ({**TH, "high_scor": 0.03}, "unknown key"),
        ({k: v for k, v in TH.items() if k != "low_score"}, "lacks"),
        ({k: v for k, v in TH.items() if k != "silhouette_range"}, "give all three or none"),
        ({**TH, "high_margin": float("nan")}, "finite number"),
        ({**TH, "high_coverage": "0.9"}, "finite number"),
        ({**TH, "high_coverage": True}, "finite number"),
    ],
)
def test_a_malformed_confidence_rule_is_named(rule, match):
    with pytest.raises(ValueError, match=match):
        check_thresholds(rule)


def test_the_default_rule_and_one_without_the_silhouette_route_pass():
    check_thresholds(CONFIDENCE)
    no_route = {k: v for k, v in CONFIDENCE.items() if not k.startswith("silhouette_")}
    check_thresholds(no_route)
    check_thresholds({k: np.float32(v) for k, v in CONFIDENCE.items()})  # NumPy scalars count
    # without the route, a pose that only the silhouette supports is "low"
    photo = dict(orientation=0.4, margin=0.002, spread=0.7, silhouette=0.75, range_agreement=0.03)
    assert classify(0.04, 0.7, CONFIDENCE, **photo) == "high"
    assert classify(0.04, 0.7, no_route, **photo) == "low"
