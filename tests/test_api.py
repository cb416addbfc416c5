"""The public face of the core: top-level names, option objects, statuses with exact messages,
``throw=True`` by default on every eager entry point, and bad input that names the argument."""

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jaxpose as jp
from jaxpose import (
    PinholeCamera,
    PnPOptions,
    Pose,
    RansacOptions,
    RefineOptions,
    Status,
)

CAM = PinholeCamera.from_K([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])


def scene(rng, n=10):
    points = rng.uniform(-0.5, 0.5, (n, 3))
    pose = Pose.from_euler(np.array([0.1, 0.2, 0.3]), np.array([0.1, -0.1, 5.0]))
    pixels = np.asarray(CAM.project(pose.apply(jnp.asarray(points))))
    return points, pixels, pose


# ----------------------------------------------------------------------------- the front door


def test_top_level_names_and_no_shadowing():
    for name in (
        "dop",
        "information_blocks",
        "select_features",
        "solve_pnp",
        "refine_pose",
        "RefineOptions",
        "PnPOptions",
        "initialise_pose",
        "InitResult",
        "StereoTracker",
        "StereoCamera",
        "load_camera",
        "Pose",
        "PinholeCamera",
        "Status",
    ):
        assert hasattr(jp, name), name
        assert name in dir(jp) and name in jp.__all__
    assert callable(jp.dop)
    from jaxpose.core import dilution

    assert dilution.information_blocks is jp.information_blocks  # the module is reachable
    assert isinstance(jp.__version__, str) and jp.__version__
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        jp.nothing  # noqa: B018
    # no function shadows its module in the core's packages
    import jaxpose.core.pnp as pnp
    import jaxpose.core.refine as refine
    import jaxpose.core.select as select

    for package in (pnp, refine, select):
        for name, value in vars(package).items():
            if callable(value) and not isinstance(value, type):
                assert f"{package.__name__}.{name}" not in sys.modules, name


def test_import_is_lazy_about_pipelines():
    code = (
        "import sys, jaxpose; "
        "heavy = [m for m in ('jaxpose.pipelines.monocular', 'jaxpose.pipelines.stereo', "
        "'jaxpose.io', 'cv2') if m in sys.modules]; print(heavy)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


# ----------------------------------------------------------------------------- options


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_option_objects_validate_and_are_hashable():
    assert hash(RefineOptions()) == hash(RefineOptions())
    assert hash(PnPOptions()) == hash(PnPOptions())
    bad = [
        (lambda: RefineOptions(method="dogleg"), "RefineOptions.method"),
        (lambda: RefineOptions(robust="l1"), "RefineOptions.robust"),
        (lambda: RefineOptions(max_steps=0), "max_steps"),
        (lambda: RefineOptions(max_steps=2.5), "max_steps"),
        (lambda: RefineOptions(rtol=-1.0), "rtol"),
        (lambda: RefineOptions(robust_scale=0.0), "robust_scale"),
        (lambda: RefineOptions(sequence="xxy"), "Euler sequence"),
        (lambda: RefineOptions(backend="scipy"), "backend"),
        (lambda: RansacOptions(threshold_px=0), "threshold_px"),
        (lambda: RansacOptions(confidence=1.0), "confidence"),
        (lambda: RansacOptions(max_outlier_fraction=1.0), "max_outlier_fraction"),
        (lambda: RansacOptions(sample_size=3), "sample_size"),
        (lambda: RansacOptions(num_hypotheses=0), "num_hypotheses"),
        (lambda: PnPOptions(method="p3p"), "PnPOptions.method"),
        (lambda: PnPOptions(refine="lm"), "PnPOptions.refine"),
        (lambda: PnPOptions(chunk=0), "chunk"),
        (lambda: PnPOptions(workers=-1), "workers"),
        (lambda: PnPOptions(planar_tol=2.0), "planar_tol"),
    ]
    for make, word in bad:
        with pytest.raises(ValueError, match=word):
            make()
    assert RansacOptions().hypotheses == 439  # Sharma et al. 2018 eq. 35, 50 % outliers
    assert PnPOptions(method="dlt").min_points == 6


# ----------------------------------------------------------------------------- statuses


def test_status_members_carry_exact_messages(rng):
    assert Status.TOO_FEW_POINTS.describe(3) == "too few valid points (at least 3 are needed)"
    assert "ok" == Status.OK.message
    points, pixels, pose = scene(rng)  # the shape of the other tests: their compiled solvers
    few = np.zeros(len(points), bool)
    few[:2] = True
    calls = {
        "at least 3": lambda: jp.refine_pose(points, pixels, pose, CAM, mask=few),
        "at least 4": lambda: jp.epnp(points, pixels, CAM, mask=few),
        "at least 6": lambda: jp.dlt(points, pixels, CAM, mask=few),
    }
    for want, call in calls.items():
        with pytest.raises(ValueError, match=want):
            call()
    with pytest.raises(ValueError, match="at least 4"):
        jp.dop(points, pose, CAM, mask=few)
    with pytest.raises(ValueError, match="ransac_pnp: .*at least 6"):
        jp.ransac_pnp(points, pixels, CAM, key=jax.random.key(0), mask=few)


def test_throw_defaults_to_true_and_false_keeps_batches_alive(rng):
    points, pixels, pose = scene(rng)
    line = np.stack([np.linspace(-1, 1, 10), np.zeros(10), np.zeros(10)], -1)
    line_pix = np.asarray(CAM.project(pose.apply(jnp.asarray(line))))
    for solver in (jp.epnp, jp.dlt):
        with pytest.raises(ValueError, match="degenerate"):
            solver(line, line_pix, CAM)
        # jit: one compilation of the batch instead of op-by-op batching (a third of the time)
        batch = jax.jit(jax.vmap(lambda p, u, f=solver: f(p, u, CAM, throw=False)))(
            jnp.stack([points, line]), jnp.stack([pixels, line_pix])
        )
        assert int(batch.status[0]) == Status.OK and int(batch.status[1]) == Status.DEGENERATE
        assert np.isinf(float(batch.reprojection_error[1]))
    with pytest.raises(ValueError, match="refine_pose"):
        jp.refine_pose(points, pixels, pose, CAM, mask=np.zeros(10, bool))


def test_pnp_result_rvec_matches_opencv(rng):
    cv2 = pytest.importorskip("cv2")
    points, pixels, pose = scene(rng)
    res = jp.solve_pnp(points, pixels, CAM)
    rvec, _ = cv2.Rodrigues(np.asarray(res.R))
    np.testing.assert_allclose(res.rvec, rvec.ravel(), atol=1e-12)
    np.testing.assert_allclose(res.rvec, Rotation.from_matrix(pose.R).as_rotvec(), atol=1e-6)


# ----------------------------------------------------------------------------- bad input


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_dop_bad_values_name_the_argument(rng):
    points, _, pose = scene(rng)
    with pytest.raises(ValueError, match="sigma"):
        jp.dop(points, pose, CAM, sigma=-1.0)
    with pytest.raises(ValueError, match="sigma"):
        jp.dop(points, pose, CAM, sigma=np.ones(3))
    with pytest.raises(ValueError, match="sigma"):
        jp.information_blocks(points, pose, CAM, sigma=np.r_[np.ones(9), -1.0])
    with pytest.raises(ValueError, match="sigma"):
        jp.refine_pose(points, np.zeros((10, 2)), pose, CAM, sigma=0.0)
    with pytest.raises(ValueError, match=r"mask must have shape \(10,\)"):
        jp.dop(points, pose, CAM, mask=np.ones(7, bool))
    with pytest.raises(ValueError, match="parameterization"):
        jp.dop(points, pose, CAM, parameterization="quaternion")
    not_rotation = Pose(2.0 * jnp.eye(3), pose.t)
    with pytest.raises(ValueError, match="not a rotation"):
        jp.dop(points, not_rotation, CAM)
    res = jp.dop(points, not_rotation, CAM, throw=False)
    assert int(res.status) == Status.NOT_A_ROTATION and np.isinf(float(res.pdop))


def test_sensitivity_of_collinear_points_is_a_status(rng):
    line = np.stack([np.linspace(-1, 1, 10), 0.1 * np.linspace(-1, 1, 10), np.zeros(10)], -1)
    pose = Pose.from_euler(np.array([0.1, 0.2, 0.3]), np.array([0.1, -0.1, 5.0]))
    pix = np.asarray(CAM.project(pose.apply(jnp.asarray(line))))
    with pytest.raises(ValueError, match="singular"):
        jp.sensitivity(line, pix, pose, CAM)
    sens = jp.sensitivity(line, pix, pose, CAM, throw=False)
    assert int(sens.status) == Status.SINGULAR
    assert not np.any(np.isnan(np.asarray(sens.d_pixels)))
    points, pixels, pose = scene(rng)
    ok = jp.sensitivity(points, pixels, pose, CAM)
    assert int(ok.status) == Status.OK and np.all(np.isfinite(np.asarray(ok.d_pixels)))


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_bad_values_of_the_audit_give_errors_or_statuses(rng):
    """Issue-14 classes on the core entry points: each is an error naming the argument, a status,
    or a NaN-free answer."""
    with pytest.raises(ValueError, match="fx .* must be positive"):
        PinholeCamera(-1000.0, -1000.0, 320.0, 240.0)
    with pytest.raises(ValueError, match="non-zero quaternion"):
        Pose.from_quat(np.zeros(4), np.array([0.0, 0.0, 5.0]))
    points, pixels, pose = scene(rng)
    blocks = jp.information_blocks(points, pose, CAM)
    with pytest.raises(ValueError, match="m must be a Python int"):
        jp.select.branch_and_bound(blocks, 4.7)
    with pytest.raises(ValueError, match=r"idx must hold indices in \[0, 10\)"):
        jp.select.subset_dop(blocks, jnp.array([0, 1, 2, 99]))
    traced = jax.jit(jp.select.subset_dop)(blocks, jnp.array([0, 1, 2, 99]))
    assert np.all(np.isinf(np.asarray(traced)))
    line = np.stack([np.linspace(-1, 1, 10), np.linspace(-0.5, 0.5, 10), np.zeros(10)], -1)
    with pytest.raises(ValueError, match="singular"):
        jp.select_features(line, pose, CAM, 5, method="greedy")
    not_rotation = Pose(2.0 * jnp.eye(3), pose.t)
    res = jp.refine_pose(points, pixels, not_rotation, CAM, throw=False)
    assert int(res.status) == Status.NOT_A_ROTATION
    with pytest.raises(ValueError, match="not a rotation"):
        jp.refine_pose(points, pixels, not_rotation, CAM)


def test_gradients_are_nan_free_at_singular_points(rng):
    points, _, pose = scene(rng)
    gimbal = jnp.asarray(jp.geometry.euler_to_dcm(jnp.array([0.3, jnp.pi / 2, 0.2])))
    for parameterization in ("euler", "tangent"):
        g = jax.jit(
            jax.grad(
                lambda R, p=parameterization: (
                    jp.dop(points, Pose(R, pose.t), CAM, parameterization=p, throw=False).pdop
                )
            )
        )(gimbal)
        assert np.all(np.isfinite(np.asarray(g))), parameterization
    g = jax.jit(jax.grad(lambda R: jp.geometry.dcm_to_euler(R).sum()))(gimbal)
    assert np.all(np.isfinite(np.asarray(g)))
    # the gradient of solve_pnp at collinear, coincident and NaN input: the "pnp-grad-degenerate"
    # rows of test_bad_inputs.py
