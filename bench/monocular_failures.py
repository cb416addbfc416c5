"""Why the monocular initialisation is wrong on labelled images: per image, what the answer is
against the labelled pose and where the truth stands in the pipeline's own scores.

    python bench/monocular_failures.py DIR [--panel-weight 0] [--out failures.json]

``DIR`` is a SPEED+ folder (:func:`jaxpose.io.load_speed_labels`). For every image it runs
:func:`jaxpose.pipelines.monocular.initialise_pose` with ``trace=True`` and every pose kept
(``low_score`` 1), then reports:

- ``rot_deg``, ``pos_m``: the answer's errors; ``sym_deg``: the rotation from the answer to the
  nearest of the 7 turns of the labelled pose that map Tango's box (0.74 x 0.77 x 0.32 m) near
  onto itself (90, 180, 270 deg about body z; 180 deg about x, y and the footprint's diagonals),
  small when the answer is a symmetric flip of the truth;
- ``key_truth``, ``key_answer``: the ranking key (``l_ROI`` units) of the labelled pose fitted as
  the shortlist is (:func:`~jaxpose.pipelines.monocular.fit._chamfer_fit`, 12 steps) and
  re-matched, and of the answer: below the answer's when the ranking would prefer the truth;
- ``panel_truth``, ``panel_answer``: the panel term (``_panel_term``, 0.5: panel hidden);
- ``close_attitudes``, ``quick_rank``: how many hypotheses and grid attitudes before the shortlist
  lie within 10 deg of the truth's attitude, and the best quick-score rank among them (the
  shortlist fits the first 128);
- ``partner_close``: whether a symmetric turn of any final candidate, fitted as the shortlist is,
  is a success (10 deg, 0.30 m).

Development diagnostics (a few seconds per image): the figures are in the docs' monocular
evaluation page.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxpose.core.geometry import Pose, so3_exp  # noqa: E402
from jaxpose.io import load_camera, load_image, load_speed_labels  # noqa: E402
from jaxpose.pipelines.monocular import CONFIDENCE, InitOptions, initialise_pose  # noqa: E402
from jaxpose.pipelines.monocular.fit import _batched_fit, _chamfer_fit  # noqa: E402
from jaxpose.pipelines.monocular.rematch import _rematch_refine  # noqa: E402
from jaxpose.pipelines.monocular.scene import _edge_scene  # noqa: E402
from jaxpose.pipelines.monocular.score import (  # noqa: E402
    _batched_quick,
    _panel_term,
    _rank_key,
)
from jaxpose.vision.models import tango  # noqa: E402
from jaxpose.vision.roi import roi_diagonal  # noqa: E402

_D = np.sqrt(0.5)
#: The turns of a square prism about its centre (body frame), as rotation vectors.
TURNS = np.array(
    [
        [0, 0, np.pi / 2],
        [0, 0, np.pi],
        [0, 0, -np.pi / 2],
        [np.pi, 0, 0],
        [0, np.pi, 0],
        [np.pi * _D, np.pi * _D, 0],
        [np.pi * _D, -np.pi * _D, 0],
    ]
)
#: Centre of Tango's box in the body frame (metres): the turns are about it.
BOX_CENTRE = np.array([0.0, 0.0, 0.161])


def _angle(A, B) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(A @ B.T) - 1.0) / 2.0, -1.0, 1.0))))


def _turns():
    return np.stack([np.asarray(so3_exp(jnp.asarray(v))) for v in TURNS])


def _turned(R, t, S):
    """Poses ``(R S, t + R c - R S c)``: the body turned by ``S`` about ``BOX_CENTRE``."""
    RS = R @ S
    return RS, t + R @ BOX_CENTRE - RS @ BOX_CENTRE


def _batched(fn, R, t, *args, chunk=64):
    n = len(R)
    pad = (-n) % chunk
    Rp = np.concatenate([R, np.repeat(R[:1], pad, 0)])
    tp = np.concatenate([t, np.repeat(t[:1], pad, 0)])
    outs = [
        fn(jnp.asarray(Rp[a : a + chunk]), jnp.asarray(tp[a : a + chunk]), *args)
        for a in range(0, len(Rp), chunk)
    ]
    if isinstance(outs[0], tuple):
        return tuple(np.concatenate([np.asarray(o[i]) for o in outs])[:n] for i in range(2))
    return np.concatenate([np.asarray(o) for o in outs])[:n]


def diagnose_image(res, truth_R, truth_t, model, panel_weight: float) -> dict:
    """The quantities of the module docstring for one result of ``initialise_pose``."""
    row = {"confidence": res.confidence}
    if res.pose is None or res.trace is None or "refined" not in res.trace:
        return row
    det = res.detection
    sc = _edge_scene(det, model, InitOptions(panel_weight=max(panel_weight, 1.0)))
    sc0 = (
        sc._replace(panel_weight=float(panel_weight))
        if panel_weight > 0
        else sc._replace(tex=None, tex_frame=None, panel=None, panel_weight=0.0)
    )
    l_roi = roi_diagonal(det.roi)
    R, t = np.asarray(res.pose.R), np.asarray(res.pose.t)
    S = _turns()
    row["rot_deg"] = _angle(R, truth_R)
    row["pos_m"] = float(np.linalg.norm(t - truth_t))
    row["sym_deg"] = min(_angle(R, truth_R @ s) for s in S)
    Rf, tf = _chamfer_fit(jnp.asarray(truth_R), jnp.asarray(truth_t), sc0, steps=12)
    pf = _rematch_refine([Pose(Rf, tf)], det, model, det.camera, l_roi, 2)[0]
    row["key_truth"] = float(_rank_key(pf.R, pf.t, sc0)[0]) / l_roi
    row["key_answer"] = float(_rank_key(jnp.asarray(R), jnp.asarray(t), sc0)[0]) / l_roi
    row["panel_truth"] = float(_panel_term(jnp.asarray(truth_R), jnp.asarray(truth_t), sc))
    row["panel_answer"] = float(_panel_term(jnp.asarray(R), jnp.asarray(t), sc))
    HR, Ht, ok = res.trace["hypotheses"]
    quick = _batched(_batched_quick(), HR, Ht, sc0, jnp.asarray(det.roi), chunk=512)
    quick = np.where(ok & np.isfinite(quick), quick, np.inf)
    rank = np.empty(len(quick), int)
    rank[np.argsort(quick, kind="stable")] = np.arange(len(quick))
    c = (np.einsum("nij,ij->n", HR, truth_R) - 1.0) / 2.0
    close = c > np.cos(np.deg2rad(10.0))
    row["close_attitudes"] = int(close.sum())
    row["quick_rank"] = int(rank[close].min()) if close.any() else None
    CR = np.stack([np.asarray(p.R) for p in res.trace["refined"]])
    Ct = np.stack([np.asarray(p.t) for p in res.trace["refined"]])
    PR, Pt = zip(*(_turned(a, b, s) for a, b in zip(CR, Ct, strict=True) for s in S), strict=True)
    FR, Ft = _batched(_batched_fit(), np.stack(PR), np.stack(Pt), sc0)
    ang = np.degrees(np.arccos(np.clip((np.einsum("nij,ij->n", FR, truth_R) - 1) / 2, -1, 1)))
    row["partner_close"] = bool(np.any((ang < 10) & (np.linalg.norm(Ft - truth_t, axis=1) < 0.3)))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("directory")
    ap.add_argument("--panel-weight", type=float, default=0.0)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    root = Path(args.directory)
    camera = load_camera(root / "camera.json")
    model = tango()
    opts = InitOptions(
        trace=True, panel_weight=args.panel_weight, confidence=dict(CONFIDENCE, low_score=1.0)
    )
    rows = []
    for lab in load_speed_labels(root):
        res = initialise_pose(load_image(lab.image), camera, model, opts)
        R, t = np.asarray(lab.pose.R, float), np.asarray(lab.pose.t, float)
        row = {"image": lab.image.name} | diagnose_image(res, R, t, model, args.panel_weight)
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
