"""Confidence class of the selected pose."""

from __future__ import annotations

import math

__all__ = ["classify"]


def classify(
    score_rel: float,
    coverage: float,
    thresholds: dict,
    *,
    orientation: float | None = None,
    margin: float | None = None,
    spread: float | None = None,
) -> str:
    """``"high"``, ``"low"`` or ``"position-only"`` from the evidence of the final pose against
    ``thresholds`` (:data:`~jaxpose.pipelines.monocular.options.CONFIDENCE`): the symmetric
    truncated chamfer distance over ``l_ROI`` (``score_rel``), the share of visible model edges
    with a detected endpoint nearby (``coverage``), the mean LINE-2D orientation similarity at
    the projected edges (``orientation``; ``None`` when the term is off: then it does not
    count) and the ranking margin to the best distinct candidate over ``l_ROI`` (``margin``;
    ``None`` or ``inf`` when there is none, which passes) and the face-shading spread at the pose
    (``spread``, :func:`~jaxpose.pipelines.monocular.score._face_spread`; ``None`` when the model
    has no faces: then it does not count).

    ``high`` when every quantity passes its ``high_*`` threshold; ``low`` when the score is at
    most ``low_score``; ``position-only`` otherwise."""
    if not math.isfinite(score_rel):
        return "position-only"
    ori_ok = orientation is None or orientation >= thresholds.get("high_orientation", 0.0)
    margin_ok = margin is None or margin >= thresholds.get("high_margin", 0.0)
    spread_ok = spread is None or spread <= thresholds.get("high_spread", math.inf)
    if (
        score_rel <= thresholds["high_score"]
        and coverage >= thresholds["high_coverage"]
        and ori_ok
        and margin_ok
        and spread_ok
    ):
        return "high"
    if score_rel <= thresholds["low_score"]:
        return "low"
    return "position-only"
