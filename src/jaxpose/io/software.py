"""The software a result was computed with, written beside it.

The stereo tracker's figures move with the numerical stack: its matches are decisions taken on
floating-point scores, so a different XLA or OpenCV release changes a few of them and, through
the map, every later pose (on the suite, by about as much as another noise seed: a scene's
RMS by up to a half). A figure is reproducible only with the versions it was measured on, so
the commands' summaries and the benches' JSON lines carry them.
"""

from __future__ import annotations

import platform
from importlib import metadata

__all__ = ["software_versions"]

# distribution names, as pip knows them, of what the results depend on
_DISTRIBUTIONS = {
    "jaxpose": "jaxpose",
    "jax": "jax",
    "jaxlib": "jaxlib",
    "numpy": "numpy",
    "scipy": "scipy",
    "opencv": "opencv-contrib-python-headless",
    "equinox": "equinox",
    "optimistix": "optimistix",
}


def software_versions() -> dict[str, str | None]:
    """Versions of Python and of the packages jaxpose's results depend on.

    Returns:
        ``{"python": "3.11.7", "jaxpose": ..., "jax": ..., "jaxlib": ..., "numpy": ...,
        "scipy": ..., "opencv": ..., "equinox": ..., "optimistix": ...}``; a package that is
        not installed as a distribution gives ``None`` (OpenCV then falls back to the imported
        module's own ``cv2.__version__``, for a build from source).
    """
    out: dict[str, str | None] = {"python": platform.python_version()}
    for key, dist in _DISTRIBUTIONS.items():
        try:
            out[key] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[key] = None
    if out["opencv"] is None:
        try:
            import cv2

            out["opencv"] = str(cv2.__version__)
        except ImportError:  # pragma: no cover - OpenCV is a dependency
            pass
    return out
