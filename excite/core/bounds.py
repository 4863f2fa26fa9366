"""Every sane range of an input number, and the work one route may cost, in one place.

A file of a few bytes can describe a drive of a million seconds or a coordinate of 1e300 m;
neither is a drive on Earth, and either would cost gigabytes or end in NaN deep inside the
model. The library checks its inputs against these tables *before* it allocates anything, at
every entry point (readers, :func:`~excite.motion.vehicle.drive`, :func:`~excite.score.evaluate.evaluate`,
rigs), and the error quotes the bound. The service states the same numbers in its OpenAPI
schema (:mod:`api.schemas` builds its fields from these tables) and may only tighten them.

To bound a new numeric rig key, add one line to :data:`RIG`: a glob over the dotted key (list
items are ``*``) → its range. ``tests/core/test_bounds.py`` fails for a numeric rig key without one.
"""

from __future__ import annotations

import fnmatch
import math
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Any, Callable, Iterator

# --------------------------------------------------------------------------------------------
# The work one route may cost (samples and keyframes are what memory and time scale with)

MAX_DURATION_S = 4 * 3600.0
"""Longest drive read, generated or scored [s] (split longer logs)."""
MAX_LENGTH_M = 200_000.0
"""Longest waypoint or GeoJSON path [m]."""
MAX_SAMPLES = 2_000_000
"""Most rows in one route file, and most samples of any grid a route is resampled on."""
MAX_KEYFRAMES = 200_000
"""Most keyframes of one evaluation (duration × keyframe rate)."""
MAX_IMU_SAMPLES = 20_000_000
"""Most IMU samples of one evaluation (duration × IMU rate)."""
MAX_SENSORS = 16
"""Most exteroceptive sensors on one rig."""
MAX_NESTING = 12
"""Deepest nesting of a rig document (the deepest real key, a rotation matrix entry, is 6)."""
# keys and list items in one rig document, all levels together (a rig of 16 sensors with
# targets and priors for each coordinate holds a few hundred): a bound on the work of checking it
MAX_RIG_NODES = 5000
"""Most keys and list items in one rig document."""
MAX_SCENE_TRIANGLES = 2_000_000
"""Most triangles of one scene (meshes, extruded vector scenes and the ground together)."""
MAX_SCENE_POINTS = 20_000_000
"""Most points of one point-cloud map."""
MAX_SCENE_EXTENT_M = 20_000.0
"""Largest horizontal extent of a scene [m] (a lot, a street, a test track)."""


_TIGHTER: ContextVar[dict[str, float]] = ContextVar("excite_bounds", default={})


def max_duration_s() -> float:
    """The duration bound in force: :data:`MAX_DURATION_S`, or tighter inside :func:`tightened`."""
    return min(MAX_DURATION_S, _TIGHTER.get().get("duration_s", math.inf))


def max_length_m() -> float:
    """The path length bound in force: :data:`MAX_LENGTH_M`, or tighter inside :func:`tightened`."""
    return min(MAX_LENGTH_M, _TIGHTER.get().get("length_m", math.inf))


@contextmanager
def tightened(*, duration_s: float | None = None, length_m: float | None = None) -> Iterator[None]:
    """Tighter work bounds for the code inside (a service's settings): every check then refuses
    before allocating, and quotes the tighter bound. Bounds can only be tightened."""
    new = dict(_TIGHTER.get())
    for key, value in (("duration_s", duration_s), ("length_m", length_m)):
        if value is not None:
            new[key] = min(value, new.get(key, math.inf))
    token = _TIGHTER.set(new)
    try:
        yield
    finally:
        _TIGHTER.reset(token)


@dataclass(frozen=True)
class Range:
    """A closed interval ``[lo, hi]`` of a quantity in ``unit``."""

    lo: float
    hi: float
    unit: str = ""

    def __str__(self) -> str:
        u = f" {self.unit}" if self.unit and self.unit != "1" else ""
        return f"[{self.lo:g}, {self.hi:g}]{u}"

    def contains(self, x: float) -> bool:
        return math.isfinite(x) and self.lo <= x <= self.hi

    def problem(self, x: Any) -> str | None:
        """Why ``x`` is not in range (None when it is)."""
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            return None
        if self.contains(float(x)):
            return None
        return f"{x!r} is outside the sane range {self}"


# --------------------------------------------------------------------------------------------
# Routes: every number a route file or a route request carries

ROUTE = {
    "t_s": Range(-1e11, 1e11, "s"),
    "position_m": Range(-1e8, 1e8, "m"),  # UTM, ECEF and local coordinates
    "altitude_m": Range(-1e5, 1e5, "m"),
    "speed_mps": Range(0.0, 100.0, "m/s"),
    "curvature_1pm": Range(-10.0, 10.0, "1/m"),
    "grade_rad": Range(-1.5, 1.5, "rad"),
    "bank_rad": Range(-1.5, 1.5, "rad"),
    "heading_rad": Range(-100.0, 100.0, "rad"),
    "quaternion": Range(-2.0, 2.0),
}

# Recorded signals in bags: GNSS fixes (sensor_msgs/NavSatFix) and a car's own signals (wheel
# speeds and steering as JointState, a radar's ego-velocity). Wheel speeds are rad/s or m/s as the
# topic says; a steering joint is a road-wheel or a steering-wheel angle (a few turns at most).
SIGNALS = {
    "latitude_deg": Range(-90.0, 90.0, "deg"),
    "longitude_deg": Range(-180.0, 180.0, "deg"),
    "altitude_m": ROUTE["altitude_m"],
    "position_covariance_m2": Range(-1e10, 1e10, "m^2"),
    "wheel_speed": Range(-1000.0, 1000.0, "rad/s or m/s"),
    "steering_rad": Range(-50.0, 50.0, "rad"),
    "ego_velocity_mps": Range(-150.0, 150.0, "m/s"),
    "velocity_covariance_m2ps2": Range(-1e6, 1e6, "m^2/s^2"),
}

# Vehicle and test limits (excite.motion.vehicle.Limits); positive, SI units.
LIMITS = {
    "speed_max_mps": Range(0.1, 100.0, "m/s"),
    "accel_max_mps2": Range(0.01, 50.0, "m/s^2"),
    "decel_max_mps2": Range(0.01, 50.0, "m/s^2"),
    "jerk_max_mps3": Range(0.01, 500.0, "m/s^3"),
    "lat_accel_max_mps2": Range(0.01, 50.0, "m/s^2"),
    "curvature_max_1pm": Range(1e-4, 10.0, "1/m"),
    "curvature_rate_max_1pms": Range(1e-4, 100.0, "1/(m s)"),
}

# Options of excite.score.evaluate.Options (rank_rtol belongs to the rank test and is checked there).
OPTIONS = {
    "segments": Range(0, 1000),
    "weak_below": Range(1e-12, 1e12),
    "max_modes": Range(1, 1000),
}

# Settings of excite.plan.OptimizeSettings.
OPTIMIZE = {
    "duration_s": Range(10.0, 600.0, "s"),
    "lot_x_m": Range(15.0, 2000.0, "m"),
    "lot_y_m": Range(15.0, 2000.0, "m"),
    "time_budget_s": Range(0.5, 3600.0, "s"),
    "n_random": Range(0, 10000),
    "seed": Range(0, 2**31 - 1),
}

# --------------------------------------------------------------------------------------------
# Rigs: glob over the dotted key → range. Densities are continuous-time (Kalibr units).

_POSE = {
    "translation_m.*": Range(-100.0, 100.0, "m"),
    "rpy_deg.*": Range(-360.0, 360.0, "deg"),
    "matrix.*.*": Range(-1.001, 1.001),
}

RIG: dict[str, Range] = {
    "keyframe_rate_hz": Range(0.1, 100.0, "Hz"),
    "vehicle.suspension.pitch_deg_per_mps2": Range(0.0, 10.0, "deg/(m/s^2)"),
    "vehicle.suspension.roll_deg_per_mps2": Range(0.0, 10.0, "deg/(m/s^2)"),
    "vehicle.axle_height_m": Range(0.05, 2.0, "m"),
    "sensors.*.beams.vertical_angles_deg.*": Range(-90.0, 90.0, "deg"),
    "sensors.*.beams.vertical_fov_deg.*": Range(-90.0, 90.0, "deg"),
    "vehicle.nonholonomic.lateral_noise_density": Range(1e-7, 10.0, "m/s/√Hz"),
    "vehicle.nonholonomic.vertical_noise_density": Range(1e-7, 10.0, "m/s/√Hz"),
    "sensors.*.rate_hz": Range(0.1, 100.0, "Hz"),
    **{f"vehicle.T_V_B.{k}": r for k, r in _POSE.items()},
    **{f"sensors.*.T_B_S.{k}": r for k, r in _POSE.items()},
}

# Accuracy targets and prior σ by SI unit (rig keys ``targets.*`` and ``priors.*``).
QUANTITY = {
    "m": Range(1e-9, 100.0, "m"),
    "rad": Range(1e-9, math.pi, "rad"),
    "s": Range(1e-9, 10.0, "s"),
    "rad/s": Range(1e-12, 10.0, "rad/s"),
    "m/s^2": Range(1e-9, 100.0, "m/s^2"),
    "1": Range(1e-9, 100.0),
}


def rig_range(key: str) -> Range | None:
    """The range of a dotted rig key (``sensors.0.rate_hz``); the most specific glob wins."""
    hits = [g for g in RIG if fnmatch.fnmatchcase(key, g)]
    return RIG[max(hits, key=len)] if hits else None


def rig_numbers(data: Any, prefix: str = "") -> list[tuple[str, float]]:
    """Every numeric leaf of a rig document as (dotted key, value), targets and priors aside."""
    out: list[tuple[str, float]] = []
    if isinstance(data, dict):
        for k, v in data.items():
            if not prefix and k in ("targets", "priors"):
                continue
            out += rig_numbers(v, f"{prefix}{k}.")
    elif isinstance(data, (list, tuple)):
        for i, v in enumerate(data):
            out += rig_numbers(v, f"{prefix}{i}.")
    elif isinstance(data, (int, float)) and not isinstance(data, bool):
        out.append((prefix[:-1], float(data)))
    return out


def size(data: Any, limit: int = MAX_RIG_NODES) -> int:
    """Keys and list items of a nested document, all levels, counted without recursion and at
    most ``limit + 1``."""
    n, level = 0, [data] if isinstance(data, (dict, list, tuple)) else []
    while level and n <= limit:
        n += sum(len(x) for x in level)
        level = [v for x in level for v in (x.values() if isinstance(x, dict) else x)
                 if isinstance(v, (dict, list, tuple))][:limit + 1]
    return min(n, limit + 1)


def nesting(data: Any, limit: int = MAX_NESTING) -> int:
    """Depth of nested mappings and lists (a scalar is 0), counted level by level without
    recursion, and at most ``limit + 1``."""
    depth, level = 0, [data] if isinstance(data, (dict, list, tuple)) else []
    while level and depth <= limit:
        depth += 1
        level = [v for x in level for v in (x.values() if isinstance(x, dict) else x)
                 if isinstance(v, (dict, list, tuple))]
    return depth


# --------------------------------------------------------------------------------------------
# Checks, raising the caller's error type


def check_range(table: dict[str, Range], name: str, value: Any, error: Callable[[str], Exception],
                label: str | None = None) -> None:
    """Raise ``error("<label>: <value> is outside the sane range [lo, hi] unit")``."""
    problem = table[name].problem(value)
    if problem is not None:
        raise error(f"{label or name}: {problem}")


def work_problem(duration_s: float, rate_hz: float, limit: int, what: str) -> str | None:
    """Why sampling ``duration_s`` at ``rate_hz`` is too much work (None when it is not)."""
    if not math.isfinite(duration_s) or duration_s > max_duration_s():
        return (f"the drive lasts {duration_s:.6g} s, over the limit of {max_duration_s():g} s "
                "(split longer drives)")
    n = duration_s * rate_hz
    if not math.isfinite(n) or n > limit:
        return (f"{duration_s:.6g} s at {rate_hz:.6g} Hz are {n:.3g} {what}, over the limit of "
                f"{limit:,}")
    return None


def describe() -> str:
    """The work bounds as one line (CLI help, README)."""
    return (f"routes up to {MAX_DURATION_S / 3600:g} h and {MAX_LENGTH_M / 1000:g} km, "
            f"{MAX_SAMPLES:,} rows or samples, {MAX_KEYFRAMES:,} keyframes, "
            f"{MAX_IMU_SAMPLES:,} IMU samples; rigs up to {MAX_SENSORS} sensors")
