"""From a geometric path to a control profile: curvature-continuous paths and speed profiles.

Waypoint routes and the reference maneuvers are both a *path* (where to drive) plus a *speed
profile* (how fast). This module holds that math, free of file I/O:

- :func:`smooth_path` passes a C2 cubic spline (chord-length parameter) through points and
  resamples it uniformly in arc length, with heading, curvature and grade. C2 positions make the
  curvature continuous, so a car can follow the path with finite steering rate.
- :func:`speed_profile` gives the fastest speed along the path that respects the limits: speed
  cap, lateral acceleration in curves, curvature rate, acceleration/deceleration (forward and
  backward pass on v²) and jerk (a smoothing of v² in arc length that provably stays below the
  caps).
- :func:`profile_from_path` turns path + speed into a time-parametrised
  :class:`~excite.vehicle.ControlProfile` that :func:`~excite.vehicle.drive` integrates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import minimum_filter1d, uniform_filter1d

from .errors import LimitError, RouteError
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


def speed_profile(s_m: np.ndarray, curvature_1pm: np.ndarray, limits: Limits,
                  speed_cap_mps: np.ndarray | float | None = None, v_start_mps: float = 0.0,
                  v_end_mps: float = 0.0, margin: float = 0.9) -> np.ndarray:
    """The fastest speed [m/s] at each ``s_m`` (uniform grid) within ``margin`` × every limit.

    Caps: ``speed_cap_mps`` (a number or one per point; 0 forces a stop there), the speed limit,
    lateral acceleration ``v²|κ| ≤ a_lat``, curvature rate ``v|dκ/ds| ≤ κ̇``. Then a forward pass
    (acceleration) and a backward pass (deceleration) on v², which is linear in s for constant
    acceleration. Jerk: v² is eroded (running minimum) and then averaged over a window
    ``L = v_max (a + d) / j`` of arc length; both keep v² below the caps and keep its slope
    (2 × acceleration) within bounds, and the averaging bounds ``da/ds`` by ``(a + d) / L``, hence
    the jerk ``v da/ds`` by ``j``. Curvature beyond the curvature limit is not fixed here (speed
    cannot fix it); :func:`~excite.vehicle.check_limits` reports it.
    """
    s = np.asarray(s_m, dtype=float)
    kappa = np.asarray(curvature_1pm, dtype=float)
    n = s.size
    ds = float(s[1] - s[0]) if n > 1 else 1.0
    v_max = margin * limits.speed_max_mps
    w_cap = np.full(n, v_max**2)
    if speed_cap_mps is not None:
        w_cap = np.minimum(w_cap, np.broadcast_to(np.asarray(speed_cap_mps, dtype=float), (n,)) ** 2)
    with np.errstate(divide="ignore"):
        w_cap = np.minimum(w_cap, margin * limits.lat_accel_max_mps2 / np.abs(kappa))
        dkappa = np.abs(np.gradient(kappa, ds)) if n > 1 else np.zeros(n)
        w_cap = np.minimum(w_cap, (margin * limits.curvature_rate_max_1pms / dkappa) ** 2)
    w_cap[0] = min(w_cap[0], v_start_mps**2)
    w_cap[-1] = min(w_cap[-1], v_end_mps**2)
    acc, dec = margin * limits.accel_max_mps2, margin * limits.decel_max_mps2
    # Forward pass w_i = min_{j≤i} (cap_j + 2a(s_i − s_j)), backward pass likewise for braking.
    w = 2.0 * acc * s + np.minimum.accumulate(w_cap - 2.0 * acc * s)
    w = np.minimum(w, -2.0 * dec * s + np.minimum.accumulate((w_cap + 2.0 * dec * s)[::-1])[::-1])
    window_m = float(np.sqrt(w.max())) * (acc + dec) / (margin * limits.jerk_max_mps3)
    k = int(np.ceil(window_m / ds)) | 1  # odd, so the windows are centred
    if k > 1:
        pad = k
        wp = np.concatenate([np.full(pad, w[0]), w, np.full(pad, w[-1])])
        wp = uniform_filter1d(minimum_filter1d(wp, k, mode="nearest"), k, mode="nearest")
        w = np.minimum(wp[pad:-pad], w)
    return np.sqrt(np.maximum(w, 0.0))


def profile_from_path(path: PathGeometry, speed_mps: np.ndarray, knot_rate_hz: float = 10.0,
                      name: str = "route") -> ControlProfile:
    """The control profile that drives ``path`` at ``speed_mps`` (one value per path sample).

    Between path samples the acceleration is constant (v² linear in s), so the time to cover a
    step is ``2 ds / (v_i + v_{i+1})``: stops at single points take finite time, two consecutive
    zero speeds would take forever and are rejected. Knots are placed uniformly in time.
    """
    v = np.asarray(speed_mps, dtype=float)
    ds = np.diff(path.s_m)
    vsum = v[1:] + v[:-1]
    if np.any(vsum <= 0):
        k = int(np.argmax(vsum <= 0))
        raise LimitError(f"the speed is zero on both ends of the path step at s={path.s_m[k]:.1f} m: "
                         "the vehicle would never arrive")
    t = np.concatenate([[0.0], np.cumsum(2.0 * ds / vsum)])
    n = max(int(round(t[-1] * knot_rate_hz)) + 1, 2)
    tk = np.linspace(0.0, t[-1], n)
    sk = np.interp(tk, t, path.s_m)
    heading0 = float(path.heading_rad[0])
    return ControlProfile(
        t_s=tk,
        speed_mps=np.interp(tk, t, v),
        curvature_1pm=np.interp(sk, path.s_m, path.curvature_1pm),
        grade_rad=np.interp(sk, path.s_m, path.grade_rad),
        start=(float(path.xyz_m[0, 0]), float(path.xyz_m[0, 1]), heading0),
        name=name,
    )


def travel_time_s(s_m: np.ndarray, speed_mps: np.ndarray) -> float:
    """Time to drive the path at ``speed_mps`` with constant acceleration between samples."""
    vsum = speed_mps[1:] + speed_mps[:-1]
    with np.errstate(divide="ignore"):
        return float(np.sum(np.where(vsum > 0, 2.0 * np.diff(s_m) / vsum, np.inf)))
