"""``python -m excite.cli``: the same as the ``excite`` command."""

from . import run

run()
