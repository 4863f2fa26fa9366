"""The excite HTTP service: a thin FastAPI layer over the :mod:`excite` library.

``create_app(Settings())`` builds the app; ``excite serve`` runs it with uvicorn. The names load
on first use, so that a job's or a worker's process imports none of the web stack it does not use.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["Settings", "create_app"]
_LAZY = {"Settings": "settings", "create_app": "app"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
