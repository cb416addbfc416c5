"""The attitude grid on labelled images: where the close attitudes rank under the quick score and
under the LINE-2D template search, and whether a close attitude, fitted and re-matched as the
pipeline's shortlist is, would be a success that the ranking key prefers.

    python bench/monocular_templates.py DIR [--out templates.json]

``DIR`` is a SPEED+ folder (:func:`jaxpose.io.load_speed_labels`). Per image, with the default
options (every pose kept: ``low_score`` 1):

- ``close``: grid attitudes within 10 deg of the labelled attitude (``best_deg``: the nearest);
- ``quick_rank``: the best quick-score rank among them, placed as the pipeline places the grid
  (on the silhouette, or on the ROI when there is none); the shortlist fits the first 128;
- ``template_rank``: their best rank under the template search
  (:mod:`jaxpose.pipelines.monocular.templates`, every attitude placed on the ROI first);
- ``moved_m``: each close attitude's position error after the search's shift and scale;
- ``fitted_deg``, ``fitted_m``: after the shortlist's edge fit (``_batched_fit``) and the
  re-matching refinement (``_rematch_refine``, 2 rounds): the *ceiling* of the search, what a
  close attitude becomes when it reaches the shortlist;
- ``key_minus_answer``: their ranking key minus the returned answer's (``l_ROI`` units; above 0:
  the ranking prefers the answer);
- ``template_cpu_s``: CPU time of the template search (``time.process_time``);
- ``label_fit_deg``, ``label_fit_range``: the labelled pose after the shortlist's edge fit
  alone, its rotation from the label and the ratio of its centre's range to the label's (above
  1: the fit moves the model away from the camera);
- ``scan_model``, ``scan_image``: at the labelled attitude, the range (times the label's, 0.85
  to 1.15 in steps of 0.01, the centre moved along its ray) where the model side and the image
  side of the fit's chamfer residuals (``_chamfer_residuals``) are least; ``scan_directional``:
  the same for a directional model side (each edge sample's distance to the nearest detected
  segment whose direction lies within 22.5 deg of the edge's, truncated at ``tau``: directional
  chamfer matching, Liu et al. 2010), to see whether segments of other directions cause the drift.

Development diagnostics (a few seconds per image); the figures are in the docs' monocular
evaluation page.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxpose.core.geometry import Pose  # noqa: E402
from jaxpose.io import load_camera, load_image, load_speed_labels  # noqa: E402
from jaxpose.pipelines.monocular import CONFIDENCE, InitOptions, initialise_pose  # noqa: E402
from jaxpose.pipelines.monocular import templates as T  # noqa: E402
from jaxpose.pipelines.monocular.fit import _batched_fit, _chamfer_residuals  # noqa: E402
from jaxpose.pipelines.monocular.hypothesise import (  # noqa: E402
    _CHUNK,
    _SHORTLIST,
    _attitudes,
    _batched_place,
    _batched_place_roi,
    _pad_batch,
)
from jaxpose.pipelines.monocular.rematch import _rematch_refine  # noqa: E402
from jaxpose.pipelines.monocular.scene import _edge_scene  # noqa: E402
from jaxpose.pipelines.monocular.score import (  # noqa: E402
    _batched_quick,
    _batched_rank,
    _visible_edges,
)
from jaxpose.vision.image_maps import orientation_maps  # noqa: E402
from jaxpose.vision.models import tango  # noqa: E402
from jaxpose.vision.roi import roi_diagonal  # noqa: E402


def _angles(R, Rt) -> np.ndarray:
    c = (np.einsum("nij,ij->n", R, Rt) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _chunked(fn, *arrays):
    """``fn`` over fixed-size chunks of ``arrays`` (one compiled shape), outputs concatenated."""
    out = []
    n = len(arrays[0])
    for a in range(0, n, _CHUNK):
        parts = _pad_batch([x[a : a + _CHUNK] for x in arrays], _CHUNK)
        r = fn(*[jnp.asarray(p) for p in parts])
        r = r if isinstance(r, tuple) else (r,)
        out.append([np.asarray(x)[: min(_CHUNK, n - a)] for x in r])
    return [np.concatenate([o[i] for o in out]) for i in range(len(out[0]))]


def _best_rank(key, close) -> int:
    r = np.empty(len(key), int)
    r[np.argsort(key, kind="stable")] = np.arange(len(key))
    return int(r[close].min()) if close.any() else -1


def _range_scan(Rt, tt, sc, centre):
    """Ranges (times the label's) where the model side and the image side of the chamfer
    residuals are least, at the labelled attitude."""
    scales = np.round(np.linspace(0.85, 1.15, 31), 2)
    c = Rt @ centre + tt
    n_model = int(np.prod(sc.geom[1].shape[:2]))
    cost = []
    for k in scales:
        t = jnp.asarray(c * k - Rt @ centre)
        R = jnp.asarray(Rt)
        r = np.asarray(_chamfer_residuals(R, t, _visible_edges(R, t, sc.geom), sc))
        cost.append((np.sum(r[:n_model] ** 2), np.sum(r[n_model:] ** 2)))
    cost = np.asarray(cost)
    return float(scales[cost[:, 0].argmin()]), float(scales[cost[:, 1].argmin()])


def _directional_maps(segments, shape, bins: int = 8) -> np.ndarray:
    """Distance maps ``(bins, H, W)`` (pixels) of the detected segments whose direction lies
    in bin ``o`` or a neighbouring bin (bin ``o``: ``o x 180 / bins`` deg, modulo 180)."""
    import cv2

    d = segments[:, 1] - segments[:, 0]
    b = np.mod(np.rint(np.mod(np.arctan2(d[:, 1], d[:, 0]), np.pi) / (np.pi / bins)), bins)
    out = np.empty((bins,) + tuple(shape), np.float32)
    for o in range(bins):
        mask = np.full(shape, 255, np.uint8)
        near = np.minimum(np.mod(b - o, bins), np.mod(o - b, bins)) <= 1
        for seg in segments[near]:
            p, q = (tuple(int(round(v)) for v in x) for x in seg)
            cv2.line(mask, p, q, 0, 1)
        out[o] = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    return out


def _directional_scan(Rt, tt, sc, det, centre, scales):
    """Range (times the label's) where the directional model side is least (NumPy)."""
    maps = _directional_maps(np.asarray(det.segments, float), det.image.shape)
    edges, samples = np.asarray(sc.geom[0]), np.asarray(sc.geom[1])
    fx, fy, cx, cy = (float(v) for v in np.asarray(sc.cam4))
    H, W = det.image.shape
    tau = float(sc.tau)
    c = Rt @ centre + tt
    cost = []
    for k in scales:
        t = c * k - Rt @ centre
        vis = np.asarray(_visible_edges(jnp.asarray(Rt), jnp.asarray(t), sc.geom))
        pc = samples @ Rt.T + t
        u, v = fx * pc[..., 0] / pc[..., 2] + cx, fy * pc[..., 1] / pc[..., 2] + cy
        ends = edges @ Rt.T + t
        du = fx * ends[:, 1, 0] / ends[:, 1, 2] - fx * ends[:, 0, 0] / ends[:, 0, 2]
        dv = fy * ends[:, 1, 1] / ends[:, 1, 2] - fy * ends[:, 0, 1] / ends[:, 0, 2]
        o = np.mod(np.rint(np.mod(np.arctan2(dv, du), np.pi) / (np.pi / 8)), 8).astype(int)
        inside = (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
        iu, iv = (
            np.clip(np.rint(u), 0, W - 1).astype(int),
            np.clip(np.rint(v), 0, H - 1).astype(int),
        )
        d = np.where(inside, np.minimum(maps[o[:, None], iv, iu], tau), tau)
        m = vis[:, None] & (pc[..., 2] > 1e-3)
        cost.append(np.sum(np.where(m, d * d, 0.0)) / max(m.sum(), 1))
    return float(scales[int(np.argmin(cost))])


def diagnose_image(res, Rt, tt, model, opts) -> dict:
    det = res.detection
    if det.roi is None or det.coarse_t_cam is None:
        return {"roi": False}
    sc = _edge_scene(det, model, opts)
    roi = jnp.asarray(det.roi)
    R = _attitudes(int(opts.attitude_grid))
    centre = np.asarray(sc.geom[1]).reshape(-1, 3).mean(0)
    coarse = np.asarray(det.coarse_t_cam, float)[None]
    (t_roi,) = _chunked(lambda a, b: _batched_place_roi()(a, b, sc, roi), R, coarse - R @ centre)
    t_grid = t_roi
    if sc.sil_pts is not None:
        c_f = np.asarray(sc.face_poly).reshape(-1, 3).mean(0)
        (t_grid,) = _chunked(lambda a, b: _batched_place()(a, b, sc), R, coarse - R @ c_f)
    (quick,) = _chunked(lambda a, b: _batched_quick()(a, b, sc, roi), R, t_grid)
    cpu = time.process_time()
    ori, frame = orientation_maps(det.image, det.roi, spread=T.TEMPLATE_STRIDE)
    shifts = jnp.asarray(T.template_shifts(roi_diagonal(det.roi) * frame[2]))
    scales = jnp.asarray(T.TEMPLATE_SCALES)
    ori, frame = jnp.asarray(ori), jnp.asarray(frame)
    f = T._batched_template_match()
    sim, k, d = _chunked(
        lambda a, b: f(a, b, sc.geom, ori, frame, sc.cam4, shifts, scales), R, t_roi
    )
    t_moved = T._moved(R, t_roi, k, d, centre, np.asarray(sc.cam4))
    cpu = time.process_time() - cpu
    ang = _angles(R, Rt)
    close = ang < 10.0
    Rl, tl = _batched_fit()(
        jnp.asarray(np.repeat(Rt[None], _SHORTLIST, 0)),
        jnp.asarray(np.repeat(tt[None], _SHORTLIST, 0)),
        sc,
    )
    Rl, tl = np.asarray(Rl[0]), np.asarray(tl[0])
    c_label = Rt @ centre + tt
    row = {
        "roi": True,
        "silhouette": sc.sil_pts is not None,
        "close": int(close.sum()),
        "best_deg": round(float(ang.min()), 1),
        "quick_rank": _best_rank(quick, close),
        "template_rank": _best_rank(-sim, close),
        "template_cpu_s": round(cpu, 3),
        "label_fit_deg": round(float(_angles(Rl[None], Rt)[0]), 1),
        "label_fit_range": round(
            float(np.linalg.norm(Rl @ centre + tl) / np.linalg.norm(c_label)), 3
        ),
    }
    row["scan_model"], row["scan_image"] = _range_scan(Rt, tt, sc, centre)
    scales = np.round(np.linspace(0.85, 1.15, 31), 2)
    row["scan_directional"] = _directional_scan(Rt, tt, sc, det, centre, scales)
    if not close.any() or res.pose is None:
        return row
    idx = np.where(close)[0][:_SHORTLIST]
    pad = np.concatenate([idx, np.repeat(idx[:1], _SHORTLIST - len(idx))])
    Rf, tf = _batched_fit()(jnp.asarray(R[pad]), jnp.asarray(t_moved[pad]), sc)
    poses = [Pose(Rf[i], tf[i]) for i in range(len(idx))]
    poses = _rematch_refine(poses, det, model, det.camera, roi_diagonal(det.roi), 2)
    key, _, _ = _batched_rank()(
        jnp.stack([p.R for p in poses] + [res.pose.R]),
        jnp.stack([p.t for p in poses] + [res.pose.t]),
        sc,
    )
    key = np.asarray(key) / roi_diagonal(det.roi)
    Rp = np.stack([np.asarray(p.R) for p in poses])
    tp = np.stack([np.asarray(p.t) for p in poses])
    row |= {
        "moved_m": [round(float(x), 2) for x in np.linalg.norm(t_moved[idx] - tt, axis=1)],
        "fitted_deg": [round(float(x), 1) for x in _angles(Rp, Rt)],
        "fitted_m": [round(float(x), 2) for x in np.linalg.norm(tp - tt, axis=1)],
        "key_minus_answer": [round(float(x - key[-1]), 4) for x in key[:-1]],
    }
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("directory")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    root = Path(args.directory)
    camera = load_camera(root / "camera.json")
    model = tango()
    opts = InitOptions(confidence=dict(CONFIDENCE, low_score=1.0))
    rows = []
    for lab in load_speed_labels(root):
        res = initialise_pose(load_image(lab.image), camera, model, opts)
        Rt, tt = np.asarray(lab.pose.R, float), np.asarray(lab.pose.t, float)
        ok = res.pose is not None
        row = {
            "image": lab.image.name,
            "answer_deg": round(float(_angles(np.asarray(res.pose.R)[None], Rt)[0]), 1)
            if ok
            else None,
            "answer_m": round(float(np.linalg.norm(np.asarray(res.pose.t) - tt)), 2)
            if ok
            else None,
        } | diagnose_image(res, Rt, tt, model, opts)
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
