"""Feature budget of the stereo tracker (jaxpose.pipelines.stereo.budget): the selection rules on
small synthetic problems against brute force, option checks, and short tracking runs."""

import itertools
import json
from importlib import metadata
from types import SimpleNamespace

import numpy as np
import pytest

from jaxpose import PinholeCamera, Pose, information_blocks, line_information_blocks
from jaxpose.core.status import Status
from jaxpose.pipelines.stereo import StereoTracker, TrackerOptions
from jaxpose.pipelines.stereo import budget as B
from jaxpose.pipelines.stereo.keyframes import FrameStereo
from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence

CAM = PinholeCamera(600.0, 600.0, 319.5, 239.5, width=640, height=480)
POSE = Pose.from_euler(np.radians([10.0, -20.0, 30.0]), np.array([0.05, -0.02, 2.0]))
SHIFT = np.array([0.3, -0.1, 0.05])  # a right camera: the body points shifted (R^T t_rl)


def _problem(n_p=14, n_l=6, seed=0):
    rng = np.random.default_rng(seed)
    P = rng.uniform(-0.4, 0.4, (n_p, 3))
    S = rng.uniform(-0.4, 0.4, (n_l, 2, 3))
    w_p = np.c_[np.full(n_p, 1.0), (rng.uniform(size=n_p) < 0.5) / 0.8]  # sigma 1 and 0.8 px
    w_l = np.c_[np.full(n_l, 1 / 1.5), (rng.uniform(size=n_l) < 0.5) / 1.5]
    rows = B.feature_rows(P, P + SHIFT, S, S + SHIFT, POSE, CAM, w_p, w_l)
    return P, S, w_p, w_l, np.asarray(rows)


def _chaser_jacobian(t0, R0, eps=1e-6):
    """d(chaser position)/d(dt, d) by finite differences (independent of criterion_weight): the
    chaser c = -R^T t, R = exp(d) R0, t = t0 + dt."""
    G = np.zeros((3, 6))
    for k in range(6):
        dx = np.zeros(6)
        dx[k] = eps
        R = np.asarray(Pose.from_rotvec(dx[3:], np.zeros(3)).R) @ R0
        G[:, k] = (-R.T @ (t0 + dx[:3]) + R0.T @ t0) / eps
    return G


G_POSE = _chaser_jacobian(np.asarray(POSE.t, float), np.asarray(POSE.R, float))


def _criterion(blocks, idx, arm):
    """Chaser position variance + arm^2 attitude variance of a subset."""
    Q = np.linalg.inv(blocks[list(idx)].sum(0))
    return np.trace(G_POSE @ Q @ G_POSE.T) + arm**2 * np.trace(Q[3:, 3:])


def test_feature_blocks_are_the_point_and_line_information_blocks():
    """rows^T rows of a feature = information_blocks / line_information_blocks of its left
    observation plus (with a stereo match) of its right one, tangent state."""
    P, S, w_p, w_l, rows = _problem()
    kw = dict(parameterization="tangent")
    ref_p = np.zeros((len(P), 6, 6))
    ref_l = np.zeros((len(S), 6, 6))
    for col, shift in ((0, 0.0), (1, SHIFT)):
        on_p, on_l = w_p[:, col] > 0, w_l[:, col] > 0
        sp = 1 / np.where(on_p, w_p[:, col], 1.0)
        sl = 1 / np.where(on_l, w_l[:, col], 1.0)
        ref_p += np.asarray(information_blocks(P + shift, POSE, CAM, sigma=sp, mask=on_p, **kw))
        ref_l += np.asarray(
            line_information_blocks(S + shift, POSE, CAM, sigma=sl, mask=on_l, **kw)
        )
    got = np.einsum("nki,nkj->nij", rows, rows)
    np.testing.assert_allclose(got, np.r_[ref_p, ref_l], rtol=1e-9, atol=1e-9 * np.abs(got).max())


def test_exact_path_equals_brute_force():
    P, S, w_p, w_l, rows = _problem(n_p=7, n_l=3, seed=1)
    blocks = np.einsum("nki,nkj->nij", rows, rows)
    arm = 0.3
    n = len(blocks)
    best = min(itertools.combinations(range(n), 6), key=lambda s: _criterion(blocks, s, arm))
    got = B.select_dop(rows, np.ones(n, bool), 6, B.criterion_weight(arm, POSE.t))
    assert tuple(got) == best


def test_greedy_selection_near_brute_force_and_better_than_random(monkeypatch):
    """Forced greedy (no enumeration): N distinct valid indices, a criterion within 10 % of the
    brute-force optimum and no worse than the best of 200 random subsets; padding never picked."""
    monkeypatch.setattr(B, "EXACT_SUBSETS", 0)
    P, S, w_p, w_l, rows = _problem(n_p=10, n_l=5, seed=2)
    rows = np.concatenate([rows, np.ones((3, 4, 6))])  # three padded rows, marked invalid
    valid = np.r_[np.ones(15, bool), np.zeros(3, bool)]
    blocks = np.einsum("nki,nkj->nij", rows, rows)
    arm, N = 0.25, 7
    W = B.criterion_weight(arm, POSE.t)
    got = B.select_dop(rows, valid, N, W)
    assert len(got) == N and len(set(got.tolist())) == N and np.all(got < 15)
    crit = _criterion(blocks, got, arm)
    opt = min(_criterion(blocks, s, arm) for s in itertools.combinations(range(15), N))
    assert crit <= 1.1 * opt
    rng = np.random.default_rng(0)
    rand = [_criterion(blocks, rng.choice(15, N, replace=False), arm) for _ in range(200)]
    assert crit <= min(rand)
    assert B.budget_criterion(blocks[got].sum(0), W) == pytest.approx(crit, rel=1e-5)


def test_fewer_candidates_than_the_budget_keeps_all():
    _, _, _, _, rows = _problem(n_p=4, n_l=2)
    valid = np.array([True, False, True, True, True, False])
    W = B.criterion_weight(0.3)
    np.testing.assert_array_equal(B.select_dop(rows, valid, 10, W), [0, 2, 3, 4])


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(feature_budget=3), "feature_budget"),
        (dict(feature_budget=20.0), "feature_budget"),
        (dict(feature_budget=True), "feature_budget"),
        (dict(feature_budget="30"), "feature_budget"),
        (dict(budget_rule="best"), "budget_rule"),
        (dict(feature_budget=30, budget_rule=None), "budget_rule"),
        (dict(budget_noise="blur"), "budget_noise"),
        (dict(budget_subsample=0.0), "budget_subsample"),
        (dict(budget_repeat_discount=float("nan")), "budget_repeat_discount"),
        (dict(budget_repeat_discount="2"), "budget_repeat_discount"),
        (dict(budget_repeat_discount=True), "budget_repeat_discount"),
        (dict(measured_point_sigma=True, landmark_point_sigma=True), "landmark_point_sigma"),
    ],
)
@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_option_validation(kw, match):
    with pytest.raises(ValueError, match=match):
        TrackerOptions(**kw)


class _Map(SimpleNamespace):
    """A landmark map stand-in (hashable and weakly referable, as the map is)."""

    __hash__ = object.__hash__


def _matches(n_p=40, n_l=6, seed=3):
    """A fake frame: landmarks, features and matches for select_budget."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-0.4, 0.4, (n_p, 3))
    L = rng.uniform(-0.4, 0.4, (n_l, 2, 3))
    n_obs = np.full(n_p, 5)
    n_obs[:5] = 1  # young: never chosen
    last_seen = np.full(n_p, 3)
    last_seen[-8:] = 1  # not inliers on the frame before: left out while 2 N others remain
    M = np.zeros((n_p, 3, 3))  # no rays yet: one stereo triangulation's covariance
    points = SimpleNamespace(X=X, n_obs=n_obs, last_seen=last_seen, ids=np.arange(n_p), M=M)
    landmarks = _Map(points=points, lines=SimpleNamespace(X=L, ids=np.arange(n_l)))  # weak key
    seg = rng.uniform(0, 400, (n_l, 2, 2))
    pixels = np.asarray(CAM.project(POSE.apply(X))) + rng.normal(0, 0.3, (n_p, 2)) + [4.0, -2.0]
    pixels[[10, 11]] += [[15.0, 0.0], [0.0, -12.0]]  # two wrong matches
    feats = SimpleNamespace(points=pixels, segments=seg, point_response=rng.uniform(size=n_p))
    stereo = FrameStereo(
        point_idx=np.arange(0, n_p, 2),
        points=np.zeros((len(range(0, n_p, 2)), 3)),  # not read by the budget
        pixels_right=np.zeros((len(range(0, n_p, 2)), 2)),
        line_idx=np.arange(n_l),
        segments=np.zeros((n_l, 2, 3)),
    )
    rig = SimpleNamespace(left=CAM, t_rl=np.array([-0.3, 0.0, 0.0]))
    matches = (np.arange(n_p), np.arange(n_p), np.arange(n_l), np.arange(n_l))
    return landmarks, feats, stereo, matches, rig


@pytest.mark.parametrize("rule", ["dop", "random", "response", "dop-both"])
def test_select_budget_rules(rule):
    landmarks, feats, stereo, matches, rig = _matches()
    noise = dict(budget_noise="both", budget_subsample=0.5) if rule == "dop-both" else {}
    rule = rule.split("-")[0]
    o = TrackerOptions(feature_budget=12, budget_rule=rule, **noise)
    kp, kl = B.select_budget(landmarks, feats, stereo, matches, POSE, rig, o, 1.0, frame=4)
    assert kp.sum() + kl.sum() == 12
    assert not kp[:5].any()  # young landmarks are left out
    assert not kp[[10, 11]].any()  # wrong matches (off the frame's motion) are left out
    assert not kp[-8:].any()  # not inliers on the frame before
    allowed = np.r_[np.arange(5, 10), np.arange(12, 32)]
    # deterministic (on a fresh map: the dop rule remembers its choices on a map's window,
    # budget_repeat_discount)
    fresh = _matches()
    again = B.select_budget(*fresh[:4], POSE, fresh[4], o, 1.0, frame=4)
    np.testing.assert_array_equal(np.r_[kp, kl], np.r_[again])
    if rule == "response":
        # points and lines in proportion (25 allowed points : 6), the strongest of each kind
        assert (kp.sum(), kl.sum()) == (10, 2)
        resp = feats.point_response
        assert resp[kp].min() >= np.sort(resp[allowed])[-10]
        length = np.linalg.norm(feats.segments[:, 1] - feats.segments[:, 0], axis=1)
        assert length[kl].min() >= np.sort(length)[-2]
    none = TrackerOptions()
    kp, kl = B.select_budget(landmarks, feats, stereo, matches, POSE, rig, none, 1.0)
    assert kp.all() and kl.all()


@pytest.fixture(scope="module")
def frames():
    scene = StereoScene(frames=4, size_m=1.0, range_m=2.0)
    return list(render_sequence(scene, default_rig(512, 384)))


def _track(frames, options):
    tracker = StereoTracker(default_rig(512, 384), frames[0].pose, options=options)
    return [tracker.process(fr.left, fr.right) for fr in frames]


def test_budget_none_leaves_the_tracker_unchanged(frames, monkeypatch):
    """With no budget the tracker's results are those of the plain pose solve, exactly."""
    import jaxpose.pipelines.stereo.tracker as T
    from jaxpose.pipelines.stereo.frame_pose import fit_pose

    got = _track(frames, TrackerOptions(feature_budget=None))
    monkeypatch.setattr(T, "fit_pose_budgeted", lambda *a, frame, stage: fit_pose(*a))
    ref = _track(frames, TrackerOptions())
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_array_equal(a.R, b.R)
        np.testing.assert_array_equal(a.t, b.t)
        assert (a.status, a.inliers, a.n_points, a.n_lines) == (
            b.status,
            b.inliers,
            b.n_points,
            b.n_lines,
        )
        assert a.timings["budget"] == 0.0


@pytest.mark.parametrize("rule", ["dop", "random", "response"])
def test_short_tracking_run_with_a_budget_loses_no_frame(frames, rule):
    res = _track(frames, TrackerOptions(feature_budget=20, budget_rule=rule))
    for r, fr in zip(res, frames, strict=True):
        assert r.status == Status.OK
        assert np.linalg.norm(r.t - np.asarray(fr.pose.t)) < 0.05
    assert all(r.timings["budget"] > 0 for r in res[1:])


@pytest.mark.parametrize(
    "argv",
    [["--feature-budget", "3"], ["--feature-budget", "0"], ["--budget-rule", "best"]],
)
def test_cli_refuses_a_bad_budget_naming_the_option(argv, capsys, tmp_path):
    from jaxpose.cli import main

    try:
        code = main(["stereo-track", *argv, "--out", str(tmp_path)])
    except SystemExit as done:
        code = done.code
    err = capsys.readouterr().err
    assert code == 2 and argv[0] in err and "Traceback" not in err


def test_cli_tracks_with_a_budget(capsys, tmp_path):
    from jaxpose.cli import main

    argv = ["stereo-track", "--frames", "3", "--image-size", "512x384", "--feature-budget", "20"]
    code = main(
        [*argv, "--budget-rule", "random", "--json", "--no-figures", "--out", str(tmp_path)]
    )
    out = capsys.readouterr().out
    assert code == 0
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["frames"] == 3 and summary["lost_frames"] == 0
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written["mean_stage_s"]["budget"] > 0
    # the numerical stack the figures were made on, as the installed distributions say
    assert written["software"]["jaxlib"] == metadata.version("jaxlib")
    assert written["software"]["numpy"] == metadata.version("numpy")


def test_greedy_keeps_its_picks_apart_in_the_image(monkeypatch):
    """Two features at one pixel (one corner found at two ORB scales): with a spacing the greedy
    never keeps both; without one it is free to."""
    monkeypatch.setattr(B, "EXACT_SUBSETS", 0)
    _, _, _, _, rows = _problem(n_p=12, n_l=4, seed=5)
    rows = np.concatenate([rows, rows[:4]])  # features 16..19 repeat 0..3
    pixels = np.c_[np.arange(16) % 4, np.arange(16) // 4] * 30.0
    pixels = np.concatenate([pixels, pixels[:4]])
    W = B.criterion_weight(0.3, POSE.t)
    got = B.select_dop(rows, np.ones(20, bool), 8, W, pixels=pixels, spacing_px=10.0)
    assert len(got) == 8
    d = np.linalg.norm(pixels[got][:, None] - pixels[got][None], axis=-1)
    assert np.all(d[np.triu_indices(8, 1)] >= 10.0)
    free = B.select_dop(rows, np.ones(20, bool), 8, W)
    assert len(free) == 8


def test_landmark_covariance_closed_forms():
    """(sigma / f)^2 M^-1 from the ray normal equations; a stereo triangulation's covariance
    where M is degenerate: (z sigma / f)^2 across the ray, (z^2 sqrt(2) sigma / (f b))^2 along."""
    cam = PinholeCamera(500.0, 500.0, 320.0, 240.0)
    ident = Pose(np.eye(3), np.zeros(3))
    X = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0]])
    M = np.stack([2.0 * np.eye(3), np.zeros((3, 3))])  # three orthogonal unit rays; none
    cov = B.landmark_covariance(M, X, ident, cam, 0.1, 0.8)
    np.testing.assert_allclose(cov[0], (0.8 / 500) ** 2 * np.eye(3) / 2, rtol=1e-12)
    across, along = (3 * 0.8 / 500) ** 2, (9 * np.sqrt(2) * 0.8 / (500 * 0.1)) ** 2
    np.testing.assert_allclose(cov[1], np.diag([across, across, along]), rtol=1e-12)


def test_effective_whitening_against_a_closed_form():
    """On the optical axis with an isotropic landmark error s (metres), the left pixels' noise
    is sqrt(sigma^2 + (f s / z)^2) per axis; with a right image the 4 x 4 whitening gives the
    information J^T C^-1 J of C = sigma^2 I + J_X s^2 J_X^T (right pixels through t_rl)."""
    cam = PinholeCamera(500.0, 500.0, 320.0, 240.0)
    ident = Pose(np.eye(3), np.zeros(3))
    z, s, sig, b = 2.0, 0.004, 0.7, 0.2
    X = np.array([[0.0, 0.0, z], [0.0, 0.0, z]])
    cov = np.broadcast_to(s**2 * np.eye(3), (2, 3, 3))
    t_rl = np.array([-b, 0.0, 0.0])
    Wh = B.effective_whitening(cov, X, ident, cam, t_rl, np.full(2, sig), [False, True])
    np.testing.assert_allclose(Wh[0, :2, :2], np.eye(2) / np.hypot(sig, 500 * s / z), rtol=1e-12)
    np.testing.assert_allclose(Wh[0, 2:, 2:], np.eye(2) / sig, rtol=1e-12)
    f = 500.0
    J = np.array([[f / z, 0, 0], [0, f / z, 0], [f / z, 0, f * b / z**2], [0, f / z, 0]])
    C = sig**2 * np.eye(4) + s**2 * J @ J.T
    np.testing.assert_allclose(Wh[1].T @ Wh[1], np.linalg.inv(C), rtol=1e-10)


def test_point_sigma_of_each_image_against_a_closed_form():
    """A landmark placed by one stereo pair (degenerate ray equations) on the optical axis: its
    error across the ray moves both images' pixels by sigma, its depth error only the right
    image's (by sqrt(2) sigma in disparity), so the effective noise is sqrt(2) sigma on the left
    and sqrt(3) sigma on the right; a landmark seen from many directions keeps about sigma."""
    cam = PinholeCamera(500.0, 500.0, 320.0, 240.0)
    rig = SimpleNamespace(left=cam, t_rl=np.array([-0.2, 0.0, 0.0]))
    z, sig = 2.0, 0.7
    pts = SimpleNamespace(
        X=np.array([[0.0, 0.0, z], [0.0, 0.0, z]]),
        M=np.stack([np.zeros((3, 3)), 1e6 * np.eye(3)]),
    )
    o = TrackerOptions(sigma_px=sig)
    left, right = B.point_sigma_images(
        SimpleNamespace(points=pts), [0, 1], Pose(np.eye(3), np.zeros(3)), rig, o
    )
    np.testing.assert_allclose([left[0], right[0]], [np.sqrt(2) * sig, np.sqrt(3) * sig], rtol=1e-9)
    np.testing.assert_allclose([left[1], right[1]], [sig, sig], rtol=1e-6)


def test_residual_spread_is_the_running_rms():
    """Within its memory the spread is the RMS of the residuals seen (capped); beyond it, an
    exponential average; never-matched landmarks get sigma."""
    sp = B.ResidualSpread(memory=4, cap_px=5.0)
    errs = [0.5, 1.5, 9.0, 1.0]
    for e in errs:
        sp.update([7], [e], 1.0)
    rms = np.sqrt(np.mean(np.minimum(errs, 5.0) ** 2))
    np.testing.assert_allclose(sp.sigma([7, 8], 1.0), [rms, 1.0], rtol=1e-12)
    sp.update([7], [0.0], 1.0)
    np.testing.assert_allclose(sp.sigma([7], 1.0), [rms * np.sqrt(0.75)], rtol=1e-12)


def _fd_jacobian(fun, x0, eps=1e-6):
    J = np.zeros((len(fun(x0)), x0.size))
    for k in range(x0.size):
        dx = np.zeros_like(x0)
        dx[k] = eps
        J[:, k] = (fun(x0 + dx) - fun(x0 - dx)) / (2 * eps)
    return J


def test_dop_selection_with_landmark_noise_against_brute_force(monkeypatch):
    """Rows whitened by the effective noise (pixel noise plus landmark covariance) give the
    information J^T C^-1 J, C = sigma^2 I + J_X C_X J_X^T over the left and right pixels, J_X by
    finite differences of a NumPy pinhole here; the forced greedy on them is within 10 % of the
    brute-force optimum of that information, and the landmark the pixel-noise DOP picks first,
    given a 20 times larger position error, is left out."""
    monkeypatch.setattr(B, "EXACT_SUBSETS", 0)
    rng = np.random.default_rng(7)
    n, N, sig, f = 10, 4, 1.0, 600.0
    X = rng.uniform(-0.4, 0.4, (n, 3))
    t_rl = np.array([-0.3, 0.0, 0.0])
    R0, t0 = np.asarray(POSE.R, float), np.asarray(POSE.t, float)
    cov = np.stack([s**2 * np.eye(3) for s in rng.uniform(0.0005, 0.003, n)])

    def pix(x_body):  # left and right pixels (CAM: f = 600, centre 319.5, 239.5)
        x = R0 @ x_body + t0
        return np.r_[f * x[:2] / x[2], f * (x[:2] + t_rl[:2]) / (x[2] + t_rl[2])]

    W = B.criterion_weight(0.3, POSE.t)
    w = np.ones((n, 2)) / sig
    no_lines = np.zeros((0, 2, 3))
    raw = B.feature_rows(X, X + R0.T @ t_rl, no_lines, no_lines, POSE, CAM, w, np.zeros((0, 2)))
    raw = np.asarray(raw)
    pixel_pick = B.select_dop(raw, np.ones(n, bool), N, W)
    cov[pixel_pick[0]] *= 400.0
    blocks = []
    for i in range(n):
        Jx = _fd_jacobian(pix, X[i])
        C = sig**2 * np.eye(4) + Jx @ cov[i] @ Jx.T
        blocks.append(raw[i].T @ np.linalg.solve(C, raw[i]))
    blocks = np.array(blocks)
    Wh = B.effective_whitening(cov, X, POSE, CAM, t_rl, np.full(n, sig), np.ones(n, bool))
    rows = np.einsum("nij,njk->nik", Wh, raw)
    got_blocks = np.einsum("nki,nkj->nij", rows, rows)
    np.testing.assert_allclose(got_blocks, blocks, rtol=1e-5, atol=1e-8 * np.abs(blocks).max())
    got = B.select_dop(rows, np.ones(n, bool), N, W)
    crit = B.budget_criterion(blocks[got].sum(0), W)
    subsets = [list(s) for s in itertools.combinations(range(n), N)]
    opt = min(B.budget_criterion(blocks[s].sum(0), W) for s in subsets)
    assert crit <= 1.1 * opt
    assert pixel_pick[0] not in got


@pytest.mark.parametrize("window", [False, True])
def test_the_budget_covers_the_window_only_when_asked(window, monkeypatch):
    """``budget_window``: the observations handed to the windowed adjustment are the budget's
    features (points kept by the solve, inlier lines among the chosen); without it, every
    matched point within ``reject_px`` of the budgeted pose and every inlier line."""
    from jaxpose.pipelines.stereo.frame_pose import PoseFit, postfit_summary

    landmarks, feats, stereo, matches, rig = _matches()
    n_p, n_l = len(matches[0]), len(matches[2])
    e_p = np.full(n_p, 0.5)
    e_p[[10, 11]] = 9.0  # beyond reject_px
    e_l = np.full(n_l, 0.5)
    e_l[0] = 9.0

    def fake_fit(lm, ft, st, sub, pose, rg, o, ls):
        k = len(sub[0])
        kept = np.ones(k, bool)
        kept[0] = False  # the solve dropped its first point
        return PoseFit(pose, True, *[np.zeros(0)] * 4, kept, (np.zeros(0), np.zeros(0)), k, 0.5)

    monkeypatch.setattr(B, "fit_pose", fake_fit)
    monkeypatch.setattr(B, "postfit_errors", lambda *a: (e_p, e_l))
    o = TrackerOptions(feature_budget=12, budget_rule="random", budget_window=window)
    fit = B.fit_pose_budgeted(landmarks, feats, stereo, matches, POSE, rig, o, 1.0, frame=4)
    kp, kl = B.select_budget(landmarks, feats, stereo, matches, POSE, rig, o, 1.0, frame=4)
    chosen = np.flatnonzero(kp)
    want = np.zeros(n_p, bool) if window else e_p < o.reject_px
    want[chosen] = True
    want[chosen[0]] = False
    np.testing.assert_array_equal(fit.kept_points, want)
    in_l = postfit_summary(e_p, e_l, o.inlier_px)["in_lines"]
    np.testing.assert_array_equal(fit.in_lines, in_l)  # the frame's inliers are all matches'
    if window:
        np.testing.assert_array_equal(fit.window_lines, in_l & kl)
    else:
        assert fit.window_lines is None


def test_a_budget_over_the_window_tracks_a_short_run(frames):
    res = _track(frames, TrackerOptions(feature_budget=20, budget_window=True))
    for r, fr in zip(res, frames, strict=True):
        assert r.status == Status.OK
        assert np.linalg.norm(r.t - np.asarray(fr.pose.t)) < 0.05


def test_relative_weight_sums_the_per_axis_variance_ratios():
    """``trace(W Q_S)`` of the ``"relative"`` weight against the per-axis variances computed apart:
    the chaser's position ``-R^T t`` differentiated by finite differences (attitude perturbed as
    ``exp([d]_x) R``, translation added) and the attitude about the camera's axes."""
    from scipy.linalg import expm

    rng = np.random.default_rng(5)
    R = np.asarray(Pose.from_euler(np.radians([25.0, -40.0, 70.0]), np.zeros(3)).R, float)
    t = np.array([0.2, -0.1, 3.0])

    def chaser(x):
        d = x[3:]
        Rd = expm(np.array([[0, -d[2], d[1]], [d[2], 0, -d[0]], [-d[1], d[0], 0]])) @ R
        return -Rd.T @ (t + x[:3])

    h = 1e-6
    J = np.stack([(chaser(h * e) - chaser(-h * e)) / (2 * h) for e in np.eye(6)], 1)
    axes = np.concatenate([J, np.eye(6)[3:]])
    A = rng.normal(size=(40, 6))
    A_all = A.T @ A
    A_sub = A[:12].T @ A[:12]
    W = B.relative_weight(A_all, R, t)
    Q_all, Q_sub = np.linalg.inv(A_all), np.linalg.inv(A_sub)
    want = sum((g @ Q_sub @ g) / (g @ Q_all @ g) for g in axes)
    np.testing.assert_allclose(B.budget_criterion(A_sub, W), want, rtol=1e-6)
    np.testing.assert_allclose(B.budget_criterion(A_all, W), 6.0, rtol=1e-9)


def test_the_relative_weight_reaches_the_selection(monkeypatch):
    landmarks, feats, stereo, matches, rig = _matches()
    seen = []
    real = B.select_dop
    monkeypatch.setattr(B, "select_dop", lambda *a, **k: seen.append(a[3]) or real(*a, **k))
    for weight in ("chaser", "relative"):
        o = TrackerOptions(feature_budget=12, budget_weight=weight)
        kp, kl = B.select_budget(landmarks, feats, stereo, matches, POSE, rig, o, 1.0, frame=4)
        assert kp.sum() + kl.sum() == 12
    assert not np.allclose(seen[0], seen[1])
    with pytest.raises(ValueError, match="budget_weight"):
        TrackerOptions(budget_weight="pdop")


def test_selection_history_counts_the_last_frames():
    """:class:`~jaxpose.pipelines.stereo.repeats.SelectionHistory`: the counts over the last
    ``frames`` selections against a count written out, and the rows' factor
    ``(1 + k) ** (-power / 2)``."""
    from jaxpose.pipelines.stereo.repeats import SelectionHistory

    rng = np.random.default_rng(11)
    h = SelectionHistory(3)
    pushed = []
    for _ in range(6):
        p, q = rng.choice(20, 6, replace=False), rng.choice(5, 2, replace=False)
        h.push(p, q)
        pushed.append((p, q))
    ids_p, ids_l = np.arange(25), np.arange(6)
    kp, kl = h.counts(ids_p, ids_l)
    want_p = [sum(int(i in p) for p, _ in pushed[-3:]) for i in ids_p]
    want_l = [sum(int(i in q) for _, q in pushed[-3:]) for i in ids_l]
    np.testing.assert_array_equal(kp, want_p)
    np.testing.assert_array_equal(kl, want_l)
    fp, fl = h.scale(ids_p, ids_l, 2.0)
    np.testing.assert_allclose(fp, 1.0 / (1.0 + np.array(want_p)))
    np.testing.assert_allclose(fl, 1.0 / (1.0 + np.array(want_l)))
    assert not SelectionHistory(0).counts(ids_p, ids_l)[0].any()
    with pytest.raises(ValueError, match="frames"):
        SelectionHistory(-1)
    with pytest.raises(ValueError, match="budget_repeat_discount"):
        TrackerOptions(budget_repeat_discount=-0.5)


@pytest.mark.parametrize("discount", [0.0, 1.0])
def test_the_dop_rule_spreads_its_choice_over_the_window(discount):
    """``budget_repeat_discount``: the same frame selected twice gives the same features without
    the discount (the rule sees independent frames), and fewer repeated landmarks with it (those
    chosen the first time count with half their information the second)."""
    landmarks, feats, stereo, matches, rig = _matches(n_p=60, seed=8)
    o = TrackerOptions(feature_budget=12, budget_rule="dop", budget_repeat_discount=discount)
    first = B.select_budget(landmarks, feats, stereo, matches, POSE, rig, o, 1.0, frame=4)
    second = B.select_budget(landmarks, feats, stereo, matches, POSE, rig, o, 1.0, frame=4)
    assert first[0].sum() + first[1].sum() == second[0].sum() + second[1].sum() == 12
    same = (first[0] & second[0]).sum() + (first[1] & second[1]).sum()
    if discount == 0:
        assert same == 12
    else:
        assert same < 10
