"""Stage diagnostics of the monocular pipeline against a labelled pose: where is the right answer
lost? Needs a result of ``initialise_pose(..., options=InitOptions(trace=True))``.

Stages, in order (each counted only for the poses that stage holds):

- ``roi_ok``: the ROI overlaps the true box (the model's projected vertices and antenna tips at
  the labelled pose, clipped to the image) with IoU >= 0.5 (the PASCAL VOC criterion);
- ``hypothesis_close``: a hypothesis (EPnP of a feature-group match, or an attitude of the grid
  placed on the silhouette) is within ``rotation_deg`` and ``translation_m`` of the truth;
- ``shortlist_close``: one of the shortlist after its edge fit is;
- ``candidate_close``: one of the ``top_k`` distinct candidates is;
- ``refined_close``: one of the candidates after the re-matching refinement is;
- ``first``: the candidate ranked first is (a success when its class returns the attitude).
"""

from __future__ import annotations

import numpy as np

from jaxpose.core.geometry import Pose
from jaxpose.vision.roi import box_iou

__all__ = ["STAGES", "stage_breakdown", "stage_counts"]

STAGES = (
    "roi_ok",
    "hypothesis_close",
    "shortlist_close",
    "candidate_close",
    "refined_close",
    "first",
    "success",
)


def _close(R, t, truth: Pose, rotation_deg: float, translation_m: float) -> np.ndarray:
    """Which poses ``R (N, 3, 3)``, ``t (N, 3)`` lie within the thresholds of ``truth``."""
    R, t = np.asarray(R, float).reshape(-1, 3, 3), np.asarray(t, float).reshape(-1, 3)
    Rt, tt = np.asarray(truth.R, float), np.asarray(truth.t, float)
    c = (np.einsum("nij,ij->n", R, Rt) - 1.0) / 2.0
    ang = np.rad2deg(np.arccos(np.clip(c, -1.0, 1.0)))
    return (ang < rotation_deg) & (np.linalg.norm(t - tt, axis=1) < translation_m)


def _stack(poses):
    if not poses:
        return np.zeros((0, 3, 3)), np.zeros((0, 3))
    return (
        np.stack([np.asarray(p.R, float) for p in poses]),
        np.stack([np.asarray(p.t, float) for p in poses]),
    )


def model_box(model, pose: Pose, camera, shape) -> np.ndarray | None:
    """``[u0, v0, u1, v1]`` of the model's vertices and antenna tips projected at ``pose`` by
    ``camera`` (with its distortion, if any), clipped to an image of ``shape (H, W)``; ``None``
    when nothing is in front."""
    pts = np.asarray(model.vertices, float)
    if len(model.antennas):
        pts = np.concatenate([pts, np.asarray(model.antenna_points, float).reshape(-1, 3)])
    cam = np.asarray(pose.apply(pts))
    front = cam[:, 2] > 1e-6
    if not front.any():
        return None
    uv = np.asarray(camera.project(cam))[front]
    H, W = shape[:2]
    return np.r_[np.clip(uv.min(0), [0, 0], [W, H]), np.clip(uv.max(0), [0, 0], [W, H])]


def true_box(result, truth: Pose, model) -> np.ndarray | None:
    """``[u0, v0, u1, v1]`` of the model's vertices and antenna tips projected at ``truth`` in the
    undistorted image of ``result`` (clipped to it, :func:`model_box`); ``None`` when nothing is
    in front."""
    det = result.detection
    if det.image is None:
        return None
    return model_box(model, truth, det.camera, det.image.shape)


def stage_breakdown(
    result, truth: Pose, model, *, rotation_deg: float = 10.0, translation_m: float = 0.30
) -> dict:
    """Per-stage record of one image (module docstring): booleans for :data:`STAGES`, the ROI's
    IoU with the true box, and the number of poses each stage held."""
    truth = Pose(np.asarray(truth.R, float), np.asarray(truth.t, float))
    tr = result.trace or {}
    box = true_box(result, truth, model)
    iou = 0.0 if result.roi is None or box is None else box_iou(np.asarray(result.roi, float), box)
    out = {"roi_iou": float(iou), "roi_ok": bool(iou >= 0.5)}
    tol = dict(rotation_deg=rotation_deg, translation_m=translation_m)
    if "hypotheses" in tr:
        R, t, ok = tr["hypotheses"]
        fin = ok & np.all(np.isfinite(t), axis=1)
        out["hypotheses"] = int(fin.sum())
        out["hypothesis_close"] = bool(np.any(_close(R[fin], t[fin], truth, **tol)))
    if "shortlist" in tr:
        out["shortlist_close"] = bool(np.any(_close(*tr["shortlist"], truth, **tol)))
    for key, name in (("candidates", "candidate_close"), ("refined", "refined_close")):
        if key in tr:
            out[name] = bool(np.any(_close(*_stack(tr[key]), truth, **tol)))
    if "refined" in tr and "chosen" in tr:
        p = tr["refined"][tr["chosen"]]
        out["first"] = bool(_close(*_stack([p]), truth, **tol)[0])
    out["success"] = result.pose is not None and bool(
        _close(*_stack([result.pose]), truth, **tol)[0]
    )
    for s in STAGES:
        out.setdefault(s, False)
    return out


def stage_counts(records: list[dict]) -> dict:
    """How many of ``records`` (:func:`stage_breakdown`) pass each stage, and how many pass every
    stage up to it (the funnel)."""
    n = len(records)
    alive = [True] * n
    out = {"images": n}
    for s in STAGES:
        out[s] = sum(bool(r.get(s)) for r in records)
        alive = [a and bool(r.get(s)) for a, r in zip(alive, records, strict=True)]
        out[f"{s}_cumulative"] = sum(alive)
    return out
