"""Host threads for batched work on a CPU: XLA runs one execution of a compiled function on about
one core, so a batch cut into parts runs faster as concurrent executions of the same function,
one host thread a core (measured in ``bench/pnp.py``: 1.6x at B = 10 000 on 2 cores)."""

from __future__ import annotations

import concurrent.futures
import os
import threading

import jax

__all__ = ["cpu_cores", "in_core_threads", "in_threads"]


def cpu_cores() -> int:
    """The CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


_POOL: concurrent.futures.ThreadPoolExecutor | None = None
_POOL_SIZE = 0
_POOL_LOCK = threading.Lock()


def in_threads(fn, pieces: list) -> list:
    """``[fn(p) for p in pieces]`` on a shared thread pool, each result ready, each piece run
    with the caller's ``jax_enable_x64``. (JAX compiles a function once when several threads
    call it first at the same time.)"""
    global _POOL, _POOL_SIZE
    with _POOL_LOCK:
        if _POOL_SIZE < len(pieces):
            _POOL_SIZE = len(pieces)
            _POOL = concurrent.futures.ThreadPoolExecutor(
                max_workers=len(pieces), thread_name_prefix="jaxpose-solve"
            )
        pool = _POOL
    # JAX's precision switch is per thread: a worker takes the caller's (an entry point that runs
    # in float64 whatever the global flag, jaxpose.core._compile.in_float64, would otherwise
    # have its chunks computed in float32 when the flag is off)
    x64 = bool(jax.config.jax_enable_x64)

    def run(p):
        with jax.enable_x64(x64):
            return jax.block_until_ready(fn(p))

    futures = [pool.submit(run, p) for p in pieces]
    return [f.result() for f in futures]


def in_core_threads(fn, items: list) -> list:
    """``[fn(x) for x in items]``, the items shared out to one host thread per CPU core (dealt
    in turn), when JAX runs on the CPU; the same results in the same order."""
    parts = min(len(items), cpu_cores()) if jax.default_backend() == "cpu" else 1
    if parts < 2:
        return [fn(x) for x in items]
    groups = [items[i::parts] for i in range(parts)]
    done = in_threads(lambda group: [fn(x) for x in group], groups)
    out = [None] * len(items)
    for i, results in enumerate(done):
        out[i::parts] = results
    return out
