"""RANSAC over EPnP for one PnP problem whose correspondences hold outliers (pure JAX).

Minimal samples of ``sample_size`` points drawn at random, EPnP on every hypothesis in one
``vmap``-ed call, inliers by reprojection error; the number of hypotheses is Sharma et al. 2018
eq. 35, ``k = log(1 - p) / log(1 - w^s)`` (:func:`~jaxpose.core.pnp.ransac_iterations`), fixed
before compilation from the largest outlier fraction to be handled.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxpose.core._compile import eager_jit
from jaxpose.core.camera import PinholeCamera, as_camera
from jaxpose.core.pnp._epnp import _epnp_core
from jaxpose.core.pnp._linalg import _mm, _rms_px
from jaxpose.core.pnp._options import RansacOptions
from jaxpose.core.pnp._problem import (
    PLANAR_TOL,
    _conclude,
    _Problem,
    _problem,
    check_planar_tol,
)
from jaxpose.core.pnp._result import PnPResult
from jaxpose.core.status import Status, check_throw, throw_for_status


def check_key(key) -> None:
    """``ValueError`` naming ``key`` unless it is a JAX PRNG key (typed, or the raw ``uint32``
    pair of ``jax.random.PRNGKey``; batched under ``vmap``): JAX's own error for ``None`` or an
    integer names no argument."""
    ok = isinstance(key, jax.Array) and (
        jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key)
        or (key.dtype == jnp.uint32 and key.shape[-1:] == (2,))
    )
    if not ok:
        raise ValueError(
            "key must be a JAX PRNG key (jax.random.key(seed) or jax.random.PRNGKey(seed)); "
            f"got {type(key).__name__}"
        )


def _ransac_core(prob: _Problem, key, *, threshold_px, sample_size, num_hypotheses, planar_tol):
    pw, xy, valid, fxy = prob.points_body, prob.xy, prob.valid, prob.fxy
    n = pw.shape[0]
    if n < sample_size:
        raise ValueError(
            f"ransac_pnp needs at least sample_size={sample_size} points; points_body has n={n}"
        )
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
    points_body: Float[ArrayLike, "n 3"],
    pixels: Float[ArrayLike, "n 2"],
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    key: Array,
    mask: Bool[ArrayLike, " n"] | None = None,
    options: RansacOptions = RansacOptions(),
    planar_tol: float = PLANAR_TOL,
    throw: bool = True,
) -> PnPResult:
    """RANSAC over EPnP for one problem whose correspondences hold outliers.

    ``options.hypotheses`` minimal samples (Sharma et al. 2018 eq. 35 unless given) are drawn
    among the valid points, EPnP solves all of them in one ``vmap``-ed call, and each hypothesis
    is scored by its inliers (reprojection error below ``options.threshold_px``, in front of the
    camera), ties broken by the truncated squared error (MSAC). EPnP on the inliers of the best
    hypothesis gives the pose, kept if it has at least as many inliers.

    Args:
        points_body: ``(n, 3)`` points in the target body frame, metres
            (``n >= options.sample_size``).
        pixels: ``(n, 2)`` measured (distorted) pixels.
        camera: :class:`~jaxpose.core.camera.PinholeCamera` or a ``3 x 3`` ``K``.
        key: JAX PRNG key of the samples.
        mask: ``(n,)`` bool, the valid points of a padded set (default: all).
        options: :class:`RansacOptions`.
        planar_tol: planarity threshold of EPnP.
        throw: raise for a status other than ``OK`` (``ValueError`` eagerly, an Equinox runtime
            error under ``jit``); pass ``False`` under ``vmap`` and read ``status``.

    Returns:
        :class:`PnPResult`; ``inliers`` marks the inliers and ``reprojection_error`` is their RMS;
        ``NO_SOLUTION`` when fewer than ``options.sample_size`` inliers remain.
    """
    if not isinstance(options, RansacOptions):
        raise ValueError(f"options must be a RansacOptions; got {type(options).__name__}")
    check_key(key)
    tol = check_planar_tol(planar_tol)
    res = _ransac_eager(points_body, pixels, as_camera(camera), key, mask, options, tol)
    if check_throw(throw):
        res = throw_for_status(
            res, "ransac_pnp", "reprojection_error", min_points=options.sample_size
        )
    return res


def _ransac_body(points_body, pixels, camera, key, mask, options, planar_tol) -> PnPResult:
    """The compiled body of :func:`ransac_pnp` (shape checks at trace time)."""
    prob = _problem(points_body, pixels, camera, mask, "ransac_pnp")
    out, inliers = _ransac_core(prob, key, planar_tol=float(planar_tol), **options._core())
    return _conclude(prob, out, options.sample_size, inliers)


_ransac_eager = eager_jit(_ransac_body, static_argnums=(5, 6))
