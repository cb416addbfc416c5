"""``bench/stereo.py``'s check of the machine around each scene: a scene whose fps other work
changed (its yardstick before and after apart or high, or its threads waiting for the cores) is
named, not hidden."""

import pytest
from bench_module import load_bench


def _scene(name, before, after, fps=10.0, cpu_s=None):
    wall_s = 1.0 / fps
    return {
        "scene": {"name": name},
        "opencv_yardstick_ms": 0.5 * (before + after),
        "opencv_yardstick_ms_before_after": [before, after],
        # CPU time a frame: 1.6 cores' worth of the wall time unless given
        "points+lines": {
            "fps": fps,
            "mean_frame_s": wall_s,
            "mean_frame_cpu_s": cpu_s or 1.6 * wall_s,
        },
    }


def test_scenes_with_the_machine_busy_around_or_during_them_are_named():
    bench = load_bench("stereo")
    results = [
        _scene("quiet-a", 25.0, 25.0),
        _scene("quiet-b", 25.0, 26.0),
        _scene("quiet-c", 24.0, 25.0),
        _scene("changed", 44.0, 29.0, fps=12.0),  # 44 / 29 = 1.52 between before and after
        _scene("shared", 40.0, 41.0, fps=12.5),  # steady, but 40.5 against a median of 25.25
        # the yardstick quiet, but the frame's wall time is its CPU time: the threads waited
        _scene("waited", 25.0, 25.0, fps=8.0, cpu_s=0.125),
    ]
    busy = bench.busy_scenes(results)
    assert [b["scene"] for b in busy] == ["changed", "shared", "waited"]
    shared, waited = busy[1], busy[2]
    assert shared["yardstick_ms_before_after"] == [40.0, 41.0]
    # the median of the six means 24.5, 25, 25, 25.5, 36.5, 40.5 ms, to a tenth
    assert shared["median_yardstick_ms"] == pytest.approx(25.25, abs=0.06)
    assert shared["frame_over_yardstick"] == pytest.approx(1000.0 / 12.5 / 40.5, abs=0.005)
    assert waited["wall_over_cpu"] == pytest.approx(1.0)
    assert waited["median_wall_over_cpu"] == pytest.approx(1 / 1.6, abs=0.006)  # to a hundredth
    notes = bench.busy_notes(busy)
    assert len(notes) == 3 and "changed" in notes[0] and "44 ms before" in notes[0]
    assert "wall over CPU time 1 against a median of 0.62" in notes[2]


def test_a_steady_run_and_results_without_a_yardstick_name_none():
    bench = load_bench("stereo")
    # yardsticks within 1.3 of each other, wall over CPU 0.55-0.70
    steady = [_scene(f"s{i}", 25.0 + i, 25.5 + i, cpu_s=0.1 / (0.55 + 0.05 * i)) for i in range(4)]
    assert bench.busy_scenes(steady) == []
    old = [{"scene": {"name": "x"}, "points+lines": {"fps": 9.0}}]  # saved before the yardstick
    assert bench.busy_scenes(old) == []


def _tracked(name, before, after, fps, errors=(1.0, 2.0, 3.0)):
    r = _scene(name, before, after, fps=fps)
    r["points+lines"].update(
        rms_position_mm=list(errors),
        rms_attitude_deg=[0.1, 0.1, 0.1],
        lost_frames=0,
        meets_targets=True,
    )
    return r


def test_busy_scenes_are_tracked_again_and_their_first_fps_kept():
    bench = load_bench("stereo")
    results = [_tracked(f"quiet-{i}", 25.0, 25.0, 10.0) for i in range(4)]
    results.insert(2, _tracked("changed", 44.0, 29.0, 6.0))  # 44 / 29: busy
    asked = []

    def rerun(name):
        asked.append(name)
        return _tracked(name, 25.0, 25.5, 10.5)

    out = bench.rerun_busy(results, rerun)
    assert asked == ["changed"]
    assert [r["scene"]["name"] for r in out] == [r["scene"]["name"] for r in results]
    assert all(a is b for a, b in zip(out, results, strict=True) if a["scene"]["name"] != "changed")
    again = out[2]
    assert again["points+lines"]["fps"] == 10.5
    assert again["rerun"] == {
        "first_fps": {"points+lines": 6.0},
        "second_fps": {"points+lines": 10.5},
        "kept": "second",
        "same_errors": True,
    }
    assert bench.busy_scenes(out) == []  # the second run is steady
    assert bench._rerun_summary(out) == {
        "scenes_rerun": {
            "changed": {"first_fps": 6.0, "second_fps": 10.5, "fps": 10.5, "same_errors": True}
        }
    }
    (note,) = bench.rerun_notes(out)
    assert "6 fps first, 10.5 the second time (the errors the same)" in note
    assert "the faster, the second run" in note
    assert bench._rerun_summary(results) == {} and bench.rerun_notes(results) == []


def test_a_rerun_slowed_more_than_the_first_run_leaves_the_first():
    """Other work only slows a run: when the second is the slower, the first stays."""
    bench = load_bench("stereo")
    results = [_tracked(f"quiet-{i}", 25.0, 25.0, 10.0) for i in range(4)]
    results.append(_tracked("changed", 44.0, 29.0, 9.0))
    out = bench.rerun_busy(results, lambda name: _tracked(name, 60.0, 66.0, 5.0))
    kept = out[-1]
    assert kept["points+lines"]["fps"] == 9.0 and kept["opencv_yardstick_ms"] == 36.5
    assert kept["rerun"]["kept"] == "first" and kept["rerun"]["second_fps"]["points+lines"] == 5.0
    assert "rerun" not in results[-1]  # the first run's record is not changed in place
    assert "9 fps first, 5 the second time" in bench.rerun_notes(out)[0]
    # results saved before: the second run's record, no second_fps nor kept
    old = dict(
        _tracked("older", 44.0, 29.0, 11.0),
        rerun={"first_fps": {"points+lines": 6.0}, "same_errors": True},
    )
    (note,) = bench.rerun_notes([old])
    assert "6 fps first, 11 the second time" in note and note.endswith("has the second run")
    assert bench._rerun_summary([old])["scenes_rerun"]["older"]["second_fps"] == 11.0


def test_a_rerun_whose_errors_differ_is_said_so():
    bench = load_bench("stereo")
    results = [_tracked(f"quiet-{i}", 25.0, 25.0, 10.0) for i in range(3)]
    results.append(_tracked("shared", 40.0, 41.0, 7.0))  # 40.5 ms against a median of 25
    out = bench.rerun_busy(results, lambda name: _tracked(name, 25.0, 25.0, 10.0, (1.0, 2.0, 3.5)))
    assert out[-1]["rerun"]["same_errors"] is False
    assert "THE ERRORS DIFFER" in bench.rerun_notes(out)[0]
    # a steady run: nothing tracked again
    assert bench.rerun_busy(results[:3], lambda name: pytest.fail(f"{name} re-run")) == results[:3]
