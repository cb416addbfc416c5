"""Options of the PnP solvers: :class:`RansacOptions` and :class:`PnPOptions` (frozen, validated,
hashable, so that they are static under ``jit``)."""

from __future__ import annotations

import dataclasses
import math

from jaxpose.core._checks import _is_real
from jaxpose.core.pnp._batch import CHUNK
from jaxpose.core.pnp._problem import MIN_POINTS, PLANAR_TOL, check_planar_tol
from jaxpose.core.refine import RefineOptions

METHODS = ("epnp", "dlt", "ransac")
#: the most RANSAC hypotheses a problem may plan: they are drawn and solved at once, about 6 kB
#: each for ten points (0.9 outliers with 6-point samples and p = 0.999 plan 6.9 million, 42 GB).
MAX_HYPOTHESES = 100_000


def ransac_iterations(confidence: float, inlier_fraction: float, sample_size: int = 6) -> int:
    """Number of random hypotheses of Sharma et al. 2018, eq. 35: ``log(1-p) / log(1-w^s)``.

    ``confidence`` is ``p``, the probability that at least one sample is outlier-free;
    ``inlier_fraction`` is eq. 35's ``w / (m n)`` (with known correspondences, the fraction of
    correct ones); ``sample_size`` is the exponent (6 in the paper: EPnP on six points).
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1); got {confidence}")
    if not 0.0 < inlier_fraction <= 1.0:
        raise ValueError(f"inlier_fraction must be in (0, 1]; got {inlier_fraction}")
    if sample_size < 1:
        raise ValueError(f"sample_size must be positive; got {sample_size}")
    good = inlier_fraction**sample_size
    if good >= 1.0:
        return 1
    return max(1, math.ceil(math.log(1.0 - confidence) / math.log1p(-good)))


def _is_int(x) -> bool:
    """An integer value given as a Python or NumPy integer or float (not a bool, not inf)."""
    return _is_real(x) and math.isfinite(x) and int(x) == x


@dataclasses.dataclass(frozen=True)
class RansacOptions:
    """RANSAC over EPnP (:func:`~jaxpose.core.pnp.ransac_pnp`, ``PnPOptions(method="ransac")``).

    Attributes:
        threshold_px: inlier threshold on the reprojection error, pixels (OpenCV's default, 8).
        confidence: probability ``p`` that at least one sample is outlier-free.
        max_outlier_fraction: the largest outlier fraction to be handled, in ``[0, 1)``.
        sample_size: points per minimal sample (at least 4; 6 in Sharma et al. 2018).
        num_hypotheses: hypotheses drawn; ``None`` (default) fixes it by Sharma et al. eq. 35
            (:func:`ransac_iterations`) from ``confidence`` and ``1 - max_outlier_fraction``:
            439 for 50% outliers, ``p = 0.999`` and 6-point samples. At most
            :data:`MAX_HYPOTHESES` either way (``ValueError`` naming the fields otherwise).
    """

    threshold_px: float = 8.0
    confidence: float = 0.999
    max_outlier_fraction: float = 0.5
    sample_size: int = 6
    num_hypotheses: int | None = None

    def __post_init__(self):
        # a string ("10") was parsed by float() and a bool taken as 1 or 0: refused by name
        for name in ("threshold_px", "confidence", "max_outlier_fraction"):
            value = getattr(self, name)
            if not _is_real(value):
                raise ValueError(f"RansacOptions.{name} must be a number; got {value!r}")
        if not float(self.threshold_px) > 0:
            raise ValueError(
                f"RansacOptions.threshold_px must be positive; got {self.threshold_px}"
            )
        if not 0.0 < float(self.confidence) < 1.0:
            raise ValueError(f"RansacOptions.confidence must be in (0, 1); got {self.confidence}")
        if not 0.0 <= float(self.max_outlier_fraction) < 1.0:
            raise ValueError(
                "RansacOptions.max_outlier_fraction must be in [0, 1); got "
                f"{self.max_outlier_fraction}"
            )
        if not _is_int(self.sample_size) or int(self.sample_size) < MIN_POINTS:
            raise ValueError(
                f"RansacOptions.sample_size must be an integer >= {MIN_POINTS}; got "
                f"{self.sample_size!r}"
            )
        if self.num_hypotheses is not None and (
            not _is_int(self.num_hypotheses) or int(self.num_hypotheses) < 1
        ):
            raise ValueError(
                f"RansacOptions.num_hypotheses must be a positive integer or None; got "
                f"{self.num_hypotheses!r}"
            )
        object.__setattr__(self, "threshold_px", float(self.threshold_px))
        object.__setattr__(self, "sample_size", int(self.sample_size))
        if self.hypotheses > MAX_HYPOTHESES:
            raise ValueError(
                f"RansacOptions plan {self.hypotheses} hypotheses (num_hypotheses, or eq. 35 from "
                f"confidence={self.confidence}, max_outlier_fraction="
                f"{self.max_outlier_fraction}, sample_size={self.sample_size}), more than "
                f"{MAX_HYPOTHESES}, which are drawn at once; lower max_outlier_fraction or "
                "confidence, take sample_size=4, or give num_hypotheses"
            )

    @property
    def hypotheses(self) -> int:
        """The number of hypotheses drawn (given, or Sharma et al. eq. 35)."""
        if self.num_hypotheses is not None:
            return int(self.num_hypotheses)
        return ransac_iterations(self.confidence, 1.0 - self.max_outlier_fraction, self.sample_size)

    def _core(self) -> dict:
        """The static arguments of the RANSAC core."""
        return {
            "threshold_px": self.threshold_px,
            "sample_size": self.sample_size,
            "num_hypotheses": self.hypotheses,
        }


SOLVE_REFINE = RefineOptions(rtol=1e-6, atol=1e-9)
"""The refinement of :func:`~jaxpose.solve_pnp` by default: LM, stopping after an accepted step
with ``|dt| <= 1e-9 + 1e-6 |t|`` and ``|dw| <= 1e-9 + 1e-6``. Convergence is quadratic, so the pose
is then much closer than that to the optimum: the same errors as ``refine_pose``'s tighter
defaults to 1e-12 relative, with one step fewer on average."""


@dataclasses.dataclass(frozen=True)
class PnPOptions:
    """How :func:`~jaxpose.solve_pnp` solves (in the manner of PoseLib's ``RansacOptions`` and
    ``BundleOptions``).

    Attributes:
        method: ``"epnp"`` (:func:`~jaxpose.core.pnp.epnp`), ``"dlt"`` (``>= 6`` non-coplanar
            points) or ``"ransac"`` (RANSAC over EPnP, for outliers).
        refine: the refinement of every closed-form pose (:class:`RefineOptions`, default
            :data:`SOLVE_REFINE`), or ``None`` for the closed-form pose only.
        ransac: :class:`RansacOptions` (used with ``method="ransac"``).
        planar_tol: planarity threshold of EPnP on ``sqrt(l3 / l1)`` of the points' scatter.
        chunk: batches larger than this run as a loop over chunks of this size.
        workers: host threads that share a large batch on a CPU; ``None``: one per CPU core, at
            most one per :data:`~jaxpose.core.pnp.THREAD_MIN_PROBLEMS` problems, and 1 on
            accelerators or with several JAX devices (the batch is then split over the devices).
    """

    method: str = "epnp"
    refine: RefineOptions | None = SOLVE_REFINE
    ransac: RansacOptions = RansacOptions()
    planar_tol: float = PLANAR_TOL
    chunk: int = CHUNK
    workers: int | None = None

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"PnPOptions.method must be one of {METHODS}; got {self.method!r}")
        if self.refine is not None and not isinstance(self.refine, RefineOptions):
            raise ValueError(
                f"PnPOptions.refine must be a RefineOptions or None; got {self.refine!r}"
            )
        if not isinstance(self.ransac, RansacOptions):
            raise ValueError(f"PnPOptions.ransac must be a RansacOptions; got {self.ransac!r}")
        check_planar_tol(self.planar_tol, "PnPOptions.planar_tol")
        if not _is_int(self.chunk) or int(self.chunk) < 1:
            raise ValueError(f"PnPOptions.chunk must be a positive integer; got {self.chunk!r}")
        if self.workers is not None and (not _is_int(self.workers) or int(self.workers) < 1):
            raise ValueError(
                f"PnPOptions.workers must be a positive integer or None; got {self.workers!r}"
            )
        object.__setattr__(self, "planar_tol", float(self.planar_tol))
        object.__setattr__(self, "chunk", int(self.chunk))

    @property
    def min_points(self) -> int:
        """The fewest valid points the method needs (EPnP 4, DLT 6, RANSAC its sample size)."""
        return {"epnp": MIN_POINTS, "dlt": 6, "ransac": self.ransac.sample_size}[self.method]
