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
                rec["alt_" + k] = np.nan if v is None else float(v)  # missing: fails
            out.append(rec)
    return out


def _high(rec, th, rule=KEYS, prefix=""):
    return all(
        (rec[prefix + k] <= v) if ALL_SIGNS[k] > 0 else (rec[prefix + k] >= v)
        for k, v in zip(rule, th, strict=True)
    )


def _high_either(rec, th, rule, th_alt, alt):
    """``high`` by the main rule, or by the alternative one (its quantities all present)."""
    return _high(rec, th, rule) or (bool(alt) and _high(rec, th_alt, alt, prefix="alt_"))


def _choose(
    records,
    precision,
    grid=12,
    keys=KEYS,
    precision_speedplus=None,
    rule=KEYS,
    already=None,
    prefix="",
    weights=(1.0, 1.0),
    tighten=False,
    widen=(),
):
    """Thresholds (one per quantity of ``rule``, at least 3: at most for score, spread and range
    agreement, at least for the others): the largest sum of the shares of each source's
    successes made ``high``, with training precision >= ``precision`` on the renders and on the
    SPEED+ images apart; ties to fewer wrong ones, then the first found. Quantities not in
    ``keys`` are left open. ``already`` (a mask of the records): those are ``high`` by another
    rule, and the precision and recall are those of either rule; ``prefix="alt_"`` reads the
    values with missing ones failing (NaN) instead of passing. ``weights``: of the renders' and
    the SPEED+ images' recall in the sum. ``tighten``: each threshold is then moved in to the
    least passing value among the successes it makes ``high`` (no training answer changes
    class; fewer near misses of new images pass). ``widen``: the thresholds of these quantities are
    moved out to halfway to the nearest wrong record that would pass (:func:`_widen`)."""
    SIGNS = tuple(ALL_SIGNS[k] for k in rule)  # noqa: N806
    KEYS = tuple(prefix + k for k in rule)  # noqa: N806
    keys = tuple(prefix + k for k in keys)
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
        if already is not None:
            sel = sel | already
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
        recall = sum(
            w * (sel & m & succ).sum(-1) / max((m & succ).sum(), 1)
            for w, m in zip(weights, sources, strict=True)
        )
        score = np.where(okp, np.round(recall, 9) * 1e4 - (n_sel - good), -1)
        j = np.unravel_index(np.argmax(score), score.shape)
        key = (float(np.round(recall[j], 9)), -int(n_sel[j] - good[j]))
        if key > best_key:
            best = tuple(cands[k][i] for k, i in enumerate(outer)) + tuple(
                cands[n_outer + k][j[k]] for k in range(3)
            )
            best_key = key
    if tighten and np.all(np.isfinite(best)):
        th = np.array(best, float)
        mine = np.all(
            [
                (X[:, k] <= v) if sg > 0 else (X[:, k] >= v)
                for k, (v, sg) in enumerate(zip(th, SIGNS, strict=True))
            ],
            axis=0,
        )
        mine &= succ
        if already is not None:
            mine &= ~already
        if mine.any():
            best = tuple(
                float(X[mine, k].max() if sg > 0 else X[mine, k].min())
                for k, sg in enumerate(SIGNS)
            )
    if widen and np.all(np.isfinite(best)):
        which = [k in widen for k in rule]
        best = _widen(np.array(best, float), X, succ, SIGNS, already, which)
    return best


def _widen(th, X, succ, signs, already, which):
    """Each threshold moved out, the others held, to halfway to the nearest value beyond it of a
    wrong record that passes the other conditions (and is not ``high`` already): the margin
    between the successes made ``high`` and the nearest wrong answer, split evenly (none: kept).
    No training record changes class."""
    out = th.copy()
    sg = np.array(signs, float)
    passes = X * sg[None] <= th * sg  # (N, K); NaN fails
    wrong = ~succ if already is None else (~succ & ~already)
    for k in range(len(th)):
        if not which[k]:
            continue
        others = np.delete(passes, k, axis=1).all(axis=1)
        v = X[wrong & others, k] * sg[k]
        v = v[np.isfinite(v) & (v > th[k] * sg[k])]
        if len(v):
            out[k] = 0.5 * (th[k] * sg[k] + v.min()) * sg[k]
    return tuple(float(x) for x in out)


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
        "--held-out",
        nargs="*",
        default=[],
        help="render records not used for the choice, classified by the rule chosen on all",
    )
    ap.add_argument(
        "--alt-photographs",
        action="store_true",
        help="the alternative rule counts the SPEED+ images' recall only (the renders' precision "
        "still binds)",
    )
    ap.add_argument(
        "--tighten",
        action="store_true",
        help="move the alternative rule's thresholds in to the least passing value among the "
        "successes it makes high",
    )
    ap.add_argument(
        "--widen",
        nargs="*",
        default=[],
        help="quantities of the alternative rule whose thresholds move out to halfway to the "
        "nearest wrong answer that would pass",
    )
    ap.add_argument("--no-loo", action="store_true", help="skip the leave-one-out")
    ap.add_argument(
        "--alt-rule",
        nargs="*",
        default=[],
        help="a second rule (at least 3 quantities; a record must have them all, e.g. the "
        "silhouette IoU): high by either; its thresholds are chosen after the first rule's",
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
    alt = tuple(args.alt_rule)
    for r_ in (rule, alt) if alt else (rule,):
        if len(r_) < 3 or any(k not in ALL_SIGNS for k in r_):
            raise SystemExit(f"a rule needs at least 3 of {', '.join(ALL_SIGNS)}; got {r_}")

    def choose_both(records, precision):
        th = choose(records, precision)
        if not alt:
            return th, ()
        first = np.array([_high(r, th, rule) for r in records])
        th_alt = _choose(
            records,
            precision,
            keys=tuple(alt),
            precision_speedplus=args.precision_speedplus,
            rule=alt,
            already=first,
            prefix="alt_",
            weights=(0.0, 1.0) if args.alt_photographs else (1.0, 1.0),
            tighten=args.tighten,
            widen=tuple(args.widen),
        )
        return th, th_alt

    th_all, th_alt = choose_both(renders + dev, args.precision)

    def show(rule_, th):
        return ", ".join(
            f"{k} {'<=' if ALL_SIGNS[k] > 0 else '>='} {float(v):.4g}"
            for k, v in zip(rule_, th, strict=True)
        )

    print("thresholds on all:", show(rule, th_all))
    if alt:
        print("or (the alternative rule):", show(alt, th_alt))

    def is_high(r, th, th2):
        return _high_either(r, th, rule, th2, alt)

    held = _records(args.held_out, "render", args.spread_key)
    sets = (("renders", renders), ("speedplus (in-sample)", dev), ("held-out renders", held))
    for name, recs in sets:
        if not recs:
            continue
        sel = [r for r in recs if is_high(r, th_all, th_alt)]
        print(
            f"{name}: {len(recs)} images, {sum(r['success'] for r in recs)} successes, "
            f"high {len(sel)}, of which right {sum(r['success'] for r in sel)}"
        )
    if args.no_loo:
        return
    loo = []
    for i, r in enumerate(dev):
        th, th2 = choose_both(renders + dev[:i] + dev[i + 1 :], args.precision)
        loo.append((r, is_high(r, th, th2)))
    hi = [r for r, h in loo if h]
    print(
        f"speedplus leave-one-out: high {len(hi)} of {len(dev)}, right "
        f"{sum(r['success'] for r in hi)} (precision "
        f"{(sum(r['success'] for r in hi) / len(hi)) if hi else float('nan'):.2f})"
    )
    for r, h in loo:
        print(
            f"  {r['image']:26s} success={int(r['success'])} high={int(h)} "
            + " ".join(f"{k[:5]}={r[k]:.3f}" for k in dict.fromkeys(rule + alt))
        )


if __name__ == "__main__":
    main()
