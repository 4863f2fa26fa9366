"""The optimal-control problem a maneuver solves, stated apart from its transcription and solver.

As rockit separates them: this module says *what* is optimised — the controls, the constraints
a test engineer sets and the objective — in physical units and continuous time;
:mod:`.transcription` says how it becomes a finite NLP (B-spline controls, where each
constraint is imposed), :mod:`.solver` how IPOPT solves that NLP.

- **Controls**: the speed u(t) ≥ 0 and the curvature κ(t) over ``[0, duration_s]``, from rest to
  rest (zero speed and acceleration at both ends), and the start pose (x0, y0, ψ0).
- **Path** (the kinematics of :mod:`.kinematics`): heading ψ' = uκ, position (x, y)' = u(cos ψ,
  sin ψ) over the lot's terrain; the body motion that the information model sees.
- **Path constraints** (:meth:`Problem.bounds`): speed, acceleration and deceleration, jerk,
  curvature, curvature rate, lateral acceleration u²κ, the clearance to the lot's edges and
  keep-out zones, and each bump's speed cap. Each has the optimizer's bound, a margin inside the
  limit (the drive is played back from sampled controls), and the limit itself (an iterate within
  it is worth the independent check).
- **Boundary**: the start pose at the lot's entry when it has one; with ``closed`` the end pose
  equals the start pose.
- **Objective**: the criterion (:mod:`.criteria`: E = λ_min, D, A) of the target-scaled marginal
  information S Λ_θ S of the drive, by the evaluator's information model on a coarse copy of the
  rig (:func:`.model.coarse_rig`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ..motion.vehicle import Limits
from ..rig.config import Rig

LIMIT_MARGIN = 0.95  # fraction of a limit the optimizer may use where the drive's playback (PCHIP
# through the profile's 20 Hz samples) or sampling can exceed the spline's own extremes
VALUE_MARGIN = 0.99  # speed and curvature: held at every sample of the model (8 Hz), and PCHIP
# through the profile's samples stays within their range
JERK_MARGIN = 0.8  # drive() plays speed back shape-preservingly (PCHIP), which adds up to ~20 % jerk
LOT_BUFFER_M = 0.25  # the optimizer keeps this much more than the lot's margin
CLOSURE_TOL_M, CLOSURE_TOL_RAD = 0.5, 0.02  # a closed maneuver's end pose, for the check's candidates


@dataclass(frozen=True)
class Bound:
    """A path constraint's bounds: the optimizer's ``[lo, hi]`` and the limit itself
    ``[lo_ok, hi_ok]`` (wider), within which an iterate goes to the independent check."""

    lo: float
    hi: float
    lo_ok: float
    hi_ok: float

    @classmethod
    def limit(cls, lo: float, hi: float, margin: float = LIMIT_MARGIN) -> "Bound":
        return cls(margin * lo, margin * hi, lo, hi)


@dataclass(frozen=True)
class Problem:
    """The maneuver problem of :class:`~excite.plan.settings.OptimizeSettings` for ``rig`` on
    ``site`` (see the module docstring)."""

    rig: Rig
    duration_s: float
    limits: Limits
    site: Any  # excite.plan.site.Site
    closed: bool = False
    criterion: str = "E"

    @classmethod
    def of(cls, rig: Rig, settings, site=None) -> "Problem":
        return cls(rig, float(settings.duration_s), settings.limits, settings.lot if site is None else site,
                   bool(settings.closed), settings.criterion)

    def bounds(self) -> dict[str, Bound]:
        """Every path constraint by name (SI units; ``clearance`` in metres from the nearest
        edge or keep-out zone)."""
        lim = self.limits
        inf = math.inf
        return {
            "speed": Bound(0.0, VALUE_MARGIN * lim.speed_max_mps, 0.0, lim.speed_max_mps),
            "accel": Bound.limit(-lim.decel_max_mps2, lim.accel_max_mps2),
            "jerk": Bound.limit(-lim.jerk_max_mps3, lim.jerk_max_mps3, JERK_MARGIN),
            "curvature": Bound.limit(-lim.curvature_max_1pm, lim.curvature_max_1pm, VALUE_MARGIN),
            "curvature_rate": Bound.limit(-lim.curvature_rate_max_1pms, lim.curvature_rate_max_1pms),
            "lat_accel": Bound.limit(-lim.lat_accel_max_mps2, lim.lat_accel_max_mps2),
            "clearance": Bound(self.site.margin_m + LOT_BUFFER_M, inf, self.site.margin_m, inf),
        }

    def bump_caps(self) -> list[Bound]:
        """The speed cap of every bump that has one (``u·w(x, y) ≤ cap``, ``w`` the bump's
        smooth indicator: :meth:`~excite.plan.terrain.Terrain.speed_limits`)."""
        return [Bound(-math.inf, LIMIT_MARGIN * f.max_speed_mps, -math.inf, f.max_speed_mps)
                for f in self.site.terrain.features if f.max_speed_mps is not None]
