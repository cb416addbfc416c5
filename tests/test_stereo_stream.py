"""A sequence tracked as a stream (the next pair's features extracted ahead, in a worker) gives
the poses of process() called pair by pair."""

import numpy as np
import pytest

from jaxpose.pipelines.stereo import STAGES, StereoTracker, TrackerOptions, track_stream
from jaxpose.studies.stereo_track import track_sequence
from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence

RIG = default_rig()


@pytest.fixture(scope="module")
def frames():
    return list(render_sequence(StereoScene(frames=6), RIG))


def _poses(results):
    return np.array([np.r_[np.ravel(r.R), r.t] for r in results])


def test_the_stream_tracks_as_process_pair_by_pair(frames):
    one = StereoTracker(RIG, frames[0].pose)
    by_pair = [one.process(f.left, f.right) for f in frames]
    for prefetch in (True, False):
        tracker = StereoTracker(RIG, frames[0].pose)
        streamed = list(
            track_stream(tracker, ((f.left, f.right) for f in frames), prefetch=prefetch)
        )
        assert len(streamed) == len(frames)
        np.testing.assert_array_equal(_poses(streamed), _poses(by_pair))
        assert [r.inliers for r in streamed] == [r.inliers for r in by_pair]
        for r in streamed:
            assert set(STAGES) <= set(r.timings)
            assert all(v >= 0 for v in r.timings.values())
            # extracted ahead: its own figure, not a stage the frame waited on
            assert ("features_ahead" in r.timings) == prefetch


def test_track_sequence_excludes_the_time_to_produce_a_frame(frames):
    """Frames that take 0.2 s each to produce (a slow reader): the tracking times leave every
    one of those 0.2 s out (their sum is at most the call's wall time less the reading), and the
    poses are those of frames given at once."""
    import time

    def slow():
        for f in frames:
            time.sleep(0.2)
            yield f

    t0 = time.perf_counter()
    results, truths, seconds = track_sequence(slow(), RIG, prefetch=True)
    wall = time.perf_counter() - t0
    assert len(results) == len(truths) == len(seconds) == len(frames)
    assert all(t is f.pose for t, f in zip(truths, frames, strict=True))
    assert sum(seconds) <= wall - 0.2 * len(frames)
    assert all(s > 0 for s in seconds)
    fast = track_sequence(frames, RIG, prefetch=False)
    np.testing.assert_array_equal(_poses(results), _poses(fast[0]))


@pytest.mark.typecheck_off
def test_a_refused_pair_is_named_in_its_turn(frames):
    pairs = [(f.left, f.right) for f in frames[:4]]
    pairs[2] = (frames[2].left, None)
    for prefetch in (True, False):
        seen = []
        with pytest.raises(ValueError, match="pair 2: the right image is None"):
            for r in track_stream(StereoTracker(RIG, frames[0].pose), pairs, prefetch=prefetch):
                seen.append(r)
        assert len(seen) == 2  # the pairs before it were tracked and yielded
    with pytest.raises(TypeError, match="pair 0: expected a \\(left, right\\) pair"):
        next(track_stream(StereoTracker(RIG, frames[0].pose), [frames[0].left]))
    seen = []
    with pytest.raises(TypeError, match="pair 1: expected a \\(left, right\\) pair"):
        odd = [(frames[0].left, frames[0].right), frames[1].left]
        for r in track_stream(StereoTracker(RIG, frames[0].pose), odd):
            seen.append(r)
    assert len(seen) == 1
    with pytest.raises(ValueError, match="pair 1: images must be"):
        list(
            track_stream(
                StereoTracker(RIG, frames[0].pose),
                [(frames[0].left, frames[0].right), (frames[1].left[:100], frames[1].right)],
            )
        )


def test_process_takes_the_features_of_detect_only(frames):
    tracker = StereoTracker(RIG, frames[0].pose, options=TrackerOptions(use_lines=False))
    f = frames[0]
    r = tracker.process(f.left, f.right, features=tracker.detect(f.left))
    assert r.status == 0
    with pytest.raises(TypeError, match="FrameFeatures of StereoTracker.detect"):
        tracker.process(f.left, f.right, features=np.zeros((10, 2)))


def test_detect_in_one_thread_finds_the_features_of_two(frames):
    """The stream's worker extracts in one thread (points, then lines); the features are those
    of the lines' own thread beside the points'."""
    tracker = StereoTracker(RIG, frames[0].pose)
    left = frames[2].left
    one, two = tracker.detect(left, threads=False), tracker.detect(left, threads=True)
    assert len(one.points) > 100 and len(one.segments) > 5
    for name in ("points", "point_desc", "segments", "line_desc", "point_response"):
        np.testing.assert_array_equal(getattr(one, name), getattr(two, name), err_msg=name)
