"""Settings, progress reports and the result of an optimization (plain data)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

from ..core import bounds
from ..errors import OptimizeError
from ..score.evaluate import Report
from ..motion.trajectory import Trajectory
from ..motion.vehicle import ControlProfile, Limits


@dataclass(frozen=True)
class OptimizeSettings:
    """What to optimize for. SI units.

    ``duration_s``: length of the maneuver, from rest to rest.
    ``lot_x_m`` × ``lot_y_m``: a rectangular test lot, the first number along the
    world x axis (the ``80`` of ``--lot 80x50``), the second along y; centred on the origin.
    ``site``: any other lot (:class:`~excite.plan.site.Site`: a polygon with keep-out
    zones, an entry pose, terrain); when given, ``lot_x_m`` and ``lot_y_m`` are ignored.
    The path of the rear axle stays the site's margin (3 m) inside its edges, like the
    reference maneuvers and the random candidates it is compared with.
    ``limits``: every vehicle limit (speed, acceleration, deceleration, jerk, lateral
    acceleration, curvature, curvature rate); the optimizer takes the tighter of these and the
    rig's own (:meth:`for_rig`: a car's steering-wheel rate).
    ``seed``: random candidates and the start; the same seed gives the same result (up to
    the time budget cutting a run short at a different iteration).
    ``time_budget_s``: wall-clock budget of the whole run: the comparison candidates, COBYLA,
    IPOPT and the checks (see :mod:`.pipeline`).
    ``closed``: the end pose equals the start pose (position and heading).
    ``n_random``: random candidates drawn for the start and the comparison (0: none).
    ``criterion``: what is maximised: ``E`` (λ_min, the score), ``D`` (log det) or ``A``
    (−trace of the inverse) of the target-scaled information (:mod:`.criteria`).
    ``max_iterations``: cap on IPOPT's iterations (None: until converged or out of time).
    ``starts``: IPOPT runs from this many of the best candidates (by the optimizer's model), at
    once on as many cores as are free (or on the Dask cluster); the best checked plan wins, and
    the run waits for the slowest. One by default: the second-best start never found a better
    plan than the best-ranked one on the default problem (five seeds) nor on a 12 s one, and
    1.4 % better on a 30 s one, while it made the default run wait up to 648 iterations instead
    of 263 and took the comparison's core (``benchmarks/bench_multistart.py``, README).
    ``scheduler``: a Dask scheduler address for the starts (default: ``EXCITE_DASK_SCHEDULER``,
    else local processes).
    ``comparison``: the random screen and COBYLA in a worker next to IPOPT — None: when a core
    is free for it (measured at the start), and what it finished when IPOPT is done counts;
    True: always, and the run waits for it within the budget; False: never (the reference
    maneuvers and the random candidates drawn as starts are compared in every case).
    """

    duration_s: float = 90.0
    lot_x_m: float = 80.0
    lot_y_m: float = 50.0
    limits: Limits = field(default_factory=Limits)
    seed: int = 0
    time_budget_s: float = 60.0
    closed: bool = False
    n_random: int = 200
    site: Any = None
    criterion: str = "E"
    max_iterations: int | None = None
    starts: int = 1
    scheduler: str | None = None
    comparison: bool | None = None

    def __post_init__(self) -> None:
        def finite(name: str) -> float:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise OptimizeError(f"{name} must be a finite number, got {value!r}")
            return float(value)

        for name in ("duration_s", "lot_x_m", "lot_y_m", "time_budget_s"):
            bounds.check_range(bounds.OPTIMIZE, name, finite(name), OptimizeError)
        if not isinstance(self.limits, Limits):
            raise OptimizeError(f"limits must be an excite.motion.vehicle.Limits, got {type(self.limits).__name__}")
        for name in ("seed", "n_random"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int):
                raise OptimizeError(f"{name} must be an integer, got {value!r}")
            bounds.check_range(bounds.OPTIMIZE, name, value, OptimizeError)
        if not isinstance(self.closed, bool):
            raise OptimizeError(f"closed must be true or false, got {self.closed!r}")
        if self.criterion not in ("E", "D", "A"):
            raise OptimizeError(f"criterion must be E, D or A, got {self.criterion!r}")
        if self.max_iterations is not None and (isinstance(self.max_iterations, bool)
                                                or not isinstance(self.max_iterations, int)
                                                or self.max_iterations < 1):
            raise OptimizeError(f"max_iterations must be a positive integer, got {self.max_iterations!r}")
        if isinstance(self.starts, bool) or not isinstance(self.starts, int) or not 1 <= self.starts <= 64:
            raise OptimizeError(f"starts must be an integer between 1 and 64, got {self.starts!r}")
        if self.comparison is not None and not isinstance(self.comparison, bool):
            raise OptimizeError(f"comparison must be true, false or None, got {self.comparison!r}")
        if self.scheduler is not None and not isinstance(self.scheduler, str):
            raise OptimizeError(f"scheduler must be a Dask scheduler address, got {self.scheduler!r}")
        from .site import Site

        if self.site is not None and not isinstance(self.site, Site):
            raise OptimizeError(f"site must be an excite.plan.site.Site, got {type(self.site).__name__}")

    def for_rig(self, rig) -> "OptimizeSettings":
        """These settings within what the rig's vehicle allows (:func:`vehicle_limits`)."""
        limits = vehicle_limits(rig, self.limits)
        return self if limits == self.limits else replace(self, limits=limits)

    @property
    def lot(self):
        """The :class:`~excite.plan.site.Site` driven in (the rectangle unless ``site``)."""
        from .site import Site

        return self.site if self.site is not None else Site.rectangle(self.lot_x_m, self.lot_y_m)


def vehicle_limits(rig, limits: Limits) -> Limits:
    """``limits`` and the rig's vehicle's, the tighter of each: a car's steering wheel turns no
    faster than ``ackermann.steering.rate_max_deg_per_s``, so the curvature (the optimizer's input,
    which the steering reads) changes no faster than
    :func:`excite.factors.ackermann.curvature_rate_max_1pms`."""
    from ..factors.ackermann import curvature_rate_max_1pms

    ac = getattr(rig.config, "ackermann", None)
    vehicle = None if ac is None else curvature_rate_max_1pms(ac)
    if vehicle is None or vehicle >= limits.curvature_rate_max_1pms:
        return limits
    floor = bounds.LIMITS["curvature_rate_max_1pms"].lo
    if vehicle < floor:
        st = ac.steering
        raise OptimizeError(f"ackermann.steering.rate_max_deg_per_s: {st.rate_max_deg_per_s:g} deg/s at ratio "
                            f"{st.ratio:g} and wheelbase {ac.wheelbase_m:g} m lets the curvature change by "
                            f"{vehicle:.3g} 1/(m·s) at most, below the {floor:g} a plan needs to turn at all")
    return replace(limits, curvature_rate_max_1pms=vehicle)


@dataclass(frozen=True)
class Progress:
    """One progress report: the optimizer's iteration, the current criterion value of its
    (coarse) model, the largest constraint violation, the wall time since the start, and the
    phase (``"start"``, ``"optimize"``, ``"check"``, ``"done"``; at ``"done"`` the score is the
    result's, by the full evaluator). ``budget_s``: the whole run's budget (the progress bar's
    total)."""

    iteration: int
    score: float
    constraint_violation: float
    elapsed_s: float
    phase: str
    budget_s: float = 0.0


@dataclass
class OptimizeResult:
    """The optimized maneuver, its full evaluator report, and the comparison with the baselines.

    The result is the best drive (by the criterion, full evaluator) among every candidate that
    passed the independent check (:func:`.candidates.check`): IPOPT's feasible iterates, its
    start, COBYLA's result, the reference maneuvers and the random candidates. ``source`` names
    it (``"optimized"`` when it is an IPOPT iterate).

    ``comparison``: one row per candidate, best first: ``{name, kind, score, worst_sigma_ratio,
    log_det, trace_inv, rotation_excitation, value, ratio, feasible, violations}`` with ``kind``
    one of ``optimized``, ``reference``, ``random``, ``cobyla``, ``start``, ``heuristic``;
    scores from the full evaluator; ``ratio`` = the result's score / this score.
    ``status``: IPOPT's outcome — ``converged`` (every start converged), ``time_budget`` (a
    start was stopped by the budget or the iteration cap), ``infeasible``, ``failed`` or
    ``cancelled``; ``ipopt_status`` and ``iterations`` are those of the start whose model value
    was best; ``starts`` and ``starts_converged`` say how many starts ran and converged.
    ``compiled``: whether the optimizer's model ran compiled (else CasADi's virtual machine;
    ``message`` says why).
    """

    profile: ControlProfile
    trajectory: Trajectory
    report: Report
    comparison: list[dict[str, Any]]
    status: str
    iterations: int
    elapsed_s: float
    cancelled: bool
    model_score: float = float("nan")  # the criterion of the optimizer's coarse model at its best iterate
    timings_s: dict[str, float] = field(default_factory=dict)
    message: str = ""
    ipopt_status: str = ""
    source: str = "optimized"
    criterion: str = "E"
    lot: dict[str, Any] | None = None  # the site planned in, in local metres (Site.outline)
    starts: int = 1
    starts_converged: int = 0
    compiled: bool = False

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (the report is :meth:`Report.to_dict`); ``drivable`` is None (a
        drivable plan's result, :meth:`excite.plan.drivable.search.DrivableResult.to_dict`, has the
        same fields and fills it)."""
        return {
            "status": self.status, "iterations": self.iterations, "elapsed_s": self.elapsed_s,
            "cancelled": self.cancelled, "model_score": self.model_score, "score": self.report.score,
            "ipopt_status": self.ipopt_status, "source": self.source, "criterion": self.criterion,
            "timings_s": self.timings_s, "message": self.message, "comparison": self.comparison, "lot": self.lot,
            "starts": self.starts, "starts_converged": self.starts_converged, "compiled": self.compiled,
            "report": self.report.to_dict(), "drivable": None,
        }
