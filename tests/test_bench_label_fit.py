"""The outline measurement of ``bench/monocular_label_fit.py``: on renders of the Tango model it
finds the outline where the renderer drew it, and reads a model drawn too small (the pose moved
away from the camera) as image edges outside the model by that much."""

import numpy as np
from bench_module import load_bench

from jaxpose.core.camera import PinholeCamera
from jaxpose.vision.models import tango
from jaxpose.vision.render import random_pose, render

bench = load_bench("monocular_label_fit")


def test_outline_offset_is_zero_at_the_rendered_pose_and_reads_a_scale_error():
    model = tango()
    cam = PinholeCamera(1500.0, 1500.0, 400.0, 300.0, width=800, height=600)
    rng = np.random.default_rng(3)
    at_truth, farther = [], []
    for _ in range(6):
        pose = random_pose(rng, cam, range_m=(5.0, 7.0), margin=0.35)
        img = render(model, pose, cam, rng=rng, background_level=0.02).image
        R, t = np.asarray(pose.R, float), np.asarray(pose.t, float)
        off = bench.outline_offset(img, cam, model, R, t)
        if off is None:  # no outline edge long and contrasted enough at this attitude
            continue
        at_truth.append(off)
        c = R @ model.vertices.mean(0) + t
        farther.append(bench.outline_offset(img, cam, model, R, t + 0.06 * c))
    assert len(at_truth) >= 3
    assert abs(np.median(at_truth)) < 0.01
    # the model drawn 1/1.06 as large: the image's edges lie about 6% of their distance outside
    assert 0.035 < np.median(farther) < 0.085
