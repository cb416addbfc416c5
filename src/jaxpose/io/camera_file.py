"""Camera files: SPEED's ``camera.json`` layout (``cameraMatrix``, ``distCoeffs``, ``Nu``,
``Nv``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from jaxpose.core.camera import PinholeCamera

__all__ = ["load_camera", "save_camera"]


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
