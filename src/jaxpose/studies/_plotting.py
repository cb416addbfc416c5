"""Matplotlib helpers shared by the studies' figures (headless backend, plain log labels)."""

from __future__ import annotations

import math

import numpy as np


def pyplot():
    """``matplotlib.pyplot`` on the headless Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _mantissa(v: float) -> int:
    return int(round(v / 10 ** math.floor(math.log10(v)))) if v > 0 else 0


def plain_log_labels(axis, limits) -> None:
    """Log-axis labels as plain numbers (``0.01``, not ``10^-2``); with less than two decades in
    view, the minor ticks at 2 and 5 times a decade are labelled too (never all of them: they
    would overlap)."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    lo, hi = np.log10(limits)
    decades = int(np.floor(hi)) - int(np.ceil(lo)) + 1
    some = FuncFormatter(lambda v, _: f"{v:g}" if _mantissa(v) in (2, 5) else "")
    axis.set_minor_formatter(some if decades < 2 else NullFormatter())
