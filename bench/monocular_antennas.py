"""Where the Tango model's antennas point, measured on labelled SPEED+ images.

    python bench/monocular_antennas.py DIR [--directions 20000] [--out antennas.json]

The built-in Tango wireframe (:func:`jaxpose.vision.models.wireframe.build_tango`) takes its
antenna tips from the SPEED keypoints 9-11, but the bases are not keypoints: they were put where
the antennas seemed to leave the body. This script measures each antenna's direction from the
images themselves. For every labelled image of ``DIR`` (a SPEED+ root or a folder with
``labels.csv``) it computes a thin-bar map of the crop around the labelled model (a pixel scores
when it is brighter, or darker, than both sides of it at twice the expected antenna width, across
the bar's direction from the Hessian, kept only where the structure is elongated and where it
continues along the bar), then, for
each antenna and each of ``--directions`` unit vectors ``d`` of the body frame (a Fibonacci
sphere), reads the map at the projections of ``tip + s d``, ``s`` from 3 to 18 cm, at the
labelled pose (through the camera's distortion). The direction whose mean response summed over
the images is highest is the measured one. Reported per antenna: the model's direction and the
measured one, the angle between them, the mean response along each, and the leave-one-out spread
(the measured direction with each image left out, its angle to the all-image one).

    python bench/monocular_antennas.py DIR --evaluate

also runs the SPEED+ evaluation (:func:`jaxpose.studies.speedplus.evaluate_speedplus`) with the
built-in model and with the model whose antenna bases are moved onto the measured directions
(each base where its line meets the panel's side: ``x = +-0.37`` m for the two antennas on the
``+y`` side, ``y = -0.385`` m for the third), and prints both summaries; ``--thin-bar-term``
makes the pipeline's antenna term read the thin-bar map above instead of its top-hat rod map
(:func:`jaxpose.vision.image_maps.rod_map`), ``--antenna-weight W`` sets
``InitOptions.antenna_weight``. The last line is one JSON line of the figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np

from jaxpose.io import load_camera, load_image, load_speed_labels
from jaxpose.vision.models import tango

#: Expected antenna width as a share of the labelled model's projected diagonal, and the range of
#: distances from the tip (metres) at which a direction is read.
WIDTH_SHARE = 0.01
SAMPLES_M = np.linspace(0.03, 0.18, 12)
WORK_SIDE = 512


def fibonacci_sphere(n: int) -> np.ndarray:
    """``(n, 3)`` unit vectors spread evenly over the sphere."""
    i = np.arange(n) + 0.5
    phi = np.arccos(1.0 - 2.0 * i / n)
    theta = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)


def thin_bar_map(gray: np.ndarray, box) -> tuple[np.ndarray, np.ndarray]:
    """Thin-bar response in ``[0, 1]`` of the crop around ``box`` (grown by 30%), resampled so
    that its longer side is ``WORK_SIDE``; returns the map and ``[u0, v0, scale]`` (image pixel
    ``(u, v)`` is map cell ``((u, v) - [u0, v0]) * scale``)."""
    u0, v0, u1, v1 = (float(x) for x in box)
    H, W = gray.shape
    g = 0.3 * max(u1 - u0, v1 - v0)
    a0, b0 = int(max(np.floor(u0 - g), 0)), int(max(np.floor(v0 - g), 0))
    a1, b1 = int(min(np.ceil(u1 + g), W)), int(min(np.ceil(v1 + g), H))
    k = WORK_SIDE / max(a1 - a0, b1 - b0, 1)
    w, h = max(int(round((a1 - a0) * k)), 1), max(int(round((b1 - b0) * k)), 1)
    img = cv2.resize(gray[b0:b1, a0:a1].astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    width = max(WIDTH_SHARE * np.hypot(u1 - u0, v1 - v0) * k, 1.0)
    sm = cv2.GaussianBlur(img, (0, 0), max(0.5 * width, 0.7))
    dxx = cv2.Sobel(sm, cv2.CV_32F, 2, 0, ksize=3)
    dyy = cv2.Sobel(sm, cv2.CV_32F, 0, 2, ksize=3)
    dxy = cv2.Sobel(sm, cv2.CV_32F, 1, 1, ksize=3)
    # the Hessian's eigenvector of the larger curvature in magnitude: across the bar (that of the
    # larger eigenvalue is across a dark bar and along a bright one)
    disc = np.sqrt((dxx - dyy) ** 2 + 4.0 * dxy**2)
    l1, l2 = 0.5 * (dxx + dyy + disc), 0.5 * (dxx + dyy - disc)
    theta = 0.5 * np.arctan2(2.0 * dxy, dxx - dyy) + np.where(
        np.abs(l2) > np.abs(l1), 0.5 * np.pi, 0.0
    )
    nx, ny = np.cos(theta).astype(np.float32), np.sin(theta).astype(np.float32)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    d = np.float32(2.0 * width)
    side_a = cv2.remap(
        sm, xx + d * nx, yy + d * ny, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
    )
    side_b = cv2.remap(
        sm, xx - d * nx, yy - d * ny, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
    )
    bright = sm - np.maximum(side_a, side_b)
    dark = np.minimum(side_a, side_b) - sm
    r = np.maximum(np.maximum(bright, dark), 0.0)
    a1, a2 = np.abs(l1), np.abs(l2)
    r = r * np.clip(1.0 - np.minimum(a1, a2) / np.maximum(np.maximum(a1, a2), 1e-6), 0.0, 1.0) ** 2
    # a bar keeps its response along its length, a blob does not: the mean over +-4 widths along
    # the bar (across the normal), capped by the pixel's own response
    r = r.astype(np.float32)
    along = np.zeros_like(r)
    for s in np.linspace(-4.0 * width, 4.0 * width, 7, dtype=np.float32):
        along += cv2.remap(
            r, xx - s * ny, yy + s * nx, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT
        )
    r = np.minimum(along / 7.0, r)
    top = float(np.percentile(r, 99.5))
    out = np.clip(r / top, 0.0, 1.0) if top > 0 else np.zeros_like(r)
    return out.astype(np.float32), np.array([a0 - 0.5 + 0.5 / k, b0 - 0.5 + 0.5 / k, k])


def direction_scores(gray, R, t, camera, model, dirs) -> np.ndarray:
    """``(A, n)``: mean thin-bar response along ``tip + s d`` for every antenna and direction."""
    K, dist = np.asarray(camera.K, float), np.asarray(camera.dist, float)
    rvec = cv2.Rodrigues(np.asarray(R, float))[0]
    t = np.asarray(t, float)
    V = np.asarray(model.vertices, float)
    uv, _ = cv2.projectPoints(V, rvec, t, K, dist)
    uv = uv[:, 0]
    box = (*uv.min(0), *uv.max(0))
    bar, frame = thin_bar_map(gray, box)
    out = []
    for _, tip in model.antennas:
        pts = V[tip][None, None] + SAMPLES_M[None, :, None] * dirs[:, None, :]
        q, _ = cv2.projectPoints(pts.reshape(-1, 3), rvec, t, K, dist)
        q = ((q[:, 0] - frame[:2]) * frame[2]).astype(np.float32)
        shape = (len(dirs), len(SAMPLES_M))
        val = cv2.remap(
            bar,
            q[:, 0].reshape(shape),
            q[:, 1].reshape(shape),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
        )
        out.append(val.mean(1))
    return np.array(out)


def moved_bases(model, directions: np.ndarray) -> np.ndarray:
    """The antenna bases on the measured directions: where each line from its tip meets the
    panel's side (``x = +-0.37`` for an antenna whose tip lies beyond it in x, else
    ``y = +-0.385``)."""
    V = np.asarray(model.vertices, float)
    panel = np.abs(V[model.keypoints[:4]]).max(0)  # half-sizes of the panel (0.37, 0.385)
    bases = []
    for (_, tip), d in zip(model.antennas, directions, strict=True):
        p = V[tip]
        axis = 0 if abs(p[0]) > panel[0] + 1e-6 else 1
        s = (abs(p[axis]) - panel[axis]) / max(abs(d[axis]), 1e-9)
        bases.append(p + s * d)
    return np.array(bases)


def thin_bar_rod_map(image: np.ndarray, roi) -> tuple[np.ndarray, np.ndarray]:
    """:func:`thin_bar_map` in the form of :func:`jaxpose.vision.image_maps.rod_map` (``(S, S)``
    zero-padded map, ``[u0, v0, scale]``), for ``--thin-bar-term``."""
    from jaxpose.vision.image_maps import ROD_SIDE

    bar, frame = thin_bar_map(np.asarray(image, np.float32), roi)
    f = ROD_SIDE / max(bar.shape)
    small = cv2.resize(bar, None, fx=f, fy=f, interpolation=cv2.INTER_AREA)[:ROD_SIDE, :ROD_SIDE]
    out = np.zeros((ROD_SIDE, ROD_SIDE))
    out[: small.shape[0], : small.shape[1]] = np.clip(
        small / max(np.percentile(small, 99.5), 1e-6), 0, 1
    )
    k = frame[2] * f
    origin = (
        frame[:2] + 0.5 - 0.5 / frame[2] - 0.5 + 0.5 / k
    )  # the same pixel grid, cells 1/f wider
    return out, np.array([*origin, k])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("root", type=Path, help="SPEED+ root or a folder with labels.csv")
    ap.add_argument("--directions", type=int, default=20000)
    ap.add_argument(
        "--evaluate", action="store_true", help="run the SPEED+ evaluation with both models"
    )
    ap.add_argument(
        "--thin-bar-term",
        action="store_true",
        help="with --evaluate, the antenna term reads the thin-bar map, not the top-hat rod map",
    )
    ap.add_argument(
        "--antenna-weight",
        type=float,
        default=None,
        help="with --evaluate: InitOptions.antenna_weight",
    )
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    if not 100 <= args.directions <= 30000:  # cv2.remap reads at most 32767 rows
        ap.error(f"--directions must be in [100, 30000]; got {args.directions}")

    try:
        camera = load_camera(args.root / "camera.json")
        labels = load_speed_labels(args.root)
    except (OSError, ValueError) as err:
        ap.error(str(err))
    model = tango()
    V = np.asarray(model.vertices, float)
    dirs = fibonacci_sphere(args.directions)
    per_image = []
    for lab in labels:
        img = load_image(lab.image)
        gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
        per_image.append(direction_scores(gray, lab.pose.R, lab.pose.t, camera, model, dirs))
    S = np.stack(per_image)  # (images, A, n)
    total = S.sum(0)
    rows, measured = [], []
    for a, (base, tip) in enumerate(model.antennas):
        cur = (V[base] - V[tip]) / np.linalg.norm(V[base] - V[tip])
        best = dirs[int(np.argmax(total[a]))]
        loo = [
            float(
                np.degrees(
                    np.arccos(np.clip(dirs[int(np.argmax(total[a] - S[i, a]))] @ best, -1, 1))
                )
            )
            for i in range(len(S))
        ]
        near = int(np.argmax(dirs @ cur))
        rows.append(
            {
                "antenna": a,
                "model_direction": np.round(cur, 3).tolist(),
                "measured_direction": np.round(best, 3).tolist(),
                "angle_deg": round(float(np.degrees(np.arccos(np.clip(best @ cur, -1, 1)))), 1),
                "response_model": round(float(total[a, near] / len(S)), 3),
                "response_measured": round(float(total[a].max() / len(S)), 3),
                "loo_max_deg": round(max(loo), 1),
                "loo_median_deg": round(float(np.median(loo)), 1),
            }
        )
        measured.append(best)
    print(f"{len(S)} labelled images of {args.root}")
    head = "| antenna | model direction | measured | angle deg | response model / measured"
    print(head + " | LOO spread max / median deg |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['antenna']} | {r['model_direction']} | {r['measured_direction']} "
            f"| {r['angle_deg']} | {r['response_model']} / {r['response_measured']} "
            f"| {r['loo_max_deg']} / {r['loo_median_deg']} |"
        )
    bases = moved_bases(model, np.array(measured))
    print("bases on the measured directions (m):", np.round(bases, 3).tolist())
    result = {"images": len(S), "antennas": rows, "moved_bases_m": np.round(bases, 4).tolist()}
    if args.evaluate:
        import jax

        jax.config.update("jax_enable_x64", True)
        from jaxpose.pipelines.monocular import InitOptions
        from jaxpose.studies.speedplus import evaluate_speedplus
        from jaxpose.vision import image_maps

        if args.thin_bar_term:  # measured here only: the package keeps its top-hat rod map
            image_maps.rod_map = thin_bar_rod_map
        opts = InitOptions()
        if args.antenna_weight is not None:
            opts = dataclasses.replace(opts, antenna_weight=args.antenna_weight)

        Vm = V.copy()
        Vm[model.antennas[:, 0]] = bases
        moved = dataclasses.replace(model, vertices=Vm)
        keys = (
            "success_rate",
            "high_confidence",
            "high_precision",
            "esa_score_mean",
            "median_runtime_s",
        )
        for name, mdl in (("built-in", model), ("measured antennas", moved)):
            ev = evaluate_speedplus(args.root, model=mdl, options=opts, progress=False)
            summary = {k: ev[k] for k in keys}
            summary["successes"] = [e["image"] for e in ev["per_image"] if e["success"]]
            print(name, json.dumps(summary))
            result[name] = summary
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))
    print(json.dumps(result))


if __name__ == "__main__":
    main()
