"""Settings, progress reports and the result of an optimization (plain data)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from .. import bounds
from ..errors import ExciteError
from ..evaluate import Report
from ..trajectory import Trajectory
from ..vehicle import ControlProfile, Limits


class OptimizeError(ExciteError, ValueError):
    """The optimization cannot be set up (bad settings, a lot too small for the limits)."""


@dataclass(frozen=True)
class OptimizeSettings:
    """What to optimize for. SI units.

    ``duration_s``: length of the maneuver, from rest to rest.
    ``lot_x_m`` × ``lot_y_m``: the rectangular test lot, the first number along the
    world x axis (the ``80`` of ``--lot 80x50``), the second along y; centred on the origin.
    The path of the rear axle stays ``maneuvers.EDGE_MARGIN_M`` (3 m) inside its edges, like the
    reference maneuvers and the random candidates it is compared with.
    ``limits``: every vehicle limit (speed, acceleration, deceleration, jerk, lateral
    acceleration, curvature, curvature rate), enforced at sample points.
    ``seed``: random candidates and multi-starts; the same seed gives the same result (up to
    the time budget cutting a run short at a different iteration).
    ``time_budget_s``: wall-clock budget of the optimization phase (IPOPT, all starts); the
    derivative-free baseline gets the same budget.
    ``closed``: the end pose equals the start pose (position and heading).
    ``n_random``: random candidates drawn for the start and the comparison (0: none).
    """

    duration_s: float = 90.0
    lot_x_m: float = 80.0
    lot_y_m: float = 50.0
    limits: Limits = field(default_factory=Limits)
    seed: int = 0
    time_budget_s: float = 60.0
    closed: bool = False
    n_random: int = 200

    def __post_init__(self) -> None:
        def finite(name: str) -> float:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise OptimizeError(f"{name} must be a finite number, got {value!r}")
            return float(value)

        for name in ("duration_s", "lot_x_m", "lot_y_m", "time_budget_s"):
            bounds.check_range(bounds.OPTIMIZE, name, finite(name), OptimizeError)
        if not isinstance(self.limits, Limits):
            raise OptimizeError(f"limits must be an excite.vehicle.Limits, got {type(self.limits).__name__}")
        for name in ("seed", "n_random"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int):
                raise OptimizeError(f"{name} must be an integer, got {value!r}")
            bounds.check_range(bounds.OPTIMIZE, name, value, OptimizeError)
        if not isinstance(self.closed, bool):
            raise OptimizeError(f"closed must be true or false, got {self.closed!r}")


@dataclass(frozen=True)
class Progress:
    """One progress report: the optimizer's iteration, the current λ_min of its (coarse) model,
    the largest constraint violation, the wall time since the start, and the phase
    (``"start"``, ``"optimize"``, ``"baseline"``, ``"rescore"``, ``"done"``)."""

    iteration: int
    score: float
    constraint_violation: float
    elapsed_s: float
    phase: str


@dataclass
class OptimizeResult:
    """The optimized maneuver, its full evaluator report, and the comparison with the baselines.

    ``comparison``: one row per candidate, best first: ``{name, kind, score, ratio, feasible,
    violations}`` with ``kind`` one of ``optimized``, ``reference``, ``random``, ``cobyla``,
    ``start``; ``score`` from the full evaluator; ``ratio`` = optimized score / this score.
    ``status``: ``"optimal"`` (converged), ``"time_budget"``, ``"cancelled"`` or
    ``"start_only"`` (no feasible improvement over the start was found).
    """

    profile: ControlProfile
    trajectory: Trajectory
    report: Report
    comparison: list[dict[str, Any]]
    status: str
    iterations: int
    elapsed_s: float
    cancelled: bool
    model_score: float = float("nan")  # λ_min of the optimizer's coarse model at the result
    timings_s: dict[str, float] = field(default_factory=dict)
    message: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (the report is :meth:`Report.to_dict`)."""
        return {
            "status": self.status, "iterations": self.iterations, "elapsed_s": self.elapsed_s,
            "cancelled": self.cancelled, "model_score": self.model_score, "score": self.report.score,
            "timings_s": self.timings_s, "message": self.message, "comparison": self.comparison,
            "report": self.report.to_dict(),
        }
