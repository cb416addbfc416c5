"""Two silhouettes the monocular pipeline does not use, measured on labelled images.

    python bench/monocular_silhouette_probes.py DIR --grabcut [--out F]
    python bench/monocular_silhouette_probes.py DIR --panel-unknown [--placement body|both]
    python bench/monocular_silhouette_probes.py --panel-unknown \
        --renders "--images 30 --domain lightbox --seed 7"     # arguments of bench/monocular.py

``DIR`` is a SPEED+ folder (:func:`jaxpose.io.load_speed_labels`). Each probe swaps one piece of
the pipeline for the run (restored afterwards) and runs
:func:`~jaxpose.pipelines.monocular.initialise_pose` on every image:

- ``--grabcut``: over a structured background (the Earth) the pipeline finds no silhouette, and
  its silhouette terms and the attitude grid are off there. Here such an image gets one from
  GrabCut (``cv2.grabCut``, Rother, Kolmogorov and Blake 2004: colour models of foreground and
  background and a graph cut, initialised with a rectangle) run at a quarter of the resolution
  inside the *labelled* box grown by 5% (the box is also given as the ROI): the upper bound of a
  perfect region of interest. Its largest component, holes filled, is the silhouette; every
  silhouette stage then runs on it as on a dark sky. Images with a silhouette of their own keep
  it.
- ``--panel-unknown``: the top of the solar panel (face 0 of the built-in Tango: its cells) is
  as dark as the lightbox's background on many photographs, so the projected model at the true
  pose reaches outside the image's silhouette. In the silhouette term of the quick score and
  the ranking key, a cell covered by the panel's top alone counts as unknown: not as the
  model's extra area where the image has no silhouette, as intersection where it has. The
  confidence class keeps the IoU it was calibrated with. ``--placement body``: the attitude
  grid is also placed on the silhouette by the body's area alone; ``both``: each grid attitude
  placed both ways (twice the grid).

With ``--renders ARGS`` the panel probe runs ``bench/monocular.py ARGS`` (rendered images)
instead.

Development probes (their figures are in the docs' monocular evaluation page); one line per
image and a JSON summary line.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import cv2  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxpose.core.metrics import rotation_error, success  # noqa: E402
from jaxpose.io import load_camera, load_image, load_speed_labels  # noqa: E402
from jaxpose.pipelines.monocular import initialise_pose  # noqa: E402
from jaxpose.pipelines.monocular.diagnose import model_box  # noqa: E402
from jaxpose.vision.models import tango  # noqa: E402
from jaxpose.vision.undistort import undistort_box  # noqa: E402

FACTOR = 4  # the silhouette's shrink factor (jaxpose.vision.features.SILHOUETTE_FACTOR)


def grabcut_silhouette(gray, box, *, factor: int = FACTOR, grow: float = 0.05, iterations=5):
    """GrabCut's foreground inside ``box`` ``[u0, v0, u1, v1]`` (pixels of ``gray (H, W)``)
    grown by ``grow`` of its larger side: ``(H // factor, W // factor)`` uint8 in {0, 1}, the
    largest component with its holes filled, or ``None`` when nothing is foreground."""
    H, W = gray.shape
    small = cv2.resize(
        np.asarray(gray, np.float32), (W // factor, H // factor), interpolation=cv2.INTER_AREA
    )
    bgr = cv2.cvtColor(np.clip(small, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    u0, v0, u1, v1 = np.asarray(box, float) / factor
    g = grow * max(u1 - u0, v1 - v0)
    u0, v0 = max(0, int(u0 - g)), max(0, int(v0 - g))
    u1, v1 = min(bgr.shape[1] - 1, int(u1 + g)), min(bgr.shape[0] - 1, int(v1 + g))
    if u1 - u0 < 2 or v1 - v0 < 2:
        return None
    mask = np.zeros(bgr.shape[:2], np.uint8)
    models = np.zeros((1, 65)), np.zeros((1, 65))
    cv2.grabCut(bgr, mask, (u0, v0, u1 - u0, v1 - v0), *models, iterations, cv2.GC_INIT_WITH_RECT)
    fg = ((mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)).astype(np.uint8)
    n, label, stats, _ = cv2.connectedComponentsWithStats(fg)
    if n <= 1:
        return None
    fg = (label == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8)
    n, label, stats, _ = cv2.connectedComponentsWithStats(1 - fg)
    for j in range(1, n):  # holes: background components that touch no image side
        x, y, w, h = stats[j, :4]
        if x > 0 and y > 0 and x + w < fg.shape[1] and y + h < fg.shape[0]:
            fg[label == j] = 1
    return fg


def iou_with_unknown(model, image, unknown):
    """Soft IoU ``sum min / sum max`` of the model's cells ``model`` and the image's ``image``
    (values in [0, 1]), the cells ``unknown`` (bool) counted as the model's only where the image
    has silhouette: there the model's excess over the image is not counted."""
    union = jnp.maximum(model, image) - unknown * jnp.maximum(model - image, 0.0)
    return jnp.sum(jnp.minimum(model, image)) / jnp.maximum(jnp.sum(union), 1e-9)


@contextlib.contextmanager
def _grabcut_patch(state):
    """``roi_from_silhouette`` and ``silhouette_mask`` of the detection: where the image has no
    silhouette of its own, GrabCut's in ``state["box"]`` (undistorted pixels)."""
    import jaxpose.vision.features as F

    own_box, own_mask = F.roi_from_silhouette, F.silhouette_mask

    def box_from(und, gradient=None):
        found = own_box(und, gradient=gradient)
        if found is not None:
            return found
        fg = grabcut_silhouette(und, state["box"])
        if fg is None:
            return None
        state["mask"] = fg
        ys, xs = np.nonzero(fg)
        return FACTOR * np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], float)

    def mask_from(und, box, factor=FACTOR, **kw):
        return state["mask"] if "mask" in state else own_mask(und, box, factor=factor, **kw)

    F.roi_from_silhouette, F.silhouette_mask = box_from, mask_from
    try:
        yield
    finally:
        F.roi_from_silhouette, F.silhouette_mask = own_box, own_mask


@contextlib.contextmanager
def _panel_patch(placement: str):
    """The silhouette term with the panel's top unknown (the class keeps its IoU), and the grid's
    placement by the body's area (``body``) or both ways (``both``)."""
    import jaxpose.pipelines.monocular.hypothesise as H
    import jaxpose.pipelines.monocular.pipeline as P
    import jaxpose.pipelines.monocular.score as S

    own = S._silhouette_term, P._jit_silhouette_term, H._place_on_silhouette, H._placed_attitudes
    classified = jax.jit(own[0])

    def covers(R, t, sc, coarse):
        pts, val = S._silhouette_cells(sc, coarse)
        inside, _ = S._face_cover(R, t, pts, sc.face_poly, sc.geom, sc.cam4)
        return pts, val, inside, jnp.any(inside[1:], axis=0)

    def term(R, t, sc, coarse=False):
        _, val, inside, body = covers(R, t, sc, coarse)
        model = jnp.any(inside, axis=0).astype(val.dtype)
        return 1.0 - iou_with_unknown(model, val, (inside[0] & ~body).astype(val.dtype))

    def place_body(R, t, sc):
        # _place_on_silhouette with the model's area and centroid counted on the body alone:
        # the package's function, its face cover without the panel's top while it is traced
        own_cover = H._face_cover

        def body_only(*args, **kw):
            inside, depth = own_cover(*args, **kw)
            return inside.at[0].set(False), depth

        H._face_cover = body_only
        try:
            return own[2](R, t, sc)
        finally:
            H._face_cover = own_cover

    def placed_both(det, opts, sc, on_roi):
        R1, t1 = own[3](det, opts, sc, on_roi)
        if on_roi:
            return R1, t1
        H._place_on_silhouette = place_body
        H._batched_place.cache_clear()
        try:
            R2, t2 = own[3](det, opts, sc, on_roi)
        finally:
            H._place_on_silhouette = own[2]
            H._batched_place.cache_clear()
        return np.concatenate([R1, R2]), np.concatenate([t1, t2])

    S._silhouette_term = term
    P._jit_silhouette_term = lambda: classified
    if placement == "body":
        H._place_on_silhouette = place_body
    elif placement == "both":
        H._placed_attitudes = placed_both
    for cached in (S._batched_quick, S._batched_rank, H._batched_place):
        cached.cache_clear()
    try:
        yield
    finally:
        S._silhouette_term, P._jit_silhouette_term, H._place_on_silhouette = own[:3]
        H._placed_attitudes = own[3]
        for cached in (S._batched_quick, S._batched_rank, H._batched_place):
            cached.cache_clear()


def _record(lab, r, grabcut: bool, runtime_s: float) -> dict:
    posed = r.pose is not None
    return {
        "image": lab.image.name,
        "grabcut": grabcut,
        "success": posed and bool(success(r.pose, lab.pose)),
        "confidence": r.confidence,
        "rotation_deg": float(np.degrees(rotation_error(r.pose.R, lab.pose.R))) if posed else None,
        "position_m": float(np.linalg.norm(np.asarray(r.pose.t) - np.asarray(lab.pose.t)))
        if posed
        else None,
        "runtime_s": runtime_s,
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("directory", nargs="?", help="SPEED+ folder (not with --renders)")
    probe = ap.add_mutually_exclusive_group(required=True)
    probe.add_argument("--grabcut", action="store_true", help="GrabCut silhouettes (module doc)")
    probe.add_argument("--panel-unknown", action="store_true", help="the panel's top unknown")
    ap.add_argument("--placement", choices=("silhouette", "body", "both"), default="silhouette")
    ap.add_argument("--out", default=None, help="write the records as JSON here")
    ap.add_argument("--renders", metavar="ARGS", help="run bench/monocular.py ARGS instead")
    args = ap.parse_args(argv)
    if args.renders is not None:
        if not args.panel_unknown:
            ap.error("--renders runs the panel probe only")
        import runpy
        import shlex
        import sys

        sys.argv = ["monocular.py", *shlex.split(args.renders)]
        sys.argv += ["--out", args.out] if args.out else []
        with _panel_patch(args.placement):
            runpy.run_path(str(Path(__file__).with_name("monocular.py")), run_name="__main__")
        return
    if args.directory is None:
        ap.error("a SPEED+ folder is needed (or --renders)")

    root = Path(args.directory)
    camera, model = load_camera(root / "camera.json"), tango()
    rows = []
    state = {}
    patch = _grabcut_patch(state) if args.grabcut else _panel_patch(args.placement)
    with patch:  # entered once: the compiled scores are reused from image to image
        for lab in load_speed_labels(root):
            img = load_image(lab.image)
            state.clear()
            roi = None
            if args.grabcut:
                roi = model_box(model, lab.pose, camera, img.shape[:2])
                state["box"] = undistort_box(roi, camera, img.shape[:2])
            t0 = time.perf_counter()
            r = initialise_pose(img, camera, model, roi=roi)
            rows.append(_record(lab, r, "mask" in state, time.perf_counter() - t0))
            print(
                f"{lab.image.name:28s} {'grabcut ' if rows[-1]['grabcut'] else ''}"
                f"{'ok' if rows[-1]['success'] else '--'} {r.confidence}",
                flush=True,
            )
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))
    cut = [r for r in rows if r["grabcut"]]
    high = [r for r in rows if r["confidence"] == "high"]
    summary = {
        "probe": "grabcut" if args.grabcut else f"panel-unknown, placement {args.placement}",
        "images": len(rows),
        "success": sum(r["success"] for r in rows),
        "success_images": [r["image"] for r in rows if r["success"]],
        "grabcut_images": [r["image"] for r in cut],
        "grabcut_success": sum(r["success"] for r in cut),
        "high": len(high),
        "high_right": sum(r["success"] for r in high),
        "high_wrong": [r["image"] for r in high if not r["success"]],
        # the first image compiles
        "median_runtime_s": float(np.median([r["runtime_s"] for r in rows[1:]])) if rows else None,
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
