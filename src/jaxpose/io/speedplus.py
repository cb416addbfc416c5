"""SPEED / SPEED+ labels (Park, Märtens, Lecuyer, Izzo, D'Amico 2021). The one place for the
conversion of their frames.

SPEED / SPEED+ labels give ``q_vbs2tango`` (scalar-first) and ``r_Vo2To_vbs``. The data set
defines ``dcm = quat2dcm(q)`` mapping camera vectors into the Tango frame, so
``R_cam_body = dcm.T``, which is the *active* matrix of ``q``: ``R_cam_body = quat_to_dcm(q)``,
and ``t_cam = r_Vo2To_vbs``.

Two layouts are read (:func:`load_speed_labels`):

- the data set's own root: ``camera.json`` and, per domain, a folder with ``images/`` and a JSON
  label file (``synthetic/train.json``, ``synthetic/validation.json``, ``lightbox/test.json``,
  ``sunlamp/test.json``), a list of ``{"filename", "q_vbs2tango_true", "r_Vo2To_vbs_true"}``
  (SPEED 2019 writes ``q_vbs2tango`` and ``r_Vo2To_vbs_true``; its root holds ``train.json`` or
  ``real.json`` with the images in ``images/train/`` or ``images/real/``);
- a folder with ``labels.csv``: one row an image, columns ``image`` (path relative to the
  folder), ``domain`` (optional), ``qw, qx, qy, qz``, ``tx, ty, tz``.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxpose.core.geometry import Pose, quat_to_dcm

__all__ = ["SpeedLabel", "load_speed_labels", "speed_label_pose", "speedplus_domains"]

#: Quaternion keys and translation keys of a JSON label, in the order they are tried.
_Q_KEYS = ("q_vbs2tango_true", "q_vbs2tango")
_T_KEYS = ("r_Vo2To_vbs_true", "r_Vo2To_vbs")
#: A label quaternion's norm must be within this of 1 (the data set's are unit to 1e-7).
_Q_NORM_TOL = 1e-3


@dataclass(frozen=True)
class SpeedLabel:
    """One labelled image: image path, domain and ground-truth pose."""

    image: Path
    domain: str
    q_vbs2tango: np.ndarray  # (4,) scalar-first, unit
    r_Vo2To_vbs: np.ndarray  # (3,) metres

    @property
    def pose(self) -> Pose:
        return speed_label_pose(self.q_vbs2tango, self.r_Vo2To_vbs)


def speed_label_pose(q_vbs2tango, r_Vo2To_vbs) -> Pose:
    """Pose ``(R_cam_body, t_cam)`` of a SPEED label (see module docstring)."""
    q = np.asarray(q_vbs2tango, dtype=float)
    return Pose(quat_to_dcm(q), np.asarray(r_Vo2To_vbs, dtype=float))


def _checked(q, t, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The label's quaternion ``(4,)`` and translation ``(3,)`` as floats; ``ValueError`` naming
    ``where`` when either is malformed, not finite, the quaternion not of unit norm or the
    translation zero (the ESA score divides by its norm)."""
    try:
        q = np.asarray(q, dtype=float).reshape(-1)
        t = np.asarray(t, dtype=float).reshape(-1)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{where}: the pose is not numeric ({err})") from None
    if q.shape != (4,):
        raise ValueError(f"{where}: the quaternion needs 4 numbers (qw, qx, qy, qz); got {q.size}")
    if t.shape != (3,):
        raise ValueError(f"{where}: the translation needs 3 numbers (x, y, z); got {t.size}")
    if not np.all(np.isfinite(q)):
        raise ValueError(f"{where}: the quaternion is not finite: {q.tolist()}")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"{where}: the translation is not finite: {t.tolist()}")
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > _Q_NORM_TOL:
        raise ValueError(
            f"{where}: the quaternion must have unit norm (a rotation); got norm {n:.6g}"
        )
    if not np.linalg.norm(t) > 0:
        raise ValueError(f"{where}: the translation is zero (the target at the camera centre)")
    return q / n, t


def _read_csv(directory: Path) -> list[SpeedLabel]:
    path = directory / "labels.csv"
    rows = []
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        need = {"image", "qw", "qx", "qy", "qz", "tx", "ty", "tz"}
        missing = need - set(reader.fieldnames or [])
        if missing:
            raise ValueError(f"{path} lacks columns {sorted(missing)}")
        for line, row in enumerate(reader, start=2):
            where = f"{path}:{line}"
            if None in row or any(row.get(k) in (None, "") for k in need):
                empty = sorted(k for k in need if row.get(k) in (None, ""))
                if None in row:
                    raise ValueError(f"{where}: the row has more fields than the header")
                raise ValueError(f"{where}: the row lacks {', '.join(empty)} (a short row?)")
            try:
                q = [float(row[k]) for k in ("qw", "qx", "qy", "qz")]
                t = [float(row[k]) for k in ("tx", "ty", "tz")]
            except ValueError as err:
                raise ValueError(f"{where}: {err}") from None
            q, t = _checked(q, t, where)
            rows.append(SpeedLabel(directory / row["image"], row.get("domain") or "", q, t))
    return rows


def _read_json(path: Path, images: Path, domain: str) -> list[SpeedLabel]:
    """Labels of one SPEED / SPEED+ JSON file; images under ``images``. Entries without a pose
    (a test split without labels) are skipped."""
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(f"cannot read label file {path}: {err}") from None
    if not isinstance(data, list):
        raise ValueError(f"label file {path} must hold a JSON list of labels")
    rows = []
    for i, entry in enumerate(data):
        where = f"{path}, entry {i}"
        if not isinstance(entry, dict) or not isinstance(entry.get("filename"), str):
            raise ValueError(f"{where}: a label must be an object with a 'filename' string")
        qk = next((k for k in _Q_KEYS if k in entry), None)
        tk = next((k for k in _T_KEYS if k in entry), None)
        if qk is None and tk is None:
            continue
        if qk is None or tk is None:
            lacking = "a quaternion (q_vbs2tango_true)" if qk is None else "r_Vo2To_vbs_true"
            raise ValueError(f"{where} ({entry['filename']}): lacks {lacking}")
        q, t = _checked(entry[qk], entry[tk], f"{where} ({entry['filename']})")
        rows.append(SpeedLabel(images / entry["filename"], domain, q, t))
    return rows


def speedplus_domains(root: str | Path) -> dict[str, list[Path]]:
    """The label files of a SPEED / SPEED+ root by domain: ``{domain: [json, ...]}`` (SPEED+:
    every sub-folder with ``images/`` and ``*.json``; SPEED 2019: ``ROOT/NAME.json`` with
    ``ROOT/images/NAME/``). Empty for a folder with ``labels.csv``."""
    root = Path(root)
    out: dict[str, list[Path]] = {}
    for sub in sorted(p for p in root.iterdir() if p.is_dir()):
        files = sorted(sub.glob("*.json"))
        if files and (sub / "images").is_dir():
            out[sub.name] = files
    for f in sorted(root.glob("*.json")):
        if (root / "images" / f.stem).is_dir():
            out.setdefault(f.stem, []).append(f)
    return out


def load_speed_labels(
    directory: str | Path, domains: list[str] | tuple[str, ...] | None = None
) -> list[SpeedLabel]:
    """Labels of a SPEED+ folder: ``DIR/labels.csv`` when there is one, otherwise the data set's
    own layout (module docstring). ``domains``: keep only these (default: every domain present);
    a domain that is not there is a ``ValueError`` naming the ones that are.

    Raises ``ValueError`` naming the file and the line (CSV) or entry (JSON) of a malformed label:
    a short row, a non-numeric field, a quaternion that is zero, not finite or not of unit norm,
    a translation that is not finite or zero.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f"SPEED+ folder not found: {directory}")
    if (directory / "labels.csv").is_file():
        rows = _read_csv(directory)
        present = sorted({r.domain for r in rows})
    else:
        files = speedplus_domains(directory)
        if not files:
            raise ValueError(
                f"no labels in {directory}: expected labels.csv, or the SPEED+ layout "
                "(DOMAIN/images/ with DOMAIN/*.json, e.g. lightbox/test.json)"
            )
        present = sorted(files)
        rows = []
        for dom in present if domains is None else [d for d in domains if d in files]:
            for f in files[dom]:
                images = (
                    f.parent / "images" if f.parent != directory else directory / "images" / f.stem
                )
                rows += _read_json(f, images, dom)
    if domains is not None:
        unknown = sorted(set(domains) - set(present))
        if unknown:
            raise ValueError(
                f"domain {', '.join(unknown)} not in {directory}; present: {', '.join(present)}"
            )
        rows = [r for r in rows if r.domain in set(domains)]
    return rows
