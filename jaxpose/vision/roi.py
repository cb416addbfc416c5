"""Region of interest from the WGE-filtered gradient (Sharma et al. 2018 Sec. III.A.1, Fig. 5):
along each image axis, the positions where the CDF of the filtered gradient reaches 0.025 and
0.975."""

from __future__ import annotations

import numpy as np

__all__ = ["roi_diagonal", "roi_from_gradient"]


def _quantiles(weights: np.ndarray, lo: float, hi: float) -> tuple[float, float]:
    c = np.cumsum(weights, dtype=np.float64)
    c /= c[-1]
    return float(np.searchsorted(c, lo)), float(np.searchsorted(c, hi))


def roi_from_gradient(
    filtered: np.ndarray, *, lo: float = 0.025, hi: float = 0.975
) -> np.ndarray | None:
    """``[u0, v0, u1, v1]`` (pixels) or ``None`` when the filtered gradient is all zero."""
    if not 0 <= lo < hi <= 1:
        raise ValueError(f"need 0 <= lo < hi <= 1; got {lo}, {hi}")
    F = np.asarray(filtered, dtype=np.float64)
    total = F.sum()
    if not np.isfinite(total) or total <= 0:
        return None
    u0, u1 = _quantiles(F.sum(0), lo, hi)
    v0, v1 = _quantiles(F.sum(1), lo, hi)
    return np.array([u0, v0, u1, v1])


def roi_diagonal(roi) -> float:
    """``l_ROI``: the ROI's diagonal length in pixels."""
    u0, v0, u1, v1 = roi
    return float(np.hypot(u1 - u0, v1 - v0))
