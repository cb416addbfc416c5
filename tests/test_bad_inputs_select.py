"""Bad input to the selection functions and to ``jaxpose select-study`` (audit rows S4, S5, S10,
S16, H1 and U17): each raises a ``ValueError`` naming the argument, or exits 2 naming the option,
and the valid calls next to them give what they gave before."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_bad_inputs import _named, _run_cli

import jaxpose as jp
from jaxpose import PinholeCamera, Pose
from jaxpose.studies import selection as study
from jaxpose.studies._selection_plan import _case_bytes

jax.config.update("jax_enable_x64", True)

# jaxtyping's test-time hook would meet a badly typed argument (rtol="1e-8", heuristic="no") with
# its own TypeCheckError before the package's ValueError; a user sees the package's.
typecheck_off = pytest.mark.typecheck_off

CAM = PinholeCamera.from_K([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
POSE = Pose.from_euler(jnp.array([0.1, 0.2, 0.3]), jnp.array([0.1, -0.1, 5.0]))
P = jnp.asarray(np.random.default_rng(0).uniform(-1, 1, (10, 3)))
P16 = jnp.asarray(np.random.default_rng(2).uniform(-1, 1, (16, 3)))


def _blocks(points=P):
    return jp.information_blocks(points, POSE, CAM)


def _raises(fn, *names):
    with pytest.raises(ValueError) as err:
        fn()
    for name in names:
        assert _named(name, str(err.value)), f"{name!r} not named in: {err.value}"
    return str(err.value)


def _refused(argv, capsys, *options):
    code, _, err = _run_cli(argv, capsys)
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert code == 2, f"exit {code}; stderr: {err[-2000:]}"
    assert "Traceback" not in err, err
    assert len(lines) == 1 and lines[0].startswith("jaxpose select-study: error: "), lines
    for option in options:
        assert _named(option, lines[0]), f"{option!r} not named in: {lines[0]}"
    return lines[0]


def _study(tmp_path, *argv):
    return [
        "select-study",
        "--n",
        "8",
        "--m",
        "5",
        "--cases",
        "2",
        "--no-figures",
        "--no-progress",
        "--out",
        tmp_path / "out",
        *argv,
    ]


# --------------------------------------------------------------------- S4: branch_and_bound rtol


@typecheck_off
@pytest.mark.parametrize("rtol", [-10.0, -1e-12, float("nan"), float("inf"), "1e-8", True])
def test_bnb_refuses_a_bad_rtol(rtol):
    _raises(lambda: jp.select.branch_and_bound(_blocks(P16), 6, rtol=rtol, heuristic=False), "rtol")


@typecheck_off
@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"relax_iters": 2.5}, "relax_iters"),
        ({"relax_iters": True}, "relax_iters"),
        ({"relax_iters": 0}, "relax_iters"),
        ({"max_nodes": 10**12}, "max_nodes"),
        ({"max_nodes": 1e6}, "max_nodes"),
        ({"max_nodes": -1}, "max_nodes"),
        ({"heuristic": "no"}, "heuristic"),
        ({"heuristic": None}, "heuristic"),
    ],
)
def test_bnb_refuses_bad_counts_and_flags(kwargs, name):
    _raises(lambda: jp.select.branch_and_bound(_blocks(P16), 6, **kwargs), name)


@pytest.mark.parametrize("seed", [2, 3])
def test_bnb_with_rtol_zero_is_the_exhaustive_optimum(seed):
    blocks = _blocks(jnp.asarray(np.random.default_rng(seed).uniform(-1, 1, (16, 3))))
    best = jp.select.exhaustive(blocks, 6)
    for rtol in (0.0, 0, np.float64(1e-9), None):
        res = jp.select.branch_and_bound(blocks, 6, rtol=rtol, heuristic=False)
        assert int(res.status) == 0
        np.testing.assert_array_equal(np.asarray(res.idx), np.sort(np.asarray(best.pdop_idx)))
        np.testing.assert_allclose(float(res.value), float(best.pdop), rtol=1e-12)


# --------------------------------------------------------------------- S5: greedy mask


@pytest.mark.parametrize("valid, m", [(4, 6), (0, 4), (5, 6)])
def test_greedy_refuses_a_mask_leaving_fewer_than_m(valid, m):
    mask = jnp.arange(10) < valid
    message = _raises(lambda: jp.select.greedy(_blocks(), m, mask=mask), "mask", "m")
    assert "too few valid points" in message
    # the same wording as the other selectors
    _raises(lambda: jp.select.quasi_optimal(POSE.apply(P), m, mask=mask), "mask", "m")
    _raises(lambda: jp.select_features(P, POSE, CAM, m, mask=mask), "mask", "m")


def test_greedy_with_exactly_m_valid_points_keeps_them():
    mask = np.zeros(10, bool)
    mask[[1, 3, 4, 7, 8, 9]] = True
    idx = jp.select.greedy(_blocks(), 6, mask=mask)
    np.testing.assert_array_equal(np.asarray(idx), [1, 3, 4, 7, 8, 9])
    # more valid points than m: the selection stays among them
    idx = np.asarray(jp.select.greedy(_blocks(), 5, mask=mask))
    assert set(idx.tolist()) <= {1, 3, 4, 7, 8, 9} and len(set(idx.tolist())) == 5
    # a traced mask cannot be looked at: no error, deterministic indices (documented)
    traced = jax.jit(lambda mk: jp.select.greedy(_blocks(), 6, mask=mk))(jnp.asarray(mask))
    np.testing.assert_array_equal(np.asarray(traced), [1, 3, 4, 7, 8, 9])


# --------------------------------------------------------------------- S10: subset_dop


@pytest.mark.parametrize("idx", [[0, 0, 1, 2], [3, 1, 3, 5, 7], [9, 9, 9, 9]])
def test_subset_dop_refuses_repeated_indices(idx):
    message = _raises(lambda: jp.select.subset_dop(_blocks(), jnp.array(idx)), "idx")
    assert "distinct" in message
    # traced: inf, as for an index out of range (a point is never counted twice)
    pdop, adop = jax.jit(jp.select.subset_dop)(_blocks(), jnp.array(idx))
    assert float(pdop) == np.inf and float(adop) == np.inf


@pytest.mark.parametrize("idx", [[0, 1, 2], [5], []])
def test_subset_dop_refuses_fewer_than_four_indices(idx):
    idx = jnp.array(idx, dtype=jnp.int32)
    _raises(lambda: jp.select.subset_dop(_blocks(), idx), "idx")
    _raises(lambda: jax.jit(jp.select.subset_dop)(_blocks(), idx), "idx")  # a shape: traced too
    # consistent with jp.dop, which reports TOO_FEW_POINTS for the same points
    if idx.size:
        assert int(jp.dop(P[idx], POSE, CAM, throw=False).status) == jp.Status.TOO_FEW_POINTS


@pytest.mark.parametrize("idx", [[0, 1, 2, 3], [9, 2, 5, 7, 1]])
def test_subset_dop_of_distinct_indices_is_the_dop_of_those_points(idx):
    pdop, adop = jp.select.subset_dop(_blocks(), jnp.array(idx))
    ref = jp.dop(P[jnp.array(idx)], POSE, CAM)
    np.testing.assert_allclose(float(pdop), float(ref.pdop), rtol=1e-9)
    np.testing.assert_allclose(float(adop), float(ref.adop), rtol=1e-9)


# --------------------------------------------------------------------- S16: features off the image


@pytest.mark.parametrize(
    "argv",
    [
        ["--image-size", "4", "4"],
        ["--offset-m", "100", "0"],
        ["--image-size", "64", "64", "--range-m", "3"],
        ["--image-size", "4", "4", "--random-attitude"],
    ],
)
def test_study_refuses_features_outside_the_image(argv, tmp_path, capsys):
    line = _refused(_study(tmp_path, *argv), capsys, "--image-size", "--offset-m")
    assert "features fall outside the image" in line
    assert not (tmp_path / "out" / "results.json").exists()


@pytest.mark.parametrize(
    "scenario",
    [study.Scenario(image_size=(4, 4)), study.Scenario(offset_x_m=0.0, offset_y_m=-100.0)],
)
def test_run_study_refuses_features_outside_the_image(scenario):
    _raises(lambda: study.run_study(scenario, [(6, 4)], cases=2, progress=False), "--image-size")


def test_study_with_part_of_the_square_outside_warns(tmp_path, capsys):
    # docs/selection.md's 5 m row: about 2.4 % of the square is off the 2048 x 2048 sensor.
    code, _, err = _run_cli(_study(tmp_path, "--range-m", "5"), capsys)
    assert code == 0, err[-2000:]
    warnings = [ln for ln in err.splitlines() if ": warning: " in ln]
    assert len(warnings) == 1 and "--image-size" in warnings[0], err


def test_default_study_is_unchanged_and_quiet(tmp_path, capsys):
    code, out, err = _run_cli(_study(tmp_path), capsys)
    assert code == 0, err[-2000:]
    assert "warning" not in err and "Table 4" in out
    res = study.run_study(study.Scenario(), [(8, 5)], cases=2, progress=False)
    again = study.run_study(
        study.Scenario(image_size=(4096, 4096)), [(8, 5)], cases=2, progress=False
    )
    # the sensor size sets only the principal point: the DOPs do not depend on it
    np.testing.assert_allclose(
        res.cases[(8, 5)]["pdop_opt"], again.cases[(8, 5)]["pdop_opt"], rtol=1e-12
    )


# --------------------------------------------------------------------- H1: unreasonable --cases


@pytest.mark.parametrize(
    "argv, limit",
    [
        (["--cases", "1000000000"], "MAX_STUDY_BYTES"),
        (["--cases", "3000000"], "MAX_STUDY_BYTES"),
        (["--n", "25", "--m", "12", "--cases", "100000"], "MAX_STUDY_SUBSETS"),
    ],
)
def test_study_refuses_an_unreasonable_number_of_cases_at_once(argv, limit, tmp_path, capsys):
    t0 = time.perf_counter()
    line = _refused(_study(tmp_path, *argv), capsys, "--cases")
    assert time.perf_counter() - t0 < 5
    assert limit in line
    assert not (tmp_path / "out" / "chunks").exists()


def test_check_plan_limits():
    study.check_plan(study.PAPER_GROUPS, 1000)  # the paper's study
    study.check_plan([(8, 5)], study.MAX_STUDY_BYTES // _case_bytes(8, 5))
    for groups, cases in [([(8, 5)], 10**9), (study.PAPER_GROUPS, 10**5), ([(25, 12)], 10**5)]:
        _raises(lambda g=groups, c=cases: study.check_plan(g, c), "--cases")
    _raises(lambda: study.run_study(study.Scenario(), [(8, 5)], cases=10**9), "--cases")


# --------------------------------------------------------------------- U17: --sequence


@pytest.mark.parametrize("sequence", ["XXY", "xyZ", "XY", "abc"])
def test_study_names_sequence(sequence, tmp_path, capsys):
    _refused(_study(tmp_path, "--sequence", sequence), capsys, "--sequence")
    _raises(lambda: study.Scenario(sequence=sequence), "--sequence", "Scenario.sequence")
