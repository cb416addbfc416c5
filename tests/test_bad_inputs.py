"""Bad input never passes silently (issue 14): one table, one row per class of bad input and
variant, each with the contract it must meet.

Expectations (see ``docs/errors.md``):

* :class:`Raises`: a ``ValueError`` whose message names the argument, option, file or field;
* :class:`Returns`: a result whose ``status`` is one of the documented members and which holds
  no NaN (``inf`` is allowed where a figure does not exist);
* :class:`Answer`: the right answer, compared with an independent reference;
* :class:`Cli`: ``jaxpose COMMAND ...`` exits with status 2 and prints one line
  ``jaxpose COMMAND: error: ...`` naming the option or file, no traceback;
  :class:`CliOk`: it exits 0 and its output passes a check.

Every class of the audit (the 18 silent-wrong or NaN answers, the 10 unclear errors, the 3 hangs
and the 30 that held) has several rows with other values of the same class; so has each class
of the second audit, of the surfaces added later (line blocks, the stereo tracker, its CLI).
"""

from __future__ import annotations

import json
import re
import signal
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose as jp
from jaxpose import PinholeCamera, Pose, Status, StereoCamera
from jaxpose.core.geometry import euler_to_dcm

# --------------------------------------------------------------------------- the scene

K = [[1000.0, 0.0, 320.0], [0.0, 1000.0, 240.0], [0.0, 0.0, 1.0]]
CAM = PinholeCamera.from_K(K)
POSE = Pose.from_euler(jnp.array([0.1, 0.2, 0.3]), jnp.array([0.1, -0.1, 5.0]))


def _points(seed=0, n=10):
    return jnp.asarray(np.random.default_rng(seed).uniform(-1.0, 1.0, (n, 3)))


P = _points()
U = CAM.project(POSE.apply(P))


def _collinear(direction=(1.0, 2.0, 0.5), n=10, offset=(0.1, 0.0, 0.2)):
    s = np.linspace(-1.0, 1.0, n)[:, None]
    return jnp.asarray(s * np.asarray(direction) / np.linalg.norm(direction) + np.asarray(offset))


def _coincident(n=10):
    return jnp.asarray(np.tile([[0.2, -0.1, 0.3]], (n, 1)))


PCOL = _collinear()
UCOL = CAM.project(POSE.apply(PCOL))
RG = euler_to_dcm(jnp.array([0.3, np.pi / 2, 0.2]))


def _pix(points, pose=POSE, camera=CAM):
    return camera.project(pose.apply(points))


def _with(a, index, value):
    a = np.array(a, dtype=float)
    a[index] = value
    return jnp.asarray(a)


@cache
def _blocks(n=10, seed=0):
    return jp.information_blocks(_points(seed, n), POSE, CAM)


# --------------------------------------------------------------------------- expectations


@dataclass(frozen=True)
class Raises:
    """``ValueError`` naming every one of ``names`` (as whole words)."""

    names: tuple[str, ...]

    def __init__(self, *names):
        object.__setattr__(self, "names", names)


@dataclass(frozen=True)
class Returns:
    """A result with a ``status`` among ``statuses`` and no NaN in its floating-point leaves."""

    statuses: tuple[int, ...]
    nan_ok: tuple[str, ...] = ()

    def __init__(self, *statuses, nan_ok=()):
        object.__setattr__(self, "statuses", tuple(int(s) for s in statuses))
        object.__setattr__(self, "nan_ok", tuple(nan_ok))


@dataclass(frozen=True)
class Answer:
    """The callable's return value passes ``check`` (which asserts against a reference)."""

    check: Callable


@dataclass(frozen=True)
class Cli:
    """``jaxpose argv`` exits 2 with one error line naming every one of ``names``."""

    names: tuple[str, ...]

    def __init__(self, *names):
        object.__setattr__(self, "names", names)


@dataclass(frozen=True)
class CliOk:
    """``jaxpose argv`` exits 0; ``check(out, err, ctx)`` asserts on its output."""

    check: Callable


@dataclass
class Ctx:
    """What a row's callable may use: a fresh folder."""

    tmp: Path
    data: dict = field(default_factory=dict)


def _named(name: str, message: str) -> bool:
    return re.search(rf"(?<![\w-]){re.escape(name)}(?!\w)", message) is not None


def _nan_free(tree, skip=()) -> list[str]:
    bad = []
    leaves = jax.tree_util.tree_leaves_with_path(tree)
    for path, leaf in leaves:
        name = jax.tree_util.keystr(path)
        if any(s in name for s in skip):
            continue
        a = np.asarray(leaf)
        if np.issubdtype(a.dtype, np.floating) and np.isnan(a).any():
            bad.append(name)
    return bad


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout


LIMIT_S = 300  # no single row may run longer (the hangs of the audit ran until killed)


def _run_cli(argv, capsys):
    from jaxpose.cli import main

    try:
        code = main([str(a) for a in argv])
    except SystemExit as done:
        code = done.code
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _check(fn, expect, ctx, capsys):
    if isinstance(expect, Raises):
        with pytest.raises(ValueError) as err:
            fn(ctx)
        message = str(err.value)
        for name in expect.names:
            assert _named(name, message), f"{name!r} not named in: {message}"
    elif isinstance(expect, Returns):
        res = fn(ctx)
        status = np.asarray(res.status)
        allowed = set(expect.statuses)
        assert set(np.unique(status).tolist()) <= allowed, (
            f"status {np.unique(status).tolist()} not in {sorted(allowed)}"
        )
        assert not _nan_free(res, expect.nan_ok), f"NaN in {_nan_free(res, expect.nan_ok)}"
    elif isinstance(expect, Answer):
        expect.check(fn(ctx))
    elif isinstance(expect, Cli):
        code, out, err = _run_cli(fn(ctx), capsys)
        lines = [ln for ln in err.strip().splitlines() if ln.strip()]
        errors = [ln for ln in lines if ": error: " in ln]
        assert code == 2, f"exit {code}; stderr: {err[-2000:]}"
        assert "Traceback" not in err, err
        assert len(errors) == 1 and re.match(r"^jaxpose [\w-]+: error: \S", errors[0]), lines
        for name in expect.names:
            assert _named(name, errors[0]), f"{name!r} not named in: {errors[0]}"
    elif isinstance(expect, Within):
        proc = _child(expect.code.replace("{tmp}", str(ctx.tmp / "out")), expect.limit_s)
        text = proc.stdout + proc.stderr
        if "ValueError:" in proc.stdout:
            message = proc.stdout.split("ValueError:", 1)[1]
        else:
            assert proc.returncode == 2 and "Traceback" not in text, text[-2000:]
            message = proc.stderr
        for name in expect.names:
            assert _named(name, message), f"{name!r} not named in: {message}"
    elif isinstance(expect, CliOk):
        code, out, err = _run_cli(fn(ctx), capsys)
        assert code == 0, f"exit {code}; stderr: {err[-2000:]}"
        assert "Traceback" not in err, err
        expect.check(out, err, ctx)
    else:  # pragma: no cover
        raise TypeError(expect)


# --------------------------------------------------------------------------- reference checks


def _close(reference, rtol=1e-6, atol=1e-9):
    def check(value):
        np.testing.assert_allclose(np.asarray(value), np.asarray(reference), rtol=rtol, atol=atol)

    return check


def _finite(value):
    leaves = jax.tree_util.tree_leaves(value)
    assert leaves and all(np.all(np.isfinite(np.asarray(x))) for x in leaves), value


def _is_identity(pose):
    np.testing.assert_allclose(np.asarray(pose.R), np.eye(3), atol=1e-12)


def _tangent_pdop(R, t=POSE.t, points=P):
    return jp.dop(points, Pose(R, t), CAM, parameterization="tangent", throw=False).pdop


def _gimbal_grad_check(R, sequence):
    def check(grad):
        ref = jax.grad(_tangent_pdop)(R)
        assert np.all(np.isfinite(np.asarray(grad))), grad
        # PDOP does not depend on how the attitude is parameterised (a Schur complement), so
        # its gradient at gimbal lock is the tangent parameterisation's.
        np.testing.assert_allclose(np.asarray(grad), np.asarray(ref), rtol=1e-5, atol=1e-9)

    return check


def _gimbal_value_check(R):
    def check(res):
        np.testing.assert_allclose(float(res.pdop), float(_tangent_pdop(R)), rtol=1e-8)

    return check


# --------------------------------------------------------------------------- images (monocular)

MONO_CAM = PinholeCamera(
    747.0, 747.0, 239.5, 149.5, [-0.22, 0.51, 0.0, 0.0, -0.13], width=480, height=300
)


@cache
def _rendered():
    from jaxpose.vision.models import tango
    from jaxpose.vision.render import render

    pose = Pose(np.asarray(euler_to_dcm(jnp.array([2.3, 0.4, 0.6]))), np.array([0.05, -0.03, 4.0]))
    return render(tango(), pose, MONO_CAM, rng=7).image


def _init(image):
    from jaxpose.pipelines.monocular import initialise_pose

    return initialise_pose(image, MONO_CAM)


def _gray(image):
    from jaxpose.vision.features import to_gray

    return to_gray(image)


def _same_gray_as_8_bit(gray):
    """``initialise_pose`` reads its image only through ``to_gray`` (in ``detect``) and is
    deterministic, so the same 8-bit image gives the same pose (``test_monocular.py``'s
    ``test_image_depths_give_the_same_pose`` checks that end to end); the rows check the 8-bit
    image, to the bit."""
    np.testing.assert_array_equal(gray, _rendered())


def _no_target(res):
    assert res.confidence in ("none", "position-only"), res.confidence
    assert res.message


def _colour(gray, dtype, scale):
    return (np.repeat(gray[..., None], 3, axis=2).astype(np.float64) * scale).astype(dtype)


# --------------------------------------------------------------------------- files


def _camera_json(ctx, **override):
    data = {
        "Nu": 480,
        "Nv": 300,
        "cameraMatrix": np.asarray(MONO_CAM.K).tolist(),
        "distCoeffs": np.asarray(MONO_CAM.dist).tolist(),
    }
    for k, v in override.items():
        if v is _DROP:
            data.pop(k, None)
        else:
            data[k] = v
    path = ctx.tmp / "camera.json"
    path.write_text(json.dumps(data))
    return path


_DROP = object()


def _image_file(ctx, image=None):
    """``img.png``: the rendered Tango, or ``image``."""
    path = ctx.tmp / "img.png"
    cv2.imwrite(str(path), _rendered() if image is None else image)
    return path


def _init_argv(ctx, **override):
    return ["init", _image_file(ctx), "--camera", _camera_json(ctx, **override)]


def _load_camera(ctx, **override):
    return jp.load_camera(_camera_json(ctx, **override))


LABEL_HEADER = "image,domain,qw,qx,qy,qz,tx,ty,tz"
GOOD_ROW = "img.png,rendered,1,0,0,0,0.1,0.2,5"


def _labels(ctx, row, image=None):
    _image_file(ctx, image)
    _camera_json(ctx)
    (ctx.tmp / "labels.csv").write_text(f"{LABEL_HEADER}\n{GOOD_ROW}\n{row}\n")
    return ctx.tmp


def _load_labels(ctx, row):
    from jaxpose.io import load_speed_labels

    return load_speed_labels(_labels(ctx, row))


# --------------------------------------------------------------------------- stereo folders

SW, SH = 320, 240


@cache
def _stereo_pairs():
    from jaxpose.vision.stereo_render import StereoScene, default_rig, render_stereo_frame

    rig = default_rig(SW, SH)
    scene = StereoScene(frames=3, range_m=1.2)
    return rig, [render_stereo_frame(scene, rig, k) for k in range(3)]


def _stereo_folder(ctx, *, n=3, calibration=None, raw_calibration=None, size=None, spoil=None):
    rig, frames = _stereo_pairs()
    path = ctx.tmp / "pairs"
    (path / "left").mkdir(parents=True)
    (path / "right").mkdir()
    for fr in frames[:n]:
        left, right = fr.left, fr.right
        if size is not None:
            left, right = cv2.resize(left, size), cv2.resize(right, size)
        cv2.imwrite(str(path / "left" / f"{fr.index:06d}.png"), left)
        cv2.imwrite(str(path / "right" / f"{fr.index:06d}.png"), right)
    if spoil is not None:
        spoil(path)
    cam = {"Nu": SW, "Nv": SH, "cameraMatrix": np.asarray(rig.left.K).tolist()}
    data = {"left": cam, "right": cam, "R_rl": np.eye(3).tolist(), "t_rl": [-0.3, 0.0, 0.0]}
    if calibration is not None:
        data = calibration(data)
    text = raw_calibration if raw_calibration is not None else json.dumps(data)
    (path / "calibration.json").write_text(text)
    return path


def _stereo_argv(ctx, *extra, **folder):
    path = _stereo_folder(ctx, **folder)
    ctx.data["folder"] = path
    return [
        "stereo-track",
        "--images",
        path,
        "--out",
        ctx.tmp / "out",
        "--no-figures",
        "--no-progress",
        "--json",
        *extra,
    ]


def _json_line(out):
    return json.loads(out.strip().splitlines()[-1])


def _no_nan_json(out, err, ctx):
    text = out.strip().splitlines()[-1]
    assert "NaN" not in text and "Infinity" not in text, text
    json.loads(text)


def _frames_honoured(k):
    def check(out, err, ctx):
        summary = _json_line(out)
        assert summary["frames"] == k, summary
        _no_nan_json(out, err, ctx)

    return check


def _drop(key, side=None):
    def edit(data):
        if side is None:
            data.pop(key)
        else:
            data[side].pop(key)
        return data

    return edit


def _set(key, value, side=None):
    def edit(data):
        (data if side is None else data[side])[key] = value
        return data

    return edit


def _unreadable(name):
    def spoil(path):
        (path / "left" / name).write_bytes(b"not a png at all")

    return spoil


def _tracker_first_frame(left, right):
    from jaxpose.pipelines.stereo import StereoTracker

    rig, frames = _stereo_pairs()
    tracker = StereoTracker(rig, frames[0].pose)
    return tracker.process(left, right)


def _tracker_says_no_pose(res):
    assert int(res.status) in (Status.TOO_FEW_POINTS, Status.LOST), res.status
    assert res.n_points == 0 or int(res.status) != Status.OK


# --------------------------------------------------------------------------- studies

STUDY = ["--no-figures", "--no-progress"]


def _study(*argv):
    def fn(ctx):
        return [argv[0], "--out", ctx.tmp / "out", *STUDY, *argv[1:]]

    return fn


SMALL_SELECT = ["select-study", "--n", "8", "--m", "5", "--cases", "6", "--chunk-size", "3"]


def _groups(folder):
    data = json.loads((folder / "results.json").read_text())
    keep = ("n", "m", "cases", "pdop_ratio_mean", "pdop_ratio_max", "adop_ratio_mean")
    return [{k: g.get(k) for k in keep if k in g} for g in data["groups"]]


@cache
def _select_reference(tmp):
    from jaxpose.cli import main

    out = Path(tmp) / "reference"
    assert main([*SMALL_SELECT, "--out", str(out), *STUDY]) == 0
    return out


def _resume(spoil):
    """A complete run, then ``spoil`` its chunk files, then the same run again (resumed)."""

    def fn(ctx):
        ref = _select_reference(str(ctx.tmp.parent))
        out = ctx.tmp / "out"
        from shutil import copytree

        copytree(ref, out)
        (out / "results.json").unlink()
        chunks = sorted((out / "chunks").glob("*.npz"))
        assert len(chunks) >= 2, chunks
        ctx.data["spoiled"] = spoil(chunks)
        ctx.data["reference"] = ref
        return [*SMALL_SELECT, "--out", out, *STUDY]

    return fn


def _same_results(out, err, ctx):
    assert _groups(ctx.tmp / "out") == _groups(ctx.data["reference"])
    for name in ctx.data.get("spoiled", []):
        # a corrupt chunk is recomputed with a one-line warning naming it
        assert "warning" in err and name in err, err


def _truncate(chunks):
    data = chunks[0].read_bytes()
    chunks[0].write_bytes(data[: len(data) // 2])
    return [chunks[0].name]


def _garbage(chunks):
    chunks[-1].write_bytes(b"PK\x03\x04 garbage")
    return [chunks[-1].name]


def _empty(chunks):
    chunks[0].write_bytes(b"")
    return [chunks[0].name]


def _kill(chunks):
    chunks[-1].unlink()  # the run was killed before it wrote its last chunk
    return []


def _fresh_same_seed(ctx):
    ctx.data["reference"] = _select_reference(str(ctx.tmp.parent))
    return [*SMALL_SELECT, "--out", ctx.tmp / "out", *STUDY]


# --------------------------------------------------------------------------- the table

Row = tuple[str, str, Callable, object]
TABLE: list[Row] = []


def row(cls: str, variant: str, fn: Callable, expect, *marks):
    if isinstance(expect, (Raises, Cli)):
        # jaxtyping's hook would meet a badly typed or shaped argument with its own TypeCheckError
        # before the package's ValueError; a user sees the package's.
        marks = (*marks, pytest.mark.typecheck_off)
    TABLE.append(pytest.param(cls, variant, fn, expect, id=f"{cls}[{variant}]", marks=marks))


def xfail(reason):
    return pytest.mark.xfail(strict=True, reason=f"not handled yet: {reason}")


def pnp(points, pixels, camera=CAM, **kw):
    return lambda ctx: jp.solve_pnp(points, pixels, camera() if callable(camera) else camera, **kw)


# ---- the 18 silent wrong answers or NaN ----------------------------------------------------

# A negative or zero focal length is not a camera (it mirrored the translation).
row(
    "negative-focal",
    "both",
    pnp(P, U, lambda: PinholeCamera(-1000.0, -1000.0, 320, 240)),
    Raises("fx"),
)
row("negative-focal", "fy", lambda ctx: PinholeCamera(800.0, -1.0, 320, 240), Raises("fy"))
row("negative-focal", "tiny-negative", lambda ctx: PinholeCamera(-1e-9, 800.0, 0, 0), Raises("fx"))
row("negative-focal", "K", lambda ctx: PinholeCamera.from_K(_with(K, (0, 0), -500.0)), Raises("K"))
row(
    "negative-focal",
    "K-solve",
    lambda ctx: jp.solve_pnp(P, U, _with(K, (1, 1), -1000.0)),
    Raises("K"),
)
row("negative-focal", "K-dop", lambda ctx: jp.dop(P, POSE, _with(K, (0, 0), -1.0)), Raises("K"))

# A pose whose R is not a rotation.
for name, R in [
    ("scaled", 2.0 * jnp.eye(3)),
    ("reflection", jnp.diag(jnp.array([1.0, 1.0, -1.0]))),
    ("shear", jnp.eye(3).at[0, 1].set(0.3)),
    ("near-rotation", POSE.R * 1.001),
    ("zero", jnp.zeros((3, 3))),
]:
    bad = Pose(R, POSE.t)
    row(
        "not-a-rotation",
        f"dop-{name}",
        lambda ctx, b=bad: jp.dop(P, b, CAM),
        Raises("R", "rotation"),
    )
    row(
        "not-a-rotation",
        f"dop-lanes-{name}",
        lambda ctx, b=bad: jp.dop(P, b, CAM, throw=False),
        Returns(Status.NOT_A_ROTATION),
    )
    row(
        "not-a-rotation",
        f"refine-{name}",
        lambda ctx, b=bad: jp.refine_pose(P, U, b, CAM),
        Raises("R", "rotation"),
    )
row(
    "not-a-rotation",
    "refine-lanes",
    lambda ctx: jp.refine_pose(P, U, Pose(2 * POSE.R, POSE.t), CAM, throw=False),
    Returns(Status.NOT_A_ROTATION),
)
row(
    "not-a-rotation",
    "select",
    lambda ctx: jp.select_features(P, Pose(2 * POSE.R, POSE.t), CAM, 5),
    Raises("R", "rotation"),
)

# A quaternion of zero norm has no direction.
for name, q in [("zeros", [0.0, 0, 0, 0]), ("zeros-batch", [[1.0, 0, 0, 0], [0, 0, 0, 0]])]:
    row(
        "zero-quaternion",
        name,
        lambda ctx, q=q: Pose.from_quat(jnp.asarray(q), jnp.zeros(3)).R,
        Raises("q"),
    )
row(
    "zero-quaternion", "quat_to_dcm", lambda ctx: jp.geometry.quat_to_dcm(jnp.zeros(4)), Raises("q")
)
row(
    "zero-quaternion",
    "tiny-is-a-direction",
    lambda ctx: Pose.from_quat(jnp.array([1e-200, 0.0, 0.0, 0.0]), jnp.zeros(3)),
    Answer(_is_identity),
)
row(
    "zero-quaternion",
    "tiny-float32",
    lambda ctx: Pose.from_quat(
        jnp.array([0.0, 3e-30, 0.0, 0.0], jnp.float32), jnp.zeros(3, jnp.float32)
    ),
    Answer(
        lambda p: np.testing.assert_allclose(np.asarray(p.R), np.diag([1.0, -1.0, -1.0]), atol=1e-6)
    ),
)

# A negative, zero or non-finite sigma (pixel noise).
for name, s in [
    ("negative", -1.0),
    ("zero", 0.0),
    ("nan", np.nan),
    ("inf", np.inf),
    ("one-negative", _with(np.ones(10), 3, -2.0)),
]:
    row("bad-sigma", f"dop-{name}", lambda ctx, s=s: jp.dop(P, POSE, CAM, sigma=s), Raises("sigma"))
    row(
        "bad-sigma",
        f"blocks-{name}",
        lambda ctx, s=s: jp.information_blocks(P, POSE, CAM, sigma=s),
        Raises("sigma"),
    )
row(
    "bad-sigma",
    "refine-negative",
    lambda ctx: jp.refine_pose(P, U, POSE, CAM, sigma=-1.0),
    Raises("sigma"),
)
row(
    "bad-sigma",
    "select-negative",
    lambda ctx: jp.select_features(P, POSE, CAM, 5, method="greedy", sigma=-1.0),
    Raises("sigma"),
)

# A non-integer (or out of range) subset size m.
for name, m in [("4.7", 4.7), ("5.0", 5.0), ("str", "5"), ("bool", True), ("3", 3), ("11", 11)]:
    row(
        "bad-m",
        f"bnb-{name}",
        lambda ctx, m=m: jp.select.branch_and_bound(_blocks(), m),
        Raises("m"),
    )
    row(
        "bad-m",
        f"exhaustive-{name}",
        lambda ctx, m=m: jp.select.exhaustive(_blocks(), m),
        Raises("m"),
    )
row("bad-m", "greedy-4.5", lambda ctx: jp.select.greedy(_blocks(), 4.5), Raises("m"))
row("bad-m", "select-6.2", lambda ctx: jp.select_features(P, POSE, CAM, 6.2), Raises("m"))
row(
    "bad-m",
    "quasi-np-float",
    lambda ctx: jp.select.quasi_optimal(POSE.apply(P), np.float64(5.5)),
    Raises("m"),
)

# DOP-based selection on points with no non-singular subset.
for method in ("greedy", "exhaustive", "bnb"):
    for name, pts in [
        ("collinear", PCOL),
        ("collinear-z", _collinear((0, 0, 1.0))),
        ("coincident", _coincident()),
    ]:
        row(
            "select-singular",
            f"{method}-{name}",
            lambda ctx, m=method, p=pts: jp.select_features(p, POSE, CAM, 5, method=m),
            Raises("singular"),
        )

# subset_dop with an index outside [0, n).
for name, idx in [("99", [0, 1, 2, 99]), ("n", [0, 1, 2, 10]), ("negative", [-1, 0, 1, 2])]:
    row(
        "subset-index",
        name,
        lambda ctx, i=idx: jp.select.subset_dop(_blocks(), jnp.array(i)),
        Raises("idx"),
    )
    row(
        "subset-index",
        f"jit-{name}",
        lambda ctx, i=idx: jax.jit(jp.select.subset_dop)(_blocks(), jnp.array(i))[0],
        Answer(lambda v: np.testing.assert_equal(float(v), np.inf)),
    )
row(
    "subset-index",
    "float-idx",
    lambda ctx: jp.select.subset_dop(_blocks(), jnp.array([0.0, 1, 2, 3])),
    Raises("idx"),
)

# sensitivity at a singular Hessian (collinear or coincident points).
for name, pts in [
    ("collinear", PCOL),
    ("collinear-y", _collinear((0, 1.0, 0))),
    ("coincident", _coincident()),
]:
    pix = _pix(pts)
    row(
        "sensitivity-singular",
        name,
        lambda ctx, p=pts, u=pix: jp.sensitivity(p, u, POSE, CAM, throw=False),
        Returns(Status.SINGULAR),
    )
    row(
        "sensitivity-singular",
        f"throw-{name}",
        lambda ctx, p=pts, u=pix: jp.sensitivity(p, u, POSE, CAM),
        Raises("singular"),
    )

# sensitivity with NaN or inf input.
for name, kw in [
    ("nan-pixel", dict(pixels=_with(U, (2, 0), np.nan))),
    ("inf-pixel", dict(pixels=_with(U, (0, 1), np.inf))),
    ("nan-point", dict(points_body=_with(P, (4, 2), np.nan))),
]:
    args = dict(points_body=P, pixels=U) | kw
    row(
        "sensitivity-nonfinite",
        name,
        lambda ctx, a=args: jp.sensitivity(a["points_body"], a["pixels"], POSE, CAM, throw=False),
        Returns(Status.NONFINITE_INPUT),
    )
row(
    "sensitivity-nonfinite",
    "nan-pose",
    lambda ctx: jp.sensitivity(P, U, Pose(POSE.R, _with(POSE.t, 0, np.nan)), CAM, throw=False),
    Returns(Status.NONFINITE_INPUT),
)

# Triangulating a NaN or inf pixel: never a NaN point (inf: no point), the others unchanged.
RIG = StereoCamera.from_baseline(CAM, 0.3)
XL, XR = RIG.project(POSE.apply(P))


def _triangulated(row_index, method="linear"):
    def check(points):
        points = np.asarray(points)
        assert not np.isnan(points).any(), points
        assert not np.isfinite(points[row_index]).all(), points[row_index]
        keep = np.ones(len(points), bool)
        keep[row_index] = False
        np.testing.assert_allclose(points[keep], np.asarray(POSE.apply(P))[keep], atol=1e-8)

    return check


for name, (left, right) in {
    "nan-left": (_with(XL, (3, 0), np.nan), XR),
    "nan-right": (XL, _with(XR, (5, 1), np.nan)),
    "inf-left": (_with(XL, (7, 1), np.inf), XR),
}.items():
    idx = {"nan-left": 3, "nan-right": 5, "inf-left": 7}[name]
    for method in ("linear", "midpoint"):
        row(
            "triangulate-nonfinite",
            f"{name}-{method}",
            lambda ctx, a=left, b=right, m=method: RIG.triangulate(a, b, method=m),
            Answer(_triangulated(idx)),
        )

# Gradients at singular points: gimbal lock of the Euler state, collinear points.
for name, (angles, seq) in {
    "XYZ+90": ([0.3, np.pi / 2, 0.2], "XYZ"),
    "XYZ-90": ([-0.4, -np.pi / 2, 0.1], "XYZ"),
    "ZYX+90": ([0.2, np.pi / 2, -0.5], "ZYX"),
}.items():
    Rl = euler_to_dcm(jnp.array(angles), seq)
    row(
        "gimbal-lock-grad",
        name,
        lambda ctx, R=Rl, s=seq: jax.jit(
            jax.grad(lambda R: jp.dop(P, Pose(R, POSE.t), CAM, sequence=s, throw=False).pdop)
        )(R),
        Answer(_gimbal_grad_check(Rl, seq)),
    )
    row(
        "gimbal-lock-grad",
        f"value-{name}",
        lambda ctx, R=Rl, s=seq: jp.dop(P, Pose(R, POSE.t), CAM, sequence=s, throw=False),
        Answer(_gimbal_value_check(Rl)),
    )

for name, pts in [
    ("collinear", PCOL),
    ("coincident", _coincident()),
    ("collinear-x", _collinear((1.0, 0, 0))),
]:
    pix = _pix(pts)
    row(
        "pnp-grad-degenerate",
        name,
        lambda ctx, p=pts, u=pix: jax.grad(
            lambda x: jp.solve_pnp(p, x, CAM, throw=False).pose.t.sum()
        )(u),
        Answer(_finite),
    )
row(
    "pnp-grad-degenerate",
    "nan-pixel",
    lambda ctx: jax.grad(lambda x: jp.solve_pnp(P, x, CAM, throw=False).pose.t.sum())(
        _with(U, (0, 0), np.nan)
    ),
    Answer(lambda g: np.testing.assert_equal(np.isnan(np.asarray(g)).any(), False)),
)

# A 16-bit or floating-point image gives the pose of its 8-bit version: the same 8-bit image, which
# is all the pipeline reads (_same_gray_as_8_bit; end to end in test_monocular.py).
row(
    "image-depth",
    "uint16",
    lambda ctx: _gray(_rendered().astype(np.uint16) * 257),
    Answer(_same_gray_as_8_bit),
)
row(
    "image-depth",
    "float32-unit",
    lambda ctx: _gray(_rendered().astype(np.float32) / 255),
    Answer(_same_gray_as_8_bit),
)
row(
    "image-depth",
    "uint16-colour",
    lambda ctx: _gray(_colour(_rendered(), np.uint16, 257)),
    Answer(_same_gray_as_8_bit),
)

# camera.json with non-finite or miscounted distortion coefficients.
for name, dist in [
    ("nan", [float("nan"), 0, 0, 0, 0]),
    ("inf", [0, float("inf"), 0, 0, 0]),
    ("three", [0.1, 0.2, 0.3]),
]:
    row(
        "camera-distortion",
        f"init-{name}",
        lambda ctx, d=dist: _init_argv(ctx, distCoeffs=d),
        Cli("distCoeffs", "camera.json"),
    )
    row(
        "camera-distortion",
        f"load-{name}",
        lambda ctx, d=dist: _load_camera(ctx, distCoeffs=d),
        Raises("distCoeffs"),
    )

# The stereo tracker on an all-NaN (or all-inf) first frame: no pose, a status that says so.
for name, value in [("nan", np.nan), ("inf", np.inf), ("neg-inf", -np.inf)]:
    img = np.full((SH, SW), value, np.float64)
    row(
        "tracker-nonfinite-first-frame",
        name,
        lambda ctx, i=img: _tracker_first_frame(i, i),
        Answer(_tracker_says_no_pose),
    )

# labels.csv with a pose that is not one.
for name, r in [
    ("zero-quaternion", "img.png,rendered,0,0,0,0,0.1,0.2,5"),
    ("nan-translation", "img.png,rendered,1,0,0,0,nan,0.2,5"),
    ("nan-quaternion", "img.png,rendered,nan,0,0,1,0.1,0.2,5"),
    ("non-unit-quaternion", "img.png,rendered,2,0,0,0,0.1,0.2,5"),
    ("zero-translation", "img.png,rendered,1,0,0,0,0,0,0"),
]:
    row(
        "labels-bad-pose",
        f"load-{name}",
        lambda ctx, r=r: _load_labels(ctx, r),
        Raises("labels.csv"),
    )
    row(
        "labels-bad-pose",
        f"cli-{name}",
        lambda ctx, r=r: ["eval-speedplus", _labels(ctx, r)],
        Cli("labels.csv"),
    )

# stereo-track options and folders that gave a silent wrong answer.
for name, argv, opt in [
    ("frame-rate-negative", ["--frame-rate-hz", "-5"], "--frame-rate-hz"),
    ("frame-rate-neg-inf", ["--frame-rate-hz", "-inf"], "--frame-rate-hz"),
    ("frame-rate-inf", ["--frame-rate-hz", "inf"], "--frame-rate-hz"),
]:
    row(
        "stereo-bad-rate",
        name,
        lambda ctx, a=argv: ["stereo-track", "--out", ctx.tmp, *a],
        Cli(opt),
    )
row(
    "stereo-unreadable-image",
    "left",
    lambda ctx: _stereo_argv(ctx, spoil=_unreadable("000001.png")),
    Cli("000001.png"),
)
row(
    "stereo-unreadable-image",
    "right",
    lambda ctx: _stereo_argv(ctx, spoil=lambda p: (p / "right" / "000002.png").write_bytes(b"")),
    Cli("000002.png"),
)
row(
    "stereo-image-size",
    "half",
    lambda ctx: _stereo_argv(ctx, size=(SW // 2, SH // 2)),
    Cli("calibration.json"),
)
row(
    "stereo-image-size",
    "wider",
    lambda ctx: _stereo_argv(ctx, size=(SW + 8, SH)),
    Cli("calibration.json"),
)
row(
    "stereo-frames-with-images",
    "2",
    lambda ctx: _stereo_argv(ctx, "--frames", "2"),
    CliOk(_frames_honoured(2)),
)
row("stereo-one-pair", "no-nan", lambda ctx: _stereo_argv(ctx, n=1), CliOk(_no_nan_json))
row("stereo-one-pair", "frames-1", lambda ctx: _stereo_argv(ctx, "--frames", "1"), Cli("--frames"))

# Study options that put points behind the camera or wrote NaN.
for name, argv, opt in [
    ("range-0", ["--range-m", "0"], "--range-m"),
    ("range-negative", ["--range-m", "-10"], "--range-m"),
    ("range-nan", ["--range-m", "nan"], "--range-m"),
    ("plane-0", ["--plane-size-m", "0"], "--plane-size-m"),
    ("plane-negative", ["--plane-size-m", "-1"], "--plane-size-m"),
    ("plane-inf", ["--plane-size-m", "inf"], "--plane-size-m"),
    ("focal-0", ["--focal-length-mm", "0"], "--focal-length-mm"),
]:
    row(
        "select-study-geometry",
        name,
        _study("select-study", "--n", "6", "--m", "4", "--cases", "2", *argv),
        Cli(opt),
    )
for name, argv, opt in [
    ("check-noise-0", ["--check-noise", "0"], "--check-noise"),
    ("check-noise-nan", ["--check-noise", "nan"], "--check-noise"),
    ("perturbation-nan", ["--init-perturbation", "nan", "0.1"], "--init-perturbation"),
    ("perturbation-inf", ["--init-perturbation", "5", "inf"], "--init-perturbation"),
    ("noise-nan", ["--noise", "nan"], "--noise"),
    ("noise-negative", ["--noise", "-1"], "--noise"),
]:
    row("pose-study-values", name, _study("pose-study", "--trials", "4", *argv), Cli(opt))

# ---- the 10 unclear errors ------------------------------------------------------------------

for name, mask in [
    ("short", jnp.ones(7, bool)),
    ("long", jnp.ones(11, bool)),
    ("2d", jnp.ones((10, 1), bool)),
]:
    row(
        "mask-shape",
        f"dop-{name}",
        lambda ctx, m=mask: jp.dop(P, POSE, CAM, mask=m),
        Raises("mask"),
    )
    row(
        "mask-shape",
        f"blocks-{name}",
        lambda ctx, m=mask: jp.information_blocks(P, POSE, CAM, mask=m),
        Raises("mask"),
    )
    row(
        "mask-shape",
        f"refine-{name}",
        lambda ctx, m=mask: jp.refine_pose(P, U, POSE, CAM, mask=m),
        Raises("mask"),
    )
row(
    "mask-shape",
    "solve-pnp",
    lambda ctx: jp.solve_pnp(P, U, CAM, mask=jnp.ones(6, bool)),
    Raises("mask"),
)

for name, cam_fn, arg in [
    ("fx", lambda: PinholeCamera(0.0, 1000.0, 320, 240), "fx"),
    ("fy", lambda: PinholeCamera(1000.0, 0.0, 320, 240), "fy"),
    ("K", lambda: _with(K, (0, 0), 0.0), "K"),
]:
    row("zero-focal", name, lambda ctx, c=cam_fn: jp.dop(P, POSE, c()), Raises(arg))
    row("zero-focal", f"solve-{name}", lambda ctx, c=cam_fn: jp.solve_pnp(P, U, c()), Raises(arg))


def _gimbal_message(R, seq):
    def fn(ctx):
        try:
            res = jp.dop(P, Pose(R, POSE.t), CAM, sequence=seq)
        except ValueError as err:
            return str(err)
        return res

    return fn


def _not_blamed_on_points(value):
    # Either the PDOP (defined at gimbal lock) or an error that says what is wrong: the Euler
    # sequence's gimbal lock, not the points.
    if isinstance(value, str):
        assert "collinear" not in value and "gimbal" in value, value
    else:
        np.testing.assert_allclose(float(value.pdop), float(_tangent_pdop(value_R[0])), rtol=1e-8)


value_R = [RG]
for name, (angles, seq) in {
    "XYZ+90": ([0.3, np.pi / 2, 0.2], "XYZ"),
    "ZYX-90": ([0.1, -np.pi / 2, 0.7], "ZYX"),
}.items():
    Rl = euler_to_dcm(jnp.array(angles), seq)
    row(
        "gimbal-lock-message",
        name,
        _gimbal_message(Rl, seq),
        Answer(lambda v, R=Rl: (value_R.__setitem__(0, R), _not_blamed_on_points(v))),
    )

row(
    "float-colour-image",
    "float64-unit",
    lambda ctx: _gray(_colour(_rendered(), np.float64, 1 / 255)),
    Answer(_same_gray_as_8_bit),
)
row(
    "float-colour-image",
    "float32-255",
    lambda ctx: _gray(_colour(_rendered(), np.float32, 1.0)),
    Answer(_same_gray_as_8_bit),
)
row(
    "float-colour-image",
    "bgra",
    lambda ctx: _gray(cv2.cvtColor(_rendered(), cv2.COLOR_GRAY2BGRA)),
    Answer(_same_gray_as_8_bit),
)

for name, kw, field_name in [
    ("matrix-string", dict(cameraMatrix="abc"), "cameraMatrix"),
    ("matrix-2x2", dict(cameraMatrix=[[1, 0], [0, 1]]), "cameraMatrix"),
    ("matrix-null", dict(cameraMatrix=None), "cameraMatrix"),
    ("no-matrix", dict(cameraMatrix=_DROP), "cameraMatrix"),
    ("Nu-null", dict(Nu=None), "Nu"),
    ("Nv-string", dict(Nv="wide"), "Nv"),
    ("Nu-negative", dict(Nu=-4), "Nu"),
]:
    row(
        "camera-json-field",
        f"load-{name}",
        lambda ctx, k=kw: _load_camera(ctx, **k),
        Raises(field_name, "camera.json"),
    )
    row(
        "camera-json-field",
        f"init-{name}",
        lambda ctx, k=kw: _init_argv(ctx, **k),
        Cli(field_name, "camera.json"),
    )
row(
    "camera-json-field",
    "not-an-object",
    lambda ctx: (
        (ctx.tmp / "camera.json").write_text('{"a": 1}') and jp.load_camera(ctx.tmp / "camera.json")
    ),
    Raises("cameraMatrix", "camera.json"),
)
# a dict of the file's fields given for its path: a TypeError of pathlib's
row(
    "camera-json-field",
    "not-a-path",
    lambda ctx: jp.load_camera({"fx": 1000.0, "fy": 1000.0, "cx": 511.5, "cy": 383.5}),
    Raises("path", "dict"),
)

for name, r in [
    ("short", "img.png,rendered,1,0,0"),
    ("text", "img.png,rendered,1,0,0,0,x,0.2,5"),
    ("empty-field", "img.png,rendered,1,0,0,0,,0.2,5"),
]:
    row(
        "labels-short-row",
        f"load-{name}",
        lambda ctx, r=r: _load_labels(ctx, r),
        Raises("labels.csv", "3"),
    )
    row(
        "labels-short-row",
        f"cli-{name}",
        lambda ctx, r=r: ["eval-speedplus", _labels(ctx, r)],
        Cli("labels.csv"),
    )

for name, argv, opt in [
    ("rate-nan", ["--rate-deg-s", "nan"], "--rate-deg-s"),
    ("rate-inf", ["--rate-deg-s", "inf"], "--rate-deg-s"),
    ("rate-text", ["--rate-deg-s", "fast"], "--rate-deg-s"),
    ("seed-negative", ["--seed", "-1"], "--seed"),
    ("seed-float", ["--seed", "1.5"], "--seed"),
    ("frame-rate-0", ["--frame-rate-hz", "0"], "--frame-rate-hz"),
    ("frame-rate-nan", ["--frame-rate-hz", "nan"], "--frame-rate-hz"),
]:
    row(
        "stereo-option-message",
        name,
        lambda ctx, a=argv: ["stereo-track", "--out", ctx.tmp, *a],
        Cli(opt),
    )


def _calibration_cli(field_name):
    return Cli("calibration.json", field_name) if field_name else Cli("calibration.json")


for name, kw, field_name in [
    ("no-right", dict(calibration=_drop("right")), "right"),
    ("no-left-matrix", dict(calibration=_drop("cameraMatrix", "left")), "cameraMatrix"),
    ("t_rl-short", dict(calibration=_set("t_rl", [0.3, 0.0])), "t_rl"),
    ("t_rl-zero", dict(calibration=_set("t_rl", [0.0, 0.0, 0.0])), "t_rl"),
    ("R_rl-text", dict(calibration=_set("R_rl", "eye")), "R_rl"),
    ("malformed-json", dict(raw_calibration="{not json"), None),
    ("a-list", dict(raw_calibration="[1, 2]"), None),
]:
    row(
        "stereo-calibration",
        name,
        lambda ctx, k=kw: _stereo_argv(ctx, **k),
        _calibration_cli(field_name),
    )


def _calibration_leaves_nothing(ctx):
    argv = _stereo_argv(ctx, calibration=_drop("right"))
    before = sorted(p.name for p in ctx.tmp.rglob("*"))
    from jaxpose.cli import main

    code = main([str(a) for a in argv])
    after = sorted(p.name for p in ctx.tmp.rglob("*") if p.name != "out")
    return code, before, after


row(
    "stereo-calibration",
    "no-temp-file",
    _calibration_leaves_nothing,
    Answer(lambda v: (v[0] == 2 and set(v[2]) <= set(v[1])) or pytest.fail(str(v))),
)

row("study-corrupt-chunk", "truncated", _resume(_truncate), CliOk(_same_results))
row("study-corrupt-chunk", "garbage", _resume(_garbage), CliOk(_same_results))
row("study-corrupt-chunk", "empty", _resume(_empty), CliOk(_same_results))

for name, argv in [
    ("-1", ["--check-noise", "-1"]),
    ("-1e30", ["--check-noise", "-1e30"]),
    ("seed-negative", ["--seed", "-3"]),
]:
    opt = argv[0]
    row("pose-study-negative", name, _study("pose-study", "--trials", "4", *argv), Cli(opt))

# ---- the 3 hangs: a limit that answers at once ------------------------------------------------
# Run in a child process: a hang inside one compiled call cannot be interrupted from Python.


@dataclass(frozen=True)
class Within:
    """``python -c code`` ends within ``limit_s`` seconds and prints ``ValueError`` naming
    ``names`` (``code`` prints the error's text); or, for a command, exits 2 naming them."""

    code: str
    names: tuple[str, ...]
    limit_s: float = 90.0


def _child(code, limit_s):
    import os
    import subprocess
    import sys

    env = dict(os.environ, PYTHONPATH=str(Path(jp.__file__).parents[1]))
    try:
        return subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, timeout=limit_s, env=env
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"no answer within {limit_s} s")


CALL = """
import jax; jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp, numpy as np, jaxpose as jp
pose = jp.Pose.from_euler(jnp.array([0.1, 0.2, 0.3]), jnp.array([0.1, -0.1, 5.0]))
cam = jp.PinholeCamera(1000.0, 1000.0, 320.0, 240.0)
P = jnp.asarray(np.random.default_rng(1).uniform(-1, 1, ({n}, 3)))
try:
    {call}
    print("RETURNED")
except ValueError as err:
    print("ValueError:", err)
"""
CLI = """
import sys
from jaxpose.cli import main
sys.exit(main({argv!r}))
"""

for name, (n, m) in {"40-20": (40, 20), "60-30": (60, 30), "35-17": (35, 17)}.items():
    row(
        "exhaustive-limit",
        name,
        None,
        Within(
            CALL.format(
                n=n, call=f"jp.select.exhaustive(jp.information_blocks(P, pose, cam), {m})"
            ),
            ("m",),
        ),
    )
row(
    "exhaustive-limit",
    "select-features",
    None,
    Within(
        CALL.format(n=40, call="jp.select_features(P, pose, cam, 20, method='exhaustive')"), ("m",)
    ),
)
for name, (n, m) in {"40-20": ("40", "20"), "50-25": ("50", "25")}.items():
    argv = [
        "select-study",
        "--n",
        n,
        "--m",
        m,
        "--cases",
        "1",
        "--no-figures",
        "--no-progress",
        "--out",
        "{tmp}",
    ]
    row("select-study-limit", name, None, Within(CLI.format(argv=argv), ("--m",)))
for name, rate in [("1e-6", "1e-6"), ("1e-4", "1e-4"), ("zero", "0")]:
    argv = ["stereo-track", "--out", "{tmp}", "--rate-deg-s", rate, "--no-figures", "--no-progress"]
    row("stereo-frames-limit", name, None, Within(CLI.format(argv=argv), ("--rate-deg-s",)))

# ---- the 30 classes that held -------------------------------------------------------------------

row("shape-points", "dop-2-columns", lambda ctx: jp.dop(P[:, :2], POSE, CAM), Raises("points_body"))
row("shape-points", "dop-batched", lambda ctx: jp.dop(P[None], POSE, CAM), Raises("points_body"))
row(
    "shape-points",
    "refine-4-columns",
    lambda ctx: jp.refine_pose(jnp.ones((10, 4)), U, POSE, CAM),
    Raises("points_body"),
)
row("shape-pixels", "solve-length", lambda ctx: jp.solve_pnp(P, U[:8], CAM), Raises("pixels"))
row(
    "shape-pixels",
    "refine-3-columns",
    lambda ctx: jp.refine_pose(P, jnp.ones((10, 3)), POSE, CAM),
    Raises("pixels"),
)
row(
    "shape-pixels",
    "sensitivity-length",
    lambda ctx: jp.sensitivity(P, U[:5], POSE, CAM),
    Raises("pixels"),
)
row("shape-pose", "pose-R-2x2", lambda ctx: Pose(jnp.eye(2), jnp.zeros(3)), Raises("R"))
row("shape-pose", "pose-t-4", lambda ctx: Pose(jnp.eye(3), jnp.zeros(4)), Raises("t"))
row(
    "shape-pose",
    "dop-batched-pose",
    lambda ctx: jp.dop(P, Pose(jnp.stack([POSE.R] * 2), jnp.stack([POSE.t] * 2)), CAM),
    Raises("pose"),
)
row("shape-camera", "K-2x3", lambda ctx: jp.solve_pnp(P, U, jnp.ones((2, 3))), Raises("K"))
row("shape-camera", "not-a-camera", lambda ctx: jp.dop(P, POSE, "camera"), Raises("camera"))
row(
    "shape-quaternion",
    "3-numbers",
    lambda ctx: Pose.from_quat(jnp.ones(3), jnp.zeros(3)),
    Raises("q"),
)

for name, pts, pix in [
    ("nan-point", _with(P, (1, 1), np.nan), U),
    ("inf-pixel", P, _with(U, (2, 0), np.inf)),
    ("nan-pixel", P, _with(U, (9, 1), np.nan)),
]:
    row(
        "nan-in-points",
        f"solve-{name}",
        lambda ctx, a=pts, b=pix: jp.solve_pnp(a, b, CAM, throw=False),
        Returns(Status.NONFINITE_INPUT),
    )
    row(
        "nan-in-points",
        f"solve-throw-{name}",
        lambda ctx, a=pts, b=pix: jp.solve_pnp(a, b, CAM),
        Raises("NaN"),
    )
    row(
        "nan-in-points",
        f"refine-{name}",
        lambda ctx, a=pts, b=pix: jp.refine_pose(a, b, POSE, CAM, throw=False),
        Returns(Status.NONFINITE_INPUT),
    )
row(
    "nan-in-points",
    "dop",
    lambda ctx: jp.dop(_with(P, (0, 0), np.nan), POSE, CAM, throw=False),
    Returns(Status.NONFINITE_INPUT),
)
row(
    "nan-in-points",
    "dop-pose",
    lambda ctx: jp.dop(P, Pose(POSE.R, _with(POSE.t, 2, np.inf)), CAM, throw=False),
    Returns(Status.NONFINITE_INPUT),
)

for name, cam in [
    ("nan-cx", PinholeCamera(1000.0, 1000.0, np.nan, 240.0)),
    ("inf-cy", PinholeCamera(1000.0, 1000.0, 320.0, np.inf)),
    ("nan-dist", PinholeCamera(1000.0, 1000.0, 320.0, 240.0, [np.nan, 0, 0, 0, 0])),
]:
    row(
        "nan-in-camera",
        f"solve-{name}",
        lambda ctx, c=cam: jp.solve_pnp(P, U, c, throw=False),
        Returns(Status.NONFINITE_INPUT),
    )
    row(
        "nan-in-camera",
        f"dop-{name}",
        lambda ctx, c=cam: jp.dop(P, POSE, c, throw=False),
        Returns(Status.NONFINITE_INPUT),
    )
row(
    "nan-in-camera",
    "nan-focal",
    lambda ctx: jp.solve_pnp(P, U, PinholeCamera(np.nan, 1000.0, 320, 240), throw=False),
    Returns(Status.NONFINITE_INPUT),
)


def _masked(nvalid, n=10):
    return jnp.arange(n) < nvalid


for solver, method, few in [("epnp", "epnp", 3), ("dlt", "dlt", 5), ("ransac", "ransac", 3)]:
    row(
        f"too-few-{solver}",
        "eager",
        lambda ctx, m=method, k=few: jp.solve_pnp(
            P[:k], U[:k], CAM, options=jp.PnPOptions(method=m)
        ),
        Raises("points_body"),
    )
    row(
        f"too-few-{solver}",
        "mask",
        lambda ctx, m=method, k=few: jp.solve_pnp(
            P, U, CAM, mask=_masked(k), options=jp.PnPOptions(method=m), throw=False
        ),
        Returns(Status.TOO_FEW_POINTS),
    )
row(
    "too-few-refine-dop",
    "refine",
    lambda ctx: jp.refine_pose(P, U, POSE, CAM, mask=_masked(2), throw=False),
    Returns(Status.TOO_FEW_POINTS),
)
row(
    "too-few-refine-dop",
    "dop",
    lambda ctx: jp.dop(P, POSE, CAM, mask=_masked(3), throw=False),
    Returns(Status.TOO_FEW_POINTS),
)
row(
    "too-few-refine-dop",
    "sensitivity",
    lambda ctx: jp.sensitivity(P, U, POSE, CAM, mask=_masked(2), throw=False),
    Returns(Status.TOO_FEW_POINTS),
)

DEGENERATE = (Status.SINGULAR, Status.DEGENERATE, Status.NO_SOLUTION)
for method in ("epnp", "dlt", "ransac"):
    for name, pts in [("collinear", PCOL), ("coincident", _coincident())]:
        row(
            f"degenerate-{method}",
            name,
            lambda ctx, m=method, p=pts: jp.solve_pnp(
                p, _pix(p), CAM, options=jp.PnPOptions(method=m), throw=False
            ),
            Returns(*DEGENERATE),
        )
row(
    "degenerate-dop-refine",
    "dop-collinear",
    lambda ctx: jp.dop(PCOL, POSE, CAM, throw=False),
    Returns(Status.SINGULAR),
)
row(
    "degenerate-dop-refine",
    "refine-coincident",
    lambda ctx: jp.refine_pose(_coincident(), _pix(_coincident()), POSE, CAM, throw=False),
    Returns(Status.SINGULAR, Status.NOT_CONVERGED),
)

BEHIND = Pose(POSE.R, jnp.array([0.0, 0.0, -5.0]))
row(
    "behind-camera",
    "dop",
    lambda ctx: jp.dop(P, BEHIND, CAM, throw=False),
    Returns(Status.BEHIND_CAMERA),
)
row("behind-camera", "dop-throw", lambda ctx: jp.dop(P, BEHIND, CAM), Raises("behind"))
row("behind-camera", "select", lambda ctx: jp.select_features(P, BEHIND, CAM, 5), Raises("behind"))


def _lanes(fn, batch):
    return lambda ctx: jax.vmap(fn)(*batch)


PB = jnp.stack([P, _with(P, (0, 0), np.nan), PCOL, P])
UB = jnp.stack([U, U, UCOL, _with(U, (1, 1), np.inf)])


def _lane_check(expected):
    def check(res):
        status = np.asarray(res.status)
        for lane, want in enumerate(expected):
            assert status[lane] in np.atleast_1d(want), (lane, status[lane], want)
        assert not _nan_free(res), _nan_free(res)
        ok = np.asarray(res.status) == 0
        np.testing.assert_allclose(
            np.asarray(res.pose.t)[ok],
            np.broadcast_to(np.asarray(POSE.t), (ok.sum(), 3)),
            atol=1e-6,
        )

    return check


row(
    "vmap-solvers",
    "solve_pnp",
    lambda ctx: jp.solve_pnp(PB, UB, CAM, throw=False),
    Answer(
        _lane_check(
            [
                0,
                Status.NONFINITE_INPUT,
                (Status.SINGULAR, Status.DEGENERATE),
                Status.NONFINITE_INPUT,
            ]
        )
    ),
)
row(
    "vmap-solvers",
    "refine",
    _lanes(lambda p, u: jp.refine_pose(p, u, POSE, CAM, throw=False), (PB, UB)),
    Returns(Status.OK, Status.NONFINITE_INPUT, Status.SINGULAR, Status.NOT_CONVERGED),
)
row(
    "vmap-selection",
    "dop",
    _lanes(lambda p: jp.dop(p, POSE, CAM, throw=False), (PB,)),
    Answer(
        lambda r: (
            np.testing.assert_array_equal(
                np.asarray(r.status), [0, Status.NONFINITE_INPUT, Status.SINGULAR, 0]
            ),
            _nan_free(r) == [] or pytest.fail(str(_nan_free(r))),
        )
    ),
)
BLOCKS_B = jnp.stack(
    [_blocks(), _blocks().at[2].set(jnp.nan), jp.information_blocks(PCOL, POSE, CAM)]
)
row(
    "vmap-selection",
    "exhaustive",
    _lanes(lambda b: jp.select.exhaustive(b, 5, throw=False), (BLOCKS_B,)),
    Answer(
        lambda r: (
            np.testing.assert_equal(np.asarray(r.status)[0], 0),
            np.testing.assert_equal((np.asarray(r.status)[1:] != 0).all(), True),
            _nan_free(r) == [] or pytest.fail(str(_nan_free(r))),
        )
    ),
)
row(
    "vmap-selection",
    "bnb",
    _lanes(lambda b: jp.select.branch_and_bound(b, 5, throw=False), (BLOCKS_B,)),
    Answer(
        lambda r: (
            np.testing.assert_equal(np.asarray(r.status)[0], 0),
            np.testing.assert_equal((np.asarray(r.status)[1:] != 0).all(), True),
            _nan_free(r) == [] or pytest.fail(str(_nan_free(r))),
        )
    ),
)

row("dark-image", "black", lambda ctx: _init(np.zeros((300, 480), np.uint8)), Answer(_no_target))
row(
    "saturated-image",
    "mono",
    lambda ctx: _init(np.full((300, 480), 255, np.uint8)),
    Answer(_no_target),
)
row(
    "dark-image",
    "noise",
    lambda ctx: _init(np.random.default_rng(3).integers(0, 40, (300, 480)).astype(np.uint8)),
    Answer(_no_target),
)
row(
    "dark-image",
    "tracker-black",
    lambda ctx: _tracker_first_frame(np.zeros((SH, SW), np.uint8), np.zeros((SH, SW), np.uint8)),
    Answer(_tracker_says_no_pose),
)

row(
    "saturated-image",
    "tracker",
    lambda ctx: _tracker_first_frame(
        np.full((SH, SW), 255, np.uint8), np.full((SH, SW), 255, np.uint8)
    ),
    Answer(_tracker_says_no_pose),
)
row(
    "missing-input-file",
    "init-image",
    lambda ctx: ["init", ctx.tmp / "nope.png", "--camera", _camera_json(ctx)],
    Cli("nope.png"),
)
row(
    "missing-camera-file",
    "init",
    lambda ctx: ["init", _image_file(ctx), "--camera", ctx.tmp / "cam.json"],
    Cli("cam.json"),
)
row(
    "missing-input-file",
    "eval-folder",
    lambda ctx: ["eval-speedplus", ctx.tmp / "absent"],
    Cli("absent"),
)
row(
    "missing-input-file",
    "stereo-folder",
    lambda ctx: ["stereo-track", "--images", ctx.tmp / "absent", "--out", ctx.tmp / "o"],
    Cli("absent"),
)
row(
    "missing-camera-file",
    "load",
    lambda ctx: jp.load_camera(ctx.tmp / "gone.json"),
    Raises("gone.json"),
)


def _image_error_row(out, err, ctx):
    # One unreadable image of a data set does not stop the evaluation: its row says why, and the
    # readable image beside it is evaluated.
    rows = {r["image"]: r for r in _json_line(out)["per_image"]}
    assert rows["other.png"]["confidence"] == "error" and not rows["other.png"]["success"], rows
    assert _named("other.png", rows["other.png"]["message"]), rows["other.png"]
    assert rows["img.png"]["confidence"] in ("none", "position-only"), rows["img.png"]


# The readable image is black: evaluated in milliseconds (no target), where the render would run
# the whole pipeline (28 s of a cold suite) for a row about the other image.
row(
    "missing-input-file",
    "labels-image",
    lambda ctx: (
        _labels(ctx, "other.png,rendered,1,0,0,0,0.1,0.2,5", np.zeros((300, 480), np.uint8)),
        ["eval-speedplus", ctx.tmp, "--json"],
    )[1],
    CliOk(_image_error_row),
)

for name, text in [("not-json", "{cameraMatrix: ["), ("empty", ""), ("list", "[1, 2, 3]")]:
    row(
        "malformed-json",
        f"camera-{name}",
        lambda ctx, t=text: (
            (ctx.tmp / "camera.json").write_text(t) * 0 or jp.load_camera(ctx.tmp / "camera.json")
        ),
        Raises("camera.json"),
    )
    row(
        "malformed-json",
        f"init-{name}",
        lambda ctx, t=text: [
            "init",
            _image_file(ctx),
            "--camera",
            (ctx.tmp / "c.json").write_text(t) * 0 or ctx.tmp / "c.json",
        ],
        Cli("c.json"),
    )

row("study-resume", "killed", _resume(_kill), CliOk(_same_results))
row("study-same-seed", "twice", _fresh_same_seed, CliOk(_same_results))

for name, call in [
    ("select-method", lambda: jp.select_features(P, POSE, CAM, 5, method="best")),
    (
        "select-criterion",
        lambda: jp.select_features(P, POSE, CAM, 5, method="greedy", criterion="gdop"),
    ),
    ("dop-parameterization", lambda: jp.dop(P, POSE, CAM, parameterization="quaternion")),
    ("triangulate-method", lambda: RIG.triangulate(XL, XR, method="dlt")),
]:
    arg = name.split("-")[1]
    row("unknown-option", name, lambda ctx, c=call: c(), Raises(arg))
row(
    "unknown-option",
    "sequence",
    lambda ctx: jp.dop(P, POSE, CAM, sequence="XYQ"),
    Raises("sequence"),
)
row("unknown-option", "pnp-method", lambda ctx: jp.PnPOptions(method="p3p"), Raises("method"))
row(
    "unknown-option", "refine-method", lambda ctx: jp.RefineOptions(method="bfgs"), Raises("method")
)
row(
    "unknown-option",
    "options-type",
    lambda ctx: jp.solve_pnp(P, U, CAM, options={"method": "epnp"}),
    Raises("options"),
)


# ---- the second audit: surfaces added after the table (line blocks, tracker options, CLI) -----

SEG = jnp.asarray(np.random.default_rng(3).uniform(-1.0, 1.0, (8, 2, 3)))

# A sigma that is not a number: a bool was taken as 1 (True), a numeric string as its number.
for name, s in [("bool", True), ("str", "1"), ("bool-array", np.ones(8, bool))]:
    row(
        "sigma-not-a-number",
        f"lines-{name}",
        lambda ctx, s=s: jp.line_information_blocks(SEG, POSE, CAM, sigma=s),
        Raises("sigma"),
    )
row(
    "sigma-not-a-number",
    "blocks-bool",
    lambda ctx: jp.information_blocks(P, POSE, CAM, sigma=True),
    Raises("sigma"),
)
row("sigma-not-a-number", "dop-str", lambda ctx: jp.dop(P, POSE, CAM, sigma="2"), Raises("sigma"))
row(
    "sigma-not-a-number",
    "refine-bool",
    lambda ctx: jp.refine_pose(P, U, POSE, CAM, sigma=True),
    Raises("sigma"),
)
# (held) the line blocks refuse a non-positive sigma as the point blocks do
for name, s in [("negative", -1.0), ("zero", 0.0), ("nan", np.nan)]:
    row(
        "bad-sigma",
        f"lines-{name}",
        lambda ctx, s=s: jp.line_information_blocks(SEG, POSE, CAM, sigma=s),
        Raises("sigma"),
    )


# A --budget-rule without --feature-budget was ignored (every feature was used, no rule chose).
for rule in ("random", "response", "dop"):
    row(
        "stereo-budget-rule-alone",
        rule,
        lambda ctx, r=rule: _stereo_argv(ctx, "--budget-rule", r),
        Cli("--budget-rule", "--feature-budget"),
    )
row(
    "stereo-budget-rule-alone",
    "budget-by-option",
    lambda ctx: _stereo_argv(ctx, "--budget-rule", "random", "--option", "feature_budget=8"),
    CliOk(_frames_honoured(3)),
)


def _tracker_roi(roi):
    from jaxpose.pipelines.stereo import StereoTracker

    rig, frames = _stereo_pairs()
    return StereoTracker(rig, frames[0].pose).process(frames[0].left, frames[0].right, roi=roi)


# A malformed roi of StereoTracker.process: NaN or inverted corners were used as they were, three
# numbers or a string raised an error that did not name roi.
for name, roi in [
    ("three", [1, 2, 3]),
    ("nan", [0, 0, np.nan, 100]),
    ("inverted", [300, 200, 10, 10]),
    ("string", "abcd"),
    ("outside", [-900, -900, -800, -800]),
]:
    row("tracker-roi", name, lambda ctx, r=roi: _tracker_roi(r), Raises("roi"))
row(
    "tracker-roi",
    "init-string",
    lambda ctx: jp.initialise_pose(_rendered(), MONO_CAM, roi="ab"),
    Raises("roi"),
)


def _options(kind: str, **fields):
    from jaxpose.pipelines.monocular import InitOptions
    from jaxpose.pipelines.stereo import TrackerOptions
    from jaxpose.vision.stereo_features import FeatureOptions
    from jaxpose.vision.stereo_match import StereoMatchOptions

    if kind == "init":  # InitOptions is checked where the pipeline starts
        return jp.initialise_pose(
            np.zeros((64, 64), np.uint8), MONO_CAM, options=InitOptions(**fields)
        )
    from jaxpose.vision.features import DetectionOptions

    cls = {
        "tracker": TrackerOptions,
        "features": FeatureOptions,
        "stereo": StereoMatchOptions,
        "detection": DetectionOptions,
    }
    return cls[kind](**fields)


# The plain fields of the stereo tracker's options (and of its feature and epipolar-search
# groups) and the integer and flag fields of InitOptions had no check: a bool was taken as 1, a
# negative count or NaN threshold ran, a string raised a TypeError that did not name the field.
for name, kind, fields, named in [
    ("tracker-bool-sigma", "tracker", dict(sigma_px=True), "sigma_px"),
    ("tracker-nan-sigma", "tracker", dict(line_sigma_px=np.nan), "line_sigma_px"),
    ("tracker-float-count", "tracker", dict(max_points=2.5), "max_points"),
    ("tracker-string-count", "tracker", dict(passes="3"), "passes"),
    ("tracker-negative-count", "tracker", dict(mature_obs=-1), "mature_obs"),
    ("tracker-no-descriptor", "tracker", dict(descriptor_memory=0), "descriptor_memory"),
    ("tracker-string-flag", "tracker", dict(use_lines="yes"), "use_lines"),
    ("tracker-nan-limit", "tracker", dict(max_rms_px=np.nan), "max_rms_px"),
    ("tracker-depths-reversed", "tracker", dict(depth_range_m=(8.0, 0.6)), "depth_range_m"),
    ("tracker-robust", "tracker", dict(robust="l2"), "robust"),
    (
        "tracker-motion-inf",
        "tracker",
        dict(window_motion_sigma=(1.0, np.inf)),
        "window_motion_sigma",
    ),
    ("tracker-motion-scalar", "tracker", dict(window_motion_sigma=5.0), "window_motion_sigma"),
    ("tracker-string-fraction", "tracker", dict(line_scale_memory="a"), "line_scale_memory"),
    ("tracker-group", "tracker", dict(features=3), "features"),
    ("features-zero-budget", "features", dict(n_points=0), "n_points"),
    ("features-ratio", "features", dict(point_ratio=1.5), "point_ratio"),
    ("features-string", "features", dict(mu="a"), "mu"),
    ("stereo-float-window", "stereo", dict(window=15.0), "window"),
    ("stereo-even-window", "stereo", dict(coarse_window=8), "coarse_window"),
    ("stereo-ncc", "stereo", dict(ncc_threshold=2.0), "ncc_threshold"),
    ("stereo-range", "stereo", dict(coarse_min_range=0), "coarse_min_range"),
    ("init-top-k", "init", dict(top_k=0), "top_k"),
    ("init-bool-count", "init", dict(max_hypotheses=True), "max_hypotheses"),
    ("init-rounds", "init", dict(rematch_rounds=-1), "rematch_rounds"),
    ("init-flag", "init", dict(trace="yes"), "trace"),
    ("detection-bool-size", "detection", dict(kappa1=True), "kappa1"),
    ("detection-zero-count", "detection", dict(max_segments=0), "max_segments"),
    ("detection-share", "detection", dict(wge_cdf=1.5), "wge_cdf"),
    ("detection-flag", "detection", dict(cluster_roi="no"), "cluster_roi"),
]:
    row("option-field-kinds", name, lambda ctx, k=kind, f=fields: _options(k, **f), Raises(named))


# A mask of indices or weights was cast to bool: indices 0..n-1 dropped the first feature and
# kept the rest, a weight of 0.5 counted as 1; a mask of strings raised a TypeError of JAX's.
for name, mask in [
    ("indices", np.arange(10)),
    ("weights", np.full(10, 0.5)),
    ("strings", np.array(list("abcdefghij"))),
]:
    row(
        "mask-not-booleans",
        f"dop-{name}",
        lambda ctx, m=mask: jp.dop(P, POSE, CAM, mask=m),
        Raises("mask"),
    )
    row(
        "mask-not-booleans",
        f"greedy-{name}",
        lambda ctx, m=mask: jp.select.greedy(jp.information_blocks(P, POSE, CAM), 5, mask=m),
        Raises("mask"),
    )
row(
    "mask-not-booleans",
    "solve-pnp-indices",
    lambda ctx: jp.solve_pnp(P, U, CAM, mask=np.arange(10)),
    Raises("mask"),
)


def _speedplus_out(ctx, out):
    root = ctx.tmp / "sp"
    root.mkdir(exist_ok=True)
    (root / "camera.json").write_text(json.dumps({"cameraMatrix": K, "Nu": 640, "Nv": 480}))
    (root / "labels.csv").write_text("image,domain,qw,qx,qy,qz,tx,ty,tz\na.png,x,1,0,0,0,0,0,5\n")
    (ctx.tmp / "a-file").write_text("")
    return ["eval-speedplus", root, "--out", ctx.tmp / out, "--no-progress"]


# eval-speedplus --out where no folder can be made: a traceback-free error naming --out
for name, out in [("a-file", "a-file"), ("under-a-file", "a-file/records")]:
    row("speedplus-out", name, lambda ctx, o=out: _speedplus_out(ctx, o), Cli("--out"))


@pytest.mark.parametrize("cls, variant, fn, expect", TABLE)
def test_bad_input(cls, variant, fn, expect, tmp_path, capsys):
    check_row(cls, variant, fn, expect, tmp_path, capsys)


def check_row(cls, variant, fn, expect, tmp_path, capsys):
    """One row's check within :data:`LIMIT_S` (the other audits' tables use it too)."""
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(LIMIT_S)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            _check(fn, expect, Ctx(tmp_path), capsys)
    except _Timeout:
        pytest.fail(f"{cls}[{variant}] did not answer within {LIMIT_S} s")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def test_the_table_covers_the_audit():
    """At least the 61 classes of the audit, each with at least two variants but a few."""
    classes = {}
    for param in TABLE:
        classes.setdefault(param.values[0], []).append(param.values[1])
    assert len(classes) >= 61, len(classes)
    single = sorted(c for c, v in classes.items() if len(v) < 2)
    assert len(single) <= 4, single
