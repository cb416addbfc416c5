"""Command-line sub-commands of the monocular system (``jaxpose init``, ``jaxpose
eval-speedplus``); each module has ``add_arguments(parser)`` and ``run(args)``."""

from __future__ import annotations

import os


def enable_compilation_cache() -> None:
    """Persist XLA compilations between runs (``$JAXPOSE_CACHE_DIR`` or ``~/.cache/jaxpose/xla``):
    the monocular pipeline compiles for about two minutes the first time, seconds afterwards."""
    import jax

    path = os.environ.get(
        "JAXPOSE_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache", "jaxpose", "xla")
    )
    try:
        os.makedirs(path, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", path)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    except (OSError, AttributeError):  # read-only home or an old JAX: run without the cache
        pass
