"""``bench/stereo_envelope.py``: the scenes meeting issue 16's targets by range and spin rate,
read from saved bench results (counts checked against a count written out here)."""

import json

import numpy as np
import pytest
from bench_module import load_bench


def _record(name, range_m, rate, pos_mm, att_deg=(0.1, 0.1, 0.1), lost=0):
    return {
        "scene": {"name": name, "range_m": range_m, "rate_deg_s": rate, "split": "held-out"},
        "points+lines": {
            "rms_position_mm": None if pos_mm is None else list(pos_mm),
            "rms_attitude_deg": None if pos_mm is None else list(att_deg),
            "lost_frames": lost,
        },
    }


def _records():
    rng = np.random.default_rng(3)
    out = []
    for i in range(40):
        r = float(rng.choice([1.5, 2.0, 2.5, 3.7, 4.0, 4.4, 5.0]))
        rate = float(rng.uniform(5, 20))
        worst = float(rng.uniform(0.2, 1.4)) * 5.0 * r  # mm: some above 5 mm per metre
        out.append(_record(f"h{i:02d}", r, rate, (worst, 0.5 * worst, 0.2 * worst)))
    out.append(_record("att", 3.0, 16.0, (1.0, 1.0, 1.0), att_deg=(0.2, 1.2, 0.1)))
    out.append(_record("lost", 4.2, 8.0, None, lost=3))
    return out


def _meets(rec):
    s, m = rec["scene"], rec["points+lines"]
    if m["rms_position_mm"] is None or m["lost_frames"]:
        return False
    return max(m["rms_position_mm"]) <= 5.0 * s["range_m"] and max(m["rms_attitude_deg"]) <= 1.0


def test_counts_by_range_band_and_spin_match_a_count_written_out():
    bench = load_bench("stereo_envelope")
    recs = _records()
    s = bench.summarise([bench.scene_figures(r) for r in recs])
    assert s["scenes"] == len(recs) and s["meet"] == sum(map(_meets, recs))
    edges = bench.RANGE_EDGES
    for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        last = i == len(edges) - 2
        inside = [
            r
            for r in recs
            if lo <= r["scene"]["range_m"] < hi or (last and r["scene"]["range_m"] == hi)
        ]
        band = s["by_range"][bench.band_label(lo, hi)]
        assert (band["meet"], band["scenes"]) == (sum(map(_meets, inside)), len(inside))
        fast = [r for r in inside if r["scene"]["rate_deg_s"] >= bench.FAST_DEG_S]
        spin = s["by_range_and_spin"][bench.band_label(lo, hi)]
        assert spin[f"{bench.FAST_DEG_S:g} deg/s or more"]["scenes"] == len(fast)
        assert spin[f"{bench.FAST_DEG_S:g} deg/s or more"]["meet"] == sum(map(_meets, fast))
    # every scene lies in a band here: 2.5 m opens the second band and 5.0 m closes the last
    assert sum(b["scenes"] for b in s["by_range"].values()) == len(recs)
    missed = {m["name"] for m in s["misses"]}
    assert {"att", "lost"} <= missed  # attitude over 1 degree; a lost track
    assert missed == {r["scene"]["name"] for r in recs if not _meets(r)}
    lost = next(m for m in s["misses"] if m["name"] == "lost")
    assert lost["worst_position_over_target"] is None and lost["lost_frames"] == 3


def test_the_worst_axis_over_its_target():
    bench = load_bench("stereo_envelope")
    f = bench.scene_figures(_record("a", 4.0, 10.0, (12.0, 22.0, 3.0), att_deg=(0.1, 0.3, 0.2)))
    assert f["worst_position_over_target"] == pytest.approx(22.0 / 20.0)
    assert f["worst_attitude_deg"] == pytest.approx(0.3) and not f["meets"]
    assert bench.scene_figures(_record("b-tumble", 2.0, 6.0, (1.0, 1.0, 1.0)))["tumbling"]


def test_main_reads_folders_writes_the_figure_and_ends_with_a_json_line(tmp_path, capsys):
    bench = load_bench("stereo_envelope")
    run = tmp_path / "run"
    run.mkdir()
    (run / "results.json").write_text(json.dumps(_records()))
    assert bench.main([str(run), "--out", str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "envelope.png").stat().st_size > 10_000
    last = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert last["bench"] == "stereo-envelope" and last["scenes"] == 42
    assert last["meet"] == sum(map(_meets, _records()))  # the lost track's miss in strict JSON


def test_a_path_without_results_is_named(tmp_path):
    bench = load_bench("stereo_envelope")
    with pytest.raises(SystemExit, match="no results.json at"):
        bench.load([tmp_path / "nothing"])
    (tmp_path / "results.json").write_text(json.dumps([{"scene": {"name": "x"}}]))
    with pytest.raises(SystemExit, match="no scene tracked with points"):
        bench.load([tmp_path])
