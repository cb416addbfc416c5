"""``jaxpose eval-speedplus DIR [--json] [--limit N]``: run the monocular initialisation on every
labelled image of a SPEED+ folder (``DIR/labels.csv``, ``DIR/camera.json``) and score it.

The first image is run once before timing (compilation); ``median_runtime_s`` is the median
wall time of :func:`~jaxpose.pipelines.monocular.initialise_pose` per image after that.
"""

from __future__ import annotations

import json
import time


def add_arguments(parser) -> None:
    parser.add_argument("directory", help="folder with labels.csv, camera.json and the images")
    parser.add_argument(
        "--json", action="store_true", help="print the summary as JSON on the last line"
    )
    parser.add_argument("--limit", type=int, default=None, help="only the first N images")
    parser.add_argument("--model", default="tango", help="'tango', a model .json or a mesh")
    parser.add_argument("--method", choices=("svd", "ransac"), default="svd")
    parser.add_argument("--detector", choices=("hough", "lsd"), default="hough")


def evaluate(
    directory, *, limit=None, model="tango", method="svd", detector="hough", progress=True
) -> dict:
    """The evaluation as a dict (the fields of ``--json``)."""
    from pathlib import Path

    import jax.numpy as jnp
    import numpy as np
    from tqdm import tqdm

    from jaxpose.core.geometry import Pose
    from jaxpose.core.metrics import esa_score, rotation_error, success
    from jaxpose.io import load_camera, load_speed_labels
    from jaxpose.pipelines.monocular import InitOptions, initialise_pose, load_image
    from jaxpose.vision.features import DetectionOptions
    from jaxpose.vision.models import load_model

    directory = Path(directory)
    camera = load_camera(directory / "camera.json")
    labels = load_speed_labels(directory)
    if limit is not None:
        if limit < 1:
            raise ValueError(f"--limit must be at least 1; got {limit}")
        labels = labels[:limit]
    if not labels:
        raise ValueError(f"{directory / 'labels.csv'} lists no image")
    mdl = load_model(model)
    opts = InitOptions(method=method, detection=DetectionOptions(detector=detector))
    initialise_pose(load_image(labels[0].image), camera, mdl, opts)  # compile (not timed)
    rows = []
    for lab in tqdm(labels, desc="eval-speedplus", disable=not progress, unit="img"):
        row = {"image": lab.image.name, "domain": lab.domain}
        try:
            image = load_image(lab.image)
        except ValueError as err:
            rows.append(row | {"confidence": "error", "message": str(err), "success": False})
            continue
        t0 = time.perf_counter()
        res = initialise_pose(image, camera, mdl, opts)
        row["runtime_s"] = time.perf_counter() - t0
        truth = Pose(jnp.asarray(np.asarray(lab.pose.R)), jnp.asarray(np.asarray(lab.pose.t)))
        rng_true = float(np.linalg.norm(np.asarray(truth.t)))
        row["confidence"] = res.confidence
        row["group"] = res.group_kind
        row["range_true_m"] = rng_true
        row["coarse_range_m"] = (
            None if res.coarse_t_cam is None else float(np.linalg.norm(res.coarse_t_cam))
        )
        row["coarse_within_20pct"] = bool(
            row["coarse_range_m"] is not None and abs(row["coarse_range_m"] / rng_true - 1) <= 0.2
        )
        row["reprojection_error_px"] = res.to_json()["reprojection_error_px"]
        row["silhouette_iou"] = res.silhouette_iou  # None without a silhouette (Earth behind)
        if res.pose is not None:
            row["translation_error_m"] = float(jnp.linalg.norm(res.pose.t - truth.t))
            row["rotation_error_deg"] = float(np.rad2deg(rotation_error(res.pose.R, truth.R)))
            row["esa_score"] = float(esa_score(res.pose, truth)[0])
            row["success"] = bool(success(res.pose, truth))
        else:
            row["success"] = False
            # ESA score of a position-only answer: the coarse position and an identity attitude.
            if res.coarse_t_cam is not None:
                guess = Pose(jnp.eye(3), jnp.asarray(res.coarse_t_cam))
                row["esa_score"] = float(esa_score(guess, truth)[0])
        rows.append(row)
    n = len(rows)
    high = [r for r in rows if r["confidence"] == "high"]
    times = [r["runtime_s"] for r in rows if "runtime_s" in r]
    esa = [r["esa_score"] for r in rows if "esa_score" in r]
    return {
        "images": n,
        "success_rate": sum(r["success"] for r in rows) / n,
        "high_confidence": len(high),
        "high_precision": (sum(r["success"] for r in high) / len(high)) if high else None,
        "esa_score_mean": float(np.mean(esa)) if esa else None,
        "coarse_range_within_20pct": sum(r.get("coarse_within_20pct", False) for r in rows) / n,
        "median_runtime_s": float(np.median(times)) if times else None,
        "per_image": rows,
    }


def _fmt(x, spec):
    return "-" if x is None else format(x, spec)


def run(args) -> int:
    from jaxpose.commands import enable_compilation_cache

    enable_compilation_cache()
    out = evaluate(
        args.directory,
        limit=args.limit,
        model=args.model,
        method=args.method,
        detector=args.detector,
    )
    row = "{:28s} {:9s} {:13s} {:>7s} {:>8s} {:>6s} {:>6s} {:>6s} {}"
    print(
        row.format("image", "domain", "conf", "E_T m", "E_R deg", "range", "coarse", "time s", "ok")
    )
    for r in out["per_image"]:
        cells = (
            r["image"],
            r["domain"],
            r["confidence"],
            _fmt(r.get("translation_error_m"), "7.3f"),
            _fmt(r.get("rotation_error_deg"), "8.2f"),
            _fmt(r.get("range_true_m"), "6.2f"),
            _fmt(r.get("coarse_range_m"), "6.2f"),
            _fmt(r.get("runtime_s"), "6.2f"),
            "yes" if r["success"] else "no",
        )
        print(row.format(*cells))
    print(
        f"success {out['success_rate']:.0%}, high confidence {out['high_confidence']} "
        f"(precision {_fmt(out['high_precision'], '.0%')}), "
        f"ESA score {_fmt(out['esa_score_mean'], '.3f')}, "
        f"coarse range within 20% {out['coarse_range_within_20pct']:.0%}, "
        f"median {_fmt(out['median_runtime_s'], '.2f')} s"
    )
    if args.json:
        print(json.dumps(out))
    return 0
