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
