"""What faces without edges do to the monocular search on labelled images (faces in shadow, a dark
solar panel over a dark background): where the labelled pose stands in each stage.

    python bench/monocular_dark_faces.py DIR [--out dark_faces.json]

``DIR`` is a SPEED+ folder (:func:`jaxpose.io.load_speed_labels`). For every image whose
detection has a silhouette (a dark background) it reports, with the labelled pose ``(R, t)``:

- ``placed_range``: range of the labelled attitude placed on the silhouette as the attitude grid
  is (:func:`~jaxpose.pipelines.monocular.hypothesise._place_on_silhouette`, matching projected
  areas), over the labelled range: above 1 when part of the target is missing from the
  silhouette;
- ``fit_range``: range after the edge fit started at the labelled pose
  (:func:`~jaxpose.pipelines.monocular.fit._chamfer_fit`, 8 steps), over the labelled range;
- ``quick_rank_truth``: rank of the labelled pose's quick score among the placed grid attitudes
  (0: best; the shortlist fits the first 128); ``quick_rank_close``: the best rank of the 3 grid
  attitudes nearest the label, and their angles ``close_deg``;
- ``fit_from_close``: how many of the 6 grid attitudes nearest the label end within 10 deg and
  0.30 m after the edge fit;
- ``silhouette_cover_truth``, ``silhouette_cover_answer``: share of the image's silhouette covered
  by the projected model at the label and at the pipeline's answer, and ``model_inside_*`` the
  share of the projected model inside the silhouette (the IoU of the ranking mixes the two).

Development diagnostics; the figures are in the docs' monocular evaluation page. Ends with one
JSON line (per-image records and medians).
"""

from __future__ import annotations

import argparse
import json

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxpose.core.geometry import Pose  # noqa: E402
from jaxpose.core.metrics import rotation_error, success  # noqa: E402
from jaxpose.io import load_camera, load_image, load_speed_labels  # noqa: E402
from jaxpose.pipelines.monocular import InitOptions, initialise_pose  # noqa: E402
from jaxpose.pipelines.monocular.fit import _chamfer_fit  # noqa: E402
from jaxpose.pipelines.monocular.hypothesise import (  # noqa: E402
    _place_on_silhouette,
    _placed_attitudes,
)
from jaxpose.pipelines.monocular.scene import _edge_scene  # noqa: E402
from jaxpose.pipelines.monocular.score import (  # noqa: E402
    _batched_quick,
    _face_cover,
    _silhouette_cells,
)
from jaxpose.vision.models import tango  # noqa: E402

_BATCH = 512


def _quick(R, t, sc, roi):
    out = []
    for a in range(0, len(R), _BATCH):
        r, tt = R[a : a + _BATCH], t[a : a + _BATCH]
        n = len(r)
        r = np.concatenate([r, np.repeat(r[:1], _BATCH - n, 0)])
        tt = np.concatenate([tt, np.repeat(tt[:1], _BATCH - n, 0)])
        q = _batched_quick()(jnp.asarray(r), jnp.asarray(tt), sc, jnp.asarray(roi))
        out.append(np.asarray(q)[:n])
    return np.concatenate(out)


def _cover(R, t, sc):
    """(share of the silhouette covered by the model, share of the model inside the silhouette)."""
    pts, val = _silhouette_cells(sc, False)
    inside, _ = _face_cover(jnp.asarray(R), jnp.asarray(t), pts, sc.face_poly, sc.geom, sc.cam4)
    model = jnp.any(inside, axis=0).astype(val.dtype)
    inter = float(jnp.sum(jnp.minimum(model, val)))
    return inter / max(float(jnp.sum(val)), 1e-9), inter / max(float(jnp.sum(model)), 1e-9)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("directory")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    camera = load_camera(f"{args.directory}/camera.json")
    model, opts = tango(), InitOptions()
    fit = jax.jit(jax.vmap(lambda R, t, sc: _chamfer_fit(R, t, sc, 8), in_axes=(0, 0, None)))
    rows = []
    for lab in load_speed_labels(args.directory):
        res = initialise_pose(load_image(lab.image), camera, model, opts)
        det = res.detection
        if det.roi is None or det.silhouette is None or det.coarse_t_cam is None:
            continue
        sc = _edge_scene(det, model, opts)
        if sc.sil_pts is None:
            continue
        R, t = np.asarray(lab.pose.R, float), np.asarray(lab.pose.t, float)
        rng = float(np.linalg.norm(t))
        truth = Pose(jnp.asarray(R), jnp.asarray(t))
        centre = np.asarray(sc.face_poly).reshape(-1, 3).mean(0)
        t0 = np.asarray(det.coarse_t_cam) - R @ centre
        placed = np.asarray(_place_on_silhouette(jnp.asarray(R), jnp.asarray(t0), sc))
        Rg, tg = _placed_attitudes(det, opts, sc, False)
        q = _quick(Rg, tg, sc, det.roi)
        q_truth = _quick(R[None], t[None], sc, det.roi)[0]
        ang = np.degrees(np.asarray(rotation_error(Rg, R)))
        near = np.argsort(ang)
        Rf, tf = fit(
            jnp.asarray(np.concatenate([R[None], Rg[near[:6]]])),
            jnp.asarray(np.concatenate([t[None], tg[near[:6]]])),
            sc,
        )
        Rf, tf = np.asarray(Rf), np.asarray(tf)
        ok = np.asarray(success(Pose(Rf[1:], tf[1:]), truth))
        cov_t, in_t = _cover(R, t, sc)
        row = dict(
            image=lab.image.name,
            success=res.pose is not None and bool(success(res.pose, truth)),
            placed_range=float(np.linalg.norm(placed) / rng),
            fit_range=float(np.linalg.norm(tf[0]) / rng),
            quick_rank_truth=int((q < q_truth).sum()),
            quick_rank_close=int(min((q < q[i]).sum() for i in near[:3])),
            close_deg=[round(float(a), 1) for a in ang[near[:3]]],
            fit_from_close=int(ok.sum()),
            silhouette_cover_truth=cov_t,
            model_inside_truth=in_t,
        )
        if res.pose is not None:
            cov_a, in_a = _cover(np.asarray(res.pose.R), np.asarray(res.pose.t), sc)
            row |= dict(silhouette_cover_answer=cov_a, model_inside_answer=in_a)
        rows.append(row)
        print(
            f"{row['image']:28s} {'right' if row['success'] else 'wrong'}  placed "
            f"{row['placed_range']:.2f}  fit {row['fit_range']:.3f}  quick rank truth "
            f"{row['quick_rank_truth']:4d} close {row['quick_rank_close']:4d}  fit from close "
            f"{row['fit_from_close']}/6  cover truth {cov_t:.2f} answer "
            f"{row.get('silhouette_cover_answer', float('nan')):.2f}",
            flush=True,
        )
    wrong = [r for r in rows if not r["success"] and "silhouette_cover_answer" in r]
    summary = dict(
        images=len(rows),
        median_placed_range_wrong=float(np.median([r["placed_range"] for r in wrong]))
        if wrong
        else None,
        cover_truth_above_answer_wrong=sum(
            r["silhouette_cover_truth"] > r["silhouette_cover_answer"] for r in wrong
        ),
        wrong=len(wrong),
        per_image=rows,
    )
    if args.out:
        with open(args.out, "w") as f:
            json.dump(summary, f, indent=1)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
