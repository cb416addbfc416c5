"""``bench/stereo.py``'s check of the machine's own speed around each scene (the yardstick
measured before and after it): a scene whose fps other work changed is named, not hidden."""

import pytest
from bench_module import load_bench


def _scene(name, before, after, fps=10.0):
    return {
        "scene": {"name": name},
        "opencv_yardstick_ms": 0.5 * (before + after),
        "opencv_yardstick_ms_before_after": [before, after],
        "points+lines": {"fps": fps},
    }


def test_scenes_whose_yardstick_moved_or_stood_above_the_run_are_named():
    bench = load_bench("stereo")
    results = [
        _scene("quiet-a", 25.0, 25.0),
        _scene("quiet-b", 25.0, 26.0),
        _scene("quiet-c", 24.0, 25.0),
        _scene("changed", 44.0, 29.0, fps=12.0),  # 44 / 29 = 1.52 between before and after
        _scene("shared", 40.0, 41.0, fps=12.5),  # steady, but 40.5 against a median of 25.5
    ]
    busy = bench.busy_scenes(results)
    assert [b["scene"] for b in busy] == ["changed", "shared"]
    shared = busy[1]
    assert shared["yardstick_ms_before_after"] == [40.0, 41.0]
    assert shared["median_yardstick_ms"] == pytest.approx(25.5)
    assert shared["frame_over_yardstick"] == pytest.approx(1000.0 / 12.5 / 40.5, abs=0.005)
    notes = bench.busy_notes(results)
    assert len(notes) == 2 and "changed" in notes[0] and "44 ms before" in notes[0]


def test_a_steady_run_and_results_without_a_yardstick_name_none():
    bench = load_bench("stereo")
    steady = [_scene(f"s{i}", 25.0 + i, 25.5 + i) for i in range(4)]  # within 1.25 of each other
    assert bench.busy_scenes(steady) == []
    old = [{"scene": {"name": "x"}, "points+lines": {"fps": 9.0}}]  # saved before the yardstick
    assert bench.busy_scenes(old) == [] and bench.busy_notes(old) == []
