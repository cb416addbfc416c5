"""Monocular pose initialisation end to end on rendered images (and the SPEED+ sample)."""

import json

import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import PinholeCamera, Pose
from jaxpose.core.geometry import euler_to_dcm
from jaxpose.core.metrics import rotation_error, success
from jaxpose.pipelines.monocular import InitOptions, draw_overlay, initialise_pose, load_image
from jaxpose.vision.models import tango
from jaxpose.vision.render import render

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def camera():
    # SPEED+-like optics at a quarter of the resolution (faster, same geometry per pixel angle).
    return PinholeCamera(
        747.0, 747.0, 239.5, 149.5, [-0.22, 0.51, 0.0, 0.0, -0.13], width=480, height=300
    )


@pytest.fixture(scope="module")
def scene(camera):
    pose = Pose(np.asarray(euler_to_dcm(jnp.array([2.3, 0.4, 0.6]))), np.array([0.05, -0.03, 4.0]))
    r = render(tango(), pose, camera, rng=7)
    return r, initialise_pose(r.image, camera)


def test_rendered_image_pose(scene):
    r, res = scene
    assert res.confidence in ("high", "low")
    assert bool(success(res.pose, r.pose))
    assert float(rotation_error(res.pose.R, jnp.asarray(r.pose.R))) < np.deg2rad(5)
    js = res.to_json()
    for key in (
        "R_cam_body",
        "t_cam",
        "quat_wxyz",
        "confidence",
        "reprojection_error_px",
        "roi",
        "coarse_t_cam",
        "runtime_s",
    ):
        assert key in js
    assert abs(np.linalg.norm(js["coarse_t_cam"]) / np.linalg.norm(r.pose.t) - 1) < 0.4


def test_given_roi(scene, camera):
    """A caller's box (here the renderer's box of the target, in the distorted image) replaces the
    gradient ROI: against the black sky the silhouette found agrees with it and is kept, so the
    answer is the one without a box; a box elsewhere drops the silhouette (the ROI is then the
    box, mapped through the distortion); a box outside the image is refused by name."""
    from jaxpose.vision.undistort import undistort_box

    r, own = scene
    res = initialise_pose(r.image, camera, roi=r.roi)
    assert bool(success(res.pose, r.pose)) and res.silhouette_iou is not None
    np.testing.assert_allclose(res.roi, own.roi)
    np.testing.assert_allclose(res.pose.t, own.pose.t, atol=1e-9)
    away = np.array([5.0, 5.0, 60.0, 50.0])  # a corner of empty sky
    det = initialise_pose(r.image, camera, roi=away).detection
    assert det.silhouette is None
    np.testing.assert_allclose(det.roi, undistort_box(away, camera, r.image.shape[:2]))
    with pytest.raises(ValueError, match="outside"):
        initialise_pose(r.image, camera, roi=[600, 400, 700, 500])


def test_overlay(scene):
    """The image part is the undistorted input where nothing is drawn, the projected model is drawn
    in its legend colour along every projected edge, and a legend strip under the image names the
    colours in white text with a swatch of each colour."""
    from jaxpose.vision.overlay import LEGEND

    r, res = scene
    img = draw_overlay(r.image, res)
    H, W = r.image.shape
    assert img.dtype == np.uint8 and img.shape[1:] == (W, 3) and img.shape[0] > H + 100
    top, strip = img[:H], img[H:]
    # anti-aliased lines: a drawn pixel is red-dominated (BGR)
    top_i = top.astype(int)
    drawn = top_i[..., 2] - np.maximum(top_i[..., 0], top_i[..., 1]) > 60
    for u, v in res.projected.mean(axis=1):  # the midpoint of each projected edge
        i, j = int(round(v)), int(round(u))
        if 1 <= i < H - 1 and 1 <= j < W - 1:
            assert drawn[i - 1 : i + 2, j - 1 : j + 2].any()
    base = np.stack([res.detection.image] * 3, -1)
    assert np.mean(np.all(top == base, axis=-1)) > 0.8
    assert np.all(strip == 255, axis=-1).sum() > 200  # white text
    for _, colour, _ in LEGEND:  # a swatch of every colour
        assert (np.abs(strip.astype(int) - np.array(colour)).max(axis=-1) < 40).sum() > 10


def test_image_depths_give_the_same_pose(scene, camera):
    """A 16-bit image (full range) and a float64 colour image in [0, 1] give exactly the pose of
    their 8-bit version."""
    r, res = scene
    for img in (r.image.astype(np.uint16) * 257, np.stack([r.image] * 3, -1) / 255.0):
        other = initialise_pose(img, camera)
        assert other.confidence == res.confidence
        np.testing.assert_array_equal(np.asarray(other.pose.R), np.asarray(res.pose.R))
        np.testing.assert_array_equal(np.asarray(other.pose.t), np.asarray(res.pose.t))


def test_pose_does_not_depend_on_the_callers_precision(scene, camera):
    """With ``jax_enable_x64`` off, for the process as a user leaves it (the suite turns it on)
    and in a local context, the pipeline still runs in float64, its host threads included: the
    same pose to the last bit as with it on (the scene's), in float64 arrays; a camera made while
    it is off (float32) gives the pose of its values within float32 rounding."""
    import jax

    r, res = scene
    jax.config.update("jax_enable_x64", False)  # the process's flag: host threads read it
    try:
        with jax.enable_x64(False):
            other = initialise_pose(r.image, camera)
        cam32 = PinholeCamera(
            747.0, 747.0, 239.5, 149.5, [-0.22, 0.51, 0.0, 0.0, -0.13], width=480, height=300
        )
        assert cam32.fx.dtype == jnp.float32
        near = initialise_pose(r.image, cam32)
    finally:
        jax.config.update("jax_enable_x64", True)
    assert other.pose.R.dtype == jnp.float64 and other.pose.t.dtype == jnp.float64
    assert other.confidence == res.confidence
    np.testing.assert_array_equal(np.asarray(other.pose.R), np.asarray(res.pose.R))
    np.testing.assert_array_equal(np.asarray(other.pose.t), np.asarray(res.pose.t))
    assert near.confidence == res.confidence
    np.testing.assert_allclose(np.asarray(near.pose.R), np.asarray(res.pose.R), atol=1e-5)
    np.testing.assert_allclose(np.asarray(near.pose.t), np.asarray(res.pose.t), atol=1e-5)


@pytest.mark.parametrize("kind", ["black", "saturated", "noise", "cut"])
def test_bad_images_do_not_crash(camera, kind):
    rng = np.random.default_rng(0)
    if kind == "black":
        img = np.zeros((300, 480), np.uint8)
    elif kind == "saturated":
        img = np.full((300, 480), 255, np.uint8)
    elif kind == "noise":
        img = rng.integers(0, 256, (300, 480)).astype(np.uint8)
    else:  # the target cut by the frame
        pose = Pose(np.asarray(euler_to_dcm(jnp.array([2.3, 0.4, 0.6]))), np.array([0.9, 0.0, 3.0]))
        img = render(tango(), pose, camera, rng=1).image
    res = initialise_pose(img, camera)
    js = res.to_json()
    json.dumps(js, allow_nan=False)  # no NaN or inf in the printed result
    if kind in ("black", "saturated"):  # no gradient at all: no target, no position
        assert res.confidence == "none" and res.pose is None and js["t_cam"] is None
        assert "no target" in res.message
    elif kind == "noise":  # no target: never an attitude called high
        assert res.confidence != "high"
    else:  # a pose is returned with its class, and "high" only when it is right
        assert (res.pose is not None) == (res.confidence in ("high", "low"))
        if res.confidence == "high":
            assert bool(success(res.pose, pose))


def test_tiny_and_unreadable(camera, tmp_path):
    with pytest.raises(ValueError, match="too small"):
        initialise_pose(np.zeros((8, 8), np.uint8), camera)
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image")
    with pytest.raises(ValueError, match="cannot read"):
        load_image(bad)
    with pytest.raises(ValueError, match="not found"):
        load_image(tmp_path / "missing.png")
    with pytest.raises(ValueError, match="method"):
        initialise_pose(np.zeros((64, 64), np.uint8), camera, options=InitOptions(method="x"))


def test_ransac_baseline_runs(scene, camera):
    r, _ = scene
    res = initialise_pose(
        r.image, camera, options=InitOptions(method="ransac", ransac_iterations=512)
    )
    assert res.group_kind == "ransac" and res.hypotheses == 512
    assert res.pose is not None and res.confidence in ("high", "low")
    assert np.isfinite(res.score) and np.all(np.isfinite(np.asarray(res.pose.t)))


def test_speedplus_image_runs(speedplus_dir):
    from jaxpose.io import load_camera, load_speed_labels

    cam = load_camera(speedplus_dir / "camera.json")
    lab = load_speed_labels(speedplus_dir)[0]
    res = initialise_pose(load_image(lab.image), cam)
    assert res.roi is not None
    # The coarse range is within 30% on this rendered SPEED+ image.
    assert abs(np.linalg.norm(res.coarse_t_cam) / np.linalg.norm(lab.r_Vo2To_vbs) - 1) < 0.3


def test_cli_init_and_eval(tmp_path, camera, scene, capsys, monkeypatch):
    import json

    import cv2

    from jaxpose.cli import main
    from jaxpose.io import save_camera

    monkeypatch.setenv("JAXPOSE_CACHE_DIR", str(tmp_path / "xla"))
    r, _ = scene
    cv2.imwrite(str(tmp_path / "img.png"), r.image)
    save_camera(camera, tmp_path / "camera.json")
    overlay = tmp_path / "overlay.png"
    assert (
        main(
            [
                "init",
                str(tmp_path / "img.png"),
                "--camera",
                str(tmp_path / "camera.json"),
                "--overlay",
                str(overlay),
            ]
        )
        == 0
    )
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert (
        out["confidence"] in ("high", "low") and len(out["R_cam_body"]) == 3 and overlay.is_file()
    )
    assert (
        main(["init", str(tmp_path / "missing.png"), "--camera", str(tmp_path / "camera.json")])
        == 2
    )
    capsys.readouterr()
    bad_roi = ["--roi", "600", "400", "700", "500"]  # beyond the 480x300 image
    assert (
        main(
            ["init", str(tmp_path / "img.png"), "--camera", str(tmp_path / "camera.json"), *bad_roi]
        )
        == 2
    )
    assert "outside" in capsys.readouterr().err
    # eval-speedplus on a one-image labelled folder made of the rendering.
    from jaxpose.core.geometry import dcm_to_quat

    q = np.asarray(dcm_to_quat(jnp.asarray(r.pose.R)))
    t = np.asarray(r.pose.t)
    (tmp_path / "labels.csv").write_text(
        "image,domain,qw,qx,qy,qz,tx,ty,tz\nimg.png,rendered," + ",".join(map(str, [*q, *t])) + "\n"
    )
    assert main(["eval-speedplus", str(tmp_path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for key in (
        "images",
        "success_rate",
        "high_confidence",
        "high_precision",
        "esa_score_mean",
        "coarse_range_within_20pct",
        "median_runtime_s",
        "per_image",
    ):
        assert key in summary
    assert summary["images"] == 1 and summary["success_rate"] == 1.0
    # black sky: the silhouette term took part, and the right pose covers the silhouette
    assert summary["per_image"][0]["silhouette_iou"] > 0.7
