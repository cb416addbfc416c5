"""The lifting of ``bench/monocular_sift.py``: pixels ray-cast onto the model land on the face
they see, at the body point whose projection they are (a closed form: the pinhole projection of
points drawn on the faces), and pixels off the model get no point."""

import numpy as np
from bench_module import load_bench

from jaxpose.vision.models import tango

bench = load_bench("monocular_sift")

K = np.array([[1500.0, 0, 400.0], [0, 1500.0, 300.0], [0, 0, 1]])


def test_lifted_pixels_are_the_body_points_they_project_from():
    model = tango()
    c, s = np.cos(np.radians(150)), np.sin(np.radians(150))
    R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])  # the panel's top face turned to the camera
    t = np.array([0.1, -0.05, 6.0])
    rng = np.random.default_rng(0)
    # points on the panel's top face (z = 0.322), away from its rims
    top = np.c_[rng.uniform(-0.3, 0.3, 50), rng.uniform(-0.3, 0.3, 50), np.full(50, 0.322)]
    P = top @ R.T + t
    pixels = P[:, :2] / P[:, 2:3] * 1500.0 + [400.0, 300.0]
    got = bench.lift(model, R, t, K, pixels)
    np.testing.assert_allclose(got, top, atol=2e-3)  # the model's vertices are float32
    off = np.array([[5.0, 5.0], [790.0, 590.0]])  # image corners: sky
    assert np.isnan(bench.lift(model, R, t, K, off)).all()
