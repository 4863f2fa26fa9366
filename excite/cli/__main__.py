"""``python -m excite.cli``: the same as the ``excite`` command."""

from .app import run

run()
