"""``python -m cosim.cli``: how `cosim run` starts its run process under the supervisor."""

import sys

from . import main

sys.exit(main())
