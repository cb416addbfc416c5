"""SPEED+ as users have it: the data set's root layout and labels.csv, label and camera-file
errors that name the file and the line or field, the 2021 competition score, and image depths."""

import json
from importlib import metadata

import cv2
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxpose import Pose
from jaxpose.io import load_camera, load_image, load_speed_labels
from jaxpose.studies.speedplus import competition_score, summarise
from jaxpose.vision.features import to_gray

CAMERA = {
    "Nu": 64,
    "Nv": 40,
    "cameraMatrix": [[100.0, 0.0, 31.5], [0.0, 100.0, 19.5], [0.0, 0.0, 1.0]],
    "distCoeffs": [0.0, 0.0, 0.0, 0.0, 0.0],
}


def _label(i, key="q_vbs2tango_true"):
    q = Rotation.from_rotvec([0.1 * i, -0.2, 0.3]).as_quat()  # x, y, z, w
    return {
        "filename": f"img{i:06d}.jpg",
        key: [q[3], q[0], q[1], q[2]],
        "r_Vo2To_vbs_true": [0.1 * i, -0.2, 5.0 + i],
    }


def _root(tmp_path, speed2019=False):
    """A tiny SPEED+ root: camera.json, synthetic/{train,validation}.json, lightbox/test.json,
    sunlamp/test.json, each domain with images/ (one black image per label)."""
    (tmp_path / "camera.json").write_text(json.dumps(CAMERA))
    files = {
        "synthetic": {"train.json": [_label(1), _label(2)], "validation.json": [_label(3)]},
        "lightbox": {"test.json": [_label(4)]},
        "sunlamp": {"test.json": [_label(5, key="q_vbs2tango"), _label(6)]},
    }
    for dom, jsons in files.items():
        (tmp_path / dom / "images").mkdir(parents=True)
        for name, labels in jsons.items():
            (tmp_path / dom / name).write_text(json.dumps(labels))
            for lab in labels:
                cv2.imwrite(str(tmp_path / dom / "images" / lab["filename"]), np.zeros((40, 64)))
    return tmp_path


def test_dataset_root_layout_is_read_with_domains(tmp_path):
    root = _root(tmp_path)
    labels = load_speed_labels(root)
    assert [(lab.domain, lab.image.name) for lab in labels] == [
        ("lightbox", "img000004.jpg"),
        ("sunlamp", "img000005.jpg"),
        ("sunlamp", "img000006.jpg"),
        ("synthetic", "img000001.jpg"),
        ("synthetic", "img000002.jpg"),
        ("synthetic", "img000003.jpg"),
    ]
    assert all(lab.image.is_file() for lab in labels)
    # the frame convention against SciPy: R_cam_body = Rotation.from_quat([qx, qy, qz, qw])
    for lab, i in zip(labels, (4, 5, 6, 1, 2, 3), strict=True):
        ref = Rotation.from_rotvec([0.1 * i, -0.2, 0.3]).as_matrix()
        np.testing.assert_allclose(np.asarray(lab.pose.R), ref, atol=1e-12)
        np.testing.assert_allclose(np.asarray(lab.pose.t), [0.1 * i, -0.2, 5.0 + i])
    only = load_speed_labels(root, ["lightbox", "sunlamp"])
    assert {lab.domain for lab in only} == {"lightbox", "sunlamp"} and len(only) == 3
    with pytest.raises(ValueError, match="domain sunlmp not in .*present: lightbox, sunlamp"):
        load_speed_labels(root, ["sunlmp"])


def test_speed2019_layout_and_unlabelled_split(tmp_path):
    (tmp_path / "images" / "train").mkdir(parents=True)
    (tmp_path / "images" / "test").mkdir(parents=True)
    (tmp_path / "train.json").write_text(json.dumps([_label(1, key="q_vbs2tango")]))
    (tmp_path / "test.json").write_text(json.dumps([{"filename": "img000009.jpg"}]))
    labels = load_speed_labels(tmp_path)
    assert [(lab.domain, lab.image) for lab in labels] == [
        ("train", tmp_path / "images" / "train" / "img000001.jpg")
    ]


def test_labels_csv_with_domain_filter(tmp_path):
    rows = (
        "image,domain,qw,qx,qy,qz,tx,ty,tz\n"
        "a.png,lightbox,1,0,0,0,0,0,5\nb.png,synthetic,0,1,0,0,0,0,6\n"
    )
    (tmp_path / "labels.csv").write_text(rows)
    labels = load_speed_labels(tmp_path, ["synthetic"])
    assert len(labels) == 1 and labels[0].image == tmp_path / "b.png"
    np.testing.assert_allclose(np.asarray(labels[0].pose.R), np.diag([1.0, -1.0, -1.0]), atol=0)


@pytest.mark.parametrize(
    ("row", "message"),
    [
        ("a.png,x,1,0,0,0,0,0", r"labels.csv:3: the row lacks tz"),
        ("a.png,x,0,0,0,0,0,0,5", r"labels.csv:3: the quaternion must have unit norm.*norm 0"),
        ("a.png,x,2,0,0,0,0,0,5", r"labels.csv:3: the quaternion must have unit norm"),
        ("a.png,x,1,0,0,0,nan,0,5", r"labels.csv:3: the translation is not finite"),
        ("a.png,x,nan,0,0,0,0,0,5", r"labels.csv:3: the quaternion is not finite"),
        ("a.png,x,1,0,0,0,0,0,0", r"labels.csv:3: the translation is zero"),
        ("a.png,x,1,0,0,0,0,zero,5", r"labels.csv:3: could not convert"),
        ("a.png,x,1,0,0,0,0,0,5,7", r"labels.csv:3: the row has more fields"),
    ],
)
def test_bad_csv_rows_name_the_line(tmp_path, row, message):
    good = "ok.png,x,1,0,0,0,0,0,5"
    (tmp_path / "labels.csv").write_text(f"image,domain,qw,qx,qy,qz,tx,ty,tz\n{good}\n{row}\n")
    with pytest.raises(ValueError, match=message):
        load_speed_labels(tmp_path)


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        (
            {"filename": "a.jpg", "q_vbs2tango_true": [0, 0, 0, 0], "r_Vo2To_vbs_true": [0, 0, 5]},
            r"test.json, entry 1 \(a.jpg\): the quaternion must have unit norm",
        ),
        (
            {"filename": "a.jpg", "q_vbs2tango_true": [1, 0, 0], "r_Vo2To_vbs_true": [0, 0, 5]},
            r"entry 1 \(a.jpg\): the quaternion needs 4 numbers",
        ),
        ({"filename": "a.jpg", "q_vbs2tango_true": [1, 0, 0, 0]}, r"entry 1 \(a.jpg\): lacks r_Vo"),
        (
            {"q_vbs2tango_true": [1, 0, 0, 0]},
            r"entry 1: a label must be an object with a 'filename'",
        ),
        (
            {"filename": "a.jpg", "q_vbs2tango_true": "abc", "r_Vo2To_vbs_true": [0, 0, 5]},
            r"entry 1 \(a.jpg\): the pose is not numeric",
        ),
    ],
)
def test_bad_json_labels_name_the_entry(tmp_path, entry, message):
    (tmp_path / "lightbox" / "images").mkdir(parents=True)
    (tmp_path / "lightbox" / "test.json").write_text(json.dumps([_label(1), entry]))
    with pytest.raises(ValueError, match=message):
        load_speed_labels(tmp_path)


def test_empty_folder_says_what_it_expects(tmp_path):
    with pytest.raises(ValueError, match="expected labels.csv, or the SPEED\\+ layout"):
        load_speed_labels(tmp_path)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"distCoeffs": [float("nan"), 0, 0, 0, 0]}, r"cam.json: distCoeffs is not finite"),
        ({"distCoeffs": [0.1, 0.2]}, r"cam.json: distCoeffs must hold 4 or 5 numbers"),
        ({"cameraMatrix": "abc"}, r"cam.json: cameraMatrix must be a 3x3 matrix.*'abc'"),
        ({"cameraMatrix": {"a": 1}}, r"cam.json: cameraMatrix must be a 3x3 matrix.*\{'a': 1\}"),
        (
            {"cameraMatrix": [[1, 2], [3, 4]]},
            r"cam.json: cameraMatrix must be a 3x3.*shape \(2, 2\)",
        ),
        ({"cameraMatrix": [[0, 0, 1], [0, 1, 1], [0, 0, 1]]}, r"cam.json: the focal lengths"),
        ({"Nu": None}, r"cam.json: Nu must be the image size in pixels.*None"),
        ({"Nv": -3}, r"cam.json: Nv must be the image size"),
        ({"Nv": 12.5}, r"cam.json: Nv must be the image size"),
    ],
)
def test_camera_file_errors_name_file_and_field(tmp_path, change, message):
    (tmp_path / "cam.json").write_text(json.dumps(CAMERA | change))
    with pytest.raises(ValueError, match=message):
        load_camera(tmp_path / "cam.json")


def test_camera_file_that_is_not_an_object(tmp_path):
    (tmp_path / "cam.json").write_text(json.dumps({"a": 1}))
    with pytest.raises(ValueError, match=r"cam.json has no 'cameraMatrix'.*keys: \['a'\]"):
        load_camera(tmp_path / "cam.json")
    (tmp_path / "cam.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match="cam.json must hold a JSON object"):
        load_camera(tmp_path / "cam.json")


def test_competition_score_thresholds():
    """The 2021 competition's score: errors below the label precision count as zero; above it the
    plain ESA score (reference: the README's formulas computed with SciPy)."""
    R = Rotation.from_rotvec([0.3, -0.2, 0.5])
    t = np.array([0.2, -0.1, 8.0])
    truth = Pose(jnp.asarray(R.as_matrix()), jnp.asarray(t))

    def est(angle_deg, dt):
        Re = Rotation.from_rotvec(np.deg2rad(angle_deg) * np.array([0.0, 0.6, 0.8])) * R
        return Pose(jnp.asarray(Re.as_matrix()), jnp.asarray(t + dt))

    # below both thresholds: 0.1 deg, 2 mm per metre
    s, e_q, e_t = competition_score(est(0.1, [0, 0, 0.002 * 8.004]), truth)
    assert (s, e_q, e_t) == (0.0, 0.0, 0.0)
    # above: 0.5 deg and 5 cm at 8 m
    dt = np.array([0.03, 0.0, 0.04])
    s, e_q, e_t = competition_score(est(0.5, dt), truth)
    q_true, q_est = (
        R.as_quat(),
        (Rotation.from_rotvec(np.deg2rad(0.5) * np.array([0, 0.6, 0.8])) * R).as_quat(),
    )
    ref_q = 2 * np.arccos(abs(np.dot(q_true, q_est)))
    ref_t = np.linalg.norm(dt) / np.linalg.norm(t)
    assert np.isclose(e_q, ref_q, rtol=1e-6) and np.isclose(e_t, ref_t, rtol=1e-9)
    assert np.isclose(s, ref_q + ref_t)
    # one below, one above
    s, e_q, e_t = competition_score(est(0.1, dt), truth)
    assert e_q == 0.0 and np.isclose(s, ref_t)


def test_summary_counts_per_image_records():
    rows = [
        {"confidence": "high", "success": True, "esa_score": 0.1, "runtime_s": 1.0},
        {"confidence": "high", "success": False, "esa_score": 0.5, "runtime_s": 3.0},
        {
            "confidence": "low",
            "success": True,
            "esa_score": 0.3,
            "runtime_s": 2.0,
            "coarse_within_20pct": True,
        },
        {"confidence": "none", "success": False},
    ]
    s = summarise(rows)
    assert s["success_rate"] == 0.5 and s["high_confidence"] == 2 and s["high_precision"] == 0.5
    assert np.isclose(s["esa_score_mean"], 0.3) and s["esa_unscored"] == 1
    assert s["median_runtime_s"] == 2.0 and s["coarse_range_within_20pct"] == 0.25


def _scene_image():
    rng = np.random.default_rng(3)
    img = np.zeros((60, 80, 3), np.uint8)
    cv2.rectangle(img, (20, 15), (60, 45), (200, 120, 90), -1)
    return np.clip(img.astype(int) + rng.integers(0, 30, img.shape), 0, 255).astype(np.uint8)


def test_image_depths_give_the_8bit_pixels(tmp_path):
    colour = _scene_image()
    gray8 = cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY)
    assert np.array_equal(to_gray(gray8), gray8)
    assert np.array_equal(to_gray(gray8.astype(np.uint16) * 257), gray8)  # 16-bit full range
    assert np.array_equal(to_gray(gray8 / 255.0), gray8)  # float in [0, 1]
    assert np.array_equal(to_gray(gray8.astype(np.float32)), gray8)  # float in [0, 255]
    assert np.array_equal(to_gray(colour), gray8)
    assert np.array_equal(to_gray(colour / 255.0), gray8)  # float64 colour image
    assert np.array_equal(to_gray(colour.astype(np.uint16) * 257), gray8)
    with pytest.raises(ValueError, match="image must be"):
        to_gray(np.zeros((4, 4, 2)))
    # a 16-bit PNG reads as its 8-bit version
    cv2.imwrite(str(tmp_path / "a16.png"), gray8.astype(np.uint16) * 257)
    cv2.imwrite(str(tmp_path / "a8.png"), gray8)
    assert load_image(tmp_path / "a16.png").dtype == np.uint8
    assert np.array_equal(load_image(tmp_path / "a16.png"), load_image(tmp_path / "a8.png"))


def test_eval_speedplus_on_a_dataset_root(tmp_path, capsys, monkeypatch):
    """The command on a fabricated SPEED+ root: --domain picks domains, each per-image record
    names its domain, the summary has the fields of issue 15 and a summary per domain (black
    images: no target, so nothing is compiled); a bad camera.json exits 2 with one line naming
    the file and the field."""
    from jaxpose.cli import main

    monkeypatch.setenv("JAXPOSE_CACHE_DIR", str(tmp_path / "xla"))
    (tmp_path / "root").mkdir()
    root = _root(tmp_path / "root")
    assert (
        main(
            [
                "eval-speedplus",
                str(root),
                "--domain",
                "sunlamp",
                "--domain",
                "lightbox",
                "--json",
                "--no-progress",
            ]
        )
        == 0
    )
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for key in (
        "images",
        "success_rate",
        "high_confidence",
        "high_precision",
        "esa_score_mean",
        "coarse_range_within_20pct",
        "median_runtime_s",
        "per_image",
        "per_domain",
    ):
        assert key in out
    assert out["images"] == 3 and sorted(out["per_domain"]) == ["lightbox", "sunlamp"]
    assert out["per_domain"]["sunlamp"]["images"] == 2
    for row in out["per_image"]:
        assert row["domain"] in ("lightbox", "sunlamp") and row["confidence"] == "none"
        for key in ("image", "success", "runtime_s"):
            assert key in row
    assert main(["eval-speedplus", str(root), "--domain", "sunlmp"]) == 2
    assert "domain sunlmp not in" in capsys.readouterr().err
    (root / "camera.json").write_text(json.dumps(CAMERA | {"distCoeffs": [float("nan")] * 5}))
    assert main(["eval-speedplus", str(root), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jaxpose eval-speedplus: error: ")
    assert "camera.json: distCoeffs is not finite" in err[0]


def test_records_resume_where_an_interrupted_run_stopped(tmp_path, capsys, monkeypatch):
    """With --out (records), each image's record is kept as it is scored: a rerun with the same
    settings runs no image again and gives the same per-image records; a record cut short by an
    interruption is run again, alone; other options, or another label, run their images anew.
    The command writes summary.json (its --json object and the software versions) and
    errors.png."""
    from jaxpose.cli import main
    from jaxpose.pipelines.monocular import InitOptions
    from jaxpose.studies.speedplus import evaluate_speedplus

    monkeypatch.setenv("JAXPOSE_CACHE_DIR", str(tmp_path / "xla"))
    (tmp_path / "root").mkdir()
    root = _root(tmp_path / "root")
    out = tmp_path / "out"
    argv = ["eval-speedplus", str(root), "--out", str(out), "--json", "--no-progress"]
    assert main(argv) == 0
    first = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    summary = json.loads((out / "summary.json").read_text())
    software = summary.pop("software")  # the versions the run used, beside its --json object
    assert summary == first
    assert software["opencv"] == metadata.version("opencv-contrib-python-headless")
    assert software["jax"] == metadata.version("jax")
    assert cv2.imread(str(out / "errors.png")) is not None
    records = out / "records.jsonl"
    assert len(records.read_text().splitlines()) == 1 + first["images"] == 7

    def run(**kw):
        ran = []
        res = evaluate_speedplus(
            root,
            records=records,
            progress=False,
            on_result=lambda lab, r, row: ran.append(lab),
            **kw,
        )
        return res, [lab.image.name for lab in ran]

    again, ran = run()
    assert ran == [] and again["per_image"] == first["per_image"]
    lines = records.read_text().splitlines()
    records.write_text("\n".join(lines[:-1] + [lines[-1][:25]]) + "\n")  # cut short
    again, ran = run()

    def timeless(rows):
        return [{k: v for k, v in r.items() if k != "runtime_s"} for r in rows]

    assert len(ran) == 1 and timeless(again["per_image"]) == timeless(first["per_image"])
    _, ran = run(options=InitOptions(top_k=3))  # other settings: every image anew
    assert len(ran) == 6
    labels = json.loads((root / "lightbox" / "test.json").read_text())
    labels[0]["r_Vo2To_vbs_true"][2] += 1.0  # a corrected label
    (root / "lightbox" / "test.json").write_text(json.dumps(labels))
    _, ran = run(options=InitOptions(top_k=3))
    assert ran == [labels[0]["filename"]]
