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
