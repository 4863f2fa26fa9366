"""A drivable plan: elements placed in the lot, in order, and everything that follows from it.

A :class:`DrivablePlan` is plain data — each :class:`Element`'s kind, parameters, pose in the lot
(its centre and heading) and the standstill after it, the lot's entry if it has one, the speed of
the transits between elements and the plan's duration — and reads and writes as JSON
(:meth:`DrivablePlan.to_dict`, :func:`plan_from_dict`, which refuses a malformed plan naming the
field). :func:`build` turns it into what is driven and what the driver gets:

- the :class:`~excite.motion.course.Course`: for every element, the transit from where the last
  one ended (a turn–straight–turn path, :func:`~excite.motion.course.connect`) and the element
  itself, each a leg from rest to rest;
- the cones in the lot's frame, numbered in the order they are met, each with its role and the
  side of the car it stays on in every pass (:class:`Cone`);
- one instruction per element.

The drive the instructions describe (:meth:`Built.timed`) lasts at most the plan's duration and
stays the lot's margin inside its edges; :meth:`Built.violations` says where it does not.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import OptimizeError
from ...motion.course import Course, Leg, Pose, TimedCourse, connect, trace
from ...motion.paths import PathGeometry
from ...motion.vehicle import Limits
from .elements import KINDS, MARGIN, Geometry, kind

TRANSIT_SPEED_MPS = 6.0  # how fast the driver goes from one element to the next (~20 km/h)
PLAN_VERSION = 1


@dataclass(frozen=True)
class Element:
    """One element: its ``kind`` (:data:`~.elements.KINDS`), its parameters, the pose of its
    centre in the lot (x, y [m], heading [rad]) and the standstill after it [s]."""

    kind: str
    params: dict[str, float]
    pose: Pose
    dwell_s: float = 0.0

    def local(self, limits: Limits) -> Geometry:
        return kind(self.kind).geometry(self.params, limits)


@dataclass(frozen=True)
class DrivablePlan:
    """Elements in the order they are driven (see the module docstring); ``expected_score``: what
    the plan promises (the 10th percentile of its scores over the driver model's drives), the
    goal of live guidance where it is below 1."""

    elements: tuple[Element, ...]
    duration_s: float
    entry: Pose | None = None
    transit_speed_mps: float = TRANSIT_SPEED_MPS
    name: str = "drivable"
    expected_score: float | None = None  # what the plan promises: its score's 10th percentile over drivers

    def to_dict(self) -> dict[str, Any]:
        return {"version": PLAN_VERSION, "name": self.name, "duration_s": self.duration_s,
                "expected_score": self.expected_score,
                "entry": None if self.entry is None else [float(v) for v in self.entry],
                "transit_speed_mps": self.transit_speed_mps,
                "elements": [{"kind": e.kind, "params": {k: _plain(v) for k, v in e.params.items()},
                              "pose": {"x_m": round(e.pose[0], 3), "y_m": round(e.pose[1], 3),
                                       "heading_deg": round(math.degrees(e.pose[2]), 3)},
                              "dwell_s": round(e.dwell_s, 3)} for e in self.elements]}

    def with_elements(self, elements) -> "DrivablePlan":
        return replace(self, elements=tuple(elements))


def _plain(v: float) -> float | int:
    return int(v) if float(v).is_integer() else round(float(v), 6)


def _number(d: dict, key: str, where: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise OptimizeError(f"{where}.{key} must be a finite number, got {json.dumps(v) if v is not None else 'nothing'}")
    if not lo <= v <= hi:
        raise OptimizeError(f"{where}.{key} must be within [{lo:g}, {hi:g}], got {v:g}")
    return float(v)


MAX_ELEMENTS = 12


def plan_from_dict(doc: Any, where: str = "plan") -> DrivablePlan:
    """A plan from its JSON form (:meth:`DrivablePlan.to_dict`); a malformed one is refused with
    an :class:`OptimizeError` naming the field."""
    if not isinstance(doc, dict):
        raise OptimizeError(f"{where}: expected a JSON object")
    els = doc.get("elements")
    if not isinstance(els, list) or not els:
        raise OptimizeError(f"{where}.elements must be a non-empty list")
    if len(els) > MAX_ELEMENTS:
        raise OptimizeError(f"{where}.elements: {len(els)} elements, over the limit of {MAX_ELEMENTS}")
    out = []
    for i, e in enumerate(els):
        w = f"{where}.elements[{i}]"
        if not isinstance(e, dict):
            raise OptimizeError(f"{w} must be an object")
        name = e.get("kind")
        if name not in KINDS:
            raise OptimizeError(f"{w}.kind must be one of {', '.join(KINDS)}, got {json.dumps(name)}")
        params = e.get("params")
        if not isinstance(params, dict):
            raise OptimizeError(f"{w}.params must be an object")
        known = {p.name for p in KINDS[name].space(Limits(), 100.0)}
        unknown = sorted(set(params) - known)
        if unknown:
            raise OptimizeError(f"{w}.params: unknown {', '.join(unknown)} (a {name} has {', '.join(sorted(known))})")
        missing = sorted(known - set(params) - {"mirror", "stops_per_lap", "passes"})
        if missing:
            raise OptimizeError(f"{w}.params: missing {', '.join(missing)}")
        p = {k: _number(params, k, f"{w}.params", 0.0, 1e4) for k in params}
        pose = e.get("pose")
        if not isinstance(pose, dict):
            raise OptimizeError(f"{w}.pose must be an object with x_m, y_m, heading_deg")
        xy = (_number(pose, "x_m", f"{w}.pose", -1e4, 1e4), _number(pose, "y_m", f"{w}.pose", -1e4, 1e4),
              math.radians(_number(pose, "heading_deg", f"{w}.pose", -3600, 3600)))
        dwell = _number(e, "dwell_s", w, 0.0, 600.0) if "dwell_s" in e else 0.0
        out.append(Element(name, p, xy, dwell))
    duration = _number(doc, "duration_s", where, 10.0, 3600.0)
    entry = doc.get("entry")
    if entry is not None:
        if not (isinstance(entry, list) and len(entry) == 3 and all(isinstance(v, (int, float)) and
                                                                    not isinstance(v, bool) and math.isfinite(v)
                                                                    for v in entry)):
            raise OptimizeError(f"{where}.entry must be [x, y, heading] or null")
        entry = tuple(float(v) for v in entry)
    transit = _number(doc, "transit_speed_mps", where, 1.0, 30.0) if "transit_speed_mps" in doc \
        else TRANSIT_SPEED_MPS
    name = doc.get("name", "drivable")
    expected = _number(doc, "expected_score", where, 0.0, 1e12) if doc.get("expected_score") is not None else None
    return DrivablePlan(tuple(out), duration, entry, transit, str(name)[:100], expected)


def as_written(plan: DrivablePlan) -> DrivablePlan:
    """The plan as its document states it (:meth:`DrivablePlan.to_dict`: poses to 1 mm and
    0.001°, parameters to six decimals): what a plan file read back, a worker or a service job
    builds. The search scores plans in this form, so the plan it hands over builds as scored."""
    return plan_from_dict(plan.to_dict())


def read_plan(path: str | Path) -> DrivablePlan:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise OptimizeError(f"{path}: cannot read the plan: {exc.strerror}") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise OptimizeError(f"{path}: not valid JSON: {exc.msg} (line {exc.lineno})") from None
    return plan_from_dict(doc, str(path))


# --------------------------------------------------------------------------------------------
# Building a plan


def to_lot(pose: Pose, x: float, y: float) -> tuple[float, float]:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return pose[0] + c * x - s * y, pose[1] + s * x + c * y


def pose_to_lot(pose: Pose, local: Pose) -> Pose:
    x, y = to_lot(pose, local[0], local[1])
    return x, y, local[2] + pose[2]


@dataclass(frozen=True)
class Cone:
    """A cone in the lot: its number (``label``, in the order the plan meets them), position,
    ``role`` (``pivot``, ``slalom``, ``start``, ``stop``), the element it belongs to, and per pass
    of that element the side of the car it stays on (None: the element does not pass it then)."""

    label: str
    x: float
    y: float
    role: str
    element: int
    sides: list[str | None]


@dataclass
class Built:
    """A plan as it is driven (see the module docstring)."""

    plan: DrivablePlan
    course: Course
    cones: list[Cone]
    instructions: list[str]
    element_legs: list[int]  # the course leg of each element (the transit to it is the leg before)
    passes: list[list[tuple[float, float]]]  # per element, each pass's span along its leg's path
    speeds_kmh: list[float] = field(default_factory=list)
    speed_plans: list = field(default_factory=list)  # every leg's SpeedPlan (MARGIN × the limits)

    def timed(self) -> TimedCourse:
        """The drive the instructions describe, up to the plan's duration."""
        return self.course.timed(Limits(), MARGIN, duration_s=self.plan.duration_s, plans=self.speed_plans)

    def points(self, step_m: float = 1.0) -> np.ndarray:
        """Points of every leg's path every ~``step_m`` (what must stay in the lot)."""
        out = []
        for leg in self.course.legs:
            k = max(int(round(step_m / float(leg.path.s_m[1] - leg.path.s_m[0]))), 1)
            out.append(leg.path.xyz_m[::k, :2])
            out.append(leg.path.xyz_m[-1:, :2])
        return np.vstack(out)


def _leg(geometry_pieces, start: Pose, speed, element: int, label: str, dwell: float = 0.0) -> Leg:
    path = trace(geometry_pieces, start)
    v = speed(path.s_m) if callable(speed) else np.full(path.s_m.size, float(speed))
    return Leg(path, v, dwell, element, label)


def build(plan: DrivablePlan, limits: Limits) -> Built:
    """The course, cones and instructions of ``plan`` (see the module docstring). Refuses, with
    an :class:`OptimizeError`, elements no driver can execute within the limits and transits
    that cannot be driven (two elements too close for the turning circle)."""
    legs: list[Leg] = []
    cones: list[Cone] = []
    instructions: list[str] = []
    element_legs: list[int] = []
    passes: list[list[tuple[float, float]]] = []
    here: Pose | None = plan.entry
    km = 0.8 * MARGIN * limits.curvature_max_1pm
    sh = MARGIN * limits.curvature_rate_max_1pms / plan.transit_speed_mps
    number = 0
    labels_per: list[list[str]] = []
    for i, e in enumerate(plan.elements):
        k = kind(e.kind)
        g = e.local(limits)
        start = pose_to_lot(e.pose, g.start)
        if here is not None and math.hypot(start[0] - here[0], start[1] - here[1]) + \
                abs(math.remainder(start[2] - here[2], 2 * math.pi)) > 1e-6:
            pieces = connect(here, start, km, sh)
            if pieces is None:
                raise OptimizeError(f"element {i + 1} ({e.kind}) starts too close to where the plan is before it "
                                    f"for a transit within the turning radius {1 / km:.1f} m")
            legs.append(_leg(pieces, here, plan.transit_speed_mps, -1, f"to element {i + 1}"))
        element_legs.append(len(legs))
        legs.append(_leg(g.pieces, start, g.speed, i, f"element {i + 1}", e.dwell_s))
        passes.append(list(g.passes))
        here = legs[-1].end
        labels = []
        sides = k.passings(e.params)
        for j, c in enumerate(g.cones):
            number += 1
            x, y = to_lot(e.pose, c.x, c.y)
            per_pass = [dict(p).get(j) for p in sides]
            cones.append(Cone(str(number), x, y, c.role, i, per_pass))
            labels.append(str(number))
        labels_per.append(labels)
    course = Course(tuple(legs), plan.name)
    plans = course.leg_plans(limits, MARGIN)
    built = Built(plan, course, cones, instructions, element_legs, passes, speed_plans=plans)
    # the speeds the instructions show: what the drive reaches in each element
    for i, e in enumerate(plan.elements):
        v = float(np.max(plans[element_legs[i]].speed_mps)) * 3.6
        built.speeds_kmh.append(v)
        instructions.append(kind(e.kind).instruction(e.params, labels_per[i], v)
                            + (f"; stop {e.dwell_s:.0f} s on level ground" if e.dwell_s >= 1.0 else ""))
    return built


def violations(built: Built, timed: TimedCourse, site) -> list[str]:
    """What keeps the plan from being driven as it is: longer than its duration, or a path that
    comes within the lot's margin of an edge or a keep-out zone."""
    out = []
    if timed.duration_s > built.plan.duration_s + 1e-6:
        out.append(f"the plan lasts {timed.duration_s:.1f} s, over its {built.plan.duration_s:g} s")
    pts = built.points(1.0)
    ok = site.lot.contains(pts, site.margin_m)
    if not ok.all():
        k = int(np.argmin(ok))
        out.append(f"the path comes closer than {site.margin_m:g} m to the lot's edge at "
                   f"x={pts[k, 0]:.1f} m, y={pts[k, 1]:.1f} m")
    return out


def outside_m(built: Built, site) -> float:
    """How far the path reaches into the lot's margin or beyond, summed over points every metre
    (0: inside): the penalty the search pushes down."""
    pts = built.points(1.0)
    d = site.lot.clearance_m(pts) - site.margin_m
    return float(np.sum(np.maximum(-d, 0.0)))


def cones_geojson(built: Built, origin: tuple[float, float] | None = None) -> dict[str, Any]:
    """The cone layout as GeoJSON: a Point per cone (``label``, ``role``, ``element``,
    ``sides`` per pass, ``x_m``/``y_m`` in the lot's frame) and a LineString per element's path
    (``element``, ``kind``, ``instruction``); in lon/lat when the lot is georeferenced
    (``origin``), else in the lot's metres with ``"crs": "local"``."""
    from ..site import Projection

    proj = None if origin is None else Projection(origin)

    def coords(xy: np.ndarray) -> list[list[float]]:
        if proj is None:
            return [[round(float(a), 3), round(float(b), 3)] for a, b in xy]
        ll = proj.to_lonlat(np.asarray(xy, dtype=float))
        return [[round(float(a), 8), round(float(b), 8)] for a, b in ll]

    feats = []
    for c in built.cones:
        feats.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": coords(np.array([[c.x, c.y]]))[0]},
                      "properties": {"role": "cone", "label": c.label, "cone_role": c.role, "element": c.element + 1,
                                     "sides": c.sides, "x_m": round(c.x, 3), "y_m": round(c.y, 3)}})
    for i, leg_i in enumerate(built.element_legs):
        leg = built.course.legs[leg_i]
        xy = leg.path.xyz_m[::10, :2]
        e = built.plan.elements[i]
        feats.append({"type": "Feature", "geometry": {"type": "LineString", "coordinates": coords(xy)},
                      "properties": {"role": "element", "element": i + 1, "kind": e.kind,
                                     "instruction": built.instructions[i]}})
    props: dict[str, Any] = {"name": built.plan.name}
    if proj is None:
        props["crs"] = "local"
    return {"type": "FeatureCollection", "properties": props, "features": feats}


def read_cones(source: str | Path | dict) -> list[Cone]:
    """The cones of a cone layout written by :func:`cones_geojson` (in the lot's frame: a
    georeferenced layout's ``x_m``/``y_m``)."""
    doc = source if isinstance(source, dict) else json.loads(Path(source).read_text(encoding="utf-8"))
    out = []
    for f in doc.get("features", []):
        p = f.get("properties", {})
        if p.get("role") != "cone":
            continue
        out.append(Cone(str(p["label"]), float(p["x_m"]), float(p["y_m"]), p["cone_role"], int(p["element"]) - 1,
                        list(p["sides"])))
    return out


def path_of(built: Built) -> PathGeometry:
    """Every leg's path end to end (for drawing)."""
    legs = built.course.legs
    return PathGeometry(np.concatenate([leg.path.s_m for leg in legs]), np.vstack([leg.path.xyz_m for leg in legs]),
                        np.concatenate([leg.path.heading_rad for leg in legs]),
                        np.concatenate([leg.path.curvature_1pm for leg in legs]),
                        np.concatenate([leg.path.grade_rad for leg in legs]))
