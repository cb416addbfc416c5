"""Which evidence separates the right monocular pose from wrong ones: every final candidate of
:func:`jaxpose.pipelines.monocular.initialise_pose`, and the labelled pose fitted to the edges as
the shortlist is, measured by the pipeline's own terms and by candidate new ones.

    python bench/monocular_evidence.py --speedplus DIR --basin --out ev_speed.json
    python bench/monocular_evidence.py --domain lightbox --images 20 --seed 7 --out ev_lb.json
    python bench/monocular_evidence.py --analyse ev_speed.json ev_lb.json ...

Per candidate (``close``: within 10 deg and 0.30 m of the label) it records:

- the ranking key and its terms (chamfer, region energy, antenna, silhouette, orientation, panel);
- ``basin`` (with ``--basin``): the share of ``BASIN_STARTS`` perturbed starts (``BASIN_DEG``
  about a random axis, ``BASIN_SHIFT`` of the range along each axis) that the shortlist's edge
  fit brings back within 2 deg and 1% of the range of the candidate's own fit;
- ``contour_contrast``: the grey-level step across the projected outer contour (the border of the
  union of front faces) over the crop's spread; ``inner_contrast``: across the projected inner
  edges (between two front faces); ``face_spread``: the mean within-face spread of grey levels
  over the crop's spread;
- ``ori_outer``, ``ori_inner``: the LINE-2D agreement at the contour edges and at the inner edges;
- ``explained``: the share of strong image gradients inside the projected body (grown by
  2% of ``l_ROI``) within ``2% l_ROI`` of a projected visible edge;
- ``spread``: the package's face-shading spread (``score._face_spread``, 48 x 48 grid).

``--analyse`` prints, per quantity, how often it prefers the fitted label (when the fit stays
within 30 deg and 0.5 m of the label) to the answer on the wrong answers, the within-image
pairwise AUC (close candidates against the others) and the AUC of the answer's value for right
against wrong answers (the confidence).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import cv2  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxpose.core.geometry import Pose, so3_exp  # noqa: E402
from jaxpose.pipelines.monocular import CONFIDENCE, InitOptions, initialise_pose  # noqa: E402
from jaxpose.pipelines.monocular.fit import _batched_fit, _chamfer_fit  # noqa: E402
from jaxpose.pipelines.monocular.rematch import _rematch_refine  # noqa: E402
from jaxpose.pipelines.monocular.scene import _edge_scene  # noqa: E402
from jaxpose.pipelines.monocular.score import (  # noqa: E402
    _antenna_term,
    _chamfer,
    _face_spread,
    _orientation_term,
    _panel_term,
    _rank_key,
    _region_energy,
    _silhouette_term,
)
from jaxpose.vision.image_maps import orientation_maps  # noqa: E402
from jaxpose.vision.models import tango  # noqa: E402
from jaxpose.vision.roi import roi_diagonal  # noqa: E402

BASIN_STARTS = 8
BASIN_DEG = 5.0
BASIN_SHIFT = 0.03
CROP_SIDE = 320


def _angle(A, B) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(A @ B.T) - 1.0) / 2.0, -1.0, 1.0))))


def _basin(R, t, sc, rng):
    """Share of perturbed starts that the edge fit returns to the candidate's own fit."""
    K = BASIN_STARTS
    ax = rng.normal(size=(K, 3))
    ax /= np.linalg.norm(ax, axis=1, keepdims=True)
    dR = np.stack([np.asarray(so3_exp(jnp.asarray(a * np.deg2rad(BASIN_DEG)))) for a in ax])
    rng_m = float(np.linalg.norm(t))
    R0 = np.concatenate([R[None], dR @ R])
    t0 = np.concatenate([t[None], t + rng.uniform(-1, 1, (K, 3)) * BASIN_SHIFT * rng_m])
    FR, Ft = _batched_fit()(jnp.asarray(R0), jnp.asarray(t0), sc)
    FR, Ft = np.asarray(FR), np.asarray(Ft)
    back = [
        _angle(FR[k], FR[0]) < 2.0 and np.linalg.norm(Ft[k] - Ft[0]) < 0.01 * rng_m
        for k in range(1, K + 1)
    ]
    return float(np.mean(back))


class _Crop:
    """The undistorted image around the ROI, shrunk so that its longer side is ``CROP_SIDE``."""

    def __init__(self, image, roi):
        u0, v0, u1, v1 = (float(x) for x in roi)
        H, W = image.shape
        g = 0.3 * max(u1 - u0, v1 - v0)
        self.a0, self.b0 = int(max(u0 - g, 0)), int(max(v0 - g, 0))
        a1, b1 = int(min(u1 + g, W)), int(min(v1 + g, H))
        self.k = CROP_SIDE / max(a1 - self.a0, b1 - self.b0, 1)
        w = max(int((a1 - self.a0) * self.k), 2)
        h = max(int((b1 - self.b0) * self.k), 2)
        self.img = cv2.resize(
            image[self.b0 : b1, self.a0 : a1].astype(np.float32), (w, h), cv2.INTER_AREA
        )
        self.spread = float(np.std(self.img)) + 1e-6
        gx = cv2.Sobel(self.img, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(self.img, cv2.CV_32F, 0, 1, ksize=3)
        mag = np.hypot(gx, gy)
        self.strong = mag >= 0.2 * float(np.percentile(mag, 99.0))
        self.l_roi = roi_diagonal(roi) * self.k

    def to_crop(self, uv):
        return (np.asarray(uv) - [self.a0, self.b0]) * self.k


def _labels(model, R, t, cam4, crop):
    """Face label of each crop pixel (painter's order; ``-1`` background) and the front faces."""
    V = model.vertices @ R.T + t
    h, w = crop.img.shape
    lab = np.full((h, w), -1, np.int32)
    order = []
    for f, idx in enumerate(model.faces):
        P = V[list(idx)]
        n = np.cross(P[1] - P[0], P[2] - P[0])
        if np.all(P[:, 2] > 1e-3) and np.dot(n, P.mean(0)) < 0:
            order.append((P[:, 2].mean(), f, P))
    for _, f, P in sorted(order, key=lambda x: -x[0]):
        uv = np.stack(
            [cam4[0] * P[:, 0] / P[:, 2] + cam4[2], cam4[1] * P[:, 1] / P[:, 2] + cam4[3]], 1
        )
        q = np.round(crop.to_crop(uv) * 4).astype(np.int32)
        cv2.fillConvexPoly(lab, q, int(f), lineType=cv2.LINE_8, shift=2)
    return lab, [f for _, f, _ in order]


def _step(crop, a, b, band):
    """Mean grey-level step between the pixels of masks ``a`` and ``b`` near their border."""
    ker = np.ones((band, band), np.uint8)
    near = cv2.dilate(a.astype(np.uint8), ker).astype(bool) & cv2.dilate(
        b.astype(np.uint8), ker
    ).astype(bool)
    if near.sum() < 5:
        return np.nan
    k2 = (2 * band + 1, 2 * band + 1)
    ia = cv2.boxFilter(crop.img * a, -1, k2, normalize=False)
    na = cv2.boxFilter(a.astype(np.float32), -1, k2, normalize=False)
    ib = cv2.boxFilter(crop.img * b, -1, k2, normalize=False)
    nb = cv2.boxFilter(b.astype(np.float32), -1, k2, normalize=False)
    ok = near & (na > 0.5) & (nb > 0.5)
    if ok.sum() < 5:
        return np.nan
    return float(np.mean(np.abs(ia[ok] / na[ok] - ib[ok] / nb[ok]))) / crop.spread


def _image_features(model, R, t, cam4, crop, ori, ori_frame, geom):
    lab, front = _labels(model, R, t, cam4, crop)
    band = max(2, int(0.02 * crop.l_roi))
    body = lab >= 0
    out = {}
    out["contour_contrast"] = _step(crop, body, ~body, band) if body.any() else np.nan
    steps, spreads, areas = [], [], []
    ker = np.ones((band, band), np.uint8)
    for f in front:
        m = lab == f
        inner = cv2.erode(m.astype(np.uint8), ker).astype(bool)
        if inner.sum() > 10:
            spreads.append(float(np.std(crop.img[inner])) / crop.spread)
            areas.append(float(inner.sum()))
        for g in front:
            if g > f and (lab == g).any():
                s = _step(crop, m, lab == g, band)
                if np.isfinite(s):
                    steps.append(s)
    out["inner_contrast"] = float(np.mean(steps)) if steps else np.nan
    out["face_spread"] = float(np.average(spreads, weights=areas)) if spreads else np.nan
    # explained gradients: strong pixels inside the grown body near a projected visible edge
    edges, _, edge_faces, _, _ = (np.asarray(x) for x in geom)
    Vc = edges @ R.T + t
    canvas = np.full(crop.img.shape, 255, np.uint8)
    outer, inner_e = [], []
    fr = set(front)
    for e in range(len(edges)):
        fs = np.nonzero(edge_faces[e])[0]
        nfront = sum(int(f) in fr for f in fs)
        if len(fs) and nfront == 0:
            continue
        if np.any(Vc[e, :, 2] <= 1e-3):
            continue
        uv = np.stack(
            [
                cam4[0] * Vc[e, :, 0] / Vc[e, :, 2] + cam4[2],
                cam4[1] * Vc[e, :, 1] / Vc[e, :, 2] + cam4[3],
            ],
            1,
        )
        q = crop.to_crop(uv)
        cv2.line(canvas, tuple(int(x) for x in q[0]), tuple(int(x) for x in q[1]), 0, 1)
        if len(fs):
            (inner_e if nfront == 2 else outer).append((e, uv))
    dist = cv2.distanceTransform(canvas, cv2.DIST_L2, 3)
    grown = cv2.dilate(body.astype(np.uint8), np.ones((band * 2 + 1,) * 2, np.uint8)).astype(bool)
    s = crop.strong & grown
    out["explained"] = float(np.mean(dist[s] < 0.02 * crop.l_roi)) if s.any() else np.nan

    def agreement(lst):
        if not lst:
            return np.nan
        B, S = ori.shape[0], ori.shape[1]
        vals = []
        for _, uv in lst:
            d = uv[1] - uv[0]
            phi = np.mod(np.arctan2(d[1], d[0]) + 0.5 * np.pi, np.pi)
            o = int(np.round(phi / (np.pi / B))) % B
            for a in np.linspace(0, 1, 8):
                p = (uv[0] + a * d - ori_frame[:2]) * ori_frame[2]
                if np.all(p >= 0) and np.all(p <= S - 1):
                    vals.append(ori[o, int(round(p[1])), int(round(p[0]))])
        return float(np.mean(vals)) if vals else np.nan

    out["ori_outer"] = agreement(outer)
    out["ori_inner"] = agreement(inner_e)
    return out


def candidate_rows(res, truth: Pose | None, model, rng, args_basin=False):
    """One row per final candidate (and the fitted label), the quantities of the docstring."""
    det = res.detection
    opts = InitOptions(orientation_weight=1.0, panel_weight=1.0)
    sc = _edge_scene(det, model, opts)
    sc0 = _edge_scene(det, model, InitOptions())
    l_roi = roi_diagonal(det.roi)
    cands = [(np.asarray(p.R), np.asarray(p.t)) for p in res.trace["refined"]]
    kinds = ["candidate"] * len(cands)
    if truth is not None:
        Rf, tf = _chamfer_fit(jnp.asarray(truth.R), jnp.asarray(truth.t), sc0, steps=12)
        pf = _rematch_refine([Pose(Rf, tf)], det, model, det.camera, l_roi, 2)[0]
        cands.append((np.asarray(pf.R), np.asarray(pf.t)))
        kinds.append("truth_fit")
    ori, ori_frame = orientation_maps(det.image, det.roi)
    crop = _Crop(det.image, det.roi)
    cam4 = np.asarray(sc.cam4)
    rows = []
    for i, ((R, t), kind) in enumerate(zip(cands, kinds, strict=True)):
        Rj, tj = jnp.asarray(R), jnp.asarray(t)
        row = {"kind": kind, "chosen": bool(i == res.trace["chosen"])}
        if truth is not None:
            row["rot_deg"] = _angle(R, np.asarray(truth.R))
            row["pos_m"] = float(np.linalg.norm(t - np.asarray(truth.t)))
            row["close"] = bool(row["rot_deg"] < 10 and row["pos_m"] < 0.3)
        if not (np.all(np.isfinite(t)) and t[2] > 0):
            row["valid"] = False
            rows.append(row)
            continue
        row["valid"] = True
        row["key"] = float(_rank_key(Rj, tj, sc0)[0]) / l_roi
        ch, near = _chamfer(Rj, tj, sc)
        row["chamfer"] = float(ch) / l_roi
        row["near"] = float(near)
        row["region"] = float(_region_energy(Rj, tj, sc))
        row["antenna"] = float(_antenna_term(Rj, tj, sc)) / float(sc.tau)
        row["silhouette"] = (
            float(_silhouette_term(Rj, tj, sc)) if sc.sil_pts is not None else np.nan
        )
        row["orientation"] = 1.0 - float(_orientation_term(Rj, tj, sc))
        row["panel"] = float(_panel_term(Rj, tj, sc)) if sc.panel is not None else np.nan
        row["spread"] = float(_face_spread(Rj, tj, sc))
        if args_basin:
            row["basin"] = _basin(R, t, sc0, rng)
        row |= _image_features(model, R, t, cam4, crop, ori, ori_frame, sc.geom)
        rows.append(row)
    return rows


def quick_ranks(res, truth: Pose, model, weights) -> dict:
    """Best quick-score rank of a hypothesis within 10 deg of the label's attitude (the
    shortlist fits the first 128), with the face-shading spread at each quick weight."""
    det = res.detection
    HR, Ht, ok = res.trace["hypotheses"]
    c = (np.einsum("nij,ij->n", HR, np.asarray(truth.R)) - 1.0) / 2.0
    close = c > np.cos(np.deg2rad(10.0))
    out = {"close_attitudes": int(close.sum())}
    if not close.any():
        return out
    from jaxpose.pipelines.monocular.score import _batched_quick

    for w in weights:
        sc = _edge_scene(det, model, InitOptions(spread_quick_weight=w))
        n, chunk = len(HR), 512
        pad = (-n) % chunk
        Rp = np.concatenate([HR, np.repeat(HR[:1], pad, 0)])
        tp = np.concatenate([Ht, np.repeat(Ht[:1], pad, 0)])
        q = np.concatenate(
            [
                np.asarray(
                    _batched_quick()(
                        jnp.asarray(Rp[a : a + chunk]),
                        jnp.asarray(tp[a : a + chunk]),
                        sc,
                        jnp.asarray(det.roi),
                    )
                )
                for a in range(0, len(Rp), chunk)
            ]
        )[:n]
        q = np.where(ok & np.isfinite(q), q, np.inf)
        rank = np.empty(n, int)
        rank[np.argsort(q, kind="stable")] = np.arange(n)
        out[f"quick_rank_w{w:g}"] = int(rank[close].min())
    return out


def _run(args):
    model = tango()
    opts = InitOptions(trace=True, confidence=dict(CONFIDENCE, low_score=1.0))
    rng = np.random.default_rng(0)
    out = []
    if args.speedplus:
        from jaxpose.io import load_camera, load_image, load_speed_labels

        root = Path(args.speedplus)
        camera = load_camera(root / "camera.json")
        items = (
            (lab.image.name, "speedplus", load_image(lab.image), lab.pose)
            for lab in load_speed_labels(root)
        )
    else:
        sys.path.insert(0, str(Path(__file__).parent))
        from monocular import SPEEDPLUS_CAMERA

        from jaxpose.vision.render import lightbox_scene, random_pose, render

        camera = SPEEDPLUS_CAMERA
        rr = np.random.default_rng(args.seed)

        def gen():
            for i in range(args.images):
                pose = random_pose(rr, camera, range_m=(3.0, 12.0))
                if args.domain == "lightbox":
                    kw = lightbox_scene(model, rr)
                elif args.domain == "lightbox-earth":
                    kw = lightbox_scene(
                        model,
                        rr,
                        earth="partial" if i % 2 == 0 else "full",
                        shape=(camera.height, camera.width),
                    )
                else:
                    kw = dict(earth=i % 2 == 1)
                r = render(model, pose, camera, rng=rr, **kw)
                yield f"{args.domain}_{args.seed}_{i:03d}", "render", r.image, pose

        items = gen()
    for name, source, image, pose in items:
        res = initialise_pose(image, camera, model, opts)
        if res.pose is None or res.trace is None or "refined" not in res.trace:
            print(json.dumps({"image": name, "skipped": res.confidence}), flush=True)
            continue
        if args.quick_weights:
            qr = quick_ranks(res, pose, model, args.quick_weights)
            print(json.dumps({"image": name} | qr), flush=True)
            out.append({"image": name, "source": source, "valid": False} | qr)
            continue
        rows = candidate_rows(res, pose, model, rng, args_basin=args.basin)
        for r in rows:
            r |= {"image": name, "source": source, "confidence": res.confidence}
        out.extend(rows)
        ch = [r for r in rows if r["chosen"]][0]
        tf = [r for r in rows if r["kind"] == "truth_fit"][0]
        print(
            name,
            "answer close" if ch.get("close") else "answer wrong",
            "| any close" if any(r.get("close") for r in rows if r["kind"] == "candidate") else "",
            f"| key ans {ch.get('key', np.nan):.4f} truth {tf.get('key', np.nan):.4f}",
            flush=True,
        )
    if args.out:
        Path(args.out).write_text(json.dumps(out, default=float))


QUANTITIES = {  # name: sign (+1: larger is better evidence for the pose)
    "key": -1,
    "chamfer": -1,
    "near": 1,
    "region": -1,
    "antenna": -1,
    "silhouette": -1,
    "orientation": 1,
    "panel": -1,
    "basin": 1,
    "spread": -1,
    "contour_contrast": 1,
    "inner_contrast": 1,
    "face_spread": -1,
    "ori_outer": 1,
    "ori_inner": 1,
    "explained": 1,
}


def _auc(pos, neg):
    pos, neg = np.asarray(pos, float), np.asarray(neg, float)
    pos, neg = pos[np.isfinite(pos)], neg[np.isfinite(neg)]
    if not len(pos) or not len(neg):
        return np.nan, 0
    d = pos[:, None] - neg[None]
    return float(np.mean((d > 0) + 0.5 * (d == 0))), len(pos) * len(neg)


def analyse(paths):
    rows = [r for p in paths for r in json.load(open(p)) if r.get("valid")]
    for source in sorted({r["source"] for r in rows}):
        rs = [r for r in rows if r["source"] == source]
        images = sorted({r["image"] for r in rs})
        print(f"\n== {source}: {len(images)} images")
        print(f"{'quantity':18s} {'near label preferred':>22s} {'pair AUC':>9s} {'conf AUC':>9s}")
        for q, sign in QUANTITIES.items():
            better = worse = 0
            pa_num = pa_den = 0.0
            right, wrong = [], []
            for im in images:
                ri = [r for r in rs if r["image"] == im and np.isfinite(r.get(q, np.nan))]
                ch = [r for r in ri if r["chosen"]]
                # the fitted label, when the fit stays near it (30 deg, 0.5 m)
                tf = [
                    r
                    for r in ri
                    if r["kind"] == "truth_fit" and r["rot_deg"] < 30 and r["pos_m"] < 0.5
                ]
                if ch:
                    (right if ch[0]["close"] else wrong).append(sign * ch[0][q])
                if ch and tf and not ch[0]["close"]:
                    if sign * tf[0][q] > sign * ch[0][q]:
                        better += 1
                    else:
                        worse += 1
                pos = [sign * r[q] for r in ri if r["close"]]
                neg = [sign * r[q] for r in ri if not r["close"]]
                a, n = _auc(pos, neg)
                if n:
                    pa_num += a * n
                    pa_den += n
            ca, _ = _auc(right, wrong)
            pa = pa_num / pa_den if pa_den else np.nan
            print(f"{q:18s} {better:>10d} / {better + worse:<10d} {pa:9.2f} {ca:9.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--speedplus", default=None)
    ap.add_argument("--domain", default="lightbox", choices=("space", "lightbox", "lightbox-earth"))
    ap.add_argument("--images", type=int, default=20)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--out", default=None)
    ap.add_argument("--analyse", nargs="*", default=None)
    ap.add_argument("--basin", action="store_true", help="also the basin test (slow)")
    ap.add_argument(
        "--quick-weights",
        type=float,
        nargs="*",
        default=None,
        help="instead: the best quick-score rank of a close attitude at these spread weights",
    )
    args = ap.parse_args()
    if args.analyse:
        analyse(args.analyse)
    else:
        _run(args)


if __name__ == "__main__":
    main()
