"""Property tests of the bad-input contract (``docs/errors.md``) at the core entry points.

Hypothesis throws random shapes and values (NaN, inf, huge, tiny, zero, degenerate sets) at
``dop``, ``information_blocks``, ``select_features``, ``solve_pnp``, ``refine_pose``,
``sensitivity``, the ``Pose`` constructors, ``PinholeCamera.project`` and
``StereoCamera.triangulate``. Each answer must be, within the deadline, either a ``ValueError``
that names the argument, or a result with a status and no NaN (and finite figures where the status
says ``OK``). The set sizes are few so that each function compiles once or twice.
"""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxpose as jp
from jaxpose import PinholeCamera, Pose, Status, StereoCamera
from jaxpose.core._checks import is_rotation

N = 8
CAM = PinholeCamera(1000.0, 1000.0, 320.0, 240.0)
POSE = Pose.from_euler(jnp.array([0.1, 0.2, 0.3]), jnp.array([0.1, -0.1, 5.0]))
BASE = np.random.default_rng(0).uniform(-1.0, 1.0, (N, 3))
PIX = np.asarray(CAM.project(POSE.apply(jnp.asarray(BASE))))
RIG = StereoCamera.from_baseline(CAM, 0.3)
PL, PR = (np.asarray(x) for x in RIG.project(POSE.apply(jnp.asarray(BASE))))

SPECIAL = [np.nan, np.inf, -np.inf, 1e300, -1e300, 1e-300, 0.0, 5e-324]
# Bad shapes and values meet the package's own checks: jaxtyping's hook, on while testing, would
# meet a badly shaped argument with its own TypeCheckError first (see pyproject.toml).
pytestmark = pytest.mark.typecheck_off

PROPS = settings(
    max_examples=12,
    deadline=10_000,  # ms per example, after the warm-up compiled each function once
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


def _named(message: str, names) -> bool:
    return any(re.search(rf"(?<!\w){re.escape(n)}(?!\w)", message) for n in names)


def _no_nan(tree) -> list[str]:
    bad = []
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        a = np.asarray(leaf)
        if np.issubdtype(a.dtype, np.floating) and np.isnan(a).any():
            bad.append(jax.tree_util.keystr(path))
    return bad


@st.composite
def corrupted(draw, base: np.ndarray, max_bad: int = 3, degenerate: bool = True):
    """``base`` with a few entries replaced by special values, or collapsed to a degenerate set."""
    a = np.array(base, dtype=float)
    kind = draw(
        st.sampled_from(
            ["entries", "collinear", "coincident", "scaled"]
            if degenerate
            else ["entries", "scaled"]
        )
    )
    if kind == "collinear":
        s = np.linspace(-1, 1, a.shape[0])[:, None]
        a = s * a[:1] + (1 - s) * a[1:2]
    elif kind == "coincident":
        a = np.repeat(a[:1], a.shape[0], axis=0)
    elif kind == "scaled":
        a = a * draw(st.sampled_from([1e-300, 1e-12, 1e12, 1e300]))
    k = draw(st.integers(0 if kind != "entries" else 1, max_bad))
    for _ in range(k):
        i = draw(st.integers(0, a.size - 1))
        a.flat[i] = draw(st.sampled_from(SPECIAL))
    return a


@st.composite
def shaped(draw, base: np.ndarray):
    """Either a corrupted ``base`` or an array of a wrong shape."""
    if draw(st.booleans()):
        return draw(corrupted(base))
    n = draw(st.sampled_from([0, 1, N]))
    tail = draw(st.sampled_from([(), (1,), (2,), (4,), (3, 1)]))
    extra = draw(st.sampled_from([(), (2,)]))
    shape = extra + (n,) + tail
    if shape[-len(base.shape) :] == base.shape and len(shape) == len(base.shape):
        shape = (n, 5)
    return np.full(shape, 0.5)


def _contract(call, names, *, ok_fields=()):
    """Run ``call``: a ``ValueError`` naming one of ``names``, or a result with a status and no
    NaN, finite ``ok_fields`` where the status is ``OK``."""
    try:
        res = call()
    except ValueError as err:
        assert _named(str(err), names), f"no argument of {names} named in: {err}"
        return None
    status = np.asarray(res.status)
    assert set(np.unique(status).tolist()) <= {int(s) for s in Status}, status
    assert not _no_nan(res), f"NaN in {_no_nan(res)} (status {status})"
    if np.all(status == Status.OK):
        for name in ok_fields:
            value = res
            for part in name.split("."):
                value = getattr(value, part)
            assert np.all(np.isfinite(np.asarray(value))), (name, value)
    return res


POINT_NAMES = ("points_body", "pixels", "mask", "sigma", "pose", "camera")


@pytest.fixture(scope="module", autouse=True)
def warm_up():
    """Compile each entry point once on good data, so that the deadline times answers only."""
    P, U = jnp.asarray(BASE), jnp.asarray(PIX)
    jp.dop(P, POSE, CAM, throw=False)
    for sigma in (None, 1.0):
        jp.information_blocks(P, POSE, CAM, sigma=sigma)
    for method in ("quasi", "greedy"):
        jp.select_features(P, POSE, CAM, 5, method=method)
    jp.solve_pnp(P, U, CAM, throw=False)
    jp.refine_pose(P, U, POSE, CAM, throw=False)
    jp.sensitivity(P, U, POSE, CAM, throw=False)
    for method in ("linear", "midpoint"):
        RIG.triangulate(jnp.asarray(PL), jnp.asarray(PR), method=method)


@PROPS
@given(points=shaped(BASE))
def test_dop(points):
    _contract(
        lambda: jp.dop(points, POSE, CAM, throw=False), POINT_NAMES, ok_fields=("pdop", "adop", "Q")
    )


@PROPS
@given(
    points=shaped(BASE), sigma=st.sampled_from([None, 1.0, 2.5, -1.0, 0.0, np.nan, np.inf, 1e-300])
)
def test_information_blocks(points, sigma):
    try:
        blocks = jp.information_blocks(points, POSE, CAM, sigma=sigma)
    except ValueError as err:
        assert _named(str(err), POINT_NAMES), err
        return
    assert blocks.shape == (N, 6, 6)
    if np.all(np.isfinite(points)) and np.all(np.abs(points) < 1e6):
        z = np.asarray(POSE.apply(jnp.asarray(points)))[:, 2]
        if np.all(z > 0):
            assert np.all(np.isfinite(np.asarray(blocks))), blocks
    # the DOP of the blocks never says OK with a non-finite figure
    res = jp.dop_from_information(
        jnp.sum(jnp.nan_to_num(blocks, nan=0.0, posinf=0.0, neginf=0.0), 0)
    )
    assert not _no_nan(res)


@PROPS
@given(
    points=shaped(BASE),
    m=st.sampled_from([5, 5, 3, 9, 4.5]),
    method=st.sampled_from(["quasi", "greedy"]),
)
def test_select_features(points, m, method):
    try:
        idx = jp.select_features(points, POSE, CAM, m, method=method)
    except ValueError as err:
        assert _named(str(err), (*POINT_NAMES, "m")) or "singular" in str(err), err
        return
    idx = np.asarray(idx)
    assert idx.shape == (m,) and np.all(np.diff(idx) > 0) and idx.min() >= 0 and idx.max() < N


@PROPS
@given(points=shaped(BASE), pixels=shaped(PIX))
def test_solve_pnp(points, pixels):
    res = _contract(
        lambda: jp.solve_pnp(points, pixels, CAM, throw=False),
        ("points_body", "pixels", "mask"),
        ok_fields=("pose.R", "pose.t", "reprojection_error"),
    )
    if res is not None and int(res.status) == Status.OK:
        assert bool(is_rotation(res.pose.R))


@PROPS
@given(points=corrupted(BASE), pixels=corrupted(PIX, degenerate=False))
def test_refine_pose(points, pixels):
    res = _contract(
        lambda: jp.refine_pose(points, pixels, POSE, CAM, throw=False),
        POINT_NAMES,
        ok_fields=("pose.R", "pose.t", "rms_px"),
    )
    if res is not None and int(res.status) == Status.OK:
        assert bool(is_rotation(res.pose.R))


@PROPS
@given(points=corrupted(BASE), pixels=corrupted(PIX, degenerate=False))
def test_sensitivity(points, pixels):
    _contract(
        lambda: jp.sensitivity(points, pixels, POSE, CAM, throw=False),
        POINT_NAMES,
        ok_fields=("d_pixels", "d_points_body", "d_intrinsics"),
    )


FLOATS = st.one_of(st.floats(-4.0, 4.0), st.sampled_from(SPECIAL))


@PROPS
@given(q=st.lists(FLOATS, min_size=3, max_size=5), t=st.lists(FLOATS, min_size=3, max_size=3))
def test_pose_from_quat(q, t):
    q = np.asarray(q)
    try:
        pose = Pose.from_quat(jnp.asarray(q), jnp.asarray(t))
    except ValueError as err:
        assert _named(str(err), ("q", "t")), err
        return
    assert q.shape == (4,)
    if np.all(np.isfinite(q)) and np.any(q != 0):
        assert bool(is_rotation(pose.R)), (q, pose.R)


@PROPS
@given(v=st.lists(FLOATS, min_size=3, max_size=3), kind=st.sampled_from(["euler", "rotvec"]))
def test_pose_from_angles(v, kind):
    v = jnp.asarray(v)
    pose = (
        Pose.from_euler(v, jnp.zeros(3)) if kind == "euler" else Pose.from_rotvec(v, jnp.zeros(3))
    )
    if np.all(np.isfinite(np.asarray(v))) and np.all(np.abs(np.asarray(v)) < 1e15):
        assert bool(is_rotation(pose.R)), (v, pose.R)


@PROPS
@given(points=corrupted(np.asarray(POSE.apply(jnp.asarray(BASE))), degenerate=False))
def test_project(points):
    pixels = np.asarray(CAM.project(jnp.asarray(points)))
    assert pixels.shape == (N, 2)
    rows = (
        np.all(np.isfinite(points), axis=1)
        & (points[:, 2] > 1e-6)
        & np.all(np.abs(points) < 1e100, 1)
    )
    assert not np.isnan(pixels[rows]).any(), (points[rows], pixels[rows])


@PROPS
@given(
    left=corrupted(PL, degenerate=False),
    right=corrupted(PR, degenerate=False),
    method=st.sampled_from(["linear", "midpoint"]),
)
def test_triangulate(left, right, method):
    points = np.asarray(RIG.triangulate(jnp.asarray(left), jnp.asarray(right), method=method))
    assert points.shape == (N, 3)
    assert not np.isnan(points).any(), points


@pytest.mark.parametrize("shape", [(N, 3), (N, 2, 1), (2, N), (N + 1, 2)])
def test_triangulate_shapes(shape):
    with pytest.raises(ValueError, match="pixels_left"):
        RIG.triangulate(jnp.ones(shape), jnp.ones((N, 2)))
