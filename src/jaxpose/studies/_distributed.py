"""Running a study across processes and hosts with JAX's multi-controller runtime.

Every process runs the same program (``jax.distributed``: one process per host, or per GPU); the
cases of a study are sharded over *all* global devices, each process builds only the cases that its
own devices hold, the results are all-gathered so every process ends with the same values, and only
process 0 reads and writes files (resumable chunks, ``results.json``, figures).

How a run becomes multi-process (:func:`initialize`):

* explicitly, with the three arguments of :func:`jax.distributed.initialize`
  (``--coordinator-address HOST:PORT --num-processes N --process-id I`` on the command line);
* from the cluster's environment when ``JAXPOSE_DISTRIBUTED=1``: JAX's own detection reads SLURM
  (``SLURM_JOB_ID``, ``SLURM_STEP_NODELIST``, ``SLURM_NTASKS``, ``SLURM_PROCID``,
  ``SLURM_LOCALID``), Open MPI (``OMPI_MCA_orte_hnp_uri``, ``OMPI_COMM_WORLD_SIZE``,
  ``OMPI_COMM_WORLD_RANK``, ...) or Cloud TPU metadata, and ``JAX_COORDINATOR_ADDRESS``; options
  given on the command line override what it detects;
* otherwise the run is a single process (every helper below then reduces to the one-process
  behaviour, with the cases sharded over the local devices).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import pickle
import re
from collections.abc import Callable, Mapping
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

__all__ = [
    "ENV_FLAG",
    "DistributedOptions",
    "broadcast_from_writer",
    "case_sharding",
    "check_address",
    "global_array",
    "initialize",
    "is_writer",
    "local_rows",
    "map_cases",
    "to_host",
]

ENV_FLAG = "JAXPOSE_DISTRIBUTED"
"""Environment variable: ``1`` lets JAX detect the processes from the cluster (SLURM, Open MPI)."""

_AXIS = "cases"
_HOST_PORT = re.compile(r"^(?:\[(?P<v6>[0-9A-Fa-f:.]+)\]|(?P<host>[A-Za-z0-9_.-]+)):(?P<port>\d+)$")


def check_address(text: str) -> str:
    """``text`` if it is ``HOST:PORT`` (``[IPv6]:PORT`` too) with a port in 1..65535, else a
    ``ValueError`` naming ``--coordinator-address``."""
    match = _HOST_PORT.match(str(text).strip())
    if match is None or not 1 <= int(match["port"]) <= 65535:
        raise ValueError(
            "coordinator address (--coordinator-address) must be HOST:PORT with a port in "
            f"1..65535 (e.g. 10.0.0.1:12345 or [::1]:12345); got {text!r}"
        )
    return str(text).strip()


@dataclasses.dataclass(frozen=True)
class DistributedOptions:
    """The arguments of :func:`jax.distributed.initialize`; ``None`` leaves one to the cluster's
    environment (with ``JAXPOSE_DISTRIBUTED=1``).

    Attributes:
        coordinator_address: ``HOST:PORT`` of process 0's coordinator service.
        num_processes: number of processes ``N >= 1``.
        process_id: this process's index ``I``, ``0 <= I < N``.
        timeout_s: how long a process waits for the others to join (s).
    """

    coordinator_address: str | None = None
    num_processes: int | None = None
    process_id: int | None = None
    timeout_s: int = 300

    def __post_init__(self) -> None:
        if self.coordinator_address is not None:
            check_address(self.coordinator_address)
        n, i = self.num_processes, self.process_id
        if n is not None and not (isinstance(n, int | np.integer) and n >= 1):
            raise ValueError(f"number of processes (--num-processes) must be >= 1; got {n!r}")
        if i is not None and not (isinstance(i, int | np.integer) and i >= 0):
            raise ValueError(f"process id (--process-id) must be an integer >= 0; got {i!r}")
        if n is not None and i is not None and i >= n:
            raise ValueError(
                f"process id (--process-id) must lie in [0, N) with N = {n} (--num-processes); "
                f"got {i}"
            )
        if not (isinstance(self.timeout_s, int | np.integer) and self.timeout_s >= 1):
            raise ValueError(f"timeout_s must be an integer >= 1; got {self.timeout_s!r}")

    @property
    def explicit(self) -> bool:
        """Whether any of the three arguments is given."""
        return any(
            v is not None for v in (self.coordinator_address, self.num_processes, self.process_id)
        )


def _env_flag(environ: Mapping[str, str]) -> bool:
    value = environ.get(ENV_FLAG, "").strip().lower()
    if value in ("", "0", "false", "no", "off"):
        return False
    if value in ("1", "true", "yes", "on"):
        return True
    raise ValueError(f"{ENV_FLAG} must be 1 or 0 (true/false); got {environ[ENV_FLAG]!r}")


def initialize(
    options: DistributedOptions | None = None, *, environ: Mapping[str, str] | None = None
) -> bool:
    """Join the multi-process run the options (or the cluster, with ``JAXPOSE_DISTRIBUTED=1``)
    describe; returns ``True`` when :func:`jax.distributed.initialize` was called.

    Must run before any JAX computation. Without options and without the flag it does nothing (a
    one-process run). Given options need all three of address, ``N`` and ``I`` unless the flag lets
    JAX detect the missing ones. A run already initialised is left as it is.

    Raises:
        ValueError: options that do not go together, a flag that is not 0/1, or a cluster whose
            environment JAX cannot read (the message names the options to give).
    """
    options = options or DistributedOptions()
    environ = os.environ if environ is None else environ
    auto = _env_flag(environ)
    if not (options.explicit or auto):
        return False
    if jax.distributed.is_initialized():
        return True
    given = (options.coordinator_address, options.num_processes, options.process_id)
    if not auto and None in given:
        raise ValueError(
            "--coordinator-address, --num-processes and --process-id go together; give all three, "
            f"or set {ENV_FLAG}=1 to let JAX detect the missing ones from the cluster (SLURM, "
            "Open MPI)"
        )
    if not jax.config.jax_cpu_collectives_implementation:
        # Cross-process collectives on CPU (the CPU backend exists on GPU hosts too).
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
    try:
        jax.distributed.initialize(
            options.coordinator_address,
            None if options.num_processes is None else int(options.num_processes),
            None if options.process_id is None else int(options.process_id),
            initialization_timeout=int(options.timeout_s),
        )
    except (ValueError, TypeError, RuntimeError) as err:  # bad or missing values, no coordinator
        raise ValueError(
            f"cannot start the multi-process run ({err}); outside SLURM / Open MPI give "
            "--coordinator-address, --num-processes and --process-id, all reachable, before any "
            "JAX computation"
        ) from None
    return True


def is_writer() -> bool:
    """Whether this process writes the outputs (process 0; always true in a one-process run)."""
    return jax.process_index() == 0


def case_sharding() -> tuple[NamedSharding | None, int]:
    """``(sharding, devices)``: a 1-D ``cases`` mesh over every global device (process by process,
    so each process holds one contiguous block of rows), or ``(None, 1)`` on a single device."""
    devices = sorted(jax.devices(), key=lambda d: (d.process_index, d.id))
    if len(devices) == 1:
        return None, 1
    mesh = Mesh(np.asarray(devices), (_AXIS,))
    return NamedSharding(mesh, PartitionSpec(_AXIS)), len(devices)


def local_rows(length: int, sharding: NamedSharding | None) -> slice:
    """The rows of a ``(length, ...)`` array sharded by ``sharding`` that this process holds."""
    if sharding is None or sharding.is_fully_addressable:
        return slice(0, length)
    index = sharding.addressable_devices_indices_map((length,))
    starts = [s[0].start or 0 for s in index.values()]
    stops = [length if s[0].stop is None else s[0].stop for s in index.values()]
    lo, hi = min(starts), max(stops)
    if hi - lo != sum(b - a for a, b in zip(starts, stops, strict=True)):
        raise ValueError("this process's rows are not contiguous; use case_sharding()")
    return slice(lo, hi)


def global_array(local, sharding: NamedSharding | None, length: int):
    """The global ``(length, ...)`` array whose rows :func:`local_rows` are ``local`` (this
    process's block); a plain ``device_put`` in a one-process run."""
    if sharding is None:
        return local
    if sharding.is_fully_addressable:
        return jax.device_put(local, sharding)
    local = np.asarray(local)
    return jax.make_array_from_process_local_data(sharding, local, (length, *local.shape[1:]))


def to_host(tree: Any) -> Any:
    """NumPy copies of the arrays of ``tree`` on every process; the leaves that other processes
    hold rows of are all-gathered in one collective call (one compilation per tree of shapes)."""
    leaves, treedef = jax.tree.flatten(tree)
    remote = [
        i for i, x in enumerate(leaves) if isinstance(x, jax.Array) and not x.is_fully_addressable
    ]
    if remote:
        mesh = leaves[remote[0]].sharding.mesh
        gathered = jax.jit(_identity, out_shardings=NamedSharding(mesh, PartitionSpec()))(
            [leaves[i] for i in remote]
        )
        for i, x in zip(remote, gathered, strict=True):
            leaves[i] = x.addressable_data(0)
    return jax.tree.unflatten(treedef, [np.asarray(x) for x in leaves])


def _identity(x):
    return x


def broadcast_from_writer(read: Callable[[], Any]) -> Any:
    """``read()`` on process 0 (file reads stay on one host), its value sent to every process.

    The value travels pickled as bytes through two collectives (length, then data), so any
    picklable value works, ``None`` included."""
    if jax.process_count() == 1:
        return read()
    from jax.experimental import multihost_utils

    source = is_writer()
    blob = pickle.dumps(read(), protocol=pickle.HIGHEST_PROTOCOL) if source else b""
    size = int(multihost_utils.broadcast_one_to_all(np.int64(len(blob)), is_source=source))
    # Padded to a power of two: a handful of compiled broadcasts serve every size.
    padded = 1 << max(8, (size - 1).bit_length())
    data = np.zeros(padded, np.uint8)
    if source:
        data[:size] = np.frombuffer(blob, np.uint8)
    data = np.asarray(multihost_utils.broadcast_one_to_all(data, is_source=source))
    return pickle.loads(data[:size].tobytes())


def map_cases(fn: Callable, batched: tuple, shared: tuple = ()) -> Any:
    """``fn(*batched, *shared)`` with the leading (case) axis of every ``batched`` leaf sharded
    over all global devices; returns the outputs as NumPy arrays on every process.

    ``fn`` must treat the cases independently (a ``vmap``): each device runs it on its own block
    (``jax.shard_map``, so a batched ``while_loop`` stops per device, without a collective per
    iteration), the batch padded to a multiple of the device count with copies of its last case
    and the padding dropped afterwards. On a single device this is ``fn`` itself; pass a jitted
    ``fn`` (``jax.jit(jax.vmap(...))``) so that both paths compile it.
    """
    sharding, ndev = case_sharding()
    if sharding is None:
        return jax.tree.map(np.asarray, fn(*batched, *shared))
    leaves = jax.tree.leaves(batched)
    length = int(leaves[0].shape[0])
    padded = int(math.ceil(length / ndev)) * ndev
    rows = local_rows(padded, sharding)

    def block(x):
        x = np.asarray(x)
        if padded > length:
            x = np.concatenate([x, np.repeat(x[-1:], padded - length, axis=0)])
        return global_array(x[rows], sharding, padded)

    run = _sharded(fn, len(batched), len(shared), sharding.mesh)
    out = run(*jax.tree.map(block, batched), *shared)
    return jax.tree.map(lambda y: y[:length], to_host(out))


@functools.lru_cache(maxsize=32)
def _sharded(fn: Callable, num_batched: int, num_shared: int, mesh: Mesh) -> Callable:
    """``fn`` per device block, compiled once per function, argument count and mesh."""
    spec = PartitionSpec(_AXIS)
    return jax.jit(
        jax.shard_map(
            fn,
            mesh=mesh,
            in_specs=(spec,) * num_batched + (PartitionSpec(),) * num_shared,
            out_specs=spec,
            # Per-device code need not declare which values vary across devices (a core solver's
            # while_loop starts from constants): no collectives are inside.
            check_vma=False,
        )
    )
