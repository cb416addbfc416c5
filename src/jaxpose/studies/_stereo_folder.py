"""A folder of stereo pairs for ``stereo-track --images``: layout, calibration, checks.

```text
DIR/
  calibration.json          {"left": camera, "right": camera, "R_rl": 3x3, "t_rl": [3]}
  left/000000.png ...       left images, paired with right/ in sorted file-name order
  right/000000.png ...
  poses.csv                 optional ground truth: frame, qw, qx, qy, qz, tx, ty, tz
```

Each camera of ``calibration.json`` is in the ``camera.json`` layout read by
:func:`jaxpose.io.load_camera` (``cameraMatrix``, ``distCoeffs``, ``Nu``, ``Nv``); ``R_rl``,
``t_rl`` map the left camera frame to the right one, ``x_right = R_rl x_left + t_rl`` (OpenCV's
``stereoCalibrate`` ``R, T``; ``R_rl`` defaults to the identity, metres). The pairs are rectified
with OpenCV (:func:`jaxpose.vision.stereo_rectify.rectify`). ``poses.csv`` holds the target pose in
the (unrectified) left camera, ``x_cam = R(q) x_body + t`` with ``q`` scalar-first; it is turned
into the rectified left camera (``R1``) and used only to report errors.
"""

from __future__ import annotations

import csv
import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxpose.core.camera import StereoCamera
from jaxpose.core.geometry import Pose

__all__ = ["StereoFolder", "open_stereo_folder"]


@dataclass
class _Pair:
    index: int
    left: np.ndarray
    right: np.ndarray
    pose: Pose | None = None


@dataclass
class StereoFolder:
    """A checked stereo folder: ``rig`` (the rectified rig the tracker uses), the image paths,
    the rectification and the ground truth (``None`` without ``poses.csv``)."""

    folder: Path
    rig: StereoCamera
    lefts: list[Path]
    rights: list[Path]
    rectification: object
    truth: list[Pose] | None

    def __len__(self) -> int:
        return len(self.lefts)

    def frames(self, n: int | None = None):
        """Generator of the first ``n`` (all) rectified pairs (objects with ``left``, ``right``,
        ``pose``); an unreadable image or one of another size raises ``ValueError`` naming it."""
        import cv2

        w, h = self.rectification.size
        count = len(self) if n is None else min(n, len(self))
        for k in range(count):
            images = []
            for path in (self.lefts[k], self.rights[k]):
                img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
                if img is None:
                    raise ValueError(f"cannot read the image {path} (not an image file?)")
                if img.ndim == 3:
                    img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else 0)
                if img.shape[:2] != (h, w):
                    raise ValueError(
                        f"{path} is {img.shape[1]}x{img.shape[0]}; calibration.json says "
                        f"{w}x{h} (Nu x Nv)"
                    )
                if img.dtype == np.uint16:
                    img = (img / 257.0 + 0.5).astype(np.uint8)
                elif img.dtype != np.uint8:
                    raise ValueError(f"{path}: 8- or 16-bit grayscale expected; got {img.dtype}")
                images.append(img)
            left, right = self.rectification.remap(*images)
            yield _Pair(k, left, right, None if self.truth is None else self.truth[k])


def _camera(calib: Path, data: dict, side: str, size: tuple[int, int] | None):
    from jaxpose.io import load_camera

    if side not in data:
        raise ValueError(
            f"{calib}: missing field '{side}' (the {side} camera, in the camera.json layout: "
            f"cameraMatrix, distCoeffs, Nu, Nv)"
        )
    if not isinstance(data[side], dict):
        raise ValueError(f"{calib}: field '{side}' must be a camera object; got {data[side]!r}")
    with tempfile.TemporaryDirectory() as tmp:  # load_camera's checks, on a file of our own
        path = Path(tmp) / f"{side}.json"
        path.write_text(json.dumps(data[side]))
        try:
            cam = load_camera(path)
        except (ValueError, TypeError) as err:
            text = str(err)
            if f"camera file {path}" in text:
                text = text.replace(f"camera file {path}", f"{calib}, field '{side}'")
            else:
                text = f"{calib}, field '{side}': {text.replace(str(path), 'the camera')}"
            raise ValueError(text) from None
    if (cam.width <= 0 or cam.height <= 0) and size is not None:
        cam = type(cam).from_K(np.asarray(cam.K), cam.dist, width=size[0], height=size[1])
    return cam


def _vector(calib: Path, data: dict, key: str, shape, default=None) -> np.ndarray:
    value = data.get(key, default)
    if value is None:
        raise ValueError(f"{calib}: missing field '{key}' ({' x '.join(map(str, shape))} numbers)")
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != tuple(shape) or not np.all(np.isfinite(a)):
        raise ValueError(
            f"{calib}: field '{key}' must be {' x '.join(map(str, shape))} finite numbers; "
            f"got {value!r}"
        )
    return a


def _read_truth(path: Path, n: int, R1: np.ndarray) -> list[Pose]:
    from jaxpose.core.geometry import quat_to_dcm

    poses = {}
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    header = [c.strip() for c in rows[0]] if rows else []
    want = ["frame", "qw", "qx", "qy", "qz", "tx", "ty", "tz"]
    if header != want:
        raise ValueError(f"{path}: the header must be {','.join(want)}; got {','.join(header)}")
    for line, row in enumerate(rows[1:], start=2):
        try:
            vals = [float(v) for v in row]
        except ValueError:
            vals = []
        if len(vals) != 8 or not np.all(np.isfinite(vals)) or vals[0] != int(vals[0]):
            raise ValueError(f"{path}, line {line}: expected 8 finite numbers; got {row}")
        q = np.asarray(vals[1:5])
        if not 0.5 < np.linalg.norm(q) < 2.0:
            raise ValueError(f"{path}, line {line}: the quaternion is not a rotation: {q}")
        R = np.asarray(quat_to_dcm(q / np.linalg.norm(q)))
        poses[int(vals[0])] = Pose(R1 @ R, R1 @ np.asarray(vals[5:]))
    missing = [k for k in range(n) if k not in poses]
    if missing:
        raise ValueError(f"{path}: no pose for frame {missing[0]} ({len(missing)} missing)")
    return [poses[k] for k in range(n)]


def open_stereo_folder(folder: str | Path) -> StereoFolder:
    """Check a stereo folder (module docstring) and prepare its rectification; ``ValueError``
    naming the file and field for each malformed case."""
    from jaxpose.vision.stereo_rectify import rectify

    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"--images {folder}: not a folder")
    calib = folder / "calibration.json"
    if not calib.is_file():
        raise ValueError(f"{calib} not found (left and right cameras, R_rl, t_rl)")
    try:
        data = json.loads(calib.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"cannot read {calib}: {err}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{calib} must hold a JSON object")
    lefts = sorted((folder / "left").glob("*.png"))
    rights = sorted((folder / "right").glob("*.png"))
    if not lefts or len(lefts) != len(rights):
        raise ValueError(
            f"{folder}: need as many left/*.png as right/*.png, at least one; got {len(lefts)} "
            f"and {len(rights)}"
        )
    size = None
    import cv2

    first = cv2.imread(str(lefts[0]), cv2.IMREAD_UNCHANGED)
    if first is None:
        raise ValueError(f"cannot read the image {lefts[0]} (not an image file?)")
    size = (first.shape[1], first.shape[0])
    left = _camera(calib, data, "left", size)
    right = _camera(calib, data, "right", size)
    if (left.width, left.height) != (right.width, right.height):
        raise ValueError(
            f"{calib}: the left and right cameras differ in size ({left.width}x{left.height} "
            f"and {right.width}x{right.height})"
        )
    R_rl = _vector(calib, data, "R_rl", (3, 3), default=np.eye(3).tolist())
    if not np.allclose(R_rl @ R_rl.T, np.eye(3), atol=1e-6) or np.linalg.det(R_rl) < 0:
        raise ValueError(f"{calib}: field 'R_rl' must be a rotation matrix; got {R_rl.tolist()}")
    t_rl = _vector(calib, data, "t_rl", (3,))
    if not np.linalg.norm(t_rl) > 0:
        raise ValueError(f"{calib}: field 't_rl' (the baseline, metres) must not be zero")
    rect = rectify(StereoCamera(left, right, R_rl, t_rl))
    truth_file = folder / "poses.csv"
    truth = _read_truth(truth_file, len(lefts), rect.R1) if truth_file.is_file() else None
    return StereoFolder(folder, rect.rectified_camera(), lefts, rights, rect, truth)
