"""Wireframe spacecraft models: type, JSON format, mesh loader, built-in Tango.

JSON format (``jaxpose/vision/models/data/tango.json`` is an example)::

    {
      "name": "tango",                    # free text
      "units": "m",                       # "m" (default), "cm" or "mm"; stored in metres
      "vertices": [[x, y, z], ...],       # body frame
      "edges": [[i, j], ...],             # vertex indices: the straight edges seen in images
      "faces": [[i, j, k, ...], ...],     # convex planar polygons, right-hand rule = outward normal
      "antennas": [[base, tip], ...],     # optional: thin segments (drawn, never occlude)
      "keypoints": [i, ...],              # optional: vertex index of each named keypoint
      "notes": "..."                      # optional
    }

Faces are used for visibility (back-face culling, painter's algorithm); edges are what the image
processing detects. Every index is checked at load time (``ValueError`` naming the field).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from pathlib import Path

import numpy as np

__all__ = [
    "WireframeModel",
    "build_tango",
    "load_model",
    "load_model_json",
    "load_model_mesh",
    "tango",
]

_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


@dataclass(frozen=True, eq=False)
class WireframeModel:
    """A polyhedral spacecraft model in the body frame (metres).

    Attributes:
        vertices: ``(V, 3)`` body-frame points.
        edges: ``(E, 2)`` vertex indices of the straight edges.
        faces: vertex-index tuples (convex planar polygons, outward by the right-hand rule).
        antennas: ``(A, 2)`` ``(base, tip)`` vertex indices of thin antenna segments.
        keypoints: vertex index of each keypoint (e.g. the 11 SPEED keypoints), may be empty.
        name: free text.
    """

    vertices: np.ndarray
    edges: np.ndarray
    faces: tuple[tuple[int, ...], ...]
    antennas: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=int))
    keypoints: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    name: str = "model"

    def __post_init__(self):
        V = np.asarray(self.vertices, dtype=float)
        if V.ndim != 2 or V.shape[1] != 3 or len(V) < 4 or not np.all(np.isfinite(V)):
            raise ValueError(f"vertices must be a finite (V>=4, 3) array; got shape {V.shape}")
        n = len(V)

        def idx(a, name, width=None):
            a = np.asarray(a, dtype=int).reshape(-1, width) if width else np.asarray(a, dtype=int)
            if a.size and (a.min() < 0 or a.max() >= n):
                raise ValueError(f"{name} index out of range 0..{n - 1}")
            return a

        E = idx(self.edges, "edges", 2)
        if len(E) == 0:
            raise ValueError("a wireframe model needs at least one edge")
        if np.any(E[:, 0] == E[:, 1]):
            raise ValueError("an edge joins a vertex to itself")
        faces = tuple(tuple(int(i) for i in idx(f, "faces")) for f in self.faces)
        if any(len(f) < 3 for f in faces):
            raise ValueError("every face needs at least 3 vertices")
        object.__setattr__(self, "vertices", V)
        object.__setattr__(self, "edges", E)
        object.__setattr__(self, "faces", faces)
        object.__setattr__(self, "antennas", idx(self.antennas, "antennas", 2))
        object.__setattr__(self, "keypoints", idx(self.keypoints, "keypoints"))

    # ------------------------------------------------------------------ derived geometry
    @cached_property
    def face_normals(self) -> np.ndarray:
        """``(F, 3)`` outward unit normals (Newell's method)."""
        out = []
        for f in self.faces:
            P = self.vertices[list(f)]
            Q = np.roll(P, -1, axis=0)
            n = np.array(
                [
                    np.sum((P[:, 1] - Q[:, 1]) * (P[:, 2] + Q[:, 2])),
                    np.sum((P[:, 2] - Q[:, 2]) * (P[:, 0] + Q[:, 0])),
                    np.sum((P[:, 0] - Q[:, 0]) * (P[:, 1] + Q[:, 1])),
                ]
            )
            out.append(n / max(np.linalg.norm(n), 1e-300))
        return np.array(out).reshape(-1, 3)

    @cached_property
    def face_centres(self) -> np.ndarray:
        return np.array([self.vertices[list(f)].mean(0) for f in self.faces]).reshape(-1, 3)

    @cached_property
    def edge_faces(self) -> tuple[tuple[int, ...], ...]:
        """For each edge, the faces whose boundary contains it (empty for free edges)."""
        sides: dict[frozenset, list[int]] = {}
        for k, f in enumerate(self.faces):
            for a, b in zip(f, f[1:] + f[:1], strict=True):
                sides.setdefault(frozenset((a, b)), []).append(k)
        return tuple(tuple(sides.get(frozenset(map(int, e)), ())) for e in self.edges)

    @cached_property
    def edge_points(self) -> np.ndarray:
        """``(E, 2, 3)`` endpoints of every edge."""
        return self.vertices[self.edges]

    @cached_property
    def antenna_points(self) -> np.ndarray:
        """``(A, 2, 3)`` base and tip of every antenna."""
        return self.vertices[self.antennas].reshape(-1, 2, 3)

    @property
    def characteristic_length(self) -> float:
        """``L_C``: the largest distance between two vertices (eq. 6 of Sharma et al. 2018), m."""
        V = self.vertices
        return float(np.sqrt(((V[:, None] - V[None]) ** 2).sum(-1)).max())

    @cached_property
    def groups(self):
        """Model feature groups (:func:`jaxpose.vision.models.groups.model_groups`, default
        thresholds)."""
        from jaxpose.vision.models.groups import model_groups

        return model_groups(self)

    # ------------------------------------------------------------------ I/O
    def to_json(self) -> dict:
        return {
            "name": self.name,
            "units": "m",
            "vertices": np.round(self.vertices, 6).tolist(),
            "edges": self.edges.tolist(),
            "faces": [list(f) for f in self.faces],
            "antennas": self.antennas.tolist(),
            "keypoints": self.keypoints.tolist(),
        }


def load_model_json(path_or_dict) -> WireframeModel:
    """Read the JSON format of this module (a path, or an already parsed ``dict``)."""
    if isinstance(path_or_dict, dict):
        data, where = path_or_dict, "model"
    else:
        path = Path(path_or_dict)
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            raise ValueError(f"model file not found: {path}") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
            raise ValueError(f"cannot read model file {path}: {err}") from None
        where = str(path)
    if not isinstance(data, dict):
        raise ValueError(f"{where}: a model file must hold a JSON object")
    for key in ("vertices", "edges"):
        if key not in data:
            raise ValueError(f"{where}: missing field '{key}'")
    units = data.get("units", "m")
    if units not in _UNITS:
        raise ValueError(f"{where}: units must be one of {sorted(_UNITS)}; got {units!r}")
    try:
        return WireframeModel(
            vertices=np.asarray(data["vertices"], dtype=float) * _UNITS[units],
            edges=np.asarray(data["edges"], dtype=int).reshape(-1, 2),
            faces=tuple(tuple(f) for f in data.get("faces", [])),
            antennas=np.asarray(data.get("antennas", []), dtype=int).reshape(-1, 2),
            keypoints=np.asarray(data.get("keypoints", []), dtype=int),
            name=str(data.get("name", Path(where).stem)),
        )
    except (TypeError, ValueError) as err:
        raise ValueError(f"{where}: {err}") from None


def load_model_mesh(path, *, feature_angle_deg: float = 20.0, units: str = "m") -> WireframeModel:
    """Read a triangle mesh (STL, OBJ, PLY, ... through ``trimesh``) as a wireframe model.

    Coplanar adjacent triangles are merged into facets (``trimesh``'s facets); the edges kept are
    the *feature edges*: those whose two faces meet at more than ``feature_angle_deg``, plus open
    boundary edges. Faces for visibility are the mesh triangles (outward as stored in the mesh).
    """
    try:
        import trimesh
    except ImportError as err:  # pragma: no cover - trimesh is a dependency
        raise ValueError("reading meshes needs the 'trimesh' package") from err
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"model file not found: {path}")
    try:
        mesh = trimesh.load(str(path), force="mesh")
    except Exception as err:  # trimesh raises many types on bad files
        raise ValueError(f"cannot read mesh {path}: {err}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path}: no triangles found")
    if units not in _UNITS:
        raise ValueError(f"units must be one of {sorted(_UNITS)}; got {units!r}")
    mesh.merge_vertices()
    angles = mesh.face_adjacency_angles
    sharp = mesh.face_adjacency_edges[angles > np.deg2rad(feature_angle_deg)]
    # Boundary edges: edges that belong to exactly one triangle.
    e_sorted = np.sort(mesh.edges, axis=1)
    uniq, counts = np.unique(e_sorted, axis=0, return_counts=True)
    edges = np.concatenate([np.sort(sharp, axis=1), uniq[counts == 1]]).reshape(-1, 2)
    edges = np.unique(edges, axis=0)
    if len(edges) == 0:
        raise ValueError(f"{path}: no feature edges sharper than {feature_angle_deg} deg")
    return WireframeModel(
        vertices=np.asarray(mesh.vertices, dtype=float) * _UNITS[units],
        edges=edges,
        faces=tuple(tuple(map(int, f)) for f in mesh.faces),
        name=path.stem,
    )


def load_model(spec: str | Path | None = "tango") -> WireframeModel:
    """``"tango"`` (or ``None``) for the built-in model, a ``.json`` file, or a mesh file."""
    if spec is None or str(spec) == "tango":
        return tango()
    path = Path(spec)
    if path.suffix.lower() == ".json":
        return load_model_json(path)
    return load_model_mesh(path)


_TANGO_CACHE: list[WireframeModel] = []


def tango() -> WireframeModel:
    """The built-in Tango model (``jaxpose/vision/models/data/tango.json``, see
    :func:`build_tango`)."""
    if not _TANGO_CACHE:
        text = resources.files("jaxpose.vision.models").joinpath("data/tango.json").read_text()
        _TANGO_CACHE.append(load_model_json(json.loads(text)))
    return _TANGO_CACHE[0]


# ---------------------------------------------------------------------------- Tango derivation

#: The 11 SPEED keypoints (``tango_keypoints.csv``), metres.
SPEED_KEYPOINTS = np.array(
    [
        [-0.37, -0.385, 0.3215],
        [-0.37, 0.385, 0.3215],
        [0.37, 0.385, 0.3215],
        [0.37, -0.385, 0.3215],
        [-0.37, -0.264, 0.0],
        [-0.37, 0.304, 0.0],
        [0.37, 0.304, 0.0],
        [0.37, -0.264, 0.0],
        [-0.5427, 0.4877, 0.2535],
        [0.5427, 0.4877, 0.2591],
        [0.305, -0.579, 0.2515],
    ]
)

#: Solar-panel thickness (m). Not in the keypoints: an assumption read off the SPEED+ images.
TANGO_PANEL_THICKNESS = 0.02


def _orient(face: list[int], V: np.ndarray, inside: np.ndarray) -> tuple[int, ...]:
    P = V[face]
    n = np.cross(P[1] - P[0], P[2] - P[0])
    return tuple(face if n @ (P[0] - inside) > 0 else face[::-1])


def build_tango() -> WireframeModel:
    """Derive the Tango wireframe from the 11 SPEED keypoints (how ``tango.json`` was made).

    * Keypoints 1-4 are the corners of the top face of the solar panel (z = 0.3215 m, 0.74 x 0.77
      m); keypoints 5-8 the corners of the bottom face of the body (z = 0, 0.74 x 0.568 m). The
      images show a box-shaped body with *vertical* walls under a panel that overhangs it in y, not
      a frustum joining 1-4 to 5-8. So the model is two boxes:
      the panel slab (1-4 and the same corners ``TANGO_PANEL_THICKNESS`` lower) and the body box
      (5-8 and the same corners raised to the panel's underside).
    * Edges: the 12 edges of each box; the body's top ring (where body meets panel) is kept because
      it shows as a crease. Faces: the 6 faces of the panel and the 5 visible faces of the body
      (its top is covered by the panel), oriented outward.
    * Antennas: tips are keypoints 9-11. The bases are not in the keypoint set; each is put where
      the images show the antenna leaving the body, at the tip's height: tips 9 and 10 on the
      vertical body edges at (x = -0.37 / +0.37, y = +0.304), tip 11 on the y = -0.264 wall at
      x = 0.305. Measured on the labelled SPEED+ development photographs
      (``bench/monocular_antennas.py``), the antennas of tips 9 and 10 point 13-16 degrees closer
      to the x axis, toward the panel's corners; the model keeps these bases (with the measured
      ones the pipeline did worse on those images: docs, monocular evaluation).
    """
    kp = SPEED_KEYPOINTS
    z_under = kp[0, 2] - TANGO_PANEL_THICKNESS
    panel_top = kp[0:4]
    panel_bot = panel_top.copy()
    panel_bot[:, 2] = z_under
    body_bot = kp[4:8]
    body_top = body_bot.copy()
    body_top[:, 2] = z_under
    bases = np.array(
        [[-0.37, 0.304, kp[8, 2]], [0.37, 0.304, kp[9, 2]], [0.305, -0.264, kp[10, 2]]]
    )
    # Vertex order: 0-7 keypoints 1-8, 8-10 keypoints 9-11 (antenna tips), 11-14 panel underside,
    # 15-18 body top ring, 19-21 antenna bases.
    V = np.concatenate([kp, panel_bot, body_top, bases])
    PT, PB, BB, BT = [0, 1, 2, 3], [11, 12, 13, 14], [4, 5, 6, 7], [15, 16, 17, 18]

    def box(top, bot):
        ring = [(top[i], top[(i + 1) % 4]) for i in range(4)] + [
            (bot[i], bot[(i + 1) % 4]) for i in range(4)
        ]
        return ring + [(top[i], bot[i]) for i in range(4)]

    edges = box(PT, PB) + box(BT, BB)
    panel_in = V[PT + PB].mean(0)
    body_in = V[BB + BT].mean(0)
    faces = [_orient(PT, V, panel_in), _orient(PB, V, panel_in)]
    faces += [
        _orient([PT[i], PT[(i + 1) % 4], PB[(i + 1) % 4], PB[i]], V, panel_in) for i in range(4)
    ]
    faces += [_orient(BB, V, body_in)]
    faces += [
        _orient([BT[i], BT[(i + 1) % 4], BB[(i + 1) % 4], BB[i]], V, body_in) for i in range(4)
    ]
    return WireframeModel(
        vertices=V,
        edges=np.array(edges),
        faces=tuple(faces),
        antennas=np.array([[19, 8], [20, 9], [21, 10]]),
        keypoints=np.arange(11),
        name="tango",
    )
