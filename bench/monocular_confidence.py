"""Calibration of the monocular confidence class (``high``) by leave-one-out.

    python bench/monocular_confidence.py --renders R1.json [R2.json ...] --speedplus S.json

Reads per-image records of ``bench/monocular.py`` (renders, ``--low-score 1`` so that every pose
is returned with its evidence) and of ``bench/monocular.py --speedplus DIR`` (the labelled SPEED+
development images). The rule is ``high`` when the chamfer score is at most ``high_score``, the
edge coverage at least ``high_coverage``, the orientation agreement at least
``high_orientation``, the margin to the best distinct candidate at least ``high_margin`` and the
face-shading spread at most ``high_spread``
(:func:`jaxpose.pipelines.monocular.classify`). Thresholds are chosen on a training set as the
rule that makes ``high`` the largest share of the successes of the renders plus the largest share
of the successes of the SPEED+ images (each source weighs the same: the renders, far more
numerous and far cleaner, would otherwise set the rule for the photographs), with a training
precision of at least ``--precision`` on the renders and on the SPEED+ images apart, among
thresholds at the quantiles of each source's successes (fewer wrong ``high`` answers on ties).

Reported: the thresholds chosen on everything (renders and SPEED+ images together), and the
leave-one-out figures on the SPEED+ images: each image classified by thresholds chosen without
it (the renders always in the training set), so that no image grades itself.
"""

from __future__ import annotations

import argparse
import itertools
import json

import numpy as np

#: Every quantity a rule may use, with +1: high needs it at most the threshold; -1: at least.
#: A record without the quantity (no silhouette, no pose) passes its condition.
ALL_SIGNS = {
    "score": 1,
    "coverage": -1,
    "orientation_agreement": -1,
    "margin": -1,
    "face_spread": 1,
    "range_agreement": 1,
    "silhouette_iou": -1,
    "e2d_rel": 1,
}
#: The quantities of the rule in use (:data:`jaxpose.pipelines.monocular.CONFIDENCE`).
KEYS = ("score", "coverage", "orientation_agreement", "margin", "face_spread")
SIGNS = tuple(ALL_SIGNS[k] for k in KEYS)


def _records(paths, source, spread_key="face_spread"):
    out = []
    for p in paths:
        for r in json.load(open(p))["per_image"]:
            if r.get("score") is None or r.get("orientation_agreement") is None:
                continue
            rec = {"source": source, "image": r.get("image", ""), "success": bool(r["success"])}
            for k, sg in ALL_SIGNS.items():
                v = r.get(spread_key if k == "face_spread" else k)
                rec[k] = -sg * np.inf if v is None else float(v)  # missing: passes
            out.append(rec)
    return out


def _high(rec, th, rule=KEYS):
    return all(
        (rec[k] <= v) if ALL_SIGNS[k] > 0 else (rec[k] >= v) for k, v in zip(rule, th, strict=True)
    )


def _choose(records, precision, grid=12, keys=KEYS, precision_speedplus=None, rule=KEYS):
    """Thresholds (one per quantity of ``rule``, at least 3: at most for score, spread and range
    agreement, at least for the others): the largest sum of the shares of each source's
    successes made ``high``, with training precision >= ``precision`` on the renders and on the
    SPEED+ images apart; ties to fewer wrong ones, then the first found. Quantities not in
    ``keys`` are left open."""
    SIGNS = tuple(ALL_SIGNS[k] for k in rule)  # noqa: N806
    KEYS = rule  # noqa: N806
    ok = [r for r in records if r["success"]]
    open_th = tuple(np.inf if sg > 0 else -np.inf for sg in SIGNS)
    if not ok:
        return tuple(-v for v in open_th)
    cands = []
    for k, sg in zip(KEYS, SIGNS, strict=True):
        if k not in keys:
            cands.append(np.array([np.inf if sg > 0 else -np.inf]))
            continue
        qs = []  # quantiles of the successes of each source apart (the photographs' own values)
        for s in ("render", "speedplus"):
            v = np.array([r[k] for r in ok if r["source"] == s])
            v = v[np.isfinite(v)]
            if len(v):
                qs.append(np.quantile(v, np.linspace(0, 1, grid)))
        qs = np.unique(np.concatenate(qs)) if qs else np.array([])
        cands.append(np.concatenate([qs, [np.inf if sg > 0 else -np.inf]]))
    X = np.array([[r[k] for k in KEYS] for r in records])  # (N, K)
    succ = np.array([r["success"] for r in records])
    src = np.array([r["source"] for r in records])
    # pass[k][j, n]: record n passes threshold j of quantity k
    passes = [
        (X[None, :, k] <= c[:, None]) if sg > 0 else (X[None, :, k] >= c[:, None])
        for k, (c, sg) in enumerate(zip(cands, SIGNS, strict=True))
    ]
    best, best_key = tuple(-v for v in open_th), (0.0, 0)
    sources = [src == s for s in ("render", "speedplus")]
    n_outer = len(KEYS) - 3
    for outer in itertools.product(*(range(len(c)) for c in cands[:n_outer])):
        base = np.ones(len(records), bool)
        for k, i in enumerate(outer):
            base = base & passes[k][i]
        if not base.any():
            continue
        # (J, J, J, N): every threshold of the last three quantities at once
        p2, p3, p4 = passes[n_outer:]
        sel = base & p2[:, None, None] & p3[None, :, None] & p4[None, None]
        n_sel = sel.sum(-1)
        good = (sel & succ).sum(-1)
        okp = n_sel > 0
        for m, p in zip(sources, (precision, precision_speedplus or precision), strict=True):
            ns = (sel & m).sum(-1)
            gs = (sel & m & succ).sum(-1)
            okp &= gs >= p * ns
        if not okp.any():
            continue
        # the share of each source's successes made high, summed (a photograph weighs as much
        # as the renders together: they are what the rule is for), then fewer wrong highs
        recall = sum((sel & m & succ).sum(-1) / max((m & succ).sum(), 1) for m in sources)
        score = np.where(okp, np.round(recall, 9) * 1e4 - (n_sel - good), -1)
        j = np.unravel_index(np.argmax(score), score.shape)
        key = (float(np.round(recall[j], 9)), -int(n_sel[j] - good[j]))
        if key > best_key:
            best = tuple(cands[k][i] for k, i in enumerate(outer)) + tuple(
                cands[n_outer + k][j[k]] for k in range(3)
            )
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
        "--precision-speedplus",
        type=float,
        default=None,
        help="the training precision asked on the SPEED+ images (default: --precision)",
    )
    ap.add_argument(
        "--keys",
        nargs="*",
        default=list(KEYS),
        help=f"the quantities the rule may use (default: all of {', '.join(KEYS)})",
    )
    ap.add_argument(
        "--rule",
        nargs="*",
        default=list(KEYS),
        help=f"the quantities of the rule, at least 3 (default: {', '.join(KEYS)}; "
        f"any of {', '.join(ALL_SIGNS)})",
    )
    ap.add_argument(
        "--spread-key",
        default="face_spread",
        help="the record field read as the spread (face_spread_bg: with the background label)",
    )
    args = ap.parse_args()
    renders = _records(args.renders, "render", args.spread_key)
    dev = _records(args.speedplus, "speedplus", args.spread_key)

    def choose(records, precision):  # noqa: F811 (the quantities asked for)
        return _choose(
            records,
            precision,
            keys=tuple(args.keys),
            precision_speedplus=args.precision_speedplus,
            rule=rule,
        )

    rule = tuple(args.rule)
    if len(rule) < 3 or any(k not in ALL_SIGNS for k in rule):
        raise SystemExit(f"--rule needs at least 3 of {', '.join(ALL_SIGNS)}; got {rule}")

    th_all = choose(renders + dev, args.precision)
    print(
        "thresholds on all:",
        ", ".join(
            f"{k} {'<=' if ALL_SIGNS[k] > 0 else '>='} {float(v):.4g}"
            for k, v in zip(rule, th_all, strict=True)
        ),
    )
    for name, recs in (("renders", renders), ("speedplus (in-sample)", dev)):
        sel = [r for r in recs if _high(r, th_all, rule)]
        print(
            f"{name}: {len(recs)} images, {sum(r['success'] for r in recs)} successes, "
            f"high {len(sel)}, of which right {sum(r['success'] for r in sel)}"
        )
    loo = []
    for i, r in enumerate(dev):
        th = choose(renders + dev[:i] + dev[i + 1 :], args.precision)
        loo.append((r, _high(r, th, rule)))
    hi = [r for r, h in loo if h]
    print(
        f"speedplus leave-one-out: high {len(hi)} of {len(dev)}, right "
        f"{sum(r['success'] for r in hi)} (precision "
        f"{(sum(r['success'] for r in hi) / len(hi)) if hi else float('nan'):.2f})"
    )
    for r, h in loo:
        print(
            f"  {r['image']:26s} success={int(r['success'])} high={int(h)} "
            + " ".join(f"{k[:5]}={r[k]:.3f}" for k in rule)
        )


if __name__ == "__main__":
    main()
