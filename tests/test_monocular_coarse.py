"""The coarse range of a ROI cut by the frame (:mod:`jaxpose.vision.coarse`) and the choice of
the whole target's box over a piece of it (:mod:`jaxpose.vision.features`)."""

import numpy as np
import pytest

from jaxpose import PinholeCamera
from jaxpose.vision.coarse import coarse_position, cut_diagonal, projected_extents
from jaxpose.vision.roi import roi_from_segments


def test_projected_extents_of_a_rod_follow_the_uniform_sphere():
    # A unit rod along x: its projected width and height are |R[0, 0]| and |R[1, 0]|, the first
    # two components of a direction uniform on the sphere; each is uniform on [0, 1] in absolute
    # value (Archimedes), so its mean is 1/2 and its median 1/2.
    E = projected_extents(np.array([[0.0, 0, 0], [1.0, 0, 0]]), samples=4000, seed=1)
    assert E.shape == (4000, 2)
    assert np.all(np.hypot(E[:, 0], E[:, 1]) <= 1 + 1e-12)
    np.testing.assert_allclose(E.mean(0), [0.5, 0.5], atol=0.02)
    # the same seed gives the same samples; another seed others
    np.testing.assert_array_equal(
        E, projected_extents([[0, 0, 0], [1, 0, 0]], samples=4000, seed=1)
    )
    assert not np.array_equal(E, projected_extents([[0, 0, 0], [1, 0, 0]], samples=4000, seed=2))
    with pytest.raises(ValueError, match="points_body"):
        projected_extents(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="samples"):
        projected_extents(np.zeros((2, 3)), samples=0)


def test_cut_diagonal_reads_the_whole_box_from_the_uncut_side():
    # every projected box a square: a ROI cut at the bottom, 100 wide and 50 high, is a square
    # 100 wide whose diagonal is 100 sqrt(2)
    square = np.ones((100, 2))
    roi = [200.0, 300.0, 300.0, 350.0]
    bottom = (False, False, False, True)
    assert cut_diagonal(roi, bottom, square) == pytest.approx(100 * np.sqrt(2))
    # cut on the left instead: the uncut side is the height (50), the box a square of 50
    assert cut_diagonal(roi, (True, False, False, False), square) == pytest.approx(
        np.hypot(100, 50)
    )
    # uncut, or cut on both axes: the ROI's own diagonal
    assert cut_diagonal(roi, (False,) * 4, square) == pytest.approx(np.hypot(100, 50))
    assert cut_diagonal(roi, (True, False, False, True), square) == pytest.approx(np.hypot(100, 50))
    # the visible part more elongated than any box of the model: the ROI's own diagonal
    tall = [200.0, 300.0, 250.0, 400.0]
    assert cut_diagonal(tall, bottom, square) == pytest.approx(np.hypot(50, 100))
    # boxes 1 x 1 and 1 x 3: only the 1 x 3 show at least a height of 2 widths
    mixed = np.array([[1.0, 1.0]] * 50 + [[1.0, 3.0]] * 50)
    assert cut_diagonal([0, 0, 10, 20], (False, True, False, False), mixed) == pytest.approx(
        10 * np.hypot(1, 3)
    )


def test_coarse_position_of_a_cut_roi_is_nearer():
    cam = PinholeCamera(1000.0, 1000.0, 399.5, 299.5, width=800, height=600)
    roi = [350.0, 500.0, 450.0, 599.0]  # reaches the bottom
    cut = (False, False, False, True)
    t0 = coarse_position(roi, cam, 1.0)
    t1 = coarse_position(roi, cam, 1.0, cut=cut, extents=np.ones((100, 2)))
    assert np.linalg.norm(t0) == pytest.approx(1000.0 / np.hypot(100, 99))
    assert np.linalg.norm(t1) == pytest.approx(1000.0 / (100 * np.sqrt(2)))
    np.testing.assert_allclose(t1 / np.linalg.norm(t1), t0 / np.linalg.norm(t0))


def _corner(x, y, size):
    """Two segments meeting at a right angle at (x, y): a cluster with a corner."""
    return [[[x, y], [x + size, y]], [[x, y], [x, y + size]]]


def test_roi_from_segments_takes_in_a_fragment_within_the_absorb_margin():
    # the target's outline with a corner piece broken off beyond its bottom-right corner, 40
    # pixels away in each direction, too far from any member's end to link (the link gap is
    # 0.15 x 400 = 60; the nearest end is 98 away); the outline's box diagonal is 566: 40 is
    # beyond 0.05 of it (28), within 0.1 (57)
    big = _corner(100, 100, 400) + [[[500, 100], [500, 450]], [[100, 500], [450, 500]]]
    S = np.array(big + _corner(540, 540, 80), float)
    box5, _ = roi_from_segments(S, absorb_margin=0.05)
    box10, _ = roi_from_segments(S, absorb_margin=0.1)
    np.testing.assert_allclose(box5, [100, 100, 500, 500])
    np.testing.assert_allclose(box10, [100, 100, 620, 620])
