"""Feature budget of the stereo tracker: the ``N`` matched features that go into the pose solve.

Ning, Zhang, Wang (2018) select feature points because an onboard computer cannot afford the
pose solve on all of them; the selection should keep the geometry that fixes the pose best. Here
the budget applies to the matched landmarks of a frame, points and lines together
(``TrackerOptions(feature_budget=N, budget_rule=...)``), after search by projection and before
the pose solve (:func:`jaxpose.pipelines.stereo.frame_pose.fit_pose`):

* ``"dop"``: the ``N`` features whose summed information gives the lowest dilution of precision at
  the predicted pose. A feature's information is the ``6 x 6`` block of its left-image observation
  plus, when it has a stereo match, of its right-image one (the landmark shifted by ``R^T t_rl``,
  as the pose solve sees it): ``J^T J / sigma^2`` with ``J`` the ``2 x 6`` Jacobian of a point's
  pixels (Ning et al. eq. 7, :func:`jaxpose.core.dilution.point_jacobians`) or of a segment's two
  endpoint-to-line distances (Yang et al. 2024 eq. 9,
  :func:`jaxpose.core.line_dop.line_jacobians`), in the tangent attitude state, so point and line
  blocks add (:func:`jaxpose.core.dilution.information_blocks`,
  :func:`jaxpose.core.line_dop.line_information_blocks`), a point's rows whitened by its effective
  noise (``budget_noise``): ``"measured"``, the running RMS of its landmark's post-fit residual
  (:class:`ResidualSpread`), as its pixel noise; ``"landmark"``, the pixel noise plus its
  landmark's position covariance (:func:`landmark_covariance`) projected into both images
  (:func:`effective_whitening`); ``"both"``; ``"pixel"``: ``sigma_px``. The criterion is ``trace(W
  Q)`` with ``Q`` the inverse of the summed information (:func:`criterion_weight`): the variance of
  the chaser's position in the target frame (the target's translation and, through the range, its
  attitude: what a rendezvous needs and the tracker's error metric) plus ``l^2`` times the attitude
  variance, ``l`` the RMS distance of the matched landmarks from their centroid (the displacement
  an attitude error gives a landmark). Without the range term it is ``PDOP^2 + (l ADOP)^2`` (Ning
  et al.'s PDOP and ADOP). With ``budget_weight="relative"`` the weight is
  :func:`relative_weight` instead: the criterion is the sum over the six axes of the error metric
  of each axis's variance over its variance with every candidate. The subset is chosen by forward
  greedy selection (each step adds the
  feature that lowers the criterion most, scored for every candidate at once by rank-one
  Sherman-Morrison updates of ``Q``, from a small prior ``1e-6`` times the mean block so that the
  first picks are defined) in one compiled call per frame at padded sizes, on a random share
  ``budget_subsample`` of the candidates drawn afresh each frame (the "stochastic greedy" of
  Mirzasoleiman et al. 2015: the picks vary from frame to frame, so that one set of landmarks'
  errors is not carried frame after frame); when ``C(n, N)`` is at most :data:`EXACT_SUBSETS`,
  every subset is scored and the optimum kept. The greedy keeps its picks ``SPACING sqrt(area /
  N)`` pixels apart while it can (``area`` the box the candidates span): ORB finds one corner at
  several scales, and such near-twins share their landmark's error, which the DOP counts as
  independent. For the same reason across frames, with the budget over the window a landmark
  the rule chose in ``k`` of its last ``window_frames - 1`` selections counts with its
  information divided by ``(1 + k) ** budget_repeat_discount``
  (:mod:`jaxpose.pipelines.stereo.repeats`).
* ``"random"``: ``N`` of the matched features at random (seeded by the frame number).
* ``"response"``: the strongest detector responses: ORB (Harris) response of the points, pixel
  length of the segments, the two kinds in proportion to their matched counts.

For every rule the candidates are the landmarks old enough for the solve (``mature_obs``), the
point matches that follow the frame's motion (an affine map of the predicted onto the observed
pixels) and, while at least ``2 N`` remain, the landmarks that were inliers on the frame before.
The pose is solved on the kept features only; the post-fit checks and the map update use every
matched feature at the fitted pose (a projection, cheap next to the solve), so that a frame is
judged and the map maintained as without a budget. The windowed adjustment takes in the
budget's features only and runs every frame (``budget_window``, the default), or, without it,
every matched point within ``reject_px`` of the budgeted pose and every inlier line. The core's
backward elimination (:func:`jaxpose.core.select.greedy`) scores ``n`` removals on each of
``n - N`` steps, ``O(n^3)`` for the hundreds of matched features of a frame, and its branch and
bound and exhaustive search minimise the PDOP or the ADOP alone: hence the forward greedy here.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import weakref
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.dilution import point_jacobians
from jaxpose.core.geometry import Pose
from jaxpose.core.line_dop import line_jacobians
from jaxpose.pipelines.stereo._arrays import find, pixel_jacobian, project
from jaxpose.pipelines.stereo.frame_pose import (
    PoseFit,
    fit_pose,
    postfit_errors,
    postfit_summary,
)
from jaxpose.pipelines.stereo.landmarks import rays_meet
from jaxpose.pipelines.stereo.options import TrackerOptions
from jaxpose.pipelines.stereo.repeats import selection_history

__all__ = [
    "EXACT_SUBSETS",
    "ResidualSpread",
    "budget_criterion",
    "criterion_weight",
    "effective_whitening",
    "feature_rows",
    "fit_pose_budgeted",
    "landmark_covariance",
    "point_sigma_eff",
    "relative_weight",
    "residual_spread",
    "select_budget",
    "select_dop",
]

#: the ``"dop"`` rule scores every subset when there are at most this many (else forward greedy)
EXACT_SUBSETS = 3000
_PRIOR = 1e-6
#: the ``"dop"`` rule's picks are kept ``SPACING sqrt(area / N)`` pixels apart while it can
SPACING = 0.5


def _bucket(n: int, least: int) -> int:
    """Padded size: a power of two, at least ``least`` (a handful of compiled shapes)."""
    return max(least, 1 << max(0, n - 1).bit_length())


@jax.jit
def feature_rows(points_body, points_right, segments_body, segments_right, pose, camera, w_p, w_l):
    """Weighted Jacobian rows ``(n_p + n_l, 4, 6)`` of every feature: left-image rows, then
    right-image rows (zero without a stereo match), each divided by its pixel noise.

    Args:
        points_body: ``(n_p, 3)`` matched point landmarks, body frame, metres.
        points_right: ``(n_p, 3)`` the same shifted by ``R^T t_rl`` (the right image seen through
            the left camera and the same pose).
        segments_body, segments_right: ``(n_l, 2, 3)`` matched segment landmarks, likewise.
        pose: predicted pose; camera: the (rectified) left camera.
        w_p, w_l: ``(n_p, 2)`` and ``(n_l, 2)``: ``1 / sigma`` of the left and right observation
            of each feature (0 where there is none).
    The block of a feature is ``rows^T rows`` (:func:`jaxpose.core.dilution.information_blocks`
    and :func:`jaxpose.core.line_dop.line_information_blocks` of its observations, summed), in
    the tangent attitude state.
    """
    kw = dict(parameterization="tangent")
    Jp = point_jacobians(points_body, pose, camera, **kw) * w_p[:, 0, None, None]
    Jpr = point_jacobians(points_right, pose, camera, **kw) * w_p[:, 1, None, None]
    Jl = line_jacobians(segments_body, pose, camera, **kw) * w_l[:, 0, None, None]
    Jlr = line_jacobians(segments_right, pose, camera, **kw) * w_l[:, 1, None, None]
    rows = jnp.concatenate(
        [jnp.concatenate([Jp, Jpr], axis=1), jnp.concatenate([Jl, Jlr], axis=1)], axis=0
    )
    return jnp.where(jnp.isfinite(rows), rows, 0.0)


def _chaser_rows(t_cam) -> np.ndarray:
    """``G = [I, [t]_x]`` (``3 x 6``): the chaser's position error, before ``-R^T``, of a
    translation error ``dt`` and a tangent attitude error ``d(theta)`` at ``t_cam`` (metres;
    ``None``: the target origin's position, ``[I, 0]``)."""
    G = np.zeros((3, 6))
    G[:, :3] = np.eye(3)
    if t_cam is not None:
        x, y, z = np.asarray(t_cam, float)
        G[:, 3:] = [[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]]
    return G


def criterion_weight(arm_m: float, t_cam=None) -> np.ndarray:
    """``W`` (``6 x 6``) of the ``"dop"`` criterion ``trace(W Q)``: the variance of the chaser's
    position in the target frame, ``G Q G^T`` with ``G = [I, [t]_x]`` (``-R^T (dt + [t]_x
    d(theta))`` to first order for a translation error ``dt`` and a tangent attitude error
    ``d(theta)`` at the translation ``t_cam``, metres; ``None``: the target origin's position),
    plus ``arm_m^2`` times the attitude variance (a landmark ``arm_m`` from the centre)."""
    G = _chaser_rows(t_cam)
    return G.T @ G + np.diag(np.r_[np.zeros(3), np.full(3, float(arm_m) ** 2)])


def relative_weight(information, R_cam, t_cam) -> np.ndarray:
    """``W`` (``6 x 6``) of the ``"relative"`` criterion: ``trace(W Q) = sum_i (g_i^T Q g_i) /
    (g_i^T Q_all g_i)`` over the six axes ``g_i`` of the tracker's error metric, the chaser's
    position in the target frame (rows of ``R^T G``, ``G`` of :func:`criterion_weight` at
    ``t_cam``) and the attitude about the camera's axes, with ``Q_all`` the inverse of
    ``information`` (``6 x 6``: every candidate's summed). A subset's criterion is then the sum
    of its per-axis variance ratios to all candidates (6 for all of them); ``Q_all`` is taken
    as the pseudo-inverse if singular."""
    axes = np.concatenate([np.asarray(R_cam, float).T @ _chaser_rows(t_cam), np.eye(6)[3:]])
    Q_all = np.linalg.pinv(np.asarray(information, float))
    var = np.einsum("ij,jk,ik->i", axes, Q_all, axes)
    var = np.where(var > 0, var, np.inf)
    return np.einsum("i,ij,ik->jk", 1.0 / var, axes, axes)


def budget_criterion(information, weight):
    """``trace(W Q)``, ``Q = information^-1`` (``(..., 6, 6)``; ``inf`` when singular), ``W``
    from :func:`criterion_weight`: the criterion of the ``"dop"`` rule."""
    A = np.asarray(information, float)
    with np.errstate(all="ignore"):
        ev = np.linalg.eigvalsh(A)
        ok = ev[..., 0] > 1e-12 * ev[..., -1]
        Q = np.linalg.inv(np.where(ok[..., None, None], A, np.eye(6)))
    return np.where(ok, np.einsum("...ij,ji->...", Q, np.asarray(weight, float)), np.inf)


@jax.jit
def _greedy_forward(rows, valid, weight, n_keep, pixels, spacing):
    """Forward greedy on ``trace(W Q)``: a ``(n,)`` mask of the ``n_keep`` (traced: one
    compilation a padded size) features of ``rows`` (``(n, 4, 6)``) it picks, each at least
    ``spacing`` pixels from those picked before while such candidates remain."""
    dtype = rows.dtype
    blocks = jnp.einsum("nki,nkj->nij", rows, rows)
    count = jnp.maximum(jnp.sum(valid), 1).astype(dtype)
    mean = jnp.sum(jnp.where(valid[:, None, None], blocks, 0.0), 0) / count
    d = jnp.diagonal(mean)
    s_p = jnp.maximum(jnp.mean(d[:3]), jnp.finfo(dtype).tiny)
    s_a = jnp.maximum(jnp.mean(d[3:]), jnp.finfo(dtype).tiny)
    scale = 1.0 / jnp.sqrt(jnp.r_[jnp.full(3, s_p), jnp.full(3, s_a)])  # entries of order one
    h = rows * scale  # (n, 4, 6): the state divided by ``scale``
    w = scale[:, None] * weight * scale[None, :]  # trace(W Q) in the scaled state
    Q0 = jnp.eye(6, dtype=dtype) / _PRIOR

    def add(Q, h_rows):
        for k in range(h_rows.shape[-2]):  # rank-one Sherman-Morrison updates
            v = jnp.einsum("...ij,...j->...i", Q, h_rows[..., k, :])
            den = 1.0 + jnp.einsum("...i,...i->...", h_rows[..., k, :], v)
            Q = Q - v[..., :, None] * v[..., None, :] / den[..., None, None]
        return Q

    def scores(Q):
        """``trace(W Q_i)`` after adding each candidate's rows, without forming ``Q_i``: with
        ``v_r = Q_(r-1) h_r``, ``trace(W Q_r) = trace(W Q_(r-1)) - v_r^T W v_r / (1 + h_r^T v_r)``,
        and the later ``Q_r h_j`` follow from ``Q_(r-1) h_j`` by the same rank-one update."""
        u = list(jnp.moveaxis(jnp.einsum("ij,nkj->nki", Q, h), 1, 0))  # Q h_k, (n, 6) each
        drop = jnp.zeros(h.shape[0], dtype)
        for r in range(len(u)):
            v = u[r]
            den = 1.0 + jnp.sum(h[:, r] * v, axis=-1)
            drop = drop + jnp.einsum("ni,ij,nj->n", v, w, v) / den
            for j in range(r + 1, len(u)):
                u[j] = u[j] - v * (jnp.sum(v * h[:, j], axis=-1) / den)[:, None]
        return jnp.trace(w @ Q) - drop

    def step(_, carry):
        Q, free, chosen = carry
        score = scores(Q)
        score = jnp.where(jnp.isfinite(score), score, jnp.inf)
        spaced = jnp.where(free, score, jnp.inf)
        # no spaced candidate left: any valid one not yet chosen
        score = jnp.where(
            jnp.isfinite(jnp.min(spaced)), spaced, jnp.where(valid & ~chosen, score, jnp.inf)
        )
        k = jnp.argmin(score)
        take = jnp.isfinite(score[k])
        near = jnp.sum((pixels - pixels[k]) ** 2, axis=1) < spacing**2
        free = jnp.where(take, free & ~near, free).at[k].set(False)
        return jnp.where(take, add(Q, h[k]), Q), free, chosen.at[k].set(chosen[k] | take)

    _, _, chosen = jax.lax.fori_loop(0, n_keep, step, (Q0, valid, jnp.zeros_like(valid)))
    return chosen


def select_dop(rows, valid, n_keep: int, weight, *, pixels=None, spacing_px=0.0) -> np.ndarray:
    """The ``"dop"`` rule: ``n_keep`` indices (ascending) of the valid features of ``rows``
    (``(n, 4, 6)`` from :func:`feature_rows`, padded; ``valid`` ``(n,)`` bool) minimising
    :func:`budget_criterion`: every subset scored when ``C(n_valid, n_keep) <=``
    :data:`EXACT_SUBSETS`, else forward greedy (module docstring), which keeps its picks at least
    ``spacing_px`` apart in the image (``pixels``, ``(n, 2)``) while it can. All valid indices
    when there are no more than ``n_keep``."""
    valid = np.asarray(valid, bool)
    idx = np.nonzero(valid)[0]
    if len(idx) <= n_keep:
        return idx
    rows_np = np.asarray(rows, float)
    if math.comb(len(idx), n_keep) <= EXACT_SUBSETS:
        blocks = np.einsum("nki,nkj->nij", rows_np[idx], rows_np[idx])
        subsets = np.array(list(itertools.combinations(range(len(idx)), n_keep)))
        cost = budget_criterion(blocks[subsets].sum(1), weight)
        return idx[subsets[int(np.argmin(cost))]]
    W = jnp.asarray(np.asarray(weight, float))
    pix = np.zeros((len(valid), 2)) if pixels is None else np.asarray(pixels, float)
    picked = _greedy_forward(
        jnp.asarray(rows_np), jnp.asarray(valid), W, n_keep, jnp.asarray(pix), float(spacing_px)
    )
    return np.nonzero(np.asarray(picked))[0]


def _split(n_keep: int, n_p: int, n_l: int) -> tuple[int, int]:
    """``n_keep`` shared between points and lines in proportion to their counts."""
    k_l = min(n_l, int(round(n_keep * n_l / max(n_p + n_l, 1))))
    k_p = min(n_p, n_keep - k_l)
    return k_p, min(n_l, n_keep - k_p)


def _consistent(predicted: np.ndarray, observed: np.ndarray, floor_px: float) -> np.ndarray:
    """Matches that follow the frame's motion: an affine map of the predicted pixels onto the
    observed ones, fitted by least squares twice (the second time without the matches beyond
    the bound), and the matches within ``max(floor_px, 3 sigma)`` of it (``sigma`` from the
    median absolute residual). A few wrong matches left among ``N`` features would pull a small
    solve far more than they pull the solve on all matches."""
    n = len(predicted)
    keep = np.ones(n, bool)
    if n < 8:
        return keep
    A = np.c_[predicted, np.ones(n)]
    for _ in range(2):
        coef = np.linalg.lstsq(A[keep], observed[keep], rcond=None)[0]
        e = np.linalg.norm(A @ coef - observed, axis=1)
        bound = max(floor_px, 3.0 * 1.4826 * float(np.median(e[keep])) / 1.1774)
        keep = e < bound
        if keep.sum() < 8:
            return np.ones(n, bool)
    return keep


def select_budget(
    landmarks,
    feats,
    stereo,
    matches,
    pose_pred: Pose,
    rig,
    options: TrackerOptions,
    line_sigma: float,
    *,
    frame: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Which matched points and lines go into the pose solve: boolean masks ``(n_p,)`` and
    ``(n_l,)`` over ``matches = (i_m, i_cur, l_m, l_cur)``, at most ``options.feature_budget``
    true together (all matches when the budget is ``None`` or not smaller than their count).
    Landmarks too young for the solve (``mature_obs``) and point matches that do not follow the
    frame's motion (:func:`_consistent`) are never chosen, whatever the rule; nor, when at least
    ``2 N`` others remain, point landmarks that were not inliers on the frame before."""
    o = options
    i_m, i_cur, l_m, l_cur = matches
    n_p, n_l = len(i_m), len(l_m)
    keep_p, keep_l = np.ones(n_p, bool), np.ones(n_l, bool)
    N = o.feature_budget
    if N is None or n_p + n_l <= N:
        return keep_p, keep_l
    ok_p = np.ones(n_p, bool)
    if o.mature_obs > 1:
        ok_p = landmarks.points.n_obs[i_m] >= o.mature_obs
    ok_p &= _consistent(
        project(rig.left, pose_pred, landmarks.points.X[i_m]), feats.points[i_cur], o.reject_px
    )
    recent = landmarks.points.last_seen[i_m] >= frame - 1  # an inlier on the frame before
    if np.count_nonzero(ok_p & recent) >= 2 * N:
        ok_p &= recent
    cand_p, cand_l = np.nonzero(ok_p)[0], np.arange(n_l)
    keep_p[:], keep_l[:] = False, False
    if len(cand_p) + n_l <= N:
        keep_p[cand_p], keep_l[cand_l] = True, True
        return keep_p, keep_l
    if o.budget_rule == "random":
        rng = np.random.default_rng([frame, 20180])
        pick = rng.choice(len(cand_p) + n_l, size=N, replace=False)
        keep_p[cand_p[pick[pick < len(cand_p)]]] = True
        keep_l[pick[pick >= len(cand_p)] - len(cand_p)] = True
        return keep_p, keep_l
    if o.budget_rule == "response":
        k_p, k_l = _split(N, len(cand_p), n_l)
        resp = getattr(feats, "point_response", None)
        if resp is None or len(resp) != len(feats.points):
            resp = np.zeros(len(feats.points))  # no responses: the first matches
        order = np.argsort(-np.asarray(resp)[i_cur[cand_p]], kind="stable")
        keep_p[cand_p[order[:k_p]]] = True
        length = np.linalg.norm(np.diff(feats.segments[l_cur], axis=1)[:, 0], axis=-1)
        keep_l[np.argsort(-length, kind="stable")[:k_l]] = True
        return keep_p, keep_l
    rows, valid, arm = _dop_inputs(
        landmarks, feats, stereo, matches, cand_p, pose_pred, rig, o, line_sigma
    )
    frac = o.budget_subsample
    if frac < 1.0:  # stochastic greedy: a fresh random share of the candidates each frame
        idx = np.nonzero(valid)[0]
        n_sub = max(2 * N, int(round(frac * len(idx))))
        if n_sub < len(idx):
            rng = np.random.default_rng([frame, 2015])
            valid = np.zeros_like(valid)
            valid[rng.choice(idx, n_sub, replace=False)] = True
    # image positions (point pixels, segment midpoints) and the spacing of N features spread
    # over the box the candidates span: features a few pixels apart (one corner found at
    # several ORB scales) share their landmark's error, which the DOP takes as independent
    B_p = _bucket(n_p, 64)  # the padded point count of _dop_inputs' rows
    pix = np.zeros((len(valid), 2))
    pix[:n_p] = feats.points[i_cur]
    pix[B_p : B_p + n_l] = feats.segments[l_cur].mean(axis=1)
    span = np.ptp(pix[valid], axis=0)
    spacing = SPACING * float(np.sqrt(span[0] * span[1] / N))
    history = None
    if o.budget_repeat_discount > 0 and o.budget_window and o.window_frames > 1:
        # landmarks chosen in the window's earlier frames share their position error there
        history = selection_history(landmarks, o.window_frames - 1)
        ids_p, ids_l = landmarks.points.ids[i_m], landmarks.lines.ids[l_m]
        f_p, f_l = history.scale(ids_p, ids_l, o.budget_repeat_discount)
        f = np.ones(len(valid))
        f[:n_p], f[B_p : B_p + n_l] = f_p, f_l
        rows = np.asarray(rows, float) * f[:, None, None]
    if o.budget_weight == "relative":
        r = np.asarray(rows, float)[valid]
        info = np.einsum("nki,nkj->ij", r, r)
        W = relative_weight(info, np.asarray(pose_pred.R, float), np.asarray(pose_pred.t, float))
    else:
        W = criterion_weight(arm, np.asarray(pose_pred.t, float))
    chosen = select_dop(rows, valid, N, W, pixels=pix, spacing_px=spacing)
    keep_p[chosen[chosen < B_p]] = True
    keep_l[chosen[chosen >= B_p] - B_p] = True
    if history is not None:
        history.push(ids_p[keep_p], ids_l[keep_l])
    return keep_p, keep_l


def landmark_covariance(M, X_body, pose: Pose, camera, baseline_m: float, sigma_px: float):
    """``(n, 3, 3)`` covariance (body frame, m^2) of point landmarks from their multi-view
    triangulations: ``(sigma / f)^2 M^-1``, ``M = sum w (I - d d^T)`` the normal equations of
    :meth:`~jaxpose.pipelines.stereo.LandmarkMap.observe` with the weights ``w = 1 / z^2`` of
    :func:`~jaxpose.pipelines.stereo.keyframes.observe_point_rays` (a ray's perpendicular
    distance to the point is ``z sigma / f`` metres for a ``sigma`` pixel error). Where ``M`` is
    still degenerate (its rays nearly parallel), the covariance of one stereo triangulation at
    ``pose``: ``(z sigma / f)^2`` across the ray and ``(z^2 sqrt(2) sigma / (f b))^2`` along it
    (the depth error of a disparity error ``sqrt(2) sigma``), ``b`` the baseline."""
    M = np.asarray(M, float).reshape(-1, 3, 3)
    X = np.asarray(X_body, float).reshape(-1, 3)
    f = float(camera.focal_px)
    R, t = np.asarray(pose.R, float), np.asarray(pose.t, float)
    x = X @ R.T + t
    z = np.maximum(x[:, 2], 1e-3)
    u = x / np.linalg.norm(x, axis=1, keepdims=True)
    across, along = (
        (z * sigma_px / f) ** 2,
        (z**2 * np.sqrt(2.0) * sigma_px / (f * baseline_m)) ** 2,
    )
    uu = u[:, :, None] * u[:, None, :]
    cam = across[:, None, None] * (np.eye(3) - uu) + along[:, None, None] * uu
    cov = np.einsum("ji,njk,kl->nil", R, cam, R)  # R^T C R
    ok = rays_meet(M)  # the map's own test of a determined triangulation
    if ok.any():
        cov[ok] = (sigma_px / f) ** 2 * np.linalg.inv(M[ok])
    return cov


def _projection_jacobian(x_cam, R, camera):
    """``(n, 2, 3)``: d(pixels)/d(body point) of points at ``x_cam`` (camera frame)."""
    return pixel_jacobian(x_cam, float(camera.fx), float(camera.fy)) @ R


def point_sigma_eff(landmarks, i_m, pose: Pose, rig, o: TrackerOptions, mode: str) -> np.ndarray:
    """``(n,)`` isotropic effective pixel noise of point landmarks ``i_m`` in the left image:
    ``sqrt(s^2 + trace(J C_X J^T) / 2)``, ``s`` the measured spread (``"measured"``,
    ``"both"``) or ``sigma_px``, ``C_X`` the landmark covariance (``"landmark"``, ``"both"``)."""
    i_m = np.asarray(i_m, int)
    sig, cov = _noise_terms(landmarks, i_m, pose, rig, o, mode)
    s2 = sig**2
    if cov is not None:
        X = landmarks.points.X[i_m]
        R, t = np.asarray(pose.R, float), np.asarray(pose.t, float)
        J = _projection_jacobian(X @ R.T + t, R, rig.left)
        s2 = s2 + np.einsum("nij,njk,nik->n", J, cov, J) / 2
    return np.sqrt(s2)


def point_sigma_images(landmarks, i_m, pose: Pose, rig, o: TrackerOptions):
    """``(n,), (n,)``: effective pixel noise of point landmarks ``i_m`` in the left and in the
    right image, ``sqrt(sigma_px^2 + trace(J C_X J^T) / 2)`` with each image's projection
    Jacobian ``J`` and the landmark covariance ``C_X`` (:func:`landmark_covariance`): a landmark
    placed by one stereo pair carries its depth error (``z^2 sqrt(2) sigma / (f b)``) into the
    right image's residual, where the left one barely sees it."""
    i_m = np.asarray(i_m, int)
    _, cov = _noise_terms(landmarks, i_m, pose, rig, o, "landmark")
    s2 = float(o.sigma_px) ** 2
    if cov is None:
        return np.full(len(i_m), float(o.sigma_px)), np.full(len(i_m), float(o.sigma_px))
    X = landmarks.points.X[i_m]
    R, t = np.asarray(pose.R, float), np.asarray(pose.t, float)
    x = X @ R.T + t
    out = []
    for shift in (np.zeros(3), np.asarray(rig.t_rl, float)):
        J = _projection_jacobian(x + shift, R, rig.left)
        out.append(np.sqrt(s2 + np.einsum("nij,njk,nik->n", J, cov, J) / 2))
    return out[0], out[1]


def _noise_terms(landmarks, i_m, pose: Pose, rig, o: TrackerOptions, mode: str):
    """The two parts of the effective noise of point landmarks ``i_m`` under ``mode``: ``(n,)``
    pixel noise (the measured spread for ``"measured"`` and ``"both"``, else ``sigma_px``) and
    the ``(n, 3, 3)`` landmark covariance for ``"landmark"`` and ``"both"`` (else ``None``)."""
    sig = np.full(len(i_m), float(o.sigma_px))
    if mode in ("measured", "both"):
        sig = residual_spread(landmarks).sigma(landmarks.points.ids[i_m], o.sigma_px)
    cov = None
    if mode in ("landmark", "both") and len(i_m):
        cov = landmark_covariance(
            landmarks.points.M[i_m],
            landmarks.points.X[i_m],
            pose,
            rig.left,
            float(np.linalg.norm(np.asarray(rig.t_rl, float))),
            o.sigma_px,
        )
    return sig, cov


def effective_whitening(cov_X, X_body, pose: Pose, camera, t_rl, sigma_px, has_right):
    """``(n, 4, 4)`` whitening ``L^-1`` (``L L^T = C``) of the left and right pixel residuals of
    point landmarks whose position error has covariance ``cov_X`` (``(n, 3, 3)``, body frame):
    ``C = diag(sigma_px^2) + J C_X J^T``, ``J`` (``4 x 3``) the landmark's projection Jacobian
    into the left and right image at ``pose`` (the right image through ``t_rl``). ``sigma_px``:
    ``(n,)`` pixel noise; rows of a point without a right match (``has_right`` false) are
    decoupled (unit block, no cross terms) and its right rows are zero anyway. A feature's
    information is then ``(L^-1 J_pose)^T (L^-1 J_pose)``: a landmark far from the cameras or
    seen from few directions counts for less than its pixels alone say."""
    X = np.asarray(X_body, float).reshape(-1, 3)
    R, t = np.asarray(pose.R, float), np.asarray(pose.t, float)
    x = X @ R.T + t
    J = np.concatenate(
        [_projection_jacobian(x, R, camera), _projection_jacobian(x + t_rl, R, camera)], axis=1
    )
    J[~np.asarray(has_right, bool), 2:] = 0.0
    C = np.einsum("nij,njk,nlk->nil", J, cov_X, J)
    s2 = np.asarray(sigma_px, float) ** 2
    C += s2[:, None, None] * np.eye(4)
    C[~np.asarray(has_right, bool), 2:, 2:] = (
        np.eye(2) * s2[~np.asarray(has_right, bool), None, None]
    )
    return np.linalg.inv(np.linalg.cholesky(C))


class ResidualSpread:
    """Running RMS of each point landmark's post-fit residual (pixels, left image), keyed by the
    landmarks' stable ids: ``s^2 <- s^2 + (min(e, cap)^2 - s^2) / min(k, memory)`` at the
    ``k``-th frame that matched it, from ``s^2 = sigma^2`` before the first. The residual of a
    landmark at the fitted pose carries its position error and its corner's blur, which the
    pixel noise alone does not; a bias counts as noise in the pose solve, hence the RMS rather
    than the variance about the mean."""

    def __init__(self, memory: int = 10, cap_px: float = 6.0):
        self.memory, self.cap = int(memory), float(cap_px)
        self._s2: dict[int, float] = {}
        self._k: dict[int, int] = {}

    def sigma(self, ids, sigma_px: float) -> np.ndarray:
        """``(n,)`` running RMS of landmarks ``ids`` (``sigma_px`` where never matched)."""
        return np.sqrt([max(self._s2.get(int(i), sigma_px**2), sigma_px**2 * 0.25) for i in ids])

    def update(self, ids, errors, sigma_px: float) -> None:
        for i, e in zip(np.asarray(ids).tolist(), np.asarray(errors, float).tolist(), strict=True):
            k = self._k.get(i, 0) + 1
            s2 = self._s2.get(i, sigma_px**2)
            self._s2[i] = s2 + (min(e, self.cap) ** 2 - s2) / min(k, self.memory)
            self._k[i] = k


_SPREADS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def residual_spread(landmarks) -> ResidualSpread:
    """The :class:`ResidualSpread` of a landmark map (one per map, created on first use)."""
    if landmarks not in _SPREADS:
        _SPREADS[landmarks] = ResidualSpread()
    return _SPREADS[landmarks]


def _dop_inputs(landmarks, feats, stereo, matches, cand_p, pose_pred, rig, o, line_sigma):
    """Padded inputs of :func:`feature_rows` for the matches, its rows, the valid mask and the
    lever arm ``l`` of the criterion."""
    i_m, i_cur, l_m, l_cur = matches
    n_p, n_l = len(i_m), len(l_m)
    B_p, B_l = _bucket(n_p, 64), _bucket(max(n_l, o.max_lines), 16)
    t_rl = np.asarray(rig.t_rl, float)
    shift = np.asarray(pose_pred.R, float).T @ t_rl
    X = np.asarray(landmarks.points.X[i_m], float)
    S = np.asarray(landmarks.lines.X[l_m], float).reshape(-1, 2, 3)
    w_p, w_l = np.zeros((B_p, 2)), np.zeros((B_l, 2))
    w_p[cand_p, 0] = 1.0 / o.sigma_px
    w_l[:n_l, 0] = 1.0 / line_sigma
    if o.stereo_residuals and stereo is not None:
        if len(stereo.point_idx):
            q, _ = find(stereo.point_idx, i_cur)
            q = q[np.isin(q, cand_p)]
            w_p[q, 1] = 1.0 / o.sigma_px
        if o.line_stereo_residuals and n_l and len(stereo.line_idx):
            q, _ = stereo.right_lines(l_cur)
            w_l[q, 1] = 1.0 / line_sigma
    # padding: a harmless point 1 m in front of the camera, weight 0
    far = (np.array([0.0, 0.0, 1.0]) - np.asarray(pose_pred.t, float)) @ np.asarray(pose_pred.R)
    P = np.tile(far, (B_p, 1))
    P[:n_p] = X
    Sg = np.tile(far, (B_l, 2, 1)) + np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    Sg[:n_l] = S
    camera: PinholeCamera = rig.left
    rows = feature_rows(
        jnp.asarray(P),
        jnp.asarray(P + shift),
        jnp.asarray(Sg),
        jnp.asarray(Sg + shift),
        pose_pred,
        camera,
        jnp.asarray(w_p),
        jnp.asarray(w_l),
    )
    noise = o.budget_noise
    if noise != "pixel" and len(cand_p):
        has_right = w_p[cand_p, 1] > 0
        sig, cov = _noise_terms(landmarks, i_m[cand_p], pose_pred, rig, o, noise)
        if cov is None:
            cov = np.zeros((len(cand_p), 3, 3))
        Wh = effective_whitening(cov, X[cand_p], pose_pred, rig.left, t_rl, sig, has_right)
        r = np.asarray(rows, float).copy()
        r[cand_p] = np.einsum("nij,njk->nik", Wh, r[cand_p] * o.sigma_px)  # unweighted, whitened
        rows = r
    valid = np.r_[w_p[:, 0] > 0, w_l[:, 0] > 0]
    centres = np.concatenate([X[cand_p], S.mean(axis=1)])
    arm = float(np.sqrt(np.mean(np.sum((centres - centres.mean(0)) ** 2, axis=1))))
    return rows, valid, arm


def fit_pose_budgeted(
    landmarks,
    feats,
    stereo,
    matches,
    pose_pred: Pose,
    rig,
    options: TrackerOptions,
    line_sigma: float,
    *,
    frame: int = 0,
    stage=None,
) -> PoseFit:
    """:func:`~jaxpose.pipelines.stereo.frame_pose.fit_pose` on the features kept by
    :func:`select_budget` (the same call when ``options.feature_budget`` is ``None``).

    The solve runs at a padded size fitted to the budget (the power of two at or above ``2 N``,
    room for the left and right residuals of ``N`` features), so its cost follows the budget.
    The returned errors, inlier flags, inlier count and RMS cover every matched feature at the
    fitted pose, as without a budget; ``kept_errors`` are the solve's.
    The selection runs inside ``stage("budget")`` when ``stage`` is given (a context-manager
    factory that times a named stage, e.g. ``StageClock.stage`` of the tracker)."""
    o = options
    if o.feature_budget is None:
        i_m = matches[0]
        sig = sig_r = None  # the points' noise: sigma_px, or one of two weightings
        if o.landmark_point_sigma:
            sig, sig_r = point_sigma_images(landmarks, i_m, pose_pred, rig, o)
        elif o.measured_point_sigma:
            sig = point_sigma_eff(landmarks, i_m, pose_pred, rig, o, "measured")
        fit = fit_pose(
            landmarks,
            feats,
            stereo,
            matches,
            pose_pred,
            rig,
            o,
            line_sigma,
            point_sigma=sig,
            point_sigma_right=sig_r,
        )
        if o.measured_point_sigma and fit.solver_ok:
            residual_spread(landmarks).update(landmarks.points.ids[i_m], fit.e_points, o.sigma_px)
        return fit
    with stage("budget") if stage is not None else contextlib.nullcontext():
        keep_p, keep_l = select_budget(
            landmarks, feats, stereo, matches, pose_pred, rig, o, line_sigma, frame=frame
        )
    i_m, i_cur, l_m, l_cur = matches
    sub = (i_m[keep_p], i_cur[keep_p], l_m[keep_l], l_cur[keep_l])
    # one padded size for a run (left and right residuals of up to N features): one compilation
    size = _bucket(2 * o.feature_budget, 16)
    o_sub = replace(o, max_points=min(o.max_points, size), max_lines=min(o.max_lines, size))
    fit = fit_pose(landmarks, feats, stereo, sub, pose_pred, rig, o_sub, line_sigma)
    e_p, e_l = postfit_errors(landmarks, feats, matches, fit.pose, rig.left)
    if fit.solver_ok and o.budget_noise in ("measured", "both"):
        residual_spread(landmarks).update(landmarks.points.ids[i_m], e_p, o.sigma_px)
    # the window's observations: every match near the budgeted pose, or the budget's own
    kept = np.zeros(len(e_p), bool) if o.budget_window else e_p < o.reject_px
    kept[keep_p] = fit.kept_points
    summary = postfit_summary(e_p, e_l, o.inlier_px)
    window_lines = summary["in_lines"] & keep_l if o.budget_window else None
    return replace(fit, kept_points=kept, window_lines=window_lines, **summary)
