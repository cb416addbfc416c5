"""Can local features learned from the labelled photographs give the pose? SIFT features of the
other photographs lifted onto the model, matched to an image and solved by PnP RANSAC
(leave-one-out).

    python bench/monocular_sift.py DIR [--contrast 0.01] [--ratio 0.8] [--per-view] [--out F]

``DIR``: a SPEED+ folder (:func:`jaxpose.io.load_speed_labels`). Not part of the package (the
measurement below found it too weak); a development diagnostic, about 10 s an image.

Every image is undistorted and its SIFT features found (OpenCV, ``contrastThreshold``
``--contrast``; the sample's coloured top-left corner blanked). At a photograph's label, each
feature's pixel is ray-cast onto the model's faces: those that land on a face become *model
features* (a body point and a descriptor). An image is then matched against the model features
of the *other* photographs (leave-one-out), Lowe's ratio test ``--ratio`` over the pooled model
features (``--per-view``: within each other photograph's apart, so that the views of one point
in several photographs do not fail the test against each other), and the pose solved by
``cv2.solvePnPRansac`` (EPnP, 2000 iterations, 6 px).

Per image (``--out`` records): ``features``, ``matches``, ``near_label`` (matches whose body point
projects within 8 px of the image's feature at the label: about right), ``inliers``, the pose's
``rotation_deg`` and ``position_m`` errors and ``success`` (10 deg, 0.30 m); ``view_deg``: the
angle between the image's viewing direction (in the body frame) and the nearest other
photograph's. Summary line: the photographs solved, and the medians of ``near_label`` and
``view_deg`` over them.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from jaxpose.io import load_camera, load_image, load_speed_labels
from jaxpose.vision.models import tango
from jaxpose.vision.undistort import undistort_image


def lift(model, R, t, K, pixels) -> np.ndarray:
    """Body points ``(n, 3)`` where the rays of ``pixels (n, 2)`` (undistorted image, intrinsics
    ``K``) first meet a model face at the pose ``(R, t)``; ``nan`` where they meet none."""
    V = np.asarray(model.vertices, float)
    rays = np.c_[
        (pixels[:, 0] - K[0, 2]) / K[0, 0], (pixels[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(pixels))
    ]
    nearest = np.full(len(pixels), np.inf)
    out = np.full((len(pixels), 3), np.nan)
    for f in model.faces:
        q = V[np.asarray(f)] @ R.T + t
        nrm = np.cross(q[1] - q[0], q[3] - q[0])
        den = rays @ nrm
        with np.errstate(divide="ignore", invalid="ignore"):
            z = (q[0] @ nrm) / den
        X = rays * z[:, None]
        side = np.stack([np.cross(q[(i + 1) % 4] - q[i], X - q[i]) @ nrm for i in range(4)], 1)
        hit = (np.all(side >= 0, 1) | np.all(side <= 0, 1)) & (z > 0) & (z < nearest)
        nearest[hit] = z[hit]
        out[hit] = (X[hit] - t) @ R
    return out


def _angle_deg(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", type=Path)
    ap.add_argument("--contrast", type=float, default=0.01, help="SIFT contrastThreshold")
    ap.add_argument("--ratio", type=float, default=0.8, help="Lowe's ratio test")
    ap.add_argument("--per-view", action="store_true", help="ratio test per photograph")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    if not 0 < a.ratio <= 1:
        ap.error(f"--ratio must be in (0, 1]; got {a.ratio}")
    camera = load_camera(a.dir / "camera.json")
    model = tango()
    sift = cv2.SIFT_create(contrastThreshold=a.contrast)
    seen = {}
    for lab in load_speed_labels(a.dir):
        und, ideal = undistort_image(load_image(lab.image), camera)
        g = und.copy()
        g[:8, :8] = g[8, 8]  # the sample's coloured corner pixels (its README)
        kp, des = sift.detectAndCompute(g, None)
        px = np.array([k.pt for k in kp]).reshape(-1, 2)
        K = np.asarray(ideal.K, float)
        R, t = np.asarray(lab.pose.R, float), np.asarray(lab.pose.t, float)
        X = lift(model, R, t, K, px)
        on = np.isfinite(X[:, 0])
        view = R.T @ (-t) / np.linalg.norm(t)  # the camera's direction in the body frame
        seen[lab.image.name] = dict(lab=lab, px=px, des=des, X=X, on=on, K=K, R=R, t=t, view=view)
    photos = [n for n, s in seen.items() if s["lab"].domain == "lightbox"]
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    records = []
    for name, s in seen.items():
        others = [m for m in photos if m != name]
        rec = {"image": name, "domain": s["lab"].domain, "features": len(s["px"])}
        rec["view_deg"] = min(_angle_deg(s["view"], seen[m]["view"]) for m in others)
        groups = [others] if not a.per_view else [[m] for m in others]
        obj, img = [], []
        for group in groups:
            Xdb = np.concatenate([seen[m]["X"][seen[m]["on"]] for m in group])
            Ddb = np.concatenate([seen[m]["des"][seen[m]["on"]] for m in group])
            if len(s["px"]) < 2 or len(Ddb) < 2:
                continue
            for p in matcher.knnMatch(s["des"], Ddb, k=2):
                if len(p) == 2 and p[0].distance < a.ratio * p[1].distance:
                    obj.append(Xdb[p[0].trainIdx])
                    img.append(s["px"][p[0].queryIdx])
        rec["matches"] = len(obj)
        rec |= {"near_label": 0, "inliers": 0, "success": False}
        if len(obj) >= 6:
            obj, img = np.array(obj), np.array(img)
            P = obj @ s["R"].T + s["t"]
            proj = P[:, :2] / P[:, 2:3] * np.diag(s["K"])[:2] + s["K"][:2, 2]
            rec["near_label"] = int((np.linalg.norm(proj - img, axis=1) < 8).sum())
            ok, rvec, tvec, inl = cv2.solvePnPRansac(
                obj, img, s["K"], None, iterationsCount=2000, reprojectionError=6.0,
                flags=cv2.SOLVEPNP_EPNP,
            )  # fmt: skip
            if ok and inl is not None:
                Rm = cv2.Rodrigues(rvec)[0]
                deg = float(
                    np.degrees(np.arccos(np.clip((np.trace(Rm @ s["R"].T) - 1) / 2, -1, 1)))
                )
                pos = float(np.linalg.norm(tvec.ravel() - s["t"]))
                rec |= {"inliers": len(inl), "rotation_deg": deg, "position_m": pos}
                rec["success"] = bool(deg < 10 and pos < 0.3)
        print(json.dumps(rec), flush=True)
        records.append(rec)
    ph = [r for r in records if r["domain"] == "lightbox"]
    summary = {
        "bench": "monocular_sift",
        "photographs": len(ph),
        "photographs_solved": [r["image"] for r in ph if r["success"]],
        "median_near_label": float(np.median([r["near_label"] for r in ph])),
        "median_view_deg": float(np.median([r["view_deg"] for r in ph])),
    }
    if a.out:
        a.out.write_text(json.dumps({"summary": summary, "images": records}, indent=1))
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
