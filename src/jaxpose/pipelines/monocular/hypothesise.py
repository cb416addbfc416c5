"""Pose hypotheses: image feature groups paired with model groups (Sharma, Ventura, D'Amico 2018,
Table 1) and solved by batched EPnP, the attitude grid placed on the silhouette, the RANSAC
baseline of the paper's Test 4, and the shortlist that the scores keep."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.core._threads import in_core_threads
from jaxpose.core.geometry import Pose
from jaxpose.pipelines.monocular.fit import _batched_fit
from jaxpose.pipelines.monocular.options import InitOptions
from jaxpose.pipelines.monocular.scene import _EdgeScene
from jaxpose.pipelines.monocular.score import (
    _batched_quick,
    _batched_rank,
    _face_cover,
    _project,
    _silhouette_cells,
)
from jaxpose.vision.features import Detection
from jaxpose.vision.models import WireframeModel
from jaxpose.vision.synthesis import KINDS, PERMUTATIONS

_PAD_POINTS = 6
_CHUNK = 512  # hypotheses per compiled call (one compilation serves every image)
_SHORTLIST = 128  # hypotheses fitted and scored by the full symmetric chamfer distance


def _allocate(needs, budget) -> np.ndarray:
    """Water-filling share of ``budget`` among ``needs``: each gets at most its need, and what the
    small needs leave is split evenly among the larger ones."""
    needs = np.asarray(needs, dtype=np.int64)
    out = np.zeros(len(needs), dtype=np.int64)
    left = int(budget)
    order = np.argsort(needs, kind="stable")
    for r, i in enumerate(order):
        out[i] = min(int(needs[i]), left // (len(order) - r))
        left -= int(out[i])
    return out


def _hypotheses(det: Detection, model: WireframeModel, opts: InitOptions):
    """Match matrix: ``points_body (H, 6, 3)``, ``pixels (H, 6, 2)``, ``mask (H, 6)`` and the
    kind and image-group index of every row.

    Every group kind with at least four points that both the image and the model have takes part
    (the Table 1 order); ``max_hypotheses`` is shared among them by water-filling, so a kind with
    few hypotheses (closed tetrads) is tried in full and the rest is split evenly. Within a kind
    the image groups are taken longest first (the order of :func:`synthesize`)."""
    mg = model.groups
    kinds_ok, needs, per = [], [], []
    for kind in KINDS:
        ni, nm = det.groups.count(kind), mg.count(kind)
        if ni == 0 or nm == 0 or mg.points[kind].shape[1] < 4:
            continue  # a proximal pair alone gives 3 points; EPnP needs 4
        kinds_ok.append(kind)
        per.append(nm * len(PERMUTATIONS[kind]))
        needs.append(ni * per[-1])
    if not kinds_ok:
        return None
    share = _allocate(needs, opts.max_hypotheses)
    rows_p, rows_q, rows_m, info, kinds = [], [], [], [], []
    for kind, per_image, budget in zip(kinds_ok, per, share, strict=True):
        # at least one image group whenever the share covers half of one
        ni = min(
            det.groups.count(kind), max(int(budget // per_image), int(2 * budget >= per_image))
        )
        if ni == 0:
            continue
        k = mg.points[kind].shape[1]
        perms = PERMUTATIONS[kind]
        img = det.groups.points[kind]  # (ni, k, 2)
        mod = mg.points[kind][:, perms]  # (nm, P, k, 3)
        nm = len(mod)
        q = np.broadcast_to(img[:ni, None, None], (ni, nm, len(perms), k, 2)).reshape(-1, k, 2)
        p = np.broadcast_to(mod[None], (ni, nm, len(perms), k, 3)).reshape(-1, k, 3)
        pad = _PAD_POINTS - k
        rows_p.append(np.concatenate([p, np.repeat(p[:, :1], pad, 1)], 1) if pad else p)
        rows_q.append(np.concatenate([q, np.repeat(q[:, :1], pad, 1)], 1) if pad else q)
        m = np.zeros((len(p), _PAD_POINTS), bool)
        m[:, :k] = True
        rows_m.append(m)
        info.append(
            np.stack(
                [np.full(len(p), KINDS.index(kind)), np.repeat(np.arange(ni), nm * len(perms))], 1
            )
        )
        kinds.append(kind)
    if not rows_p:
        return None
    return (
        np.concatenate(rows_p),
        np.concatenate(rows_q),
        np.concatenate(rows_m),
        np.concatenate(info),
        kinds,
    )


def _svd_candidates(det, model, opts, cam, sc: _EdgeScene, trace=None):
    hyp = _hypotheses(det, model, opts)
    if hyp is None:
        return None
    P, Q, M, info, kinds = hyp
    n = len(P)
    fitted = opts.shortlist_fit and opts.rank_by == "chamfer"
    grid = _grid_poses(det, model, opts, sc) if fitted else None
    tpl = _template_grid(det, opts, sc) if fitted else None
    R_all, t_all, ok, key = _solve_and_score(
        P,
        Q,
        M,
        cam,
        sc,
        opts.rank_by,
        det.roi,
        fit=fitted,
        extra=grid,
        reserved=tpl,
        trace=trace,
    )
    if not ok.any():
        return None
    order = np.argsort(key, kind="stable")
    order = order[np.isfinite(key[order])]
    # Fitted hypotheses of one pose converge to the same pose: keep distinct ones only.
    order = _distinct(R_all, t_all, order, opts.top_k) if fitted else order[: opts.top_k]
    pad = np.concatenate([order, np.repeat(order[:1], opts.top_k - len(order))])
    pose0 = Pose(jnp.asarray(R_all[pad]), jnp.asarray(t_all[pad]))
    if not fitted:  # Newton-Raphson on each hypothesis's own correspondences (eqs. 23-29)
        ref = _batched_refine()(
            pose0, jnp.asarray(P[pad]), jnp.asarray(Q[pad]), jnp.asarray(M[pad]), cam
        )
    poses = []
    from jaxpose.core.pnp import planar_flip

    for j in range(len(order)):
        if fitted:  # already fitted to the edges; its own 4-6 points would pull it back
            p = Pose(pose0.R[j], pose0.t[j])
        elif int(ref.status[j]) in (0, 5):
            p = Pose(ref.pose.R[j], ref.pose.t[j])
        else:
            p = Pose(pose0.R[j], pose0.t[j])
        poses.append(p)
        if order[j] >= n:  # an attitude of the grid: no correspondences
            continue
        # The planar mirror of a planar group (tetrads of a face): same image at long range.
        pts = P[order[j]][M[order[j]]]
        c = pts.mean(0)
        _, sv, vt = np.linalg.svd(pts - c)
        if sv[-1] < 1e-6 * max(sv[0], 1e-12):
            poses.append(planar_flip(p, jnp.asarray(c), jnp.asarray(vt[-1])))
    tried = n + (0 if grid is None else len(grid[0]))  # hypotheses and grid attitudes
    if order[0] >= n:
        n_grid = 0 if grid is None else len(grid[0])
        kind = "attitude-template" if order[0] >= n + n_grid else "attitude-grid"
        return poses, tried, np.zeros(0, int), kind
    kind = KINDS[int(info[order[0], 0])]
    seg_idx = det.groups.segments[kind][int(info[order[0], 1])]
    return poses, tried, np.asarray(seg_idx), kind


def _ransac_candidates(det, model, opts, cam, sc: _EdgeScene, trace=None):
    """Test 4 baseline: 3 image segments and 3 model edges at random (random endpoint order),
    EPnP of the 6 endpoint pairs, score by the chamfer distance; the best ``top_k`` go on."""
    segs = det.segments
    m_segs = model.edge_points
    n, m = len(segs), len(m_segs)
    if n < 3:
        return None
    # k = log(1 - p) / log(1 - (w / (m n))^6) is astronomically large for p = 0.99 with the
    # edge counts here; the budget is capped (the paper's point: RANSAC is slow).
    k = opts.ransac_iterations or 4096
    rng = np.random.default_rng(opts.ransac_seed)
    ii = np.argsort(rng.random((k, n)), axis=1)[:, :3]
    jj = np.argsort(rng.random((k, m)), axis=1)[:, :3]
    flip = rng.random((k, 3)) < 0.5
    q = segs[ii]  # (k, 3, 2, 2)
    q = np.where(flip[..., None, None], q[:, :, ::-1], q)
    p = m_segs[jj]
    P = p.reshape(k, 6, 3)
    Q = q.reshape(k, 6, 2)
    M = np.ones((k, 6), bool)
    R_all, t_all, ok, key = _solve_and_score(P, Q, M, cam, sc, "chamfer", det.roi, trace=trace)
    order = np.argsort(key, kind="stable")[: opts.top_k]
    order = order[np.isfinite(key[order])]
    if not len(order):
        return None
    poses = [Pose(jnp.asarray(R_all[j]), jnp.asarray(t_all[j])) for j in order]
    return poses, k, np.asarray(ii[order[0]]), "ransac"


def _solve_and_score(
    P, Q, M, cam, sc: _EdgeScene, rank_by, roi, fit=False, extra=None, reserved=None, trace=None
):
    """EPnP of every hypothesis (``jax.vmap(epnp)``, fixed-size chunks) and its ranking key.

    ``chamfer``: a quick model-side score ranks all hypotheses, the best ``_SHORTLIST`` get the
    symmetric chamfer distance (after :func:`_chamfer_fit` when ``fit``: their poses are then
    replaced by the fitted ones); ``e2d``: EPnP's own reprojection error (eq. 22). ``extra``:
    ``(R (X, 3, 3), t (X, 3))`` more poses (no correspondences) ranked with the hypotheses
    (``chamfer`` only); they come after the ``len(P)`` hypotheses in the outputs. ``reserved``:
    ``(R (Y, 3, 3), t (Y, 3))`` poses that take ``Y`` of the shortlist's places whatever their
    quick score (the template search's, :mod:`~jaxpose.pipelines.monocular.templates`); they
    come last in the outputs."""
    n = len(P)

    def solve(a):
        b = min(a + _CHUNK, n)
        Pp, Qp, Mp = _pad_batch([P[a:b], Q[a:b], M[a:b]], _CHUNK)
        res = _batched_epnp()(jnp.asarray(Pp), jnp.asarray(Qp), jnp.asarray(Mp), cam)
        if rank_by == "e2d":
            k = res.reprojection_error
        else:
            k = _batched_quick()(res.pose.R, res.pose.t, sc, jnp.asarray(roi))
        R, t, status = (np.asarray(x)[: b - a] for x in (res.pose.R, res.pose.t, res.status))
        return R, t, status == 0, np.asarray(k)[: b - a]

    def quick(a):
        Re, te = (np.asarray(x[a : a + _CHUNK]) for x in extra)
        Rp, tp = _pad_batch([Re, te], _CHUNK)
        k = _batched_quick()(jnp.asarray(Rp), jnp.asarray(tp), sc, jnp.asarray(roi))
        return Re, te, np.ones(len(Re), bool), np.asarray(k)[: len(Re)]

    chunks = in_core_threads(solve, list(range(0, n, _CHUNK)))
    if extra is not None and rank_by == "chamfer":
        chunks += in_core_threads(quick, list(range(0, len(extra[0]), _CHUNK)))
    Rs, ts, ok, key = (list(x) for x in zip(*chunks, strict=True)) if chunks else ([],) * 4
    n_res = 0
    if reserved is not None and rank_by == "chamfer":
        n_res = min(len(reserved[0]), _SHORTLIST)
        Rs.append(np.asarray(reserved[0][:n_res]))
        ts.append(np.asarray(reserved[1][:n_res]))
        ok.append(np.ones(n_res, bool))
        key.append(np.full(n_res, np.inf))
    R_all, t_all, ok = np.concatenate(Rs), np.concatenate(ts), np.concatenate(ok)
    if trace is not None:  # every hypothesis and grid pose before the shortlist's fit
        trace["hypotheses"] = (R_all.copy(), t_all.copy(), ok.copy())
    key = np.where(ok, np.concatenate(key), np.inf)
    key = np.where(np.isfinite(key), key, np.inf)
    if rank_by == "chamfer":
        short = np.argsort(key, kind="stable")[: _SHORTLIST - n_res]
        short = short[np.isfinite(key[short])]
        short = np.concatenate([short, np.arange(len(key) - n_res, len(key))])
        if len(short):
            pad = np.concatenate([short, np.repeat(short[:1], _SHORTLIST - len(short))])
            Rs_, ts_ = jnp.asarray(R_all[pad]), jnp.asarray(t_all[pad])
            if fit:
                Rs_, ts_ = _batched_fit()(Rs_, ts_, sc)
                R_all[short] = np.asarray(Rs_)[: len(short)]
                t_all[short] = np.asarray(ts_)[: len(short)]
            full, _, _ = _batched_rank()(Rs_, ts_, sc)
            new = np.full(len(key), np.inf)  # hypotheses and extra poses
            new[short] = np.asarray(full)[: len(short)]
            if trace is not None:  # the shortlist after its fit
                trace["shortlist"] = (R_all[short].copy(), t_all[short].copy())
            key = new
    return R_all, t_all, ok, key


def _pad_batch(arrays, n):
    out = []
    for a in arrays:
        pad = np.zeros((n - len(a),) + a.shape[1:], dtype=a.dtype)
        if a.dtype == bool:
            pad[:] = False
        elif a.ndim >= 2 and a.dtype.kind == "f":
            pad[:] = a[:1] if len(a) else 0
        out.append(np.concatenate([a, pad]))
    return out


@functools.lru_cache(maxsize=4)
def _batched_epnp():
    from jaxpose.core.pnp import epnp

    return jax.jit(
        jax.vmap(lambda p, q, m, cam: epnp(p, q, cam, mask=m, throw=False), in_axes=(0, 0, 0, None))
    )


@functools.lru_cache(maxsize=4)
def _batched_refine():
    from jaxpose.core.refine import RefineOptions, refine_pose

    options = RefineOptions(method="newton-raphson", max_steps=30)

    def one(pose, pts, pix, mask, cam):
        return refine_pose(pts, pix, pose, cam, mask=mask, options=options, throw=False)

    return jax.jit(jax.vmap(one, in_axes=(0, 0, 0, 0, None)))


def _grid_poses(det, model: WireframeModel, opts: InitOptions, sc: _EdgeScene):
    """``opts.attitude_grid`` attitudes (:func:`jaxpose.core.geometry.super_fibonacci_rotations`),
    each placed on the silhouette (:func:`_place_on_silhouette`, from the model's centre at the
    coarse position), ``(R (X, 3, 3), t (X, 3))``; ``None``
    when the grid is off or the image has no silhouette term (the edges alone cannot rank an
    attitude that no feature group proposed: with ``opts.grid_without_silhouette`` the grid is
    placed on the ROI instead, measured in the docs' monocular evaluation)."""
    if opts.attitude_grid <= 0 or det.coarse_t_cam is None:
        return None
    on_roi = sc.sil_pts is None
    if on_roi and not opts.grid_without_silhouette:
        return None
    return _placed_attitudes(det, opts, sc, on_roi)


def _placed_attitudes(det, opts: InitOptions, sc: _EdgeScene, on_roi: bool):
    """The ``opts.attitude_grid`` grid attitudes ``R (X, 3, 3)`` and their translations
    ``t (X, 3)`` (metres): the model's centre (the face polygons' with a silhouette, the edges'
    on the ROI) at the coarse position, then placed on the silhouette
    (:func:`_place_on_silhouette`) or on the ROI (:func:`_place_on_roi`), in fixed-size chunks."""
    R = _attitudes(int(opts.attitude_grid))
    if on_roi:
        centre = np.asarray(sc.geom[1]).reshape(-1, 3).mean(0)
    else:
        centre = np.asarray(sc.face_poly).reshape(-1, 3).mean(0)
    t = np.asarray(det.coarse_t_cam, dtype=float)[None] - R @ centre

    def place(a):
        Rp, tp = _pad_batch([R[a : a + _CHUNK], t[a : a + _CHUNK]], _CHUNK)
        if on_roi:
            tp = _batched_place_roi()(jnp.asarray(Rp), jnp.asarray(tp), sc, jnp.asarray(det.roi))
        else:
            tp = _batched_place()(jnp.asarray(Rp), jnp.asarray(tp), sc)
        return np.asarray(tp)[: len(R[a : a + _CHUNK])]

    return R, np.concatenate(in_core_threads(place, list(range(0, len(R), _CHUNK))))


def _template_grid(det, opts: InitOptions, sc: _EdgeScene):
    """The ``opts.template_slots`` best poses of the LINE-2D template search
    (:func:`jaxpose.pipelines.monocular.templates._template_poses`) over the ``opts.attitude_grid``
    attitudes, each placed on the ROI first (:func:`_place_on_roi`, from the model's centre at
    the coarse position): ``(R (n, 3, 3), t (n, 3))``, or ``None`` when off. It needs no
    silhouette: only the image's gradient orientations at the model's edges vote."""
    from jaxpose.pipelines.monocular.templates import _template_poses

    n = int(opts.template_slots)
    if n <= 0 or opts.attitude_grid <= 0 or det.coarse_t_cam is None:
        return None
    R, t = _placed_attitudes(det, opts, sc, on_roi=True)
    Rt, tt, _ = _template_poses(R, t, sc, det, n)
    return Rt, tt


@functools.lru_cache(maxsize=4)
def _attitudes(n: int) -> np.ndarray:
    from jaxpose.core.geometry import super_fibonacci_rotations

    return super_fibonacci_rotations(n).astype(np.float64)


def _place_on_silhouette(R, t, sc: _EdgeScene):
    """Translation that puts the model's projected silhouette at attitude ``R`` on the image's
    silhouette: the range scaled by ``sqrt(model area / silhouette area)`` (a projected area
    falls as the inverse square of the range) and the position moved so that the silhouettes'
    centroids coincide (the centroid's offset from the projected model centre scaled by the
    range ratio). Areas and centroids are counted on the pooled cells of
    :func:`jaxpose.vision.image_maps.silhouette_grid` (:func:`_silhouette_cells`).
    Returns ``t`` unchanged when the model covers no cell."""
    centre = jnp.mean(sc.face_poly.reshape(-1, 3), axis=0)
    pts, val = _silhouette_cells(sc, coarse=True)
    inside, _ = _face_cover(R, t, pts, sc.face_poly, sc.geom, sc.cam4)
    cover = jnp.any(inside, axis=0).astype(val.dtype)
    a_model, a_img = jnp.sum(cover), jnp.sum(val)
    g_model = cover @ pts / jnp.maximum(a_model, 1.0)
    g_img = val @ pts / jnp.maximum(a_img, 1e-9)
    c = R @ centre + t
    k = jnp.sqrt(a_model / jnp.maximum(a_img, 1e-9))
    z = c[2] * k
    # the new centre's pixel is g_img minus the centroid offset at the new range
    uv = g_img - (g_model - _project(c, sc.cam4)) / k
    c_new = jnp.stack(
        [(uv[0] - sc.cam4[2]) / sc.cam4[0] * z, (uv[1] - sc.cam4[3]) / sc.cam4[1] * z, z]
    )
    ok = (a_model > 0) & (a_img > 0) & (c[2] > 1e-3)
    return jnp.where(ok, c_new - R @ centre, t)


@functools.lru_cache(maxsize=4)
def _batched_place():
    return jax.jit(jax.vmap(_place_on_silhouette, in_axes=(0, 0, None)))


def _place_on_roi(R, t, sc: _EdgeScene, roi):
    """Translation that puts the box of the model's projected edge samples at attitude ``R`` on
    the ROI ``[u0, v0, u1, v1]``: the range scaled by the box's diagonal over the ROI's (a
    projected length falls as the inverse of the range) and the position moved so that the box
    centre lands on the ROI centre (the box centre's offset from the projected model centre
    scaled by the range ratio). Returns ``t`` unchanged when the model is behind the camera."""
    samples = sc.geom[1].reshape(-1, 3)
    centre = jnp.mean(samples, axis=0)
    pc = samples @ R.T + t
    pix = _project(pc, sc.cam4)
    lo, hi = jnp.min(pix, axis=0), jnp.max(pix, axis=0)
    diag = jnp.linalg.norm(hi - lo)
    roi_diag = jnp.linalg.norm(roi[2:] - roi[:2])
    c = R @ centre + t
    k = diag / jnp.maximum(roi_diag, 1e-9)
    z = c[2] * k
    uv = 0.5 * (roi[:2] + roi[2:]) - (0.5 * (lo + hi) - _project(c, sc.cam4)) / k
    c_new = jnp.stack(
        [(uv[0] - sc.cam4[2]) / sc.cam4[0] * z, (uv[1] - sc.cam4[3]) / sc.cam4[1] * z, z]
    )
    ok = jnp.all(pc[:, 2] > 1e-3) & (diag > 0) & (roi_diag > 0)
    return jnp.where(ok, c_new - R @ centre, t)


@functools.lru_cache(maxsize=4)
def _batched_place_roi():
    return jax.jit(jax.vmap(_place_on_roi, in_axes=(0, 0, None, None)))


def _distinct(R, t, order, k, angle_deg=5.0, rel_dist=0.05):
    """The first ``k`` of ``order`` that differ from every earlier pick by more than
    ``angle_deg`` in attitude or ``rel_dist`` of the range in position."""
    cos_max = np.cos(np.deg2rad(angle_deg))
    picked = []
    for j in order:
        dup = False
        for i in picked:
            c = (np.trace(R[j] @ R[i].T) - 1.0) / 2.0
            if c > cos_max and np.linalg.norm(t[j] - t[i]) < rel_dist * np.linalg.norm(t[i]):
                dup = True
                break
        if not dup:
            picked.append(j)
            if len(picked) == k:
                break
    return np.asarray(picked, dtype=np.int64)
