"""Wireframe models: built-in Tango, JSON and mesh loaders, model feature groups."""

import json

import numpy as np
import pytest

from jaxpose.vision.models import (
    WireframeModel,
    load_model,
    load_model_json,
    load_model_mesh,
    tango,
)
from jaxpose.vision.models.wireframe import SPEED_KEYPOINTS, build_tango
from jaxpose.vision.synthesis import KINDS, POINTS_PER_GROUP


def test_tango_json_matches_its_derivation():
    assert tango().to_json() == build_tango().to_json()


def test_tango_keypoints_are_the_speed_keypoints():
    m = tango()
    np.testing.assert_allclose(m.vertices[m.keypoints], SPEED_KEYPOINTS)


def test_tango_keypoints_match_the_data_file(speedplus_dir):
    kp = np.loadtxt(
        speedplus_dir / "tango_keypoints.csv", delimiter=",", skiprows=1, usecols=(1, 2, 3)
    )
    m = tango()
    np.testing.assert_allclose(m.vertices[m.keypoints], kp)


def test_tango_faces_are_outward_and_every_edge_has_a_face():
    m = tango()
    # Outward: each face normal points away from the centre of its box.
    panel = m.vertices[[0, 1, 2, 3, 11, 12, 13, 14]].mean(0)
    body = m.vertices[[4, 5, 6, 7, 15, 16, 17, 18]].mean(0)
    for f, (n, c) in enumerate(zip(m.face_normals, m.face_centres, strict=True)):
        inside = panel if f < 6 else body
        assert n @ (c - inside) > 0
    assert all(len(f) >= 1 for f in m.edge_faces)
    assert len(m.edges) == 24 and len(m.antennas) == 3


def test_tango_groups():
    g = tango().groups
    s = g.summary()
    # 6 panel faces + 5 body faces + the body's top ring close a loop of 4 edges.
    assert s["closed_tetrad"] == 12
    assert s["antennas"] == 3
    for k in KINDS:
        assert g.points[k].shape[1:] == (POINTS_PER_GROUP[k], 3)
    # Closed tetrad points are model vertices, consecutive ones joined by an edge.
    V = tango().vertices
    edges = {frozenset(map(int, e)) for e in tango().edges}
    for quad in g.points["closed_tetrad"]:
        idx = [int(np.argmin(np.linalg.norm(V - p, axis=1))) for p in quad]
        assert all(frozenset((idx[i], idx[(i + 1) % 4])) in edges for i in range(4))


def test_json_round_trip_and_units(tmp_path):
    data = tango().to_json()
    data["units"] = "mm"
    data["vertices"] = (np.asarray(data["vertices"]) * 1000).tolist()
    p = tmp_path / "m.json"
    p.write_text(json.dumps(data))
    m = load_model(p)
    np.testing.assert_allclose(m.vertices, tango().vertices, atol=1e-9)


@pytest.mark.parametrize(
    "patch, match",
    [
        ({"edges": [[0, 99]]}, "out of range"),
        ({"units": "inch"}, "units"),
        ({"vertices": [[0, 0, 0]]}, "vertices"),
        ({"edges": [[1, 1]]}, "itself"),
    ],
)
def test_json_errors(tmp_path, patch, match):
    data = tango().to_json() | patch
    with pytest.raises(ValueError, match=match):
        load_model_json(data)


def test_unreadable_model_file(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text("{not json")
    with pytest.raises(ValueError, match="cannot read"):
        load_model(p)
    with pytest.raises(ValueError, match="not found"):
        load_model(tmp_path / "missing.stl")


def test_mesh_loader_box(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    for ext in ("stl", "obj"):
        p = tmp_path / f"box.{ext}"
        box.export(p)
        m = load_model_mesh(p)
        assert isinstance(m, WireframeModel)
        assert len(m.vertices) == 8
        assert len(m.edges) == 12  # the face diagonals are not feature edges
        assert m.groups.count("closed_tetrad") >= 6
        lengths = np.linalg.norm(m.edge_points[:, 1] - m.edge_points[:, 0], axis=1)
        np.testing.assert_allclose(sorted(set(np.round(lengths, 9))), [1.0, 2.0, 3.0])
