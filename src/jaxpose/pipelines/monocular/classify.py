"""Confidence class of the selected pose."""

from __future__ import annotations

import math

from jaxpose.core._checks import is_finite_number

__all__ = ["check_thresholds", "classify"]

#: Keys of a confidence rule: always needed, optional one by one, and the silhouette route's,
#: which come together or not at all.
_REQUIRED = ("high_score", "high_coverage", "low_score")
_OPTIONAL = ("high_orientation", "high_margin", "high_spread")
_SILHOUETTE = ("silhouette_iou", "silhouette_spread", "silhouette_range")


def check_thresholds(thresholds) -> None:
    """Raise ``ValueError`` naming what is wrong with a confidence rule (``InitOptions.
    confidence``, the layout of :data:`~jaxpose.pipelines.monocular.options.CONFIDENCE`):
    not a mapping, an unknown or missing key, the silhouette route's keys given in part, a value
    that is not a finite number."""
    if not hasattr(thresholds, "keys"):
        kind = type(thresholds).__name__
        raise ValueError(f"confidence must be a dict of thresholds; got {kind}")
    keys, known = set(thresholds), _REQUIRED + _OPTIONAL + _SILHOUETTE
    unknown = sorted(keys - set(known), key=str)
    if unknown:
        raise ValueError(f"confidence has unknown key(s) {unknown}; known: {list(known)}")
    missing = [k for k in _REQUIRED if k not in keys]
    if missing:
        raise ValueError(f"confidence lacks {missing} (needed by every rule)")
    part = [k for k in _SILHOUETTE if k in keys]
    if part and len(part) != len(_SILHOUETTE):
        raise ValueError(
            f"confidence has {part} of the silhouette route's keys {list(_SILHOUETTE)}: "
            "give all three or none (none: no silhouette route)"
        )
    for k, v in thresholds.items():
        if not is_finite_number(v):
            raise ValueError(f"confidence[{k!r}] must be a finite number; got {v!r}")


def classify(
    score_rel: float,
    coverage: float,
    thresholds: dict,
    *,
    orientation: float | None = None,
    margin: float | None = None,
    spread: float | None = None,
    silhouette: float | None = None,
    range_agreement: float | None = None,
) -> str:
    """``"high"``, ``"low"`` or ``"position-only"`` from the evidence of the final pose against
    ``thresholds`` (:data:`~jaxpose.pipelines.monocular.options.CONFIDENCE`): the symmetric
    truncated chamfer distance over ``l_ROI`` (``score_rel``), the share of visible model edges
    with a detected endpoint nearby (``coverage``), the mean LINE-2D orientation similarity at
    the projected edges (``orientation``; ``None`` when the term is off: then it does not
    count) and the ranking margin to the best distinct candidate over ``l_ROI`` (``margin``;
    ``None`` or ``inf`` when there is none, which passes) and the face-shading spread at the pose
    (``spread``, :func:`~jaxpose.pipelines.monocular.score._face_spread`; ``None`` when the model
    has no faces: then it does not count); the IoU of the projected faces with the image's
    silhouette (``silhouette``; ``None`` without a silhouette) and the absolute log ratio of the
    pose's range to the ROI's coarse range (``range_agreement``).

    ``high`` when every quantity passes its ``high_*`` threshold, or, with a silhouette, when
    the silhouette IoU, the spread and the range agreement pass their ``silhouette_*``
    thresholds and the score ``low_score`` (a second route for photographs, whose edges are
    cluttered by surface texture and shadow but whose silhouette, shading and size agree with
    the pose; thresholds absent: no second route); ``low`` when the score is at most
    ``low_score``; ``position-only`` otherwise."""
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
    if (
        "silhouette_iou" in thresholds
        and silhouette is not None
        and spread is not None
        and range_agreement is not None
        and silhouette >= thresholds["silhouette_iou"]
        and spread <= thresholds["silhouette_spread"]
        and range_agreement <= thresholds["silhouette_range"]
        and score_rel <= thresholds["low_score"]
    ):
        return "high"
    if score_rel <= thresholds["low_score"]:
        return "low"
    return "position-only"
