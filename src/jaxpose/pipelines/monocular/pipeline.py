"""The monocular pipeline: :func:`initialise_pose` runs the stages in order (detect, hypothesise,
score, fit, re-match, classify)."""

from __future__ import annotations

import time

import jax.numpy as jnp
import numpy as np

from jaxpose.core._checks import check_fields
from jaxpose.core._compile import in_float64
from jaxpose.core.camera import PinholeCamera, as_camera
from jaxpose.pipelines.monocular.classify import check_thresholds, classify
from jaxpose.pipelines.monocular.hypothesise import _ransac_candidates, _svd_candidates
from jaxpose.pipelines.monocular.options import ROI_LENGTH_FACTOR, InitOptions, InitResult
from jaxpose.pipelines.monocular.rematch import _e2d, _rematch_refine
from jaxpose.pipelines.monocular.scene import _as_jax, _edge_scene, _with_shading
from jaxpose.pipelines.monocular.score import (
    _jit_face_spread,
    _jit_orientation_term,
    _jit_silhouette_term,
    _score_poses,
)
from jaxpose.vision.coarse import model_extents
from jaxpose.vision.features import detect
from jaxpose.vision.image_maps import orientation_maps
from jaxpose.vision.models import WireframeModel, tango
from jaxpose.vision.render import visible_edges
from jaxpose.vision.roi import roi_diagonal

__all__ = ["initialise_pose"]


@in_float64
def initialise_pose(
    image: np.ndarray,
    camera: PinholeCamera | np.ndarray,
    model: WireframeModel | None = None,
    options: InitOptions | None = None,
    *,
    roi=None,
) -> InitResult:
    """Pose of the target from one image with no prior (see the module docstring).

    ``camera``: the camera of ``image`` (a :class:`PinholeCamera`, or a ``3x3`` ``K`` without
    distortion); when it has an image size, ``image`` must be that size (``ValueError``
    otherwise: a transposed or resized image would give a confident wrong pose).

    ``roi``: optional ``[u0, v0, u1, v1]`` (pixels of ``image``), the target's box from elsewhere
    (an object detector, as two-stage SPEED+ methods use, or a previous frame):
    it replaces the detection's ROI stage (:func:`jaxpose.vision.features.detect`), so no
    silhouette is searched and the silhouette terms are off. Raises ``ValueError`` for a
    malformed box, one outside the image or one too small.

    Never raises for image *content* (black, saturated, noise, cut target): the answer is then a
    position-only or ``"none"`` result with a message. Raises ``ValueError`` for a wrong input type
    or shape, or an image smaller than 16 pixels.

    The pipeline runs in float64 whatever ``jax_enable_x64`` says outside (the result's arrays
    are float64): its ranking compares scores that differ in the fourth digit, and the
    confidence rule was calibrated in float64. In float32 the same 24 SPEED+ development images
    gave the same successes but two wrong answers classed ``"high"``.
    """
    model = tango() if model is None else model
    options = InitOptions() if options is None else options
    camera = as_camera(camera)
    if not isinstance(model, WireframeModel):
        raise ValueError(f"model must be a WireframeModel or None; got {type(model).__name__}")
    if not isinstance(options, InitOptions):
        raise ValueError(f"options must be an InitOptions or None; got {type(options).__name__}")
    if options.method not in ("svd", "ransac"):
        raise ValueError(f"method must be 'svd' or 'ransac'; got {options.method!r}")
    if options.rank_by not in ("chamfer", "e2d"):
        raise ValueError(f"rank_by must be 'chamfer' or 'e2d'; got {options.rank_by!r}")
    check_fields(  # a weight of 0, the grid's or the template slots' 0, turns that part off
        options,
        flags=("shortlist_fit", "grid_without_silhouette", "fit_by_length", "trace"),
        integers={
            "top_k": 1,
            "max_hypotheses": 1,
            "rematch_rounds": 0,
            "attitude_grid": 0,
            "template_slots": 0,
            "ransac_iterations": 1,
            "ransac_seed": 0,
        },
        positive=("fit_model_weight",),
        non_negative=(
            "region_weight",
            "antenna_weight",
            "silhouette_weight",
            "orientation_weight",
            "panel_weight",
            "spread_weight",
            "spread_quick_weight",
        ),
        optional=("ransac_iterations",),
    )
    if options.template_slots > 128:
        raise ValueError(
            f"InitOptions.template_slots must be at most 128 (the shortlist's places); "
            f"got {options.template_slots}"
        )
    check_thresholds(options.confidence)
    timings = {}
    trace = {} if options.trace else None
    t0 = time.perf_counter()
    L_C = model.characteristic_length * ROI_LENGTH_FACTOR
    det = detect(image, camera, L_C, options.detection, extents=model_extents(model), roi=roi)
    timings.update(det.timings)
    base = dict(
        pose=None,
        coarse_t_cam=det.coarse_t_cam,
        roi=det.roi,
        reprojection_error_px=np.inf,
        score=np.inf,
        coverage=0.0,
        detection=det,
        timings=timings,
        trace=trace,
    )
    if det.roi is None:
        return InitResult(confidence="none", message="no target found: no strong gradients", **base)
    if det.groups is None or len(det.segments) < 3:
        return InitResult(confidence="position-only", message="too few line segments", **base)
    cam = det.camera
    l_roi = roi_diagonal(det.roi)
    H, W = det.image.shape
    t1 = time.perf_counter()
    sc = _edge_scene(det, model, options)
    timings["distance_map_s"] = time.perf_counter() - t1

    t1 = time.perf_counter()
    if options.method == "ransac":
        cand = _ransac_candidates(det, model, options, cam, sc, trace)
        kind_used = "ransac"
    else:
        cand = _svd_candidates(det, model, options, cam, sc, trace)
        kind_used = cand[-1] if cand is not None else None
    timings["hypotheses_epnp_s"] = time.perf_counter() - t1
    if cand is None:
        return InitResult(confidence="position-only", message="no usable feature group", **base)
    poses, n_hyp, used = cand[0], cand[1], cand[2]

    # Refinement by re-matching visible model edges to detected segments.
    t1 = time.perf_counter()
    if trace is not None:
        trace["candidates"] = list(poses)
    poses = _rematch_refine(poses, det, model, cam, l_roi, options.rematch_rounds)
    timings["refine_rematch_s"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    key, score = _score_poses(poses, sc)
    t = np.stack([np.asarray(p.t) for p in poses])
    good = np.isfinite(score) & (t[:, 2] > 0)
    if not good.any():
        return InitResult(
            confidence="position-only", message="no pose in front of the camera", **base
        )
    best = int(np.argmin(np.where(good, key, np.inf)))
    if trace is not None:
        trace.update(refined=list(poses), keys=np.where(good, key, np.inf), chosen=best)
    pose = poses[best]
    vis = visible_edges(model, pose, cam, shape=(H, W), buffer_scale=0.25)
    e2d, coverage = _e2d(vis, det, l_roi)
    sil_iou = None
    if sc.sil_pts is not None:
        sil_iou = 1.0 - float(_jit_silhouette_term()(jnp.asarray(pose.R), jnp.asarray(pose.t), sc))
    # the orientation agreement is evidence for the confidence class even when its ranking
    # weight is 0 (then its maps are made here, for the final pose only)
    sc_ori = (
        sc
        if sc.ori is not None
        else sc._replace(
            **dict(
                zip(
                    ("ori", "ori_frame"), _as_jax(orientation_maps(det.image, det.roi)), strict=True
                )
            )
        )
    )
    pose_R, pose_t = jnp.asarray(pose.R), jnp.asarray(pose.t)
    ori = 1.0 - float(_jit_orientation_term()(pose_R, pose_t, sc_ori))
    margin = _margin(poses, np.where(good, key, np.inf), best) / l_roi
    spread = None  # evidence for the class whatever its ranking weight (None: no faces)
    if sc.face_poly is not None and len(model.faces):
        spread = float(_jit_face_spread()(pose_R, pose_t, _with_shading(sc, det)))
    timings["select_s"] = time.perf_counter() - t1
    s_rel = float(score[best]) / l_roi
    conf = classify(
        s_rel,
        coverage,
        options.confidence,
        orientation=ori,
        margin=margin,
        spread=spread,
        silhouette=sil_iou,
        range_agreement=_range_agreement(pose.t, det.coarse_t_cam),
    )
    timings["total_s"] = 0.0
    total = time.perf_counter() - t0
    timings = {k: v for k, v in timings.items() if k != "total_s"}
    timings["other_s"] = max(total - sum(timings.values()), 0.0)
    return InitResult(
        confidence=conf,
        pose=pose if conf != "position-only" else None,
        coarse_t_cam=det.coarse_t_cam,
        roi=det.roi,
        reprojection_error_px=e2d,
        score=s_rel,
        coverage=coverage,
        detection=det,
        group_kind=kind_used,
        hypotheses=n_hyp,
        message=""
        if conf != "position-only"
        else "pose rejected: the model does not fit the edges",
        timings=timings,
        trace=trace,
        projected=vis.segments,
        used_segments=used,
        silhouette_iou=sil_iou,
        orientation_agreement=ori,
        margin=margin,
        face_spread=spread,
    )


def _range_agreement(t, coarse_t) -> float | None:
    """``|log(||t|| / ||coarse_t||)|``: how far the pose's range is from the ROI's coarse range
    (eq. 6); ``None`` without a coarse position."""
    if coarse_t is None:
        return None
    r, rc = float(np.linalg.norm(np.asarray(t))), float(np.linalg.norm(np.asarray(coarse_t)))
    return abs(float(np.log(r / rc))) if r > 0 and rc > 0 else None


#: Candidates whose attitudes differ by more than this are distinct answers for the margin.
_DISTINCT_DEG = 10.0


def _margin(poses, key, best) -> float:
    """Ranking key of the best candidate whose attitude differs from the chosen one by more than
    ``_DISTINCT_DEG``, minus the chosen one's (pixels; ``inf`` when there is none)."""
    Rb = np.asarray(poses[best].R)
    alt = np.inf
    for i, p in enumerate(poses):
        c = (np.trace(np.asarray(p.R) @ Rb.T) - 1.0) / 2.0
        if np.isfinite(key[i]) and c < np.cos(np.deg2rad(_DISTINCT_DEG)):
            alt = min(alt, float(key[i]))
    return alt - float(key[best])
