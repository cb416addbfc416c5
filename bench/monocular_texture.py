"""Does the target's appearance tell the labelled pose from the pipeline's wrong answers? A
face-texture model learned from the labelled photographs, leave-one-out.

    python bench/monocular_texture.py DIR [--step 0.04] [--hypotheses] [--out F]

``DIR``: a SPEED+ folder (:func:`jaxpose.io.load_speed_labels`). Not part of the package (the
measurement below found no place for it in the pipeline); a development diagnostic.

The model's large faces (area at least 0.05 m^2: the panel's two sides, the body's bottom and
four sides) are sampled on a grid of ``--step`` metres. At a pose, a sample counts where its
face turns at least 0.25 (cosine) to the camera, no model face lies in front of it (ray-cast
against every face) and it projects inside the undistorted image, blurred by a Gaussian of 0.6
``step`` projected at the label's range. Each photograph gives, at its label, each face's samples
standardised (zero mean, unit spread per face: the light differs between photographs); the
*texture* of an image is the mean of those of the other photographs (leave-one-out; a sample
seen in fewer than two is left out). The *texture score* of a pose is the per-face ZNCC of the
image's samples with the texture, averaged over faces weighted by their counted samples (1: the
image looks like the texture everywhere).

Per image (``--out`` records): ``label`` (the texture score at the label), ``answer`` (at the
pipeline's returned pose, default options), ``best_wrong`` (the highest among the final
candidates not within 10 deg and 0.30 m) and ``best_wrong_deg`` (its rotation from the label),
``success``; with ``--hypotheses``, the rank by
texture score of the best-ranked hypothesis or grid pose whose attitude is within 10 deg of the
label, among all of them before the shortlist (the trace's ``hypotheses``; about 20 s an image
at ``--step 0.1``, minutes at 0.04: every sample is ray-cast against every face).
Summary line: among the photographs the pipeline gets wrong, how many have the label scoring
above the returned answer and above every candidate.
"""

from __future__ import annotations

import argparse
import functools
import json
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import cv2  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.scipy.ndimage import map_coordinates  # noqa: E402

from jaxpose.core.geometry import Pose  # noqa: E402
from jaxpose.core.metrics import rotation_error, success  # noqa: E402
from jaxpose.io import load_camera, load_image, load_speed_labels  # noqa: E402
from jaxpose.pipelines.monocular import InitOptions, initialise_pose  # noqa: E402
from jaxpose.vision.models import tango  # noqa: E402
from jaxpose.vision.undistort import undistort_image  # noqa: E402

MIN_AREA = 0.05  # m^2: the panel's rims and the body's 2 cm strips are left out
MIN_COS = 0.25  # a face turned less than this to the camera is not sampled
MIN_SAMPLES = 12  # per face, for its ZNCC


def face_samples(model, step):
    """Sample points ``(S, 3)``, their face index ``(S,)``, the faces' outward normals ``(F, 3)``
    and every model face as a quad ``(Q, 4, 3)`` (occluders)."""
    V = np.asarray(model.vertices, float)
    pts, fid, normals = [], [], []
    for f, n in zip(model.faces, model.face_normals, strict=True):  # outward (the model's)
        q = V[np.asarray(f)]
        a, b = np.linalg.norm(q[1] - q[0]), np.linalg.norm(q[3] - q[0])
        if a * b < MIN_AREA:
            continue
        nu, nv = int(np.ceil(a / step)), int(np.ceil(b / step))
        s, t = np.meshgrid((np.arange(nu) + 0.5) / nu, (np.arange(nv) + 0.5) / nv, indexing="ij")
        w = np.stack([(1 - s) * (1 - t), s * (1 - t), s * t, (1 - s) * t], -1).reshape(-1, 4)
        pts.append(w @ q)
        fid.append(np.full(len(w), len(normals)))
        normals.append(np.asarray(n, float))
    quads = np.stack([V[np.asarray(f)] for f in model.faces])
    return np.concatenate(pts), np.concatenate(fid), np.stack(normals), quads


def _occluded(Xc, quads_c):
    """``(S,)``: the ray to each camera-frame point meets a quad nearer than the point (4 mm)."""
    d = Xc / Xc[:, 2:3]

    def one(qc):
        nrm = jnp.cross(qc[1] - qc[0], qc[3] - qc[0])
        den = d @ nrm
        safe = jnp.where(jnp.abs(den) > 1e-12, den, 1.0)
        z = jnp.where(jnp.abs(den) > 1e-12, (qc[0] @ nrm) / safe, jnp.inf)
        X = d * z[:, None]
        side = jnp.stack([jnp.cross(qc[(i + 1) % 4] - qc[i], X - qc[i]) @ nrm for i in range(4)], 1)
        inside = jnp.all(side >= -1e-12, 1) | jnp.all(side <= 1e-12, 1)
        return inside & (z < Xc[:, 2] - 0.004) & (z > 0)

    return jnp.any(jax.vmap(one)(quads_c), 0)


def _samples(R, t, img, K, pts, fid, normals, quads):
    Xc = pts @ R.T + t
    nf = len(normals)
    cen = (
        jax.ops.segment_sum(Xc, fid, nf) / jax.ops.segment_sum(jnp.ones(len(fid)), fid, nf)[:, None]
    )
    cosf = jnp.sum((normals @ R.T) * (-cen), 1) / jnp.linalg.norm(cen, axis=1)
    u = K[0, 0] * Xc[:, 0] / Xc[:, 2] + K[0, 2]
    v = K[1, 1] * Xc[:, 1] / Xc[:, 2] + K[1, 2]
    H, W = img.shape
    inside = (u > 1) & (u < W - 2) & (v > 1) & (v < H - 2) & (Xc[:, 2] > 0.1)
    use = (cosf > MIN_COS)[fid] & ~_occluded(Xc, quads @ R.T + t) & inside
    return map_coordinates(img, [v, u], order=1, mode="nearest"), use


def _zncc(g, use, T, T_ok, fid, nf):
    w = (use & T_ok).astype(g.dtype)

    def seg(x):
        return jax.ops.segment_sum(x, fid, nf)

    n = seg(w)
    mg, mT = seg(w * g) / jnp.maximum(n, 1), seg(w * T) / jnp.maximum(n, 1)
    cov = seg(w * g * T) - n * mg * mT
    vg, vT = seg(w * g * g) - n * mg * mg, seg(w * T * T) - n * mT * mT
    r = cov / jnp.sqrt(jnp.maximum(vg * vT, 1e-12))
    wf = jnp.where((n >= MIN_SAMPLES) & (vg > 1e-6 * jnp.maximum(n, 1)), n, 0.0)
    return jnp.sum(wf * r) / jnp.maximum(jnp.sum(wf), 1.0)


@functools.lru_cache(maxsize=2)
def _scorers(step):
    pts, fid, normals, quads = (jnp.asarray(x) for x in face_samples(tango(), step))
    nf = len(normals)
    one = jax.jit(lambda R, t, img, K: _samples(R, t, img, K, pts, fid, normals, quads))

    def score(R, t, img, K, T, T_ok):
        g, use = _samples(R, t, img, K, pts, fid, normals, quads)
        return _zncc(g, use, T, T_ok, fid, nf)

    batch = jax.jit(jax.vmap(score, in_axes=(0, 0, None, None, None, None)))
    return one, batch, np.asarray(fid), nf


def standardised(g, use, fid, nf):
    """Each face's counted samples standardised; ``nan`` elsewhere."""
    g, use = np.asarray(g), np.asarray(use)
    z = np.full(len(g), np.nan)
    for k in range(nf):
        s = use & (fid == k)
        if s.sum() >= MIN_SAMPLES and g[s].std() > 1e-3:
            z[s] = (g[s] - g[s].mean()) / g[s].std()
    return z


def texture(observations):
    """Mean of the standardised observations ``(S,)`` where at least two saw the sample."""
    Z = np.stack(observations)
    count = np.isfinite(Z).sum(0)
    return np.where(count >= 2, np.nansum(Z, 0) / np.maximum(count, 1), 0.0), count >= 2


def score_poses(batch, R, t, img, K, T, T_ok, chunk=256):
    out = []
    for a in range(0, len(R), chunk):
        Rc, tc = np.asarray(R[a : a + chunk]), np.asarray(t[a : a + chunk])
        k = len(Rc)
        pad = max(chunk - k, 0) if len(R) > chunk else 0
        if pad:
            Rc = np.concatenate([Rc, np.repeat(Rc[:1], pad, 0)])
            tc = np.concatenate([tc, np.repeat(tc[:1], pad, 0)])
        s = batch(jnp.asarray(Rc), jnp.asarray(tc), img, K, jnp.asarray(T), jnp.asarray(T_ok))
        out.append(np.asarray(s)[:k])
    return np.concatenate(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", type=Path)
    ap.add_argument("--step", type=float, default=0.04, help="texture grid step (m)")
    ap.add_argument("--hypotheses", action="store_true", help="rank the close hypotheses too")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    if not a.step > 0:
        ap.error(f"--step must be > 0 (metres); got {a.step}")
    camera = load_camera(a.dir / "camera.json")
    labels = load_speed_labels(a.dir)
    one, batch, fid, nf = _scorers(a.step)
    seen = {}
    for lab in labels:
        R, t = np.asarray(lab.pose.R, float), np.asarray(lab.pose.t, float)
        und, ideal = undistort_image(load_image(lab.image), camera)
        g = und.astype(np.float32)
        g[:8, :8] = g[8, 8]  # the sample's coloured corner pixels (its README)
        sigma = max(0.5, 0.6 * a.step * float(ideal.fx) / float(np.linalg.norm(t)))
        img = jnp.asarray(cv2.GaussianBlur(g, (0, 0), sigma), jnp.float64)
        K = jnp.asarray(np.asarray(ideal.K, float))
        z = standardised(*one(jnp.asarray(R), jnp.asarray(t), img, K), fid, nf)
        seen[lab.image.name] = (lab, img, K, z)
    photos = [n for n, (lab, *_) in seen.items() if lab.domain == "lightbox"]
    records = []
    for name, (lab, img, K, _) in seen.items():
        T, T_ok = texture([seen[m][3] for m in photos if m != name])
        truth = lab.pose
        res = initialise_pose(load_image(lab.image), camera, options=InitOptions(trace=True))
        rec = {"image": name, "domain": lab.domain}
        lab_s = score_poses(
            batch, np.asarray(truth.R)[None], np.asarray(truth.t)[None], img, K, T, T_ok
        )
        rec["label"] = float(lab_s[0])
        if res.pose is not None:
            rec["success"] = bool(success(res.pose, truth))
            cands = res.trace["refined"]
            Rc = np.stack([np.asarray(p.R) for p in cands])
            tc = np.stack([np.asarray(p.t) for p in cands])
            s = score_poses(batch, Rc, tc, img, K, T, T_ok)
            close = np.asarray(success(Pose(jnp.asarray(Rc), jnp.asarray(tc)), truth))
            rec["answer"] = float(s[res.trace["chosen"]])
            rec["best_wrong"], rec["best_wrong_deg"] = None, None
            if (~close).any():
                w = int(np.argmax(np.where(close, -np.inf, s)))
                rec["best_wrong"] = float(s[w])
                deg = rotation_error(jnp.asarray(Rc[w]), jnp.asarray(truth.R))
                rec["best_wrong_deg"] = float(np.degrees(deg))
        if a.hypotheses and res.trace and "hypotheses" in res.trace:
            Rh, th, ok = res.trace["hypotheses"]
            s = np.where(ok, score_poses(batch, Rh, th, img, K, T, T_ok), -np.inf)
            err = np.degrees(np.asarray(rotation_error(jnp.asarray(Rh), jnp.asarray(truth.R))))
            rank = np.empty(len(s), int)
            rank[np.argsort(-s, kind="stable")] = np.arange(len(s))
            rec["close_rank"] = int(rank[err < 10].min()) if (err < 10).any() else None
            rec["hypotheses"] = int(len(s))
        print(json.dumps(rec), flush=True)
        records.append(rec)
    wrong = [r for r in records if r["domain"] == "lightbox" and r.get("success") is False]
    summary = {
        "bench": "monocular_texture",
        "step_m": a.step,
        "photographs_wrong": len(wrong),
        "label_above_answer": sum(r["label"] > r["answer"] for r in wrong),
        "label_above_every_wrong_candidate": sum(
            r["best_wrong"] is not None and r["label"] > r["best_wrong"] for r in wrong
        ),
    }
    if a.out:
        a.out.write_text(json.dumps({"summary": summary, "images": records}, indent=1))
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
