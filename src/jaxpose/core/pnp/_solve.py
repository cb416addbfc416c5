"""``solve_pnp``: OpenCV's ``solvePnP``, batched, with statuses (the eager entry point).

``jaxpose.solve_pnp(points_body, pixels, camera)`` takes ``(..., n, 3)`` body points and their
``(..., n, 2)`` measured pixels with any leading batch axes, solves every problem with one
compiled function (EPnP, DLT or RANSAC over EPnP from :mod:`jaxpose.core.pnp`, then
:func:`jaxpose.core.refine.refine_pose`) and returns a :class:`~jaxpose.core.pnp.PnPResult` with the
same leading axes.

Planar targets far away are two-fold ambiguous; when a batch holds planar problems and
``refine`` is on, each planar problem is refined from both the EPnP pose and its mirror
(:func:`jaxpose.core.pnp.planar_flip`) and the lower reprojection error wins.

Errors, in the house style: wrong shapes and options raise ``ValueError`` at once; bad values
(NaN, fewer than four valid points, collinear points, points behind the camera in the solution,
no convergence) give a :class:`~jaxpose.core.status.Status` per problem, and with ``throw=True``
(the default) a ``ValueError`` naming each failure and where it happened. Pass ``throw=False`` for
batches so that one bad problem does not cost the others.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
import threading

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxpose.core._checks import (
    as_bool_mask,
    float_dtype,
    intrinsic_matrix_problem,
    real_array,
)
from jaxpose.core._compile import any_tracer, known_cpu_options
from jaxpose.core._threads import in_threads
from jaxpose.core.camera import PinholeCamera
from jaxpose.core.geometry import Pose
from jaxpose.core.pnp._batch import (
    _flat,
    _map,
    _map_chunks,
    _pad,
    _thread_parts,
)
from jaxpose.core.pnp._dlt import _dlt_core
from jaxpose.core.pnp._epnp import _epnp_core, planar_flip
from jaxpose.core.pnp._gauss_newton import _accepts as _gn_accepts
from jaxpose.core.pnp._gauss_newton import gauss_newton_pnp, reprojection_rms
from jaxpose.core.pnp._options import PnPOptions, RansacOptions
from jaxpose.core.pnp._problem import (
    DLT_MIN_POINTS,
    MIN_POINTS,
    _conclude,
    _kept,
    _Problem,
    _problem,
)
from jaxpose.core.pnp._ransac import _ransac_core, check_key
from jaxpose.core.pnp._result import PnPResult
from jaxpose.core.refine import RefineOptions, refine_pose
from jaxpose.core.refine._implicit import _with_implicit_grad
from jaxpose.core.refine._problem import _prepare as _refine_problem
from jaxpose.core.status import Status, check_throw, throw_for_status


def _solve(prob: _Problem, method: str, planar_tol: float, key=None, ransac=None):
    """Run a solver core; returns the :class:`PnPResult` and the core's output (plane etc.)."""
    weights = prob.valid.astype(prob.points_body.dtype)
    if method == "epnp":
        out = _epnp_core(prob.points_body, prob.xy, weights, prob.fxy, planar_tol)
        return _conclude(prob, out, MIN_POINTS), out
    if method == "dlt":
        out = _dlt_core(prob.points_body, prob.xy, weights, prob.fxy, planar_tol)
        return _conclude(prob, out, DLT_MIN_POINTS), out
    out, inliers = _ransac_core(prob, key, planar_tol=planar_tol, **ransac._core())
    return _conclude(prob, out, ransac.sample_size, inliers), out


def _batch_shape(points_body, pixels, mask) -> tuple[tuple[int, ...], int]:
    ps, xs = np.shape(points_body), np.shape(pixels)
    if len(ps) < 2 or ps[-1] != 3:
        raise ValueError(f"points_body must have shape (..., n, 3); got {ps}")
    if len(xs) < 2 or xs[-1] != 2:
        raise ValueError(f"pixels must have shape (..., n, 2); got {xs}")
    n = ps[-2]
    if xs[-2] != n:
        raise ValueError(f"points_body {ps} and pixels {xs} must hold the same number of points n")
    shapes = [ps[:-2], xs[:-2]]
    if mask is not None:
        ms = np.shape(mask)
        if len(ms) < 1 or ms[-1] != n:
            raise ValueError(f"mask must have shape (..., {n}); got {ms}")
        shapes.append(ms[:-1])
    try:
        batch = np.broadcast_shapes(*shapes)
    except ValueError:
        raise ValueError(
            f"leading (batch) axes do not broadcast: points_body {ps}, pixels {xs}"
            + ("" if mask is None else f", mask {np.shape(mask)}")
        ) from None
    if n < MIN_POINTS:
        raise ValueError(f"PnP needs at least {MIN_POINTS} points; points_body has n = {n}")
    return batch, n


class _Initial(eqx.Module):
    result: PnPResult
    centroid: Array  # (3,) body frame, of the points used
    normal: Array  # (3,) body frame, their least-spread direction (the plane's normal if planar)


@dataclasses.dataclass(frozen=True)
class _Static:
    """Everything that is fixed at compile time (hashable)."""

    method: str
    planar_tol: float
    ransac: RansacOptions | None
    refine: RefineOptions | None
    undistort: bool
    chunk: int


def _camera(intrinsics) -> PinholeCamera:
    return PinholeCamera(intrinsics[0], intrinsics[1], intrinsics[2], intrinsics[3], intrinsics[4:])


def _cast(points_body, pixels, mask, intrinsics):
    """One float dtype for every input (that of the points), and the camera."""
    dtype = float_dtype(points_body)
    camera = _camera(jnp.asarray(intrinsics).astype(dtype))
    return points_body.astype(dtype), pixels.astype(dtype), mask.astype(bool), camera


def _initial(points_body, pixels, mask, keys, camera, cfg: _Static) -> _Initial:
    """The closed-form (or RANSAC) solution of every problem, with the plane for a mirror pose.

    ``keys``: RANSAC's PRNG key per problem (``None`` for the other methods)."""

    def one(p, x, m, k=None):
        prob = _problem(p, x, camera, m, "solve_pnp", cfg.undistort)
        res, out = _solve(prob, cfg.method, cfg.planar_tol, key=k, ransac=cfg.ransac)
        return _Initial(res, out.centroid, out.normal)

    args = (points_body, pixels, mask) + (() if keys is None else (keys,))
    return _map(one, args, cfg.chunk, pixels.ndim == 2)


def _refined(init: _Initial, points_body, pixels, camera, cfg: _Static, two: bool) -> PnPResult:
    """Refine every problem from its closed-form pose (and, if ``two``, from its mirror).

    Without distortion or robust kernel, a fixed number of Gauss-Newton steps
    (:func:`~jaxpose.core.pnp._gauss_newton.gauss_newton_pnp`) refines every problem; a chunk
    in which any of them does not converge is refined again by ``refine_pose`` (LM), whose
    answer is kept for those problems."""
    single = pixels.ndim == 2
    if cfg.undistort or not _gn_accepts(cfg.refine):
        return _map(
            lambda i, p, x: _refined_lm(i, p, x, camera, cfg, two),
            (init, points_body, pixels),
            cfg.chunk,
            single,
        )

    def chunk(init, p, x, batched):
        if not batched:  # one problem: the LM only when the Gauss-Newton did not converge
            res, need = _refined_gn(init, p, x, camera, cfg, two)
            return jax.lax.cond(
                need, lambda: _refined_lm(init, p, x, camera, cfg, two), lambda: res
            )
        res, need = jax.vmap(lambda i, p, x: _refined_gn(i, p, x, camera, cfg, two))(init, p, x)
        lm = jax.vmap(lambda i, p, x: _refined_lm(i, p, x, camera, cfg, two))
        size = need.shape[0]
        slots = min(size, LM_SLOTS)

        def more(state):
            return jnp.any(state[1])

        def lm_round(state):
            # the next `slots` problems that need the LM, gathered (the unused lanes point past
            # the end: gathered as fill values, dropped when written back)
            res, left = state
            (where,) = jnp.nonzero(left, size=slots, fill_value=size)
            sub = jax.tree.map(lambda a: a.at[where].get(mode="fill", fill_value=0), (init, p, x))
            res = jax.tree.map(lambda a, b: a.at[where].set(b, mode="drop"), res, lm(*sub))
            return res, left.at[where].set(False, mode="drop")

        return jax.lax.while_loop(more, lm_round, (res, need))[0]

    return _map_chunks(chunk, (init, points_body, pixels), cfg.chunk, single)


def _finished(res: PnPResult, status, pose: Pose, rms) -> PnPResult:
    """The refined result of one problem: identity, zero and inf where the status drops it."""
    keep = _kept(status)
    dtype = pose.R.dtype
    pose = Pose(jnp.where(keep, pose.R, jnp.eye(3, dtype=dtype)), jnp.where(keep, pose.t, 0.0))
    return PnPResult(pose, status, jnp.where(keep, rms, jnp.inf), res.inliers, res.planar)


def _refined_lm(init: _Initial, p, x, camera, cfg: _Static, two: bool) -> PnPResult:
    """One problem refined by :func:`~jaxpose.core.refine.refine_pose`."""
    # The refined pose's derivatives come from implicit differentiation at the optimum;
    # the starting pose carries none (and EPnP's own are not defined everywhere).
    init = jax.lax.stop_gradient(init)
    res = init.result
    ok = res.status == Status.OK

    def run(pose):
        return refine_pose(p, x, pose, camera, mask=res.inliers, options=cfg.refine, throw=False)

    ref = run(res.pose)
    if two:
        flipped = planar_flip(res.pose, init.centroid, init.normal)
        flipped = jax.tree.map(lambda a, b: jnp.where(res.planar, a, b), flipped, res.pose)
        alt = run(flipped)
        better = (ref.status != Status.OK) | (alt.rms_px < ref.rms_px)
        take = res.planar & (alt.status == Status.OK) & better
        ref = jax.tree.map(lambda a, b: jnp.where(take, a, b), alt, ref)
    status = jnp.where(ok, ref.status, res.status).astype(jnp.int32)
    return _finished(res, status, ref.pose, ref.rms_px)


@jax.custom_jvp
def _error_with_derivatives(rms, R, t, p, x, camera, use):
    """``rms`` (the Gauss-Newton's reprojection error at ``(R, t)``), given the derivatives of
    :func:`~jaxpose.core.pnp._gauss_newton.reprojection_rms` in ``R``, ``t``, the points ``p``,
    the pixels ``x`` and the camera. The steps ran on held inputs; this puts the error's
    derivatives back without computing it twice in a plain solve."""
    return rms


def _gn_inputs(p, x, camera, use):
    """The arguments of :func:`~jaxpose.core.pnp._gauss_newton.gauss_newton_pnp` and
    :func:`~jaxpose.core.pnp._gauss_newton.reprojection_rms` after ``(R, t)``: the points and the
    normalised coordinates, zero where not used, the weights and the focal lengths."""
    keep = use[:, None]
    xy = jnp.where(keep, camera.normalize(x, undistort=False), 0.0)
    return jnp.where(keep, p, 0.0), xy, use.astype(p.dtype), jnp.stack([camera.fx, camera.fy])


def _error_at(R, t, p, x, camera, use):
    return reprojection_rms(R, t, *_gn_inputs(p, x, camera, use))[0]


@_error_with_derivatives.defjvp
def _error_with_derivatives_jvp(primals, tangents):
    rms, *args = primals
    _, *dargs = tangents
    use = args[-1]
    _, d = jax.jvp(lambda *a: _error_at(*a, use), tuple(args[:-1]), tuple(dargs[:-1]))
    return rms, d


def _refined_gn(init: _Initial, p, x, camera, cfg: _Static, two: bool):
    """One problem refined by the fast Gauss-Newton; also whether it must go to the LM."""
    init = jax.lax.stop_gradient(init)
    res = init.result
    ok = res.status == Status.OK
    use = res.inliers & ok
    # the steps carry no derivatives (they are the implicit function theorem's, below): held,
    # they are not linearised by a caller's grad
    p0, xy0, weights, fxy = _gn_inputs(*jax.lax.stop_gradient((p, x, camera)), use)

    def run(pose):
        return gauss_newton_pnp(
            p0, xy0, weights, fxy, pose, rtol=cfg.refine.rtol, atol=cfg.refine.atol
        )

    pose, rms, good = run(res.pose)
    if two:
        flipped = planar_flip(res.pose, init.centroid, init.normal)
        flipped = jax.tree.map(lambda a, b: jnp.where(res.planar, a, b), flipped, res.pose)
        pose_b, rms_b, good_b = run(flipped)
        take = res.planar & good_b & (~good | (rms_b < rms))
        pose = jax.tree.map(lambda a, b: jnp.where(take, a, b), pose_b, pose)
        rms = jnp.where(take, rms_b, rms)
        good = good | take
    # derivatives: the implicit function theorem at the optimum, as refine_pose's (and those of
    # the error at that pose)
    _, prob, *_ = _refine_problem(pose, p, x, camera, res.inliers, None, None, None, None, None)
    R, t = _with_implicit_grad(cfg.refine, pose.R, pose.t, prob)
    rms = _error_with_derivatives(rms, R, t, p, x, camera, use)
    status = jnp.where(ok, Status.OK, res.status).astype(jnp.int32)
    return _finished(res, status, Pose(R, t), rms), ok & ~good


def _initial_held(points_body, pixels, mask, keys, camera, cfg: _Static) -> _Initial:
    """:func:`_initial` of inputs that carry no derivatives. The refined pose's derivatives come
    from the implicit function theorem at the optimum; held here, the closed form and RANSAC are
    not linearised by a caller's ``grad`` at all instead of being linearised and dropped (with
    the Gauss-Newton steps held too, tracing ``jit(grad)`` of a 20-point solve took 18.2 -> 9.6
    s under a profiler; an eager ``grad`` of collinear points in the test suite, cold, 28.7 ->
    18.7 s). Without refinement the closed-form pose keeps its derivatives."""
    if cfg.refine is not None:
        points_body, pixels, camera = jax.lax.stop_gradient((points_body, pixels, camera))
    return _initial(points_body, pixels, mask, keys, camera, cfg)


def _solve_fused(points_body, pixels, mask, keys, intrinsics, *, cfg: _Static, two: bool):
    """Closed form and refinement in one call (from both candidates of planar problems when
    ``two``)."""
    points_body, pixels, mask, camera = _cast(points_body, pixels, mask, intrinsics)
    init = _initial_held(points_body, pixels, mask, keys, camera, cfg)
    if cfg.refine is None:
        return init.result
    return _refined(init, points_body, pixels, camera, cfg, two)


def _solve_stage1(points_body, pixels, mask, keys, intrinsics, *, cfg: _Static):
    points_body, pixels, mask, camera = _cast(points_body, pixels, mask, intrinsics)
    return _initial_held(points_body, pixels, mask, keys, camera, cfg)


def _solve_stage2(init, points_body, pixels, mask, intrinsics, *, cfg: _Static, two: bool):
    points_body, pixels, mask, camera = _cast(points_body, pixels, mask, intrinsics)
    return _refined(init, points_body, pixels, camera, cfg, two)


COMPILER_OPTIONS_CPU = {
    "xla_cpu_use_fusion_emitters": False,
    "xla_cpu_experimental_ynn_fusion_type": "",
}
"""XLA options of the compiled solvers on a CPU. XLA's older element-wise emitters compile this
code (hundreds of small fused kernels) about 1.6x faster than its MLIR fusion emitters for the
same run time (EPnP alone: 4.5 s -> 2.8 s of CPU time). No YNNPACK fusions: XLA hands the
reductions over a problem's points (``(256, 20) -> (256,)``) to YNNPACK, whose calls cost more
than the sums (EPnP 13.6 -> 11.6 us a problem, profiled with ``jax.profiler``). Each option is
dropped where the installed XLA does not know it (``known_cpu_options``)."""


def _cpu_options() -> dict:
    """:data:`COMPILER_OPTIONS_CPU` less the options that the installed XLA does not know."""
    return known_cpu_options(COMPILER_OPTIONS_CPU)


@functools.cache
def _compiled(name: str, cfg: _Static, two: bool, devices: int):
    """A jitted stage for one configuration, built on first use (importing jaxpose picks no
    backend). With several devices the batch axis is split over them (``shard_map``), the
    convention of :mod:`jaxpose.studies.selection`: on a CPU, run with
    ``XLA_FLAGS=--xla_force_host_platform_device_count=<cores>`` to use every core."""
    if name == "stage1":
        fn = functools.partial(_solve_stage1, cfg=cfg)
    else:
        fn = functools.partial(
            {"fused": _solve_fused, "stage2": _solve_stage2}[name], cfg=cfg, two=two
        )
    if devices > 1:
        from jax.sharding import Mesh, PartitionSpec

        mesh = Mesh(np.asarray(jax.local_devices()[:devices]), ("batch",))
        split, whole = PartitionSpec("batch"), PartitionSpec()
        fn = jax.shard_map(
            fn,
            mesh=mesh,
            in_specs=(split, split, split, split, whole),
            out_specs=split,
            check_vma=False,  # the problems are independent; nothing is reduced over devices
        )
    options = _cpu_options() if jax.default_backend() == "cpu" else None
    return jax.jit(fn, compiler_options=options)


@functools.cache
def _traced(cfg: _Static, two: bool):
    """The fused solve for callers that transform it: inside their ``jit`` it is inlined; under
    an eager ``grad`` or ``vmap`` it runs as one compiled program instead of op by op (eager
    ``grad`` of a 10-point solve: 84 -> 32 s of CPU time, mostly compilation). A jit apart from
    :func:`_compiled`'s: JAX refuses ``compiler_options`` on a jit nested in the caller's."""
    return jax.jit(functools.partial(_solve_fused, cfg=cfg, two=two))


_WARM_LOCK = threading.Lock()
_WARMED: dict = {}
_COMPILER: concurrent.futures.ThreadPoolExecutor | None = None


def _compile_stage2_aside(cfg: _Static, devices: int, args, intrinsics):
    """On the first two-stage solve of a shape, compile the refinement stage in another thread
    while the closed-form stage compiles and runs (XLA compiles without the GIL: the two
    compilations overlap). Returns the future of that compilation (the same one for the host
    threads that share a batch, so that it is compiled once)."""
    global _COMPILER
    shapes = tuple(None if a is None else (np.shape(a), str(a.dtype)) for a in args)
    key = (cfg, devices, shapes)
    with _WARM_LOCK:
        if key in _WARMED:
            return _WARMED[key]
        if _COMPILER is None:
            _COMPILER = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="jaxpose-xla")
        init = jax.eval_shape(_compiled("stage1", cfg, False, devices), *args, intrinsics)
        stage2 = _compiled("stage2", cfg, False, devices)
        future = _COMPILER.submit(lambda: stage2.lower(init, *args[:3], intrinsics).compile())
        _WARMED[key] = future
    return future


LM_SLOTS = 16
"""The problems of a chunk that the fast Gauss-Newton leaves to the LM (about 2% at 0.5 px noise,
5 of a chunk of 256) are gathered and refined this many at a time."""

FUSED_MAX = 64
"""Batches up to this size refine planar problems from both candidates in one compiled call;
larger ones first check (one device-to-host read) whether any problem is planar, so that
batches of non-planar problems are refined once."""


def solve_pnp(
    points_body: Float[ArrayLike, "... n 3"],
    pixels: Float[ArrayLike, "... n 2"],
    camera: PinholeCamera | Float[ArrayLike, "3 3"],
    *,
    mask: Bool[ArrayLike, "... n"] | None = None,
    key: Array | None = None,
    options: PnPOptions = PnPOptions(),
    throw: bool = True,
) -> PnPResult:
    """Pose of a target from 3-D/2-D point correspondences, for one problem or a batch.

    Args:
        points_body: ``(..., n, 3)`` model points in the body frame, metres (``n >= 4``).
        pixels: ``(..., n, 2)`` their measured (distorted) pixels. Leading axes of
            ``points_body``, ``pixels`` and ``mask`` broadcast (one model for many images works).
        camera: :class:`~jaxpose.core.camera.PinholeCamera` (with its distortion) or a
            ``3 x 3`` ``K``; one camera for the whole batch.
        mask: ``(..., n)`` bool, the valid points of padded sets.
        key: PRNG key of RANSAC (default ``jax.random.key(0)``), split over the batch.
        options: :class:`PnPOptions`: the closed-form method (``"epnp"``, ``"dlt"``,
            ``"ransac"``), the refinement (:class:`~jaxpose.core.refine.RefineOptions`: LM,
            Gauss-Newton or Sharma et al. 2018's Newton-Raphson, eqs. 23-29; a robust kernel;
            or ``None`` for the closed-form pose only), RANSAC's options, batching.
        throw: raise ``ValueError`` when any problem fails (the default); pass ``False`` for
            batches and read ``status``.

    Returns:
        :class:`~jaxpose.core.pnp.PnPResult` with the batch's leading axes: ``pose`` (``R``, ``t``
        with ``x_cam = R @ x_body + t``), ``status``, ``reprojection_error`` (RMS pixels over
        the points used), ``inliers`` and ``planar``. Failed problems have ``R = I``, ``t = 0``,
        an infinite error and a non-zero status.

    Raises:
        ValueError: shapes that do not match, fewer points than the method needs, a camera that
            is not one; with ``throw=True``, any problem whose status is not ``OK`` (NaN input,
            too few valid points, collinear or otherwise degenerate points, points behind the
            camera, ...), naming each failure and where it happened.
    """
    if not isinstance(options, PnPOptions):
        raise ValueError(f"options must be a PnPOptions; got {type(options).__name__}")
    method = options.method
    real_array(points_body, "points_body")
    real_array(pixels, "pixels")
    batch, n = _batch_shape(points_body, pixels, mask)
    if n < options.min_points:
        raise ValueError(
            f"solve_pnp(method={method!r}) needs at least {options.min_points} points; "
            f"points_body has n = {n}"
        )
    intrinsics, undistort = _intrinsics(camera)
    cfg = _Static(
        method=method,
        planar_tol=options.planar_tol,
        ransac=options.ransac if method == "ransac" else None,
        refine=options.refine,
        undistort=undistort,
        chunk=options.chunk,
    )
    size = int(np.prod(batch, dtype=int))
    flat = () if batch == () else (size,)
    points_body = _flat(points_body, batch, flat, (n, 3))
    pixels = _flat(pixels, batch, flat, (n, 2))
    if mask is not None:
        mask = as_bool_mask(mask)  # refuses indices or weights, while the values can be seen
    mask = np.ones(flat + (n,), bool) if mask is None else _flat(mask, batch, flat, (n,))
    traced = any_tracer((points_body, pixels, mask, intrinsics))
    keys = None
    if method == "ransac":
        key = jax.random.key(0) if key is None else key
        check_key(key)
        keys = key if batch == () else jax.random.split(key, size)
    two = options.refine is not None
    if traced:  # under the caller's transformation (jit, grad, vmap): one compiled unit
        res = _traced(cfg, two)(points_body, pixels, mask, keys, intrinsics)
    else:
        devices = jax.local_device_count() if size >= 2 * jax.local_device_count() else 1
        parts = _thread_parts(size, devices, options.workers)
        args = _pad((points_body, pixels, mask, keys), size, devices * parts)
        if parts == 1:
            res = _solve_eager(args, intrinsics, cfg, two, devices, size)
        else:
            step = args[0].shape[0] // parts
            pieces = [
                tuple(None if a is None else a[i * step : (i + 1) * step] for a in args)
                for i in range(parts)
            ]
            res = in_threads(
                lambda piece: _solve_eager(piece, intrinsics, cfg, two, devices, step), pieces
            )
            res = jax.tree.map(lambda *a: jnp.concatenate(a)[:size], *res)
    if len(batch) > 1:
        res = jax.tree.map(lambda a: a.reshape(batch + a.shape[1:]), res)
    if check_throw(throw):
        res = throw_for_status(
            res,
            f"solve_pnp(method={method!r})",
            "reprojection_error",
            min_points=options.min_points,
        )
    return res


def _solve_eager(args, intrinsics, cfg: _Static, two: bool, devices: int, size: int):
    """One compiled solve of a flat batch (``args`` padded to a multiple of ``devices``)."""
    if cfg.refine is None or size <= FUSED_MAX:
        res = _compiled("fused", cfg, two, devices)(*args, intrinsics)
    else:
        aside = _compile_stage2_aside(cfg, devices, args, intrinsics)
        init = _compiled("stage1", cfg, False, devices)(*args, intrinsics)
        planar = np.asarray(init.result.planar) & (np.asarray(init.result.status) == 0)
        aside.result()
        stage2 = _compiled("stage2", cfg, bool(planar.any()), devices)
        res = stage2(init, *args[:3], intrinsics)
    if res.status.ndim and res.status.shape[0] != size:
        res = jax.tree.map(lambda a: a[:size], res)
    return res


def _intrinsics(camera) -> tuple[Float[Array, "9"] | Float[np.ndarray, "9"], bool]:
    """``(fx, fy, cx, cy, k1, k2, p1, p2, k3)`` of a camera or ``K``, and whether to undistort."""
    if isinstance(camera, PinholeCamera):
        leaves = (camera.fx, camera.fy, camera.cx, camera.cy)
        if any(np.ndim(leaf) for leaf in leaves):
            raise ValueError("solve_pnp takes one camera for the batch (scalar intrinsics)")
        if any_tracer(leaves + (camera.dist,)):
            return jnp.concatenate([jnp.stack(leaves), camera.dist]), True
        values = np.concatenate(
            [np.asarray(leaves, dtype=float), np.asarray(camera.dist, dtype=float)]
        )
        return values, bool(np.any(values[4:] != 0))
    if isinstance(camera, jax.core.Tracer) and camera.shape == (3, 3):
        return jnp.concatenate(
            [camera[[0, 1, 0, 1], [0, 1, 2, 2]], jnp.zeros(5, camera.dtype)]
        ), False
    K = np.asarray(camera, dtype=float) if np.shape(camera) == (3, 3) else None
    if K is None:
        raise ValueError(
            f"camera must be a PinholeCamera or a 3x3 K matrix; got {type(camera).__name__} "
            f"of shape {np.shape(camera)}"
        )
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K must be finite with positive fx, fy; got {K.tolist()}")
    if (problem := intrinsic_matrix_problem(K)) is not None:
        raise ValueError(f"K has {problem}")
    return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], 0, 0, 0, 0, 0], dtype=float), False
