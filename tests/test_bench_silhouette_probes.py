"""The two silhouette probes of ``bench/monocular_silhouette_probes.py``: GrabCut's silhouette of
a dark target over a bright textured background against the drawn target, and the IoU with an
unknown region against a count of cells written out (the plain IoU where nothing is unknown)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from bench_module import load_bench

jax.config.update("jax_enable_x64", True)

bench = load_bench("monocular_silhouette_probes")


def test_grabcut_finds_a_dark_target_on_a_textured_background():
    rng = np.random.default_rng(3)
    img = rng.uniform(150, 250, (240, 320))  # bright clouds
    truth = np.zeros_like(img, bool)
    truth[80:160, 100:220] = True
    img[truth] = rng.uniform(20, 50, truth.sum())  # the target, dark
    img[90:100, 120:140] = 200.0  # a lit patch inside it (a hole GrabCut may leave: filled)
    fg = bench.grabcut_silhouette(img, [100, 80, 220, 160], factor=4)
    want = truth[::4, ::4]
    assert fg is not None and fg.shape == want.shape
    iou = (fg.astype(bool) & want).sum() / (fg.astype(bool) | want).sum()
    assert iou > 0.85


def test_grabcut_gives_none_for_a_box_off_the_image():
    img = np.full((64, 64), 100.0)
    assert bench.grabcut_silhouette(img, [70, 70, 90, 90], factor=4) is None


def test_iou_with_an_unknown_region_against_counted_cells():
    model = np.array([1, 1, 1, 1, 0, 0, 1, 1], float)
    image = np.array([1, 1, 0, 0, 1, 0, 0, 1], float)
    unknown = np.array([0, 0, 1, 0, 0, 0, 1, 1], float)
    # intersection: cells 0, 1, 7; union: cells 0, 1, 3, 4, 7 (2 and 6 unknown with no
    # silhouette there: not the model's extra; 7 unknown with silhouette: counted)
    assert float(
        bench.iou_with_unknown(jnp.asarray(model), jnp.asarray(image), jnp.asarray(unknown))
    ) == pytest.approx(3 / 5)
    plain = (np.minimum(model, image).sum()) / np.maximum(model, image).sum()
    got = bench.iou_with_unknown(jnp.asarray(model), jnp.asarray(image), jnp.zeros(8))
    assert float(got) == pytest.approx(plain)
