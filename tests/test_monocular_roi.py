"""The silhouette ROI grown to the finer silhouette (faces in shadow), a silhouette that holds none
of the strong gradients declined, and the sides a ROI reaches (:mod:`jaxpose.vision.roi`,
:func:`jaxpose.vision.features.detect`)."""

from dataclasses import replace

import numpy as np
import pytest

from jaxpose import PinholeCamera
from jaxpose.vision.features import DetectionOptions, detect
from jaxpose.vision.roi import silhouette_box


def test_silhouette_box_grows_to_faces_in_shadow_only():
    f = 4
    m = np.zeros((100, 160), np.uint8)
    m[20:50, 30:70] = 1  # the lit part: the box below
    m[50:70, 30:60] = 1  # a face in shadow below it, joined
    m[40:44, 70:72] = 1  # reaches 2 pixels beyond the box's right side: within the slack
    m[90:91, 150:151] = 1  # an isolated noise pixel: under min_share of the largest component
    m[0:100, 0:5] = 1  # a lit wall touching three sides: not the target
    box = np.array([30, 20, 70, 50], float) * f
    out = silhouette_box(m, box, f)
    # left and top are the box's (the mask ends there too); the bottom moves to the shadow face's
    # edge (row 70); the right side stays (the mask reaches only 2 pixels beyond)
    np.testing.assert_allclose(out, np.array([30, 20, 70, 70], float) * f)
    # nothing beyond the box, or an empty mask: the box as it was
    np.testing.assert_allclose(silhouette_box(m[:50], box, f), box)
    np.testing.assert_allclose(silhouette_box(np.zeros_like(m), box, f), box)
    with pytest.raises(ValueError, match="mask"):
        silhouette_box(np.zeros(5), box, f)
    with pytest.raises(ValueError, match="factor"):
        silhouette_box(m, box, 0)


def test_detect_declines_a_silhouette_without_strong_gradients():
    # A dark blob (no edge survives the WGE in it) and, far from it, a bright textured target:
    # the silhouette test alone would box the blob; the strong gradients say it is not the target.
    rng = np.random.default_rng(3)
    cam = PinholeCamera(1000.0, 1000.0, 399.5, 299.5, width=800, height=600)
    img = 20.0 + 1.0 * rng.standard_normal((600, 800))
    uu, vv = np.meshgrid(np.arange(800), np.arange(600))
    # a faint, soft, large blob: the largest silhouette, with no strong edge
    img += 14.0 * np.exp(-(((uu - 600) / 90.0) ** 4 + ((vv - 420) / 70.0) ** 4))
    check = (uu // 10 + vv // 10) % 2  # a small, sharp, textured target
    img[100:150, 100:160] = (20.0 + 120.0 * check)[100:150, 100:160]
    image = np.clip(img, 0, 255).astype(np.uint8)
    by_area = DetectionOptions(silhouette_gradient=False)
    on = detect(image, cam, 1.0, replace(by_area, silhouette_min_gradient=0.01))
    off = detect(image, cam, 1.0, replace(by_area, silhouette_min_gradient=0.0))
    assert off.roi_silhouette is not None
    assert off.roi_silhouette[0] > 400  # the blob, far from the target
    assert on.roi_silhouette is None or on.roi_silhouette[0] < 250
    assert on.roi is not None and on.roi[0] < 250 and on.roi[2] < 300
    # chosen by its strong gradients (the default), the component is the target; the larger free
    # blob still fails the area test, so the ROI is the gradient one, on the target too
    sharp = detect(image, cam, 1.0)
    assert sharp.roi_silhouette is None or sharp.roi_silhouette[0] < 250
    assert sharp.roi is not None and sharp.roi[0] < 250 and sharp.roi[2] < 300


def test_roi_cut_names_the_sides_the_roi_reaches():
    from jaxpose.vision.features import roi_cut

    assert roi_cut([0, 10, 50, 60], (100, 200)) == (True, False, False, False)
    assert roi_cut([10, 0, 199, 99], (100, 200)) == (False, True, True, True)
    assert roi_cut([10, 10, 190, 90], (100, 200)) == (False, False, False, False)


def test_silhouette_mask_leaves_out_an_earth_touching_two_sides():
    from jaxpose.vision.roi import silhouette_mask

    rng = np.random.default_rng(5)
    img = 20.0 + 2.0 * rng.standard_normal((400, 640))
    img[100:200, 200:300] += 40.0  # the target
    img[225:, 325:] += 60.0  # an Earth in the corner, within the grown box's reach
    box = [200, 100, 300, 200]
    mask = silhouette_mask(np.clip(img, 0, 255).astype(np.uint8), box, factor=4)
    assert mask is not None
    assert mask[25:50, 50:75].mean() > 0.9  # the target (quarter resolution)
    assert mask[60:, 85:].sum() == 0  # not the Earth


def test_given_roi_replaces_the_roi_stage():
    # The same image as above: the blob would win by area; a caller's box on the blob is kept as
    # the ROI (no silhouette, gradient or cluster ROI searched), and bad boxes are refused by name.
    rng = np.random.default_rng(3)
    cam = PinholeCamera(1000.0, 1000.0, 399.5, 299.5, width=800, height=600)
    img = 20.0 + 1.0 * rng.standard_normal((600, 800))
    check = (np.arange(800)[None] // 10 + np.arange(600)[:, None] // 10) % 2
    img[100:150, 100:160] = (20.0 + 120.0 * check)[100:150, 100:160]
    image = np.clip(img, 0, 255).astype(np.uint8)
    box = np.array([500.0, 350.0, 700.0, 500.0])
    det = detect(image, cam, 1.0, roi=box)
    np.testing.assert_allclose(det.roi, box)
    np.testing.assert_allclose(det.roi_given, box)
    assert det.silhouette is None and det.roi_silhouette is None and det.roi_gradient is None
    assert detect(image, cam, 1.0).roi[0] < 250  # without it, the textured target
    # a box reaching past the frame is clipped to it
    np.testing.assert_allclose(
        detect(image, cam, 1.0, roi=[-50, 10, 900, 200]).roi, [0, 10, 799, 200]
    )
    for bad, word in (
        ([1, 2, 3], "four"),
        ([10, 10, 5, 20], "u0 < u1"),
        ([0, 0, np.nan, 5], "four finite"),
        ([900, 700, 950, 800], "outside"),
        ([10, 10, 15, 15], "too small"),
    ):
        with pytest.raises(ValueError, match=word):
            detect(image, cam, 1.0, roi=bad)


def test_given_roi_is_mapped_through_the_distortion():
    # A pixel seen through a distorting camera, boxed there: the box in the undistorted image
    # holds where the ideal camera sees that point (the camera's own forward model, not OpenCV).
    from jaxpose.vision.undistort import undistort_box

    cam = PinholeCamera(900.0, 900.0, 399.5, 299.5, [-0.25, 0.08, 0.001, -0.002, 0.0])
    ideal = cam.without_distortion()
    p = np.array([0.31, -0.22, 1.0])  # camera frame
    seen, true = np.asarray(cam.project(p)), np.asarray(ideal.project(p))
    out = undistort_box(np.r_[seen - 2.0, seen + 2.0], cam, (600, 800))
    assert out[0] < true[0] < out[2] and out[1] < true[1] < out[3]
    # the 4-pixel box stays a few pixels wide; without distortion it is the box itself
    assert 2.0 < out[2] - out[0] < 8.0 and 2.0 < out[3] - out[1] < 8.0
    assert abs((out[0] + out[2]) / 2 - true[0]) < 0.5 and abs((out[1] + out[3]) / 2 - true[1]) < 0.5
    np.testing.assert_allclose(undistort_box([1, 2, 30, 40], ideal, (600, 800)), [1, 2, 30, 40])
