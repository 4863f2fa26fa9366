"""A course a person drives: paths built from straights, arcs and clothoids, driven rest to rest.

A drivable plan is told to a driver as cones and instructions; what the driver is asked to do is a
:class:`Course`: a sequence of :class:`Leg`\\ s, each a path from rest to rest with the speed the
instructions ask for along it (0 where it asks for a stop) and a standstill after it. This module
holds the geometry such courses are made of and turns a course into the drive the instructions
describe (:meth:`Course.timed`); :mod:`excite.motion.driver` turns it into the drives people make
of it.

Geometry is built in *curvature space*: a path is a sequence of :class:`Piece`\\ s along which the
curvature changes linearly with distance (a straight, a circular arc, or a clothoid between
them), traced from a start pose (:func:`trace`). A :func:`turn` by a heading change is a clothoid
up to the turning curvature, an arc and a clothoid back to straight, the clothoids as sharp as the
curvature rate allows at the speed it is driven: curvature is continuous everywhere, so a car can
follow the path with a finite steering rate and every piece starts and ends straight.
:func:`connect` finds the shortest turn–straight–turn path between two poses (a Dubins path with
clothoid turns): how a driver gets from one element of a plan to the next.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq

from ..errors import LimitError
from .paths import PathGeometry, SpeedPlan, plan_speed
from .vehicle import ControlProfile, Limits

STEP_M = 0.1  # spacing of a traced path's samples
KNOT_RATE_HZ = 20.0  # knots of the control profile of a timed course
_GL_X, _GL_W = np.polynomial.legendre.leggauss(24)  # quadrature of a clothoid's position


@dataclass(frozen=True)
class Piece:
    """A stretch of ``length_m`` along which the curvature goes linearly from ``kappa0_1pm`` to
    ``kappa1_1pm`` (positive: left): a straight (both 0), an arc (equal) or a clothoid."""

    length_m: float
    kappa0_1pm: float
    kappa1_1pm: float

    @property
    def turn_rad(self) -> float:
        return 0.5 * self.length_m * (self.kappa0_1pm + self.kappa1_1pm)

    def mirrored(self) -> "Piece":
        return Piece(self.length_m, -self.kappa0_1pm, -self.kappa1_1pm)


Pose = tuple[float, float, float]  # x [m], y [m], heading [rad]


def straight(length_m: float) -> tuple[Piece, ...]:
    return (Piece(float(length_m), 0.0, 0.0),) if length_m > 0 else ()


def turn(delta_rad: float, kappa_max_1pm: float, sharpness_1pm2: float) -> tuple[Piece, ...]:
    """A turn by ``delta_rad`` (positive: left) from straight to straight: a clothoid of
    ``sharpness_1pm2`` (dκ/ds) up to ``kappa_max_1pm``, an arc, a clothoid back; a turn too small
    to reach ``kappa_max_1pm`` is two clothoids meeting at √(|δ|·sharpness)."""
    a = abs(float(delta_rad))
    if a == 0.0:
        return ()
    sgn = math.copysign(1.0, delta_rad)
    km, sh = float(kappa_max_1pm), float(sharpness_1pm2)
    if a >= km * km / sh:
        lc = km / sh
        arc = (a - km * lc) / km
        return (Piece(lc, 0.0, sgn * km), Piece(arc, sgn * km, sgn * km), Piece(lc, sgn * km, 0.0))
    kp = math.sqrt(a * sh)
    lc = kp / sh
    return (Piece(lc, 0.0, sgn * kp), Piece(lc, sgn * kp, 0.0))


def bulb(kappa_max_1pm: float, sharpness_1pm2: float, left: bool = True) -> tuple[Piece, ...]:
    """A turnaround back onto the same line: a turn away by α, a loop the other way by π + 2α
    and a turn away by α again, ending where it started, heading the opposite way (how a driver
    turns at the end of a slalom to drive it back). Symmetric about the loop's far point, so it
    ends on the start line exactly when that point lies on it; α is found so."""
    sgn = 1.0 if left else -1.0

    def pieces(alpha: float) -> tuple[Piece, ...]:
        return (turn(-sgn * alpha, kappa_max_1pm, sharpness_1pm2)
                + turn(sgn * (math.pi + 2 * alpha), kappa_max_1pm, sharpness_1pm2)
                + turn(-sgn * alpha, kappa_max_1pm, sharpness_1pm2))

    def offset(alpha: float) -> float:
        return end_pose(pieces(alpha))[1]

    alpha = brentq(offset, 1e-3, 0.5 * math.pi, xtol=1e-12)
    return pieces(alpha)


def length_of(pieces) -> float:
    return float(sum(p.length_m for p in pieces))


def trace(pieces, start: Pose = (0.0, 0.0, 0.0), step_m: float = STEP_M) -> PathGeometry:
    """The path of ``pieces`` from ``start``, sampled uniformly in arc length (about every
    ``step_m``): heading and curvature exact, positions by the trapezoid rule on the heading."""
    pieces = [p for p in pieces if p.length_m > 0]
    if not pieces:
        raise LimitError("a path needs a piece of positive length")
    lengths = np.array([p.length_m for p in pieces])
    ends = np.cumsum(lengths)
    total = float(ends[-1])
    n = max(int(math.ceil(total / step_m)), 1) + 1
    s = np.linspace(0.0, total, n)
    k = np.minimum(np.searchsorted(ends, s, side="right"), len(pieces) - 1)
    starts = ends - lengths
    k0 = np.array([p.kappa0_1pm for p in pieces])
    k1 = np.array([p.kappa1_1pm for p in pieces])
    psi0 = start[2] + np.concatenate([[0.0], np.cumsum([p.turn_rad for p in pieces])[:-1]])
    u = s - starts[k]
    slope = (k1[k] - k0[k]) / lengths[k]
    kappa = k0[k] + slope * u
    psi = psi0[k] + k0[k] * u + 0.5 * slope * u * u
    c, si = np.cos(psi), np.sin(psi)
    h = np.diff(s)
    x = start[0] + np.concatenate([[0.0], np.cumsum(0.5 * h * (c[1:] + c[:-1]))])
    y = start[1] + np.concatenate([[0.0], np.cumsum(0.5 * h * (si[1:] + si[:-1]))])
    return PathGeometry(s, np.column_stack([x, y, np.zeros(n)]), psi, kappa, np.zeros(n))


def end_pose(pieces, start: Pose = (0.0, 0.0, 0.0)) -> Pose:
    """Where ``pieces`` traced from ``start`` end (exact quadrature, no sampling)."""
    x, y, h = start
    for p in pieces:
        dx, dy = _piece_displacement(p, h)
        x, y, h = x + dx, y + dy, h + p.turn_rad
    return float(x), float(y), float(h)


def _piece_displacement(p: Piece, heading: float) -> tuple[float, float]:
    L, a, b = p.length_m, p.kappa0_1pm, p.kappa1_1pm
    if L <= 0:
        return 0.0, 0.0
    if a == b:
        if a == 0.0:
            return L * math.cos(heading), L * math.sin(heading)
        r = 1.0 / a
        h1 = heading + a * L
        return r * (math.sin(h1) - math.sin(heading)), r * (math.cos(heading) - math.cos(h1))
    u = 0.5 * L * (_GL_X + 1.0)
    psi = heading + a * u + 0.5 * (b - a) / L * u * u
    w = 0.5 * L * _GL_W
    return float(w @ np.cos(psi)), float(w @ np.sin(psi))


def _turn_ends(delta: np.ndarray, km: float, sh: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Displacement (in the turn's start frame) and length of :func:`turn` for every ``delta``
    at once."""
    a = np.abs(delta)
    sgn = np.sign(delta)
    full = a >= km * km / sh
    kp = np.where(full, km, np.sqrt(a * sh))
    lc = kp / sh
    arc = np.where(full, (a - kp * lc) / np.maximum(kp, 1e-12), 0.0)
    # first clothoid: from heading 0, curvature 0 → sgn·kp over lc
    u = 0.5 * lc[:, None] * (_GL_X[None] + 1.0)
    w = 0.5 * lc[:, None] * _GL_W[None]
    psi = 0.5 * (sgn * kp / np.maximum(lc, 1e-12))[:, None] * u * u
    x1, y1 = (w * np.cos(psi)).sum(1), (w * np.sin(psi)).sum(1)
    h1 = 0.5 * sgn * kp * lc
    # the arc
    h2 = h1 + sgn * kp * arc
    r = 1.0 / np.maximum(kp, 1e-12)
    xa = sgn * r * (np.sin(h2) - np.sin(h1))
    ya = sgn * r * (np.cos(h1) - np.cos(h2))
    # the last clothoid is the first one mirrored and reversed: its displacement, seen from the
    # turn's end heading backwards, is the first one's reflected
    hend = sgn * a
    c, s = np.cos(hend), np.sin(hend)
    # first clothoid run backwards from the end: (x1, -y1) in the end frame, reflected in turn direction
    x3 = c * x1 + s * y1
    y3 = s * x1 - c * y1
    return x1 + xa + x3, y1 + ya + y3, 2 * lc + arc


def connect(a: Pose, b: Pose, kappa_max_1pm: float, sharpness_1pm2: float) -> tuple[Piece, ...] | None:
    """The shortest turn–straight–turn path (clothoid turns, :func:`turn`) from pose ``a`` to
    pose ``b``, both straight; None when there is none (the poses are too close for the turning
    circle)."""
    km, sh = float(kappa_max_1pm), float(sharpness_1pm2)
    ax, ay, ah = a
    bx, by, bh = b
    grid = np.linspace(-2 * np.pi, 2 * np.pi, 721)
    best: tuple[float, tuple[Piece, ...]] | None = None
    dpsi = math.remainder(bh - ah, 2 * math.pi)

    def residual(d1: np.ndarray, d2: np.ndarray):
        x1, y1, l1 = _turn_ends(d1, km, sh)
        x2, y2, l2 = _turn_ends(d2, km, sh)
        h = ah + d1
        c, s = np.cos(h), np.sin(h)
        ca, sa = math.cos(ah), math.sin(ah)
        rx = bx - ax - (ca * x1 - sa * y1) - (c * x2 - s * y2)
        ry = by - ay - (sa * x1 + ca * y1) - (s * x2 + c * y2)
        return c * ry - s * rx, c * rx + s * ry, l1 + l2

    for k in (-1, 0, 1):
        d2 = dpsi + 2 * math.pi * k - grid
        ok = np.abs(d2) < 2 * math.pi
        f, L, _ = residual(grid, d2)
        for i in np.nonzero(ok[:-1] & ok[1:] & (np.sign(f[:-1]) != np.sign(f[1:])))[0]:
            if abs(f[i] - f[i + 1]) > 10 * (abs(f[i]) + abs(f[i + 1]) + 1.0):  # a jump, not a root
                continue
            g = lambda d: float(residual(np.array([d]), np.array([dpsi + 2 * math.pi * k - d]))[0][0])  # noqa: E731
            try:
                d1 = brentq(g, grid[i], grid[i + 1], xtol=1e-12)
            except ValueError:
                continue
            d2r = dpsi + 2 * math.pi * k - d1
            _, Ls, lt = residual(np.array([d1]), np.array([d2r]))
            if Ls[0] < -1e-6:
                continue
            total = float(Ls[0] + lt[0])
            if best is None or total < best[0]:
                best = (total, turn(d1, km, sh) + straight(max(float(Ls[0]), 0.0)) + turn(d2r, km, sh))
    return None if best is None else best[1]


# --------------------------------------------------------------------------------------------
# Courses


@dataclass(frozen=True)
class Leg:
    """One part of a course, from rest to rest: ``path`` with the speed the instructions ask for
    at every sample (``speed_mps``: a cap on the fastest drive within the limits; 0: a stop), a
    standstill of ``dwell_s`` after it, and what it belongs to (``element``: the plan's element
    index, −1 for none)."""

    path: PathGeometry
    speed_mps: np.ndarray
    dwell_s: float = 0.0
    element: int = -1
    label: str = ""

    @property
    def start(self) -> Pose:
        p = self.path
        return float(p.xyz_m[0, 0]), float(p.xyz_m[0, 1]), float(p.heading_rad[0])

    @property
    def end(self) -> Pose:
        p = self.path
        return float(p.xyz_m[-1, 0]), float(p.xyz_m[-1, 1]), float(p.heading_rad[-1])


@dataclass(frozen=True)
class TimedCourse:
    """A course driven as its instructions say: the control profile and, per leg, when it starts
    and ends (its standstill included) and its path's samples' times (``leg_times``)."""

    profile: ControlProfile
    leg_intervals: list[tuple[float, float]]
    leg_plans: list[SpeedPlan] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return self.profile.duration_s


@dataclass(frozen=True)
class Course:
    """A sequence of legs (each starting where the previous one ended)."""

    legs: tuple[Leg, ...]
    name: str = "course"

    def leg_plans(self, limits: Limits, margin: float = 0.9) -> list[SpeedPlan]:
        """The fastest drive of every leg within ``margin`` × the limits and its speeds."""
        return [plan_speed(leg.path, limits, leg.speed_mps, margin=margin) for leg in self.legs]

    def timed(self, limits: Limits, margin: float = 0.9, duration_s: float | None = None,
              plans: list[SpeedPlan] | None = None) -> TimedCourse:
        """The drive the instructions describe: every leg as fast as its speeds and ``margin`` ×
        the limits allow, rest to rest, its standstill after it; a standstill at the end up to
        ``duration_s``."""
        plans = self.leg_plans(limits, margin) if plans is None else plans
        return timed(self.legs, plans, duration_s, self.name)

    def length_m(self) -> float:
        return float(sum(leg.path.length_m for leg in self.legs))


def timed(legs, plans: list[SpeedPlan], duration_s: float | None, name: str) -> TimedCourse:
    """Legs and their speed plans as one control profile (knots at :data:`KNOT_RATE_HZ`)."""
    ts, vs, ks = [], [], []
    t0 = 0.0
    intervals = []
    dt = 1.0 / KNOT_RATE_HZ
    for leg, plan in zip(legs, plans):
        n = max(int(round(plan.duration_s * KNOT_RATE_HZ)) + 1, 2)
        tk = np.linspace(plan.t_s[0], plan.t_s[-1], n)
        sk = np.interp(tk, plan.t_s, plan.s_m)
        vk = np.interp(tk, plan.t_s, plan.speed_mps)
        kk = np.interp(sk, leg.path.s_m, leg.path.curvature_1pm)
        if ts:  # the previous leg's last knot is this one's first (both at rest, straight)
            tk, vk, kk = tk[1:], vk[1:], kk[1:]
        ts.append(t0 + (tk - plan.t_s[0]))
        vs.append(vk)
        ks.append(kk)
        t_end = t0 + plan.duration_s
        dwell = max(float(leg.dwell_s), 0.0)
        m = int(math.floor(dwell * KNOT_RATE_HZ + 1e-9))
        if m > 0:
            ts.append(t_end + dt * np.arange(1, m + 1))
            vs.append(np.zeros(m))
            ks.append(np.full(m, kk[-1]))
            t_end += m * dt
        intervals.append((t0, t_end))
        t0 = t_end
    t = np.concatenate(ts)
    v = np.concatenate(vs)
    k = np.concatenate(ks)
    if duration_s is not None and duration_s > t[-1] + dt:
        m = int(math.floor((duration_s - t[-1]) * KNOT_RATE_HZ + 1e-9))
        t = np.concatenate([t, t[-1] + dt * np.arange(1, m + 1)])
        v = np.concatenate([v, np.zeros(m)])
        k = np.concatenate([k, np.full(m, k[-1])])
    start = legs[0].start
    prof = ControlProfile(t - t[0], np.maximum(v, 0.0), k, start=start, name=name)
    return TimedCourse(prof, intervals, list(plans))
