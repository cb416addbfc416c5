"""The antenna-direction measurement of ``bench/monocular_antennas.py``: its thin-bar map answers
to a thin bar and not to an edge or a wide band, and on renders of the Tango model it finds the
antennas where the renderer drew them (the renderer, not the measurement, knows the model)."""

import numpy as np
import pytest
from bench_module import load_bench

from jaxpose.core.camera import PinholeCamera
from jaxpose.vision.models import tango
from jaxpose.vision.render import random_pose, render

bench = load_bench("monocular_antennas")


def test_thin_bar_map_answers_to_a_bar_not_to_an_edge_or_a_wide_band():
    img = np.full((400, 400), 20.0, np.float32)
    img[100:300, 60:64] = 200.0  # a bar 4 px wide (the expected width: 1% of the box diagonal)
    img[100:300, 200:300] = 200.0  # a wide band: two step edges
    bar, frame = bench.thin_bar_map(img, (50, 50, 350, 350))

    def at(u, v):
        i, j = np.round((np.array([u, v]) - frame[:2]) * frame[2]).astype(int)
        return bar[j, i]

    assert at(61.5, 200) > 0.5
    for u in (200, 250, 299, 198, 302):  # edges and inside of the band
        assert at(u, 200) < 0.1, u
    assert at(150, 200) < 0.05  # flat background


def test_fibonacci_directions_are_unit_and_spread():
    d = bench.fibonacci_sphere(2000)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    rng = np.random.default_rng(0)
    probe = rng.normal(size=(50, 3))
    probe /= np.linalg.norm(probe, axis=1, keepdims=True)
    # every direction has a sample within about twice the mean spacing (~2.6 deg for 2000)
    assert np.degrees(np.arccos(np.clip((probe @ d.T).max(1), -1, 1))).max() < 6.0


def test_moved_bases_lie_on_the_panel_sides_along_the_given_directions():
    model = tango()
    V = np.asarray(model.vertices)
    tips = V[model.antennas[:, 1]]
    dirs = np.array([[0.85, -0.5, 0.1], [-0.85, -0.5, 0.0], [0.0, 1.0, 0.1]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    bases = bench.moved_bases(model, dirs)
    np.testing.assert_allclose(np.abs(bases[:2, 0]), 0.37, atol=1e-12)
    np.testing.assert_allclose(bases[2, 1], -0.385, atol=1e-12)
    step = bases - tips
    np.testing.assert_allclose(np.cross(step, dirs), 0.0, atol=1e-12)
    assert np.all(np.einsum("ij,ij->i", step, dirs) > 0)


@pytest.mark.slow
def test_measured_directions_match_the_rendered_antennas():
    model = tango()
    V = np.asarray(model.vertices)
    camera = PinholeCamera(2988.6, 2988.3, 960.0, 600.0, width=1920, height=1200)
    dirs = bench.fibonacci_sphere(6000)
    rng = np.random.default_rng(3)
    total = 0.0
    for _ in range(6):
        pose = random_pose(rng, camera, range_m=(4.0, 6.0))
        img = render(model, pose, camera, rng=rng).image
        total = total + bench.direction_scores(
            np.asarray(img, np.float32), pose.R, pose.t, camera, model, dirs
        )
    for a, (base, tip) in enumerate(model.antennas):
        true = (V[base] - V[tip]) / np.linalg.norm(V[base] - V[tip])
        best = dirs[int(np.argmax(total[a]))]
        assert np.degrees(np.arccos(np.clip(best @ true, -1, 1))) < 8.0, a
