"""``bench/stereo_warp_truth.py``: the faces it takes as true, how it splits the offsets, and a
short run whose true warps align patches onto their physical points."""

import numpy as np
import pytest
from bench_module import load_bench

from jaxpose.vision.stereo_render import tumbler_model

bench = load_bench("stereo_warp_truth")


def test_face_normals_are_the_nearest_box_faces():
    """Points on the body box's faces (ray-cast points lie exactly there) get those faces'
    outward normals; a point in empty space gets none."""
    V = tumbler_model(1.0).vertices[:8]
    lo, hi = V.min(0), V.max(0)
    X = np.array(
        [
            [hi[0], 0.0, 0.0],  # +x face
            [0.05, lo[1], 0.1],  # -y face
            [-0.1, 0.02, hi[2]],  # +z face
            [hi[0] + 0.3, 0.0, 0.0],  # beyond the box (the wing lies along +y)
        ]
    )
    n = bench.face_normals(X, tumbler_model(1.0))
    np.testing.assert_array_equal(n[:3], [[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]])
    assert np.isnan(n[3]).all()


def test_offsets_split_into_a_constant_a_rest_and_a_drift():
    """Two patches with a known constant offset, a known drift a frame and no noise: the split
    gives them back (RMS over the patches, to the 3 decimals it prints), and patches seen
    fewer than four times are left out."""
    k = np.arange(6)[:, None]
    offsets = {
        (1, 0): list(np.array([0.3, -0.1]) + 0.02 * (k - 2.5) * np.array([1.0, 0.0])),
        (2, 0): list(np.array([-0.3, 0.1]) + 0.02 * (k - 2.5) * np.array([1.0, 0.0])),
        (3, 0): [np.array([5.0, 5.0])] * 3,
    }
    split = bench.offset_split(offsets)
    assert split["patches"] == 2
    np.testing.assert_allclose(split["constant_px"], [0.3, 0.1], atol=1e-3)
    np.testing.assert_allclose(split["constant_mean_px"], [0.0, 0.0], atol=1e-3)
    np.testing.assert_allclose(split["drift_px_a_frame"], [0.02, 0.0], atol=1e-3)
    rest = 0.02 * np.sqrt(np.mean((np.arange(6) - 2.5) ** 2))
    np.testing.assert_allclose(split["varying_px"], [rest, 0.0], atol=1e-3)


def test_a_short_run_aligns_patches_near_their_physical_points():
    """Three frames of the default scene at 2 m: no frame lost, patches aligned, and with the
    true warps their pixels lie a fraction of a pixel from the physical points' true pixels."""
    r = bench.run("d1-clean-2m", 3, 0, "exact")
    assert r["lost"] == 0 and r["aligned_a_frame"] > 50
    if r["patches"]:
        assert max(r["constant_px"]) < 1.0
    with pytest.raises(SystemExit):
        bench.main(["d1-clean-2m", "--frames", "1"])


def test_true_landmarks_move_only_the_points_with_a_physical_point():
    """``move_to_truth`` puts each landmark whose id has a physical point on it, in the map's
    frame, and leaves the others where they were."""
    from types import SimpleNamespace

    anchors = bench.TruthAnchors.__new__(bench.TruthAnchors)
    anchors.physical = {7: np.array([1.0, 2.0, 3.0]), 9: np.array([-1.0, 0.0, 0.5])}
    points = SimpleNamespace(ids=np.array([3, 7, 9]), X=np.zeros((3, 3)))
    assert anchors.move_to_truth(points) == 2
    np.testing.assert_array_equal(points.X, [[0, 0, 0], [1.0, 2.0, 3.0], [-1.0, 0.0, 0.5]])
    points.X[:] = 0.0  # a map whose origin lies at (1, 0, 0) in the body frame
    assert anchors.move_to_truth(points, origin=[1.0, 0.0, 0.0]) == 2
    np.testing.assert_array_equal(points.X, [[0, 0, 0], [0.0, 2.0, 3.0], [-2.0, 0.0, 0.5]])


def test_a_short_run_with_the_true_map():
    """Three frames with ``true_landmarks``: the map's landmarks are moved every frame, and
    the run still tracks."""
    r = bench.run("d1-clean-2m", 3, 0, "facing", true_landmarks=True)
    assert r["lost"] == 0 and r["true_landmarks"]
    assert r["landmarks_moved_a_frame"] > 50


def test_an_unknown_scene_or_option_is_named(capsys):
    cases = ((["d9-nowhere"], "d9-nowhere"), (["d1-clean-2m", "--option", "nope=1"], "nope"))
    for argv, name in cases:
        with pytest.raises(SystemExit):
            bench.main(argv)
        assert name in capsys.readouterr().err
