"""Tumbling-target motion and the sweeping light of the stereo renderer, against the kinematics
they stand for (closed-form angles, SciPy rotations)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxpose.vision.stereo_render import (
    StereoScene,
    default_rig,
    render_stereo_frame,
    scene_pose,
)


def test_spin_about_an_off_principal_axis_keeps_that_axis_fixed():
    axis = np.array([0.3, -0.2, 1.0])
    axis /= np.linalg.norm(axis)
    scene = StereoScene(spin_axis_body=tuple(axis), rate_deg_s=12.0)
    R0, _ = scene_pose(scene, 0.0)
    R1, _ = scene_pose(scene, 2.5)
    np.testing.assert_allclose(R0 @ axis, R1 @ axis, atol=1e-12)  # the spin axis stays put
    rel = Rotation.from_matrix(R1 @ R0.T)
    assert np.degrees(rel.magnitude()) == pytest.approx(30.0, abs=1e-9)
    np.testing.assert_allclose(rel.as_rotvec() / rel.magnitude(), R0 @ axis, atol=1e-9)
    # the default motion is unchanged: a flat spin about body z
    R, t = scene_pose(StereoScene(), 1.0)
    R_ref, _ = scene_pose(StereoScene(spin_axis_body=(0.0, 0.0, 2.0)), 1.0)
    np.testing.assert_allclose(R, R_ref, atol=1e-12)
    with pytest.raises(ValueError, match="spin_axis_body"):
        scene_pose(StereoScene(spin_axis_body=(0.0, 0.0, 0.0)), 0.0)


def test_nutation_keeps_a_constant_cone_angle_and_precesses():
    scene = StereoScene(nutation_deg=15.0, precession_deg_s=6.0, rate_deg_s=10.0)
    z = np.array([0.0, 0.0, 1.0])
    R0, _ = scene_pose(scene, 0.0)
    # the precession axis: the spin axis' rest direction (the flat-spin scene's body z)
    p = scene_pose(StereoScene(), 0.0)[0] @ z
    dirs = [scene_pose(scene, s)[0] @ z for s in np.linspace(0.0, 30.0, 7)]
    cone = [np.degrees(np.arccos(np.clip(d @ p, -1, 1))) for d in dirs]
    np.testing.assert_allclose(cone, 15.0, atol=1e-9)
    # after 30 s the spin axis went 180 degrees round the cone
    assert np.degrees(np.arccos(np.clip(dirs[0] @ dirs[-1], -1, 1))) == pytest.approx(
        30.0, abs=1e-6
    )
    for R in (scene_pose(scene, s)[0] for s in (0.0, 7.0)):
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


def test_the_light_sweep_changes_the_shading_over_the_sequence():
    rig = default_rig(320, 240)
    still = StereoScene(frames=5, noise_sigma=0.0, sun_rate_deg_s=0.0, rate_deg_s=0.0)
    sweep = StereoScene(
        frames=5, noise_sigma=0.0, sun_rate_deg_s=0.0, rate_deg_s=0.0, sun_sweep_deg=60.0
    )
    a0, a4 = (render_stereo_frame(still, rig, k).left.astype(int) for k in (0, 4))
    b0, b4 = (render_stereo_frame(sweep, rig, k).left.astype(int) for k in (0, 4))
    np.testing.assert_array_equal(a0, a4)  # nothing moves
    np.testing.assert_array_equal(a0, b0)  # the sweep starts where the still light is
    assert np.abs(b4 - b0).mean() > 1.0  # and has moved the shading by the last frame


# -------------------------------------------------------------------------- motion blur
# A stripe edge on the face that looks at the camera (face 2, body y-) moves across the image as
# the target spins: 90 deg/s and a full exposure at 5 Hz sweep it ~13 px in a 320 x 240 image.
_BLUR = dict(frames=2, rate_deg_s=90.0, blur=1.0, noise_sigma=0.0, defocus_px=0.0)


def _stripe(points_body):
    return np.where(points_body[:, 0] < 0.05, 0.25, 0.85)


@pytest.fixture(scope="module")
def smear():
    """The blurred left image with the default sampling and with 3 samples, and the exposure's
    integral as 96 sub-frame radiances averaged (midpoint rule), one row through the stripe."""
    from jaxpose.core.geometry import Pose
    from jaxpose.vision.render import apply_sensor, render_layers
    from jaxpose.vision.stereo_render import tumbler_model

    rig, model, tex = default_rig(320, 240), tumbler_model(), {2: _stripe}
    scene = StereoScene(**_BLUR)
    new = render_stereo_frame(scene, rig, 0, model=model, textures=tex).left
    three = StereoScene(**_BLUR, blur_samples=3)
    old = render_stereo_frame(three, rig, 0, model=model, textures=tex).left
    sun = np.asarray(scene.sun_dir_cam) / np.linalg.norm(scene.sun_dir_cam)
    n, exposure = 96, scene.blur / scene.frame_rate_hz
    acc = np.zeros((240, 320))
    for off in ((np.arange(n) + 0.5) / n - 0.5) * exposure:
        R, t = scene_pose(scene, off)
        radiance, _ = render_layers(
            model, Pose(R, t), rig.left, sun_dir_cam=sun, ambient=scene.ambient, textures=tex
        )
        acc += np.nan_to_num(radiance)
    ref = apply_sensor(acc / n, np.random.default_rng(0), blur_sigma_px=0.0, noise_sigma=0.0)
    return new.astype(int), old.astype(int), ref.astype(int)


def _ramp(row):
    """Indices of the longest strictly increasing run of ``row``."""
    up = np.diff(row) > 0
    best, start = (0, 0), None
    for i, u in enumerate(np.r_[up, False]):
        if u and start is None:
            start = i
        elif not u and start is not None:
            best = max(best, (i - start, start))
            start = None
    return np.arange(best[1], best[1] + best[0] + 1)


def test_motion_blur_is_a_smear_not_copies(smear):
    new, old, ref = smear
    for v in (105, 120, 135):  # rows through the stripe, below the antenna
        ramp = _ramp(ref[v])
        assert len(ramp) >= 10  # the exposure's integral: a ramp of ~13 px
        # the default sampling: a ramp over the same pixels (no plateau inside it), close to
        # the integral
        assert np.all(np.diff(new[v, ramp[1:-1]]) > 0), v
        assert np.abs(new[v, ramp] - ref[v, ramp]).max() <= 6, v
        # three samples leave three copies of the edge: plateaus of several pixels
        assert np.sum(np.diff(old[v, ramp]) == 0) >= 4, v
    # over the whole image: the smear is within a few grey levels of the integral
    assert np.percentile(np.abs(new - ref), 99.9) <= 6
    assert np.percentile(np.abs(old - ref), 99.9) >= 20


def test_exposure_offsets_keep_every_vertex_within_the_step():
    from jaxpose.vision.stereo_render import exposure_offsets, tumbler_model

    rig, model = default_rig(320, 240), tumbler_model()
    scene = StereoScene(**_BLUR)
    off = exposure_offsets(scene, rig, 0.0, model=model)
    exposure = scene.blur / scene.frame_rate_hz
    n = len(off)
    # midpoints of n equal parts of the exposure
    np.testing.assert_allclose(off, (np.arange(n) + 0.5) / n * exposure - exposure / 2)

    def pixels(times):  # the vertices through the JAX projection (not the renderer's NumPy one)
        out = []
        for s in times:
            R, t = scene_pose(scene, s)
            out.append(np.asarray(rig.left.project(model.vertices @ R.T + t)))
        return np.stack(out)

    step = np.linalg.norm(np.diff(pixels(off), axis=0), axis=-1).max()
    assert step <= 1.01 * scene.blur_step_px  # the speed is probed at 17 poses: within 1%
    # and no fewer samples would do: with n - 1 the fastest vertex moves more than the step
    fewer = ((np.arange(n - 1) + 0.5) / (n - 1) - 0.5) * exposure
    assert np.linalg.norm(np.diff(pixels(fewer), axis=0), axis=-1).max() > scene.blur_step_px
    assert len(exposure_offsets(StereoScene(**{**_BLUR, "blur_samples": 5}), rig, 0.0)) == 5
    np.testing.assert_array_equal(exposure_offsets(StereoScene(), rig, 0.0), [0.0])
    for bad in (
        dict(blur=-0.5),
        dict(blur_step_px=0.0),
        dict(blur_samples=0),
        dict(pixel_samples=0),
        dict(pixel_samples=-2),
    ):
        with pytest.raises(ValueError, match=next(iter(bad))):
            StereoScene(**bad)


@pytest.mark.parametrize("samples", [1, 2])
def test_rendering_the_target_window_gives_the_whole_image_pixels(monkeypatch, samples):
    """Also with 2 x 2 samples a pixel: the window's sampling camera (its principal point moved
    by the window's corner, then scaled) sees what the whole image's does."""
    import jaxpose.vision.stereo_render as sr

    rig = default_rig(320, 240)
    scene = StereoScene(
        frames=2, range_m=2.5, rate_deg_s=20.0, blur=1.0, glints=1.0, pixel_samples=samples
    )
    windowed = render_stereo_frame(scene, rig, 1)
    (v0, v1, u0, u1), _ = sr._target_window(rig.left, sr.tumbler_model(), [scene_pose(scene, 0.2)])
    assert (v1 - v0) * (u1 - u0) < 0.5 * 240 * 320  # the window is a part of the image
    monkeypatch.setattr(sr, "_target_window", lambda camera, *_: ((0, 240, 0, 320), camera))
    whole = render_stereo_frame(scene, rig, 1)
    np.testing.assert_array_equal(windowed.left, whole.left)
    np.testing.assert_array_equal(windowed.right, whole.right)
    np.testing.assert_array_equal(windowed.roi, whole.roi)
    assert u0 < windowed.roi[0] < windowed.roi[2] < u1  # the target inside the window
    assert v0 < windowed.roi[1] < windowed.roi[3] < v1


def test_the_sample_camera_spreads_each_pixels_samples_about_its_centre():
    """Sample ``(n u + k, n v + l)`` of the sampling camera seen through the pixel's camera lies
    at ``u - 1/2 + (k + 1/2) / n``: the samples tile the pixel and their mean is its centre."""
    import jaxpose.vision.stereo_render as sr

    cam = default_rig(320, 240).left
    for n in (2, 3, 4):
        s = sr._sampling_camera(cam, n)
        assert (s.width, s.height) == (n * 320, n * 240)
        u, v = 17, 101
        k = np.arange(n)
        x = (n * u + k - float(s.cx)) / float(s.fx)  # the samples' normalised coordinates
        y = (n * v + k - float(s.cy)) / float(s.fy)
        np.testing.assert_allclose(float(cam.fx) * x + float(cam.cx), u - 0.5 + (k + 0.5) / n)
        np.testing.assert_allclose(float(cam.fy) * y + float(cam.cy), v - 0.5 + (k + 0.5) / n)
    block = np.arange(36.0).reshape(6, 6)
    np.testing.assert_allclose(sr._pixel_means(block, 3), [[7.0, 10.0], [25.0, 28.0]])


def _centroid(img):
    w = img.astype(float)
    vv, uu = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    return np.array([(w * uu).sum(), (w * vv).sum()]) / w.sum()


def test_area_sampling_keeps_the_image_at_the_pixel_centres_and_follows_a_subpixel_shift():
    """With the faces filled exactly (the model without its antennas, which ``cv2.line`` draws),
    the target's intensity centroid converges as the samples per pixel grow and stays where one
    sample at each pixel's centre puts it (a sampling camera off by its ``(n - 1) / 2`` would
    move it by 0.4 px), and moving the principal point by 0.3 px moves the area-sampled image
    by 0.3 px (a box-filtered image is shift covariant). ``cv2.fillPoly``'s faces, half a
    pixel grown, move the one-sample centroid by more."""
    import dataclasses

    import equinox as eqx

    from jaxpose.vision.stereo_render import tumbler_model

    model = dataclasses.replace(tumbler_model(), antennas=np.zeros((0, 2), int))
    rig = default_rig(320, 240)
    base = dict(frames=2, range_m=2.5, rate_deg_s=10.0, noise_sigma=0.0, exact_faces=True)

    def centroid(n, camera_rig=rig, **over):
        scene = StereoScene(**{**base, **over}, pixel_samples=n)
        return _centroid(render_stereo_frame(scene, camera_rig, 1, model=model).left)

    c1, c4, c8 = centroid(1), centroid(4), centroid(8)
    assert np.abs(c4 - c8).max() < 0.03
    assert np.abs(c1 - c8).max() < 0.12
    moved = centroid(4, eqx.tree_at(lambda r: r.left.cx, rig, rig.left.cx + 0.3))
    np.testing.assert_allclose(moved - c4, [0.3, 0.0], atol=0.02)
    assert np.abs(centroid(1, exact_faces=False) - c8).max() > 0.15


@pytest.mark.parametrize(
    "bad",
    [
        dict(range_m=0.0),
        dict(range_m=-1.0),
        dict(range_m=float("nan")),
        dict(range_m="3"),
        dict(frame_rate_hz=0.0),
        dict(size_m=-0.5),
        dict(glints=-0.1),
        dict(noise_sigma=float("inf")),
        dict(rate_deg_s=float("nan")),
        dict(nutation_deg=float("inf")),
        dict(sun_dir_cam=(0.0, 0.0, 0.0)),
        dict(spin_axis_body=(1.0, 2.0)),
        dict(spin_axis_body="up"),
        dict(frames=1),
        dict(frames=2.5),
        dict(frames="10"),
    ],
)
@pytest.mark.typecheck_off
def test_a_scene_with_a_bad_parameter_is_refused_naming_it(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        StereoScene(**bad)
    # numbers of any real type pass (a draw's NumPy floats)
    StereoScene(range_m=np.float32(3.0), frames=np.int64(4), rate_deg_s=np.float64(-5.0))


def test_a_frame_renders_on_one_blas_thread_and_leaves_the_library_as_it_was(monkeypatch):
    """The ray cast's BLAS threads would spin after the frame and take a tracker's cores: the
    frame is drawn with BLAS on one thread, the caller's setting restored after, and the images
    are the same bits as those drawn without the limit."""
    import threadpoolctl

    import jaxpose.vision.stereo_render as sr

    def blas_threads():
        info = threadpoolctl.threadpool_info()
        return [p["num_threads"] for p in info if p["user_api"] == "blas"]

    before = blas_threads()
    seen = []
    draw = sr._render_stereo_frame

    def spy(*args):
        seen.append(blas_threads())
        return draw(*args)

    monkeypatch.setattr(sr, "_render_stereo_frame", spy)
    rig = default_rig(320, 240)
    scene = StereoScene(frames=2, range_m=2.5, glints=1.0, blur=0.5)
    limited = render_stereo_frame(scene, rig, 1)
    assert seen and all(n == 1 for n in seen[0])
    assert blas_threads() == before
    free = draw(scene, rig, 1, None, None, None, None)
    np.testing.assert_array_equal(limited.left, free.left)
    np.testing.assert_array_equal(limited.right, free.right)


def test_quilt_facets_mirror_the_sun_cell_by_cell():
    from jaxpose.vision.stereo_render import _faceted, tumbler_model

    model = tumbler_model()
    R = Rotation.from_euler("xyz", [20.0, -35.0, 10.0], degrees=True).as_matrix()
    t = np.array([0.05, -0.1, 3.0])
    n_cam = model.face_normals @ R.T
    rng = np.random.default_rng(0)
    # points on the body's faces (body frame), their camera rays, on the faces seen from the camera
    face = rng.integers(0, 6, 4000)
    lo, hi = model.vertices[:8].min(0), model.vertices[:8].max(0)
    P = rng.uniform(lo, hi, (4000, 3))
    axis, side = face // 2, face % 2  # z-, z+, y-, y+, x-, x+ (tumbler_model's order)
    k = np.array([2, 1, 0])[axis]
    P[np.arange(4000), k] = np.where(side == 1, hi[k], lo[k])
    X = P @ R.T + t
    seen = np.einsum("ij,ij->i", n_cam[face], X) < 0
    face, P, X = face[seen], P[seen], X[seen]
    rays = X / np.linalg.norm(X, axis=1, keepdims=True)
    n = _faceted(n_cam[face], face, rays, model, R, t, 45.0, 0.05)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    tilt = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", n, n_cam[face]), -1, 1)))
    assert tilt.max() <= 45.0 + 1e-9 and tilt.mean() > 15.0  # tilted, within the bound
    # one normal a quilt cell (cells of the body point, the texture's), different across cells
    cell = np.floor(P / 0.05).astype(np.int64)
    _, inverse = np.unique(np.c_[face, cell], axis=0, return_inverse=True)
    for c in np.unique(inverse)[:200]:
        sel = inverse.ravel() == c
        assert np.ptp(n[sel], axis=0).max() < 1e-9
    assert len(np.unique(np.round(n, 6), axis=0)) > 100
    # the wing (faces 6-11) keeps its flat normals
    flat = _faceted(n_cam[[6, 7]], np.array([6, 7]), rays[:2], model, R, t, 45.0, 0.05)
    np.testing.assert_array_equal(flat, n_cam[[6, 7]])


def test_glints_are_seen_with_facets_and_not_on_flat_faces():
    rig = default_rig()
    seen = {}
    for facets in (0.0, 45.0):
        extra = []
        for k in (3, 6, 9):  # d4's scene of bench/stereo.py
            scene = dict(frames=30, range_m=4.0, rate_deg_s=6.0, noise_sigma=0.0)
            glinting = StereoScene(glints=1.0, glint_facet_deg=facets, **scene)
            on = render_stereo_frame(glinting, rig, k)
            off = render_stereo_frame(StereoScene(**scene), rig, k)
            extra.append(int((on.left.astype(int) - off.left.astype(int) > 10).sum()))
        seen[facets] = extra
    # flat faces: no face mirrors the Sun into the camera in this geometry
    assert seen[0.0] == [0, 0, 0]
    assert max(seen[45.0]) > 100
    for bad in (-1.0, 91.0, float("nan")):
        with pytest.raises(ValueError, match="glint_facet_deg"):
            StereoScene(glint_facet_deg=bad)
