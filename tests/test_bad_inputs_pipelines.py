"""Bad input never passes silently: the rows of the third audit (2026-11-29) on the pipelines, the
PnP solvers' direct arguments and the commands' shared options, in the contract of
``tests/test_bad_inputs.py`` (its expectations and checker, imported from it).
"""

from __future__ import annotations

import json

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_bad_inputs import (
    CAM,
    MONO_CAM,
    POSE,
    Answer,
    Cli,
    CliOk,
    P,
    Raises,
    U,
    _rendered,
    _stereo_argv,
    _stereo_pairs,
    check_row,
)

import jaxpose as jp
from jaxpose import Pose

TABLE: list = []


def row(cls, variant, fn, expect):
    marks = (pytest.mark.typecheck_off,) if isinstance(expect, (Raises, Cli)) else ()
    TABLE.append(pytest.param(cls, variant, fn, expect, id=f"{cls}[{variant}]", marks=marks))


# ------------------------------------------- monocular: an image of another size than the camera
# A transposed image was answered "high" with a pose 0.7 m off; a resized one "low", no message.


def _init(image):
    from jaxpose.pipelines.monocular import initialise_pose

    return initialise_pose(image, MONO_CAM)


row(
    "image-size-not-camera", "transposed", lambda ctx: _init(_rendered().T.copy()), Raises("camera")
)
row(
    "image-size-not-camera",
    "resized",
    lambda ctx: _init(cv2.resize(_rendered(), (960, 600))),
    Raises("camera"),
)


def _init_argv(ctx, image):
    cv2.imwrite(str(ctx.tmp / "img.png"), image)
    jp.save_camera(MONO_CAM, ctx.tmp / "camera.json")
    return ["init", ctx.tmp / "img.png", "--camera", ctx.tmp / "camera.json", "--no-progress"]


row(
    "image-size-not-camera",
    "cli-init-transposed",
    lambda ctx: _init_argv(ctx, _rendered().T.copy()),
    Cli("camera"),
)


def _speedplus_argv(ctx):
    root = ctx.tmp / "sp"
    (root / "images").mkdir(parents=True)
    cv2.imwrite(str(root / "images" / "a.png"), _rendered().T.copy())
    jp.save_camera(MONO_CAM, root / "camera.json")
    (root / "labels.csv").write_text(
        "image,domain,qw,qx,qy,qz,tx,ty,tz\nimages/a.png,x,1,0,0,0,0.05,-0.03,4.0\n"
    )
    return ["eval-speedplus", root, "--json", "--no-progress"]


def _error_row(out, err, ctx):
    summary = json.loads(out.strip().splitlines()[-1])
    text = json.dumps(summary)
    assert "error" in text and "camera" in text, text[:2000]


row("image-size-not-camera", "cli-eval-speedplus", _speedplus_argv, CliOk(_error_row))

# ------------------------------------------------- stereo tracker: a starting pose that is not one
# Behind the camera it tracked "OK" with negative depths; 2 R was OK on the first frame.


def _tracker(pose):
    from jaxpose.pipelines.stereo import StereoTracker

    rig, _ = _stereo_pairs()
    return StereoTracker(rig, pose)


def _start():
    return _stereo_pairs()[1][0].pose


row(
    "initial-pose-not-a-pose",
    "behind-camera",
    lambda ctx: _tracker(Pose(_start().R, jnp.array([0.0, 0.0, -1.2]))),
    Raises("initial_pose"),
)
row(
    "initial-pose-not-a-pose",
    "not-a-rotation",
    lambda ctx: _tracker(Pose(2.0 * _start().R, _start().t)),
    Raises("initial_pose"),
)
row(
    "initial-pose-not-a-pose",
    "a-reflection",
    lambda ctx: _tracker(Pose(_start().R * jnp.array([1.0, 1.0, -1.0]), _start().t)),
    Raises("initial_pose"),
)
row(
    "initial-pose-not-a-pose",
    "a-tuple",
    lambda ctx: _tracker((_start().R, _start().t)),
    Raises("initial_pose"),
)
row(
    "initial-pose-not-a-pose",
    "a-batch",
    lambda ctx: _tracker(Pose(jnp.stack([_start().R] * 2), jnp.stack([_start().t] * 2))),
    Raises("initial_pose"),
)

# ------------------------------------------- PnP: planar_tol given to the solver, not PnPOptions
# EPnP took -1 or 2 and answered OK 25 mm off on noise-free data.

for value in (-1.0, 2.0, float("nan"), "x", True):
    row(
        "planar-tol-direct",
        f"epnp-{value}",
        lambda ctx, v=value: jp.epnp(P, U, CAM, planar_tol=v),
        Raises("planar_tol"),
    )
row(
    "planar-tol-direct",
    "dlt-nan",
    lambda ctx: jp.dlt(P, U, CAM, planar_tol=float("nan")),
    Raises("planar_tol"),
)
row(
    "planar-tol-direct",
    "ransac-2",
    lambda ctx: jp.ransac_pnp(P, U, CAM, key=jax.random.key(0), planar_tol=2.0),
    Raises("planar_tol"),
)

# --------------------------------------------- RANSAC: a plan too large to draw, a key that is not
# 0.9 outliers planned 6.9 million hypotheses at once and died allocating 42 GB.

row(
    "ransac-plan-too-large",
    "outlier-fraction-0.9",
    lambda ctx: jp.RansacOptions(max_outlier_fraction=0.9),
    Raises("max_outlier_fraction", "confidence"),
)
row(
    "ransac-plan-too-large",
    "num-hypotheses-1e6",
    lambda ctx: jp.RansacOptions(num_hypotheses=10**6),
    Raises("num_hypotheses"),
)
row("ransac-key", "none", lambda ctx: jp.ransac_pnp(P, U, CAM, key=None), Raises("key"))
row(
    "ransac-key",
    "solve-pnp-int",
    lambda ctx: jp.solve_pnp(P, U, CAM, key=3, options=jp.PnPOptions(method="ransac")),
    Raises("key"),
)


def _ransac_answers(res):
    np.testing.assert_allclose(np.asarray(res.t), np.asarray(POSE.t), atol=1e-6)


row(
    "ransac-plan-too-large",
    "four-point-samples-still-run",
    lambda ctx: jp.ransac_pnp(
        P,
        U,
        CAM,
        key=jax.random.key(0),
        options=jp.RansacOptions(max_outlier_fraction=0.8, sample_size=4),
    ),
    Answer(_ransac_answers),
)

# ------------------------------------------------------------- pose-study: no NaN, no huge plan
# --noise 1e6 died after the work on "not JSON compliant: nan"; --trials 1e9 ran out of memory.


def _no_converged(out, err, ctx):
    groups = json.loads((ctx.tmp / "ps" / "results.json").read_text())["groups"]
    wild = [g for g in groups if g["noise_px"] == 1e6]
    assert wild and all(g["ratio"] is None and "converged" in g["message"] for g in wild), wild
    assert "converged" in out


row(
    "pose-study-no-figure",
    "noise-1e6",
    lambda ctx: [
        "pose-study",
        "--trials",
        "3",
        "--geometries",
        "cube-3m",
        "--noise",
        "1e6",
        "--out",
        ctx.tmp / "ps",
        "--no-figures",
        "--no-progress",
    ],
    CliOk(_no_converged),
)
row(
    "pose-study-no-figure",
    "trials-1e9",
    lambda ctx: ["pose-study", "--trials", "1000000000", "--out", ctx.tmp / "ps"],
    Cli("--trials"),
)

# ---------------------------------------------------------- --out that cannot be made a folder
# The commands failed with "[Errno 20] Not a directory: '.../chunks'", naming no option, some
# after the work.


def _a_file(ctx):
    (ctx.tmp / "a-file").write_text("")
    return ctx.tmp / "a-file"


for command, extra in [
    ("demo", []),
    ("select-study", ["--n", "8", "--m", "5", "--cases", "2"]),
    ("pose-study", ["--trials", "3"]),
]:
    for name, below in [("a-file", ""), ("under-a-file", "sub")]:
        row(
            "out-not-a-folder",
            f"{command}-{name}",
            lambda ctx, c=command, e=extra, b=below: [c, *e, "--out", _a_file(ctx) / b],
            Cli("--out"),
        )


def _stereo_out_under_file(ctx):
    argv = _stereo_argv(ctx)
    return [
        *argv[: argv.index("--out") + 1],
        _a_file(ctx) / "sub",
        *argv[argv.index("--out") + 2 :],
    ]


row("out-not-a-folder", "stereo-track-under-a-file", _stereo_out_under_file, Cli("--out"))

# ------------------------------------------------ stereo-track: more frames than the folder holds

row(
    "frames-beyond-folder",
    "ten-of-three",
    lambda ctx: _stereo_argv(ctx, "--frames", "10"),
    Cli("--frames"),
)
row(
    "frames-beyond-folder",
    "four-of-three",
    lambda ctx: _stereo_argv(ctx, "--frames", "4"),
    Cli("--frames"),
)


# ---------------------------------------------------- arguments named as the caller names them
# sensitivity named "pose0" for its "pose"; pose_covariance's lines met opt_einsum's "label 'k'";
# save_camera of a K matrix died on "no attribute 'width'".

SEG = jnp.stack([P[:8], P[1:9]], 1)
row(
    "named-as-called",
    "sensitivity-pose",
    lambda ctx: jp.sensitivity(P, U, "pose", CAM),
    Raises("pose"),
)
row(
    "named-as-called",
    "covariance-lines-length",
    lambda ctx: jp.pose_covariance(P, POSE, CAM, segments_body=SEG, lines_img=jnp.ones((3, 3))),
    Raises("lines_img"),
)
row(
    "named-as-called",
    "save-camera-K",
    lambda ctx: jp.save_camera(np.asarray(CAM.K), ctx.tmp / "k.json"),
    Raises("camera"),
)


# ------------------------------------------------------------------------ throw= not a bool
# None was taken as False (no raise where one was asked for) and "no" as True.

for value in (None, "no", 0):
    row(
        "throw-not-a-bool",
        f"dop-{value}",
        lambda ctx, v=value: jp.dop(P, Pose(POSE.R, jnp.array([0.0, 0.0, -5.0])), CAM, throw=v),
        Raises("throw"),
    )
row(
    "throw-not-a-bool",
    "solve-pnp-none",
    lambda ctx: jp.solve_pnp(P, U, CAM, throw=None),
    Raises("throw"),
)
row(
    "throw-not-a-bool",
    "refine-none",
    lambda ctx: jp.refine_pose(P, U, POSE, CAM, throw=None),
    Raises("throw"),
)


# --------------------------------------------------- arrays of complex numbers, objects, strings
# Complex points or pixels lost their imaginary part silently; objects or strings met JAX's
# "Error interpreting argument", which names no argument.

for kind, convert in [
    ("complex", lambda a: np.asarray(a) + 1j),
    ("object", lambda a: np.asarray(a).astype(object)),
    ("strings", lambda a: np.asarray(a).astype(str)),
]:
    row(
        "arrays-not-real",
        f"dop-points-{kind}",
        lambda ctx, c=convert: jp.dop(c(P), POSE, CAM),
        Raises("points_body"),
    )
    row(
        "arrays-not-real",
        f"solve-pnp-pixels-{kind}",
        lambda ctx, c=convert: jp.solve_pnp(P, c(U), CAM),
        Raises("pixels"),
    )
row(
    "arrays-not-real",
    "epnp-points-complex",
    lambda ctx: jp.epnp(np.asarray(P) + 1j, U, CAM),
    Raises("points_body"),
)
row(
    "arrays-not-real",
    "refine-pixels-complex",
    lambda ctx: jp.refine_pose(P, np.asarray(U) + 1j, POSE, CAM),
    Raises("pixels"),
)


@pytest.mark.parametrize("cls, variant, fn, expect", TABLE)
def test_bad_input_third_audit(cls, variant, fn, expect, tmp_path, capsys):
    check_row(cls, variant, fn, expect, tmp_path, capsys)


def test_a_start_in_front_of_the_camera_still_tracks():
    """The checks refuse nothing that was right: the true start and the identity start."""
    rig, frames = _stereo_pairs()
    for start in (frames[0].pose, None, Pose.identity()):
        tracker = _tracker(start)
        res = tracker.process(frames[0].left, frames[0].right)
        assert int(res.status) == int(jp.Status.OK)
