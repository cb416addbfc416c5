"""The ``jaxpose`` sub-commands (one module a command, each with ``add_arguments(parser)`` and
``run(args)``) and their shared plumbing in :mod:`jaxpose.commands._common`."""

from __future__ import annotations

from jaxpose.commands._common import CommandError as CommandError
from jaxpose.commands._common import enable_compilation_cache as enable_compilation_cache

__all__ = ["CommandError", "enable_compilation_cache"]
