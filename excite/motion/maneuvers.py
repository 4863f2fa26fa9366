"""Reference calibration maneuvers and random candidate drives, as control profiles.

Every generator returns a :class:`~excite.motion.vehicle.ControlProfile` (its ``name`` set) that stays
within ``margin`` (default 0.9) of every :class:`~excite.motion.vehicle.Limits` bound and, except the
highway run, inside a rectangular lot of ``length_m`` (along x) × ``width_m`` (along y) centred
on the origin, ``margin_m`` away from its edges. A maneuver is a closed path driven in laps, from
rest to rest, lasting ``duration_s`` (to a fraction of a second). Drive one with
:func:`~excite.motion.vehicle.drive` and a :class:`~excite.motion.vehicle.Suspension` (:func:`reference_drives`
does both).

``python -m excite.io.references --write trajectories/`` regenerates the committed reference files
(TUM and control CSV) deterministically.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import LimitError
from .paths import PathGeometry, SpeedPlan, plan_speed, profile_from_plan, smooth_path
from .trajectory import Trajectory
from .vehicle import ControlProfile, Limits, Suspension, check_limits, drive

__all__ = [
    "Lot", "REFERENCE_MANEUVERS", "highway_run", "stop_and_go", "circle_left", "circle_right",
    "figure_eight", "slalom", "reference_maneuvers", "reference_drives", "random_candidates",
]

LOT_LENGTH_M = 80.0
LOT_WIDTH_M = 50.0
EDGE_MARGIN_M = 3.0
LIMIT_MARGIN = 0.9
_CLOSED_SAMPLES = 400  # points per lap handed to the periodic path spline


@dataclass(frozen=True)
class Lot:
    """A test lot: a simple polygon ``polygon_m`` (m, 2), vertices in order, not repeated,
    optionally with ``holes`` (keep-out zones: simple polygons inside it)."""

    polygon_m: np.ndarray
    holes: tuple[np.ndarray, ...] = ()

    def __post_init__(self) -> None:
        rings = []
        for what, ring in [("a lot polygon", self.polygon_m)] + [(f"keep-out zone {i + 1}", h)
                                                                  for i, h in enumerate(self.holes)]:
            poly = np.asarray(ring, dtype=float)
            if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3 or not np.all(np.isfinite(poly)):
                raise LimitError(f"{what} needs at least 3 finite (x, y) vertices, got {poly.shape}")
            rings.append(poly)
        object.__setattr__(self, "polygon_m", rings[0])
        object.__setattr__(self, "holes", tuple(rings[1:]))
        for i, h in enumerate(self.holes):
            if not _in_ring(rings[0], h).all():
                raise LimitError(f"keep-out zone {i + 1} is not inside the lot")

    @classmethod
    def rectangle(cls, length_m: float = LOT_LENGTH_M, width_m: float = LOT_WIDTH_M) -> "Lot":
        """A ``length_m`` (along x) × ``width_m`` (along y) rectangle centred on the origin."""
        a, b = 0.5 * length_m, 0.5 * width_m
        return cls(np.array([[-a, -b], [a, -b], [a, b], [-a, b]]))

    @property
    def centroid_m(self) -> np.ndarray:
        return self.polygon_m.mean(axis=0)

    def distance_to_edge_m(self, points_m: np.ndarray) -> np.ndarray:
        """Distance [m] from each point (n, 2) to the nearest edge of the lot or a hole."""
        p = np.asarray(points_m, dtype=float)[:, :2]
        return np.min([_ring_distance(r, p) for r in (self.polygon_m, *self.holes)], axis=0)

    def clearance_m(self, points_m: np.ndarray) -> np.ndarray:
        """Signed distance [m] of each point to the nearest edge: positive inside the lot (and
        outside every hole), negative outside."""
        p = np.asarray(points_m, dtype=float)[:, :2]
        d = self.distance_to_edge_m(p)
        return np.where(self.contains(p), d, -d)

    def contains(self, points_m: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """Whether each point (n, 2[+]) is inside the polygon, outside every hole, and at least
        ``margin_m`` from every edge (even-odd ray casting)."""
        p = np.asarray(points_m, dtype=float)[:, :2]
        inside = _in_ring(self.polygon_m, p)
        for h in self.holes:
            inside &= ~_in_ring(h, p)
        if margin_m > 0:
            inside &= self.distance_to_edge_m(p) >= margin_m
        return inside


def _in_ring(ring: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Even-odd ray casting: whether each point (n, 2) is inside the simple polygon ``ring``."""
    x, y = p[:, 0:1], p[:, 1:2]
    a = ring
    b = np.roll(a, -1, axis=0)
    crosses = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return np.sum(crosses & (x < x_at), axis=1) % 2 == 1


def _ring_distance(ring: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Distance from each point (n, 2) to the nearest edge of the closed polygon ``ring``."""
    out = np.full(len(p), np.inf)
    a = ring
    ab = np.roll(ring, -1, axis=0) - a
    for s in range(0, len(p), 4096):  # bounded memory for large grids
        q = p[s:s + 4096, None, :]
        u = np.clip(np.sum((q - a[None]) * ab[None], axis=2) / np.sum(ab * ab, axis=1), 0.0, 1.0)
        out[s:s + 4096] = np.linalg.norm(q - (a[None] + u[..., None] * ab[None]), axis=2).min(axis=1)
    return out


# --------------------------------------------------------------------------------------------
# Building blocks


def _laps(lap: PathGeometry, n_laps: int) -> PathGeometry:
    """``n_laps`` repetitions of a closed path (its last sample equals its first)."""
    m = lap.s_m.size - 1
    reps = np.arange(n_laps)
    turn = lap.heading_rad[-1] - lap.heading_rad[0]
    s = (lap.s_m[:m][None] + reps[:, None] * lap.length_m).ravel()
    heading = (lap.heading_rad[:m][None] + reps[:, None] * turn).ravel()
    return PathGeometry(
        s_m=np.append(s, n_laps * lap.length_m),
        xyz_m=np.vstack([np.tile(lap.xyz_m[:m], (n_laps, 1)), lap.xyz_m[:1]]),
        heading_rad=np.append(heading, lap.heading_rad[0] + n_laps * turn),
        curvature_1pm=np.append(np.tile(lap.curvature_1pm[:m], n_laps), lap.curvature_1pm[0]),
        grade_rad=np.zeros(n_laps * m + 1),
    )


def _head(path: PathGeometry, m: int) -> PathGeometry:
    return PathGeometry(path.s_m[:m], path.xyz_m[:m], path.heading_rad[:m],
                        path.curvature_1pm[:m], path.grade_rad[:m])


def _timed_profile(path: PathGeometry, duration_s: float, limits: Limits, name: str,
                   speed_cap: Callable[[np.ndarray], np.ndarray] | None = None,
                   margin: float = LIMIT_MARGIN) -> ControlProfile:
    """Drive ``path`` from rest to rest for ``duration_s``: the end point along the path is found
    by bisection so that the fastest feasible drive (:func:`plan_speed`) takes as long as
    possible within ``duration_s``; a standstill at the end fills the remaining fraction."""
    kappa_max = float(np.abs(path.curvature_1pm).max())
    if kappa_max > margin * limits.curvature_max_1pm:
        raise LimitError(f"{name}: the path needs curvature {kappa_max:.3g} 1/m, beyond "
                         f"{margin:g} × the limit {limits.curvature_max_1pm:g}: the lot is too "
                         "small for this maneuver")
    cap = None if speed_cap is None else speed_cap(path.s_m)

    def plan(m: int) -> SpeedPlan:
        c = None
        if cap is not None:
            c = cap[:m].copy()
            c[-3:][c[-3:] == 0.0] = np.inf  # the end is a stop already
        return plan_speed(_head(path, m), limits, c, margin=margin)

    lo, hi = 3, path.s_m.size
    if plan(hi).duration_s < duration_s:
        raise LimitError(f"{name}: the path is too short for {duration_s:g} s")
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if plan(mid).duration_s <= duration_s:
            lo = mid
        else:
            hi = mid
    return profile_from_plan(path, plan(lo).with_standstill(duration_s), name=name)


def _loop_profile(points_m: np.ndarray, duration_s: float, limits: Limits, name: str,
                  stops_per_lap: int = 0, stop_phase: float = 0.5,
                  speed_cap: Callable[[np.ndarray], np.ndarray] | None = None,
                  margin: float = LIMIT_MARGIN) -> ControlProfile:
    """Laps of the closed curve through ``points_m`` (first point not repeated), with
    ``stops_per_lap`` evenly spaced standstills (the first at ``stop_phase`` of a spacing)."""
    lap = smooth_path(points_m, closed=True)
    n_laps = int(np.ceil(margin * limits.speed_max_mps * duration_s / lap.length_m)) + 1
    path = _laps(lap, n_laps)
    caps = [speed_cap] if speed_cap is not None else []
    if stops_per_lap > 0:
        spacing = lap.length_m / stops_per_lap
        ds = float(path.s_m[1] - path.s_m[0])
        stop_s = (np.arange(n_laps * stops_per_lap) + stop_phase) * spacing

        def stops(s: np.ndarray) -> np.ndarray:
            out = np.full(s.size, np.inf)
            idx = np.clip(np.round(stop_s / ds).astype(int), 0, s.size - 1)
            out[idx] = 0.0
            return out

        caps.append(stops)

    def cap(s: np.ndarray) -> np.ndarray:
        return np.minimum.reduce([c(s) for c in caps]) if caps else np.full(s.size, np.inf)

    return _timed_profile(path, duration_s, limits, name, cap, margin)


def _ellipse(a_m: float, b_m: float, n: int = _CLOSED_SAMPLES, clockwise: bool = False,
             weave_m: float = 0.0, weave_cycles: int = 0) -> np.ndarray:
    """Points of an ellipse starting at its bottom (0, −b) heading +x (counter-clockwise), or at
    its top (0, b) heading +x (clockwise), optionally weaving ``weave_m`` along the normal."""
    th = -0.5 * np.pi + 2.0 * np.pi * np.arange(n) / n
    if clockwise:
        th = 0.5 * np.pi - 2.0 * np.pi * np.arange(n) / n
    x, y = a_m * np.cos(th), b_m * np.sin(th)
    if weave_m:
        nx, ny = b_m * np.cos(th), a_m * np.sin(th)  # outward normal of the ellipse
        norm = np.hypot(nx, ny)
        w = weave_m * np.sin(weave_cycles * (th - th[0]))
        x, y = x + w * nx / norm, y + w * ny / norm
    return np.column_stack([x, y])


def _inner(length_m: float, width_m: float, margin_m: float) -> tuple[float, float]:
    a, b = 0.5 * length_m - margin_m, 0.5 * width_m - margin_m
    if a <= 0 or b <= 0:
        raise LimitError(f"a {length_m:g} × {width_m:g} m lot leaves no room inside a {margin_m:g} m "
                         "edge margin")
    return a, b


# --------------------------------------------------------------------------------------------
# Reference maneuvers


def highway_run(duration_s: float = 90.0, limits: Limits = Limits(),
                margin: float = LIMIT_MARGIN) -> ControlProfile:
    """Straight road (no lot): accelerate from rest to ``margin`` × the speed limit, cruise, stop.

    The degenerate baseline: long stretches of straight constant-speed driving.
    """
    length_m = margin * limits.speed_max_mps * duration_s + 100.0
    path = smooth_path(np.array([[0.0, 0.0], [length_m, 0.0]]))
    return _timed_profile(path, duration_s, limits, "highway_run", margin=margin)


def stop_and_go(duration_s: float = 90.0, width_m: float = LOT_WIDTH_M,
                length_m: float = LOT_LENGTH_M, limits: Limits = Limits(),
                margin_m: float = EDGE_MARGIN_M, stops_per_lap: int = 4,
                margin: float = LIMIT_MARGIN) -> ControlProfile:
    """Laps of the largest ellipse in the lot with ``stops_per_lap`` full stops per lap: hard
    acceleration and braking (body pitch) in straights and curves."""
    a, b = _inner(length_m, width_m, margin_m)
    return _loop_profile(_ellipse(a, b), duration_s, limits, "stop_and_go",
                         stops_per_lap=stops_per_lap, margin=margin)


def _circle(duration_s: float, width_m: float, length_m: float, limits: Limits, margin_m: float,
            clockwise: bool, margin: float) -> ControlProfile:
    r = min(_inner(length_m, width_m, margin_m))
    return _loop_profile(_ellipse(r, r, clockwise=clockwise), duration_s, limits,
                         "circle_right" if clockwise else "circle_left", margin=margin)


def circle_left(duration_s: float = 90.0, width_m: float = LOT_WIDTH_M,
                length_m: float = LOT_LENGTH_M, limits: Limits = Limits(),
                margin_m: float = EDGE_MARGIN_M, margin: float = LIMIT_MARGIN) -> ControlProfile:
    """Counter-clockwise laps of the largest circle in the lot at the fastest steady speed the
    lateral-acceleration limit allows (from rest, to rest)."""
    return _circle(duration_s, width_m, length_m, limits, margin_m, False, margin)


def circle_right(duration_s: float = 90.0, width_m: float = LOT_WIDTH_M,
                 length_m: float = LOT_LENGTH_M, limits: Limits = Limits(),
                 margin_m: float = EDGE_MARGIN_M, margin: float = LIMIT_MARGIN) -> ControlProfile:
    """Clockwise laps of the largest circle in the lot (mirror image of :func:`circle_left`)."""
    return _circle(duration_s, width_m, length_m, limits, margin_m, True, margin)


def figure_eight(duration_s: float = 90.0, width_m: float = LOT_WIDTH_M,
                 length_m: float = LOT_LENGTH_M, limits: Limits = Limits(),
                 margin_m: float = EDGE_MARGIN_M, margin: float = LIMIT_MARGIN) -> ControlProfile:
    """Laps of a figure-eight (1:2 Lissajous curve) filling the lot: left and right turns with
    curvature passing smoothly through zero at the crossing."""
    a, b = _inner(length_m, width_m, margin_m)
    th = 2.0 * np.pi * np.arange(_CLOSED_SAMPLES) / _CLOSED_SAMPLES
    pts = np.column_stack([a * np.sin(th), b * np.sin(2.0 * th)])
    return _loop_profile(pts, duration_s, limits, "figure_eight", margin=margin)


def slalom(duration_s: float = 90.0, width_m: float = LOT_WIDTH_M, length_m: float = LOT_LENGTH_M,
           limits: Limits = Limits(), margin_m: float = EDGE_MARGIN_M,
           gate_spacing_m: float = 15.0, offset_m: float = 1.5,
           margin: float = LIMIT_MARGIN) -> ControlProfile:
    """Laps of an ellipse in the lot weaving ±``offset_m`` between gates ``gate_spacing_m`` apart:
    alternating left and right turns, hence alternating body roll."""
    a, b = _inner(length_m, width_m, margin_m)
    a, b = a - offset_m, b - offset_m
    perimeter = np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b)))  # Ramanujan
    cycles = max(int(round(perimeter / (2.0 * gate_spacing_m))), 1)
    return _loop_profile(_ellipse(a, b, weave_m=offset_m, weave_cycles=cycles), duration_s,
                         limits, "slalom", margin=margin)


REFERENCE_MANEUVERS: dict[str, Callable[..., ControlProfile]] = {
    "highway_run": highway_run,
    "stop_and_go": stop_and_go,
    "circle_left": circle_left,
    "circle_right": circle_right,
    "figure_eight": figure_eight,
    "slalom": slalom,
}


def reference_maneuvers(duration_s: float = 90.0, width_m: float = LOT_WIDTH_M,
                        length_m: float = LOT_LENGTH_M,
                        limits: Limits = Limits()) -> dict[str, ControlProfile]:
    """Every reference maneuver's control profile, by name."""
    out = {}
    for name, gen in REFERENCE_MANEUVERS.items():
        if gen is highway_run:
            out[name] = gen(duration_s, limits=limits)
        else:
            out[name] = gen(duration_s, width_m=width_m, length_m=length_m, limits=limits)
    return out


def reference_drives(duration_s: float = 90.0, width_m: float = LOT_WIDTH_M,
                     length_m: float = LOT_LENGTH_M, limits: Limits = Limits(),
                     suspension: Suspension = Suspension()) -> dict[str, Trajectory]:
    """Every reference maneuver driven with ``suspension``, by name."""
    return {name: drive(p, suspension)
            for name, p in reference_maneuvers(duration_s, width_m, length_m, limits).items()}


# --------------------------------------------------------------------------------------------
# Random candidates


def _random_loop(rng: np.random.Generator, half_extent_m: np.ndarray) -> np.ndarray:
    """A random smooth closed curve scaled to ``half_extent_m`` (x, y), centred on the origin:
    a star-shaped loop with random harmonics, or a randomly proportioned figure-eight."""
    th = 2.0 * np.pi * np.arange(_CLOSED_SAMPLES) / _CLOSED_SAMPLES
    if rng.random() < 0.3:
        x, y = np.sin(th), np.sin(2.0 * th + rng.uniform(-0.3, 0.3))
    else:
        r = np.ones_like(th)
        for k in (2, 3, 4):
            r += rng.uniform(-0.25, 0.25) / (k - 1) * np.cos(k * th + rng.uniform(0, 2 * np.pi))
        x, y = r * np.cos(th), r * np.sin(th)
    x = x / np.abs(x).max() * half_extent_m[0] * rng.uniform(0.6, 1.0)
    y = y / np.abs(y).max() * half_extent_m[1] * rng.uniform(0.6, 1.0)
    pts = np.column_stack([x, y])
    if rng.random() < 0.5:
        pts = pts[::-1]
    return np.roll(pts, -int(rng.integers(len(pts))), axis=0)


def random_candidates(n: int, duration_s: float = 90.0, lot: Lot | None = None,
                      limits: Limits = Limits(), seed: int = 0,
                      suspension: Suspension = Suspension(), margin_m: float = EDGE_MARGIN_M,
                      max_tries: int | None = None) -> list[ControlProfile]:
    """``n`` random control profiles, each feasible: within ``limits`` (checked on the drive with
    :func:`~excite.motion.vehicle.check_limits`) and inside ``lot`` with ``margin_m`` to spare (checked
    point-in-polygon on the driven path). Same ``seed``, same candidates.

    Each is laps of a random smooth closed curve (loop or figure-eight) around the lot's centroid,
    shrunk until it fits, driven in a random direction with a random speed cap, random
    speed modulation and a random number of stops per lap. Infeasible samples are rejected;
    after ``max_tries`` (default 20 n) a :class:`~excite.errors.LimitError` is raised.
    """
    lot = Lot.rectangle() if lot is None else lot
    rng = np.random.default_rng(seed)
    c = lot.centroid_m
    half = np.maximum(np.abs(lot.polygon_m - c).max(axis=0) - margin_m, 1.0)
    out: list[ControlProfile] = []
    tries = 0
    max_tries = 20 * n if max_tries is None else max_tries
    while len(out) < n:
        tries += 1
        if tries > max_tries:
            raise LimitError(f"only {len(out)} of {n} random candidates were feasible after "
                             f"{max_tries} tries: the lot may be too small for these limits")
        pts = _random_loop(rng, half) + c
        for _ in range(8):  # repair: shrink towards the centroid until the curve fits
            if lot.contains(pts, margin_m).all():
                break
            pts = c + 0.85 * (pts - c)
        v_cap = rng.uniform(3.0, LIMIT_MARGIN * limits.speed_max_mps)
        depth = rng.uniform(0.0, 0.7)
        wavelength = rng.uniform(20.0, 80.0)
        phase = rng.uniform(0.0, 2.0 * np.pi)
        stops = int(rng.choice([0, 0, 1, 2, 3]))

        def cap(s: np.ndarray, v_cap=v_cap, depth=depth, wavelength=wavelength,
                phase=phase) -> np.ndarray:
            return v_cap * (1.0 - depth * (0.5 + 0.5 * np.sin(2 * np.pi * s / wavelength + phase)))

        name = f"random_{seed}_{len(out)}"
        try:
            prof = _loop_profile(pts, duration_s, limits, name, stops_per_lap=stops,
                                 stop_phase=rng.uniform(0.2, 0.8), speed_cap=cap)
        except LimitError:
            continue
        traj = drive(prof, suspension)
        if check_limits(traj, limits):
            continue
        if not lot.contains(traj.sample(traj.times(5.0)).p_W_V).all():
            continue
        out.append(prof)
    return out
