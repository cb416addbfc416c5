"""Refinement by re-matching: visible model edges projected at each candidate, their endpoints
and lines matched to the detected segments, and the pose refined on those matches (points and
lines, Huber-robust Levenberg-Marquardt), batched over the candidates; eq. 22's ``E_2D``."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.core.geometry import Pose
from jaxpose.pipelines.monocular.score import _MAX_CANDIDATES, _pad_to
from jaxpose.vision.render import visible_edges

_PAD_MATCH = 48


@functools.lru_cache(maxsize=4)
def _refine_points_lines():
    from jaxpose.core.refine import RefineOptions, refine_pose

    options = RefineOptions(method="lm", robust="huber", robust_scale=3.0, max_steps=30)

    def one(pose, pts, pix, mask, seg_body, lines, lmask, cam):
        return refine_pose(
            pts,
            pix,
            pose,
            cam,
            mask=mask,
            segments_body=seg_body,
            lines_img=lines,
            line_mask=lmask,
            options=options,
            throw=False,
        )

    return jax.jit(jax.vmap(one, in_axes=(0, 0, 0, 0, 0, 0, 0, None)))


def _match(vis, det, radius):
    """Nearest-neighbour matches of projected visible endpoints to detected endpoints, and of
    visible edges to detected segments (angle within 6 deg, midpoint-to-line within radius)."""
    ends = det.segments.reshape(-1, 2)
    proj = vis.segments.reshape(-1, 2)
    body = vis.points_body.reshape(-1, 3)
    if len(ends) == 0 or len(proj) == 0:
        return np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 2, 3)), np.zeros((0, 2, 2))
    d = np.linalg.norm(proj[:, None] - ends[None], axis=-1)
    j = d.argmin(1)
    keep = d[np.arange(len(proj)), j] < radius
    # one image endpoint per model endpoint: keep the closest when several claim it
    pairs = sorted((d[i, j[i]], i, j[i]) for i in np.nonzero(keep)[0])
    used, pts, pix = set(), [], []
    for _, i, jj in pairs:
        if jj not in used:
            used.add(jj)
            pts.append(body[i])
            pix.append(ends[jj])
    # lines
    S = det.segments
    su = S[:, 1] - S[:, 0]
    su = su / np.maximum(np.linalg.norm(su, axis=1, keepdims=True), 1e-12)
    lb, ls = [], []
    for seg, b in zip(vis.segments, vis.points_body, strict=True):
        v = seg[1] - seg[0]
        L = np.linalg.norm(v)
        if L < 1e-6:
            continue
        v /= L
        ang = np.abs(su @ v)
        mid = seg.mean(0)
        r = mid - S[:, 0]
        dist = np.abs(su[:, 0] * r[:, 1] - su[:, 1] * r[:, 0])
        ok = (ang > np.cos(np.deg2rad(6.0))) & (dist < radius)
        if ok.any():
            k = np.nonzero(ok)[0][np.argmin(dist[ok])]
            lb.append(b)
            ls.append(S[k])
    return (
        np.asarray(pts).reshape(-1, 3),
        np.asarray(pix).reshape(-1, 2),
        np.asarray(lb).reshape(-1, 2, 3),
        np.asarray(ls).reshape(-1, 2, 2),
    )


def _rematch_refine(poses, det, model, cam, l_roi, rounds):
    H, W = det.image.shape
    radius = 0.06 * l_roi
    for _ in range(rounds):
        batch = []
        for p in poses:
            vis = visible_edges(model, p, cam, shape=(H, W), buffer_scale=0.25)
            batch.append(_match(vis, det, radius))
        N, L = _PAD_MATCH, _PAD_MATCH
        P = np.zeros((len(poses), N, 3))
        Q = np.zeros((len(poses), N, 2))
        M = np.zeros((len(poses), N), bool)
        SB = np.zeros((len(poses), L, 2, 3))
        SB[..., 1, 2] = 1.0
        LI = np.zeros((len(poses), L, 3))
        LI[..., 2] = 1.0
        LM = np.zeros((len(poses), L), bool)
        for i, (pts, pix, lb, ls) in enumerate(batch):
            a, b = min(len(pts), N), min(len(lb), L)
            P[i, :a], Q[i, :a], M[i, :a] = pts[:a], pix[:a], True
            if b:
                SB[i, :b] = lb[:b]
                LI[i, :b] = np.cross(np.c_[ls[:b, 0], np.ones(b)], np.c_[ls[:b, 1], np.ones(b)])
                LM[i, :b] = True
        R0 = jnp.stack([p.R for p in poses])
        t0 = jnp.stack([p.t for p in poses])
        R0, t0, P, Q, M, SB, LI, LM = (
            _pad_to(x, _MAX_CANDIDATES) for x in (R0, t0, P, Q, M, SB, LI, LM)
        )
        res = _refine_points_lines()(
            Pose(R0, t0),
            jnp.asarray(P),
            jnp.asarray(Q),
            jnp.asarray(M),
            jnp.asarray(SB),
            jnp.asarray(LI),
            jnp.asarray(LM),
            cam,
        )
        M, LM = np.asarray(M), np.asarray(LM)
        enough = (M.sum(1) + LM.sum(1)) >= 3
        status = np.asarray(res.status)
        new = []
        for i, p in enumerate(poses):
            if enough[i] and status[i] in (0, 5) and np.all(np.isfinite(np.asarray(res.pose.t[i]))):
                new.append(Pose(res.pose.R[i], res.pose.t[i]))
            else:
                new.append(p)
        poses = new
    return poses


def _e2d(vis, det, l_roi):
    """Eq. 22 over nearest-neighbour endpoint matches, and the matched share of visible edges."""
    if len(vis.segments) == 0 or len(det.segments) == 0:
        return np.inf, 0.0
    ends = det.segments.reshape(-1, 2)
    proj = vis.segments.reshape(-1, 2)
    d = np.linalg.norm(proj[:, None] - ends[None], axis=-1).min(1)
    radius = 0.06 * l_roi
    matched = d < radius
    e2d = float(d[matched].mean()) if matched.any() else np.inf
    edge_matched = matched.reshape(-1, 2).any(1)
    return e2d, float(edge_matched.mean())
