"""The drivable plan of a problem: which elements, how many laps, where, in what order.

:func:`optimize_drivable` runs, within one time budget:

1. **library** (:func:`.design.library`): every element of the catalogue's grids that fits the
   lot, driven alone and scored by the full evaluator (a few seconds);
2. **design** (:func:`.design.e_design`): the E-optimal time shares over the library, the same
   set with its many-lap elements split in two (a driver's errors over an element average over
   two), and variants without its leading kinds (different element sets to refine), each rounded
   to whole laps (:func:`.design.repetitions`);
3. **layout** (:func:`layout`): every element of a set placed in the lot (its centre and heading
   on a grid) so that its path stays the lot's margin inside the edges and keeps clear of every
   other element's cones, in the order with the shortest transits;
4. **refine** (:func:`refine`): CMA-ES over the elements' continuous parameters, centres,
   headings and standstills, maximising the full evaluator's score of the whole drive (driven
   from the instructions: transits included), the laps refitted to the duration at every step;
   the element sets side by side on the free cores;
5. **robust** (:func:`.robust.robust_scores`): the best plans driven ``draws`` times by the
   driver model (the same drivers for each) and chosen by the quantile of their scores; the
   chosen plan's quantile is then reported over as many as ``draws`` *other* drivers (the
   choosing drivers' quantile is optimistic: the plan that did best on them won).

The result is re-scored by the full evaluator on the drive as instructed (the 100 Hz grid).

With a ``scene`` (:class:`~excite.scene.model.Scene`, in the lot's frame) every drive the search
scores — the library's elements, every plan the refinement tries, the driver model's drives and
the result — is scored with what the rig's sensors see in it (:class:`Scorer`): where each
element goes and at what heading is chosen by what the lidars see there. A drive seen in a scene
(:func:`excite.scene.along.seen`, its default sampling) costs several times a blind evaluation
(the ray casting); for a rig whose exteroceptive sensors are lidars only, the search casts the
scene's scans once on a grid over the lot (:func:`excite.scene.field.field`, a few seconds) and
ranks its drives by scans looked up there, at the cost of a blind evaluation
(:func:`scene_scorers`); the result and its drives by the fresh drivers are seen exactly.
"""

from __future__ import annotations

import itertools
import math
import os
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from ...core import processes
from ...errors import OptimizeError
from ...motion.driver import DriverModel
from ...motion.vehicle import Limits, drive
from ...rig.config import Rig
from ...scene.model import Scene
from ..site import Site
from .design import (Candidate, Design, describe, e_design, half_extent, lambda_min, library, repeat_param,
                     repetitions)
from .elements import KINDS, MARGIN, footprint, kind
from .plan import Built, DrivablePlan, Element, as_written, build, outside_m
from .robust import QUANTILE, Robust, driven_scores, robust_scores

CONE_CLEARANCE_M = 1.2  # a path keeps this far from every cone but its own element's (half a car and room)
SCREEN_RATE_HZ = 25.0
SHARES = {"library": 0.08, "refine": 0.5}  # of the budget; the rest for the robust choice and the result
RESULT_S = 5.0  # kept at the end for the result's own drive and report
FRESH_SHARE = 0.12  # of the budget, for the chosen plan's drives by drivers it was not chosen by
FRESH_SEED = 1000  # those drivers: default_rng([seed + FRESH_SEED, i])


@dataclass(frozen=True)
class DrivableSettings:
    """What to plan for. SI units.

    ``duration_s``, ``site`` (default: the ``lot_x_m`` × ``lot_y_m`` rectangle), ``limits`` and
    ``time_budget_s`` as for the free-form optimizer; ``kinds``: the element kinds allowed;
    ``max_elements``: at most this many elements; ``speed_max_mps``: the fastest speed the
    instructions may ask for (None: ``MARGIN`` × the speed limit; above the lot's safe speed it is
    refused); ``driver``: the driver model; ``draws`` drives per plan in the robust choice;
    ``quantile`` the plans are chosen by; ``seed``: the drivers and CMA-ES; ``scene``: the scene
    every drive is scored in (in the lot's frame; None: blind).
    """

    duration_s: float = 90.0
    lot_x_m: float = 80.0
    lot_y_m: float = 50.0
    site: Site | None = None
    limits: Limits = field(default_factory=Limits)
    time_budget_s: float = 60.0
    kinds: tuple[str, ...] = tuple(KINDS)
    max_elements: int = 4
    speed_max_mps: float | None = None
    driver: DriverModel = field(default_factory=DriverModel)
    draws: int = 30
    quantile: float = QUANTILE
    seed: int = 0
    workers: int | None = None
    scene: Scene | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        for k in self.kinds:
            kind(k)
        if not self.kinds:
            raise OptimizeError("kinds: at least one element kind")
        if not 1 <= self.max_elements <= 8:
            raise OptimizeError(f"max_elements must be 1 to 8, got {self.max_elements}")
        if not 5 <= self.draws <= 1000:
            raise OptimizeError(f"draws must be 5 to 1000, got {self.draws}")
        if not 0 < self.quantile < 1:
            raise OptimizeError(f"quantile must be in (0, 1), got {self.quantile}")
        if not (10.0 <= self.duration_s <= 600.0):
            raise OptimizeError(f"duration_s must be 10 to 600 s, got {self.duration_s:g}")
        if not (1.0 <= self.time_budget_s <= 3600.0):
            raise OptimizeError(f"time_budget_s must be 1 to 3600 s, got {self.time_budget_s:g}")
        if self.scene is not None:
            check_scene(self.scene, self.lot)

    @property
    def lot(self) -> Site:
        return self.site if self.site is not None else Site.rectangle(self.lot_x_m, self.lot_y_m)


def safe_speed_mps(site: Site, limits: Limits) -> tuple[float, float]:
    """The lot's safe speed: the fastest a car reaches from rest and stops from again, at
    ``MARGIN`` × its acceleration and braking, along the longest straight that fits the lot
    inside its margin (a lot's own ``max_speed_mps`` where the site gives one is not modelled
    here); and that straight's length."""
    lx, ly = site.extent_m
    best = 0.0
    c = site.centre_m
    for ang in np.linspace(0.0, math.pi, 36, endpoint=False):
        d = np.array([math.cos(ang), math.sin(ang)])
        for off in np.linspace(-0.5, 0.5, 11) * min(lx, ly):
            p = c + off * np.array([-d[1], d[0]])
            if not site.lot.contains(p[None], site.margin_m)[0]:
                continue
            best = max(best, 2 * site.reach_m(p, d))
    a, b = MARGIN * limits.accel_max_mps2, MARGIN * limits.decel_max_mps2
    return math.sqrt(2 * best * a * b / (a + b)), best


def check_scene(scene: Scene, site: Site) -> None:
    """Refuse a scene that does not reach over the lot (a lot and a scene in different frames:
    a lot given as ``XxY`` is centred on the origin, a GeoJSON lot is in its file's frame)."""
    lo, hi = site.lot.polygon_m.min(axis=0), site.lot.polygon_m.max(axis=0)
    b = scene.bounds
    if np.any(b[0, :2] > hi) or np.any(b[1, :2] < lo):
        raise OptimizeError(f"scene: {scene.source} spans x {b[0, 0]:.0f} to {b[1, 0]:.0f} m, y {b[0, 1]:.0f} to "
                            f"{b[1, 1]:.0f} m and the lot x {lo[0]:.0f} to {hi[0]:.0f} m, y {lo[1]:.0f} to "
                            f"{hi[1]:.0f} m: they do not overlap (the scene must be in the lot's frame)")


@dataclass(frozen=True)
class Scorer:
    """The full evaluator's report of a drive with ``rig``, the drive first seen in ``scene``
    (:func:`excite.scene.along.seen`) when there is one, or looked up in the scene's ``field``
    (:class:`excite.scene.field.Field`) when one is given. Pickles (a worker process builds the
    scene's ray caster again)."""

    rig: Rig
    scene: Scene | None = None
    field: Any = None

    def __call__(self, traj):
        from ...score.evaluate import evaluate

        if self.field is not None:
            traj = self.field.seen(traj, self.rig)
        elif self.scene is not None:
            from ...scene.along import seen

            traj = seen(traj, self.rig, self.scene)
        return evaluate(traj, self.rig)


def scene_scorers(rig: Rig, scene: Scene | None, site: Site) -> tuple[Scorer, Scorer]:
    """The scorer the search ranks drives by and the exact one its result is reported with:
    with a scene and a rig whose exteroceptive sensors are lidars only, the scene's field over
    the lot (:func:`excite.scene.field.field`, cast once: a drive looked up in it costs what a
    blind one does) and :func:`~excite.scene.along.seen`; otherwise both the same."""
    exact = Scorer(rig, scene)
    if scene is None:
        return exact, exact
    from ...scene.along import cameras
    from ...scene.field import field

    if cameras(rig):
        return exact, exact
    lo, hi = site.lot.polygon_m.min(axis=0), site.lot.polygon_m.max(axis=0)
    return Scorer(rig, scene, field(scene, rig, lo, hi)), exact


def check_problem(site: Site, limits: Limits, speed_max_mps: float | None = None) -> None:
    """Refuse, before any work, a lot too small for any element (the smallest, circles at the
    turning radius, needs a circle of the turning radius and a metre inside the lot's margin)
    and an instructed speed above the lot's safe speed (:func:`safe_speed_mps`); each error
    names the limit."""
    from .elements import turning_radius_m

    r = turning_radius_m(limits)
    lo, hi = site.lot.polygon_m.min(axis=0), site.lot.polygon_m.max(axis=0)
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + 0.5, 0.5), np.arange(lo[1], hi[1] + 0.5, 0.5))
    room = float(site.lot.clearance_m(np.column_stack([gx.ravel(), gy.ravel()])).max()) - site.margin_m
    if room < r + 1.0:
        lx, ly = site.extent_m
        raise OptimizeError(f"the lot ({lx:.0f} × {ly:.0f} m, {site.margin_m:g} m margin) is too small for any "
                            f"element within the limits: the smallest, circles at the turning radius {r:.1f} m, "
                            f"needs a circle of {2 * (r + 1.0):.0f} m across inside the margin, and the lot has "
                            f"{2 * max(room, 0.0):.0f} m")
    if speed_max_mps is not None:
        safe, straight = safe_speed_mps(site, limits)
        if speed_max_mps > safe + 1e-9:
            raise OptimizeError(f"speed_max_mps: {speed_max_mps:.3g} m/s is above the lot's safe speed {safe:.3g} m/s "
                                f"(the fastest a car reaches and stops from again at {MARGIN:g} × its acceleration "
                                f"and braking along the lot's longest straight, {straight:.0f} m)")


@dataclass
class Progress:
    phase: str
    elapsed_s: float
    best: float
    detail: str = ""
    budget_s: float = 0.0


@dataclass
class DrivableResult:
    """The chosen plan, what it builds into, its drive as instructed and its report, how it fares
    under the driver model (:class:`.robust.Robust`) and the plans it was chosen among (``rows``:
    name, nominal score, quantile score)."""

    plan: DrivablePlan
    built: Built
    profile: Any
    trajectory: Any
    report: Any
    robust: Robust
    rows: list[dict[str, Any]]
    elapsed_s: float
    timings_s: dict[str, float]
    design: list[dict[str, Any]] = field(default_factory=list)
    lot: dict[str, Any] | None = None  # the site planned in, in local metres (Site.outline)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary with the fields of the free-form optimizer's
        (:meth:`excite.plan.settings.OptimizeResult.to_dict`: one result shape for both), the
        plans it was chosen among as the ``comparison`` and ``drivable``: the plan, its
        instructions, its robust score, its cones (GeoJSON in the lot's metres) and the design."""
        from .plan import cones_geojson

        rows = [{"name": r["plan"], "kind": "drivable", "score": r["score"], "score_quantile": r["score_quantile"],
                 "ratio": self.report.score / r["score"] if r["score"] else None, "feasible": True,
                 "result": r["chosen"]} for r in self.rows]
        return {"status": "done", "iterations": 0, "elapsed_s": self.elapsed_s, "cancelled": False,
                "model_score": None, "score": self.report.score, "ipopt_status": "", "source": "drivable",
                "criterion": "E", "timings_s": self.timings_s, "message": "", "comparison": rows, "lot": self.lot,
                "starts": 0, "starts_converged": 0, "compiled": False, "report": self.report.to_dict(),
                "drivable": {"plan": self.plan.to_dict(), "instructions": self.built.instructions,
                             "robust": self.robust.to_dict(), "cones": cones_geojson(self.built),
                             "candidates": self.rows, "design": self.design}}


# --------------------------------------------------------------------------------------------
# Evaluating a plan


def cone_conflicts_m(built: Built) -> float:
    """How far paths intrude on other elements' cones (within :data:`CONE_CLEARANCE_M`), summed
    over path points every metre: 0 when every path keeps clear of every cone not its own."""
    if not built.cones:
        return 0.0
    cones = np.array([[c.x, c.y] for c in built.cones])
    owner = np.array([c.element for c in built.cones])
    total = 0.0
    for leg in built.course.legs:
        k = max(int(round(1.0 / float(leg.path.s_m[1] - leg.path.s_m[0]))), 1)
        pts = leg.path.xyz_m[::k, :2]
        d = np.linalg.norm(pts[:, None, :] - cones[None], axis=2)
        other = owner != leg.element
        if other.any():
            total += float(np.sum(np.maximum(CONE_CLEARANCE_M - d[:, other], 0.0)))
    return total


def _lap_durations(elements: list[Element], limits: Limits) -> list[tuple[float, float]]:
    """(duration of the element with one lap, of each further lap) for every element, its
    standstill aside."""
    from .design import element_drive  # noqa: F401 (same construction)
    from ...motion.course import Course, Leg, trace

    out = []
    for e in elements:
        d = []
        for laps in (1, 2):
            p = dict(e.params)
            p[repeat_param(e.kind)] = laps
            g = kind(e.kind).geometry(p, limits)
            path = trace(g.pieces, g.start)
            plan = Course((Leg(path, g.speed(path.s_m)),)).leg_plans(limits, MARGIN)[0]
            d.append(plan.duration_s)
        out.append((d[0], max(d[1] - d[0], 1.0)))
    return out


def fit_laps(plan: DrivablePlan, limits: Limits, shares: list[float], transit_s: float) -> DrivablePlan:
    """The plan with every element's laps chosen so that the whole fits its duration (given the
    transits' time) and the time of each comes closest to its share: fewer laps where over,
    one more lap at a time to the element furthest below its share while it fits."""
    els = list(plan.elements)
    if not els:
        return plan
    durs = _lap_durations(els, limits)
    avail = plan.duration_s - transit_s - sum(e.dwell_s for e in els)
    share = np.asarray(shares, dtype=float)
    share = share / share.sum() if share.sum() > 0 else np.full(len(els), 1 / len(els))
    n = np.ones(len(els), dtype=int)

    def t(n):
        return np.array([d1 + (k - 1) * dl for (d1, dl), k in zip(durs, n)])

    while True:
        left = avail - t(n).sum()
        room = [j for j in range(len(els)) if durs[j][1] <= left]
        if not room:
            break
        j = min(room, key=lambda j: t(n)[j] / (share[j] * avail + 1e-9))
        n[j] += 1
    return plan.with_elements(replace(e, params={**e.params, repeat_param(e.kind): int(k)}) for e, k in zip(els, n))


@dataclass
class Scored:
    plan: DrivablePlan
    score: float
    penalty: float
    built: Built | None = None

    @property
    def value(self) -> float:
        """What the search maximises: the score when the plan is feasible, else below every
        feasible one by its penalty."""
        return self.score if self.penalty == 0 else -self.penalty


def score_plan(plan: DrivablePlan, rig: Rig, limits: Limits, site: Site, evaluate=None,
               shares: list[float] | None = None, rate_hz: float = SCREEN_RATE_HZ) -> Scored:
    """Build ``plan`` as written (:func:`~.plan.as_written`; laps refitted to its duration with
    ``shares``), check it, drive it as instructed and score it. Infeasible plans get a penalty: the lot and cone intrusions [m]
    plus the seconds over the duration."""
    from ...score.evaluate import evaluate as full

    try:
        plan = as_written(plan)
        built = build(plan, limits)
        if shares is not None:
            transit = sum(p.duration_s for leg, p in zip(built.course.legs, built.speed_plans) if leg.element < 0)
            plan = fit_laps(plan, limits, shares, transit)  # whole laps: still as written
            built = build(plan, limits)
    except OptimizeError:
        return Scored(plan, 0.0, 1e6)
    timed = built.timed()
    over = max(timed.duration_s - plan.duration_s, 0.0)
    pen = outside_m(built, site) + cone_conflicts_m(built) + 10.0 * over
    if pen > 0:
        return Scored(plan, 0.0, pen, built)
    traj = drive(timed.profile, rig.suspension, rate_hz=rate_hz)
    rep = (evaluate or (lambda tr: full(tr, rig)))(traj)
    return Scored(plan, float(rep.score), 0.0, built)


# --------------------------------------------------------------------------------------------
# Layout


def _placements(g, site: Site, step_m: float = 2.5, headings: int = 8) -> list[tuple[float, float, float]]:
    """Every pose (centre on a ``step_m`` grid, ``headings`` headings) at which the element's
    path stays inside the lot's margin."""
    pts = footprint(g, 1.0)
    lo = site.lot.polygon_m.min(axis=0)
    hi = site.lot.polygon_m.max(axis=0)
    xs = np.arange(lo[0], hi[0] + 1e-9, step_m)
    ys = np.arange(lo[1], hi[1] + 1e-9, step_m)
    out = []
    for k in range(headings):
        a = 2 * math.pi * k / headings
        c, s = math.cos(a), math.sin(a)
        rot = pts @ np.array([[c, s], [-s, c]])
        rx, ry = rot[:, 0], rot[:, 1]
        for x in xs:
            if x + rx.min() < lo[0] or x + rx.max() > hi[0]:
                continue
            for y in ys:
                if y + ry.min() < lo[1] or y + ry.max() > hi[1]:
                    continue
                q = rot + [x, y]
                if site.lot.contains(q, site.margin_m + 0.3).all():
                    out.append((float(x), float(y), a))
    return out


def _clear(g1, pose1, g2, pose2) -> bool:
    """Whether each element's path keeps clear of the other's cones."""
    from .plan import to_lot

    def world(g, pose):
        pts = footprint(g, 1.0)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        return pts @ np.array([[c, s], [-s, c]]) + pose[:2]

    def cones(g, pose):
        return np.array([to_lot(pose, c.x, c.y) for c in g.cones])

    for (ga, pa), (gb, pb) in (((g1, pose1), (g2, pose2)), ((g2, pose2), (g1, pose1))):
        d = np.linalg.norm(world(ga, pa)[:, None] - cones(gb, pb)[None], axis=2)
        if d.min() < CONE_CLEARANCE_M + 0.5:
            return False
    return True


def layout(elements: list[Element], limits: Limits, site: Site, rng: np.random.Generator,
           tries: int = 30) -> list[Element] | None:
    """The elements placed in the lot (see the module docstring) and ordered for the shortest
    transits (straight-line distances from one's end to the next's start); None when they do not
    fit together."""
    from .plan import pose_to_lot

    geos = [e.local(limits) for e in elements]
    options = [_placements(g, site) for g in geos]
    if any(not o for o in options):
        return None
    best, best_cost = None, math.inf
    order_by_size = np.argsort([-len(footprint(g, 1.0)) for g in geos])
    for _ in range(tries):
        poses: list[tuple | None] = [None] * len(elements)
        ok = True
        for i in order_by_size:
            cand = options[i]
            idx = rng.permutation(len(cand))[:200]
            placed = [(geos[j], poses[j]) for j in range(len(elements)) if poses[j] is not None]
            found = None
            for k in idx:
                pose = cand[k]
                if all(_clear(geos[i], pose, g, p) for g, p in placed):
                    found = pose
                    break
            if found is None:
                ok = False
                break
            poses[i] = found
        if not ok:
            continue
        # order: the permutation with the shortest straight-line transits
        starts = [pose_to_lot(p, g.start) for g, p in zip(geos, poses)]
        ends = [pose_to_lot(p, g.end) for g, p in zip(geos, poses)]
        for perm in itertools.permutations(range(len(elements))):
            cost = sum(math.hypot(starts[b][0] - ends[a][0], starts[b][1] - ends[a][1]) for a, b in zip(perm, perm[1:]))
            if cost < best_cost:
                best_cost = cost
                best = [replace(elements[i], pose=poses[i]) for i in perm]
    return best


# --------------------------------------------------------------------------------------------
# Refining a set of elements (CMA-ES)


class Encoding:
    """A plan's continuous decision vector in [0, 1]ⁿ: per element its continuous parameters
    (the kind's ranges), centre (the lot's bounding box), heading and standstill (0–5 s); the
    discrete parameters (laps aside, refitted to the duration) stay as given."""

    DWELL_MAX_S = 5.0

    def __init__(self, plan: DrivablePlan, limits: Limits, site: Site, speed_max_mps: float):
        self.plan, self.limits, self.site = plan, limits, site
        ext = max(site.extent_m)
        self.lo = site.lot.polygon_m.min(axis=0)
        self.hi = site.lot.polygon_m.max(axis=0)
        self.slots: list[list] = []
        for e in plan.elements:
            params = [p for p in kind(e.kind).space(limits, ext) if not p.integer]
            params = [replace(p, hi=min(p.hi, speed_max_mps)) if p.name == "speed_mps" else p for p in params]
            self.slots.append(params)

    @property
    def size(self) -> int:
        return sum(len(s) + 4 for s in self.slots)

    def encode(self, plan: DrivablePlan) -> np.ndarray:
        z = []
        for e, params in zip(plan.elements, self.slots):
            for p in params:
                z.append((e.params[p.name] - p.lo) / max(p.hi - p.lo, 1e-9))
            z.append((e.pose[0] - self.lo[0]) / (self.hi[0] - self.lo[0]))
            z.append((e.pose[1] - self.lo[1]) / (self.hi[1] - self.lo[1]))
            z.append((math.remainder(e.pose[2], 2 * math.pi) + math.pi) / (2 * math.pi))
            z.append(e.dwell_s / self.DWELL_MAX_S)
        return np.clip(np.array(z, dtype=float), 0.0, 1.0)

    def decode(self, z: np.ndarray) -> DrivablePlan:
        z = np.clip(np.asarray(z, dtype=float), 0.0, 1.0)
        out, i = [], 0
        for e, params in zip(self.plan.elements, self.slots):
            p = dict(e.params)
            for q in params:
                p[q.name] = float(q.lo + z[i] * (q.hi - q.lo))
                i += 1
            x = self.lo[0] + z[i] * (self.hi[0] - self.lo[0])
            y = self.lo[1] + z[i + 1] * (self.hi[1] - self.lo[1])
            h = -math.pi + 2 * math.pi * z[i + 2]
            dwell = self.DWELL_MAX_S * z[i + 3]
            i += 4
            out.append(Element(e.kind, p, (float(x), float(y), float(h)), float(dwell)))
        return self.plan.with_elements(out)


def refine(plan: DrivablePlan, shares: list[float], rig: Rig, limits: Limits, site: Site, speed_max_mps: float,
           deadline: float, seed: int, evaluate=None, report: Callable[[float], None] | None = None) -> list[Scored]:
    """CMA-ES from ``plan`` until ``deadline`` (``time.monotonic()``): the best few plans seen,
    best first."""
    import cma

    enc = Encoding(plan, limits, site, speed_max_mps)
    z0 = enc.encode(plan)
    seen: list[Scored] = []
    start = score_plan(plan, rig, limits, site, evaluate, shares)
    seen.append(start)
    if report is not None:
        report(start.value)
    es = cma.CMAEvolutionStrategy(z0, 0.08, {"bounds": [0.0, 1.0], "seed": seed + 1, "verbose": -9,
                                             "popsize": max(8, 4 + int(3 * math.log(enc.size)))})
    best = start.value
    while time.monotonic() < deadline and not es.stop():
        zs = es.ask()
        vals = []
        for z in zs:
            if time.monotonic() >= deadline:
                break
            s = score_plan(enc.decode(z), rig, limits, site, evaluate, shares)
            vals.append(s)
            if s.value > best:
                best = s.value
                if report is not None:
                    report(best)
        if len(vals) < len(zs):
            break
        es.tell(zs, [-math.log(v.score) if v.penalty == 0 and v.score > 0 else 50.0 + v.penalty for v in vals])
        seen.extend(v for v in vals if v.penalty == 0)
        seen = sorted(seen, key=lambda s: -s.value)[:12]
    return sorted(seen, key=lambda s: -s.value)


def _refine_task(args) -> list[tuple[dict, float]]:
    plan, shares, rig, limits, site, vmax, deadline_s, seed, scorer = args
    deadline = time.monotonic() + deadline_s
    res = refine(plan, shares, rig, limits, site, vmax, deadline, seed, scorer)
    return [(s.plan.to_dict(), s.score) for s in res if s.penalty == 0][:6]


def _reraise(_: Any, exc: BaseException) -> Any:
    raise exc


def _robust_task(args) -> tuple[int, Robust]:
    from .plan import plan_from_dict

    i, doc, rig, limits, settings, nominal, scorer = args
    built = build(plan_from_dict(doc), limits)
    return i, robust_scores(built.course, rig, limits, settings.draws, nominal, settings.seed, settings.driver,
                            duration_s=settings.duration_s, quantile=settings.quantile, evaluate=scorer)


# --------------------------------------------------------------------------------------------
# The whole run


def element_sets(cands: list[Candidate], time_s: float, max_elements: int, kinds: tuple[str, ...]) -> list[tuple[list[tuple[int, int]], Design]]:
    """The design's element set, the same with its elements of several laps split in two, and
    variants without its leading kind, then without its two leading kinds: (candidate, laps) per
    set, and the design."""
    rates = [c.rate for c in cands]
    out = []
    excluded: set[str] = set()
    for _ in range(3):
        allowed = [i for i, c in enumerate(cands) if c.kind not in excluded]
        if not allowed:
            break
        d = e_design([rates[i] for i in allowed], time_s)
        w = np.zeros(len(cands))
        w[allowed] = d.weights
        order = np.argsort(-w)[:max_elements]
        w2 = np.zeros(len(cands))
        w2[order] = w[order]
        reps = repetitions(cands, w2 / w2.sum(), time_s)
        out.append((reps, Design(w2 / w2.sum(), d.value, d.iterations)))
        excluded.add(cands[int(np.argmax(w))].kind)
    # the design's set with every element of several laps split in two, each half its own element
    # (cones of its own, driven as a leg of its own): what a driver gets wrong over one element
    # (its speed, its effort) then averages over two; the robust choice weighs it
    reps, d = out[0]
    split = [part for i, n in reps for part in ([(i, (n + 1) // 2), (i, n // 2)] if n >= 2 else [(i, n)])]
    if len(split) > len(reps) and len(split) <= max_elements:
        out.insert(1, (split, d))
    return out


def optimize_drivable(rig: Rig, settings: DrivableSettings = DrivableSettings(),
                      progress: Callable[[Progress], None] | None = None,
                      should_stop: Callable[[], bool] | None = None) -> DrivableResult:
    """The drivable plan of the problem (see the module docstring)."""
    t0 = time.monotonic()
    budget = settings.time_budget_s
    site, limits = settings.lot, settings.limits
    from ..settings import vehicle_limits

    limits = vehicle_limits(rig, limits)
    check_problem(site, limits, settings.speed_max_mps)
    vmax = MARGIN * limits.speed_max_mps
    if settings.speed_max_mps is not None:
        vmax = min(vmax, settings.speed_max_mps)
    limits_plan = replace(limits, speed_max_mps=vmax / MARGIN)
    timings: dict[str, float] = {}
    best_so_far = [0.0]

    def report(phase: str, detail: str = "") -> None:
        if progress is not None:
            progress(Progress(phase, time.monotonic() - t0, best_so_far[0], detail, budget))

    report("library")
    scorer, exact = scene_scorers(rig, settings.scene, site)
    lib = library(rig, limits_plan, site, settings.kinds,
                  evaluate=scorer, progress=lambda i, n: report("library", f"{i}/{n}"))
    timings["library"] = time.monotonic() - t0
    transit_guess = 6.0  # seconds per transit, taken off the time the design shares out
    sets = element_sets(lib, settings.duration_s - transit_guess * (settings.max_elements - 1),
                        settings.max_elements, settings.kinds)
    report("design", f"{len(sets)} element sets")
    rng = np.random.default_rng(settings.seed)
    starts = []
    for reps, d in sets:
        els = []
        for i, n in reps:
            c = lib[i]
            p = dict(c.params)
            p[repeat_param(c.kind)] = n
            els.append(Element(c.kind, p, c.pose, 0.0))
        shares = [d.weights[i] for i, _ in reps]
        placed = layout(els, limits_plan, site, rng)
        if placed is None and len(els) > 1:  # drop the smallest share until it fits
            while placed is None and len(els) > 1:
                k = int(np.argmin(shares))
                els.pop(k)
                shares.pop(k)
                placed = layout(els, limits_plan, site, rng)
        if placed is None:
            continue
        order = [next(j for j, e in enumerate(els) if e.kind == q.kind and e.params == q.params) for q in placed]
        plan = DrivablePlan(tuple(placed), settings.duration_s, site.entry, name="drivable")
        starts.append((plan, [shares[j] for j in order]))
    if not starts:
        raise OptimizeError("no element of the catalogue fits this lot with its cones within the limits")
    timings["layout"] = time.monotonic() - t0 - sum(timings.values())
    report("refine", f"{len(starts)} element sets")
    refine_s = max(SHARES["refine"] * budget - (time.monotonic() - t0), 1.0)
    workers = settings.workers or max(1, min(len(starts), os.cpu_count() or 1))
    rounds = math.ceil(len(starts) / workers)
    spawn_s = 2.5 if workers > 1 else 0.0  # a spawned worker's imports, off its share
    per_set = max(refine_s / rounds - spawn_s, 1.0)
    results: list[tuple[DrivablePlan, float]] = []
    from .plan import plan_from_dict

    if workers > 1:
        def refined(k: int, found: list[tuple[dict, float]]) -> None:
            nonlocal sets_done
            sets_done += 1
            best_so_far[0] = max([best_so_far[0]] + [sc for _, sc in found])

        def refining() -> bool:
            report("refine", f"{sets_done}/{len(starts)} element sets done")
            return should_stop is not None and should_stop()

        sets_done = 0
        tasks = [(p, sh, rig, limits_plan, site, vmax, per_set, settings.seed + k, scorer)
                 for k, (p, sh) in enumerate(starts)]
        for found in processes.map_ordered(_refine_task, tasks, workers, failed=_reraise, context="spawn",
                                           on_result=refined, poll=refining):
            results += [(plan_from_dict(doc), sc) for doc, sc in found or []]
    else:
        for k, (p, sh) in enumerate(starts):
            deadline = time.monotonic() + per_set
            for s in refine(p, sh, rig, limits_plan, site, vmax, deadline, settings.seed + k, scorer,
                            report=lambda b: (best_so_far.__setitem__(0, max(best_so_far[0], b)), report("refine"))):
                if s.penalty == 0:
                    results.append((s.plan, s.score))
    if not results:
        raise OptimizeError("no plan of the element sets fits the lot and the duration")
    timings["refine"] = time.monotonic() - t0 - sum(timings.values())

    # the robust choice: the best plan of each element set and the next best overall
    results.sort(key=lambda r: -r[1])
    picked: list[tuple[DrivablePlan, float]] = []
    kinds_seen = []
    for plan, sc in results:
        sig = tuple(sorted(e.kind for e in plan.elements))
        if sig not in kinds_seen or len(picked) < 2:
            picked.append((plan, sc))
            kinds_seen.append(sig)
        if len(picked) >= 4:
            break
    report("robust", f"{len(picked)} plans × {settings.draws} drives")
    # best nominal first; a plan whose drives are not in by the deadline is not chosen
    deadline = t0 + budget - RESULT_S - FRESH_SHARE * budget
    robust: list[Robust | None] = [None] * len(picked)
    args = [(i, p.to_dict(), rig, limits_plan, settings, sc, scorer) for i, (p, sc) in enumerate(picked)]
    if workers > 1 and len(picked) > 1:
        def choosing() -> bool:  # a plan whose drives are not in by the deadline is cut short with its worker
            report("robust", f"{sum(r is not None for r in robust)}/{len(picked)} plans driven")
            return robust[0] is not None and time.monotonic() > deadline

        processes.map_ordered(_robust_task, args, min(workers, len(picked)), failed=_reraise, context="spawn",
                              on_result=lambda _, ir: robust.__setitem__(*ir), poll=choosing)
    else:
        for a in args:
            if robust[0] is not None and time.monotonic() > deadline:
                break
            i, r = _robust_task(a)
            robust[i] = r
    done = [i for i, r in enumerate(robust) if r is not None]
    picked = [picked[i] for i in done]
    robust = [robust[i] for i in done]
    timings["robust"] = time.monotonic() - t0 - sum(timings.values())
    k = int(np.argmax([r.low for r in robust]))
    plan = picked[k][0]
    built = build(plan, limits_plan)
    timed = built.timed()
    traj = drive(timed.profile, rig.suspension)
    rep = exact(traj)
    # the chosen plan's quantile over drivers it was not chosen by (the choosing drivers' is
    # optimistic: the plan that did best on them was picked), as many as the time left allows
    chosen_by = robust[k]
    fresh, fresh_w = [], []
    t_draw = 0.0
    while len(fresh) < settings.draws:
        if fresh and time.monotonic() + t_draw > t0 + budget - 0.5 * RESULT_S:
            break
        c0 = time.monotonic()
        sc, w = driven_scores(built.course, rig, limits_plan, 1, settings.seed + FRESH_SEED, settings.driver,
                              settings.duration_s, exact, first=len(fresh))
        fresh.append(float(sc[0]))
        fresh_w.append(float(w[0]))
        t_draw = max(t_draw, time.monotonic() - c0)
    rob = Robust(rep.score, np.array(fresh), settings.quantile, settings.seed + FRESH_SEED, np.array(fresh_w))
    if len(fresh) < 5:  # no time for a fair sample: the choosing drivers' figure, said so in the rows
        rob = chosen_by
        rob.nominal = rep.score
    plan = replace(plan, expected_score=rob.low)
    built.plan = plan
    rows = [{"plan": " + ".join(f"{e.kind}×{int(e.params[repeat_param(e.kind)])}" for e in p.elements),
             "score": sc, "score_quantile": r.low, "quantile": settings.quantile, "chosen": i == k}
            for i, ((p, sc), r) in enumerate(zip(picked, robust))]
    design_rows = [{"set": j, "elements": [describe(lib[i]) + f" ×{n}" for i, n in reps], "predicted": d.value}
                   for j, (reps, d) in enumerate(sets)]
    timings["result"] = time.monotonic() - t0 - sum(timings.values())
    best_so_far[0] = rep.score
    report("done")
    return DrivableResult(plan, built, timed.profile, traj, rep, rob, rows, time.monotonic() - t0,
                          {k: round(v, 2) for k, v in timings.items()}, design_rows, site.outline())
