"""Confidence class of the selected pose."""

from __future__ import annotations

__all__ = ["classify"]


def classify(score_rel: float, coverage: float, thresholds: dict) -> str:
    """``"high"``, ``"low"`` or ``"position-only"`` from the symmetric truncated chamfer distance at
    the final pose over ``l_ROI`` (``score_rel``) and the share of visible model edges with a
    detected endpoint nearby (``coverage``), against ``thresholds``
    (:data:`~jaxpose.pipelines.monocular.options.CONFIDENCE`): ``high`` when the score is at most
    ``high_score`` and the coverage at least ``high_coverage``; ``low`` when the score is at most
    ``low_score``."""
    if score_rel <= thresholds["high_score"] and coverage >= thresholds["high_coverage"]:
        return "high"
    if score_rel <= thresholds["low_score"]:
        return "low"
    return "position-only"
