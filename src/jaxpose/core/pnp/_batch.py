"""Batching machinery of :func:`jaxpose.solve_pnp`: chunked ``vmap``, padding, host threads."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.core._threads import cpu_cores as _cpu_cores

CHUNK = 256
"""Batches larger than this run as a loop over chunks of this many problems (``lax.map``): the
working set of a chunk stays in cache, which is faster on a CPU than one pass over everything."""


def _map(fn, args, chunk: int, single: bool):
    """``vmap`` over the leading axis, as a loop over chunks when the batch is large; a single
    problem is solved as it is."""
    if single:
        return fn(*args)
    size = jax.tree.leaves(args)[0].shape[0]
    if size <= chunk:
        return jax.vmap(fn)(*args)
    pad = -size % chunk
    args = jax.tree.map(lambda a: jnp.concatenate([a, jnp.repeat(a[:1], pad, axis=0)]), args)
    out = jax.lax.map(lambda a: fn(*a), args, batch_size=chunk)
    return jax.tree.map(lambda a: a[:size], out)


def _map_chunks(fn, args, chunk: int, single: bool):
    """Like :func:`_map`, for a function of a whole chunk: ``fn(*args, batched=...)`` takes
    arrays with a leading chunk axis (``batched=True``) or one problem (``batched=False``), so
    that it can decide once for the chunk (a ``lax.cond`` on any of its problems)."""
    if single:
        return fn(*args, batched=False)
    size = jax.tree.leaves(args)[0].shape[0]
    if size <= chunk:
        return fn(*args, batched=True)
    pad = -size % chunk
    count = (size + pad) // chunk

    def split(a):
        a = jnp.concatenate([a, jnp.repeat(a[:1], pad, axis=0)]) if pad else a
        return a.reshape((count, chunk) + a.shape[1:])

    out = jax.lax.map(lambda a: fn(*a, batched=True), jax.tree.map(split, args))
    return jax.tree.map(lambda a: a.reshape((count * chunk,) + a.shape[2:])[:size], out)


def _pad(args, size: int, devices: int):
    """Repeat the first problem so that the batch splits evenly over ``devices``."""
    pad = -size % devices
    if devices == 1 or pad == 0:
        return args

    def one(a):
        xp = jnp if isinstance(a, jax.Array) else np
        return xp.concatenate([a, xp.repeat(a[:1], pad, axis=0)])

    return tuple(None if a is None else one(a) for a in args)


THREAD_MIN_PROBLEMS = 2048
"""Each thread of a CPU solve gets at least this many problems (below, the split costs more than
it saves)."""


def _thread_parts(size: int, devices: int, workers: int | None) -> int:
    """How many host threads share a batch. XLA runs one execution of these solvers on about one
    CPU core, so a large batch on a single CPU device is cut into equal parts solved by
    concurrent executions of the same compiled function (measured in ``bench/pnp.py``: 1.6x at
    B = 10 000 on 2 cores). Not used on accelerators, nor with several devices (``shard_map``
    already splits the batch)."""
    if workers is not None:
        return max(1, min(int(workers), size))
    if devices > 1 or jax.default_backend() != "cpu":
        return 1
    return max(1, min(_cpu_cores(), size // THREAD_MIN_PROBLEMS))


def _flat(x, batch, flat, tail):
    """Broadcast the leading axes to ``batch`` and flatten them (eagerly; NumPy stays NumPy)."""
    xp = jnp if isinstance(x, jax.Array) else np
    x = x if xp is jnp else np.asarray(x)
    if x.shape[: x.ndim - len(tail)] == flat:
        return x
    return xp.broadcast_to(x, batch + tail).reshape(flat + tail)
