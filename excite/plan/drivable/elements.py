"""The elements of a drivable plan: what a driver can execute from cones and one line of
instructions.

Every element is built in its own frame (its cones where a driver would set them out: the pivot
cones of a figure-eight on the x axis, a slalom's cones along it) from the pieces of
:mod:`excite.motion.course` — straights, arcs and clothoids, curvature continuous everywhere —
and driven from rest at its start cone to rest at its end, as one leg. Its cones carry the side
of the car they stay on as it passes (what the instructions say, and what the test that drives
the plan through its cones checks).

| kind | parameters | the driver is told |
|---|---|---|
| ``figure_eight`` | radius around each cone, cone spacing, speed, laps, direction, stops per lap | figure-eight around a pair of cones, one clockwise, one counter-clockwise |
| ``circles`` | radius, speed, laps, direction, stops per lap | circles around one cone |
| ``slalom`` | cone spacing, cones per line, offset beside each cone, speed, laps, direction, stops | weave through a line of cones, U-turn, weave back through a second line beside it |
| ``straight_run`` | length, top speed, laps, direction | accelerate hard from one cone, brake hard to stop at the next; U-turn, the same back |

Every element leaves where and as it left after one lap (the figure-eight, slalom and straight run
where they began, circles a clothoid's shift further along the tangent), so its laps repeat it
and the plan around it does not change with their number.

The clothoids are as sharp as the curvature rate allows at the element's speed; the speed
planner (:func:`excite.motion.paths.plan_speed`) slows the car wherever the lateral acceleration
or the curvature rate would otherwise exceed ``margin`` × the limits. What the instructions show
as the speed is what that drive reaches.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from scipy.optimize import brentq

from ...errors import OptimizeError
from ...motion.course import Piece, Pose, end_pose, length_of, straight, trace, turn
from ...motion.vehicle import Limits

MARGIN = 0.9  # instructions ask for at most this fraction of every limit
MIN_OFFSET_M = 1.5  # a slalom passes its cones at least this far (rear axle to cone): half a car and room
CONE_OFFSET_M = 2.5  # marker cones (start, stop) stand this far to the side of the path
RUN_M = 2.0  # straight run-in and run-out of a slalom beyond its ramps


@dataclass(frozen=True)
class Param:
    """One parameter of an element: its name and unit, its range for the limits and the lot
    (``lo``, ``hi``), and whether it is a whole number."""

    name: str
    unit: str
    lo: float
    hi: float
    integer: bool = False


@dataclass(frozen=True)
class LocalCone:
    """A cone in the element's frame: ``role`` (``pivot``, ``slalom``, ``start``, ``stop``,
    ``marker``) and the side of the car it stays on when passed (``left``/``right``; None for a
    cone that is only a place)."""

    x: float
    y: float
    role: str
    side: str | None = None


@dataclass(frozen=True)
class Geometry:
    """An element in its own frame: its path's pieces from ``start`` (at rest), the speed the
    instructions ask for as a function of the distance along it (0 at a stop), its cones, and
    the distances along the path where each pass of the element begins (for the cone check)."""

    start: Pose
    pieces: tuple[Piece, ...]
    speed: Callable[[np.ndarray], np.ndarray]
    cones: list[LocalCone]
    passes: list[tuple[float, float]] = field(default_factory=list)  # [s0, s1) of each pass over its cones

    @property
    def end(self) -> Pose:
        return end_pose(self.pieces, self.start)

    @property
    def length_m(self) -> float:
        return length_of(self.pieces)


def turning_radius_m(limits: Limits) -> float:
    """The tightest radius the instructions may ask for: ``1 / (MARGIN × curvature_max)``."""
    return 1.0 / (MARGIN * limits.curvature_max_1pm)


def sharpness(limits: Limits, speed_mps: float) -> float:
    """dκ/ds of the clothoids of an element driven at ``speed_mps``: the curvature rate at
    ``MARGIN`` × its limit."""
    return MARGIN * limits.curvature_rate_max_1pms / max(speed_mps, 1.0)


def _constant(v: float, stops: list[float] = ()) -> Callable[[np.ndarray], np.ndarray]:
    stops = np.asarray(list(stops), dtype=float)

    def speed(s: np.ndarray) -> np.ndarray:
        out = np.full(np.shape(s), float(v))
        if stops.size:
            ds = float(s[1] - s[0]) if len(s) > 1 else 0.1
            idx = np.clip(np.round((stops - s[0]) / ds).astype(int), 0, len(s) - 1)
            out[idx] = 0.0
        return out

    return speed


def held_speed(v: float, kappa_1pm: float, limits: Limits) -> float:
    """The speed a driver can hold where the curvature is ``kappa_1pm``: ``v`` or less, the
    lateral acceleration within ``MARGIN`` × its limit."""
    return min(float(v), math.sqrt(MARGIN * limits.lat_accel_max_mps2 / max(abs(kappa_1pm), 1e-9)))


def _recentred(g: Geometry, cx: float, cy: float) -> Geometry:
    """``g`` with its frame's origin moved to (cx, cy): an element is placed by its centre."""
    cones = [LocalCone(c.x - cx, c.y - cy, c.role, c.side) for c in g.cones]
    return Geometry((g.start[0] - cx, g.start[1] - cy, g.start[2]), g.pieces, g.speed, cones, g.passes)


def _swap(side: str) -> str:
    return {"left": "right", "right": "left"}[side]


def _mirror(g: Geometry, mirror: bool) -> Geometry:
    if not mirror:
        return g
    cones = [LocalCone(c.x, -c.y, c.role, {"left": "right", "right": "left"}.get(c.side, c.side)) for c in g.cones]
    return Geometry((g.start[0], -g.start[1], -g.start[2]), tuple(p.mirrored() for p in g.pieces), g.speed, cones,
                    g.passes)


class Kind:
    """One kind of element (see the module docstring)."""

    name: str = ""
    title: str = ""

    def space(self, limits: Limits, extent_m: float) -> list[Param]:
        """The parameters the optimizer chooses, with their ranges for ``limits`` and a lot whose
        bounding box's longer side is ``extent_m``."""
        raise NotImplementedError

    def check(self, p: dict[str, float], limits: Limits) -> None:
        """Refuse what no driver can execute within the limits (:class:`OptimizeError` naming the
        limit)."""

    def geometry(self, p: dict[str, float], limits: Limits) -> Geometry:
        raise NotImplementedError

    def instruction(self, p: dict[str, float], labels: list[str], speed_kmh: float) -> str:
        raise NotImplementedError

    def passings(self, p: dict[str, float]) -> list[list[tuple[int, str]]]:
        """Per pass of the element, the cones it passes (their index in its cones) and the side of
        the car each stays on: what the instructions say, by their rule."""
        raise NotImplementedError


def _radius_check(what: str, radius_m: float, limits: Limits) -> None:
    r = turning_radius_m(limits)
    if radius_m < r * (1 - 1e-6):
        raise OptimizeError(f"{what}: {radius_m:.2f} m is below the vehicle's turning radius for the plan, "
                            f"{r:.2f} m (1 / ({MARGIN:g} × curvature_max {limits.curvature_max_1pm:g} 1/m))")


def _speed_check(what: str, v: float, limits: Limits) -> None:
    if not (v > 0):
        raise OptimizeError(f"{what}: the speed must be positive, got {v:g} m/s")
    if v > MARGIN * limits.speed_max_mps + 1e-9:
        raise OptimizeError(f"{what}: {v:.3g} m/s is above {MARGIN:g} × the vehicle's speed limit "
                            f"{limits.speed_max_mps:g} m/s")


def _count(p: dict[str, float], name: str, lo: int, hi: int, what: str) -> int:
    n = p.get(name, 0 if name in ("stops_per_lap", "mirror") else None)
    if n is None or not float(n).is_integer() or not lo <= int(n) <= hi:
        raise OptimizeError(f"{what}: {name} must be a whole number from {lo} to {hi}, got {n!r}")
    return int(n)


class FigureEight(Kind):
    """Two pivot cones ``spacing_m`` apart; a lobe of radius ``radius_m`` around each, clockwise
    around the first, counter-clockwise around the second (``mirror``: the other way), joined by
    straights that cross between them; from rest at the crossing, ``laps`` laps, a stop at each
    lobe's far point when ``stops_per_lap`` is 2."""

    name = "figure_eight"
    title = "figure-eight"

    def space(self, limits, extent_m):
        r = turning_radius_m(limits)
        return [Param("radius_m", "m", r, max(r, 0.25 * extent_m)),
                Param("spacing_m", "m", 2 * r + 2.0, max(2 * r + 2.0, extent_m)),
                Param("speed_mps", "m/s", 3.0, MARGIN * limits.speed_max_mps),
                Param("laps", "", 1, 6, True), Param("mirror", "", 0, 1, True),
                Param("stops_per_lap", "", 0, 2, True)]

    @staticmethod
    def _lap(R: float, theta: float, sh: float) -> tuple[tuple[Piece, ...], float, float]:
        """One lap from the crossing at heading ``theta`` (cones on the x axis) and the first
        lobe's centre x and the straight's half length."""
        t = turn(-(math.pi + 2 * theta), 1.0 / R, sh)
        ex, ey, _ = end_pose(t)
        a = math.hypot(ex, ey) / (2 * math.sin(theta))
        lap = straight(a) + t + straight(2 * a) + tuple(p.mirrored() for p in t) + straight(a)
        # the first lobe's arc centre: the end of its entry clothoid, one radius to its right
        x1, y1, h1 = end_pose(straight(a) + t[:1], (0.0, 0.0, theta))
        return lap, x1 + R * math.sin(h1), a

    def _theta(self, R: float, D: float, sh: float) -> float:
        def gap(theta: float) -> float:
            return 2 * self._lap(R, theta, sh)[1] - D

        lo, hi = 0.05, 0.5 * math.pi - 1e-4
        if gap(hi) > 0:
            d_min = 2 * self._lap(R, hi, sh)[1]
            raise OptimizeError(f"figure_eight: the cone spacing {D:.2f} m is below what a radius of {R:.2f} m "
                                f"around each cone needs, {d_min:.2f} m (twice the radius and the clothoids)")
        if gap(lo) < 0:
            raise OptimizeError(f"figure_eight: the cone spacing {D:.2f} m is too wide for a radius of {R:.2f} m")
        return brentq(gap, lo, hi, xtol=1e-10)

    def check(self, p, limits):
        _radius_check("figure_eight: radius_m", p["radius_m"], limits)
        _speed_check("figure_eight: speed_mps", p["speed_mps"], limits)
        _count(p, "laps", 1, 20, "figure_eight")
        _count(p, "stops_per_lap", 0, 2, "figure_eight")
        if p["spacing_m"] < 2 * turning_radius_m(limits) * (1 - 1e-6):
            raise OptimizeError(f"figure_eight: the cone spacing {p['spacing_m']:.2f} m is below twice the "
                                f"vehicle's turning radius, {2 * turning_radius_m(limits):.2f} m")

    def geometry(self, p, limits):
        self.check(p, limits)
        R, D = float(p["radius_m"]), float(p["spacing_m"])
        v = held_speed(p["speed_mps"], 1.0 / R, limits)
        sh = sharpness(limits, v)
        theta = self._theta(R, D, sh)
        lap, xc, a = self._lap(R, theta, sh)
        laps = int(p["laps"])
        pieces = lap * laps
        L = length_of(lap)
        stops = []
        if int(p.get("stops_per_lap", 0)) == 2:  # at each lobe's far point (half way round it)
            t1 = length_of(straight(a) + turn(-(math.pi + 2 * theta), 1.0 / R, sh)) - 0.5 * length_of(
                turn(-(math.pi + 2 * theta), 1.0 / R, sh))
            stops = [k * L + s for k in range(laps) for s in (t1, t1 + 0.5 * L)]
        cones = [LocalCone(xc, 0.0, "pivot", "right"), LocalCone(-xc, 0.0, "pivot", "left")]
        if stops:
            cones += [LocalCone(xc + R + CONE_OFFSET_M, 0.0, "stop", "left"),
                      LocalCone(-xc - R - CONE_OFFSET_M, 0.0, "stop", "right")]
        g = Geometry((0.0, 0.0, theta), pieces, _constant(v, stops), cones, [(0.0, laps * L)])
        return _mirror(g, bool(p.get("mirror", 0)))

    def passings(self, p):
        swap = _swap if p.get("mirror") else (lambda side: side)
        out = [(0, swap("right")), (1, swap("left"))]
        if int(p.get("stops_per_lap", 0)) == 2:
            out += [(2, swap("left")), (3, swap("right"))]
        return [out]

    def instruction(self, p, labels, speed_kmh):
        first, second = ("clockwise", "counter-clockwise") if not p.get("mirror") else \
            ("counter-clockwise", "clockwise")
        laps = int(p["laps"])
        text = (f"Figure-eight around cones {labels[0]} and {labels[1]} ({p['spacing_m']:.0f} m apart), "
                f"{p['radius_m']:.0f} m from each: {first} around {labels[0]}, {second} around {labels[1]}, "
                f"{laps} lap{'s' if laps != 1 else ''} at {speed_kmh:.0f} km/h")
        if int(p.get("stops_per_lap", 0)) == 2:
            text += f"; stop beside cones {labels[2]} and {labels[3]} every lap"
        return text


class Circles(Kind):
    """``laps`` laps of radius ``radius_m`` around one cone, counter-clockwise (``mirror``:
    clockwise), from rest; ``stops_per_lap`` full stops each lap beside marker cones."""

    name = "circles"
    title = "circles"

    def space(self, limits, extent_m):
        r = turning_radius_m(limits)
        return [Param("radius_m", "m", r, max(r, 0.3 * extent_m)),
                Param("speed_mps", "m/s", 3.0, MARGIN * limits.speed_max_mps),
                Param("laps", "", 1, 8, True), Param("mirror", "", 0, 1, True),
                Param("stops_per_lap", "", 0, 2, True)]

    def check(self, p, limits):
        _radius_check("circles: radius_m", p["radius_m"], limits)
        _speed_check("circles: speed_mps", p["speed_mps"], limits)
        _count(p, "laps", 1, 20, "circles")
        _count(p, "stops_per_lap", 0, 2, "circles")

    def geometry(self, p, limits):
        self.check(p, limits)
        R, laps = float(p["radius_m"]), int(p["laps"])
        v = held_speed(p["speed_mps"], 1.0 / R, limits)
        sh = sharpness(limits, v)
        pieces = turn(2 * math.pi * laps, 1.0 / R, sh)
        clothoid = pieces[0]
        x1, y1, h1 = end_pose(pieces[:1])
        centre = (x1 - R * math.sin(h1), y1 + R * math.cos(h1))
        cones = [LocalCone(centre[0], centre[1], "pivot", "left")]
        stops = []
        n = int(p.get("stops_per_lap", 0))
        if n:
            lap = 2 * math.pi * R
            for k in range(n):  # the stops at fixed places on the circle, each lap
                phase = (k + 0.5) / n
                stops += [clothoid.length_m + (j + phase) * lap for j in range(laps)
                          if clothoid.length_m + (j + phase) * lap < length_of(pieces) - clothoid.length_m]
                ang = h1 - 0.5 * math.pi + 2 * math.pi * phase
                r = R + CONE_OFFSET_M
                cones.append(LocalCone(centre[0] + r * math.cos(ang), centre[1] + r * math.sin(ang), "stop", "right"))
        g = Geometry((0.0, 0.0, 0.0), pieces, _constant(v, stops), cones, [(0.0, length_of(pieces))])
        return _mirror(_recentred(g, *centre), bool(p.get("mirror", 0)))

    def passings(self, p):
        swap = _swap if p.get("mirror") else (lambda side: side)
        return [[(0, swap("left"))] + [(1 + k, swap("right")) for k in range(int(p.get("stops_per_lap", 0)))]]

    def instruction(self, p, labels, speed_kmh):
        way = "counter-clockwise" if not p.get("mirror") else "clockwise"
        laps = int(p["laps"])
        text = (f"Circle {way} around cone {labels[0]}, {p['radius_m']:.0f} m from it, "
                f"{laps} lap{'s' if laps != 1 else ''} at {speed_kmh:.0f} km/h")
        n = int(p.get("stops_per_lap", 0))
        if n:
            text += f"; stop beside cone{'s' if n > 1 else ''} {' and '.join(labels[1:1 + n])} every lap"
        return text


def u_turn_radius_m(limits: Limits) -> float:
    """The radius of the U-turns that bring a slalom or a straight run back to its start: 1.25 ×
    the turning radius (a turn a driver takes without thinking)."""
    return 1.25 * turning_radius_m(limits)


def _return_lane(limits: Limits, length_m: float, speed_mps: float) -> tuple[tuple[Piece, ...], tuple[Piece, ...], float]:
    """A left U-turn, the straight back and a left U-turn onto the start line: the pieces of the
    first U-turn, of the straight and second U-turn, and the return lane's offset."""
    R = u_turn_radius_m(limits)
    sh = sharpness(limits, held_speed(speed_mps, 1.0 / R, limits))
    u = turn(math.pi, 1.0 / R, sh)
    return u, straight(length_m) + u, end_pose(u)[1]


class Slalom(Kind):
    """``cones`` cones on a line ``spacing_m`` apart; the car enters on the line, weaves to pass
    each cone ``offset_m`` beside it, alternately on its right and left (``mirror``: left first),
    leaves on the line; a U-turn onto a second line of cones beside it, the same back, a U-turn
    to the start (``stops_per_lap`` 1: a hard stop at the end of each line); ``laps`` laps."""

    name = "slalom"
    title = "slalom"

    def space(self, limits, extent_m):
        return [Param("spacing_m", "m", self.min_spacing_m(MIN_OFFSET_M, limits), 30.0),
                Param("cones", "", 3, 8, True), Param("offset_m", "m", MIN_OFFSET_M, 3.0),
                Param("speed_mps", "m/s", 3.0, MARGIN * limits.speed_max_mps), Param("laps", "", 1, 8, True),
                Param("mirror", "", 0, 1, True), Param("stops_per_lap", "", 0, 1, True)]

    @staticmethod
    def min_spacing_m(offset_m: float, limits: Limits) -> float:
        """The closest cone spacing a weave of ``offset_m`` allows: its curvature A·π²/d² within
        ``MARGIN`` × the curvature limit (the turning radius)."""
        return math.pi * math.sqrt(offset_m / (MARGIN * limits.curvature_max_1pm))

    def check(self, p, limits):
        _speed_check("slalom: speed_mps", p["speed_mps"], limits)
        _count(p, "cones", 2, 30, "slalom")
        _count(p, "laps", 1, 20, "slalom")
        _count(p, "stops_per_lap", 0, 1, "slalom")
        if p["offset_m"] < MIN_OFFSET_M:
            raise OptimizeError(f"slalom: offset_m {p['offset_m']:.2f} m passes the cones closer than "
                                f"{MIN_OFFSET_M:g} m (half a car and room)")
        d_min = self.min_spacing_m(p["offset_m"], limits)
        if p["spacing_m"] < d_min * (1 - 1e-6):
            raise OptimizeError(f"slalom: the cone spacing {p['spacing_m']:.2f} m is below {d_min:.2f} m, the "
                                f"closest a weave of {p['offset_m']:.2f} m allows within the vehicle's turning "
                                f"radius {turning_radius_m(limits):.2f} m")

    @staticmethod
    def _pass(d: float, n: int, A: float) -> tuple[tuple[Piece, ...], float]:
        """One pass along +x from (0, 0): run-in, ramp over one spacing, the weave past ``n``
        cones (the first at x0), ramp, run-out; as pieces with linear curvature between 0.25 m
        samples; and x0."""
        x0 = RUN_M + d
        x_end = x0 + (n - 1) * d + d + RUN_M
        x = np.linspace(0.0, x_end, int(math.ceil(x_end / 0.05)) + 1)
        phase = math.pi * (x - x0) / d

        def ramp(u):
            u = np.clip(u, 0.0, 1.0)
            return u ** 3 * (10 - 15 * u + 6 * u * u)

        def dramp(u):
            return np.where((u > 0) & (u < 1), 30 * u ** 2 * (1 - u) ** 2, 0.0)

        def ddramp(u):
            return np.where((u > 0) & (u < 1), 60 * u * (1 - u) * (1 - 2 * u), 0.0)

        xl = x0 + (n - 1) * d
        u1, u2 = (x - (x0 - d)) / d, (xl + d - x) / d
        w = ramp(u1) * ramp(u2)
        dw = (dramp(u1) * ramp(u2) - ramp(u1) * dramp(u2)) / d
        ddw = (ddramp(u1) * ramp(u2) - 2 * dramp(u1) * dramp(u2) + ramp(u1) * ddramp(u2)) / (d * d)
        k = math.pi / d
        c, s = np.cos(phase), np.sin(phase)
        y1 = A * (dw * c - w * k * s)
        y2 = A * (ddw * c - 2 * dw * k * s - w * k * k * c)
        kappa = y2 / (1 + y1 ** 2) ** 1.5
        ds = np.sqrt(1 + y1 ** 2) * np.gradient(x)
        s_arc = np.concatenate([[0.0], np.cumsum(0.5 * (ds[1:] + ds[:-1]))])
        knots = np.linspace(0.0, s_arc[-1], int(math.ceil(s_arc[-1] / 0.25)) + 1)
        kk = np.interp(knots, s_arc, kappa)
        # the sampled weave turns by a little: take it off the inner knots so that a pass leaves
        # exactly as it came in (laps would drift)
        h = np.diff(knots)
        kk[1:-1] -= float(np.sum(0.5 * h * (kk[1:] + kk[:-1]))) / (knots[-1] - 0.5 * h[0] - 0.5 * h[-1])
        pieces = tuple(Piece(float(knots[i + 1] - knots[i]), float(kk[i]), float(kk[i + 1]))
                       for i in range(knots.size - 1))
        return pieces, x0

    def geometry(self, p, limits):
        self.check(p, limits)
        d, n, A = float(p["spacing_m"]), int(p["cones"]), float(p["offset_m"])
        laps = int(p["laps"])
        one, x0 = self._pass(d, n, A)
        v = held_speed(p["speed_mps"], max(abs(q.kappa1_1pm) for q in one), limits)
        x_end = end_pose(one)[0]
        R = u_turn_radius_m(limits)
        u = turn(math.pi, 1.0 / R, sharpness(limits, held_speed(v, 1.0 / R, limits)))
        lane = end_pose(u)[1]
        # lane 1 along +x, U-turn, lane 2 (its own cones) back along −x, U-turn to the start
        lap = one + u + one + u
        L = length_of(lap)
        stops = []
        if int(p.get("stops_per_lap", 0)):  # a full stop at the end of each lane, before its U-turn
            lane_len, u_len = length_of(one), length_of(u)
            stops = [k * L + e for k in range(laps) for e in (lane_len, 2 * lane_len + u_len)]
        cones = [LocalCone(x0 + i * d, 0.0, "slalom", "right" if i % 2 == 0 else "left") for i in range(n)]
        cones += [LocalCone(x_end - x0 - i * d, lane, "slalom", "right" if i % 2 == 0 else "left") for i in range(n)]
        turns = [(k * L + length_of(one), k * L + length_of(one + u)) for k in range(laps)] + \
            [(k * L + length_of(one + u + one), (k + 1) * L) for k in range(laps)]
        v_turn = held_speed(v, 1.0 / R, limits)

        def speed(s: np.ndarray) -> np.ndarray:
            out = _constant(v, stops)(s)
            for a, b in turns:
                out[(s > a) & (s < b)] = v_turn
            return out

        g = Geometry((0.0, 0.0, 0.0), lap * laps, speed, cones, [(0.0, laps * L)])
        return _mirror(_recentred(g, 0.5 * x_end, 0.5 * lane), bool(p.get("mirror", 0)))

    def passings(self, p):
        swap = _swap if p.get("mirror") else (lambda side: side)
        n = int(p["cones"])
        return [[(i, swap("right" if i % 2 == 0 else "left")) for i in range(n)]
                + [(n + i, swap("right" if i % 2 == 0 else "left")) for i in range(n)]]

    def instruction(self, p, labels, speed_kmh):
        laps = int(p["laps"])
        first = "left" if p.get("mirror") else "right"
        turn_way = "right" if p.get("mirror") else "left"
        n = int(p["cones"])
        stop = int(p.get("stops_per_lap", 0))
        text = (f"Slalom through cones {labels[0]}–{labels[n - 1]} ({p['spacing_m']:.0f} m apart), "
                f"{p['offset_m']:.1f} m beside each, first cone on your {first}, at {speed_kmh:.0f} km/h"
                + ("; brake hard to a stop after the last" if stop else "")
                + f"; U-turn {turn_way}, the same through cones {labels[n]}–{labels[2 * n - 1]}"
                + (", stop" if stop else "") + f", U-turn {turn_way} to the start")
        return text + f"; {laps} lap{'s' if laps != 1 else ''}"


class StraightRun(Kind):
    """Accelerate hard from rest at a start cone up to ``speed_mps``, brake hard to stop at the
    stop cone ``length_m`` further; U-turn, the same back along the return lane, U-turn to the
    start; ``laps`` laps (``mirror``: the U-turns to the right)."""

    name = "straight_run"
    title = "straight run"

    def space(self, limits, extent_m):
        return [Param("length_m", "m", 15.0, max(15.0, extent_m)),
                Param("speed_mps", "m/s", 4.0, MARGIN * limits.speed_max_mps), Param("laps", "", 1, 6, True),
                Param("mirror", "", 0, 1, True)]

    def check(self, p, limits):
        _speed_check("straight_run: speed_mps", p["speed_mps"], limits)
        _count(p, "laps", 1, 20, "straight_run")
        if p["length_m"] < 5.0:
            raise OptimizeError(f"straight_run: length_m {p['length_m']:.2f} m is under 5 m")

    def geometry(self, p, limits):
        self.check(p, limits)
        L, v, laps = float(p["length_m"]), float(p["speed_mps"]), int(p["laps"])
        u1, back, lane = _return_lane(limits, L, 5.0)
        lap = straight(L) + u1 + back
        lap_len = length_of(lap)
        ends = [L, L + length_of(u1), L + length_of(u1) + L, lap_len]  # stops: end of each run, each U-turn
        stops = [k * lap_len + e for k in range(laps) for e in ends]
        turns = [(k * lap_len + L, k * lap_len + L + length_of(u1)) for k in range(laps)] + \
            [(k * lap_len + 2 * L + length_of(u1), (k + 1) * lap_len) for k in range(laps)]
        v_turn = held_speed(v, 1.0 / u_turn_radius_m(limits), limits)

        def speed(s: np.ndarray) -> np.ndarray:
            out = np.full(np.shape(s), v)
            for a, b in turns:
                out[(s > a) & (s < b)] = v_turn
            ds = float(s[1] - s[0]) if len(s) > 1 else 0.1
            idx = np.clip(np.round((np.asarray(stops) - s[0]) / ds).astype(int), 0, len(s) - 1)
            out[idx] = 0.0
            return out

        cones = [LocalCone(0.0, -CONE_OFFSET_M, "start", "right"), LocalCone(L, -CONE_OFFSET_M, "stop", "right"),
                 LocalCone(0.0, lane + CONE_OFFSET_M, "stop", "right")]
        g = Geometry((0.0, 0.0, 0.0), lap * laps, speed, cones, [(0.0, laps * lap_len)])
        return _mirror(_recentred(g, 0.5 * L, 0.5 * lane), bool(p.get("mirror", 0)))

    def passings(self, p):
        swap = _swap if p.get("mirror") else (lambda side: side)
        return [[(0, swap("right")), (1, swap("right")), (2, swap("right"))]]

    def instruction(self, p, labels, speed_kmh):
        laps = int(p["laps"])
        way = "right" if p.get("mirror") else "left"
        return (f"From rest at cone {labels[0]}, accelerate hard to {speed_kmh:.0f} km/h, brake hard to stop at "
                f"cone {labels[1]} ({p['length_m']:.0f} m); U-turn {way}, stop, the same back to stop at cone "
                f"{labels[2]}; U-turn {way} to cone {labels[0]} and stop; {laps} lap{'s' if laps != 1 else ''}")


KINDS: dict[str, Kind] = {k.name: k for k in (FigureEight(), Circles(), Slalom(), StraightRun())}


def kind(name: str) -> Kind:
    try:
        return KINDS[name]
    except KeyError:
        raise OptimizeError(f"unknown element kind {name!r}; the kinds are {', '.join(KINDS)}") from None


def footprint(g: Geometry, step_m: float = 1.0) -> np.ndarray:
    """Points of the element's path (element frame) every ``step_m``: what must fit in the lot."""
    path = trace(g.pieces, g.start, step_m=step_m)
    return path.xyz_m[:, :2]


def params_of(values: dict[str, Any]) -> dict[str, float]:
    return {k: float(v) for k, v in values.items()}
