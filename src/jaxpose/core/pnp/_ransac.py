"""RANSAC over EPnP for one PnP problem whose correspondences hold outliers (pure JAX).

Minimal samples of ``sample_size`` points drawn at random, EPnP on every hypothesis in one
``vmap``-ed call, inliers by reprojection error; the number of hypotheses is Sharma et al. 2018
eq. 35, ``k = log(1 - p) / log(1 - w^s)`` (:func:`ransac_iterations`), fixed before compilation
from the largest outlier fraction to be handled.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, Bool, Float

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.pnp._epnp import _epnp_core
from jaxpose.core.pnp._linalg import _mm, _rms_px
from jaxpose.core.pnp._problem import MIN_POINTS, PLANAR_TOL, _conclude, _Problem, _problem
from jaxpose.core.pnp._result import PnPResult
from jaxpose.core.status import Status


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


def _ransac_options(threshold_px, confidence, max_outlier_fraction, sample_size, num_hypotheses):
    """Validated static RANSAC options (``ValueError`` at trace time)."""
    if not threshold_px > 0:
        raise ValueError(f"threshold_px must be positive; got {threshold_px}")
    if not 0.0 <= max_outlier_fraction < 1.0:
        raise ValueError(f"max_outlier_fraction must be in [0, 1); got {max_outlier_fraction}")
    if sample_size < MIN_POINTS:
        raise ValueError(f"sample_size must be at least {MIN_POINTS}; got {sample_size}")
    if num_hypotheses is None:
        num_hypotheses = ransac_iterations(confidence, 1.0 - max_outlier_fraction, sample_size)
    if int(num_hypotheses) < 1:
        raise ValueError(f"num_hypotheses must be positive; got {num_hypotheses}")
    return {
        "threshold_px": float(threshold_px),
        "sample_size": int(sample_size),
        "num_hypotheses": int(num_hypotheses),
    }


def _ransac_core(prob: _Problem, key, *, threshold_px, sample_size, num_hypotheses, planar_tol):
    pw, xy, valid, fxy = prob.points_body, prob.xy, prob.valid, prob.fxy
    n = pw.shape[0]
    if n < sample_size:
        raise ValueError(f"ransac_pnp needs at least sample_size={sample_size} points; got n={n}")
    dtype = pw.dtype
    u = jax.random.uniform(key, (num_hypotheses, n), dtype=dtype)
    u = jnp.where(valid, u, 2.0)
    _, idx = lax.top_k(-u, sample_size)  # (k, s): samples without replacement among the valid
    sw = valid[idx].astype(dtype)
    hyp = jax.vmap(lambda i, w: _epnp_core(pw[i], xy[i], w, fxy, planar_tol))(idx, sw)
    thr2 = jnp.asarray(threshold_px, dtype) ** 2

    def score(R, t):
        cam = _mm(pw, R.T) + t
        z = cam[:, 2]
        front = z > 0
        d = (cam[:, :2] / jnp.where(front, z, 1.0)[:, None] - xy) * fxy
        e2 = d[:, 0] ** 2 + d[:, 1] ** 2
        inl = valid & front & (e2 < thr2)
        # MSAC's truncated cost, scaled below 1 so that it only breaks ties of the inlier count
        cost = jnp.sum(jnp.where(valid, jnp.where(inl, e2, thr2), 0.0)) / (n * thr2 + 1.0)
        return inl, jnp.sum(inl), cost

    inl, cnt, cost = jax.vmap(score)(hyp.R, hyp.t)
    ok_h = hyp.status == Status.OK
    best = jnp.argmax(jnp.where(ok_h, cnt.astype(dtype) - cost, -1.0))
    inl_best, cnt_best = inl[best], cnt[best]
    final = _epnp_core(pw, xy, inl_best.astype(dtype), fxy, planar_tol)
    inl_f, cnt_f, _ = score(final.R, final.t)
    use_final = (final.status == Status.OK) & (cnt_f >= cnt_best)
    chosen = jax.tree.map(lambda a, b: jnp.where(use_final, a, b[best]), final, hyp)
    inliers = jnp.where(use_final, inl_f, inl_best)
    rms = _rms_px(_mm(pw, chosen.R.T) + chosen.t, xy, inliers.astype(dtype), fxy)
    enough = jnp.any(ok_h) & (jnp.sum(inliers) >= sample_size)
    status = jnp.where(enough, chosen.status, Status.NO_SOLUTION).astype(jnp.int32)
    return eqx.tree_at(lambda o: (o.status, o.rms), chosen, (status, rms)), inliers


def ransac_pnp(
    points_body: Float[Array, "n 3"],
    pixels: Float[Array, "n 2"],
    camera: PinholeCamera | Float[Array, "3 3"],
    *,
    key: Array,
    mask: Bool[Array, " n"] | None = None,
    threshold_px: float = 8.0,
    confidence: float = 0.999,
    max_outlier_fraction: float = 0.5,
    sample_size: int = 6,
    num_hypotheses: int | None = None,
    planar_tol: float = PLANAR_TOL,
) -> PnPResult:
    """RANSAC over EPnP for one problem whose correspondences hold outliers.

    ``num_hypotheses`` (default: :func:`ransac_iterations` of ``confidence`` and
    ``1 - max_outlier_fraction``: 439 for 50% outliers, ``p = 0.999`` and 6-point samples)
    minimal samples are drawn among the valid points, EPnP solves all of them in one
    ``vmap``-ed call, and each hypothesis is scored by its inliers (reprojection error below
    ``threshold_px``, in front of the camera), ties broken by the truncated squared error (MSAC).
    EPnP on the inliers of the best hypothesis gives the pose, kept if it has at least as many
    inliers. ``inliers`` of the result marks them and ``reprojection_error`` is their RMS;
    ``NO_SOLUTION`` when fewer than ``sample_size`` inliers remain.
    """
    opts = _ransac_options(
        threshold_px, confidence, max_outlier_fraction, sample_size, num_hypotheses
    )
    prob = _problem(points_body, pixels, camera, mask, "ransac_pnp")
    out, inliers = _ransac_core(prob, key, planar_tol=planar_tol, **opts)
    return _conclude(prob, out, opts["sample_size"], inliers)
