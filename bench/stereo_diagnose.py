"""Building blocks of the stereo tracker against the renderer's ground truth.

The true 3-D point behind a left-image pixel is found by casting its ray into the target's two
boxes (body and wing; the antennas are left out) at the true pose, so every figure below compares
an estimate with geometry the estimate never saw:

* stereo: the disparity of each ORB keypoint matched by the epipolar ZNCC search (eq. 4) against
  the true disparity ``fx b / Z`` (median = bias, MAD-scaled spread, share beyond 1 px);
* keypoints: ORB keypoints of frame 0 ray-cast to the body, projected into frame ``k`` with the
  true pose, matched by descriptor within 12 px of that projection; the distance between the
  matched keypoint and the projection is how far one corner's keypoints move between views, for
  ``cv2.cornerSubPix`` half-windows 3 and 7.

* drift (``--drift SCENE``, a scene of ``bench/stereo.py`` or ``hNN``): the tracker run twice
  on the same frames, as it is and with its landmark map updated at the *true* poses (an
  oracle map; the poses are still estimated from it). The oracle run is always without the
  windowed adjustment (``window_frames=0``): the adjustment moves landmarks and poses by the
  rays of the estimated poses, which the oracle does not reach, and the mixture is neither
  (measured on ``d6``: 382 mm x with the window, 12 mm without; compare with
  ``--window-frames 0`` for a like-for-like "as is"). Reported per axis: the error of the
  target position in the camera, ``t_est - t_true``; of the chaser position in the target
  frame, ``c = -R^T t`` (the stereo-track metric); of the attitude, and the attitude error
  split into the rotation about the spin axis (spin phase) and across it.
* repeatability (``--repeat SCENE``): per ORB budget, frame 0's keypoints (``cornerSubPix``
  refined, in the target's box), how many get a stereo match, and how many are found again in
  frames 1, 4 and 8 (matched by descriptor within 12 px of their ray-cast pixel there; median
  distance to it).
* disparity bias (``--disparity-bias SCENE``, a scene of ``bench/stereo.py`` or a held-out
  ``hNN`` of ``bench/stereo_heldout.py``): is the sub-pixel disparity biased ("pixel locking",
  the parabola through integer-disparity ZNCC scores pulled toward whole pixels)? Two parts.
  Estimator: the left image of frame 0 against itself shifted by ``80 + s`` px (``s`` = 0,
  0.1, ..., 0.9, cubic interpolation): the error of the tracker's search at its ORB keypoints
  binned by the fractional part of the true right column (the integer grid the parabola is
  fitted on), and the same for a two-phase estimate (the mean of the search on the right image
  and on it shifted by half a pixel, whose locking has the opposite sign). Rendered pairs:
  frames 0-2 against ray-cast truth, binned the same way and by image column and row
  quintiles, and a plane fitted to the error over the target, read as the depth tilt it
  would give a map (``Z * slope / baseline``); the points whose 15 x 7 window lies on one
  plane (ray-cast at its corners) and those whose window spans a change of depth (an edge, a
  crease, an occluding boundary) apart.
* disparity oracle (``--disparity-oracle SCENE``, ``--frames``, ``--seed``, ``--points-only``):
  the tracker run as it is and with every matched point's disparity replaced by the ray-cast
  truth at the true pose (lines as they are); the signed mean and the RMS of the camera-frame
  attitude error over frames 1.. and the chaser position RMS. If the attitude offsets came from
  the stereo disparities, the second run would lose them.
* full bundle adjustment (``--full-ba SCENE``, ``--frames``, ``--seed``): the tracker as it
  is, then one adjustment of the whole sequence as the tracker left it (every tracked frame's
  rays and line planes in one window, frame 0's given pose the gauge, every landmark free;
  ``--ba-rounds`` calls of ``--ba-iterations`` steps): what all the data the tracker gathered
  allow, against what its causal window made of them. ``--ba-points-only``: without any line
  term; ``--ba-from-truth``: started from the true poses (the same optimum, or another?);
  ``--ba-drop K``: frames 1..K's rays and planes taken out of the map first.

    python bench/stereo_diagnose.py               # 2 m; --range-m 3 for the far scene
    python bench/stereo_diagnose.py --drift d2-blur-3m-fast --frames 60
    python bench/stereo_diagnose.py --drift d6-blur-5m-slow --frames 40 --window-frames 0
    python bench/stereo_diagnose.py --repeat d6-blur-5m-slow
    python bench/stereo_diagnose.py --disparity-bias d4-glints-4m-slow
    python bench/stereo_diagnose.py --disparity-oracle h04 --frames 16 --points-only
    python bench/stereo_diagnose.py --full-ba d6-blur-5m-slow --frames 30 --seed 1 --ba-drop 5
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace

import numpy as np

from jaxpose.pipelines.stereo import target_roi
from jaxpose.vision.stereo_features import FeatureOptions, extract, match_points_guided
from jaxpose.vision.stereo_match import disparity_range, match_points_stereo
from jaxpose.vision.stereo_render import (
    StereoScene,
    default_rig,
    render_sequence,
    render_stereo_frame,
    tumbler_model,
)


def model_boxes(model) -> list[tuple[np.ndarray, np.ndarray]]:
    """The ``(low, high)`` corners of the target's two boxes, body and wing (the antennas are
    left out): the geometry the ray casts and the true faces of these benches are taken from."""
    V = model.vertices
    return [(V[:8].min(0), V[:8].max(0)), (V[8:16].min(0), V[8:16].max(0))]


def raycast(pixels, R, t, camera, model) -> np.ndarray:
    """Body points ``(N, 3)`` hit by the rays of left pixels at pose ``(R, t)``; NaN on a miss."""
    boxes = model_boxes(model)
    fx, fy, cx, cy = (float(v) for v in (camera.fx, camera.fy, camera.cx, camera.cy))
    d = np.stack([(pixels[:, 0] - cx) / fx, (pixels[:, 1] - cy) / fy, np.ones(len(pixels))], 1)
    o, d = -R.T @ t, d @ R  # camera centre and rays in the body frame
    best = np.full(len(pixels), np.inf)
    for lo, hi in boxes:
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (lo - o) / d, (hi - o) / d
        near, far = np.nanmax(np.minimum(t1, t2), 1), np.nanmin(np.maximum(t1, t2), 1)
        hit = (near <= far) & (near > 0) & (near < best)
        best = np.where(hit, near, best)
    with np.errstate(invalid="ignore"):  # a miss: inf times a zero component
        X = o + d * best[:, None]
    X[~np.isfinite(best)] = np.nan
    return X


def _errors(results, truths, spin_axis_cam):
    """Per-axis RMS of the camera-frame position (mm), chaser position (mm), attitude (deg) and
    the attitude error about / across the spin axis (deg) over the tracked frames."""
    from jaxpose.core.geometry import so3_log

    et, ec, ea, ephase, eacross = [], [], [], [], []
    for res, truth in zip(results, truths, strict=True):
        if res.status != 0:
            continue
        Rt, tt = np.asarray(truth.R), np.asarray(truth.t)
        et.append((res.t - tt) * 1000)
        ec.append((-res.R.T @ res.t + Rt.T @ tt) * 1000)
        w = np.degrees(np.asarray(so3_log(res.R @ Rt.T)))  # camera-frame rotation error
        ea.append(w)
        ephase.append(w @ spin_axis_cam)
        eacross.append(np.linalg.norm(w - (w @ spin_axis_cam) * spin_axis_cam))

    def rms(e):
        return np.round(np.sqrt(np.mean(np.square(e), axis=0)), 3).tolist()

    return {
        "about_spin_axis_mean_deg": round(float(np.mean(ephase)), 3),
        # the spin-phase error of every other frame: where it appears and whether it grows
        "about_spin_axis_every_2nd_frame_deg": np.round(ephase[::2], 2).tolist(),
        "camera_position_mm": rms(et),
        "chaser_position_mm": rms(ec),
        "attitude_rotvec_deg": rms(ea),
        "about_spin_axis_deg": rms(ephase),
        "across_spin_axis_deg": rms(eacross),
        "lost": int(sum(r.status != 0 for r in results)),
    }


def drift(name: str, frames: int, window_frames: int | None = None) -> dict:
    """Drift of the tracker as it is and with an oracle map (module docstring)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jaxpose.pipelines.stereo.tracker as tracker_module
    from jaxpose.pipelines.stereo import StereoTracker, TrackerOptions

    scene = _scene_by_name(name, frames, 0)
    rig = default_rig()
    seq = list(render_sequence(scene, rig))
    R0 = np.asarray(seq[0].pose.R)
    axis_body = np.asarray(scene.spin_axis_body, float)
    spin_axis_cam = R0 @ axis_body / np.linalg.norm(axis_body)
    import stereo  # bench/stereo.py

    opts = TrackerOptions(depth_range_m=stereo.depth_range(scene))
    if window_frames is not None:
        opts = replace(opts, window_frames=window_frames)
    out = {}
    update_map, observe = tracker_module.update_map, tracker_module.observe_point_rays
    truth = [None]
    for label in ("as is", "oracle map"):
        if label == "oracle map":
            opts = replace(opts, window_frames=0)  # see the module docstring
            tracker_module.update_map = lambda *a, **k: update_map(*a[:3], truth[0], *a[4:], **k)
            tracker_module.observe_point_rays = lambda *a, **k: observe(
                *a[:4], truth[0], *a[5:], **k
            )
        try:
            tr = StereoTracker(rig, seq[0].pose, options=opts)
            results = []
            for fr in seq:
                truth[0] = fr.pose
                results.append(tr.process(fr.left, fr.right))
        finally:
            tracker_module.update_map, tracker_module.observe_point_rays = update_map, observe
        out[label] = _errors(results, [fr.pose for fr in seq], spin_axis_cam)
        print(f"{name}, {frames} frames, {label}: {json.dumps(out[label])}", flush=True)
    return out


def _project(Xb, pose, cam) -> np.ndarray:
    Xc = Xb @ np.asarray(pose.R).T + np.asarray(pose.t)
    fx, fy, cx, cy = (float(v) for v in (cam.fx, cam.fy, cam.cx, cam.cy))
    return np.stack([fx * Xc[:, 0] / Xc[:, 2] + cx, fy * Xc[:, 1] / Xc[:, 2] + cy], 1)


def repeatability(name: str, budgets=(250, 640, 1000, 2000), seed: int = 0) -> None:
    """ORB keypoints of frame 0 found again in later frames, per budget (module docstring)."""
    from jaxpose.vision.stereo_features import detect_points
    from jaxpose.vision.stereo_match import StereoMatchOptions

    scene = _scene_by_name(name, 9, seed)
    rig, model = default_rig(), tumbler_model()
    cam = rig.left
    fb = float(cam.fx) * float(rig.baseline)
    frames = {k: render_stereo_frame(scene, rig, k) for k in (0, 1, 4, 8)}
    disp = disparity_range(rig, scene.range_m - 0.8, scene.range_m + 0.8)
    R0, t0 = np.asarray(frames[0].pose.R), np.asarray(frames[0].pose.t)
    for n in budgets:
        opts = FeatureOptions(n_points=n)
        feats = {
            k: detect_points(fr.left, options=opts, roi=target_roi(fr.left))
            for k, fr in frames.items()
        }
        p0, d0 = feats[0]
        Xb = raycast(p0, R0, t0, cam, model)
        pm = match_points_stereo(
            frames[0].left,
            frames[0].right,
            p0,
            disp,
            options=StereoMatchOptions(coarse_min_range=128),
        )
        Z = (Xb @ R0.T + t0)[:, 2]
        e = ((p0[:, 0] - pm.pixels_right[:, 0]) - fb / Z)[pm.ok]
        e = e[np.isfinite(e)]
        line = f"{name} budget {n}: {len(p0)} keypoints, {len(e)} stereo (disparity MAD-std "
        line += f"{_mad_std(e):.3f} px); found again:"
        for k in (1, 4, 8):
            pk, dk = feats[k]
            pred = _project(Xb, frames[k].pose, cam)
            i0, ik = match_points_guided(np.nan_to_num(pred), d0, pk, dk, radius_px=12.0)
            keep = np.isfinite(pred).all(1)[i0]
            dist = np.linalg.norm(pk[ik[keep]] - pred[i0[keep]], axis=1)
            line += f" frame {k} {len(dist)} (median {np.median(dist):.2f} px)"
        print(line, flush=True)


def track_with_history(scene, option=()):
    """``scene`` rendered with the default rig and tracked from its true first pose at the
    bench's depths (``stereo.depth_range``), every frame's ray record kept (``keep_history``),
    then the ``NAME=VALUE`` items ``option`` (``stereo.tracker_options``). Returns ``(rig,
    frames, tracker, results)``."""
    import stereo  # bench/stereo.py

    from jaxpose.pipelines.stereo import StereoTracker, TrackerOptions

    base = TrackerOptions(depth_range_m=stereo.depth_range(scene), keep_history=True)
    opts = stereo.tracker_options(option, base)
    rig = default_rig()
    seq = list(render_sequence(scene, rig))
    tracker = StereoTracker(rig, seq[0].pose, options=opts)
    return rig, seq, tracker, [tracker.process(fr.left, fr.right) for fr in seq]


def rendered(name: str, frames: int, seed: int):
    """Scene ``name`` (:func:`_scene_by_name`) rendered with the default rig, and the tracker
    options at the bench's depths (``stereo.depth_range``): ``(rig, frames, options)``."""
    import stereo  # bench/stereo.py

    from jaxpose.pipelines.stereo import TrackerOptions

    scene = _scene_by_name(name, frames, seed)
    rig = default_rig()
    return (
        rig,
        list(render_sequence(scene, rig)),
        TrackerOptions(depth_range_m=stereo.depth_range(scene)),
    )


def _scene_by_name(name: str, frames: int, seed: int):
    """A scene of ``bench/stereo.py``, ``hNN`` of ``bench/stereo_heldout.py`` (its default
    draw), or a scene of your own as ``NAME={StereoScene fields as JSON}`` (as ``bench/stereo.py
    --scene`` takes it)."""
    sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
    import stereo  # bench/stereo.py

    if "=" in name:
        return StereoScene(frames=frames, seed=seed, **stereo.own_scene_params(name)[1])
    if name in stereo.SCENES:
        return stereo.scene_of(name, frames, seed)
    from stereo_heldout import DRAW_SEED, N_SCENES, draw_scenes

    drawn = {k.split("-")[0]: v for k, v in draw_scenes(N_SCENES, DRAW_SEED).items()}
    if name.split("-")[0] not in drawn:
        raise ValueError(
            f"unknown scene {name!r}: a scene of bench/stereo.py ({', '.join(stereo.SCENES)}), "
            f"{', '.join(drawn)} of bench/stereo_heldout.py's draw, or NAME={{StereoScene "
            "fields as JSON}"
        )
    return StereoScene(frames=frames, seed=seed, **drawn[name.split("-")[0]])


def _mad_std(e) -> float:
    """Robust standard deviation: 1.4826 times the median absolute deviation."""
    return float(1.4826 * np.median(np.abs(e - np.median(e))))


def _shifted(image, dx: float) -> np.ndarray:
    """``out(x) = image(x + dx)`` (float32, cubic interpolation, edges replicated)."""
    import cv2

    im = np.asarray(image, np.float32)
    M = np.float32([[1, 0, -dx], [0, 1, 0]])
    return cv2.warpAffine(
        im, M, im.shape[::-1], flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE
    )


def _two_phase(left, right, pixels, disparities, options):
    """Right columns: the mean of the search on ``right`` and on ``right`` shifted left by half
    a pixel (cubic), whose parabola locks on the other half-integers; ok where both match."""
    R = np.asarray(right, np.float32)
    shifted = _shifted(R, 0.5)
    a = match_points_stereo(left, R, pixels, disparities, options=options)
    b = match_points_stereo(left, shifted, pixels, disparities, options=options)
    return 0.5 * (a.pixels_right[:, 0] + b.pixels_right[:, 0] + 0.5), a.ok & b.ok


def _binned(e, key, bins=10) -> list:
    b = np.minimum((key * bins).astype(int), bins - 1)
    return [round(float(np.mean(e[b == i])), 3) if np.any(b == i) else None for i in range(bins)]


def disparity_bias(name: str, seed: int = 0) -> dict:
    """Sub-pixel disparity bias of the epipolar search (module docstring)."""

    from jaxpose.pipelines.stereo import TrackerOptions

    scene = _scene_by_name(name, 3, seed)
    rig, model = default_rig(), tumbler_model()
    cam, B = rig.left, float(rig.baseline)
    fb = float(cam.fx) * B
    to = TrackerOptions()
    fo = replace(to.features, n_points=to.keypoint_floor or to.features.n_points)
    frames = [render_stereo_frame(scene, rig, k) for k in (0, 1, 2)]
    out = {"scene": name, "seed": seed}
    # 1. the estimator alone: known sub-pixel shifts of frame 0's left image
    L = np.asarray(frames[0].left, np.float32)
    p0 = extract(frames[0].left, roi=target_roi(frames[0].left), lines=False, options=fo).points
    flat = replace(to.stereo, coarse_min_range=None)
    e1, e2, key = [], [], []
    for s in np.arange(10) / 10:
        D = 80.0 + s
        R = _shifted(L, D)  # R(x) = L(x + D): disparity D everywhere
        pm = match_points_stereo(L, R, p0, (74, 86), options=flat)
        ur2, ok2 = _two_phase(L, R, p0, (74, 86), flat)
        ok = pm.ok & ok2
        e1.append(p0[ok, 0] - pm.pixels_right[ok, 0] - D)
        e2.append(p0[ok, 0] - ur2[ok] - D)
        key.append((p0[ok, 0] - D) % 1.0)
    e1, e2, key = map(np.concatenate, (e1, e2, key))
    out["shift_test"] = {
        "n": len(e1),
        "error_by_frac_right_col_px": _binned(e1, key),
        "two_phase_by_frac_right_col_px": _binned(e2, key),
        "mad_std_px": round(_mad_std(e1), 3),
    }
    # 2. rendered pairs against ray-cast truth
    disp = disparity_range(rig, *to.depth_range_m)
    cols = {k: [] for k in ("e", "e2", "fr", "fd", "u", "v", "Z", "planar")}
    for fr in frames:
        Rt, tt = np.asarray(fr.pose.R), np.asarray(fr.pose.t)
        p = extract(fr.left, roi=target_roi(fr.left), lines=False, options=fo).points
        pm = match_points_stereo(fr.left, fr.right, p, disp, options=to.stereo)
        ur2, ok2 = _two_phase(fr.left, fr.right, p, disp, to.stereo)
        # true disparity at the window's centre and corners: a window on one plane has the
        # corners' mean at the centre (disparity is affine over a plane) and equal diagonals
        dw = np.array(
            [
                fb / (raycast(p + o, Rt, tt, cam, model) @ Rt.T + tt)[:, 2]
                for o in ((0, 0), (-7, -3), (7, -3), (-7, 3), (7, 3))
            ]
        )
        Z = fb / dw[0]
        with np.errstate(invalid="ignore"):
            planar = (np.abs(dw[1:].mean(0) - dw[0]) < 0.05) & (
                np.abs(dw[1] + dw[4] - dw[2] - dw[3]) < 0.1
            )
        good = pm.ok & ok2 & np.isfinite(Z)
        dt = fb / Z[good]
        q = p[good]
        cols["e"].append(q[:, 0] - pm.pixels_right[good, 0] - dt)
        cols["e2"].append(q[:, 0] - ur2[good] - dt)
        cols["fr"].append((q[:, 0] - dt) % 1.0)
        cols["fd"].append(dt % 1.0)
        cols["u"].append(q[:, 0])
        cols["v"].append(q[:, 1])
        cols["Z"].append(Z[good])
        cols["planar"].append(planar[good])
    c = {k: np.concatenate(v) for k, v in cols.items()}
    # gross mismatches out (and points where the two phases found different peaks)
    inl = (np.abs(c["e"] - np.median(c["e"])) < 1.0) & (np.abs(c["e2"] - c["e"]) < 0.5)
    c = {k: v[inl] for k, v in c.items()}
    e, Zm = c["e"], float(np.median(c["Z"]))
    rendered = {
        "n": int(len(e)),
        "range_m": round(Zm, 2),
        "median_px": round(float(np.median(e)), 3),
        "mad_std_px": round(_mad_std(e), 3),
        "by_frac_right_col_px": _binned(e, c["fr"]),
        "by_frac_disparity_px": _binned(e, c["fd"]),
    }
    for axis in ("u", "v"):
        edges = np.quantile(c[axis], np.linspace(0, 1, 6))
        rendered[f"by_{axis}_quintile_px"] = [
            round(float(np.mean(e[(c[axis] >= lo) & (c[axis] <= hi)])), 3)
            for lo, hi in zip(edges[:-1], edges[1:], strict=True)
        ]
    pl = c["planar"]
    M0 = np.stack([np.ones(len(e)), c["u"] - c["u"].mean(), c["v"] - c["v"].mean()], 1)
    rendered["planar_window"] = {"n": int(pl.sum()), "median_px": round(float(np.median(e[pl])), 3)}
    rendered["window_across_depth_change"] = {
        "n": int((~pl).sum()),
        "median_px": round(float(np.median(e[~pl])), 3),
    }
    for label, err, sel in (
        ("parabola", e, np.ones(len(e), bool)),
        ("two_phase", c["e2"], np.ones(len(e), bool)),
        ("parabola_planar_windows", e, pl),
    ):
        M, err = M0[sel], err[sel]
        coef, *_ = np.linalg.lstsq(M, err, rcond=None)
        r = err - M @ coef
        # x3 on the standard error: frames 0-2 see mostly the same corners (not independent)
        se = 3 * np.sqrt(np.diag(np.linalg.inv(M.T @ M)) * r.var())
        rendered[f"plane_{label}"] = {
            "slope_px_per_100px_u_v": np.round(100 * coef[1:], 4).tolist(),
            "tilt_deg_about_v_u": np.round(np.degrees(coef[1:] * Zm / B), 2).tolist(),
            "tilt_se_deg": np.round(np.degrees(se[1:] * Zm / B), 2).tolist(),
        }
    out["rendered_frames_0_2"] = rendered
    print(json.dumps(out), flush=True)
    return out


def disparity_oracle(name: str, frames: int, seed: int = 0, points_only: bool = False) -> dict:
    """The tracker with true point disparities against as it is (module docstring)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jaxpose.pipelines.stereo.keyframes as keyframes
    from jaxpose.core.geometry import so3_log
    from jaxpose.pipelines.stereo import StereoTracker, TrackerOptions

    scene = _scene_by_name(name, frames, seed)
    rig, model = default_rig(), tumbler_model()
    cam = rig.left
    fb = float(cam.fx) * float(rig.baseline)
    seq = list(render_sequence(scene, rig))
    truth = [None]
    search_points, search_both = keyframes.match_points_stereo, keyframes.match_stereo

    def true_points(left, right, p, disp, *, options):
        pm = search_points(left, right, p, disp, options=options)
        R, t = np.asarray(truth[0].R), np.asarray(truth[0].t)
        Z = (raycast(p, R, t, cam, model) @ R.T + t)[:, 2]
        g = pm.ok & np.isfinite(Z)
        pm.pixels_right[g, 0] = p[g, 0] - fb / Z[g]
        return pm

    def true_both(left, right, p, dp, seg, dl, *, options, executor=None):
        _, lm = search_both(left, right, p[:0], np.zeros((0, 2)), seg, dl, options=options)
        return true_points(left, right, p, dp, options=options), lm

    out = {"scene": name, "seed": seed, "frames": frames, "points_only": points_only}
    for label in ("as is", "true point disparities"):
        if label != "as is":
            keyframes.match_points_stereo, keyframes.match_stereo = true_points, true_both
        try:
            tr = StereoTracker(rig, seq[0].pose, options=TrackerOptions(use_lines=not points_only))
            w, c = [], []
            for fr in seq:
                truth[0] = fr.pose
                r = tr.process(fr.left, fr.right)
                Rt, tt = np.asarray(fr.pose.R), np.asarray(fr.pose.t)
                w.append(np.degrees(np.asarray(so3_log(np.asarray(r.R) @ Rt.T))))
                c.append((-np.asarray(r.R).T @ np.asarray(r.t) + Rt.T @ tt) * 1000)
        finally:
            keyframes.match_points_stereo, keyframes.match_stereo = search_points, search_both
        w, c = np.array(w[1:]), np.array(c[1:])
        out[label] = {
            "attitude_error_camera_mean_deg": np.round(w.mean(0), 2).tolist(),
            "attitude_error_camera_rms_deg": np.round(np.sqrt((w**2).mean(0)), 2).tolist(),
            "chaser_position_rms_mm": np.round(np.sqrt((c**2).mean(0)), 1).tolist(),
        }
    print(json.dumps(out), flush=True)
    return out


def full_ba(
    name: str,
    frames: int,
    seed: int = 0,
    *,
    rounds: int = 3,
    iterations: int = 4,
    lines: bool = True,
    drop: int = 0,
    from_truth: bool = False,
    right_only: bool = False,
) -> dict:
    """The tracker as it is, then one bundle adjustment of the whole sequence (module
    docstring): every tracked frame's rays and line planes, as the tracker left them, in one
    window (:class:`~jaxpose.pipelines.stereo.window.WindowAdjuster` with ``frames`` = the
    tracked frames and every landmark), frame 0's given pose the gauge, ``rounds`` calls of
    ``iterations`` Gauss-Newton steps (the rays moved and the landmarks re-solved between
    calls). ``lines=False``: the adjustment without any line term (the poses from the points'
    rays alone); ``drop``: the rays and planes of frames 1..``drop`` taken out of the map first
    (their landmarks then rest on the later frames' observations; ``right_only``: only their
    right-image rays and planes, the frames kept with their left-image ones); ``from_truth``: the
    adjustment started from the true poses (every frame's rays and planes moved there, the
    landmarks re-solved) instead of the tracker's."""
    import copy

    import jax

    jax.config.update("jax_enable_x64", True)
    from jaxpose.core.geometry import Pose, so3_log
    from jaxpose.pipelines.stereo._arrays import find
    from jaxpose.pipelines.stereo.smooth import adjust_sequence
    from jaxpose.pipelines.stereo.window import WindowAdjuster, ray_geometry
    from jaxpose.studies.stereo_track import summarize

    scene = _scene_by_name(name, frames, seed)
    rig, seq, tr, results = track_with_history(scene)
    logs = tr._window.history  # every frame's ray record, not only the window's
    truths = [fr.pose for fr in seq]

    def report(res):
        s = summarize(res, truths, [0.0] * len(res))["summary"]
        w = [
            np.degrees(np.asarray(so3_log(r.R @ np.asarray(t.R).T)))
            for r, t in zip(res[1:], truths[1:], strict=True)
            if r.status == 0
        ]
        return {
            "rms_position_mm": np.round(s["rms_position_mm"], 1).tolist(),
            "rms_attitude_deg": np.round(s["rms_attitude_deg"], 2).tolist(),
            "meets": bool(
                max(s["rms_position_mm"]) <= 5 * scene.range_m and max(s["rms_attitude_deg"]) <= 1
            ),
            "attitude_error_camera_mean_deg": np.round(np.mean(w, 0), 2).tolist(),
            "attitude_error_per_frame_deg": np.round(np.linalg.norm(w, axis=1), 2).tolist(),
        }

    out = {"scene": name, "seed": seed, "frames": frames, "lines": lines, "drop": drop}
    out["drop_right_only"] = right_only
    out["tracker"] = report(results)
    m = tr.map
    if drop:
        for fr in logs:
            if not 1 <= fr.index <= drop:
                continue
            ids, px, right, w = fr.arrays()
            q, at = find(m.points.ids, ids)
            q, at = (q[right[q]], at[right[q]]) if right_only else (q, at)
            o, d = ray_geometry(rig, fr.R, fr.t, px[q], right[q])
            m.observe(at, o, d, -w[q])
            ids, n, dd, cam, w = fr.plane_arrays()
            q, at = find(m.lines.ids, ids)
            q, at = (q[cam[q] == 1], at[cam[q] == 1]) if right_only else (q, at)
            m.observe_lines(at, n[q] @ fr.R, dd[q] - n[q] @ fr.t, -w[q])
            if right_only:  # the frame stays, with its left-image rays and planes only
                ids, px, right, w = fr.arrays()
                fr.rays = [(ids[~right], px[~right], right[~right], w[~right])]
                ids, n, dd, cam, w = fr.plane_arrays()
                fr.planes = [(ids[cam == 0], n[cam == 0], dd[cam == 0], cam[cam == 0], w[cam == 0])]
        if not right_only:
            logs = [fr for fr in logs if not 1 <= fr.index <= drop]
    if from_truth:  # move every frame's rays and planes to its true pose
        true_R = [np.asarray(truths[fr.index].R, float) for fr in logs]
        true_t = [np.asarray(truths[fr.index].t, float) for fr in logs]
        idx, o, d, w = [], [], [], []
        for fr, R, t in zip(logs, true_R, true_t, strict=True):
            ids, px, right, wr = fr.arrays()
            q, at = find(m.points.ids, ids)
            for RR, tt, sign in ((fr.R, fr.t, -1.0), (R, t, 1.0)):
                oo, dd = ray_geometry(rig, RR, tt, px[q], right[q])
                idx.append(at), o.append(oo), d.append(dd), w.append(sign * wr[q])
        m.observe(*(np.concatenate(c) for c in (idx, o, d, w)))
        WindowAdjuster._move_planes(m, logs, true_R, true_t)
        for fr, R, t in zip(logs, true_R, true_t, strict=True):
            fr.R, fr.t = R, t
        out["started from the true poses"] = True
    by_index = {fr.index: fr for fr in logs}
    for r in range(rounds):
        ran = adjust_sequence(
            m,
            rig,
            logs,
            rounds=1,
            iterations=iterations,
            lines=lines,
            max_lines=tr.options.max_lines,
        )
        res = []
        for k, orig in enumerate(results):
            rr = copy.copy(orig)
            if k in by_index and orig.status == 0:
                rr.pose = Pose(by_index[k].R, by_index[k].t)
            elif k:
                rr.status = 1 if drop and 1 <= k <= drop else orig.status
            res.append(rr)
        out[f"full BA, {(r + 1) * iterations} iterations"] = {"ran": ran, **report(res)}
    print(json.dumps(out), flush=True)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--range-m", type=float, default=2.0)
    p.add_argument("--drift", default=None, help="a scene of bench/stereo.py: drift diagnosis")
    p.add_argument("--frames", type=int, default=60, help="frames of the drift diagnosis")
    p.add_argument(
        "--window-frames",
        type=int,
        default=None,
        help="drift diagnosis with this window_frames (0: no windowed adjustment)",
    )
    p.add_argument("--repeat", default=None, help="a scene of bench/stereo.py: repeatability")
    p.add_argument(
        "--disparity-bias", default=None, help="a scene (or hNN): sub-pixel disparity bias"
    )
    p.add_argument("--seed", type=int, default=0, help="scene seed of --disparity-bias/oracle")
    p.add_argument(
        "--disparity-oracle", default=None, help="a scene (or hNN): true point disparities"
    )
    p.add_argument("--points-only", action="store_true", help="--disparity-oracle without lines")
    p.add_argument("--full-ba", default=None, help="a scene (or hNN): whole-sequence adjustment")
    p.add_argument("--ba-rounds", type=int, default=3, help="--full-ba: adjustment calls")
    p.add_argument("--ba-iterations", type=int, default=4, help="--full-ba: steps a call")
    p.add_argument("--ba-points-only", action="store_true", help="--full-ba without line terms")
    p.add_argument("--ba-from-truth", action="store_true", help="--full-ba from the true poses")
    p.add_argument(
        "--ba-drop-right", action="store_true", help="--ba-drop: the right-image rays only"
    )
    p.add_argument("--ba-drop", type=int, default=0, help="--full-ba: frames 1..K taken out")
    args = p.parse_args(argv)
    if args.full_ba:
        full_ba(
            args.full_ba,
            args.frames,
            args.seed,
            rounds=args.ba_rounds,
            iterations=args.ba_iterations,
            lines=not args.ba_points_only,
            drop=args.ba_drop,
            from_truth=args.ba_from_truth,
            right_only=args.ba_drop_right,
        )
        return 0
    if args.disparity_oracle:
        disparity_oracle(args.disparity_oracle, args.frames, args.seed, args.points_only)
        return 0
    if args.disparity_bias:
        disparity_bias(args.disparity_bias, args.seed)
        return 0
    if args.repeat:
        repeatability(args.repeat)
        return 0
    if args.drift:
        drift(args.drift, args.frames, args.window_frames)
        return 0
    scene = StereoScene(range_m=args.range_m)
    rig, model = default_rig(), tumbler_model()
    cam = rig.left
    fb = float(cam.fx) * float(rig.baseline)
    frames = {k: render_stereo_frame(scene, rig, k) for k in (0, 1, 10, 30, 60)}
    print(f"range {args.range_m} m; true disparity about {fb / args.range_m:.0f} px")
    for k in (0, 30, 60):
        fr = frames[k]
        R, t = np.asarray(fr.pose.R), np.asarray(fr.pose.t)
        f = extract(fr.left, roi=target_roi(fr.left), lines=False)
        disp = disparity_range(rig, args.range_m - 0.8, args.range_m + 0.8)
        pm = match_points_stereo(fr.left, fr.right, f.points, disp)
        pl, pr = f.points[pm.ok], pm.pixels_right[pm.ok]
        Z = (raycast(pl, R, t, cam, model) @ R.T + t)[:, 2]
        e = (pl[:, 0] - pr[:, 0]) - fb / Z
        e = e[np.isfinite(e)]
        mad = _mad_std(e)
        print(
            f"stereo frame {k}: {len(e)} points, disparity error median {np.median(e):+.3f} px, "
            f"MAD-std {mad:.3f} px, beyond 1 px {np.mean(np.abs(e) > 1):.1%}"
        )
    for half in (3, 7):
        opts = FeatureOptions(subpixel_half_window=half)
        f0 = extract(frames[0].left, roi=target_roi(frames[0].left), lines=False, options=opts)
        R0, t0 = np.asarray(frames[0].pose.R), np.asarray(frames[0].pose.t)
        Xb = raycast(f0.points, R0, t0, cam, model)
        for k in (1, 10):
            fr = frames[k]
            fk = extract(fr.left, roi=target_roi(fr.left), lines=False, options=opts)
            Xc = Xb @ np.asarray(fr.pose.R).T + np.asarray(fr.pose.t)
            pred = np.stack(
                [
                    float(cam.fx) * Xc[:, 0] / Xc[:, 2] + float(cam.cx),
                    float(cam.fy) * Xc[:, 1] / Xc[:, 2] + float(cam.cy),
                ],
                1,
            )
            good = np.isfinite(pred).all(1)
            i0, ik = match_points_guided(
                np.nan_to_num(pred), f0.point_desc, fk.points, fk.point_desc, radius_px=12.0
            )
            keep = good[i0]
            n = np.linalg.norm(fk.points[ik[keep]] - pred[i0[keep]], axis=1)
            print(
                f"keypoints, cornerSubPix half-window {half}, frame 0 -> {k} "
                f"({k * scene.rate_deg_s / scene.frame_rate_hz:.0f} deg): {len(n)} matches, "
                f"median {np.median(n):.2f} px, beyond 1 px {np.mean(n > 1):.0%}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
