"""The select-study runner: schema, determinism, resumption, two devices, independent re-check."""

import itertools
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from jaxpose.cli import main
from jaxpose.studies import selection as study

SMALL = dict(cases=6, seed=3, chunk_size=4, progress=False)
GROUPS = [(9, 5), (10, 6)]


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    res = study.run_study(study.Scenario(), GROUPS, out_dir=out, **SMALL)
    return out, res


def test_results_schema_and_ratios(small_run):
    _, res = small_run
    groups = res.results["groups"]
    assert [(g["n"], g["m"]) for g in groups] == GROUPS
    for g in groups:
        assert g["cases"] == SMALL["cases"]
        for key in ("pdop_ratio", "adop_ratio"):
            assert set(g[key]) == {"mean", "max"}
            assert g[key]["mean"] >= 1 - 1e-12 and g[key]["max"] >= g[key]["mean"]
        for key in ("pdop", "adop"):
            assert set(g[key]) == {"optimal_mean", "quasi_mean", "all_mean"}
            assert (
                g[key]["all_mean"] <= g[key]["optimal_mean"] <= g[key]["quasi_mean"] * (1 + 1e-12)
            )
        assert set(g["time_s"]) == {"optimal_per_case", "quasi_per_case"}
    assert res.results["scenario"]["range_m"] == study.Scenario().range_m


def test_optimum_against_independent_brute_force(small_run, tmp_path):
    """Re-check the dumped cases with NumPy only: DOPs from (points, R, t, K) and every subset."""
    _, res = small_run
    paths = study.write_outputs(res, tmp_path, dump_cases=True)
    assert {p.name for p in paths} >= {"results.json", "cases.npz", "fig9_10_timing.png"}
    z = np.load(tmp_path / "cases.npz")
    for n, m in GROUPS:
        pre = f"n{n}_m{m}/"
        for c in range(SMALL["cases"]):
            P, R, t, K = z[pre + "points_body"][c], z[pre + "R"][c], z[pre + "t"][c], z[pre + "K"]
            H = _numpy_H(P, R, t, K)
            best_p, best_a = np.inf, np.inf
            for idx in itertools.combinations(range(n), m):
                rows = np.ravel([[2 * i, 2 * i + 1] for i in idx])
                Q = np.linalg.inv(H[rows].T @ H[rows])
                best_p = min(best_p, np.sqrt(np.trace(Q[:3, :3])))
                best_a = min(best_a, np.sqrt(np.trace(Q[3:, 3:])))
            np.testing.assert_allclose(z[pre + "pdop_opt"][c], best_p, rtol=1e-7)
            np.testing.assert_allclose(z[pre + "adop_opt"][c], best_a, rtol=1e-7)
            idx = z[pre + "quasi_idx"][c]
            assert np.all(np.diff(idx) > 0)
            rows = np.ravel([[2 * i, 2 * i + 1] for i in idx])
            Q = np.linalg.inv(H[rows].T @ H[rows])
            np.testing.assert_allclose(
                z[pre + "pdop_quasi"][c], np.sqrt(np.trace(Q[:3, :3])), rtol=1e-7
            )


def _numpy_H(P, R, t, K, h=1e-6):
    """H by central differences of a NumPy projection over (t, xyz Euler angles)."""
    from scipy.spatial.transform import Rotation

    ang = Rotation.from_matrix(R).as_euler("XYZ")

    def pix(x):
        Rx = Rotation.from_euler("XYZ", x[3:]).as_matrix()
        c = P @ Rx.T + x[:3]
        return np.c_[
            K[0, 0] * c[:, 0] / c[:, 2] + K[0, 2], K[1, 1] * c[:, 1] / c[:, 2] + K[1, 2]
        ].ravel()

    x0 = np.r_[t, ang]
    return np.stack([(pix(x0 + h * e) - pix(x0 - h * e)) / (2 * h) for e in np.eye(6)], axis=1)


def test_same_seed_same_numbers_and_resume(small_run, monkeypatch):
    out, res = small_run
    calls = []
    real = study._run_chunk
    monkeypatch.setattr(study, "_run_chunk", lambda *a: calls.append(1) or real(*a))
    chunks = sorted((out / "chunks").glob("*.npz"))
    assert len(chunks) == 4  # 2 groups x 2 chunks of 4 (6 cases)
    chunks[-1].unlink()  # an interrupted run: the last chunk is missing
    again = study.run_study(study.Scenario(), GROUPS, out_dir=out, **SMALL)
    assert len(calls) == 1  # only the missing chunk was recomputed
    for key in res.cases[GROUPS[1]]:
        np.testing.assert_array_equal(again.cases[GROUPS[1]][key], res.cases[GROUPS[1]][key])
    fresh = study.run_study(study.Scenario(), GROUPS, **SMALL)  # no disk: recomputed from the seed
    for g in GROUPS:
        np.testing.assert_allclose(fresh.cases[g]["pdop_opt"], res.cases[g]["pdop_opt"], rtol=1e-12)
        np.testing.assert_array_equal(fresh.cases[g]["quasi_idx"], res.cases[g]["quasi_idx"])
    other = study.run_study(study.Scenario(range_m=20.0), GROUPS, out_dir=out, **SMALL)
    assert not np.allclose(other.cases[GROUPS[0]]["pdop_opt"], res.cases[GROUPS[0]]["pdop_opt"])


def test_two_devices_give_the_same_numbers(small_run, tmp_path):
    _, res = small_run
    code = (
        "import jax, json, sys; jax.config.update('jax_enable_x64', True);"
        "from jaxpose.studies import selection as s;"
        "assert len(jax.devices()) == 2, jax.devices();"
        f"r = s.run_study(s.Scenario(), {GROUPS!r}, cases=6, seed=3, chunk_size=4, progress=False);"
        "print(json.dumps({f'{n}_{m}': [c['pdop_opt'].tolist(), c['adop_opt'].tolist(),"
        " c['quasi_idx'].tolist()]"
        " for (n, m), c in r.cases.items()}))"
    )
    env = dict(
        os.environ,
        XLA_FLAGS=os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2",
        JAX_PLATFORMS="cpu",
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    two = json.loads(proc.stdout.strip().splitlines()[-1])
    for n, m in GROUPS:
        pd, ad, qi = two[f"{n}_{m}"]
        np.testing.assert_allclose(pd, res.cases[(n, m)]["pdop_opt"], rtol=1e-12)
        np.testing.assert_allclose(ad, res.cases[(n, m)]["adop_opt"], rtol=1e-12)
        np.testing.assert_array_equal(qi, res.cases[(n, m)]["quasi_idx"])


def test_cli_select_study(tmp_path, capsys):
    rc = main(
        [
            "select-study",
            "--n",
            "9",
            "--m",
            "5",
            "--cases",
            "3",
            "--out",
            str(tmp_path),
            "--no-progress",
            "--range-m",
            "8",
            "--attitude-deg",
            "10",
            "10",
            "10",
        ]
    )
    assert rc == 0
    data = json.loads((tmp_path / "results.json").read_text())
    assert data["scenario"]["range_m"] == 8 and data["scenario"]["attitude_deg"] == [10, 10, 10]
    assert "Table 4" in capsys.readouterr().out


def test_bad_study_options():
    with pytest.raises(ValueError, match="4 <= m <= n"):
        study.default_groups([6], [8])
    with pytest.raises(ValueError, match="cases"):
        study.run_study(study.Scenario(), [(8, 4)], cases=0, progress=False)
    assert main(["select-study", "--n", "5", "--m", "7", "--no-progress"]) == 2


def _one_error_line(capsys, command="select-study"):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"jaxpose {command}: error: ")
    return err[0]


@pytest.mark.parametrize(
    "argv, option",
    [
        (["--range-m", "0"], "--range-m"),
        (["--range-m", "-10"], "--range-m"),
        (["--range-m", "nan"], "--range-m"),
        (["--plane-size-m", "0"], "--plane-size-m"),
        (["--plane-size-m", "inf"], "--plane-size-m"),
        (["--focal-length-mm", "-5"], "--focal-length-mm"),
        (["--pixel-size-um", "0"], "--pixel-size-um"),
        (["--image-size", "0", "10"], "--image-size"),
        (["--attitude-deg", "10", "nan", "0"], "--attitude-deg"),
        (["--offset-m", "inf", "0"], "--offset-m"),
        (["--cases", "0"], "--cases"),
        (["--chunk-size", "-1"], "--chunk-size"),
        (["--seed", "-1"], "--seed"),
        (["--n", "18", "--m", "0"], "--m"),
    ],
)
def test_bad_scenario_options_are_refused_naming_the_option(argv, option, tmp_path, capsys):
    assert main(["select-study", *argv, "--out", str(tmp_path), "--no-progress"]) == 2
    assert option in _one_error_line(capsys)
    assert not (tmp_path / "results.json").exists()


@pytest.mark.parametrize(
    "field, value",
    [("range_m", 0.0), ("range_m", -10.0), ("plane_size_m", 0.0), ("sigma_px", -1.0)],
)
def test_scenario_refuses_bad_values_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        study.Scenario(**{field: value})


@pytest.mark.parametrize("random", [False, True])
def test_points_behind_the_camera_are_refused(random, tmp_path, capsys):
    # A 1 m square tilted by 80 deg at 0.3 m: its far edge is 0.3 - 0.5 sin 80 = -0.19 m deep
    # (random attitudes in [-80, 80] deg per axis: some of the 8 cases reach behind too).
    argv = ["--range-m", "0.3", "--attitude-deg", "0", "80", "0", "--n", "6", "--m", "4"]
    argv += ["--random-attitude", "--no-progress"] if random else []
    assert main(["select-study", *argv, "--cases", "8", "--out", str(tmp_path)]) == 2
    line = _one_error_line(capsys)
    assert "behind the camera" in line and "--range-m" in line


def test_a_search_too_large_is_refused_at_once(tmp_path, capsys):
    import time

    t0 = time.perf_counter()
    assert main(["select-study", "--n", "40", "--m", "20", "--cases", "1", "--out", str(tmp_path)])
    assert time.perf_counter() - t0 < 5
    line = _one_error_line(capsys)
    assert "C(40, 20)" in line and "--n" in line and f"{study.MAX_SUBSETS_PER_CASE:.0e}" in line
    study.check_group(25, 12)  # 5.2e6 subsets: under the limit
    with pytest.raises(ValueError, match="C\\(26, 13\\)"):
        study.check_group(26, 13)


def test_a_truncated_chunk_is_recomputed_with_a_warning(tmp_path, capsys):
    argv = ["select-study", "--n", "9", "--m", "5", "--cases", "6", "--chunk-size", "3"]
    argv += ["--seed", "3", "--out", str(tmp_path), "--no-progress", "--no-figures"]
    assert main(argv) == 0
    first = json.loads((tmp_path / "results.json").read_text())
    chunk = sorted((tmp_path / "chunks").glob("*.npz"))[-1]
    data = chunk.read_bytes()
    chunk.write_bytes(data[: len(data) // 2])  # a run killed while writing (or a bad copy)
    capsys.readouterr()
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert f"jaxpose select-study: warning: chunk file {chunk}" in err and "recomput" in err
    again = json.loads((tmp_path / "results.json").read_text())
    assert again["groups"][0]["pdop_ratio"] == first["groups"][0]["pdop_ratio"]
    with np.load(chunk) as z:  # rewritten whole
        assert "pdop_opt" in z.files


def test_failed_cases_give_null_statistics_never_nan():
    inf = np.inf
    group = {
        "pdop_quasi": np.array([2.0, inf]),
        "pdop_opt": np.array([1.0, inf]),
        "adop_quasi": np.array([3.0, inf]),
        "adop_opt": np.array([2.0, inf]),
        "pdop_all": np.array([0.5, np.nan]),
        "adop_all": np.array([1.0, np.nan]),
        "status": np.array([0, 3]),
    }
    failed = {k: v[1:] for k, v in group.items()}
    res = study._summarise(
        study.Scenario(),
        0,
        {(18, 8): group, (18, 9): failed},
        {(18, 8): [1, 1], (18, 9): [1, 1]},
        1,
    )
    text = json.dumps(res, allow_nan=False)  # raises on NaN or inf
    g8, g9 = res["groups"]
    assert g8["pdop_ratio"] == {"mean": 2.0, "max": 2.0} and g8["failed_cases"] == 1
    assert g9["pdop_ratio"] == {"mean": None, "max": None} and g9["failed_cases"] == 1
    assert "NaN" not in text and "Infinity" not in text
    assert "Table 4" in study.format_report(res)


@pytest.mark.parametrize(
    "groups, panels",
    [
        (study.TABLE4_GROUPS, ["n"]),
        (study.PAPER_GROUPS, ["n", "m"]),
        ([(18, 8)], [""]),
        ([(9, 5), (10, 6)], [""]),
        ([(12, 8), (14, 8), (9, 5)], ["n", ""]),
    ],
)
def test_timing_figure_plots_what_ran(groups, panels):
    from jaxpose.studies._selection_figures import _timing_panels

    fake = [{"n": n, "m": m} for n, m in groups]
    got = _timing_panels(fake)
    assert [key for _, key, _ in got] == panels
    shown = sorted((g["n"], g["m"]) for gs, _, _ in got for g in gs)
    assert set(shown) == set(groups)  # every group that ran is on a panel


def test_ratio_histogram_bins_fit_the_data():
    from jaxpose.studies._selection_figures import _ratio_bins

    bins = _ratio_bins([np.array([1.0, 1.3]), np.array([1.1, 1.2])])
    top = np.quantile([1.0, 1.3], 0.99)
    assert bins[0] == 1.0 and top <= bins[-1] < top + 2 * (bins[1] - bins[0])
    assert 30 <= len(bins) <= 45
    # One far outlier does not stretch the axis: it lands in the last bin.
    spread = np.r_[np.linspace(1.0, 1.5, 999), 4.3]
    assert _ratio_bins([spread])[-1] < 1.6
