"""``excite score``: the evaluator's report of a route."""

from __future__ import annotations

from . import app  # noqa: F401
