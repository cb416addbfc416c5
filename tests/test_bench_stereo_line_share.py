"""The per-axis variance ratio of ``bench/stereo_line_share.py`` against closed forms."""

import numpy as np
from bench_module import load_bench

bench = load_bench("stereo_line_share")


def test_independent_axes_give_the_ratio_of_their_informations():
    """Rows that each measure one axis: the variance of an axis is one over its summed squares,
    so the ratio is ``a / (a + b)`` for point information ``a`` and line information ``b``."""
    a = np.array([4.0, 1.0, 9.0, 2.0, 5.0, 3.0])
    b = np.array([0.0, 1.0, 3.0, 6.0, 0.5, 1.0])
    rows = np.concatenate([np.diag(np.sqrt(a)), np.diag(np.sqrt(b))])[:, None, :]
    got = bench.variance_ratios(rows, 6)
    assert np.allclose(got, a / (a + b))


def test_correlated_rows_match_the_inverse_of_the_summed_information():
    rng = np.random.default_rng(0)
    rows = rng.normal(size=(40, 4, 6))
    got = bench.variance_ratios(rows, 30)
    J_p, J = rows[:30].reshape(-1, 6), rows.reshape(-1, 6)
    want = np.diag(np.linalg.inv(J.T @ J)) / np.diag(np.linalg.inv(J_p.T @ J_p))
    assert np.allclose(got, want)
    assert (got <= 1 + 1e-12).all()  # more rows never raise a variance


def test_compare_must_hold_the_same_scenes_and_seeds(tmp_path, capsys):
    """A ``--compare`` log of other runs is a usage error before anything is tracked."""
    import json

    import pytest

    log = tmp_path / "earlier.log"
    runs = [{"scene": "d1-clean-2m", "seed": 0, "points": 1, "lines": 1, "variance_ratio": {}}]
    log.write_text("| a table |\n" + json.dumps({"frames": 16, "options": [], "runs": runs}))
    with pytest.raises(SystemExit) as err:
        bench.main(["d1-clean-2m", "--seeds", "0", "1", "--compare", str(log)])
    assert err.value.code == 2
    assert "scenes and seeds" in capsys.readouterr().err
    log.write_text("not json")
    with pytest.raises(SystemExit):
        bench.main(["d1-clean-2m", "--compare", str(log)])
    assert "not an output of this script" in capsys.readouterr().err


def test_the_figure_draws_one_panel_a_run(tmp_path):
    ratio = dict(zip(bench.AXES, [0.9, 0.95, 0.99, 0.98, 0.9, 0.85], strict=True))
    runs = [
        {"scene": f"d{i}-x", "seed": 0, "points": 300, "lines": 5, "variance_ratio": ratio}
        for i in (1, 2)
    ]
    path = tmp_path / "share.png"
    bench.figure([("defaults", runs), ("other", runs)], path)
    assert path.stat().st_size > 1000


def test_the_chaser_position_ratio_maps_the_covariance_and_matches_finite_differences():
    rng = np.random.default_rng(1)
    rows = rng.normal(size=(30, 4, 6))
    G = rng.normal(size=(3, 6))
    J_p, J = rows[:20].reshape(-1, 6), rows.reshape(-1, 6)
    Q_p, Q = np.linalg.inv(J_p.T @ J_p), np.linalg.inv(J.T @ J)
    want = np.diag(G @ Q @ G.T) / np.diag(G @ Q_p @ G.T)
    assert np.allclose(bench.variance_ratios(rows, 20, G), want)
    # chaser_map: the derivative of c = -R^T t under R <- exp([e]) R, t <- t + dt
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    t = rng.normal(size=3)
    h = 1e-6
    num = np.zeros((3, 6))
    for k in range(6):
        dx = np.zeros(6)
        dx[k] = h
        R2 = Rotation.from_rotvec(dx[3:]).as_matrix() @ R
        num[:, k] = (-R2.T @ (t + dx[:3]) + R.T @ t) / h
    assert np.allclose(bench.chaser_map(R, t), num, atol=1e-5)
