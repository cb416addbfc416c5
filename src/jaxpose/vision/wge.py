"""Weak gradient elimination (Sharma et al. 2018 Sec. III.A.1, eqs. 3-4, Fig. 4).

Prewitt gradient magnitude; a 100-bin histogram of the magnitude normalised to ``[0, 1]``; an
exponential PDF fitted to that histogram (maximum likelihood: rate = 1 / binned mean; the paper
does not say how it fits); every pixel in a bin below the bin where the fitted CDF reaches 0.99 is
zeroed.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["WGEResult", "prewitt_magnitude", "weak_gradient_elimination"]

_PREWITT_X = np.array([[-1, 0, 1], [-1, 0, 1], [-1, 0, 1]], dtype=np.float32)


def prewitt_magnitude(image: np.ndarray) -> np.ndarray:
    """``G = sqrt(Gx^2 + Gy^2)`` with the 3x3 Prewitt kernels (eqs. 3-4), float32."""
    img = np.asarray(image, dtype=np.float32)
    gx = cv2.filter2D(img, cv2.CV_32F, _PREWITT_X, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.filter2D(img, cv2.CV_32F, _PREWITT_X.T, borderType=cv2.BORDER_REPLICATE)
    return cv2.magnitude(gx, gy)


@dataclass
class WGEResult:
    """Output of :func:`weak_gradient_elimination`.

    Attributes:
        filtered: ``(H, W)`` float32 gradient magnitude with the weak pixels set to zero.
        magnitude: ``(H, W)`` the Prewitt magnitude before elimination.
        threshold: magnitude below which pixels were zeroed (lower edge of the CDF bin).
        rate: fitted exponential rate (per unit of normalised magnitude).
    """

    filtered: np.ndarray
    magnitude: np.ndarray
    threshold: float
    rate: float

    @property
    def binary(self) -> np.ndarray:
        return (self.filtered > 0).astype(np.uint8) * 255


def weak_gradient_elimination(
    image: np.ndarray | None,
    *,
    cdf: float = 0.99,
    bins: int = 100,
    magnitude: np.ndarray | None = None,
) -> WGEResult:
    """Zero the weak gradients of ``image`` (grayscale, already smoothed by the caller)."""
    if not 0 < cdf < 1:
        raise ValueError(f"cdf must be in (0, 1); got {cdf}")
    G = prewitt_magnitude(image) if magnitude is None else magnitude
    gmax = float(G.max())
    if not np.isfinite(gmax) or gmax <= 0:
        return WGEResult(np.zeros_like(G), G, np.inf, np.inf)
    counts, edges = np.histogram(G / gmax, bins=bins, range=(0.0, 1.0))
    centres = 0.5 * (edges[:-1] + edges[1:])
    mean = float(counts @ centres) / max(int(counts.sum()), 1)
    rate = 1.0 / max(mean, 1e-12)
    x99 = -np.log(1.0 - cdf) / rate  # fitted CDF 1 - exp(-rate x) reaches `cdf`
    k = min(int(np.searchsorted(edges, x99, side="right") - 1), bins - 1)
    threshold = float(edges[max(k, 0)]) * gmax
    filtered = np.where(G >= threshold, G, 0.0).astype(np.float32)
    return WGEResult(filtered, G, threshold, rate)
