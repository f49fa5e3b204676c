"""``python -m cosim``: the `cosim` command, for where the console script is not on PATH."""

import sys

from .cli import main

sys.exit(main())
