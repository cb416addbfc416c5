"""``python -m jaxpose``: the same commands as the ``jaxpose`` script (for a cluster's
``srun python -m jaxpose select-study ...`` or an environment without the script on PATH)."""

import sys

from jaxpose.cli import main

sys.exit(main())
