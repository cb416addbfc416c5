"""The per-frame fit of ``bench/stereo_frame_bias.py``: it recovers a known pose from exact
pixels of known points (a closed form), and its normal matrix is that of finite differences."""

import numpy as np
import pytest
from bench_module import load_bench
from scipy.spatial.transform import Rotation

bench = load_bench("stereo_frame_bias")  # it imports its sibling stereo_bound

FOCAL, CENTRE = (800.0, 790.0), (320.0, 240.0)
T_RL = np.array([-0.3, 0.0, 0.0])


def _scene(rng, n=40):
    points = rng.uniform(-0.5, 0.5, size=(n, 3))
    R = Rotation.from_rotvec([0.2, -0.4, 0.1]).as_matrix()
    t = np.array([0.05, -0.1, 4.0])
    offsets = np.where((np.arange(n) % 2 == 1)[:, None], T_RL, 0.0)
    return points, R, t, offsets


def _pixels(R, t, points, offsets):
    xc = points @ R.T + t + offsets
    return np.stack(
        [FOCAL[0] * xc[:, 0] / xc[:, 2] + CENTRE[0], FOCAL[1] * xc[:, 1] / xc[:, 2] + CENTRE[1]], 1
    )


def test_frame_fit_recovers_the_pose_that_made_the_pixels():
    rng = np.random.default_rng(0)
    points, R, t, offsets = _scene(rng)
    dR = Rotation.from_rotvec(np.radians([0.0, 0.5, 0.0])).as_matrix()  # 0.5 deg about y
    R_true, t_true = dR @ R, t + np.array([0.01, 0.0, -0.02])
    pix = _pixels(R_true, t_true, points, offsets)
    R_fit, t_fit, _ = bench.frame_fit(pix, points, offsets, R, t, FOCAL, CENTRE)
    err = Rotation.from_matrix(R_fit @ R_true.T).magnitude()
    assert np.degrees(err) < 1e-7
    np.testing.assert_allclose(t_fit, t_true, atol=1e-9)
    # from the pose that made the pixels, nothing moves
    R_same, t_same, _ = bench.frame_fit(pix, points, offsets, R_true, t_true, FOCAL, CENTRE)
    np.testing.assert_allclose(R_same, R_true, atol=1e-12)


def test_frame_fit_normal_matrix_matches_finite_differences():
    rng = np.random.default_rng(1)
    points, R, t, offsets = _scene(rng)

    def pixels(x):
        Rx = Rotation.from_rotvec(x[:3]).as_matrix() @ R
        return _pixels(Rx, t + x[3:], points, offsets).ravel()

    h = 1e-6
    J = np.stack([(pixels(h * e) - pixels(-h * e)) / (2 * h) for e in np.eye(6)], 1)
    _, _, normal = bench.frame_fit(
        _pixels(R, t, points, offsets), points, offsets, R, t, FOCAL, CENTRE
    )
    np.testing.assert_allclose(normal, J.T @ J, rtol=1e-5)


def test_an_unknown_scene_field_is_a_usage_error(capsys):
    with pytest.raises(SystemExit):
        bench.main(["d1-clean-2m", "--scene-option", "pixel_sample=3"])
    assert "StereoScene has no field 'pixel_sample'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        bench.main(["d1-clean-2m", "--scene-option", "pixel_samples"])
    assert "NAME=VALUE" in capsys.readouterr().err


@pytest.mark.parametrize(
    "option", ["window_frame=3", "features.subpixl=False", "window_frames=three", "features"]
)
def test_a_bad_tracker_option_is_a_usage_error(capsys, option):
    with pytest.raises(SystemExit):
        bench.main(["d1-clean-2m", "--option", option])
    err = capsys.readouterr().err
    assert f"--option {option!r}" in err and "TrackerOptions" in err


def test_motion_summary_reads_a_displacement_along_the_motion():
    rng = np.random.default_rng(2)
    motion = rng.normal(0.0, 4.0, (500, 2))
    length = np.linalg.norm(motion, axis=1, keepdims=True)
    residuals = 0.2 * motion + 0.3 * motion / length + rng.normal(0.0, 0.05, (500, 2))
    got = bench.motion_summary(residuals, motion)
    assert abs(got["slope_along_motion"] - 0.2) < 0.01
    assert abs(got["intercept_px"] - 0.3) < 0.02
    np.testing.assert_allclose(got["mean_residual_uv_px"], residuals.mean(0), atol=1e-3)
    across = bench.motion_summary(motion[:, ::-1] * [1, -1] * 0.2, motion)  # perpendicular
    assert abs(across["slope_along_motion"]) < 1e-9 and abs(across["intercept_px"]) < 1e-9


def test_surface_classes_tell_a_face_an_edge_and_the_silhouette():
    """The body's +z face seen head-on at 4 m: its centre is on one face, the midpoint of its +x
    edge has sky beside it, and the midpoint of its +y edge has the wing (another box, behind)
    beside it; the classes come from rays cast through the pixels around each."""
    from jaxpose.vision.stereo_render import default_rig, tumbler_model

    cam = default_rig().left
    model = tumbler_model(1.0)
    R, t = np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 4.0])
    bx, by, bz = 0.25, 0.225, 0.275  # the body's half-sizes (tumbler_model)
    X = np.array([[0.0, 0.0, bz], [bx, 0.0, bz], [0.0, by, bz]])
    xc = X @ R.T + t
    fx, fy, cx, cy = (float(v) for v in (cam.fx, cam.fy, cam.cx, cam.cy))
    pix = np.stack([fx * xc[:, 0] / xc[:, 2] + cx, fy * xc[:, 1] / xc[:, 2] + cy], 1)
    got = bench.surface_classes(pix, R, t, cam, model, margin=5.0)
    assert got.tolist() == ["face", "silhouette", "edge"]
    # a pixel 20 px inside the +x edge is on the face again
    inside = bench.surface_classes(pix[1:2] - [20.0, 0.0], R, t, cam, model, margin=5.0)
    assert inside.tolist() == ["face"]


def test_surface_summary_counts_and_averages_each_class():
    classes = np.array(["face", "face", "edge"])
    observed = np.array(["face", "face", "edge", "face"])
    res = np.array([[0.1, 0.0], [0.3, 0.0], [1.0, -1.0], [0.2, 0.3]])
    got = bench.surface_summary(classes, res, observed)
    assert got["face"]["landmarks"] == 2 and got["face"]["observations"] == 3
    np.testing.assert_allclose(got["face"]["mean_residual_uv_px"], [0.2, 0.1], atol=1e-9)
    assert got["edge"]["median_length_px"] == round(float(np.sqrt(2.0)), 3)
    assert got["silhouette"] == {"landmarks": 0, "observations": 0}


def test_surface_figure_draws_each_class_in_its_colour_about_the_target(tmp_path):
    import cv2

    img = np.zeros((240, 320), np.uint8)
    img[100:160, 120:220] = 120  # the target: 100 x 60 px, so the crop is 120 x 80 (10 px more)
    pix = np.array([[170.0, 130.0], [125.0, 130.0], [150.0, 105.0]])
    classes = np.array(["face", "silhouette", "edge"])
    path = tmp_path / "f.png"
    bench.surface_figure(img, pix, classes, path)
    out = cv2.imread(str(path))
    assert out.shape[:2] == (400, 600)  # scaled by 600 / 120 = 5
    for (u, v), c in zip(pix, classes, strict=True):
        x, y = round((u - 110 + 0.5) * 5 - 0.5), round((v - 90 + 0.5) * 5 - 0.5)
        np.testing.assert_array_equal(out[y, x], bench.SURFACE_COLOURS[c])
    assert np.all(out[5, 5] == 0) and np.all(out[100, 100] == 120)  # the sky and the face
