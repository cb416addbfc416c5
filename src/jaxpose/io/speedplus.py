"""SPEED / SPEED+ labels (Park, Märtens, Lecuyer, Izzo, D'Amico 2021). The one place for the
conversion of their frames.

SPEED / SPEED+ labels give ``q_vbs2tango`` (scalar-first) and ``r_Vo2To_vbs``. The data set
defines ``dcm = quat2dcm(q)`` mapping camera vectors into the Tango frame, so
``R_cam_body = dcm.T``, which is the *active* matrix of ``q``: ``R_cam_body = quat_to_dcm(q)``,
and ``t_cam = r_Vo2To_vbs``.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxpose.core.geometry import Pose, quat_to_dcm

__all__ = ["SpeedLabel", "load_speed_labels", "speed_label_pose"]


@dataclass(frozen=True)
class SpeedLabel:
    """One row of a SPEED+ ``labels.csv``: image path, domain and ground-truth pose."""

    image: Path
    domain: str
    q_vbs2tango: np.ndarray  # (4,) scalar-first
    r_Vo2To_vbs: np.ndarray  # (3,) metres

    @property
    def pose(self) -> Pose:
        return speed_label_pose(self.q_vbs2tango, self.r_Vo2To_vbs)


def speed_label_pose(q_vbs2tango, r_Vo2To_vbs) -> Pose:
    """Pose ``(R_cam_body, t_cam)`` of a SPEED label (see module docstring)."""
    q = np.asarray(q_vbs2tango, dtype=float)
    return Pose(quat_to_dcm(q), np.asarray(r_Vo2To_vbs, dtype=float))


def load_speed_labels(directory: str | Path) -> list[SpeedLabel]:
    """Read ``DIR/labels.csv`` (columns ``image, domain, qw, qx, qy, qz, tx, ty, tz``)."""
    directory = Path(directory)
    path = directory / "labels.csv"
    if not path.is_file():
        raise ValueError(f"no labels.csv in {directory}")
    rows = []
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        need = {"image", "qw", "qx", "qy", "qz", "tx", "ty", "tz"}
        missing = need - set(reader.fieldnames or [])
        if missing:
            raise ValueError(f"{path} lacks columns {sorted(missing)}")
        for line, row in enumerate(reader, start=2):
            try:
                q = np.array([float(row[k]) for k in ("qw", "qx", "qy", "qz")])
                t = np.array([float(row[k]) for k in ("tx", "ty", "tz")])
            except ValueError as err:
                raise ValueError(f"{path}:{line}: {err}") from None
            rows.append(SpeedLabel(directory / row["image"], row.get("domain", ""), q, t))
    return rows
