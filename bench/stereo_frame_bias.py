"""Are the tracker's observations of one frame biased beyond their noise? Each frame's pose from
perfect landmarks.

    python bench/stereo_frame_bias.py SCENE [SCENE ...] [--frames 12] [--seeds 0]
        [--scene-option NAME=VALUE ...] [--option NAME=VALUE ...]

Runs the stereo tracker as it is (points + lines, default options, first pose given) on a scene
of ``bench/stereo.py`` (or ``hNN`` of ``bench/stereo_heldout.py``), keeping every tracked frame's
point observations (``keep_history``). The landmarks first seen in frame 0 get their true body
points by ray-casting their frame-0 left pixels at the true pose, so that in each later frame
the only errors left are those of the observations the tracker kept (left and right pixels).
For every frame the pose is then fitted to those observations alone by Gauss-Newton from the
true pose (:func:`frame_fit`), and its attitude error (rotation vector, left camera frame,
degrees) is set against the frame's Cramer-Rao bound with the landmarks known (independent
pixel noise of the size measured at the true pose, the MAD-scaled residual spread). Independent
noise gives errors of about one bound (``|z|`` below 3 in 99% of frames); errors of several
bounds that keep their sign from frame to frame are a bias of the observations, which no
adjustment over frames can remove. The fit on the left pixels alone tells the left image's
keypoints from the stereo disparities.

``motion``: whether the left observations are displaced along their image motion (what a blurred
corner found nearer one end of its smear would give): over every kept left observation of the
frame-0 landmarks in frames 1 on, the least-squares slope and intercept of its residual (observed
minus the true body point's projection at the frame's true pose, pixels) along its motion on the
motion's length (the true projection's change since the frame before, pixels a frame), and the
mean residual in u and v.

``by_surface``: the frame-0 landmarks by where their first pixel lies on the model, from rays cast
at the true pose through the pixels ``margin`` (5) pixels around it (:func:`surface_classes`):
``face`` (every ray on one face), ``edge`` (on two faces or more: a crease of the box, or one
part in front of another) or ``silhouette`` (a ray misses the target: sky); the rays meet the
model's two boxes only (body and wing: a landmark on an antenna has no true point and is left
out, one beside an antenna is classed by what lies behind it); per class the
landmarks, their left observations in frames 1 on, the MAD-scaled spread and median length of
their residuals and the mean residual in u and v (pixels).

``--figure DIR`` writes ``DIR/SCENE-seedS-surface.png``: the first left image about the target,
each frame-0 landmark drawn at its pixel in its class's colour (face green, edge yellow,
silhouette red).

``--scene-option`` changes a field of every scene (``pixel_samples=3``, ``exact_faces=True``,
``noise_sigma=0.0``, ...), to tell the renderer's part from the features'; ``--option`` a field
of the tracker's options as in ``bench/stereo.py`` (``features.subpixel=False``,
``features.orb_levels=1``, ...). The last line is one JSON line of the figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from stereo_bound import check_scenes, observation_jacobians, project  # noqa: E402

from jaxpose.commands._common import CommandError, with_options  # noqa: E402


def _rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector (radians) of a rotation matrix."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()


def _exp(w: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(w).as_matrix()


def frame_fit(pixels, points, offsets, R, t, focal, centre, iterations: int = 10):
    """Gauss-Newton fit of one frame's pose ``(R, t)`` (``x_cam = R X + t``, left camera) to the
    pixels ``(n, 2)`` of body points ``(n, 3)`` seen by cameras whose centres sit at
    ``-offsets (n, 3)`` in the left camera's frame (0 for the left camera, ``t_rl`` for the
    right one of a rectified rig), focal lengths ``focal (fx, fy)`` and principal point
    ``centre (cx, cy)``. Starts at ``(R, t)``; returns the fitted ``(R, t)`` and the ``(6, 6)``
    normal matrix ``J^T J`` at the start (the pose perturbation ``(dtheta, dt)``, ``R <- exp(
    dtheta) R``, of :func:`stereo_bound.observation_jacobians`)."""

    def residuals_jacobian(R, t):
        r = project(R, t, points, offsets, focal, centre) - pixels
        J = [
            observation_jacobians(R, t, X, o, focal)[0]
            for X, o in zip(points, offsets, strict=True)
        ]
        return r.ravel(), np.concatenate(J)

    r, J = residuals_jacobian(R, t)
    normal = J.T @ J
    for _ in range(iterations):
        dx = -np.linalg.solve(J.T @ J, J.T @ r)
        R, t = _exp(dx[:3]) @ R, t + dx[3:]
        if np.linalg.norm(dx) < 1e-12:
            break
        r, J = residuals_jacobian(R, t)
    return R, t, normal


def _faces(X: np.ndarray, model) -> np.ndarray:
    """Which face of the model's two boxes (body, wing; ``6 box + side``) each body point ``(n,
    3)`` lies on (the nearest of the box's six planes, the box holding the point); -1 for NaN."""
    V = model.vertices
    out = np.full(len(X), -1)
    for b in (1, 0):  # the body last: a point where the wing meets it is the body's
        lo, hi = V[8 * b : 8 * b + 8].min(0), V[8 * b : 8 * b + 8].max(0)
        with np.errstate(invalid="ignore"):
            inside = np.all((X >= lo - 1e-6) & (X <= hi + 1e-6), axis=1)
        d = np.concatenate([np.abs(X[inside] - lo), np.abs(X[inside] - hi)], axis=1)
        out[inside] = 6 * b + np.argmin(d, axis=1)
    return out


def surface_classes(pixels, R, t, camera, model, margin: float = 5.0) -> np.ndarray:
    """``(n,)`` ``"face"``, ``"edge"`` or ``"silhouette"`` for left pixels ``(n, 2)`` at the pose
    ``(R, t)``: rays are cast through the 3 x 3 pixels ``margin`` apart about each (the module
    docstring's ``by_surface``)."""
    from stereo_diagnose import raycast

    faces = np.stack(
        [
            _faces(raycast(pixels + [du, dv], R, t, camera, model), model)
            for du in (-margin, 0.0, margin)
            for dv in (-margin, 0.0, margin)
        ],
        axis=1,
    )
    several = np.array([len(set(f)) > 1 for f in faces])
    return np.where((faces < 0).any(1), "silhouette", np.where(several, "edge", "face"))


def surface_summary(classes: np.ndarray, residuals: np.ndarray, observed: np.ndarray) -> dict:
    """Per class of :func:`surface_classes`: the landmarks, and the residuals ``(m, 2)`` of their
    observations (``observed (m,)``: each observation's class) summarised (``by_surface``)."""
    from stereo_diagnose import _mad_std

    out = {}
    for c in ("face", "edge", "silhouette"):
        r = residuals[observed == c]
        out[c] = {"landmarks": int(np.sum(classes == c)), "observations": len(r)}
        if len(r):
            out[c] |= {
                "spread_px": round(float(_mad_std(r.ravel())), 3),
                "median_length_px": round(float(np.median(np.linalg.norm(r, axis=1))), 3),
                "mean_residual_uv_px": np.round(r.mean(0), 3).tolist(),
            }
    return out


SURFACE_COLOURS = {"face": (60, 200, 60), "edge": (0, 220, 255), "silhouette": (40, 40, 255)}


def surface_figure(image: np.ndarray, pixels: np.ndarray, classes: np.ndarray, path) -> None:
    """A PNG at ``path`` of the grey ``image`` about its bright target (10 px around), scaled to
    600 px on its longer side, with a dot at each of ``pixels (n, 2)`` in the colour of its class
    (:data:`SURFACE_COLOURS`)."""
    import cv2

    from jaxpose.pipelines.stereo import target_roi

    box = target_roi(image)
    H, W = image.shape
    u0, v0, u1, v1 = (0, 0, W, H) if box is None else box.astype(int)
    u0, v0, u1, v1 = max(u0 - 10, 0), max(v0 - 10, 0), min(u1 + 10, W), min(v1 + 10, H)
    scale = 600.0 / max(u1 - u0, v1 - v0)
    crop = np.ascontiguousarray(image[v0:v1, u0:u1])
    out = cv2.resize(cv2.cvtColor(crop, cv2.COLOR_GRAY2BGR), None, fx=scale, fy=scale)
    for (u, v), c in zip(pixels, classes, strict=True):
        centre = (
            int(round((u - u0 + 0.5) * scale - 0.5)),
            int(round((v - v0 + 0.5) * scale - 0.5)),
        )
        cv2.circle(out, centre, 3, SURFACE_COLOURS[str(c)], -1, cv2.LINE_AA)
    if not cv2.imwrite(str(path), out):
        raise OSError(f"could not write {path}")


def motion_summary(residuals: np.ndarray, motion: np.ndarray) -> dict:
    """Residuals ``(n, 2)`` (pixels) against the image motion ``(n, 2)`` of the same points:
    the least-squares slope and intercept of the residual's component along the motion on the
    motion's length, the median motion and the mean residual (module docstring, ``motion``)."""
    length = np.linalg.norm(motion, axis=1)
    along = np.sum(residuals * motion, axis=1) / np.maximum(length, 1e-9)
    A = np.c_[length, np.ones(len(length))]
    (slope, intercept), *_ = np.linalg.lstsq(A, along, rcond=None)
    return {
        "observations": len(length),
        "median_motion_px": round(float(np.median(length)), 2),
        "slope_along_motion": round(float(slope), 3),
        "intercept_px": round(float(intercept), 3),
        "mean_residual_uv_px": np.round(residuals.mean(0), 3).tolist(),
    }


def frame_bias(
    name: str, frames: int, seed: int, scene_options=(), option=(), figure_dir=None
) -> dict:
    """Per frame: the fitted attitude error and its bound (module docstring). ``scene_options``
    and ``option``: ``NAME=VALUE`` items for the scene and the tracker's options; ``figure_dir``:
    where :func:`surface_figure` writes the first frame's landmarks by class (``None``: no
    figure)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from stereo_diagnose import _mad_std, _scene_by_name, raycast, track_with_history

    from jaxpose.vision.stereo_render import tumbler_model

    scene = with_options(_scene_by_name(name, frames, seed), scene_options, "--scene-option")
    rig, seq, tracker, _ = track_with_history(scene, option)
    model = tumbler_model(scene.size_m)
    cam = rig.left
    focal = (float(cam.fx), float(cam.fy))
    centre = (float(cam.cx), float(cam.cy))
    t_rl = np.asarray(rig.t_rl, float)
    logs = sorted(tracker._window.history, key=lambda f: f.index)
    ids0, px0, right0, _ = logs[0].arrays()
    R0, t0 = np.asarray(seq[0].pose.R, float), np.asarray(seq[0].pose.t, float)
    X = raycast(px0[~right0], R0, t0, cam, model)
    hit = np.all(np.isfinite(X), axis=1)
    truth = {int(i): x for i, x, h in zip(ids0[~right0], X, hit, strict=True) if h}
    classes = surface_classes(px0[~right0][hit], R0, t0, cam, model)
    surface = dict(zip(ids0[~right0][hit].tolist(), classes, strict=True))
    if figure_dir is not None:
        path = Path(figure_dir) / f"{name}-seed{seed}-surface.png"
        surface_figure(np.asarray(seq[0].left), px0[~right0][hit], classes, path)
    rows, motion, resid, kinds = [], [], [], []
    for log in logs[1:]:
        ids, px, right, _ = log.arrays()
        keep = np.array([int(i) in truth for i in ids], bool)
        if keep.sum() < 6:
            continue
        pts = np.array([truth[int(i)] for i in ids[keep]])
        pix, rt = px[keep], right[keep]
        offsets = np.where(rt[:, None], t_rl, 0.0)
        R, t = np.asarray(seq[log.index].pose.R, float), np.asarray(seq[log.index].pose.t, float)
        proj = project(R, t, pts, offsets, focal, centre)
        prev = seq[log.index - 1].pose
        left = ~rt  # the image motion of the left observations since the frame before
        before = project(np.asarray(prev.R), np.asarray(prev.t), pts[left], 0.0, focal, centre)
        resid.append(pix[left] - proj[left])
        kinds.append(np.array([surface[int(i)] for i in ids[keep][left]]))
        motion.append(proj[left] - before)
        sigma = _mad_std((proj - pix).ravel())
        Rf, _, normal = frame_fit(pix, pts, offsets, R, t, focal, centre)
        bound = np.degrees(sigma * np.sqrt(np.diag(np.linalg.inv(normal))[:3]))
        err = np.degrees(_rotvec(Rf @ R.T))
        Rl, _, _ = frame_fit(pix[left], pts[left], offsets[left], R, t, focal, centre)
        rows.append(
            {
                "frame": int(log.index),
                "observations": int(keep.sum()),
                "sigma_px": round(float(sigma), 3),
                "attitude_error_deg": np.round(err, 3).tolist(),
                "left_only_error_deg": np.round(np.degrees(_rotvec(Rl @ R.T)), 3).tolist(),
                "bound_deg": np.round(bound, 3).tolist(),
                "z": np.round(err / bound, 1).tolist(),
            }
        )
    z = np.abs(np.array([r["z"] for r in rows]))
    return {
        "scene": name,
        "seed": seed,
        "scene_options": list(scene_options),
        "tracker_options": list(option),
        "frames": rows,
        "median_abs_z": np.round(np.median(z, axis=0), 1).tolist(),
        "share_abs_z_above_3": np.round(np.mean(z > 3, axis=0), 2).tolist(),
        "motion": motion_summary(np.concatenate(resid), np.concatenate(motion)),
        "by_surface": surface_summary(classes, np.concatenate(resid), np.concatenate(kinds)),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("scenes", nargs="+", help="scenes of bench/stereo.py or hNN")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument(
        "--scene-option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a StereoScene field for every scene (a Python literal), e.g. pixel_samples=3",
    )
    ap.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a TrackerOptions field as in bench/stereo.py, e.g. features.subpixel=False",
    )
    ap.add_argument(
        "--figure",
        metavar="DIR",
        help="write each run's first frame with its landmarks by surface class to DIR",
    )
    args = ap.parse_args(argv)
    if args.figure is not None:
        Path(args.figure).mkdir(parents=True, exist_ok=True)
    if args.frames < 3:
        ap.error(f"--frames must be at least 3; got {args.frames}")
    check_scenes(ap, args.scenes)
    from stereo_diagnose import _scene_by_name

    try:  # the same parser as the command line's --option; checked before any rendering
        for name in args.scenes:
            with_options(_scene_by_name(name, args.frames, 0), args.scene_option, "--scene-option")
    except CommandError as e:
        ap.error(str(e))
    from stereo import tracker_options

    try:
        tracker_options(args.option)
    except ValueError as e:
        ap.error(str(e))
    runs = []
    for name in args.scenes:
        for seed in args.seeds:
            r = frame_bias(name, args.frames, seed, args.scene_option, args.option, args.figure)
            runs.append(r)
            print(f"{name} seed {seed} {' '.join(args.scene_option)} {' '.join(args.option)}")
            print("| frame | obs | sigma px | error x, y, z deg | left only | bound | z |")
            print("|---|---|---|---|---|---|---|")
            for f in r["frames"]:
                print(
                    f"| {f['frame']} | {f['observations']} | {f['sigma_px']} "
                    f"| {f['attitude_error_deg']} | {f['left_only_error_deg']} "
                    f"| {f['bound_deg']} | {f['z']} |"
                )
            print(
                f"median |z| {r['median_abs_z']}, share of frames |z| > 3 "
                f"{r['share_abs_z_above_3']}; along the motion {r['motion']}",
                flush=True,
            )
            print(f"by surface {r['by_surface']}", flush=True)
    print(json.dumps({"frames": args.frames, "runs": runs}))


if __name__ == "__main__":
    main()
