"""Camera files: SPEED's ``camera.json`` layout (``cameraMatrix``, ``distCoeffs``, ``Nu``,
``Nv``)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from jaxpose.core._checks import intrinsic_matrix_problem
from jaxpose.core.camera import PinholeCamera

__all__ = ["load_camera", "save_camera"]


def load_camera(path: str | Path) -> PinholeCamera:
    """Read a camera file: SPEED's ``camera.json`` (``cameraMatrix``, ``distCoeffs``, ``Nu``,
    ``Nv``), or ``fx, fy, cx, cy`` (pixels) instead of ``cameraMatrix``, ``dist`` for
    ``distCoeffs``, ``width``/``height`` for ``Nu``/``Nv``.

    Raises ``ValueError`` naming the file and the missing or malformed field: a matrix that is
    not 3x3 numbers (a number given as a string or a bool included), a non-positive or non-finite
    focal length, a non-finite principal point or, with a known image size, one outside the image
    (``cx`` not in ``[0, Nu]``, ``cy`` not in ``[0, Nv]``), a ``cameraMatrix`` with a skew or a
    last row other than ``(0, 0, 1)`` (not supported), distortion coefficients that are not 4 or
    5 finite numbers, an image size that is not a non-negative integer, or a ``path`` that is not
    a path.
    """
    if not isinstance(path, str | os.PathLike):
        raise ValueError(
            f"load_camera takes the path of a camera file; got a {type(path).__name__} (a camera "
            "from numbers: jaxpose.PinholeCamera(fx, fy, cx, cy, dist, width=, height=) or "
            "PinholeCamera.from_K)"
        )
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"camera file not found: {path}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"cannot read camera file {path}: {err}") from None
    if not isinstance(data, dict):
        raise ValueError(f"camera file {path} must hold a JSON object")
    if "cameraMatrix" in data:
        K = _numbers(data["cameraMatrix"], path, "cameraMatrix", "a 3x3 matrix of numbers")
        if K.shape != (3, 3):
            raise ValueError(
                f"camera file {path}: cameraMatrix must be a 3x3 matrix of numbers; "
                f"got shape {K.shape}"
            )
    elif all(k in data for k in ("fx", "fy", "cx", "cy")):
        fx, fy, cx, cy = (_numbers(data[k], path, k, "a number") for k in ("fx", "fy", "cx", "cy"))
        for k, v in zip(("fx", "fy", "cx", "cy"), (fx, fy, cx, cy), strict=True):
            if v.shape != ():
                raise ValueError(f"camera file {path}: {k} must be a number; got {data[k]!r}")
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    else:
        raise ValueError(
            f"camera file {path} has no 'cameraMatrix' (nor fx, fy, cx, cy in pixels); "
            f"its keys: {sorted(data)}"
        )
    if not np.all(np.isfinite(K)):
        raise ValueError(f"camera file {path}: cameraMatrix is not finite: {K.tolist()}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(
            f"camera file {path}: the focal lengths (cameraMatrix[0][0], [1][1]) must be "
            f"positive; got {K[0, 0]}, {K[1, 1]}"
        )
    problem = intrinsic_matrix_problem(K)
    if problem is not None:
        raise ValueError(
            f"camera file {path}: cameraMatrix must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]; "
            f"got {problem.replace('K[', 'cameraMatrix[')} in {K.tolist()}"
        )
    key = "distCoeffs" if "distCoeffs" in data else "dist"
    dist = data.get(key)
    if dist is not None:
        dist = _numbers(dist, path, key, "4 or 5 numbers (k1, k2, p1, p2[, k3])").ravel()
        if dist.size not in (4, 5) and not (dist.size > 5 and np.all(dist[5:] == 0)):
            raise ValueError(
                f"camera file {path}: {key} must hold 4 or 5 numbers (k1, k2, p1, p2[, k3]); "
                f"got {dist.size}"
            )
        if not np.all(np.isfinite(dist)):
            raise ValueError(f"camera file {path}: {key} is not finite: {dist.tolist()}")
    size, sides = [], []
    for keys in (("Nu", "width"), ("Nv", "height")):
        k = next((k for k in keys if k in data), keys[0])
        sides.append(k)
        v = data.get(k, 0)
        bad = isinstance(v, bool) or not isinstance(v, int | float)
        if bad or not np.isfinite(v) or v < 0 or v != int(v):
            raise ValueError(
                f"camera file {path}: {k} must be the image size in pixels, an integer >= 0; "
                f"got {v!r}"
            )
        size.append(int(v))
    for i, name in enumerate(("cx", "cy")):
        value, extent = K[i, 2], size[i]
        if extent > 0 and not 0 <= value <= extent:
            where = f" (cameraMatrix[{i}][2])" if "cameraMatrix" in data else ""
            raise ValueError(
                f"camera file {path}: the principal point {name}{where} = {value:g} lies outside "
                f"the image [0, {sides[i]} = {extent}] pixels (a matrix for another image size?)"
            )
    return PinholeCamera.from_K(K, dist, width=size[0], height=size[1])


def _json_numbers(value) -> bool:
    """Whether ``value`` is a JSON number or (nested) list of them: no string (``"10"`` would be
    parsed), no bool (taken as 1 or 0), no null, no object."""
    if isinstance(value, list):
        return all(_json_numbers(v) for v in value)
    return isinstance(value, int | float) and not isinstance(value, bool)


def _numbers(value, path: Path, field: str, expected: str) -> np.ndarray:
    """``value`` as a float array; ``ValueError`` naming the file and field otherwise."""
    if not _json_numbers(value):
        raise ValueError(f"camera file {path}: {field} must be {expected}; got {value!r}")
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"camera file {path}: {field} must be {expected}; got {value!r}") from None


def save_camera(camera: PinholeCamera, path: str | Path) -> None:
    """Write a camera in the SPEED ``camera.json`` layout (readable by :func:`load_camera`)."""
    if not isinstance(camera, PinholeCamera):
        raise ValueError(f"camera must be a PinholeCamera; got {type(camera).__name__}")
    data = {
        "Nu": camera.width,
        "Nv": camera.height,
        "cameraMatrix": np.asarray(camera.K).tolist(),
        "distCoeffs": np.asarray(camera.dist).tolist(),
    }
    Path(path).write_text(json.dumps(data, indent=1))
