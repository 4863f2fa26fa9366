"""A plan's score over the drives people make of it: the driver model's distribution, and its low
quantile.

A plan is driven by a person (:mod:`excite.motion.driver`): every drive is a little off the path
and the speeds. :func:`robust_scores` draws ``n`` drives of a course (drive ``i`` by the driver of
``default_rng([seed, i])``: the same drivers for every plan compared, so that two plans' quantiles
differ by the plans and not by the draw) and scores each with the evaluator; :class:`Robust`
holds the scores and the quantile a plan is reported and chosen by (the 10th percentile by
default: nine drives in ten do at least this well).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ...motion.course import Course
from ...motion.driver import DriverModel, drive_course
from ...motion.vehicle import Limits, drive
from ...rig.config import Rig
from .elements import MARGIN

QUANTILE = 0.1


@dataclass
class Robust:
    """The scores of ``len(scores)`` driven drives and the nominal (the drive as instructed)."""

    nominal: float
    scores: np.ndarray
    quantile: float = QUANTILE
    seed: int = 0
    worst_sigma_ratio: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def low(self) -> float:
        """The ``quantile`` of the driven scores (linear interpolation between order statistics)."""
        return float(np.quantile(self.scores, self.quantile)) if self.scores.size else float("nan")

    @property
    def ratio(self) -> float:
        return self.low / self.nominal if self.nominal > 0 else float("nan")

    def to_dict(self) -> dict:
        s = self.scores
        return {"quantile": self.quantile, "score_quantile": self.low, "nominal": self.nominal,
                "quantile_over_nominal": self.ratio, "draws": int(s.size), "seed": self.seed,
                "median": float(np.median(s)) if s.size else None, "min": float(s.min()) if s.size else None,
                "max": float(s.max()) if s.size else None}


def driven_scores(course: Course, rig: Rig, limits: Limits, n: int, seed: int = 0,
                  model: DriverModel = DriverModel(), duration_s: float | None = None,
                  evaluate: Callable | None = None, rate_hz: float = 25.0, first: int = 0,
                  margin: float = MARGIN) -> tuple[np.ndarray, np.ndarray]:
    """Scores (and worst σ/target) of drives ``first … first + n − 1`` of ``course`` by the
    driver model."""
    from ...score.evaluate import evaluate as full

    evaluate = evaluate or (lambda traj: full(traj, rig))
    scores, worst = [], []
    for i in range(first, first + n):
        dc = drive_course(course, limits, model, np.random.default_rng([seed, i]), margin, duration_s)
        rep = evaluate(drive(dc.profile, rig.suspension, rate_hz=rate_hz))
        scores.append(rep.score)
        ratios = [np.inf if p.sigma is None else p.sigma / p.target for p in rep.parameters]
        worst.append(max(ratios))
    return np.array(scores), np.array(worst)


def robust_scores(course: Course, rig: Rig, limits: Limits, n: int, nominal: float, seed: int = 0,
                  model: DriverModel = DriverModel(), duration_s: float | None = None,
                  quantile: float = QUANTILE, evaluate: Callable | None = None, margin: float = MARGIN) -> Robust:
    s, w = driven_scores(course, rig, limits, n, seed, model, duration_s, evaluate, margin=margin)
    return Robust(nominal, s, quantile, seed, w)
