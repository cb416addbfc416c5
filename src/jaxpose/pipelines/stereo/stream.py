"""A stereo sequence tracked as a stream: the next pair's features extracted while this one is
tracked.

:meth:`StereoTracker.process <jaxpose.pipelines.stereo.StereoTracker.process>` runs a frame's
stages one after the other: the features (ORB and LSD + LBD, two threads), the search by
projection, the stereo search (two threads), the pose and the map (one thread for most of their
time). The features depend on the images and the options only, so :func:`track_stream` extracts
pair ``k + 1``'s in a worker thread (points, then lines: one thread) while pair ``k`` is tracked,
filling the core the pose and map stages leave idle. The results are those of calling
``process`` pair by pair.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor

from jaxpose.pipelines.stereo.frames import checked_pair
from jaxpose.pipelines.stereo.options import FrameResult

__all__ = ["track_stream"]


def track_stream(tracker, pairs: Iterable, *, prefetch: bool = True) -> Iterator[FrameResult]:
    """Track the stereo ``pairs`` (an iterable of ``(left, right)`` rectified images, as
    :meth:`~jaxpose.pipelines.stereo.StereoTracker.process` takes them; read lazily) with
    ``tracker``, yielding each pair's :class:`~jaxpose.pipelines.stereo.FrameResult` once it is
    tracked.

    ``prefetch``: extract pair ``k + 1``'s features (:meth:`StereoTracker.detect
    <jaxpose.pipelines.stereo.StereoTracker.detect>`) in a worker thread while pair ``k`` is
    tracked; pair ``k + 1`` is read from ``pairs`` before pair ``k`` is tracked. A frame's
    ``timings["features"]`` is then the wall time its tracking waited for them (near zero once
    the pipe runs), ``timings["features_ahead"]`` the wall time of their extraction in the
    worker, and the CPU time by stage counts the worker's CPU in the stage it overlapped (the
    frame's total is exact). ``False``: ``process`` pair by pair. Either way the poses are
    the same (tested). A pair the tracker refuses (``None``, another size: ``ValueError``; not
    a pair: ``TypeError``) raises naming the pair's index when its turn comes.
    """
    it = iter(pairs)
    if not prefetch:
        for index, pair in enumerate(it):
            left, right = _unpacked(pair, index)
            try:
                result = tracker.process(left, right)
            except ValueError as err:
                raise ValueError(f"pair {index}: {err}") from err
            yield result
        return
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxpose-prefetch") as pool:

        def ahead(index: int):
            """Pair ``index`` read, checked and its features submitted; ``None`` past the end;
            a refused pair's error is kept for its turn."""
            pair = next(it, None)
            if pair is None:
                return None
            try:
                left, right = _unpacked(pair, index)
            except TypeError as err:
                return err
            try:
                left, right = checked_pair(left, right, tracker.rig)
            except ValueError as err:
                return ValueError(f"pair {index}: {err}")
            return left, right, pool.submit(timed_detect, left)

        def timed_detect(left):
            t0 = time.perf_counter()
            # one thread: this worker already runs beside the tracking thread, and the lines'
            # own thread would take the tracking's core from it (paired on 2 cores: the frame
            # 2-17% shorter than with the lines in a third thread; the same features)
            features = tracker.detect(left, threads=False)
            return features, time.perf_counter() - t0

        index = 0
        current = ahead(index)
        while current is not None:
            if isinstance(current, Exception):
                raise current
            left, right, pending = current
            t0, c0 = time.perf_counter(), time.process_time()
            features, extraction = pending.result()
            wait, wait_cpu = time.perf_counter() - t0, time.process_time() - c0
            current = ahead(index + 1)
            result = tracker.process(left, right, features=features)
            result.timings["features"] = wait
            result.cpu_timings["features"] = wait_cpu
            result.timings["features_ahead"] = extraction
            index += 1
            yield result


def _unpacked(pair, index: int):
    try:
        left, right = pair
    except (TypeError, ValueError):
        raise TypeError(
            f"pair {index}: expected a (left, right) pair of images; got {type(pair).__name__}"
        ) from None
    return left, right
