"""Live guidance that follows a drivable plan: which element is being driven and which is next,
and, when an element was cut short or the plan ends short of its goal, what to repeat.

:class:`PlanGuide` watches the vehicle's pose against the plan's elements (an element is being
driven while the vehicle is within :data:`MATCH_M` of its path, heading along it; the distance it
covers there counts as laps) and says, as it happens, which element is being driven and which is
next. It knows what the drive has achieved (the target-scaled information so far, from the live
evaluator) and what every element gives (each element's one lap driven alone, scored by the full
evaluator), so it predicts the drive's outcome:

- with the rest of the plan as planned (the *original remainder*: the elements not yet driven),
- and with a re-plan: laps of the plan's own elements — their cones are already set out — added
  one at a time, each the lap that raises the predicted λ_min most, until the goal is reached or
  the session's time is used, ordered from where the vehicle is (:meth:`PlanGuide.propose`; the
  session lasts twice the plan's duration unless told).

When an element is left with fewer laps than planned, or the plan's last element is done, and the
original remainder's predicted score is short of the goal, it proposes the re-plan: which
elements to repeat, how many laps, in which order. The goal is every target met (score 1) or, when
the plan itself promises less, what it promises (``expected_score``: its 10th percentile over the
driver model's drives, recorded in plan.json by ``excite optimize --drivable``).

:class:`PlanStream` is the live evaluator (:class:`excite.score.live.PoseStream`) with a plan guide
beside it: ``excite live --plan`` and the service's ``/v1/live`` with a plan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ...motion.vehicle import Limits, drive
from ...rig.config import Rig
from .design import element_drive, lambda_min
from .elements import MARGIN
from .plan import DrivablePlan, Element, build

MATCH_M = 3.0  # within this of an element's path (and heading along it) the vehicle is driving it
MATCH_RAD = math.radians(60.0)
LEFT_S = 4.0  # away from an element this long (or at rest this long beyond its standstill): it was left
TRANSIT_S = 8.0  # time to another element's start, where it is not known from where
SESSION_FACTOR = 2.0  # a re-plan may take the drive up to this multiple of the plan's duration


@dataclass
class ElementState:
    laps_planned: int
    lap_m: float
    travelled_m: float = 0.0
    state: str = "pending"  # pending | active | done | short

    @property
    def laps_done(self) -> float:
        return self.travelled_m / self.lap_m


@dataclass
class Proposal:
    """A re-plan: ``remainder`` as (element index, laps), in order; the predicted scores with it
    and with the original remainder; the goal and the time it fits."""

    remainder: list[tuple[int, int]]
    predicted: float
    predicted_original: float
    goal: float
    time_left_s: float
    reason: str
    instructions: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"type": "proposal", "reason": self.reason, "goal": self.goal, "time_left_s": self.time_left_s,
                "remainder": [{"element": i + 1, "laps": n, "instruction": s}
                              for (i, n), s in zip(self.remainder, self.instructions)],
                "predicted_score": self.predicted, "predicted_score_original": self.predicted_original}


class PlanGuide:
    """The plan's side of live guidance (see the module docstring)."""

    def __init__(self, rig: Rig, plan: DrivablePlan, limits: Limits = Limits(), goal: float | None = None,
                 session_s: float | None = None):
        self.rig, self.plan, self.limits = rig, plan, limits
        self.built = build(plan, limits)
        self.session_s = SESSION_FACTOR * plan.duration_s if session_s is None else session_s
        expected = plan.expected_score
        self.goal = goal if goal is not None else (1.0 if expected is None else min(1.0, expected))
        self.lap: list[tuple[np.ndarray, float]] = []  # (S Λ S, duration) of one lap of every element alone
        from ...score.evaluate import evaluate

        for e in plan.elements:
            p = {**e.params, "laps": 1}
            _, timed, traj = element_drive(e.kind, p, limits, rig, e.pose)
            self.lap.append((np.asarray(evaluate(traj, rig).information_scaled), timed.duration_s))
        self.states = []
        self.paths = []
        for i, e in enumerate(plan.elements):
            leg = self.built.course.legs[self.built.element_legs[i]]
            n = int(e.params["laps"])
            self.states.append(ElementState(n, leg.path.length_m / n))
            k = max(int(round(0.5 / float(leg.path.s_m[1] - leg.path.s_m[0]))), 1)
            self.paths.append((leg.path.xyz_m[::k, :2], leg.path.heading_rad[::k]))
        self.current: int | None = None
        self._last: tuple[float, np.ndarray] | None = None
        self._away_since: float | None = None
        self._still_since: float | None = None
        self.proposed = False
        self.info = np.zeros_like(self.lap[0][0])

    # --- where the vehicle is in the plan

    def _match(self, xy: np.ndarray, heading: float) -> int | None:
        best, which = MATCH_M, None
        order = list(range(len(self.paths)))
        if self.current is not None:  # the current element first: laps overlap other paths rarely
            order.remove(self.current)
            order.insert(0, self.current)
        for i in order:
            pts, hd = self.paths[i]
            d = np.hypot(pts[:, 0] - xy[0], pts[:, 1] - xy[1])
            ok = np.abs(np.remainder(hd - heading + math.pi, 2 * math.pi) - math.pi) < MATCH_RAD
            if ok.any():
                dm = float(d[ok].min())
                if dm < best - (0.5 if i != self.current else 0.0):
                    best, which = dm, i
        return which

    def observe(self, t: float, xy, heading: float, speed: float) -> list[dict[str, Any]]:
        """A pose of the vehicle (lot frame); the plan events it causes."""
        xy = np.asarray(xy, dtype=float)[:2]
        out: list[dict[str, Any]] = []
        on = self._match(xy, heading) if speed > 0.3 else self.current  # at rest it stays where it was
        if self._last is not None and on is not None and on == self.current:
            self.states[on].travelled_m += float(np.hypot(*(xy - self._last[1])))
        self._last = (t, xy)
        if on is not None and on != self.current:
            if self.current is not None:
                out += self._leave(t, self.current)
            self.current = on
            self.states[on].state = "active"
            self._away_since = self._still_since = None
            out.append(self._now(t, on))
        elif on is None and self.current is not None:
            self._away_since = self._away_since if self._away_since is not None else t
            if t - self._away_since >= LEFT_S:
                out += self._leave(t, self.current)
                self.current = None
        elif on is not None:
            self._away_since = None
        # at rest beyond the element's standstill, its laps not done: it was left
        if speed < 0.1:
            self._still_since = self._still_since if self._still_since is not None else t
            cur = self.current
            if cur is not None and t - self._still_since >= LEFT_S + self.plan.elements[cur].dwell_s + 2.0:
                out += self._leave(t, cur)
                self.current = None
        else:
            self._still_since = None
        return out

    def _now(self, t: float, i: int) -> dict[str, Any]:
        nxt = next((j for j in range(i + 1, len(self.states)) if self.states[j].state == "pending"), None)
        return {"type": "element", "t_s": t, "element": i + 1, "instruction": self.built.instructions[i],
                "laps_planned": self.states[i].laps_planned,
                "next": None if nxt is None else {"element": nxt + 1, "instruction": self.built.instructions[nxt]}}

    def _leave(self, t: float, i: int) -> list[dict[str, Any]]:
        s = self.states[i]
        if s.state in ("done", "short"):
            return []
        s.state = "done" if s.laps_done >= s.laps_planned - 0.25 else "short"
        ev = {"type": "element_done" if s.state == "done" else "element_short", "t_s": t, "element": i + 1,
              "laps_done": round(s.laps_done, 2), "laps_planned": s.laps_planned}
        return [ev]

    # --- what the drive will achieve

    def original_remainder(self) -> list[tuple[int, int]]:
        """The elements not yet driven, as planned."""
        return [(i, s.laps_planned) for i, s in enumerate(self.states) if s.state == "pending"]

    def predict(self, info: np.ndarray, remainder: list[tuple[int, int]]) -> float:
        return lambda_min(info + sum((n * self.lap[i][0] for i, n in remainder), np.zeros_like(info)))

    def propose(self, info: np.ndarray, time_left_s: float, here: tuple[float, float, float] | None = None,
                reason: str = "") -> Proposal:
        """The re-plan from the information so far ``info`` (S Λ S): laps of the plan's own elements
        (their cones are out), one at a time, each the lap that raises the drive's predicted λ_min
        most (a smooth lower bound of it breaks ties, so that a lap that helps the weakest
        directions together counts), until the goal is reached or ``time_left_s`` is used; in the
        order nearest first from ``here``."""
        orig = self.original_remainder()
        predicted_original = self.predict(info, orig)
        laps = np.zeros(len(self.lap), dtype=int)
        used = 0.0
        M = info.copy()

        def soft(X):
            w = np.linalg.eigvalsh(0.5 * (X + X.T))
            beta = 50.0 / max(abs(w[0]), 1e-300)
            return float(w[0] - np.log(np.sum(np.exp(-beta * (w - w[0])))) / beta)

        while lambda_min(M) < self.goal:
            best = None
            for i, (Mi, d) in enumerate(self.lap):
                cost = d + (self._reach_s(i, here) if laps[i] == 0 else 0.0)
                if used + cost > time_left_s:
                    continue
                gain = (lambda_min(M + Mi), soft(M + Mi))
                if best is None or gain > best[0]:
                    best = (gain, i, cost)
            if best is None:
                break
            _, i, cost = best
            laps[i] += 1
            used += cost
            M = M + self.lap[i][0]
        remainder = [(i, int(n)) for i, n in enumerate(laps) if n > 0]
        if here is not None:
            remainder.sort(key=lambda r: self._reach_s(r[0], here))
        instructions = [self.built.instructions[i].split("; ")[0] + f"; {n} lap{'s' if n != 1 else ''}"
                        for i, n in remainder]
        return Proposal(remainder, self.predict(info, remainder), predicted_original, self.goal, time_left_s,
                        reason, instructions)

    def _reach_s(self, i: int, here: tuple[float, float, float] | None) -> float:
        """Time to get to element ``i``'s start from ``here`` and stop there."""
        if here is None:
            return TRANSIT_S
        start = self.built.course.legs[self.built.element_legs[i]].start
        return 4.0 + math.hypot(start[0] - here[0], start[1] - here[1]) / self.plan.transit_speed_mps

    def remainder_plan(self, remainder: list[tuple[int, int]], here: tuple[float, float, float],
                       duration_s: float) -> DrivablePlan:
        """The remainder as a plan from ``here`` (the elements where the plan placed them)."""
        els = [replace(self.plan.elements[i], params={**self.plan.elements[i].params, "laps": n})
               for i, n in remainder]
        return DrivablePlan(tuple(els), duration_s, entry=here, transit_speed_mps=self.plan.transit_speed_mps,
                            name=f"{self.plan.name} (remainder)")

    def update(self, t: float, info: np.ndarray, here: tuple[float, float, float] | None,
               events: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """The proposal, if one is due: an element was cut short, or every element is behind and
        the drive is short of the goal; once per such occasion."""
        self.info = info
        due = [e for e in events if e["type"] == "element_short"]
        finished = all(s.state in ("done", "short") for s in self.states)
        if not due and not (finished and not self.proposed):
            return []
        if lambda_min(info) >= self.goal:
            return []
        if self.predict(info, self.original_remainder()) >= self.goal and not finished:
            return []
        why = (f"element {due[0]['element']} was left after {due[0]['laps_done']:.1f} of "
               f"{due[0]['laps_planned']} laps" if due else "the plan's elements are done")
        prop = self.propose(info, max(self.session_s - t, 0.0), here,
                            reason=f"{why}; the drive is short of its goal")
        self.proposed = True
        return [{"t_s": t, **prop.to_dict()}]


class PlanStream:
    """The live evaluator with a plan guide beside it: poses in, the live updates and the plan's
    events out."""

    def __init__(self, rig: Rig, plan: DrivablePlan, limits: Limits = Limits(), name: str = "live",
                 session_s: float | None = None, **kw: Any):
        from ...score.live import PoseStream

        self.stream = PoseStream(rig, name=name, **kw)
        self.guide = PlanGuide(rig, plan, limits, session_s=session_s)
        self.rig = rig
        self._t0: float | None = None

    def add(self, t: np.ndarray, p: np.ndarray, R: np.ndarray) -> list[dict[str, Any]]:
        from ...score.evaluate import scaled

        t = np.asarray(t, dtype=float).reshape(-1)
        p = np.asarray(p, dtype=float).reshape(-1, 3)
        R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
        if self._t0 is None and t.size:
            self._t0 = float(t[0])
        events: list[dict[str, Any]] = []
        prev = None
        for k in range(t.size):
            heading = math.atan2(R[k, 1, 0], R[k, 0, 0])
            if prev is None and self.guide._last is not None:  # noqa: SLF001 — its own state
                prev = (self.guide._last[0], self.guide._last[1])  # noqa: SLF001
            speed = 0.0
            if prev is not None and t[k] > prev[0]:
                speed = float(np.hypot(*(p[k, :2] - prev[1]))) / (t[k] - prev[0])
            events += self.guide.observe(float(t[k] - self._t0), p[k, :2], heading, speed)
            prev = (float(t[k]), p[k, :2])
        out = self.stream.add(t, p, R)
        info = None
        if self.stream.incremental.n_keyframes >= 3:
            info = scaled(self.rig, self.stream.incremental.information().information)[1]
        elif events:
            info = np.zeros_like(self.guide.lap[0][0])
        if info is not None and t.size:
            here = (float(p[-1, 0]), float(p[-1, 1]), math.atan2(R[-1, 1, 0], R[-1, 0, 0]))
            events += self.guide.update(float(t[-1] - self._t0), info, here, events)
        return events + out

    def finish(self) -> dict[str, Any]:
        return self.stream.finish()


def concatenated(first, second, name: str = "drive"):
    """Two control profiles one after the other (``second`` starting where ``first`` ends, at rest)."""
    from ...motion.vehicle import ControlProfile

    t = np.concatenate([first.t_s, first.t_s[-1] + second.t_s[1:] - second.t_s[0]])
    cat = {k: np.concatenate([getattr(first, k), getattr(second, k)[1:]])
           for k in ("speed_mps", "curvature_1pm", "grade_rad", "bank_rad")}
    return ControlProfile(t, cat["speed_mps"], cat["curvature_1pm"], cat["grade_rad"], cat["bank_rad"],
                          first.start, name)


def end_pose(profile, rig) -> tuple[float, float, float]:
    traj = drive(profile, rig.suspension)
    s = traj.sample(np.array([traj.t_end]))
    R = s.R_W_A[0]
    return float(s.p_W_V[0, 0]), float(s.p_W_V[0, 1]), float(math.atan2(R[1, 0], R[0, 0]))


__all__ = ["PlanGuide", "PlanStream", "Proposal", "concatenated", "end_pose", "MARGIN"]
