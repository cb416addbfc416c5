"""File I/O: cameras, SPEED+ labels, study results. The one place for frame conversions of files.

SPEED / SPEED+ labels give ``q_vbs2tango`` (scalar-first) and ``r_Vo2To_vbs``. The data README
(``../shared/data/speedplus/README.md``) defines ``dcm = quat2dcm(q)`` mapping camera vectors into
the Tango frame, so ``R_cam_body = dcm.T``, which is the *active* matrix of ``q``:
``R_cam_body = quat_to_dcm(q)``, and ``t_cam = r_Vo2To_vbs``.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.geometry import Pose, quat_to_dcm

__all__ = ["SpeedLabel", "load_camera", "load_speed_labels", "save_camera", "speed_label_pose"]


def load_camera(path: str | Path) -> PinholeCamera:
    """Read a camera file: SPEED's ``camera.json`` (``cameraMatrix``, ``distCoeffs``, ``Nu``,
    ``Nv``).

    Raises ``ValueError`` naming the file and the missing or malformed field.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"camera file not found: {path}") from None
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(f"cannot read camera file {path}: {err}") from None
    if not isinstance(data, dict):
        raise ValueError(f"camera file {path} must hold a JSON object")
    if "cameraMatrix" in data:
        K = np.asarray(data["cameraMatrix"], dtype=float)
    elif all(k in data for k in ("fx", "fy", "cx", "cy")) and "ppx" not in data:
        K = np.array([[data["fx"], 0, data["cx"]], [0, data["fy"], data["cy"]], [0, 0, 1.0]])
    else:
        raise ValueError(f"camera file {path} has no 'cameraMatrix' (nor fx, fy, cx, cy in pixels)")
    if K.shape != (3, 3):
        raise ValueError(f"camera file {path}: cameraMatrix must be 3x3, got shape {K.shape}")
    dist = data.get("distCoeffs", data.get("dist"))
    width = int(data.get("Nu", data.get("width", 0)))
    height = int(data.get("Nv", data.get("height", 0)))
    return PinholeCamera.from_K(K, dist, width=width, height=height)


def save_camera(camera: PinholeCamera, path: str | Path) -> None:
    """Write a camera in the SPEED ``camera.json`` layout (readable by :func:`load_camera`)."""
    data = {
        "Nu": camera.width,
        "Nv": camera.height,
        "cameraMatrix": np.asarray(camera.K).tolist(),
        "distCoeffs": np.asarray(camera.dist).tolist(),
    }
    Path(path).write_text(json.dumps(data, indent=1))


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
