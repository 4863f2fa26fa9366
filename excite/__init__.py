"""excite: calibration excitation planner for autonomous vehicles.

The names below load on first use (PEP 562): ``excite --help`` or ``import excite.errors`` need
neither numpy nor scipy.
"""

from __future__ import annotations

import importlib
from typing import Any

from .errors import EvaluationError, ExciteError, LimitError, RigError, RouteError

_LAZY = {
    "GRAVITY": "motion.trajectory", "BodySamples": "motion.trajectory", "MotionSamples": "motion.trajectory",
    "Trajectory": "motion.trajectory", "ControlProfile": "motion.vehicle", "Limits": "motion.vehicle",
    "Suspension": "motion.vehicle", "Violation": "motion.vehicle", "check_limits": "motion.vehicle",
    "drive": "motion.vehicle",
}

__all__ = [
    "GRAVITY", "BodySamples", "ControlProfile", "EvaluationError", "ExciteError", "LimitError",
    "Limits", "MotionSamples", "RigError", "RouteError", "Suspension", "Trajectory", "Violation",
    "check_limits", "drive",
]
__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'excite' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
