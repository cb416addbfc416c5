"""Calibration of the monocular confidence class (``high``) by leave-one-out.

    python bench/monocular_confidence.py --renders R1.json [R2.json ...] --speedplus S.json

Reads per-image records of ``bench/monocular.py`` (renders, ``--low-score 1`` so that every pose
is returned with its evidence) and of ``bench/monocular.py --speedplus DIR`` (the labelled SPEED+
development images). The rule is ``high`` when the chamfer score is at most ``high_score``, the
edge coverage at least ``high_coverage``, the orientation agreement at least
``high_orientation``, the margin to the best distinct candidate at least ``high_margin`` and the
face-shading spread at most ``high_spread``
(:func:`jaxpose.pipelines.monocular.classify`). Thresholds are chosen on a training set as the
rule that gives the most correct ``high`` answers with a training precision of at least
``--precision`` on the renders and on the SPEED+ images apart (the renders, far more numerous and
far cleaner, would otherwise set the rule for the photographs), among thresholds at the observed
values (the most conservative on ties).

Reported: the thresholds chosen on everything (renders and SPEED+ images together), and the
leave-one-out figures on the SPEED+ images: each image classified by thresholds chosen without
it (the renders always in the training set), so that no image grades itself.
"""

from __future__ import annotations

import argparse
import itertools
import json

import numpy as np

KEYS = ("score", "coverage", "orientation_agreement", "margin", "face_spread")
#: +1: high needs the quantity at most the threshold; -1: at least.
SIGNS = (1, -1, -1, -1, 1)


def _records(paths, source):
    out = []
    for p in paths:
        for r in json.load(open(p))["per_image"]:
            if r.get("score") is None or r.get("orientation_agreement") is None:
                continue
            out.append(
                {
                    "source": source,
                    "image": r.get("image", ""),
                    "success": bool(r["success"]),
                    "score": float(r["score"]),
                    "coverage": float(r["coverage"]),
                    "orientation_agreement": float(r["orientation_agreement"]),
                    "margin": np.inf if r.get("margin") is None else float(r["margin"]),
                    "face_spread": -np.inf
                    if r.get("face_spread") is None
                    else float(r["face_spread"]),
                }
            )
    return out


def _high(rec, th):
    return all(
        (rec[k] <= v) if sg > 0 else (rec[k] >= v) for k, sg, v in zip(KEYS, SIGNS, th, strict=True)
    )


def _choose(records, precision, grid=12, keys=KEYS):
    """Thresholds (one per quantity of ``KEYS``: at most for score and spread, at least for the
    others): the most correct ``high`` answers with training precision >= ``precision`` on the
    renders and on the SPEED+ images apart; ties to fewer wrong ones, then the first found
    (the strictest). Quantities not in ``keys`` are left open."""
    ok = [r for r in records if r["success"]]
    open_th = tuple(np.inf if sg > 0 else -np.inf for sg in SIGNS)
    if not ok:
        return tuple(-v for v in open_th)
    cands = []
    for k, sg in zip(KEYS, SIGNS, strict=True):
        if k not in keys:
            cands.append(np.array([np.inf if sg > 0 else -np.inf]))
            continue
        v = np.array([r[k] for r in ok])
        v = v[np.isfinite(v)]
        qs = np.unique(np.quantile(v, np.linspace(0, 1, grid))) if len(v) else np.array([])
        cands.append(np.concatenate([qs, [np.inf if sg > 0 else -np.inf]]))
    X = np.array([[r[k] for k in KEYS] for r in records])  # (N, K)
    succ = np.array([r["success"] for r in records])
    src = np.array([r["source"] for r in records])
    # pass[k][j, n]: record n passes threshold j of quantity k
    passes = [
        (X[None, :, k] <= c[:, None]) if sg > 0 else (X[None, :, k] >= c[:, None])
        for k, (c, sg) in enumerate(zip(cands, SIGNS, strict=True))
    ]
    best, best_key = tuple(-v for v in open_th), (0, 0)
    sources = [src == s for s in ("render", "speedplus")]
    for i0, i1, i2 in itertools.product(*(range(len(c)) for c in cands[:3])):
        base = passes[0][i0] & passes[1][i1] & passes[2][i2]
        if not base.any():
            continue
        sel = base[None, None] & passes[3][:, None] & passes[4][None]  # (J3, J4, N)
        n_sel = sel.sum(-1)
        good = (sel & succ).sum(-1)
        okp = n_sel > 0
        for m in sources:
            ns = (sel & m).sum(-1)
            gs = (sel & m & succ).sum(-1)
            okp &= gs >= precision * ns
        if not okp.any():
            continue
        score = np.where(okp, good * 10000 - (n_sel - good), -1)
        j3, j4 = np.unravel_index(np.argmax(score), score.shape)
        key = (int(good[j3, j4]), -int(n_sel[j3, j4] - good[j3, j4]))
        if key > best_key:
            best = (cands[0][i0], cands[1][i1], cands[2][i2], cands[3][j3], cands[4][j4])
            best_key = key
    return best


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--renders", nargs="*", default=[])
    ap.add_argument("--speedplus", nargs="*", default=[])
    ap.add_argument("--precision", type=float, default=0.95)
    ap.add_argument(
        "--keys",
        nargs="*",
        default=list(KEYS),
        help=f"the quantities the rule may use (default: all of {', '.join(KEYS)})",
    )
    args = ap.parse_args()
    renders = _records(args.renders, "render")
    dev = _records(args.speedplus, "speedplus")

    def choose(records, precision):  # noqa: F811 (the quantities asked for)
        return _choose(records, precision, keys=tuple(args.keys))

    th_all = choose(renders + dev, args.precision)
    print(
        "thresholds (score<=, coverage>=, orientation>=, margin>=, spread<=) on all:",
        tuple(float(x) for x in th_all),
    )
    for name, recs in (("renders", renders), ("speedplus (in-sample)", dev)):
        sel = [r for r in recs if _high(r, th_all)]
        print(
            f"{name}: {len(recs)} images, {sum(r['success'] for r in recs)} successes, "
            f"high {len(sel)}, of which right {sum(r['success'] for r in sel)}"
        )
    loo = []
    for i, r in enumerate(dev):
        th = choose(renders + dev[:i] + dev[i + 1 :], args.precision)
        loo.append((r, _high(r, th)))
    hi = [r for r, h in loo if h]
    print(
        f"speedplus leave-one-out: high {len(hi)} of {len(dev)}, right "
        f"{sum(r['success'] for r in hi)} (precision "
        f"{(sum(r['success'] for r in hi) / len(hi)) if hi else float('nan'):.2f})"
    )
    for r, h in loo:
        print(
            f"  {r['image']:26s} success={int(r['success'])} high={int(h)} "
            + " ".join(f"{k[:5]}={r[k]:.3f}" for k in KEYS)
        )


if __name__ == "__main__":
    main()
