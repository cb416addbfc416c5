"""The region of interest and the coarse range alone on labelled SPEED+ images.

    python bench/monocular_roi.py DIR [--out roi.json] [--crops FOLDER]

Runs only the image processing (:func:`jaxpose.vision.features.detect`, with the pipeline's
characteristic length) on every labelled image of ``DIR`` (a SPEED+ root or a folder with
``labels.csv``) and reports per image: the ROI's kind (silhouette, gradient, cluster), its IoU
with the true box (the model's vertices and antenna tips projected at the label in the
undistorted image, clipped to it: the definition of
:func:`jaxpose.pipelines.monocular.diagnose.model_box`), the coarse range over the label's, which
image sides the ROI reaches (``roi_cut``) and the CPU time of ``detect``. The summary counts ROI
right (IoU >= 0.5) and coarse range within 20%. ``--crops`` writes a quarter-size picture of
each image with the true box (green) and the ROI (red), for looking at the misses. For renders
use ``bench/monocular.py --roi-only``.

    python bench/monocular_roi.py DIR --given-roi

runs the whole monocular pipeline twice on every labelled image: as it is, and with the true box
(in the image as given, through the camera's distortion) as the caller's ``roi``
(:func:`jaxpose.pipelines.monocular.initialise_pose`), which replaces the ROI stage and turns the
silhouette terms off. It counts the successes of both runs, over all images and over those on
which the pipeline finds no silhouette (an Earth or other background behind the target): how
much a perfect localisation would give the later stages. With ``--no-silhouette`` the run with
the given box also searches no silhouette (``DetectionOptions(silhouette_roi=False)``): what the
silhouette terms give.

    python bench/monocular_roi.py --cut-study lightbox --images 40 --seed 11

renders ``--images`` images of a domain (``space``: black sky; ``lightbox``) whose targets lie
anywhere in the image at 3-6 m (``random_pose(margin=0)``: many cut by the frame) and counts, on
the images whose coarse range ``DetectionOptions.cut_range`` changes, how many are within 20%
of the truth with it and without it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from jaxpose.io import load_camera, load_image, load_speed_labels
from jaxpose.pipelines.monocular.diagnose import model_box
from jaxpose.pipelines.monocular.options import ROI_LENGTH_FACTOR
from jaxpose.vision.coarse import model_extents
from jaxpose.vision.features import DetectionOptions, detect
from jaxpose.vision.models import tango
from jaxpose.vision.roi import box_iou


def roi_kind(det) -> str | None:
    if det.roi is None:
        return None
    if det.roi_silhouette is not None:
        return "silhouette"
    return "gradient" if np.array_equal(det.roi, det.roi_gradient) else "cluster"


def cut_study(domain: str, images: int, seed: int) -> None:
    """``--cut-study``: the coarse range with and without ``cut_range`` on close, uncentred
    targets (see the module docstring)."""
    from dataclasses import replace

    from monocular import SPEEDPLUS_CAMERA as cam  # the SPEED+ camera, with distortion

    from jaxpose.vision.render import lightbox_scene, random_pose, render

    model = tango()
    extents = model_extents(model)
    L_C = model.characteristic_length * ROI_LENGTH_FACTOR
    rng = np.random.default_rng(seed)
    moved, within = 0, {False: 0, True: 0}
    for _ in range(images):
        pose = random_pose(rng, cam, range_m=(3.0, 6.0), margin=0.0)
        try:
            scene = lightbox_scene(model, rng) if domain == "lightbox" else {}
            r = render(model, pose, cam, rng=rng, **scene)
        except (AttributeError, ValueError):  # a pose the renderer cannot draw
            continue
        rng_true = float(np.linalg.norm(np.asarray(pose.t)))
        ratio = {}
        for on in (False, True):
            opts = replace(DetectionOptions(), cut_range=on)
            det = detect(r.image, cam, L_C, opts, extents=extents)
            ratio[on] = (
                None
                if det.coarse_t_cam is None
                else float(np.linalg.norm(det.coarse_t_cam)) / rng_true
            )
        if ratio[False] is None or abs(ratio[False] - ratio[True]) < 1e-9:
            continue
        moved += 1
        for on in (False, True):
            within[on] += abs(ratio[on] - 1) <= 0.2
    print(
        json.dumps(
            {
                "domain": domain,
                "images": images,
                "seed": seed,
                "moved_by_cut_range": moved,
                "within_20pct_without": within[False],
                "within_20pct_with": within[True],
            }
        )
    )


def given_roi_study(root: Path, silhouette: bool = True) -> None:
    """``--given-roi``: the pipeline with its own ROI and with the true box given (module
    docstring); one line per image and a JSON summary."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from jaxpose.core.metrics import success
    from jaxpose.pipelines.monocular import InitOptions, initialise_pose

    camera = load_camera(root / "camera.json")
    model = tango()
    given_opts = InitOptions(detection=DetectionOptions(silhouette_roi=silhouette))
    rows = []
    for lab in load_speed_labels(root):
        img = load_image(lab.image)
        own = initialise_pose(img, camera, model)
        box = model_box(model, lab.pose, camera, img.shape)  # the distorted image's pixels
        given = initialise_pose(img, camera, model, given_opts, roi=box)
        ok = [r.pose is not None and bool(success(r.pose, lab.pose)) for r in (own, given)]
        row = {
            "image": lab.image.name,
            "silhouette": own.detection.silhouette is not None,
            "success_own_roi": ok[0],
            "success_given_roi": ok[1],
            "confidence_own_roi": own.confidence,
            "confidence_given_roi": given.confidence,
        }
        rows.append(row)
        print(
            f"{row['image']:28s} {'silhouette' if row['silhouette'] else 'none':10s} own "
            f"{'ok' if ok[0] else '--'} ({own.confidence}) given {'ok' if ok[1] else '--'} "
            f"({given.confidence})",
            flush=True,
        )
    bare = [r for r in rows if not r["silhouette"]]
    summary = {
        "images": len(rows),
        "success_own_roi": sum(r["success_own_roi"] for r in rows),
        "success_given_roi": sum(r["success_given_roi"] for r in rows),
        "without_silhouette": len(bare),
        "without_silhouette_success_own_roi": sum(r["success_own_roi"] for r in bare),
        "without_silhouette_success_given_roi": sum(r["success_given_roi"] for r in bare),
        "high_given_roi": sum(r["confidence_given_roi"] == "high" for r in rows),
        "high_given_roi_right": sum(
            r["confidence_given_roi"] == "high" and r["success_given_roi"] for r in rows
        ),
    }
    summary["given_roi_silhouette_search"] = silhouette
    print(json.dumps(summary))


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("speedplus", nargs="?", help="SPEED+ root or a folder with labels.csv")
    ap.add_argument("--cut-study", choices=("space", "lightbox"), default=None)
    ap.add_argument("--images", type=int, default=40)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--out", help="write the summary and per-image records (JSON)")
    ap.add_argument("--crops", help="folder for pictures of the true box and the ROI")
    ap.add_argument(
        "--given-roi", action="store_true", help="the whole pipeline with the true box as roi"
    )
    ap.add_argument(
        "--no-silhouette", action="store_true", help="--given-roi: no silhouette with the box"
    )
    args = ap.parse_args()
    if args.given_roi and args.speedplus:
        given_roi_study(Path(args.speedplus), silhouette=not args.no_silhouette)
        return
    if args.cut_study:
        cut_study(args.cut_study, args.images, args.seed)
        return
    if not args.speedplus:
        ap.error("give a SPEED+ folder or --cut-study")
    root = Path(args.speedplus)
    camera = load_camera(root / "camera.json")
    model = tango()
    opts = DetectionOptions()
    extents = model_extents(model)
    rows = []
    for lab in load_speed_labels(root):
        img = load_image(lab.image)
        t0 = time.process_time()
        det = detect(
            img, camera, model.characteristic_length * ROI_LENGTH_FACTOR, opts, extents=extents
        )
        cpu = time.process_time() - t0
        box = model_box(model, lab.pose, det.camera, det.image.shape)
        rng = float(np.linalg.norm(np.asarray(lab.pose.t)))
        ratio = None if det.coarse_t_cam is None else float(np.linalg.norm(det.coarse_t_cam)) / rng
        iou = 0.0 if det.roi is None or box is None else box_iou(det.roi, box)
        rows.append(
            {
                "image": lab.image.name,
                "domain": lab.domain,
                "roi_kind": roi_kind(det),
                "roi": None if det.roi is None else [float(x) for x in det.roi],
                "true_box": None if box is None else [float(x) for x in box],
                "roi_iou": iou,
                "roi_right": iou >= 0.5,
                "coarse_range_ratio": ratio,
                "coarse_within_20pct": ratio is not None and abs(ratio - 1) <= 0.2,
                "roi_cut": [bool(c) for c in det.roi_cut],
                "detect_cpu_s": cpu,
            }
        )
        if args.crops:
            import cv2

            Path(args.crops).mkdir(parents=True, exist_ok=True)
            pic = cv2.cvtColor(det.image, cv2.COLOR_GRAY2BGR)
            for b, c in ((box, (0, 255, 0)), (det.roi, (0, 0, 255))):
                if b is not None:
                    p = np.rint(b).astype(int)
                    cv2.rectangle(pic, (p[0], p[1]), (p[2], p[3]), c, 6)
            pic = cv2.resize(pic, (pic.shape[1] // 4, pic.shape[0] // 4))
            cv2.imwrite(str(Path(args.crops) / lab.image.name.replace(".jpg", ".png")), pic)
    summary = {
        "images": len(rows),
        "roi_right": sum(r["roi_right"] for r in rows),
        "coarse_within_20pct": sum(r["coarse_within_20pct"] for r in rows),
        "median_detect_cpu_s": float(np.median([r["detect_cpu_s"] for r in rows])),
    }
    for r in rows:
        ratio = r["coarse_range_ratio"]
        cut = "".join("x" if c else "." for c in r["roi_cut"])
        print(
            f"{r['image']:28s} {str(r['roi_kind']):10s} iou {r['roi_iou']:.2f} "
            f"range {ratio if ratio is None else round(ratio, 2)} cut {cut}"
        )
    print(json.dumps(summary))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps({"summary": summary, "per_image": rows}))


if __name__ == "__main__":
    main()
