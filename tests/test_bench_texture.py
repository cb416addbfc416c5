"""The texture score of ``bench/monocular_texture.py``: its visibility against a closed form (seen
from straight below, the body hides the part of the panel's underside over its footprint), its
per-face ZNCC against NumPy's correlation coefficients, and a texture read at one pose scoring 1
there and less at a pose turned away."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from bench_module import load_bench

from jaxpose.vision.models import tango

jax.config.update("jax_enable_x64", True)

bench = load_bench("monocular_texture")

K = jnp.asarray([[1500.0, 0, 400.0], [0, 1500.0, 300.0], [0, 0, 1]])


def _geometry():
    pts, fid, normals, quads = bench.face_samples(tango(), 0.04)
    return pts, fid, normals, quads, tuple(jnp.asarray(x) for x in (pts, fid, normals, quads))


def test_the_body_hides_the_panel_underside_over_its_footprint():
    pts, fid, normals, _, geo = _geometry()
    depth = 6.0  # camera at (0, 0, -6) of the body frame, looking along the body's +z
    R, t = np.eye(3), np.array([0.0, 0.0, depth])
    _, use = bench._samples(jnp.asarray(R), jnp.asarray(t), jnp.zeros((600, 800)), K, *geo)
    use = np.asarray(use)
    down = [k for k, n in enumerate(normals) if n[2] < -0.9]
    panel = next(k for k in down if pts[fid == k][0, 2] > 0.2)  # the underside, z = 0.30
    body = next(k for k in down if abs(pts[fid == k][0, 2]) < 1e-6)  # the body's bottom, z = 0
    p = pts[fid == panel]
    # the ray to (x, y, z) crosses the body's bottom (z = 0) at (x, y) depth / (depth + z):
    # hidden when that point lies in the body's footprint (-0.37..0.37 by -0.264..0.304)
    s = depth / (depth + p[0, 2])
    hidden = (np.abs(s * p[:, 0]) < 0.37) & (s * p[:, 1] > -0.264) & (s * p[:, 1] < 0.304)
    assert hidden.any() and (~hidden).any()
    np.testing.assert_array_equal(use[fid == panel], ~hidden)
    assert use[fid == body].all()  # nothing hides the body's bottom
    sides = [k for k, n in enumerate(normals) if abs(n[2]) < 0.1]
    assert not use[np.isin(fid, sides)].any()  # edge-on faces are not sampled


def test_zncc_is_the_sample_weighted_mean_of_per_face_correlations():
    rng = np.random.default_rng(0)
    n, nf = 400, 4
    fid = rng.integers(0, nf, n)
    g, T = rng.normal(size=n), rng.normal(size=n)
    T += 0.8 * g * (fid + 1) / nf  # a different correlation per face
    use, ok = rng.random(n) < 0.8, rng.random(n) < 0.9
    got = float(bench._zncc(jnp.asarray(g), use, jnp.asarray(T), ok, jnp.asarray(fid), nf))
    r, w = [], []
    for k in range(nf):
        m = use & ok & (fid == k)
        r.append(np.corrcoef(g[m], T[m])[0, 1])
        w.append(m.sum())
    np.testing.assert_allclose(got, np.dot(r, w) / np.sum(w), rtol=1e-10)


def test_a_texture_read_at_a_pose_scores_one_there_and_less_turned_away():
    pts, fid, normals, _, geo = _geometry()
    rng = np.random.default_rng(1)
    img = cv2.GaussianBlur(rng.normal(size=(600, 800)).astype(np.float32), (0, 0), 4.0)
    img = jnp.asarray(img, jnp.float64)
    c, s = np.cos(np.radians(40)), np.sin(np.radians(40))
    R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])  # two faces in view
    t = np.array([0.05, -0.05, 5.0])
    g, use = bench._samples(jnp.asarray(R), jnp.asarray(t), img, K, *geo)
    z = bench.standardised(g, use, fid, len(normals))
    T, T_ok = np.nan_to_num(z), np.isfinite(z)
    _, batch, _, _ = bench._scorers(0.04)
    turn = np.radians(12)
    Rz = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
    s = bench.score_poses(batch, np.stack([R, R @ Rz]), np.stack([t, t]), img, K, T, T_ok)
    np.testing.assert_allclose(s[0], 1.0, atol=1e-9)
    assert s[1] < 0.8
