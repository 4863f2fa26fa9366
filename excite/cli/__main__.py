"""``python -m excite.cli``: the same as the ``excite`` command."""

import sys

from . import main

sys.exit(main())
