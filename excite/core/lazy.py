"""Modules imported on first use. Scoring a drive never needs CasADi (the kinds' compiled kernels
do the evaluator's work), but every kind states its math in CasADi: importing it there would make
every ``excite score`` load it (the command line's cold start, ``tests/cli/test_app.py``)."""

from __future__ import annotations

import importlib
from typing import Any


class LazyModule:
    """A module imported at the first attribute read (not registered before that)."""

    def __init__(self, name: str):
        self._name = name

    def __getattr__(self, attr: str) -> Any:
        return getattr(importlib.import_module(self._name), attr)


ca = LazyModule("casadi")  # the name excite's CasADi code uses for it
