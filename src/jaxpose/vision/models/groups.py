"""Model feature groups, built with the same rules as the image's (:mod:`jaxpose.vision.synthesis`).

For a 3-D model, "proximal" means sharing a vertex (``d_max`` a micrometre) and "parallel" means
3-D directions within ``theta_max_deg``. Antenna segments are kept apart (``antennas``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jaxpose.vision.synthesis import FeatureGroups, synthesize

__all__ = ["ModelGroups", "model_groups"]


@dataclass
class ModelGroups(FeatureGroups):
    """:class:`FeatureGroups` of a model; ``antenna_points`` is ``(A, 2, 3)`` (base, tip)."""

    antenna_points: np.ndarray | None = None


def model_groups(model, *, theta_max_deg: float = 5.0, max_groups: int = 100_000) -> ModelGroups:
    """Precompute the feature groups of a :class:`~jaxpose.vision.models.WireframeModel`."""
    g = synthesize(
        model.edge_points, d_max=1e-6, theta_max_deg=theta_max_deg, max_groups=max_groups
    )
    return ModelGroups(
        points=g.points,
        segments=g.segments,
        antennas=np.arange(len(model.antennas)),
        antenna_points=model.antenna_points,
    )
