"""Bad inputs to the core's cameras, poses, options, information blocks and lines (audit rows S2,
S2b, S3, S8, S9, S12-S15, S19, U2-U4, U16): a clear ``ValueError`` naming the argument (or a
status saying what is wrong), while good inputs, and rigs or cameras built under ``jit``, ``vmap``
and ``grad``, still work.

Tests that pass a value against its annotation are marked ``typecheck_off``: they check the
package's own ``ValueError``, which jaxtyping's test hook would pre-empt."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose as jp
from jaxpose import PinholeCamera, Pose, StereoCamera
from jaxpose.core._checks import is_rotation
from jaxpose.core.geometry import so3_exp
from jaxpose.core.residuals import joint_cost, line_from_segment
from jaxpose.io import load_camera

K = np.array([[1000.0, 0.0, 320.0], [0.0, 1000.0, 240.0], [0.0, 0.0, 1.0]])
CAM = PinholeCamera.from_K(K, width=640, height=480)
X = np.array([[0.1, 0.05, 4.0], [-0.3, 0.2, 5.0], [0.0, 0.0, 3.0]])


def _named(name: str) -> str:
    """A ``match`` pattern for ``name`` as a whole word."""
    return rf"(?<!\w){name}(?!\w)"


def _with(M, index, value):
    M = np.array(M, dtype=float)
    M[index] = value
    return M


# ------------------------------------------------------------------ S2: from_K skew / last row


@pytest.mark.typecheck_off
@pytest.mark.parametrize(
    "bad",
    [
        _with(K, (0, 1), 50.0),  # skew
        _with(K, (0, 1), 1e-3),  # a small skew is still a skew (above 1e-9 fx)
        _with(K, (1, 0), 3.0),
        _with(K, (2, 2), 2.0),
        _with(_with(K, (2, 0), 0.5), (2, 2), 2.0),
        _with(K, (2, 1), 1e-6),
    ],
    ids=["skew", "small-skew", "K10", "K22", "last-row", "K21"],
)
def test_from_K_refuses_what_it_would_drop(bad):
    with pytest.raises(ValueError, match=_named("K")):
        PinholeCamera.from_K(bad)
    with pytest.raises(ValueError, match=_named("K")):
        PinholeCamera.from_K(jnp.asarray(bad))


@pytest.mark.typecheck_off
def test_from_K_refuses_strings_and_bools():
    with pytest.raises(ValueError, match=_named("K")):
        PinholeCamera.from_K([["1000", 0, 320], [0, 1000, 240], [0, 0, 1]])
    with pytest.raises(ValueError, match=_named("K")):
        PinholeCamera.from_K(np.eye(3, dtype=bool))


def test_from_K_exact_K_round_trips():
    Ks = np.array([[812.5, 0.0, 319.25], [0.0, 790.0, 241.5], [0.0, 0.0, 1.0]])
    cam = PinholeCamera.from_K(Ks, width=640, height=480)
    np.testing.assert_array_equal(np.asarray(cam.K), Ks)
    # a skew at rounding level is not a skew
    PinholeCamera.from_K(_with(Ks, (0, 1), 1e-10))
    # a traced K is not looked at (a camera built under jit from K)
    fx = jax.jit(lambda k: PinholeCamera.from_K(k).fx)(jnp.asarray(Ks))
    assert float(fx) == 812.5


# ------------------------------------------------------------------ S2b: camera.json


def _camera_file(tmp_path, matrix, name="camera.json"):
    path = tmp_path / name
    path.write_text(json.dumps({"Nu": 640, "Nv": 480, "cameraMatrix": matrix}))
    return path


@pytest.mark.parametrize(
    "matrix",
    [
        [[1000, 30, 320], [0, 1000, 240], [0, 0, 1]],
        [[1000, 0, 320], [0, 1000, 240], [0.1, 0, 1]],
        [[1000, 0, 320], [2, 1000, 240], [0, 0, 1]],
        [[1000, 0, 320], [0, 1000, 240], [0, 0, 2]],
    ],
    ids=["skew", "last-row", "K10", "K22"],
)
def test_load_camera_refuses_skew_and_last_row(tmp_path, matrix):
    path = _camera_file(tmp_path, matrix)
    with pytest.raises(ValueError, match="cameraMatrix") as err:
        load_camera(path)
    assert str(path) in str(err.value)


def test_load_camera_exact_matrix_loads(tmp_path):
    path = _camera_file(tmp_path, K.tolist())
    cam = load_camera(path)
    np.testing.assert_array_equal(np.asarray(cam.K), K)
    assert (cam.width, cam.height) == (640, 480)


# ------------------------------------------------------------------ S12, U2, U3: PinholeCamera


@pytest.mark.typecheck_off
@pytest.mark.parametrize("field", ["width", "height"])
@pytest.mark.parametrize(
    "value", [-640, 640.7, "640", True, np.nan, np.array([640, 480]), None], ids=repr
)
def test_camera_size_must_be_an_integer(field, value):
    size = {"width": 640, "height": 480, field: value}
    with pytest.raises(ValueError, match=_named(field)):
        PinholeCamera(1000.0, 1000.0, 320, 240, **size)


@pytest.mark.typecheck_off
def test_camera_size_good_values():
    assert (PinholeCamera(1000.0, 1000.0, 320, 240).width, CAM.height) == (0, 480)  # 0: unknown
    cam = PinholeCamera(1000.0, 1000.0, 320, 240, width=640.0, height=np.int64(480))
    assert (cam.width, cam.height) == (640, 480)
    assert type(cam.width) is int and type(cam.height) is int
    with pytest.raises(ValueError, match=_named("image_size")):
        PinholeCamera.from_focal_length(0.05, 1e-5, (640.7, 480))
    assert PinholeCamera.from_focal_length(0.05, 1e-5, (640, 480)).width == 640


@pytest.mark.typecheck_off
@pytest.mark.parametrize("field", ["fx", "fy", "cx", "cy"])
@pytest.mark.parametrize(
    "value",
    ["1000", True, np.bool_(False), 1000.0 + 1j, jnp.array([1000.0, 900.0]), [1000.0]],
    ids=["str", "bool", "np-bool", "complex", "array", "list"],
)
def test_camera_intrinsics_must_be_one_real_number(field, value):
    args = {"fx": 1000.0, "fy": 1000.0, "cx": 320.0, "cy": 240.0, field: value}
    with pytest.raises(ValueError, match=_named(field)):
        PinholeCamera(**args)


def test_camera_intrinsics_good_values_and_transforms():
    cam = PinholeCamera(1000, np.float64(1000.0), jnp.asarray(320.0), np.int64(240))
    np.testing.assert_allclose(np.asarray(cam.K), K)
    # NaN intrinsics stay a status downstream (NONFINITE_INPUT), not an error here
    assert np.isnan(float(PinholeCamera(np.nan, 1000.0, 320, 240).fx))
    # built under jit, vmap and grad from traced intrinsics
    pts = jnp.asarray(X)

    def u0(fx):
        return PinholeCamera(fx, 1000.0, 320.0, 240.0).project(pts)[0, 0]

    assert float(jax.jit(u0)(1000.0)) == pytest.approx(1000.0 * 0.1 / 4.0 + 320.0)
    assert float(jax.grad(u0)(1000.0)) == pytest.approx(0.1 / 4.0)
    out = jax.vmap(u0)(jnp.array([1000.0, 2000.0]))
    np.testing.assert_allclose(out, [345.0, 370.0])


# ------------------------------------------------------------------ S13: last axes


@pytest.mark.typecheck_off
def test_project_needs_three_coordinates():
    with pytest.raises(ValueError, match=_named("points_cam")):
        CAM.project(jnp.array([[1.0, 1.0]]))
    with pytest.raises(ValueError, match=_named("points_cam")):
        CAM.project(np.ones((4, 4)))
    with pytest.raises(ValueError, match=_named("points_cam")):
        jax.jit(lambda p: CAM.project(p))(jnp.ones((4, 2)))  # shapes are static: under jit too


@pytest.mark.typecheck_off
def test_pixels_need_two_coordinates():
    with pytest.raises(ValueError, match=_named("pixels")):
        CAM.undistort_pixels(jnp.ones((4, 3)))
    with pytest.raises(ValueError, match=_named("pixels")):
        CAM.normalize(jnp.ones((4, 1)))
    with pytest.raises(ValueError, match=_named("pixels")):
        CAM.bearing(jnp.ones(3))
    with pytest.raises(ValueError, match=_named("xy")):
        CAM.distort(jnp.ones((4, 3)))
    with pytest.raises(ValueError, match=_named("xy_distorted")):
        CAM.undistort(jnp.ones((4, 3)))


def test_project_and_undistort_good_shapes_under_jit():
    dist = np.array([-0.05, 0.01, 1e-3, -1e-3, 0.0])
    cam = PinholeCamera.from_K(K, dist, width=640, height=480)
    uv = jax.jit(lambda p: cam.project(p))(jnp.asarray(X))
    assert uv.shape == (3, 2)
    np.testing.assert_allclose(uv, cam.project(X), atol=1e-12)
    ideal = jax.jit(lambda u: cam.undistort_pixels(u))(uv)
    np.testing.assert_allclose(ideal, cam.without_distortion().project(X), atol=1e-6)
    assert cam.project(jnp.ones((2, 5, 3))).shape == (2, 5, 2)


# ------------------------------------------------------------------ S3, U4: StereoCamera


@pytest.mark.typecheck_off
@pytest.mark.parametrize(
    "R",
    [
        2.0 * np.eye(3),
        np.diag([1.0, 1.0, -1.0]),  # a reflection
        np.asarray(so3_exp(np.array([0.1, 0.2, 0.0]))) + 1e-3,
        _with(np.eye(3), (0, 0), np.nan),
        _with(np.eye(3), (1, 1), np.inf),
    ],
    ids=["2I", "reflection", "off-by-1e-3", "nan", "inf"],
)
def test_stereo_R_rl_must_be_a_rotation(R):
    with pytest.raises(ValueError, match=_named("R_rl")):
        StereoCamera(CAM, CAM, R, [-0.3, 0.0, 0.0])
    with pytest.raises(ValueError, match=_named("R_rl")):
        StereoCamera(CAM, CAM, jnp.asarray(R), jnp.array([-0.3, 0.0, 0.0]))


@pytest.mark.typecheck_off
@pytest.mark.parametrize(
    "t", [[np.nan, 0.0, 0.0], [np.inf, 0.0, 0.0], [-0.3, -np.inf, 0.0], ["-0.3", "0", "0"]]
)
def test_stereo_t_rl_must_be_finite_numbers(t):
    with pytest.raises(ValueError, match=_named("t_rl")):
        StereoCamera(CAM, CAM, None, t)


@pytest.mark.typecheck_off
def test_stereo_R_rl_strings():
    with pytest.raises(ValueError, match=_named("R_rl")):
        StereoCamera(CAM, CAM, "eye", [-0.3, 0.0, 0.0])


@pytest.mark.typecheck_off
@pytest.mark.parametrize(
    "baseline",
    [np.inf, -np.inf, np.nan, 0.0, -0.3, "0.3", True, np.array([0.3, 0.2]), [0.3], None],
    ids=repr,
)
def test_from_baseline_must_be_one_positive_finite_number(baseline):
    with pytest.raises(ValueError, match=_named("baseline_m")):
        StereoCamera.from_baseline(CAM, baseline)


@pytest.mark.typecheck_off
def test_from_baseline_camera_must_be_a_camera():
    with pytest.raises(ValueError, match=_named("camera")):
        StereoCamera.from_baseline(K, 0.3)


def test_stereo_good_rigs():
    R = np.asarray(so3_exp(np.array([0.01, -0.03, 0.005])))
    rig = StereoCamera(CAM, CAM, R, np.array([-0.25, 0.004, 0.002]))
    l, r = rig.project(X)
    np.testing.assert_allclose(rig.triangulate(l, r), X, atol=1e-8)
    # a float32 rotation passes at float32's tolerance
    R32 = jnp.asarray(R, jnp.float32)
    StereoCamera(CAM, CAM, R32, jnp.array([-0.25, 0.0, 0.0], jnp.float32))
    for b in (0.3, jnp.asarray(0.3), 1):
        assert float(StereoCamera.from_baseline(CAM, b).baseline) == pytest.approx(float(b))


@pytest.mark.typecheck_off
def test_good_values_outside_the_annotations():
    # NumPy scalars and 0-d arrays for a baseline, a list of coordinates for project
    for b in (np.float32(0.3), np.array(0.3), np.int64(1)):
        assert float(StereoCamera.from_baseline(CAM, b).baseline) == pytest.approx(float(b))
    assert CAM.project(X[0].tolist()).shape == (2,)


def test_stereo_rig_built_under_jit_and_grad():
    b0 = 0.3
    rig0 = StereoCamera.from_baseline(CAM, b0)
    l, r = rig0.project(X)

    def depth(b):
        return StereoCamera.from_baseline(CAM, b).triangulate(l, r)[0, 2]

    assert float(jax.jit(depth)(b0)) == pytest.approx(4.0, abs=1e-9)
    # z = f b / d for a fixed disparity d: dz/db = z / b
    g = jax.grad(depth)(b0)
    assert np.isfinite(float(g))
    assert float(g) == pytest.approx(4.0 / b0, rel=1e-6)
    assert float(jax.jit(jax.grad(depth))(b0)) == pytest.approx(4.0 / b0, rel=1e-6)
    np.testing.assert_allclose(jax.vmap(depth)(jnp.array([0.3, 0.6])), [4.0, 8.0], atol=1e-9)

    def depth_full(w, t):  # a general rig from a traced rotation and translation
        rig = StereoCamera(CAM, CAM, so3_exp(w), t)
        return rig.triangulate(l, r, method="midpoint")[0, 2]

    w, t = jnp.zeros(3), jnp.array([-b0, 0.0, 0.0])
    assert float(jax.jit(depth_full)(w, t)) == pytest.approx(4.0, abs=1e-9)
    gw, gt = jax.grad(depth_full, argnums=(0, 1))(w, t)
    assert np.all(np.isfinite(np.asarray(gw))) and np.all(np.isfinite(np.asarray(gt)))


# ------------------------------------------------------------------ S14: quaternion


@pytest.mark.typecheck_off
@pytest.mark.parametrize(
    "q",
    [[np.nan, 0, 0, 0], [np.inf, 0, 0, 0], [1, 0, -np.inf, 0], [[1, 0, 0, 0], [np.nan, 0, 0, 0]]],
    ids=["nan", "inf", "minus-inf", "batch"],
)
def test_from_quat_refuses_non_finite(q):
    q = jnp.asarray(q, dtype=float)
    with pytest.raises(ValueError, match=_named("q")):
        Pose.from_quat(q, jnp.zeros(q.shape[:-1] + (3,)))


def test_from_quat_good_and_traced():
    q = np.array([0.9, 0.1, -0.2, 0.3])
    pose = Pose.from_quat(q, np.zeros(3))
    np.testing.assert_allclose(np.asarray(pose.quat), q / np.linalg.norm(q), atol=1e-12)
    with pytest.raises(ValueError, match=_named("q")):
        Pose.from_quat(np.zeros(4), np.zeros(3))  # as before
    # a traced quaternion is not looked at: NaN in, NaN out (jit paths keep working)
    R = jax.jit(lambda q: Pose.from_quat(q, jnp.zeros(3)).R)(jnp.array([np.nan, 0, 0, 0]))
    assert np.all(np.isnan(np.asarray(R)))
    g = jax.grad(lambda q: Pose.from_quat(q, jnp.zeros(3)).R[0, 1])(jnp.asarray(q))
    assert np.all(np.isfinite(np.asarray(g)))


# ------------------------------------------------------------------ S9: conversions of R


@pytest.mark.typecheck_off
@pytest.mark.parametrize(
    "R", [np.diag([1.0, 1.0, -1.0]), 2.0 * np.eye(3), np.ones((3, 3))], ids=["refl", "2I", "ones"]
)
def test_quat_and_euler_need_a_rotation(R):
    pose = Pose(jnp.asarray(R), jnp.zeros(3))
    with pytest.raises(ValueError, match=_named("R")):
        _ = pose.quat
    with pytest.raises(ValueError, match=_named("R")):
        pose.euler()
    with pytest.raises(ValueError, match=_named("R")):
        Pose(R, np.zeros(3)).euler("ZXZ")


def test_quat_and_euler_good_nan_and_traced():
    pose = Pose.from_euler(jnp.array([0.1, 0.2, 0.3]), jnp.zeros(3))
    np.testing.assert_allclose(np.asarray(pose.euler()), [0.1, 0.2, 0.3], atol=1e-12)
    assert pose.quat.shape == (4,)
    batch = Pose(jnp.stack([pose.R, jnp.eye(3)]), jnp.zeros((2, 3)))
    assert batch.quat.shape == (2, 4)
    # a failed (NaN) estimate gives NaN, not an error
    assert np.all(np.isnan(np.asarray(Pose(jnp.full((3, 3), np.nan), jnp.zeros(3)).quat)))
    # a traced R is not looked at: the quaternion round trip to the nearest rotation still runs
    near = jax.jit(lambda p: Pose.from_quat(p.quat, p.t))(Pose(pose.R * 1.01, pose.t))
    assert bool(is_rotation(near.R))
    np.testing.assert_allclose(np.asarray(near.R), np.asarray(pose.R), atol=1e-2)


# ------------------------------------------------------------------ S8: blocks at a non-rotation

POSE = Pose.from_euler(jnp.array([0.1, 0.2, 0.3]), jnp.array([0.1, -0.1, 5.0]))
P = jnp.asarray(np.random.default_rng(0).uniform(-1.0, 1.0, (10, 3)))
U = CAM.project(POSE.apply(P))
SEG = jnp.stack([P[:4], P[4:8] + 0.1], axis=1)  # (4, 2, 3)
LINES = jax.vmap(line_from_segment)(
    CAM.project(POSE.apply(SEG[:, 0])), CAM.project(POSE.apply(SEG[:, 1]))
)
NOT_ROTATIONS = [2.0 * np.eye(3), np.diag([1.0, 1.0, -1.0]), np.asarray(POSE.R) + 1e-3]
NOT_ROTATION_IDS = ["2I", "reflection", "off-by-1e-3"]


@pytest.mark.parametrize("R", NOT_ROTATIONS, ids=NOT_ROTATION_IDS)
def test_blocks_and_covariance_need_a_rotation(R):
    bad = Pose(jnp.asarray(R), POSE.t)
    for call in (
        lambda: jp.information_blocks(P, bad, CAM),
        lambda: jp.line_information_blocks(SEG, bad, CAM),
        lambda: jp.pose_covariance(P, bad, CAM),
    ):
        with pytest.raises(ValueError, match=r"pose\.R must be a rotation"):
            call()


def test_blocks_at_traced_or_nan_poses_are_not_looked_at():
    bad = Pose(2.0 * POSE.R, POSE.t)
    # traced: computed as before (jit, vmap), so the batched selection paths keep working
    A = jax.jit(lambda p: jp.information_blocks(P, p, CAM))(bad)
    assert A.shape == (10, 6, 6) and np.all(np.isfinite(np.asarray(A)))
    poses = Pose(jnp.stack([POSE.R, 2.0 * POSE.R]), jnp.stack([POSE.t, POSE.t]))
    assert jax.vmap(lambda p: jp.information_blocks(P, p, CAM))(poses).shape == (2, 10, 6, 6)
    # a NaN pose is a failed estimate: NaN blocks, whose DOP says NONFINITE_INPUT
    nan = Pose(jnp.full((3, 3), jnp.nan), POSE.t)
    status = jp.dop_from_information(jp.information_blocks(P, nan, CAM).sum(0)).status
    assert int(status) == jp.Status.NONFINITE_INPUT
    assert int(jp.dop(P, bad, CAM, throw=False).status) == jp.Status.NOT_A_ROTATION
    cov = jp.pose_covariance(P, POSE, CAM, sigma=0.5)
    np.testing.assert_allclose(cov, jp.dop(P, POSE, CAM, sigma=0.5, parameterization="tangent").Q)


# ------------------------------------------------------------------ S19d: dop_from_information


def test_dop_from_information_refuses_an_asymmetric_A():
    A = np.asarray(jp.information_blocks(P, POSE, CAM).sum(0))
    for bad in (_with(A, (0, 1), A[0, 1] + 1.0), np.triu(A)):
        with pytest.raises(ValueError, match=_named("A")):
            jp.dop_from_information(bad)
    # rounding-level asymmetry passes; a traced A is not looked at (its lower triangle is used)
    assert (
        int(jp.dop_from_information(_with(A, (0, 1), A[0, 1] * (1 + 1e-12))).status) == jp.Status.OK
    )
    res = jax.jit(jp.dop_from_information)(jnp.asarray(np.tril(A)))
    assert int(res.status) == jp.Status.OK
    assert (
        int(jp.dop_from_information(_with(A, (2, 3), np.nan)).status) == jp.Status.NONFINITE_INPUT
    )


def test_summed_blocks_cannot_tell_points_behind_the_camera():
    # (U16) the blocks of points behind the camera hold no depth information: their sum is
    # SINGULAR; only jp.dop, which sees the points, can say BEHIND_CAMERA
    behind = Pose(POSE.R, POSE.t.at[2].set(-5.0))
    A = jp.information_blocks(P, behind, CAM).sum(0)
    assert int(jp.dop_from_information(A).status) == jp.Status.SINGULAR
    assert int(jp.dop(P, behind, CAM, throw=False).status) == jp.Status.BEHIND_CAMERA


# ------------------------------------------------------------------ S19c: zero-length segments


def test_line_blocks_refuse_a_zero_length_segment():
    zero = SEG.at[2, 1].set(SEG[2, 0])
    with pytest.raises(ValueError, match=r"segments_body\[2\] has zero length"):
        jp.line_information_blocks(zero, POSE, CAM)
    # masked out it is not used; traced it is not looked at (a zero block)
    off = np.array([True, True, False, True])
    A = jp.line_information_blocks(zero, POSE, CAM, mask=off)
    np.testing.assert_array_equal(np.asarray(A[2]), 0.0)
    A = jax.jit(lambda s: jp.line_information_blocks(s, POSE, CAM))(zero)
    np.testing.assert_array_equal(np.asarray(A[2]), 0.0)
    np.testing.assert_allclose(A[:2], jp.line_information_blocks(SEG[:2], POSE, CAM), atol=1e-9)


# ------------------------------------------------------------------ S19b, U16: line options


@pytest.mark.parametrize("name", ["line_mask", "line_sigma"])
def test_line_options_need_lines(name):
    value = {"line_mask": jnp.ones(4, bool), "line_sigma": 2.0}[name]
    with pytest.raises(ValueError, match=_named(name)):
        jp.refine_pose(P, U, POSE, CAM, **{name: value})
    with pytest.raises(ValueError, match=_named(name)):
        jp.sensitivity(P, U, POSE, CAM, **{name: value})
    with pytest.raises(ValueError, match=_named(name)):
        jp.pose_covariance(P, POSE, CAM, **{name: value})
    with pytest.raises(ValueError, match=_named("segments_body")):
        jp.pose_covariance(P, POSE, CAM, lines_img=LINES)


@pytest.mark.parametrize("name", ["line_mask", "line_information"])
def test_joint_cost_line_options_need_lines(name):
    value = {"line_mask": jnp.ones(4, bool), "line_information": jnp.tile(jnp.eye(2), (4, 1, 1))}
    with pytest.raises(ValueError, match=_named(name)):
        joint_cost(P, U, POSE, CAM, **{name: value[name]})
    # with the lines they are used: a line masked out changes the cost
    kw = dict(segments_body=SEG, lines_img=LINES + jnp.array([0.0, 0.0, 3.0]))
    full = joint_cost(P, U, POSE, CAM, **kw)
    part = joint_cost(P, U, POSE, CAM, line_mask=jnp.array([True, False, True, True]), **kw)
    assert float(full) > float(part) > 0.0


@pytest.mark.parametrize("line", [[0.0, 0.0, 0.0], [0.0, 0.0, 5.0]], ids=["zeros", "at-infinity"])
def test_a_line_without_direction_is_said_so(line):
    lines = LINES.at[1].set(jnp.asarray(line))
    kw = dict(segments_body=SEG, lines_img=lines)
    res = jp.refine_pose(P, U, POSE, CAM, throw=False, **kw)
    assert int(res.status) == jp.Status.DEGENERATE_LINE
    assert np.all(np.isfinite(np.asarray(res.pose.R)))
    with pytest.raises(ValueError, match=_named("lines_img")):
        jp.refine_pose(P, U, POSE, CAM, **kw)
    assert (
        int(jp.sensitivity(P, U, POSE, CAM, throw=False, **kw).status) == jp.Status.DEGENERATE_LINE
    )
    with pytest.raises(ValueError, match=r"lines_img\[1\]"):
        jp.pose_covariance(P, POSE, CAM, **kw)
    # masked out, the line is not used (nor a NaN one): the covariance of the other lines
    keep = np.array([True, False, True, True])
    assert int(jp.refine_pose(P, U, POSE, CAM, line_mask=keep, **kw).status) == jp.Status.OK
    cov = jp.pose_covariance(P, POSE, CAM, line_mask=keep, **kw)
    ref = jp.pose_covariance(P, POSE, CAM, segments_body=SEG[keep], lines_img=LINES[keep])
    np.testing.assert_allclose(cov, ref, rtol=1e-9)
    nan = lines.at[1].set(np.nan)
    nan = jp.pose_covariance(P, POSE, CAM, segments_body=SEG, lines_img=nan, line_mask=keep)
    np.testing.assert_allclose(nan, ref, rtol=1e-9)
    # traced: a status per lane under vmap, an inf covariance under jit
    lanes = jax.vmap(
        lambda l: jp.refine_pose(P, U, POSE, CAM, segments_body=SEG, lines_img=l, throw=False)
    )(jnp.stack([LINES, lines]))
    assert np.asarray(lanes.status).tolist() == [0, int(jp.Status.DEGENERATE_LINE)]
    cov = jax.jit(lambda l: jp.pose_covariance(P, POSE, CAM, segments_body=SEG, lines_img=l))
    assert np.all(np.isinf(np.asarray(cov(lines))))
    assert np.all(np.isfinite(np.asarray(cov(LINES))))


# ------------------------------------------------------------------ S15: option fields


@pytest.mark.typecheck_off
@pytest.mark.parametrize(
    "field, value",
    [
        ("rtol", "1e-3"),
        ("atol", "0"),
        ("robust_scale", "3"),
        ("max_steps", "10"),
        ("max_steps", True),
        ("rtol", False),
        ("robust_scale", np.bool_(True)),
        ("max_steps", np.inf),
    ],
    ids=repr,
)
def test_refine_options_numbers_are_numbers(field, value):
    with pytest.raises(ValueError, match=rf"RefineOptions\.{field}(?!\w)"):
        jp.RefineOptions(**{field: value})


@pytest.mark.typecheck_off
@pytest.mark.parametrize(
    "field, value",
    [
        ("threshold_px", "10"),
        ("confidence", "0.99"),
        ("max_outlier_fraction", "0.5"),
        ("threshold_px", True),
        ("max_outlier_fraction", False),
        ("sample_size", "6"),
        ("num_hypotheses", np.inf),
    ],
    ids=repr,
)
def test_ransac_options_numbers_are_numbers(field, value):
    with pytest.raises(ValueError, match=rf"RansacOptions\.{field}(?!\w)"):
        jp.RansacOptions(**{field: value})


@pytest.mark.typecheck_off
def test_options_good_numbers():
    opt = jp.RefineOptions(rtol=np.float64(1e-6), atol=0, max_steps=10.0, robust_scale=np.int64(2))
    assert (opt.rtol, opt.atol, opt.max_steps, opt.robust_scale) == (1e-6, 0.0, 10, 2.0)
    assert jp.RefineOptions(robust_scale=None).robust_scale is None
    opt = jp.RansacOptions(threshold_px=np.float32(3.0), confidence=0.99, sample_size=np.int64(6))
    assert (opt.threshold_px, opt.sample_size) == (3.0, 6)


# ------------------------------------------------------------------ S15, S19a: camera.json


@pytest.mark.parametrize(
    "data, field",
    [
        ({"cameraMatrix": [["1000", 0, 320], [0, 1000, 240], [0, 0, 1]]}, "cameraMatrix"),
        ({"cameraMatrix": [[1000, 0, 320], [0, 1000, 240], [0, 0, True]]}, "cameraMatrix"),
        ({"cameraMatrix": K.tolist(), "distCoeffs": ["0.1", 0, 0, 0, 0]}, "distCoeffs"),
        ({"fx": "1000", "fy": 1000, "cx": 320, "cy": 240}, "fx"),
        ({"cameraMatrix": K.tolist(), "Nu": "640"}, "Nu"),
        ({"cameraMatrix": K.tolist(), "Nv": 1e999}, "Nv"),  # Infinity in the file
    ],
    ids=["K-string", "K-bool", "dist-string", "fx-string", "Nu-string", "Nv-inf"],
)
def test_load_camera_numbers_are_numbers(tmp_path, data, field):
    path = tmp_path / "camera.json"
    path.write_text(json.dumps({"Nu": 640, "Nv": 480} | data))
    with pytest.raises(ValueError, match=_named(field)):
        load_camera(path)


@pytest.mark.parametrize(
    "cx, cy, name",
    [(-1.0, 240.0, "cx"), (641.0, 240.0, "cx"), (320.0, 480.5, "cy"), (320.0, -0.1, "cy")]
    + [(240.0, 640.0, "cy")],
    ids=["cx-negative", "cx-beyond", "cy-beyond", "cy-negative", "transposed"],
)
def test_load_camera_principal_point_in_the_image(tmp_path, cx, cy, name):
    path = _camera_file(tmp_path, [[1000, 0, cx], [0, 1000, cy], [0, 0, 1]])
    with pytest.raises(ValueError, match=_named(name)):
        load_camera(path)
    path.write_text(json.dumps({"fx": 1e3, "fy": 1e3, "cx": cx, "cy": cy, "Nu": 640, "Nv": 480}))
    with pytest.raises(ValueError, match=_named(name)):
        load_camera(path)


def test_load_camera_principal_point_edges_and_unknown_size(tmp_path):
    for cx, cy in [(0.0, 0.0), (640.0, 480.0), (319.5, 239.5)]:
        cam = load_camera(_camera_file(tmp_path, [[1e3, 0, cx], [0, 1e3, cy], [0, 0, 1]]))
        assert (float(cam.cx), float(cam.cy)) == (cx, cy)
    path = tmp_path / "camera.json"
    path.write_text(json.dumps({"cameraMatrix": [[1e3, 0, 2000], [0, 1e3, -5], [0, 0, 1]]}))
    assert float(load_camera(path).cx) == 2000.0  # no image size: nothing to compare with
    # a camera of a crop may have its principal point outside the crop: PinholeCamera takes it
    assert PinholeCamera(1e3, 1e3, -40.0, 700.0, width=64, height=48).width == 64


# ------------------------------------------------------------------ from_focal_length


@pytest.mark.typecheck_off
@pytest.mark.parametrize(
    "args, name",
    [
        (("0.05", 1e-5), "focal_length_m"),
        ((True, 1e-5), "focal_length_m"),
        ((np.array([0.05, 0.06]), 1e-5), "focal_length_m"),
        ((0.05, "1e-5"), "pixel_size_m"),
        ((0.05, ("1e-5", 1e-5)), "pixel_size_m"),
        ((0.05, (1e-5, 1e-5, 1e-5)), "pixel_size_m"),
    ],
    ids=["str", "bool", "array", "pixel-str", "pixel-pair-str", "pixel-triple"],
)
def test_from_focal_length_numbers(args, name):
    with pytest.raises(ValueError, match=_named(name)):
        PinholeCamera.from_focal_length(*args, (640, 480))
    with pytest.raises(ValueError, match=_named("focal_length_m")):
        PinholeCamera.from_focal_length(-0.05, 1e-5, (640, 480))
    cam = PinholeCamera.from_focal_length(np.float64(0.05), (1e-5, 2e-5), (640, 480))
    assert (float(cam.fx), float(cam.fy)) == pytest.approx((5000.0, 2500.0))
