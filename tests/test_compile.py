"""The eager entry points' compile options (``jaxpose.core._compile``)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose.core._compile import eager_jit, known_cpu_options


def test_an_option_the_installed_xla_does_not_know_is_dropped():
    known = {"xla_backend_optimization_level": 0}
    unknown = {"xla_jaxpose_no_such_option": True}
    assert known_cpu_options({**known, **unknown}) == known
    # the same unknown name given to XLA fails the compilation: why it must be dropped
    x = jax.device_put(1.0, jax.devices("cpu")[0])
    with pytest.raises(Exception, match="compile option"):
        jax.jit(lambda v: v + 1.0, compiler_options=unknown).lower(x).compile()


def test_an_eager_entry_point_with_an_unknown_option_still_computes():
    def f(x, k):
        return jnp.sin(x) * k

    call = eager_jit(f, static_argnums=(1,), cpu_options={"xla_jaxpose_no_such_option": True})
    x = np.linspace(0.0, 1.0, 5)
    np.testing.assert_allclose(np.asarray(call(x, 3)), np.sin(x) * 3, rtol=1e-12)
    # under the caller's transformation it is traced, not compiled with options
    np.testing.assert_allclose(
        np.asarray(jax.grad(lambda v: call(v, 3).sum())(x)), np.cos(x) * 3, rtol=1e-12
    )
    # known values inside the caller's jit are constants of its program: traced, not refused
    # (JAX refuses compiler options on a nested jit)
    default = eager_jit(f, static_argnums=(1,))
    np.testing.assert_allclose(np.asarray(jax.jit(lambda: default(x, 3))()), np.sin(x) * 3)


def _compilations(fn):
    """The number of XLA compilations that ``fn()`` causes (JAX's own event)."""
    seen = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            seen.append(duration)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        jax.block_until_ready(fn())
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    return len(seen)


def test_small_functions_compile_once_per_shape_and_equal_their_traced_form():
    from jaxpose.core.camera import PinholeCamera
    from jaxpose.core.geometry import so3_exp

    cam = PinholeCamera(800.0, 810.0, 320.0, 240.0, np.array([0.1, -0.02, 1e-3, 2e-3, 0.01]))
    points = np.random.default_rng(1).normal(size=(13, 3)) + [0.0, 0.0, 5.0]
    omega = np.random.default_rng(2).normal(size=(11, 3))
    so3_exp(omega[:2])  # the first call also asks XLA which options it knows
    # eagerly, one program for a new shape (each operation of these alone compiles more than 10)
    assert _compilations(lambda: cam.project(points)) == 1
    assert _compilations(lambda: so3_exp(omega)) == 1
    assert _compilations(lambda: so3_exp(omega)) == 0
    # the same numbers as the function traced inline into a caller's program
    np.testing.assert_allclose(
        cam.project(points), jax.jit(lambda c, p: c.project(p))(cam, points), rtol=1e-14
    )
    np.testing.assert_allclose(so3_exp(omega), jax.jit(so3_exp)(omega), rtol=1e-14, atol=1e-15)
    # known values inside a caller's jit (constants of its program) are traced inline
    np.testing.assert_allclose(jax.jit(lambda: so3_exp(omega))(), so3_exp(omega), atol=1e-15)


@pytest.mark.typecheck_off  # the package's own ValueError, not jaxtyping's
def test_small_functions_name_the_argument_that_is_not_numbers():
    from jaxpose.core.geometry import euler_to_dcm, so3_exp

    with pytest.raises(ValueError, match="omega must hold real numbers"):
        so3_exp(["a", "b", "c"])
    with pytest.raises(ValueError, match="omega must hold real numbers"):
        so3_exp([[0.1, 0.2, 0.3], [0.1, 0.2]])  # ragged
    with pytest.raises(ValueError, match="Euler sequence must be"):
        euler_to_dcm(np.zeros(3), ["X", "Y", "Z"])  # not hashable: the function's own check
