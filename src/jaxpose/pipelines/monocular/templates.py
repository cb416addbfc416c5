"""Gradient-orientation template search over the attitude grid in the manner of LINE-2D
(Hinterstoisser et al. 2012): every attitude of the grid, projected at its coarse placement, is a
template of quantised edge-normal orientations at its visible model edges; it slides over the
image's spread orientation maps (:func:`jaxpose.vision.image_maps.orientation_maps`) on a coarse
stride of in-plane shifts and a few scales, and keeps its best shift and scale. Only the model's
edges are read, so background texture away from them does not vote.

The similarity of one template at shift ``d`` and scale ``s`` is eq. (2) of Hinterstoisser et al.
(2012) with the spread responses of their section 2.3: the mean over the template's features
``r`` of ``max |cos(o_r - b)|`` over the orientations ``b`` of strong gradients within the spread
radius of ``c + s (p_r - c) + d`` (``c``: the projected model centre, ``p_r``: the feature's
pixel at the placement). The spread equals the shift stride, so a true edge within half a stride
of the template's still votes."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.pipelines.monocular.score import _edge_normal_bins, _project, _visible_edges

#: Shift stride of the search, as a share of ``l_ROI`` (also the diameter of the spreading disc
#: of the orientation maps it reads); the shifts cover ``+-TEMPLATE_STEPS`` strides on both axes.
TEMPLATE_STRIDE = 0.04
TEMPLATE_STEPS = 3
#: Scales of the search about the placement's projected size (a projected length is inverse to
#: the range: scale 1.15 is a range 13% shorter).
TEMPLATE_SCALES = (0.87, 1.0, 1.15)
#: Every ``TEMPLATE_SAMPLE_STEP``-th sample of each model edge is a candidate feature; a template
#: keeps at most ``TEMPLATE_FEATURES`` of those on visible edges (every edge's first sample, then
#: every edge's second, ...), LINE-2D's fixed feature count (63 there).
TEMPLATE_SAMPLE_STEP = 2
TEMPLATE_FEATURES = 64


def _template_match(R, t, geom, ori, frame, cam4, shifts, scales):
    """Best LINE-2D similarity of the model at attitude ``R (3, 3)``, placed at ``t (3,)``
    (metres, camera frame), over in-plane shifts ``shifts (D, 2)`` (cells of the orientation
    maps) and scales ``scales (S,)`` about the projected model centre.

    ``geom``: the model geometry of :func:`jaxpose.pipelines.monocular.scene._model_geometry`;
    ``ori (B, M, M)``, ``frame [u0, v0, k]``: :func:`jaxpose.vision.image_maps.orientation_maps`
    (a pixel ``p`` of the undistorted image is cell ``(p - [u0, v0]) k``); ``cam4 = [fx, fy, cx,
    cy]``. Returns ``(score in [0, 1], scale, shift (2,) in pixels)``; a feature off the maps or
    behind the camera scores 0, and a template with no visible feature scores 0."""
    _, samples, _, _, _ = geom
    B, M = ori.shape[0], ori.shape[1]
    vis = _visible_edges(R, t, geom)
    pts = samples[:, ::TEMPLATE_SAMPLE_STEP]
    pc = pts @ R.T + t  # (E, K, 3)
    pix = _project(pc, cam4)
    o = _edge_normal_bins(pix, B)  # (E,): the bin of each edge's normal
    centre = jnp.mean(samples.reshape(-1, 3), axis=0)
    cc = (_project(R @ centre + t, cam4) - frame[:2]) * frame[2]
    rel = (pix - frame[:2]) * frame[2] - cc  # (E, K, 2) cells
    E, K = pts.shape[:2]
    ok = vis[:, None] & (pc[..., 2] > 1e-3)  # (E, K)
    # the first TEMPLATE_FEATURES usable features in the order sample-major, edge-minor
    order = jnp.arange(E * K).reshape(K, E).T  # (E, K): rank of each feature in that order
    rank = jnp.where(ok, order, E * K + order).reshape(-1)
    _, pick = jax.lax.top_k(-rank, min(TEMPLATE_FEATURES, E * K))
    rel = rel.reshape(-1, 2)[pick]
    o = jnp.broadcast_to(o[:, None], (E, K)).reshape(-1)[pick]
    m = ok.reshape(-1)[pick].astype(ori.dtype)
    n = jnp.maximum(jnp.sum(m), 1.0)

    def one(scale, shift):
        q = cc + scale * rel + shift
        inside = jnp.all((q >= 0) & (q <= M - 1), axis=-1)
        ij = jnp.clip(jnp.round(q).astype(jnp.int32), 0, M - 1)
        val = jnp.where(inside, ori[o, ij[:, 1], ij[:, 0]], 0.0)
        return jnp.sum(val * m) / n

    sim = jax.vmap(lambda s: jax.vmap(lambda dd: one(s, dd))(shifts))(scales)  # (S, D)
    sim = jnp.where(jnp.sum(m) > 0, sim, 0.0)
    best = jnp.argmax(sim.reshape(-1))
    i, j = best // shifts.shape[0], best % shifts.shape[0]
    return sim.reshape(-1)[best], scales[i], shifts[j] / frame[2]


@functools.lru_cache(maxsize=4)
def _batched_template_match():
    return jax.jit(jax.vmap(_template_match, in_axes=(0, 0, None, None, None, None, None, None)))


def _moved(R, t, scale, shift_px, centre, cam4):
    """Poses ``(R, t')`` whose projected model centre is moved by ``shift_px (X, 2)`` and whose
    projected size is ``scale (X,)`` times that at ``t (X, 3)`` (the range divided by it)."""
    c = np.einsum("xij,j->xi", R, centre) + t
    fx, fy, cx, cy = (float(v) for v in cam4)
    u = fx * c[:, 0] / c[:, 2] + cx + shift_px[:, 0]
    v = fy * c[:, 1] / c[:, 2] + cy + shift_px[:, 1]
    z = c[:, 2] / scale
    c_new = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], axis=1)
    return c_new - np.einsum("xij,j->xi", R, centre)


def template_shifts(l_roi_cells: float) -> np.ndarray:
    """The search's shifts ``((2 TEMPLATE_STEPS + 1)^2, 2)`` in cells of the orientation maps,
    for an ROI whose diagonal spans ``l_roi_cells`` cells."""
    step = TEMPLATE_STRIDE * l_roi_cells
    a = step * np.arange(-TEMPLATE_STEPS, TEMPLATE_STEPS + 1)
    U, V = np.meshgrid(a, a, indexing="xy")
    return np.stack([U.ravel(), V.ravel()], axis=1)


def _template_poses(R, t, sc, det, n: int, chunk: int = 512):
    """The ``n`` best poses of the template search, ``(R (n, 3, 3), t (n, 3), score (n,))``,
    best first: every attitude ``R (X, 3, 3)`` placed at ``t (X, 3)`` (metres) searched over
    shifts and scales (:func:`_template_match`, batches of ``chunk``) on orientation maps spread
    by the stride, then moved to its best shift and scale (:func:`_moved`). ``sc``: the image's
    :class:`~jaxpose.pipelines.monocular.scene._EdgeScene`; ``det``: its detection."""
    from jaxpose.vision.image_maps import orientation_maps
    from jaxpose.vision.roi import roi_diagonal

    ori, frame = orientation_maps(det.image, det.roi, spread=TEMPLATE_STRIDE)
    shifts = jnp.asarray(template_shifts(roi_diagonal(det.roi) * frame[2]))
    scales = jnp.asarray(TEMPLATE_SCALES, dtype=jnp.asarray(t).dtype)
    ori, frame = jnp.asarray(ori), jnp.asarray(frame)
    f = _batched_template_match()
    X = len(R)
    sims, ks, ds = [], [], []
    for a in range(0, X, chunk):
        b = min(a + chunk, X)
        idx = np.minimum(np.arange(a, a + chunk), b - 1)  # fixed compiled shape
        s, k, d = f(
            jnp.asarray(R[idx]), jnp.asarray(t[idx]), sc.geom, ori, frame, sc.cam4, shifts, scales
        )
        sims.append(np.asarray(s)[: b - a])
        ks.append(np.asarray(k)[: b - a])
        ds.append(np.asarray(d)[: b - a])
    sim, k, d = np.concatenate(sims), np.concatenate(ks), np.concatenate(ds)
    best = np.argsort(-sim, kind="stable")[:n]
    centre = np.asarray(sc.geom[1]).reshape(-1, 3).mean(0)
    t_new = _moved(R[best], np.asarray(t)[best], k[best], d[best], centre, np.asarray(sc.cam4))
    return np.asarray(R)[best], t_new, sim[best]
