"""From a geometric path to a control profile: curvature-continuous paths and speed profiles.

Waypoint routes and the reference maneuvers are both a *path* (where to drive) plus a *speed
profile* (how fast). This module holds that math, free of file I/O:

- :func:`smooth_path` passes a C2 cubic spline (chord-length parameter) through points and
  resamples it uniformly in arc length, with heading, curvature and grade. C2 positions make the
  curvature continuous, so a car can follow the path with finite steering rate.
- :func:`plan_speed` gives the fastest drive along the path that respects the limits: speed
  cap, lateral acceleration in curves, curvature rate, acceleration/deceleration (forward and
  backward pass on v²) and jerk (a smoothing in time that never raises the speed);
  :func:`plan_given_speed` drives it at given speeds instead.
- :func:`profile_from_plan` turns path + plan into a time-parametrised
  :class:`~excite.motion.vehicle.ControlProfile` that :func:`~excite.motion.vehicle.drive` integrates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from ..core import bounds
from ..errors import LimitError, RouteError
from .vehicle import ControlProfile, Limits


@dataclass(frozen=True)
class PathGeometry:
    """A path sampled uniformly in arc length.

    ``s_m`` arc length from the start, ``xyz_m`` (n, 3) points, ``heading_rad`` (unwrapped),
    ``curvature_1pm`` = dheading/ds (positive = left), ``grade_rad`` (positive = uphill).
    """

    s_m: np.ndarray
    xyz_m: np.ndarray
    heading_rad: np.ndarray
    curvature_1pm: np.ndarray
    grade_rad: np.ndarray

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1])


def smooth_path(points_m: np.ndarray, closed: bool = False, step_m: float = 0.2) -> PathGeometry:
    """A curvature-continuous path through ``points_m`` (n, 2 or 3), resampled every ~``step_m``.

    The path interpolates every point with a C2 cubic spline in the chord-length parameter
    (natural end conditions, or periodic when ``closed``: then the first point must not be
    repeated at the end). Consecutive points must be distinct.
    """
    p = np.asarray(points_m, dtype=float)
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise RouteError(f"path points must be (n, 2) or (n, 3), got shape {p.shape}")
    if p.shape[1] == 2:
        p = np.column_stack([p, np.zeros(len(p))])
    if closed:
        p = np.vstack([p, p[:1]])
    if len(p) < 2:
        raise RouteError(f"a path needs at least 2 points, got {len(p)}")
    chord = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if np.any(chord < 1e-6):
        raise RouteError("a path has two consecutive identical points")
    u = np.concatenate([[0.0], np.cumsum(chord)])
    if not u[-1] <= bounds.max_length_m():  # the path is resampled every few cm: bound it first
        raise RouteError(f"the path is {u[-1]:.6g} m long, over the limit of {bounds.max_length_m():g} m")
    if len(p) == 2:  # a straight segment: a spline of degree 1 is the whole story
        n = max(int(np.ceil(u[-1] / step_m)) + 1, 2)
        s = np.linspace(0.0, u[-1], n)
        xyz = p[0] + (s / u[-1])[:, None] * (p[1] - p[0])
        d = p[1] - p[0]
        heading = np.full(n, np.arctan2(d[1], d[0]))
        grade = np.full(n, np.arctan2(d[2], np.hypot(d[0], d[1])))
        return PathGeometry(s, xyz, heading, np.zeros(n), grade)
    spline = CubicSpline(u, p, bc_type="periodic" if closed else "natural")
    # Dense in the parameter, then uniform in arc length.
    ud = np.linspace(0.0, u[-1], max(int(np.ceil(u[-1] / (0.25 * step_m))), 50) + 1)
    d1 = spline(ud, 1)
    speed_u = np.linalg.norm(d1, axis=1)
    sd = np.concatenate([[0.0], np.cumsum(0.5 * (speed_u[1:] + speed_u[:-1]) * np.diff(ud))])
    n = max(int(np.ceil(sd[-1] / step_m)) + 1, 2)
    s = np.linspace(0.0, sd[-1], n)
    us = np.interp(s, sd, ud)
    d1, d2 = spline(us, 1), spline(us, 2)
    horiz2 = d1[:, 0] ** 2 + d1[:, 1] ** 2
    if np.any(horiz2 < 1e-12):
        raise RouteError("the path is vertical somewhere: a car cannot follow it")
    heading = np.unwrap(np.arctan2(d1[:, 1], d1[:, 0]))
    dheading_du = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / horiz2
    curvature = dheading_du / np.linalg.norm(d1, axis=1)
    grade = np.arctan2(d1[:, 2], np.sqrt(horiz2))
    return PathGeometry(s, spline(us), heading, curvature, grade)


def speed_caps(s_m: np.ndarray, curvature_1pm: np.ndarray, limits: Limits,
               speed_cap_mps: np.ndarray | float | None = None,
               margin: float = 0.9) -> np.ndarray:
    """The highest v² [m²/s²] allowed at each ``s_m`` (uniform grid) by ``margin`` × the limits.

    Caps: ``speed_cap_mps`` (a number or one per point; 0 forces a stop there), the speed limit,
    lateral acceleration ``v²|κ| ≤ a_lat`` and curvature rate ``v|dκ/ds| ≤ κ̇``. Curvature beyond
    the curvature limit is not fixed here (speed cannot fix it):
    :func:`~excite.motion.vehicle.check_limits` reports it.
    """
    s = np.asarray(s_m, dtype=float)
    kappa = np.asarray(curvature_1pm, dtype=float)
    n = s.size
    w_cap = np.full(n, (margin * limits.speed_max_mps) ** 2)
    if speed_cap_mps is not None:
        w_cap = np.minimum(w_cap, np.broadcast_to(np.asarray(speed_cap_mps, dtype=float), (n,)) ** 2)
    with np.errstate(divide="ignore"):
        w_cap = np.minimum(w_cap, margin * limits.lat_accel_max_mps2 / np.abs(kappa))
        if n > 1:
            dkappa = np.abs(np.gradient(kappa, s[1] - s[0]))
            w_cap = np.minimum(w_cap, (margin * limits.curvature_rate_max_1pms / dkappa) ** 2)
    return w_cap


def _passes(s: np.ndarray, w_cap: np.ndarray, acc: float, dec: float) -> np.ndarray:
    """Forward (acceleration) and backward (braking) passes on v², which is linear in s for
    constant acceleration: ``w_i = min_j (cap_j + 2a(s_i − s_j))`` for j ≤ i, likewise for j ≥ i."""
    w = 2.0 * acc * s + np.minimum.accumulate(w_cap - 2.0 * acc * s)
    return np.minimum(w, -2.0 * dec * s + np.minimum.accumulate((w_cap + 2.0 * dec * s)[::-1])[::-1])


def travel_time_s(s_m: np.ndarray, speed_mps: np.ndarray) -> float:
    """Time to drive the path at ``speed_mps`` with constant acceleration between samples."""
    vsum = speed_mps[1:] + speed_mps[:-1]
    with np.errstate(divide="ignore"):
        return float(np.sum(np.where(vsum > 0, 2.0 * np.diff(s_m) / vsum, np.inf)))


@dataclass(frozen=True)
class SpeedPlan:
    """Progress along a path on a uniform time grid: ``s_m(t_s)`` and ``speed_mps(t_s)``."""

    t_s: np.ndarray
    s_m: np.ndarray
    speed_mps: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    def with_standstill(self, duration_s: float) -> "SpeedPlan":
        """The plan followed by a standstill until ``duration_s`` (if it ends at rest earlier)."""
        dt = float(self.t_s[1] - self.t_s[0])
        extra = int(np.floor((duration_s - self.duration_s) / dt + 1e-9))
        if extra <= 0:
            return self
        t = np.concatenate([self.t_s, self.t_s[-1] + dt * np.arange(1, extra + 1)])
        return SpeedPlan(t, np.concatenate([self.s_m, np.full(extra, self.s_m[-1])]),
                         np.concatenate([self.speed_mps, np.zeros(extra)]))


def _timed(s: np.ndarray, v: np.ndarray, step_s: float,
           dwell_s: np.ndarray | None = None) -> SpeedPlan:
    """Time-parametrise v(s) (constant acceleration between samples) onto a uniform grid,
    standing still for ``dwell_s[i]`` at sample i."""
    vsum = v[1:] + v[:-1]
    if np.any(vsum <= 0):
        k = int(np.argmax(vsum <= 0))
        raise LimitError(f"the speed is zero on both ends of the path step at s={s[k]:.1f} m: "
                         "the vehicle would never arrive")
    dwell = np.zeros(s.size) if dwell_s is None else np.asarray(dwell_s, dtype=float)
    # Knots: arrival at each sample, and departure after a dwell (same place, zero speed).
    travel = np.concatenate([[0.0], 2.0 * np.diff(s) / vsum])
    arrive = np.cumsum(travel) + np.concatenate([[0.0], np.cumsum(dwell)[:-1]])
    has = dwell > 0
    kt = np.concatenate([arrive, (arrive + dwell)[has]])
    ks = np.concatenate([s, s[has]])
    kv = np.concatenate([v, np.zeros(has.sum())])
    order = np.lexsort((np.concatenate([np.zeros(s.size), np.ones(has.sum())]), kt))
    kt, ks, kv = kt[order], ks[order], kv[order]
    too_long = bounds.work_problem(float(kt[-1]), 1.0 / step_s, bounds.MAX_SAMPLES, "plan samples")
    if too_long:
        raise RouteError(f"driving this path: {too_long}")
    grid = np.linspace(0.0, kt[-1], max(int(round(kt[-1] / step_s)) + 1, 2))
    k = np.clip(np.searchsorted(kt, grid, side="right") - 1, 0, kt.size - 2)
    span = kt[k + 1] - kt[k]
    a = np.where(span > 0, (kv[k + 1] - kv[k]) / np.where(span > 0, span, 1.0), 0.0)
    tau = grid - kt[k]
    # Between two speeds ≥ 0 the speed is ≥ 0; at a stop, kv + a·span rounds to about -1e-15,
    # which a control profile would refuse as reversing.
    return SpeedPlan(grid, ks[k] + kv[k] * tau + 0.5 * a * tau**2, np.maximum(kv[k] + a * tau, 0.0))


def plan_given_speed(path: PathGeometry, speed_mps: np.ndarray, step_s: float = 0.01) -> SpeedPlan:
    """Drive ``path`` at the given speed per path sample, accelerating uniformly in between (so a
    single zero takes finite time; two consecutive zeros raise :class:`LimitError`)."""
    return _timed(path.s_m, np.asarray(speed_mps, dtype=float), step_s)


def plan_speed(path: PathGeometry, limits: Limits, speed_cap_mps: np.ndarray | float | None = None,
               margin: float = 0.9, step_s: float = 0.01) -> SpeedPlan:
    """The fastest drive along ``path`` from rest to rest within ``margin`` × every limit.

    v² is capped (:func:`speed_caps`), passed forward and backward for acceleration and braking,
    and time-parametrised; then the speed is averaged over ``T = (a + d) / j`` in time, which
    keeps acceleration within bounds, bounds jerk by ``(a + d) / T = j`` and preserves distance
    (the smoothed car is never far from the unsmoothed one). So that averaging cannot exceed a
    cap, positive caps are first widened by the distance covered in ``T / 2`` (running minimum
    in s); every stop (a zero cap, and both ends) gets a standstill of ``T`` (``T / 2`` at the
    ends), so that the averaged speed still reaches zero there. The result is re-checked
    against the caps where the smoothed car actually is.
    """
    from scipy.ndimage import minimum_filter1d, uniform_filter1d  # planning only: not on score's cold path

    s = path.s_m
    ds = float(s[1] - s[0])
    w_cap = speed_caps(s, path.curvature_1pm, limits, speed_cap_mps, margin)
    w_cap[0] = w_cap[-1] = 0.0
    stop = w_cap <= 0.0
    acc, dec = margin * limits.accel_max_mps2, margin * limits.decel_max_mps2
    # A further 0.8 on jerk: drive() interpolates speed knots shape-preservingly (PCHIP), which
    # flattens speed extrema at knots and adds up to ~20 % jerk.
    window_s = (acc + dec) / (0.8 * margin * limits.jerk_max_mps3)
    k = int(np.ceil(window_s / step_s)) | 1  # odd, so the average is centred
    window_s = k * step_s
    dwell = np.where(stop, window_s, 0.0)
    dwell[0] = dwell[-1] = 0.5 * window_s
    reach_m = float(np.sqrt(np.max(w_cap))) * 0.5 * window_s + 1.0
    for _ in range(5):
        n = 2 * int(np.ceil(reach_m / ds)) + 1
        w_wide = minimum_filter1d(np.where(stop, np.inf, w_cap), n, mode="nearest")
        w_wide[stop] = 0.0
        raw = _timed(s, np.sqrt(np.maximum(_passes(s, w_wide, acc, dec), 0.0)), step_s, dwell)
        padded = np.concatenate([np.zeros(k), raw.speed_mps, np.zeros(k)])
        v = np.maximum(uniform_filter1d(padded, k, mode="constant")[k:-k], 0.0)
        v[0] = v[-1] = 0.0
        pos = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * step_s)])
        idx = np.clip(np.round(pos / ds).astype(int), 0, s.size - 1)
        over = (v**2 > w_cap[idx] * (1.0 + 1e-3) + 1e-6) & ~stop[idx]
        if not over.any():
            return SpeedPlan(raw.t_s, np.minimum(pos, s[-1]), v)
        reach_m += 2.0
    raise LimitError("no speed profile within the limits was found for this path")


def profile_from_plan(path: PathGeometry, plan: SpeedPlan, knot_rate_hz: float = 20.0,
                      name: str = "route") -> ControlProfile:
    """The control profile that drives ``path`` as ``plan`` says, with knots uniform in time."""
    n = max(int(round(plan.duration_s * knot_rate_hz)) + 1, 2)
    tk = np.linspace(plan.t_s[0], plan.t_s[-1], n)
    sk = np.interp(tk, plan.t_s, plan.s_m)
    return ControlProfile(
        t_s=tk - tk[0],
        speed_mps=np.interp(tk, plan.t_s, plan.speed_mps),
        curvature_1pm=np.interp(sk, path.s_m, path.curvature_1pm),
        grade_rad=np.interp(sk, path.s_m, path.grade_rad),
        start=(float(path.xyz_m[0, 0]), float(path.xyz_m[0, 1]), float(path.heading_rad[0])),
        name=name,
    )
