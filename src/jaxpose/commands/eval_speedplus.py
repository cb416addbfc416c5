"""``jaxpose eval-speedplus ROOT [--domain NAME ...] [--json] [--limit N] [--out DIR] [--option
NAME=VALUE ...]``: run the monocular initialisation on every labelled image of a SPEED+ folder and
score it (:func:`jaxpose.studies.speedplus.evaluate_speedplus`).

With ``--out DIR``: ``DIR/records.jsonl`` keeps each image's record as soon as it is scored, so
that a run over the whole data set resumes where it stopped when run again with the same
settings; ``DIR/summary.json`` (the ``--json`` object) and ``DIR/errors.png`` (every image's
position and attitude errors against the success region, success and confidence per domain) are
written at the end.

``ROOT`` is the SPEED+ data set's root (``camera.json`` and per domain ``images/`` with a JSON
label file: ``synthetic/train.json``, ``synthetic/validation.json``, ``lightbox/test.json``,
``sunlamp/test.json``) or a folder with ``labels.csv`` and ``camera.json``.
"""

from __future__ import annotations

import json
from pathlib import Path

from jaxpose.commands._common import add_option_argument, add_progress_argument, with_options


def add_arguments(parser) -> None:
    parser.add_argument(
        "directory",
        help="SPEED+ root (camera.json, DOMAIN/images/, DOMAIN/*.json) or a folder with "
        "labels.csv and camera.json",
    )
    parser.add_argument(
        "--domain",
        action="append",
        default=None,
        metavar="NAME",
        help="run only this domain (repeat for several; e.g. lightbox, sunlamp, synthetic); "
        "default: every domain present",
    )
    parser.add_argument(
        "--json", action="store_true", help="print the summary as JSON on the last line"
    )
    parser.add_argument(
        "--limit", type=int, default=None, help="only the first N images (default: all)"
    )
    parser.add_argument(
        "--model", default="tango", help="'tango', a model .json or a mesh (default: tango)"
    )
    parser.add_argument(
        "--method", choices=("svd", "ransac"), default="svd", help="pose search (default: svd)"
    )
    parser.add_argument(
        "--detector",
        choices=("hough", "lsd"),
        default="hough",
        help="line detector (default: hough)",
    )
    parser.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="write records.jsonl (each image as it is scored; a rerun with the same settings "
        "resumes from it), summary.json and errors.png here",
    )
    add_option_argument(
        parser, "InitOptions (jaxpose.pipelines.monocular)", "detection.detector=lsd"
    )
    add_progress_argument(parser)


def evaluate(
    directory,
    *,
    domains=None,
    limit=None,
    model="tango",
    method="svd",
    detector="hough",
    progress=True,
    option_items=(),
    records=None,
) -> dict:
    """The evaluation as a dict (the fields of ``--json``); ``option_items``: ``NAME=VALUE``
    strings of ``--option`` (:func:`jaxpose.commands._common.with_options`); ``records``: the
    records file to resume from and append to."""
    from jaxpose.pipelines.monocular import InitOptions
    from jaxpose.studies.speedplus import evaluate_speedplus
    from jaxpose.vision.features import DetectionOptions

    opts = InitOptions(method=method, detection=DetectionOptions(detector=detector))
    opts = with_options(opts, option_items)
    return evaluate_speedplus(
        directory,
        domains=domains,
        limit=limit,
        model=model,
        options=opts,
        progress=progress,
        records=records,
    )


def _fmt(x, spec):
    return "-" if x is None else format(x, spec)


def run(args) -> int:
    from jaxpose.commands import enable_compilation_cache

    enable_compilation_cache()
    out_dir = None if args.out is None else Path(args.out)
    if out_dir is not None:  # before any image is run
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise ValueError(f"--out {out_dir}: cannot make this folder ({err.strerror})") from None
    out = evaluate(
        args.directory,
        domains=args.domain,
        limit=args.limit,
        model=args.model,
        method=args.method,
        detector=args.detector,
        progress=not args.no_progress,
        option_items=args.option,
        records=None if out_dir is None else out_dir / "records.jsonl",
    )
    if out_dir is not None:
        from jaxpose.io.software import software_versions
        from jaxpose.studies._speedplus_figures import plot_errors

        summary = {**out, "software": software_versions()}
        (out_dir / "summary.json").write_text(json.dumps(summary, indent=1))
        plot_errors(out_dir / "errors.png", out)
    row = "{:28s} {:9s} {:13s} {:>7s} {:>8s} {:>6s} {:>6s} {:>6s} {:>6s} {}"
    print(
        row.format(
            "image", "domain", "conf", "E_T m", "E_R deg", "ESA", "range", "coarse", "time s", "ok"
        )
    )
    for r in out["per_image"]:
        cells = (
            r["image"],
            r["domain"],
            r["confidence"],
            _fmt(r.get("translation_error_m"), "7.3f"),
            _fmt(r.get("rotation_error_deg"), "8.2f"),
            _fmt(r.get("esa_score"), "6.3f"),
            _fmt(r.get("range_true_m"), "6.2f"),
            _fmt(r.get("coarse_range_m"), "6.2f"),
            _fmt(r.get("runtime_s"), "6.2f"),
            "yes" if r["success"] else "no",
        )
        print(row.format(*cells))
    for name, s in [*out["per_domain"].items(), ("all", out)]:
        print(
            f"{name}: {s['images']} images, success {s['success_rate']:.0%}, "
            f"high confidence {s['high_confidence']} "
            f"(precision {_fmt(s['high_precision'], '.0%')}), "
            f"ESA score {_fmt(s['esa_score_mean'], '.3f')}, "
            f"coarse range within 20% {s['coarse_range_within_20pct']:.0%}, "
            f"median {_fmt(s['median_runtime_s'], '.2f')} s"
        )
    if out_dir is not None:
        print(f"records, summary.json and errors.png in {out_dir}")
    if args.json:
        print(json.dumps(out))
    return 0
