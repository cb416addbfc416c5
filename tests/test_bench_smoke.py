"""The benches run end to end at the smallest size and end with one JSON line of their figures
(their timings are not checked here: speed is the benches' business, not the tests').

The benches run their ``main`` in the test's process, where the programs are already compiled
by the other tests (as subprocesses the stereo benches spent most of their 11-22 s each
importing and compiling the tracker again, in-process 1-5 s after the first; the monocular
bench 21 s against 14 s after a monocular test)."""

import json

import pytest
from bench_module import load_bench


@pytest.mark.slow
def test_monocular_bench_runs_and_ends_with_its_figures(tmp_path, capsys, monkeypatch):
    # in this process, as the stereo benches below: the programs other tests compiled are reused;
    # the bench's own cache settings (every compilation stored) would outlive it in this worker
    bench = load_bench("monocular")
    monkeypatch.setattr(bench, "enable_compilation_cache", lambda: None)
    out = _main_json(bench, ["--images", "1", "--out", tmp_path / "m.json"], capsys)
    assert out["images"] == 1
    assert 0.0 <= out["success_rate"] <= 1.0
    assert out["median_runtime_s"] > 0
    assert set(out["confidence_counts"]) >= {"high", "low", "position-only"}
    per_image = json.loads((tmp_path / "m.json").read_text())["per_image"]
    assert len(per_image) == 1


@pytest.mark.slow
def test_stereo_bench_runs_and_ends_with_its_figures(tmp_path, capsys):
    out = _main_json(
        "stereo",
        [
            "--scenes",
            "d1-clean-2m",
            "--scene",
            'own-2.5m={"range_m": 2.5, "spin_axis_body": [0.3, -0.2, 1.0], "nutation_deg": 10}',
            "--frames",
            "3",
            "--points-lines-only",
            "--init",
            "identity",
            "--out",
            str(tmp_path / "st"),
        ],
        capsys,
    )
    assert out["scenes"] == 2 and out["frames_per_scene"] == 3 and out["init"] == ["identity"]
    assert set(out["meets_targets"]) == {"dev", "check", "own"}  # the --scene counted apart
    assert out["median_fps"] > 0
    assert out["median_opencv_yardstick_ms"] > 0 and out["median_frame_over_yardstick"] > 0
    # scenes the machine's other work slowed are named (three frames: any, or none)
    assert set(out["scenes_on_a_busy_machine"]) <= {"d1-clean-2m", "own-2.5m"}
    assert {"features", "stereo", "pose", "map"} <= set(out["median_stage_ms"])
    assert (tmp_path / "st" / "results.json").is_file()


@pytest.mark.slow
def test_stereo_matching_bench_counts_what_it_finds(capsys):
    out = _main_json(
        "stereo_matching",
        ["--scene", 'far={"range_m": 4.0, "rate_deg_s": 10.0}', "--frames", "3"],
        capsys,
    )
    orb = out["orb_between_frames"]
    assert 0 < orb["found_again"] <= orb["on_target"] <= orb["keypoints"]
    assert 0.0 <= orb["same_level_share"] <= 1.0
    assert 0 < orb["distinct_corners_1px"] <= orb["refined_keypoints"]
    assert 0 < out["median_right"] <= out["median_matched"]
    assert out["median_right"] <= out["median_findable"]


@pytest.mark.slow
def test_stereo_budget_bench_runs_every_rule_on_shared_features(tmp_path, capsys):
    """``bench/stereo_budget.py`` shares one feature extraction among its trackers by replacing
    the features stage's ``extract`` (a move of that stage broke it once without a test), and
    puts the stage's own back when it is done (it runs in this process here)."""
    from jaxpose.pipelines.stereo import frames

    extract = frames.extract
    argv = ["--scenes", "d1-clean-2m", "--frames", "3", "--budgets", "30"]
    argv += ["--rules", "dop", "random", "--out", tmp_path / "b"]
    out = _main_json("stereo_budget", argv, capsys)
    assert frames.extract is extract
    assert out["bench"] == "stereo-budget" and out["scenes"] == 1 and out["N"] == 30
    assert {"all", "dop@30", "random@30"} <= set(out["median_pose_cpu_ms"])


@pytest.mark.slow
def test_stereo_turnover_bench_measures_matches_against_the_truth(tmp_path, capsys):
    figure = tmp_path / "turnover.png"
    out = _main_json(
        "stereo_turnover", ["d1-clean-2m", "--frames", "6", "--figure", figure], capsys
    )
    assert figure.stat().st_size > 10_000
    (scene,) = out["scenes"]
    early = scene["summary"]["early"]
    assert early["matches"] > 100
    # on the clean 2 m scene the matched keypoints lie on their landmarks' true projections
    # (a wrong pose convention or ray cast would put them tens of pixels away)
    assert early["median_e_true_px"] < 1.5
    lateral, depth = early["old_lat_dep_mm"]
    assert 0 < lateral < 5 and 0 < depth < 20


@pytest.mark.slow
def test_stereo_paired_bench_tells_same_tracking_from_changed(capsys):
    """The features in one thread or two are the same features (a speed option), so the two
    trackers' poses agree to the bit; a different search radius changes the tracking."""
    common = ["d1-clean-2m", "--frames", "4", "--reps", "1"]
    out = _main_json("stereo_paired", [*common, "--option", "threads=False"], capsys)
    (scene,) = out["scenes"]
    assert scene["same_poses"] is True
    assert scene["A"]["wall_ms"]["frame"] > 0 and "stereo" in scene["ratio_B_over_A"]["cpu_ms"]
    out = _main_json("stereo_paired", [*common, "--option", "search_radius_px=3.0"], capsys)
    assert out["scenes"][0]["same_poses"] is False


def _scene_run(name, seed, lines, points, **scene):
    """A ``bench/stereo.py`` record of one scene in both modes (RMS x, y, z mm; roll, pitch,
    yaw deg)."""

    def mode(v):
        return {"rms_position_mm": v[:3], "rms_attitude_deg": v[3:]}

    record = {
        "scene": {"name": name, "seed": seed, **scene},
        "points+lines": mode(lines),
        "points-only": mode(points),
    }
    if lines and points:  # bench/stereo.py's verdict, recorded where both modes have an RMS
        record["lines_help"] = all(a < b for a, b in zip(lines, points, strict=True))
    return record


def _main_json(bench, argv, capsys) -> dict:
    """Run ``bench/<bench>.py``'s ``main`` (``bench``: its name or the loaded module) in this
    process; its last printed line, as JSON."""
    module = load_bench(bench) if isinstance(bench, str) else bench
    assert module.main([str(a) for a in argv]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.strip()]
    return json.loads(lines[-1])


def test_stereo_bench_refuses_an_unknown_start_before_rendering():
    with pytest.raises(ValueError, match="init must be 'truth' or 'identity'; got 'Truth'"):
        load_bench("stereo").run_scene("d1-clean-2m", 3, init="Truth")


def test_lines_gain_bench_reads_runs_of_both_modes(tmp_path, capsys):
    """Per axis the geometric mean of the ratios (here 0.5 and 2 on x give 1; 0.5 twice on yaw
    gives 0.5), the scene-runs lower on every axis, only scenes with blur or glints."""
    one = [1.0] * 6
    runs = {
        "a": [
            _scene_run("b", 0, [0.5, 0.9, 0.9, 0.9, 0.9, 0.5], one, blur=1.0),
            _scene_run("clean", 0, [9.0] * 6, one),  # no blur or glints: left out
            _scene_run("lost", 0, [], one, blur=1.0),  # a mode without RMS: named, not compared
        ],
        "b": [_scene_run("b", 1, [2.0, 0.9, 1.1, 0.9, 0.9, 0.5], one, glints=1.0)],
    }
    for d, rows in runs.items():
        (tmp_path / d).mkdir()
        (tmp_path / d / "results.json").write_text(json.dumps(rows))
    out = _main_json(
        "stereo_lines_gain", [tmp_path / "a", tmp_path / "b", "--out", tmp_path / "fig"], capsys
    )
    assert out["scene_runs"] == 2 and out["every_axis_lower"] == "1/2"
    assert out["every_axis_lower_runs"] == ["b s0"]
    assert out["left_out_lost_track"] == ["lost s0"]
    assert out["per_axis"]["x"]["geometric_mean_ratio"] == pytest.approx(1.0)
    assert out["per_axis"]["yaw"]["geometric_mean_ratio"] == pytest.approx(0.5)
    assert out["per_axis"]["z"]["lower"] == 1 and out["per_axis"]["y"]["lower"] == 2
    assert (tmp_path / "fig" / "lines_gain.png").stat().st_size > 0
    # a run of points + lines only cannot be read: the error names the file
    (tmp_path / "c").mkdir()
    rows = [{"scene": {"name": "b", "blur": 1.0}, "points+lines": {}}]
    (tmp_path / "c" / "results.json").write_text(json.dumps(rows))
    with pytest.raises(SystemExit, match=r"results\.json has no scene run in both modes"):
        load_bench("stereo_lines_gain").main([str(tmp_path / "c")])


def _budget_run(rule, n, position, attitude):
    return {
        "rule": rule,
        "N": n,
        "rms_position_mm": position,
        "rms_attitude_deg": attitude,
        "lost_frames": 0,
        "pose_cpu_ms": 10.0,
        "select_cpu_ms": 1.0,
        "map_cpu_ms": 20.0,
        "dop_rms_ratio": 2.0,
    }


def test_budget_bench_reads_several_seeds_together(tmp_path, capsys):
    """``--from-results`` of two noise seeds: the scene runs keep their seeds apart, and
    ``dop_against`` gives the geometric mean of dop's sums over random's and the runs where dop
    is lower."""
    files = []
    for seed, dop_x in enumerate([1.0, 4.0]):
        runs = [
            _budget_run("all", None, [1.0, 1.0, 1.0], [0.1, 0.1, 0.1]),
            _budget_run("dop", 30, [dop_x, 1.0, 1.0], [0.1, 0.1, 0.1]),
            _budget_run("random", 30, [4.0, 0.0, 0.0], [0.2, 0.2, 0.2]),
        ]
        scene = {"scene": {"name": "d1-clean-2m", "frames": 3, "seed": seed}, "runs": runs}
        scene["target"] = None
        f = tmp_path / f"s{seed}.json"
        f.write_text(json.dumps([scene]))
        files.append(str(f))
    out = _main_json("stereo_budget", ["--from-results", *files, "--out", tmp_path / "b"], capsys)
    assert set(out["per_scene"]) == {"d1-clean-2m s0", "d1-clean-2m s1"}
    vs = out["dop_against"]["random"]
    # position sums: dop 3 and 6 against random 4 and 4 -> ratios 0.75 and 1.5
    assert vs["position"]["geometric_mean_ratio"] == pytest.approx((0.75 * 1.5) ** 0.5, abs=1e-3)
    assert vs["position"]["dop_lower"] == "1/2"
    assert vs["attitude"]["geometric_mean_ratio"] == pytest.approx(0.5, abs=1e-3)
    assert vs["attitude"]["dop_lower"] == "2/2"
    assert "response" not in out["dop_against"]  # no response runs: nothing compared


def test_stereo_paired_base_rev_imports_a_revision_beside_the_working_tree(tmp_path):
    """``--base-rev``: the package at a git revision, renamed, imports beside the working tree's
    and rebuilds the working tree's options, rig and pose from its own classes (field by field,
    the same values); a revision git does not know is a ValueError that names it."""
    import subprocess

    import numpy as np

    bench = load_bench("stereo_paired")
    if subprocess.run(["git", "rev-parse", "HEAD"], cwd=bench.REPO, capture_output=True).returncode:
        pytest.skip("not a git checkout")
    name = bench.package_at("HEAD", tmp_path)
    try:
        import importlib

        from jaxpose.core.camera import PinholeCamera, StereoCamera
        from jaxpose.core.geometry import Pose
        from jaxpose.pipelines.stereo import TrackerOptions
        from jaxpose.vision.stereo_features import FeatureOptions

        other = importlib.import_module(name + ".pipelines.stereo")
        assert other.__file__.startswith(str(tmp_path))
        opts = TrackerOptions(window_points=123, features=FeatureOptions(n_points=777))
        got = bench._in_package(opts, name)
        assert type(got) is other.TrackerOptions and type(got) is not TrackerOptions
        assert got.window_points == 123 and got.features.n_points == 777
        cam = PinholeCamera(800.0, 801.0, 512.0, 384.0, width=1024, height=768)
        rig = bench._in_package(StereoCamera(cam, cam, np.eye(3), np.array([-0.3, 0, 0])), name)
        assert type(rig).__module__.startswith(name) and rig.left.width == 1024
        assert float(rig.left.fy) == 801.0 and float(rig.t_rl[0]) == -0.3
        pose = bench._in_package(Pose(np.eye(3), np.ones(3)), name)
        assert type(pose).__module__.startswith(name)
        with pytest.raises(ValueError, match="no-such-revision"):
            bench.package_at("no-such-revision", tmp_path / "x")
    finally:
        import sys

        sys.path.remove(str(tmp_path))
        for mod in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
            del sys.modules[mod]
