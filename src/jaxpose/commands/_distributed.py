"""The multi-process options shared by the study commands (``select-study``, ``pose-study``).

``--coordinator-address HOST:PORT --num-processes N --process-id I`` are the arguments of
:func:`jax.distributed.initialize`; with ``JAXPOSE_DISTRIBUTED=1`` and none of them, JAX detects
the processes from the cluster (SLURM, Open MPI). See ``docs/distributed.md`` and
:mod:`jaxpose.studies._distributed`.
"""

from __future__ import annotations

import argparse

from jaxpose.commands._common import nonnegative_int, positive_int

__all__ = ["add_distributed_arguments", "start_distributed"]


def _address(text: str) -> str:
    from jaxpose.studies._distributed import check_address

    try:
        return check_address(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected HOST:PORT with a port in 1..65535 (e.g. 10.0.0.1:12345); got {text!r}"
        ) from None


def add_distributed_arguments(parser: argparse.ArgumentParser) -> None:
    """``--coordinator-address``, ``--num-processes``, ``--process-id``."""
    g = parser.add_argument_group(
        "multi-process run (jax.distributed; or JAXPOSE_DISTRIBUTED=1 on SLURM / Open MPI)"
    )
    g.add_argument(
        "--coordinator-address",
        type=_address,
        metavar="HOST:PORT",
        help="address of process 0's coordinator service, the same for every process",
    )
    g.add_argument(
        "--num-processes", type=positive_int, metavar="N", help="number of processes in the run"
    )
    g.add_argument(
        "--process-id", type=nonnegative_int, metavar="I", help="this process's index in [0, N)"
    )


def start_distributed(args: argparse.Namespace) -> bool:
    """Join the multi-process run the options (or the environment) describe, before any JAX
    computation; returns whether this process writes the outputs (process 0, or a lone process).

    Raises:
        ValueError: options that do not go together (printed as a one-line error by the CLI).
    """
    from jaxpose.studies._distributed import DistributedOptions, initialize, is_writer

    initialize(
        DistributedOptions(
            coordinator_address=args.coordinator_address,
            num_processes=args.num_processes,
            process_id=args.process_id,
        )
    )
    return is_writer()
