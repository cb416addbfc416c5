"""Benchmark and evaluation of the monocular initialisation (Sharma, Ventura, D'Amico 2018) on
rendered Tango images and, with ``--speedplus DIR``, on labelled SPEED+ images.

    python bench/monocular.py --images 200 --out runs/monocular_rendered.json [--method ransac]

Renders ``--images`` random poses (uniform attitude, range 3-12 m, target centre in the central
half of the image, every other image with an Earth background) with the SPEED+ camera
(1920x1200, distortion), runs :func:`jaxpose.pipelines.monocular.initialise_pose` on each and
reports: success rate (|t err| < 0.30 m and rotation error < 10 deg), confidence classes and the
precision of each, ESA score, coarse range within 20 %, and the run time per image broken down
by stage (mean and median seconds), after one untimed warm-up image (compilation). Per-image
records (score, coverage, errors) are written to ``--out`` for the confidence calibration.
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
from tqdm import tqdm  # noqa: E402

from jaxpose import PinholeCamera  # noqa: E402
from jaxpose.commands import enable_compilation_cache  # noqa: E402
from jaxpose.core.metrics import esa_score, rotation_error, success  # noqa: E402
from jaxpose.io.software import software_versions  # noqa: E402
from jaxpose.pipelines.monocular import (  # noqa: E402
    ANTENNA_WEIGHT,
    ATTITUDE_GRID,
    CONFIDENCE,
    ORIENTATION_WEIGHT,
    PANEL_WEIGHT,
    REGION_WEIGHT,
    SILHOUETTE_WEIGHT,
    SPREAD_QUICK_WEIGHT,
    SPREAD_WEIGHT,
    TEMPLATE_SLOTS,
    InitOptions,
    initialise_pose,
)
from jaxpose.pipelines.monocular.diagnose import stage_breakdown, stage_counts  # noqa: E402
from jaxpose.pipelines.monocular.options import ROI_LENGTH_FACTOR  # noqa: E402
from jaxpose.vision.features import DetectionOptions  # noqa: E402
from jaxpose.vision.models import tango  # noqa: E402
from jaxpose.vision.render import lightbox_scene, random_pose, render  # noqa: E402
from jaxpose.vision.roi import box_iou  # noqa: E402

SPEEDPLUS_CAMERA = PinholeCamera(
    2988.5795163815555,
    2988.3401159176124,
    960.0,
    600.0,
    [
        -0.22383016606510672,
        0.5140979708910638,
        -0.0006649961199834066,
        -0.00021404771667484594,
        -0.13124227429077406,
    ],
    width=1920,
    height=1200,
)


def true_pose_score(res, pose, model, opts) -> float:
    """Score (``l_ROI`` units) that the pipeline's ranking gives the true pose after the same
    edge fit as the hypotheses (from the truth): below ``res.score`` when the ranking would
    prefer the truth to the chosen pose."""
    from jaxpose.pipelines.monocular.fit import _chamfer_fit
    from jaxpose.pipelines.monocular.scene import _edge_scene
    from jaxpose.pipelines.monocular.score import _chamfer
    from jaxpose.vision.roi import roi_diagonal

    sc = _edge_scene(res.detection, model, opts)
    R0, t0 = jnp.asarray(np.asarray(pose.R)), jnp.asarray(np.asarray(pose.t))
    Rf, tf = _chamfer_fit(R0, t0, sc, steps=12)
    return float(_chamfer(Rf, tf, sc)[0]) / roi_diagonal(res.detection.roi)


def spread_with_background(res, model) -> float | None:
    """The face-shading spread at the returned pose with the background as one more label
    (``_face_spread(..., background=True)``; a diagnostic for the confidence calibration)."""
    from jaxpose.pipelines.monocular.scene import _edge_scene, _with_shading
    from jaxpose.pipelines.monocular.score import _jit_face_spread

    if res.pose is None or res.detection is None or res.detection.roi is None:
        return None
    sc = _edge_scene(res.detection, model, InitOptions())
    if sc.face_poly is None:
        return None
    sc = _with_shading(sc, res.detection)
    R, t = jnp.asarray(np.asarray(res.pose.R)), jnp.asarray(np.asarray(res.pose.t))
    return float(_jit_face_spread()(R, t, sc, False, True))


def range_evidence(res) -> dict:
    """Evidence for the confidence class from the ROI: ``range_agreement`` (the absolute log
    ratio of the pose's range to the ROI's coarse range; ``None`` without a pose), ``roi_cut``
    (the ROI reaches the frame), ``silhouette_iou`` and ``e2d_px`` over ``l_ROI``."""
    from jaxpose.vision.roi import roi_diagonal

    agree = None
    if res.pose is not None and res.coarse_t_cam is not None:
        r_pose = float(np.linalg.norm(np.asarray(res.pose.t)))
        r_coarse = float(np.linalg.norm(np.asarray(res.coarse_t_cam)))
        if r_pose > 0 and r_coarse > 0:
            agree = abs(float(np.log(r_pose / r_coarse)))
    det = res.detection
    e2d = res.reprojection_error_px
    return {
        "range_agreement": agree,
        "roi_cut": bool(det is not None and any(det.roi_cut)),
        "silhouette_iou": res.silhouette_iou,
        "e2d_rel": None
        if res.roi is None or not np.isfinite(e2d)
        else float(e2d) / roi_diagonal(res.roi),
    }


def _mean(values) -> float | None:
    """Mean of a list, ``None`` when empty (a domain without images of that kind)."""
    return float(np.mean(values)) if values else None


def _roi_row(r, camera, model, detection, earth, cover) -> dict:
    """Per-image record of the image processing alone (``--roi-only``)."""
    from jaxpose.vision.coarse import model_extents
    from jaxpose.vision.features import detect
    from jaxpose.vision.roi import roi_diagonal

    t0 = time.perf_counter()
    # the pipeline's characteristic length and extents (initialise_pose): the pipeline's range
    L_C = model.characteristic_length * ROI_LENGTH_FACTOR
    det = detect(r.image, camera, L_C, detection, extents=model_extents(model))
    wall = time.perf_counter() - t0
    rng_true = float(np.linalg.norm(np.asarray(r.pose.t)))
    ratio = None if det.coarse_t_cam is None else float(np.linalg.norm(det.coarse_t_cam)) / rng_true
    kind = "roi" if det.roi_silhouette is None else "silhouette"
    if det.roi is not None and det.roi_silhouette is None and det.roi_gradient is not None:
        kind = "gradient" if np.array_equal(det.roi, det.roi_gradient) else "cluster"
    return {
        "earth": earth,
        "cover": cover,
        "range_m": rng_true,
        "coarse_range_ratio": ratio,
        "coarse_within_20pct": ratio is not None and abs(ratio - 1) <= 0.2,
        "roi_kind": kind if det.roi is not None else None,
        "roi_over_true_diagonal": None
        if det.roi is None
        else roi_diagonal(det.roi) / roi_diagonal(r.roi),
        "roi_iou": 0.0 if det.roi is None else box_iou(det.roi, r.roi),
        "roi_cut": [bool(c) for c in det.roi_cut],
        "detect_s": wall,
    }


def _roi_summary(rows, args) -> None:
    by_cover = {}
    for r in rows:
        key = (r["cover"] or "earth") if r["earth"] else "no-earth"
        by_cover.setdefault(key, []).append(r)
    summary = {
        "images": len(rows),
        "domain": args.domain,
        "seed": args.seed,
        "coarse_range_within_20pct": _mean([r["coarse_within_20pct"] for r in rows]),
        "coarse_range_within_20pct_by_background": {
            k: _mean([r["coarse_within_20pct"] for r in v]) for k, v in sorted(by_cover.items())
        },
        "roi_iou_at_least_half": _mean([r["roi_iou"] >= 0.5 for r in rows]),
        "roi_kinds": {
            str(k): sum(r["roi_kind"] == k for r in rows)
            for k in sorted({str(r["roi_kind"]) for r in rows})
        },
        "median_detect_s": float(np.median([r["detect_s"] for r in rows])),
    }
    summary["software"] = software_versions()
    print(json.dumps(summary))  # the last line: one JSON line
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps({"summary": summary, "per_image": rows}))


def _speedplus(args, model, opts) -> None:
    """``--speedplus DIR``: the SPEED+ evaluation (per domain), with ``--stages`` the breakdown."""
    from jaxpose.studies.speedplus import evaluate_speedplus

    def hook(label, result, row):
        if args.stages:
            row["stages"] = stage_breakdown(result, label.pose, model)
        row["score"], row["coverage"] = result.score, result.coverage
        row["face_spread"] = result.face_spread
        row["face_spread_bg"] = spread_with_background(result, model)
        row["timings"] = result.timings
        row.update(range_evidence(result))

    out = evaluate_speedplus(args.speedplus, limit=None, model=model, options=opts, on_result=hook)
    rows = out["per_image"]
    if args.stages:
        out["stages"] = stage_counts([r["stages"] for r in rows if "stages" in r])
        for dom in out["per_domain"]:
            out["per_domain"][dom]["stages"] = stage_counts(
                [r["stages"] for r in rows if "stages" in r and r["domain"] == dom]
            )
    stages = sorted({k for r in rows for k in r.get("timings", {})})
    out["stage_median_s"] = {
        s: float(np.median([r["timings"].get(s, 0.0) for r in rows if "timings" in r]))
        for s in stages
    }
    print(json.dumps({k: v for k, v in out.items() if k != "per_image"}))  # one JSON line
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(out, default=_json_default))


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(type(x))


def main(argv: list[str] | None = None) -> int:
    """Run the bench on the command line ``argv`` (default ``sys.argv[1:]``); 0 when it ran."""
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--images", type=int, default=200)
    ap.add_argument("--seed", type=int, default=2018)
    ap.add_argument("--method", choices=("svd", "ransac"), default="svd")
    ap.add_argument("--detector", choices=("hough", "lsd"), default="hough")
    ap.add_argument(
        "--domain",
        choices=("space", "lightbox", "lightbox-earth"),
        default="space",
        help="space: black sky, every other image over the Earth; lightbox: grey noisy "
        "background, faint shadowed faces, saturated lit faces, MLI blanket creases "
        "(jaxpose.vision.render.lightbox_scene), a development domain like the SPEED+ photographs; "
        "lightbox-earth: the same over an Earth of "
        "photographic contrast (bright sharp clouds), its limb crossing the image in even images, "
        "filling it in odd ones (lightbox_scene(earth=...))",
    )
    ap.add_argument(
        "--true-score",
        action="store_true",
        help="also record the chamfer score of the true pose after the edge fit from the truth "
        "(true_score, l_ROI units; diagnosis: does the score prefer the truth?)",
    )
    ap.add_argument(
        "--roi-only",
        action="store_true",
        help="run only the image processing (jaxpose.vision.features.detect) and report the "
        "coarse range (within 20%%, ratio to the truth) and the ROI diagonal over the true box's",
    )
    ap.add_argument(
        "--antenna-weight",
        type=float,
        default=ANTENNA_WEIGHT,
        help="weight of the antenna term in the ranking (0: off; ablation)",
    )
    ap.add_argument(
        "--region-weight",
        type=float,
        default=REGION_WEIGHT,
        help="weight of the region term in the ranking (0: off; ablation)",
    )
    ap.add_argument(
        "--silhouette-weight",
        type=float,
        default=SILHOUETTE_WEIGHT,
        help="weight of the silhouette term in the ranking (0: off; ablation)",
    )
    ap.add_argument(
        "--orientation-weight",
        type=float,
        default=ORIENTATION_WEIGHT,
        help="weight of the gradient-orientation (LINE-2D) term in the ranking (0: off)",
    )
    ap.add_argument(
        "--panel-weight",
        type=float,
        default=PANEL_WEIGHT,
        help="weight of the solar-panel (cell lines) term in the ranking (0: off)",
    )
    ap.add_argument(
        "--spread-weight",
        type=float,
        default=SPREAD_WEIGHT,
        help="weight of the face-shading spread in the ranking (0: off)",
    )
    ap.add_argument(
        "--spread-quick-weight",
        type=float,
        default=SPREAD_QUICK_WEIGHT,
        help="weight of the face-shading spread in the quick score (0: off)",
    )
    ap.add_argument(
        "--grid-on-roi",
        action="store_true",
        help="place the attitude grid on the ROI when the image has no silhouette "
        "(InitOptions.grid_without_silhouette; off by default)",
    )
    ap.add_argument(
        "--attitude-grid",
        type=int,
        default=ATTITUDE_GRID,
        help="attitudes placed on the silhouette when the image has one (0: off)",
    )
    ap.add_argument(
        "--template-slots",
        type=int,
        default=TEMPLATE_SLOTS,
        help="shortlist places for the LINE-2D template search over the attitude grid "
        "(InitOptions.template_slots; 0: off)",
    )
    ap.add_argument(
        "--cell-grid",
        type=float,
        nargs=3,
        default=None,
        metavar=("CELLS_U", "CELLS_V", "LINE"),
        help="lightbox domains: a solar-cell grid of CELLS_U x CELLS_V cells with gaps of "
        "radiance LINE on the panel (lightbox_scene(cell_grid=...); a stress test like the "
        "SPEED+ panel, e.g. 12 14 0.6)",
    )
    ap.add_argument(
        "--low-score",
        type=float,
        default=None,
        help="override the confidence class's low_score (l_ROI units; e.g. 1 returns every "
        "pose, to record score, coverage and silhouette IoU against success for calibration)",
    )
    ap.add_argument(
        "--stages",
        action="store_true",
        help="record where the right answer is lost, per image: ROI right (IoU >= 0.5 with the "
        "true box), a hypothesis within 10 deg and 0.3 m, the fitted shortlist, the top-k "
        "candidates, after refinement, ranked first (jaxpose.pipelines.monocular.diagnose)",
    )
    ap.add_argument(
        "--speedplus",
        default=None,
        metavar="DIR",
        help="run the labelled SPEED+ images of DIR (a SPEED+ root or a labels.csv folder) "
        "instead of renders (with --stages: the per-stage breakdown on them)",
    )
    ap.add_argument("--out", default=None, help="write the summary and per-image records (JSON)")
    args = ap.parse_args(argv)
    enable_compilation_cache()
    model, camera = tango(), SPEEDPLUS_CAMERA
    opts = InitOptions(
        method=args.method,
        detection=DetectionOptions(detector=args.detector),
        antenna_weight=args.antenna_weight,
        region_weight=args.region_weight,
        silhouette_weight=args.silhouette_weight,
        attitude_grid=args.attitude_grid,
        orientation_weight=args.orientation_weight,
        panel_weight=args.panel_weight,
        spread_weight=args.spread_weight,
        spread_quick_weight=args.spread_quick_weight,
        grid_without_silhouette=args.grid_on_roi,
        template_slots=args.template_slots,
        confidence=dict(
            CONFIDENCE, **({} if args.low_score is None else {"low_score": args.low_score})
        ),
        trace=args.stages,
    )
    if args.speedplus:
        _speedplus(args, model, opts)
        return 0
    rng = np.random.default_rng(args.seed)
    warm = render(model, random_pose(rng, camera), camera, rng=rng)
    t0 = time.perf_counter()
    if not args.roi_only:
        initialise_pose(warm.image, camera, model, opts)
    compile_s = time.perf_counter() - t0
    grid = None
    if args.cell_grid is not None:
        grid = (int(args.cell_grid[0]), int(args.cell_grid[1]), float(args.cell_grid[2]))
    rows = []
    for i in tqdm(range(args.images), desc=f"rendered ({args.method})", unit="img"):
        pose = random_pose(rng, camera, range_m=(3.0, 12.0))
        cover = None
        if args.domain == "lightbox":
            earth = False
            r = render(model, pose, camera, rng=rng, **lightbox_scene(model, rng, cell_grid=grid))
        elif args.domain == "lightbox-earth":
            earth = True
            cover = "partial" if i % 2 == 0 else "full"
            opts_i = lightbox_scene(
                model, rng, earth=cover, shape=(camera.height, camera.width), cell_grid=grid
            )
            r = render(model, pose, camera, rng=rng, **opts_i)
        else:
            earth = i % 2 == 1
            r = render(model, pose, camera, rng=rng, earth=earth)
        if args.roi_only:
            rows.append(_roi_row(r, camera, model, opts.detection, earth, cover))
            continue
        t0 = time.perf_counter()
        res = initialise_pose(r.image, camera, model, opts)
        wall = time.perf_counter() - t0
        rng_true = float(np.linalg.norm(pose.t))
        row = {
            "earth": earth,
            "range_m": rng_true,
            "confidence": res.confidence,
            "group": res.group_kind,
            "score": res.score,
            "coverage": res.coverage,
            "silhouette_iou": res.silhouette_iou,
            "orientation_agreement": res.orientation_agreement,
            "face_spread": res.face_spread,
            "face_spread_bg": spread_with_background(res, model),
            "margin": res.margin if res.margin is not None and np.isfinite(res.margin) else None,
            "e2d_px": res.reprojection_error_px if np.isfinite(res.reprojection_error_px) else None,
            **range_evidence(res),
            "runtime_s": wall,
            "timings": res.timings,
            "coarse_within_20pct": bool(
                res.coarse_t_cam is not None
                and abs(np.linalg.norm(res.coarse_t_cam) / rng_true - 1) <= 0.2
            ),
            "roi_length_ratio": None
            if res.roi is None
            else float(
                rng_true
                * np.hypot(res.roi[2] - res.roi[0], res.roi[3] - res.roi[1])
                / (camera.focal_px * model.characteristic_length)
            ),
            "success": False,
        }
        if args.stages:
            row["stages"] = stage_breakdown(res, pose, model)
        if args.true_score and res.roi is not None and res.confidence != "none":
            row["true_score"] = true_pose_score(res, pose, model, opts)
        if res.pose is not None:
            row["success"] = bool(success(res.pose, pose))
            row["translation_error_m"] = float(jnp.linalg.norm(res.pose.t - pose.t))
            row["rotation_error_deg"] = float(
                np.rad2deg(rotation_error(res.pose.R, jnp.asarray(pose.R)))
            )
            row["esa_score"] = float(esa_score(res.pose, pose)[0])
            row["range_ratio"] = float(jnp.linalg.norm(res.pose.t) / rng_true)
        rows.append(row)
    if args.roi_only:
        _roi_summary(rows, args)
        return 0
    n = len(rows)
    by = {
        c: [r for r in rows if r["confidence"] == c]
        for c in ("high", "low", "position-only", "none")
    }
    stages = sorted({k for r in rows for k in r["timings"]})
    summary = {
        "images": n,
        "domain": args.domain,
        "cell_grid": args.cell_grid,
        "method": args.method,
        "antenna_weight": args.antenna_weight,
        "region_weight": args.region_weight,
        "silhouette_weight": args.silhouette_weight,
        "attitude_grid": args.attitude_grid,
        "low_score": args.low_score,
        "detector": args.detector,
        "success_rate": sum(r["success"] for r in rows) / n,
        "success_rate_no_earth": _mean([r["success"] for r in rows if not r["earth"]]),
        "success_rate_earth": _mean([r["success"] for r in rows if r["earth"]]),
        "coarse_range_within_20pct_no_earth": _mean(
            [r["coarse_within_20pct"] for r in rows if not r["earth"]]
        ),
        "coarse_range_within_20pct_earth": _mean(
            [r["coarse_within_20pct"] for r in rows if r["earth"]]
        ),
        "confidence_counts": {c: len(v) for c, v in by.items()},
        "precision": {
            c: (sum(r["success"] for r in v) / len(v) if v else None) for c, v in by.items()
        },
        "esa_score_mean_posed": float(
            np.mean([r["esa_score"] for r in rows if "esa_score" in r] or [np.nan])
        ),
        "true_scores_better_than_chosen": sum(
            r.get("true_score", np.inf) < r["score"] for r in rows
        ),
        "true_scored": sum("true_score" in r for r in rows),
        "coarse_range_within_20pct": sum(r["coarse_within_20pct"] for r in rows) / n,
        "roi_length_ratio_median": float(
            np.median([r["roi_length_ratio"] for r in rows if r["roi_length_ratio"]])
        ),
        "stages": stage_counts([r["stages"] for r in rows]) if args.stages else None,
        "compile_and_first_run_s": compile_s,
        "median_runtime_s": float(np.median([r["runtime_s"] for r in rows])),
        "stage_mean_s": {
            s: float(np.mean([r["timings"].get(s, 0.0) for r in rows])) for s in stages
        },
        "stage_median_s": {
            s: float(np.median([r["timings"].get(s, 0.0) for r in rows])) for s in stages
        },
    }
    summary["software"] = software_versions()
    print(json.dumps(summary))  # the last line: one JSON line
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(
            json.dumps({"summary": summary, "per_image": rows}, default=_json_default)
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
