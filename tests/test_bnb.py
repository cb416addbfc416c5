"""Branch and bound for the DOP-optimal subset: exact (brute force), valid bounds, bad inputs."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from bnb_numpy import branch_and_bound_numpy
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.dilution import information_blocks
from jaxpose.core.geometry import Pose
from jaxpose.core.select import bnb as bnb_module
from jaxpose.core.select import branch_and_bound
from jaxpose.core.status import Status

SEL = {"pdop": slice(0, 3), "adop": slice(3, 6)}
CAMERA = PinholeCamera.from_focal_length(0.0165, 5.5e-6, (2048, 2048))  # fx = 3000 px


def make_blocks(n, seed, *, planar=True, weighted=False):
    """Paper-like random case: features in a 1 m square (or a 1 m cube), ~10 m range, tilted."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-0.5, 0.5, (n, 3))
    if planar:
        points[:, 2] = 0.0
    angles = np.deg2rad(rng.uniform(-30, 30, 3))
    t = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(6.0, 14.0)])
    pose = Pose.from_euler(jnp.asarray(angles), jnp.asarray(t))
    sigma = jnp.asarray(rng.uniform(0.5, 2.0, n)) if weighted else None
    return np.asarray(information_blocks(jnp.asarray(points), pose, CAMERA, sigma=sigma))


def brute_force(blocks, m, criterion):
    """Every m-subset with np.linalg.inv; returns (best idx, best DOP, second-best DOP)."""
    n = len(blocks)
    subsets = np.array(list(itertools.combinations(range(n), m)))
    M = blocks[subsets].sum(axis=1)
    d = np.sqrt(np.abs(np.diagonal(M, axis1=1, axis2=2))) + 1e-300
    S = M / (d[:, :, None] * d[:, None, :])
    evals = np.linalg.eigvalsh(S)
    ok = evals[:, 0] > 1e3 * np.finfo(float).eps * evals[:, -1]
    Q = np.linalg.inv(np.where(ok[:, None, None], M, np.eye(6)))
    s = SEL[criterion]
    vals = np.where(ok, np.sqrt(np.trace(Q[:, s, s], axis1=1, axis2=2)), np.inf)
    order = np.argsort(vals)
    second = vals[order[1]] if len(vals) > 1 else np.inf
    return subsets[order[0]], vals[order[0]], second


def check_against_brute(blocks, m, criterion, **kw):
    res = branch_and_bound(blocks, m, criterion=criterion, **kw)
    idx, best, second = brute_force(blocks, m, criterion)
    assert int(res.status) == Status.OK
    np.testing.assert_allclose(float(res.value), best, rtol=1e-9)
    if second > best * (1 + 1e-8):  # unique optimum: the same subset
        np.testing.assert_array_equal(np.asarray(res.idx), idx)
    assert np.all(np.diff(np.asarray(res.idx)) > 0)
    return res


N = 10  # one size for the whole file: the search compiles once per n


@pytest.mark.parametrize("criterion", ["pdop", "adop"])
@pytest.mark.parametrize("seed", range(8))
def test_equals_brute_force(criterion, seed):
    blocks = make_blocks(N, seed, planar=seed % 3 != 0, weighted=seed % 2 == 1)
    nodes = []
    for m in (4, 5, 6, 8, N):
        nodes.append(int(check_against_brute(blocks, m, criterion).nodes))
    assert nodes[1] < 252 and nodes[2] < 210  # it prunes: fewer nodes than C(10, 5), C(10, 6)


def test_m_equals_n_returns_every_point():
    blocks = make_blocks(N, 3)
    res = branch_and_bound(blocks, N)
    np.testing.assert_array_equal(np.asarray(res.idx), np.arange(N))
    assert int(res.nodes) == 1


@pytest.mark.parametrize("bound", ["monotone", "linear"])
def test_weaker_bounds_are_exact_too(bound):
    blocks = make_blocks(N, 11)
    for m in (4, 6):
        check_against_brute(blocks, m, "pdop", bound=bound)
    # Without the heuristic incumbent the tree alone still finds the optimum.
    check_against_brute(blocks, 5, "adop", bound=bound, heuristic=False)


def test_without_heuristic_and_numpy_host_loop_agree():
    blocks = make_blocks(N, 7)
    for criterion in ("pdop", "adop"):
        res = check_against_brute(blocks, 6, criterion, heuristic=False)
        assert int(res.status) == Status.OK
        res = branch_and_bound(blocks, 6, criterion=criterion)
        idx, value, nodes, iters = branch_and_bound_numpy(blocks, 6, criterion=criterion)
        np.testing.assert_array_equal(idx, np.asarray(res.idx))
        np.testing.assert_allclose(value, float(res.value), rtol=1e-9)
        assert (nodes, iters) == (int(res.nodes), int(res.iterations))


def test_singular_subsets_are_skipped():
    # Six of ten points on one line: many 4- and 5-subsets are singular (collinear points).
    rng = np.random.default_rng(5)
    line = np.stack([np.linspace(-0.5, 0.5, 6), 0.3 * np.linspace(-0.5, 0.5, 6), np.zeros(6)], 1)
    other = np.concatenate([rng.uniform(-0.5, 0.5, (4, 2)), np.zeros((4, 1))], 1)
    points = np.concatenate([line, other])
    pose = Pose.from_euler(jnp.deg2rad(jnp.array([20.0, 20.0, 20.0])), jnp.array([0.0, 0.0, 10.0]))
    blocks = np.asarray(information_blocks(jnp.asarray(points), pose, CAMERA))
    for m in (4, 5):
        for criterion in ("pdop", "adop"):
            check_against_brute(blocks, m, criterion)


def test_all_subsets_singular_gives_status_and_error():
    points = np.stack([np.linspace(-0.5, 0.5, N), np.zeros(N), np.zeros(N)], 1)  # collinear
    pose = Pose.from_euler(jnp.deg2rad(jnp.array([20.0, 20.0, 20.0])), jnp.array([0.0, 0.0, 10.0]))
    blocks = np.asarray(information_blocks(jnp.asarray(points), pose, CAMERA))
    res = branch_and_bound(blocks, 5, throw=False)
    assert int(res.status) == Status.SINGULAR and np.isinf(float(res.value))
    with pytest.raises(ValueError, match="singular"):
        branch_and_bound(blocks, 5)


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_bad_inputs():
    blocks = make_blocks(N, 1)
    with pytest.raises(ValueError, match="cannot select m = "):
        branch_and_bound(blocks, N + 1)
    with pytest.raises(ValueError, match="at least 4 points"):
        branch_and_bound(blocks, 3)
    with pytest.raises(ValueError, match="shape"):
        branch_and_bound(blocks[:, :3, :3], 4)
    with pytest.raises(ValueError, match="criterion"):
        branch_and_bound(blocks, 4, criterion="gdop")
    with pytest.raises(ValueError, match="bound"):
        branch_and_bound(blocks, 4, bound="none")
    bad = blocks.copy()
    bad[2, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        branch_and_bound(bad, 5)
    res = branch_and_bound(bad, 5, throw=False)
    assert int(res.status) == Status.NONFINITE_INPUT and np.isinf(float(res.value))
    assert not np.any(np.isnan(np.asarray(res.value)))


def test_node_budget_gives_not_converged():
    blocks = make_blocks(N, 2)
    res = branch_and_bound(blocks, 5, heuristic=False, max_nodes=3, throw=False)
    assert int(res.status) == Status.NOT_CONVERGED
    assert int(res.nodes) <= 3


def test_vmap_and_jit_with_a_bad_lane():
    batch = np.stack([make_blocks(N, s) for s in range(3)])
    batch[1, 0, 0, 0] = np.nan
    run = jax.jit(jax.vmap(lambda b: branch_and_bound(b, 5, throw=False)))
    res = run(jnp.asarray(batch))
    expected = [Status.OK, Status.NONFINITE_INPUT, Status.OK]
    np.testing.assert_array_equal(np.asarray(res.status), expected)
    for lane in (0, 2):
        one = branch_and_bound(batch[lane], 5)
        np.testing.assert_array_equal(np.asarray(res.idx[lane]), np.asarray(one.idx))
        np.testing.assert_allclose(float(res.value[lane]), float(one.value), rtol=1e-12)


# ----------------------------------------------------------------------------- the bound is valid
_N = N
_CASES = [make_blocks(_N, 200 + s, planar=s % 2 == 0) for s in range(4)]


def _scaled(blocks, criterion):
    dtot = np.diagonal(blocks.sum(0))
    sc = 1.0 / np.sqrt(dtot)
    A = blocks * sc[None, :, None] * sc[None, None, :]
    wsel = np.zeros(6)
    wsel[SEL[criterion]] = 1.0 / dtot[SEL[criterion]]
    return A, wsel


@jax.jit
def _bound(A, MC, R, r, wsel, threshold, bound):
    Af = A.reshape(A.shape[0], 36)
    return bnb_module._node_bound(A, Af, MC, R, r, wsel, threshold, bound, 16)[0]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    case=st.integers(0, len(_CASES) - 1),
    criterion=st.sampled_from(["pdop", "adop"]),
    m=st.integers(4, _N - 1),
    split=st.integers(0, 2**_N - 1),
    k=st.integers(0, _N - 1),
    factor=st.floats(0.5, 3.0),
    data=st.data(),
)
def test_bound_never_exceeds_any_completion(case, criterion, m, split, k, factor, data):
    A, wsel = _scaled(_CASES[case], criterion)
    decided = np.arange(_N) < k
    chosen = decided & (((split >> np.arange(_N)) & 1) == 1)
    R = ~decided
    r = m - int(chosen.sum())
    if r < 0 or r > R.sum():
        return  # no completion: not a node of the tree
    free = np.flatnonzero(R)
    fixed = np.flatnonzero(chosen).tolist()
    completions = [fixed + list(c) for c in itertools.combinations(free, r)]

    def phi(S):
        M = A[S].sum(0)
        if np.linalg.cond(M) > 1e12:
            return np.inf
        return float(np.sum(wsel * np.diagonal(np.linalg.inv(M))))

    values = np.array([phi(S) for S in completions])
    best = values.min()
    # The search calls the bound with the incumbent as threshold; any threshold must be safe.
    threshold = best * factor if np.isfinite(best) else 1.0
    MC = A[chosen].sum(0)
    args = [jnp.asarray(x) for x in (A, MC, R, np.int32(r), wsel, threshold)]
    lbs = {b: _bound(*args, np.int32(i)) for i, b in enumerate(bnb_module._BOUNDS)}
    for name, lb in lbs.items():
        lb = float(lb)
        assert lb <= best * (1 + 1e-9), (name, lb, best)
        # ... hence below every completion, e.g. a random one:
        pick = data.draw(st.integers(0, len(values) - 1))
        assert lb <= values[pick] * (1 + 1e-9)
    if np.isfinite(best):
        # The tangent-plane bound at M_U is never weaker than the monotone one.
        assert float(lbs["linear"]) >= float(lbs["monotone"]) * (1 - 1e-9)
