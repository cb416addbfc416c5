"""The LINE-2D template search over the attitude grid (pipelines.monocular.templates): its
similarity against a NumPy brute force over every shift and scale, and the pose it moves to."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose.core.geometry import euler_to_dcm
from jaxpose.pipelines.monocular import templates as T
from jaxpose.pipelines.monocular.scene import _model_geometry
from jaxpose.vision.models import tango

CAM4 = np.array([1000.0, 1000.0, 320.0, 240.0])
FRAME = np.array([224.0, 144.0, 0.5])  # cell = (pixel - [224, 144]) * 0.5


def _features(R, t, model, B):
    """NumPy: the template's features ``[(bin, cell offset from the centre's cell)]`` and the
    centre's cell: at most ``TEMPLATE_FEATURES`` of the visible edges' samples (an edge of a
    face whose outward normal faces the camera, or an antenna) with the quantised orientation
    of its projected normal."""
    segs = np.concatenate([model.edge_points, model.antenna_points])
    faces = list(model.edge_faces) + [()] * len(model.antennas)
    normals, centres = np.asarray(model.face_normals), np.asarray(model.face_centres)
    front = [(R @ n) @ (R @ c + t) < 0 for n, c in zip(normals, centres, strict=True)]

    def px(p):
        q = p @ R.T + t
        return np.stack(
            [CAM4[0] * q[..., 0] / q[..., 2] + CAM4[2], CAM4[1] * q[..., 1] / q[..., 2] + CAM4[3]],
            -1,
        )

    all8 = segs[:, :1] + np.linspace(0, 1, 8)[None, :, None] * (segs[:, 1:] - segs[:, :1])
    cc = (px(all8.reshape(-1, 3).mean(0)) - FRAME[:2]) * FRAME[2]
    feats = []
    for e in range(len(segs)):
        if faces[e] and not any(front[f] for f in faces[e]):
            continue
        a, b = px(segs[e, 0]), px(segs[e, 1])
        phi = np.mod(np.arctan2(b[1] - a[1], b[0] - a[0]) + np.pi / 2, np.pi)
        o = int(np.mod(np.round(phi / (np.pi / B)), B))
        for i, s in enumerate(np.linspace(0.0, 1.0, 8)[:: T.TEMPLATE_SAMPLE_STEP]):
            p = segs[e, 0] + s * (segs[e, 1] - segs[e, 0])
            feats.append(((i, e), o, (px(p) - FRAME[:2]) * FRAME[2] - cc))
    # the first TEMPLATE_FEATURES: every edge's first sample, then every edge's second, ...
    feats = sorted(feats, key=lambda f: f[0])[: T.TEMPLATE_FEATURES]
    return [f[1:] for f in feats], cc


def _cell(cc, rel, k, d, M):
    q = cc + k * rel + d
    if np.all(q >= 0) and np.all(q <= M - 1):
        return tuple(int(np.round(x)) for x in q)
    return None


def _reference(R, t, model, ori, shifts, scales):
    """NumPy brute force of eq. (2) of Hinterstoisser et al. (2012) over every shift and scale
    (nearest cell, 0 off the maps)."""
    feats, cc = _features(R, t, model, ori.shape[0])
    out = np.zeros((len(scales), len(shifts)))
    for i, k in enumerate(scales):
        for j, d in enumerate(shifts):
            cells = [(o, _cell(cc, rel, k, d, ori.shape[1])) for o, rel in feats]
            out[i, j] = sum(ori[o, c[1], c[0]] for o, c in cells if c is not None) / len(feats)
    return out


def _match(R, t, model, ori, shifts, scales):
    return jax.jit(T._template_match)(
        jnp.asarray(R),
        jnp.asarray(t),
        _model_geometry(model),
        jnp.asarray(ori),
        jnp.asarray(FRAME),
        jnp.asarray(CAM4),
        jnp.asarray(shifts),
        jnp.asarray(scales),
    )


@pytest.fixture(scope="module")
def case():
    model = tango()
    rng = np.random.default_rng(5)
    ori = rng.random((8, 96, 96)).astype(np.float32)
    R = np.asarray(euler_to_dcm(jnp.asarray([0.4, -0.3, 0.9])), float)
    t = np.array([0.05, -0.03, 18.0])
    shifts = T.template_shifts(40.0)[::4]  # 13 of the 49 (the brute force is slow)
    scales = np.array(T.TEMPLATE_SCALES)
    return model, ori, R, t, shifts, scales


def test_template_match_against_brute_force(case):
    model, ori, R, t, shifts, scales = case
    ref = _reference(R, t, model, ori, shifts, scales)
    s, k, d = _match(R, t, model, ori, shifts, scales)
    i, j = np.unravel_index(np.argmax(ref), ref.shape)
    assert float(s) == pytest.approx(ref.max(), abs=1e-5)
    assert float(k) == pytest.approx(scales[i])
    np.testing.assert_allclose(np.asarray(d), shifts[j] / FRAME[2], atol=1e-9)


def test_template_finds_planted_shift(case):
    """Maps lit (1) only at the template's own features placed at a known shift and scale, in
    each feature's orientation bin: the search returns that shift and scale, similarity 1."""
    model, _, R, t, shifts, scales = case
    ori = np.zeros((8, 96, 96), np.float32)
    j_true, k_true = 9, scales[2]
    feats, cc = _features(R, t, model, 8)
    for o, rel in feats:
        c = _cell(cc, rel, k_true, shifts[j_true], 96)
        assert c is not None
        ori[o, c[1], c[0]] = 1.0
    s, k, d = _match(R, t, model, ori, shifts, scales)
    assert float(s) == pytest.approx(1.0)
    assert float(k) == pytest.approx(k_true)
    np.testing.assert_allclose(np.asarray(d), shifts[j_true] / FRAME[2], atol=1e-9)
    assert _reference(R, t, model, ori, shifts, scales).max() == pytest.approx(1.0)


def test_moved_pose_projects_where_asked():
    """The moved pose's projected centre lies at the shift, and its range is divided by the
    scale (closed form of the pinhole projection)."""
    R = np.asarray(euler_to_dcm(jnp.asarray([0.1, 0.2, -0.3])), float)[None]
    t = np.array([[0.3, -0.2, 7.0]])
    centre = np.array([0.0, 0.0, 0.16])
    shift, scale = np.array([[12.0, -7.5]]), np.array([1.15])
    t2 = T._moved(R, t, scale, shift, centre, CAM4)
    c1, c2 = R[0] @ centre + t[0], R[0] @ centre + t2[0]
    p1 = CAM4[:2] * c1[:2] / c1[2] + CAM4[2:]
    p2 = CAM4[:2] * c2[:2] / c2[2] + CAM4[2:]
    np.testing.assert_allclose(p2 - p1, shift[0], atol=1e-9)
    assert c2[2] == pytest.approx(c1[2] / 1.15)


def test_template_poses_find_the_rendered_attitude():
    """A rendering at one of 64 grid attitudes, every attitude placed 4% of the range off
    sideways and 8% too far: the best template is the rendered attitude, moved back to within
    two strides of the true centre's pixel and 10% of its range."""
    from types import SimpleNamespace

    from jaxpose import PinholeCamera, Pose
    from jaxpose.pipelines.monocular.hypothesise import _attitudes
    from jaxpose.vision.render import render

    model = tango()
    camera = PinholeCamera(747.0, 747.0, 239.5, 149.5, width=480, height=300)
    R = _attitudes(64)
    k = 23
    t_true = np.array([0.1, -0.05, 5.0])
    r = render(model, Pose(R[k], t_true), camera, rng=3)
    geom = _model_geometry(model)
    centre = np.asarray(geom[1]).reshape(-1, 3).mean(0)
    c_true = R[k] @ centre + t_true
    c_off = c_true * 1.08 + np.array([0.04 * c_true[2], 0.0, 0.0])
    t0 = c_off[None] - R @ centre
    cam4 = jnp.asarray([747.0, 747.0, 239.5, 149.5])
    sc = SimpleNamespace(geom=geom, cam4=cam4)
    det = SimpleNamespace(image=r.image, roi=np.asarray(r.roi, float))
    Rb, tb, sim = T._template_poses(R, t0, sc, det, 3, chunk=64)
    assert np.allclose(Rb[0], R[k])
    assert sim[0] > sim[1]
    c = Rb[0] @ centre + tb[0]
    px = 747.0 * c[:2] / c[2]
    px_true = 747.0 * c_true[:2] / c_true[2]
    l_roi = np.hypot(r.roi[2] - r.roi[0], r.roi[3] - r.roi[1])
    assert np.linalg.norm(px - px_true) < 2 * T.TEMPLATE_STRIDE * l_roi
    assert abs(c[2] / c_true[2] - 1.0) < 0.1


@pytest.mark.parametrize("bad", [-1, 129, True])
def test_template_slots_checked(bad):
    from jaxpose import PinholeCamera
    from jaxpose.pipelines.monocular import InitOptions, initialise_pose

    camera = PinholeCamera(747.0, 747.0, 239.5, 149.5, width=480, height=300)
    with pytest.raises(ValueError, match="template_slots"):
        initialise_pose(np.zeros((300, 480)), camera, options=InitOptions(template_slots=bad))
