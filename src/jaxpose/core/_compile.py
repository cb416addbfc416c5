"""How the eager entry points compile themselves (the fast front door)."""

from __future__ import annotations

import functools
import inspect

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.core._checks import real_array

EAGER_COMPILER_OPTIONS_CPU = {
    "xla_backend_optimization_level": 0,
    "xla_cpu_use_fusion_emitters": False,
}
"""XLA options of an eager entry point's own compilation on a CPU. An eager call of one small
problem is dominated by dispatch (about 0.3 ms), not by the compiled code, so the first call's
compilation is what a user waits for: these options compile ``jp.dop`` several times faster
(``bench/front_door.py``) at no visible cost per call. Under the caller's ``jax.jit`` the entry
point is traced into the caller's program and compiled with the caller's options."""


@functools.cache
def _known_option(name: str, value) -> bool:
    """Whether the installed XLA takes ``name`` as a compile option (one tiny compilation on the
    CPU, once per option and process)."""
    try:
        x = jax.device_put(1.0, jax.devices("cpu")[0])
        jax.jit(lambda v: v + 1.0, compiler_options={name: value}).lower(x).compile()
    except Exception:  # "No such compile option"
        return False
    return True


def known_cpu_options(options: dict) -> dict:
    """``options`` less those that the installed XLA does not know. XLA's option names come and
    go between releases (``xla_cpu_use_fusion_emitters`` is known to jaxlib 0.10 and refused as
    a flag by jaxlib 0.11, ``xla_cpu_experimental_ynn_fusion_type`` is new), and an unknown
    name makes the whole compilation fail; these options only change compile and run times,
    never results, so an unknown one is dropped."""
    return {k: v for k, v in options.items() if _known_option(k, v)}


def any_tracer(tree) -> bool:
    """Whether any leaf of ``tree`` is a tracer (the call is under the caller's ``jit``,
    ``vmap`` or ``grad``)."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(tree))


def _with_options(fn, cpu_options: dict, inline, **jit_kwargs):
    """``fn`` compiled with ``cpu_options`` on a CPU (built on first use for the backend then in
    use: importing jaxpose picks no backend). Called with known values while the caller's
    ``jit`` is being traced (constants of its program), JAX refuses compiler options on the
    nested jit: ``inline`` takes the call instead."""

    @functools.cache
    def compiled(backend: str):
        options = known_cpu_options(cpu_options) if backend == "cpu" else None
        return jax.jit(fn, compiler_options=options, **jit_kwargs)

    def call(*args, **kwargs):
        try:
            return compiled(jax.default_backend())(*args, **kwargs)
        except ValueError as error:
            if "top-level" not in str(error):
                raise
            return inline(*args, **kwargs)

    return call


def eager_jit(fn, static_argnums: tuple[int, ...], cpu_options: dict | None = None):
    """``jax.jit(fn)`` with ``cpu_options`` (default :data:`EAGER_COMPILER_OPTIONS_CPU`) on a
    CPU. Called with traced arguments (inside the caller's ``jit``, ``vmap`` or ``grad``), or
    with known values inside the caller's ``jit``, a plain ``jax.jit(fn)`` takes them: JAX
    refuses compiler options on a jit nested in the caller's; this one is inlined into the
    caller's ``jit``, and one compiled program under an eager ``grad`` or ``vmap`` instead of a
    dispatch per operation."""
    cpu = EAGER_COMPILER_OPTIONS_CPU if cpu_options is None else cpu_options
    traced = jax.jit(fn, static_argnums=static_argnums)
    eager = _with_options(fn, cpu, traced, static_argnums=static_argnums)

    @functools.wraps(fn)
    def call(*args):
        return traced(*args) if any_tracer(args) else eager(*args)

    return call


def small_jit(fn=None, *, static_argnames: tuple[str, ...] = ()):
    """One compiled program per input shape for a small function of the core (a projection, a
    rotation formula) when it is called eagerly, instead of one dispatch and one compilation per
    operation. Measured on the project's 2-core CPU at XLA's default options: ``so3_exp`` of a
    new shape 1.56 -> 0.11 s, ``PinholeCamera.project`` 0.87 -> 0.09 s (17 compilations -> 1),
    a repeated ``so3_exp`` 6 -> 0.2 ms.

    Eagerly, lists and NumPy arrays are checked first (:func:`~jaxpose.core._checks.real_array`:
    a ``ValueError`` naming the argument, as the function's own checks would) and the function
    is compiled with :data:`EAGER_COMPILER_OPTIONS_CPU` on a CPU. Under the caller's ``jit``,
    ``vmap`` or ``grad`` it is traced inline as written (the caller's program is unchanged), and
    so are a call with known values inside the caller's ``jit`` and a call whose static
    arguments cannot be hashed (the function's own check names them).
    Shape checks run at trace time, so they still raise; checks of values must not be inside
    ``fn`` (under ``jit`` they would not see values)."""
    if fn is None:
        return functools.partial(small_jit, static_argnames=static_argnames)
    signature = inspect.signature(fn)
    eager = _with_options(fn, EAGER_COMPILER_OPTIONS_CPU, fn, static_argnames=static_argnames)

    @functools.wraps(fn)
    def call(*args, **kwargs):
        if any_tracer((args, kwargs)):
            return fn(*args, **kwargs)
        bound = signature.bind(*args, **kwargs)
        for name, value in bound.arguments.items():
            if name in static_argnames:
                try:
                    hash(value)
                except TypeError:
                    return fn(*args, **kwargs)
            elif isinstance(value, list | tuple | np.ndarray | np.generic):
                bound.arguments[name] = np.asarray(real_array(value, name))
        return eager(*bound.args, **bound.kwargs)

    return call


def in_float64(fn):
    """Run ``fn`` with ``jax_enable_x64`` on whatever the caller's setting (its arrays come back
    float64). For the pipelines, whose results must not depend on a global flag set elsewhere:
    the monocular ranking compares scores that differ in the fourth digit and its confidence
    rule was calibrated in float64; the stereo solves form normal equations (the condition
    number squared)."""

    @functools.wraps(fn)
    def call(*args, **kwargs):
        with jax.enable_x64(True):
            # JAX arrays made while float64 was off (a camera, a model, a pose built before the
            # call) are float32: widened first (their values as the caller holds them), so that
            # the pipeline computes in one precision (mixed, strict dtype promotion refuses them)
            args, kwargs = jax.tree.map(_widened, (args, kwargs))
            return fn(*args, **kwargs)

    return call


def _widened(leaf):
    """A concrete lower-precision floating JAX array as float64; anything else as it is (NumPy
    arrays, images and options are the pipelines' own to convert)."""
    if (
        isinstance(leaf, jax.Array)
        and not isinstance(leaf, jax.core.Tracer)
        and jnp.issubdtype(leaf.dtype, jnp.floating)
        and leaf.dtype != jnp.float64
    ):
        return leaf.astype(jnp.float64)
    return leaf
