"""Evaluation of the monocular initialisation on SPEED+ images (Park, Märtens, Lecuyer, Izzo,
D'Amico 2021): success as Sharma, Ventura, D'Amico (2018) define it, the ESA score as the 2021
competition (Kelvins, SPEC2021) computes it, both per domain.

Competition score of one image: ``e_t = ||t_true - t_est|| / ||t_true||`` and
``e_q = 2 arccos |<q_est, q_true>|`` (radians), each set to 0 below the precision of the lab's own
labels (``e_t < 2.173e-3``, ``e_q < 0.169 deg``); score ``e_q + e_t``, averaged over the images.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from jaxpose.core.geometry import Pose
from jaxpose.core.metrics import esa_score, rotation_error, success

__all__ = [
    "ESA_ORIENTATION_PRECISION_DEG",
    "ESA_POSITION_PRECISION",
    "competition_score",
    "evaluate_image",
    "evaluate_speedplus",
    "summarise",
]

#: Below these an error counts as zero in the 2021 competition's score (the lab's label precision):
#: relative position error (2.173 mm per metre of range) and orientation error (degrees).
ESA_POSITION_PRECISION = 2.173e-3
ESA_ORIENTATION_PRECISION_DEG = 0.169


def competition_score(pose_est: Pose, pose_true: Pose) -> tuple[float, float, float]:
    """``(score, e_q, e_t)`` of one image as the 2021 competition scores it (module docstring):
    :func:`jaxpose.core.metrics.esa_score` with the precision thresholds applied."""
    _, e_q, e_t = (float(x) for x in esa_score(pose_est, pose_true))
    if e_t < ESA_POSITION_PRECISION:
        e_t = 0.0
    if e_q < np.deg2rad(ESA_ORIENTATION_PRECISION_DEG):
        e_q = 0.0
    return e_q + e_t, e_q, e_t


def evaluate_image(result, truth: Pose) -> dict:
    """One per-image record of :func:`evaluate_speedplus` from an
    :class:`~jaxpose.pipelines.monocular.InitResult` and the labelled pose."""
    rng_true = float(np.linalg.norm(np.asarray(truth.t)))
    row = {
        "confidence": result.confidence,
        "group": result.group_kind,
        "range_true_m": rng_true,
        "coarse_range_m": None
        if result.coarse_t_cam is None
        else float(np.linalg.norm(result.coarse_t_cam)),
    }
    row["coarse_within_20pct"] = bool(
        row["coarse_range_m"] is not None and abs(row["coarse_range_m"] / rng_true - 1) <= 0.2
    )
    row["reprojection_error_px"] = result.to_json()["reprojection_error_px"]
    row["silhouette_iou"] = result.silhouette_iou  # None without a silhouette (Earth behind)
    # the evidence the confidence class reads (jaxpose.pipelines.monocular.classify)
    row["score"] = _finite_or_none(result.score)
    row["coverage"] = float(result.coverage)
    row["orientation_agreement"] = result.orientation_agreement
    row["margin"] = _finite_or_none(result.margin)
    row["face_spread"] = result.face_spread
    guess = result.pose
    if guess is not None:
        row["translation_error_m"] = float(jnp.linalg.norm(guess.t - truth.t))
        row["rotation_error_deg"] = float(np.rad2deg(rotation_error(guess.R, truth.R)))
        row["success"] = bool(success(guess, truth))
    else:
        row["success"] = False
        # a position-only answer is scored with the coarse position and an identity attitude
        if result.coarse_t_cam is not None:
            guess = Pose(jnp.eye(3), jnp.asarray(result.coarse_t_cam))
    if guess is not None:
        s, e_q, e_t = competition_score(guess, truth)
        row.update(esa_score=s, esa_orientation=e_q, esa_position=e_t)
    return row


def _finite_or_none(x):
    return float(x) if x is not None and np.isfinite(x) else None


def summarise(rows: list[dict]) -> dict:
    """Summary of per-image records: success rate, high-confidence count and precision, mean
    competition score (over the images with an answer; ``esa_unscored`` counts the others),
    coarse range within 20 %, median run time."""
    n = len(rows)
    if n == 0:
        return {"images": 0}
    high = [r for r in rows if r["confidence"] == "high"]
    times = [r["runtime_s"] for r in rows if "runtime_s" in r]
    esa = [r["esa_score"] for r in rows if r.get("esa_score") is not None]
    return {
        "images": n,
        "success_rate": sum(r["success"] for r in rows) / n,
        "high_confidence": len(high),
        "high_precision": (sum(r["success"] for r in high) / len(high)) if high else None,
        "esa_score_mean": float(np.mean(esa)) if esa else None,
        "esa_unscored": n - len(esa),
        "coarse_range_within_20pct": sum(r.get("coarse_within_20pct", False) for r in rows) / n,
        "median_runtime_s": float(np.median(times)) if times else None,
    }


def evaluate_speedplus(
    directory,
    *,
    domains=None,
    limit=None,
    model="tango",
    options=None,
    progress=True,
    on_result=None,
    records=None,
) -> dict:
    """Run :func:`~jaxpose.pipelines.monocular.initialise_pose` on every labelled image of a
    SPEED+ folder (:func:`jaxpose.io.load_speed_labels`: the data set's root or a folder with
    ``labels.csv``; ``camera.json`` at its root) and score it. ``domains``: the domains to run
    (default: all present). ``on_result(label, result, row)`` is called after each image run.

    ``records``: a JSON-lines file that keeps each image's record as soon as it is scored (a
    first line holds the settings' fingerprint: the model, the options and the camera), so that
    an interrupted run over the whole data set (SPEED+'s lightbox domain alone has 6740 images,
    more than an hour here) resumes where it stopped: an image already recorded with the same
    settings and label is not run again and keeps its record. Records made with other settings
    are replaced (the file starts anew).

    Returns the summary of :func:`summarise` with ``per_domain`` (the same summary per domain)
    and ``per_image`` (records with ``domain``, ``image``, ``confidence``, ``success``, the
    errors, ``esa_score`` and ``runtime_s``). The first image is run once before timing
    (compilation); ``runtime_s`` is the wall time of ``initialise_pose``.
    """
    from tqdm import tqdm

    from jaxpose.io import load_camera, load_image, load_speed_labels
    from jaxpose.pipelines.monocular import InitOptions, initialise_pose
    from jaxpose.vision.models import load_model

    directory = Path(directory)
    camera = load_camera(directory / "camera.json")
    labels = load_speed_labels(directory, domains)
    if limit is not None:
        if limit < 1:
            raise ValueError(f"--limit must be at least 1; got {limit}")
        labels = labels[:limit]
    if not labels:
        raise ValueError(f"{directory} lists no labelled image")
    mdl = load_model(model) if isinstance(model, str) else model
    opts = InitOptions() if options is None else options
    done, log = _open_records(records, _fingerprint(mdl, opts, camera), progress)
    todo = [lab for lab in labels if _key(lab) not in done]
    readable = next((lab for lab in todo if lab.image.is_file()), None)
    if readable is not None:
        from jaxpose.commands._common import stage

        with stage("eval-speedplus: compiling on the first image", enabled=progress):
            try:  # compile (not timed)
                initialise_pose(load_image(readable.image), camera, mdl, opts)
            except ValueError:
                pass
    rows = []
    try:
        for lab in tqdm(
            labels, desc="eval-speedplus", disable=not progress, unit="img", file=sys.stderr
        ):
            if _key(lab) in done:
                rows.append(done[_key(lab)])
                continue
            row = {"image": lab.image.name, "domain": lab.domain}
            try:
                image = load_image(lab.image)
            except ValueError as err:
                rows.append(row | {"confidence": "error", "message": str(err), "success": False})
                _record(log, lab, rows[-1])
                continue
            t0 = time.perf_counter()
            try:  # bad input only (an image of another size than the camera's): an error row
                res = initialise_pose(image, camera, mdl, opts)
            except ValueError as err:
                rows.append(row | {"confidence": "error", "message": str(err), "success": False})
                _record(log, lab, rows[-1])
                continue
            runtime = time.perf_counter() - t0
            R, t = np.asarray(lab.pose.R), np.asarray(lab.pose.t)
            row |= evaluate_image(res, Pose(jnp.asarray(R), jnp.asarray(t)))
            row["runtime_s"] = runtime
            rows.append(row)
            _record(log, lab, row)
            if on_result is not None:
                on_result(lab, res, row)
    finally:
        if log is not None:
            log.close()
    out = summarise(rows)
    out["per_domain"] = {
        d: summarise([r for r in rows if r["domain"] == d])
        for d in sorted({r["domain"] for r in rows})
    }
    out["per_image"] = rows
    return out


def _fingerprint(model, options, camera) -> str:
    """What a record depends on besides its image and label: the model's geometry, the options
    and the camera (a hash of their reprs)."""
    parts = [
        np.asarray(model.vertices).tobytes(),
        np.asarray(model.edges).tobytes(),
        repr(options).encode(),
        repr(camera).encode(),
    ]
    return hashlib.sha256(b"\0".join(parts)).hexdigest()[:16]


def _key(label) -> str:
    """An image's key in the records: its domain, its name and its label (a record scored
    against another label is not reused)."""
    pose = np.concatenate([np.ravel(label.pose.R), np.ravel(label.pose.t)])
    return f"{label.domain}/{label.image.name}/" + ",".join(f"{v:.9g}" for v in pose)


def _open_records(path, fingerprint: str, progress: bool):
    """``(records already made, by :func:`_key`; the file open for appending)`` of a records
    file (``None``: no file, nothing kept)."""
    if path is None:
        return {}, None
    path = Path(path)
    done = {}
    if path.is_file():
        lines = path.read_text().splitlines()
        try:
            head = json.loads(lines[0]) if lines else {}
        except json.JSONDecodeError:
            head = {}
        if isinstance(head, dict) and head.get("fingerprint") == fingerprint:
            for line in lines[1:]:
                try:
                    kept = json.loads(line)
                except json.JSONDecodeError:  # a line cut short by an interruption
                    continue
                if isinstance(kept, dict) and {"key", "row"} <= kept.keys():
                    done[kept["key"]] = kept["row"]
        elif progress:
            print(
                f"eval-speedplus: {path} was made with other settings: starting anew",
                file=sys.stderr,
            )
    if done and progress:
        print(f"eval-speedplus: {len(done)} images already scored in {path}", file=sys.stderr)
    # written anew with what is kept, so that a line cut short by an interruption goes
    path.parent.mkdir(parents=True, exist_ok=True)
    kept = [json.dumps({"fingerprint": fingerprint})]
    kept += [json.dumps({"key": k, "row": r}) for k, r in done.items()]
    path.write_text("\n".join(kept) + "\n")
    return done, path.open("a")


def _record(log, label, row: dict) -> None:
    if log is not None:
        log.write(json.dumps({"key": _key(label), "row": row}) + "\n")
        log.flush()
