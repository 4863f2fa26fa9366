"""Ground-vehicle kinematics: control profiles, suspension, limits.

A :class:`ControlProfile` gives speed(t), curvature(t) and optionally road grade(t) and bank(t)
at knots; :func:`drive` integrates it into a :class:`~excite.motion.trajectory.Trajectory` of the
rear-axle frame, tilting the sprung body by the :class:`Suspension` gains so that braking pitches
the nose down and cornering rolls the body outwards, as on a real car.
:func:`check_limits` reports every :class:`Limits` violation of any trajectory: which limit, by
how much, where.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from ..core import bounds, so3
from ..errors import LimitError, RouteError
from .trajectory import GRAVITY, MotionSamples, Trajectory

_GRID_HZ = 100.0  # internal integration grid of generated drives


@dataclass(frozen=True)
class Suspension:
    """Quasi-static body tilt per unit acceleration (typical passenger car by default).

    ``pitch_deg_per_mps2``: nose-down pitch per m/s² of deceleration.
    ``roll_deg_per_mps2``: outward roll per m/s² of lateral acceleration.
    """

    pitch_deg_per_mps2: float = 0.3
    roll_deg_per_mps2: float = 0.5

    @classmethod
    def rigid(cls) -> "Suspension":
        """No suspension: the body stays aligned with the road."""
        return cls(0.0, 0.0)


@dataclass(frozen=True)
class Limits:
    """What the vehicle and the test engineer allow. Positive numbers, SI units."""

    speed_max_mps: float = 15.0
    accel_max_mps2: float = 3.0
    decel_max_mps2: float = 4.0
    jerk_max_mps3: float = 6.0
    lat_accel_max_mps2: float = 4.0
    curvature_max_1pm: float = 0.18
    curvature_rate_max_1pms: float = 0.25

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise LimitError(f"limits.{name} must be a number, got {value!r}")
            bounds.check_range(bounds.LIMITS, name, float(value), LimitError, f"limits.{name}")


@dataclass(frozen=True)
class Violation:
    """The worst excess of one limit over a drive."""

    limit: str
    bound: float
    value: float
    t_s: float
    x_m: float
    y_m: float
    duration_s: float  # total time spent beyond the bound

    @property
    def excess(self) -> float:
        return abs(self.value) - self.bound

    def __str__(self) -> str:
        return (f"{self.limit}: {self.value:+.3g} exceeds ±{self.bound:.3g} by {self.excess:.3g} "
                f"at t={self.t_s:.2f} s (x={self.x_m:.1f} m, y={self.y_m:.1f} m), "
                f"{self.duration_s:.2f} s beyond the limit in all")


@dataclass(frozen=True)
class ControlProfile:
    """Controls at knots ``t_s``; interpolated shape-preserving (PCHIP) in between.

    ``speed_mps`` ≥ 0, ``curvature_1pm`` (positive = left turn), ``grade_rad`` (positive = uphill),
    ``bank_rad`` (road roll about the forward axis, positive = left side up). ``start`` is the
    initial (x, y, heading) [m, m, rad].
    """

    t_s: np.ndarray
    speed_mps: np.ndarray
    curvature_1pm: np.ndarray
    grade_rad: np.ndarray | None = None
    bank_rad: np.ndarray | None = None
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name: str = "profile"

    def __post_init__(self) -> None:
        t = np.asarray(self.t_s, dtype=float)
        object.__setattr__(self, "t_s", t)
        if t.ndim != 1 or t.size < 2:
            raise RouteError(f"a control profile needs at least 2 knots, got {t.size}")
        if not np.all(np.diff(t) > 0):
            raise RouteError("control profile times must be strictly increasing")
        for name in ("speed_mps", "curvature_1pm", "grade_rad", "bank_rad"):
            value = getattr(self, name)
            if value is None:
                value = np.zeros_like(t)
            value = np.asarray(value, dtype=float)
            if value.shape != t.shape:
                raise RouteError(f"control profile {name} has {value.size} values for {t.size} knots")
            if not np.all(np.isfinite(value)):
                raise RouteError(f"control profile {name} contains NaN or inf")
            object.__setattr__(self, name, value)
        if np.any(self.speed_mps < 0):
            raise RouteError("control profile speed must be ≥ 0 (reversing is not modelled)")
        if not self.duration_s <= bounds.max_duration_s():
            raise RouteError(f"the control profile lasts {self.duration_s:.6g} s, over the limit of "
                             f"{bounds.max_duration_s():g} s")

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    def at(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """Interpolated controls and the speed derivative at times ``t``."""
        out = {}
        for name in ("speed_mps", "curvature_1pm", "grade_rad", "bank_rad"):
            out[name] = PchipInterpolator(self.t_s, getattr(self, name))(t)
        out["accel_mps2"] = PchipInterpolator(self.t_s, self.speed_mps).derivative()(t)
        return out


def drive(profile: ControlProfile, suspension: Suspension = Suspension(), rate_hz: float = _GRID_HZ) -> Trajectory:
    """Integrate a control profile into the trajectory of the rear-axle frame V, on a grid of
    ``rate_hz`` (the trajectory's splines pass through it: a coarser grid is a cheaper, slightly
    smoother drive, e.g. to screen many candidates)."""
    n = max(int(round(profile.duration_s * rate_hz)) + 1, 6)
    t = np.linspace(profile.t_s[0], profile.t_s[-1], n)
    c = profile.at(t)
    u, kappa = c["speed_mps"], c["curvature_1pm"]
    yaw_rate = u * kappa
    # the trapezoid rule (scipy.integrate.cumulative_trapezoid's arithmetic; scipy.integrate
    # would be imported for this line alone)
    yaw = profile.start[2] + np.concatenate([[0.0], np.cumsum(np.diff(t) * (yaw_rate[1:] + yaw_rate[:-1]) / 2.0)])
    R_W_A = so3.rot_z(yaw) @ so3.rot_y(-c["grade_rad"]) @ so3.rot_x(c["bank_rad"])
    v_W = u[:, None] * R_W_A[:, :, 0]
    pitch = -np.deg2rad(suspension.pitch_deg_per_mps2) * c["accel_mps2"]
    roll = np.deg2rad(suspension.roll_deg_per_mps2) * u**2 * kappa
    R_W_V = R_W_A @ so3.rot_y(pitch) @ so3.rot_x(roll)
    p0 = np.zeros((n, 3))
    p0[0, :2] = profile.start[:2]
    return Trajectory(t, R_W_V, p0, tilt_pitch_roll=np.stack([pitch, roll], axis=1), velocity=v_W,
                      name=profile.name)


def curvature(s: MotionSamples, min_speed_mps: float = 0.5) -> np.ndarray:
    """Path curvature [1/m] (NaN where the vehicle is slower than ``min_speed_mps``)."""
    u = s.speed
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.abs(u) >= min_speed_mps, s.yaw_rate / u, np.nan)


# What no road vehicle does: beyond these, a logged drive is a pose jump, a mapping error (the
# wrong axes) or not a car, and the information model (a car on wheels) does not describe it.
PLAUSIBLE_SPEED_MPS = 70.0  # 252 km/h, forward or backward
PLAUSIBLE_ACCEL_MPS2 = 15.0  # 1.5 g in the road plane (tyres give ~1 g)
PLAUSIBLE_TILT_DEG = 35.0  # pitch or roll (the steepest roads are ~20°)


def implausible(traj: Trajectory, rate_hz: float = 10.0) -> list[str]:
    """What in ``traj`` no road vehicle does (speed, acceleration in the road plane, pitch or
    roll beyond the ``PLAUSIBLE_*`` bounds): one sentence per quantity, at its worst moment."""
    t = traj.times(rate_hz)
    R, _, f = traj.imu(t, np.eye(3), np.zeros(3))  # V's orientation and specific force (compiled: cheap)
    ypr = so3.yaw_pitch_roll(R)
    speed = np.einsum("nji,nj->ni", R, traj.velocity(t))[:, 0]  # along V's x axis
    a_V = f + np.einsum("nji,j->ni", R, GRAVITY)  # Rᵀ a: the acceleration in V's axes
    checks = [("speed", speed, PLAUSIBLE_SPEED_MPS, " m/s", "a pose jump?"),
              ("acceleration", np.hypot(a_V[:, 0], a_V[:, 1]), PLAUSIBLE_ACCEL_MPS2, " m/s²", "a pose jump?"),
              ("pitch", np.degrees(ypr[:, 1]), PLAUSIBLE_TILT_DEG, "°", "not a car, or the wrong axes (--axes)?"),
              ("roll", np.degrees(ypr[:, 2]), PLAUSIBLE_TILT_DEG, "°", "not a car, or the wrong axes (--axes)?")]
    out = []
    for name, x, bound, unit, why in checks:
        k = int(np.argmax(np.abs(x)))
        if abs(x[k]) > bound:
            out.append(f"{name} {x[k]:.3g}{unit} at t = {t[k] - traj.t_start:.1f} s is beyond what a road "
                       f"vehicle does (±{bound:g}{unit}): {why} The numbers assume a car.")
    return out


def check_limits(traj: Trajectory, limits: Limits, rate_hz: float = 20.0) -> list[Violation]:
    """Every limit the drive exceeds, each with its worst value, where, and for how long."""
    t = traj.times(rate_hz)
    s = traj.sample(t)
    a_long = s.accel_long
    kappa = curvature(s)
    quantities = {
        "speed_max_mps": (s.speed, limits.speed_max_mps),
        "accel_max_mps2": (np.maximum(a_long, 0.0), limits.accel_max_mps2),
        "decel_max_mps2": (np.minimum(a_long, 0.0), limits.decel_max_mps2),
        "jerk_max_mps3": (np.gradient(a_long, t), limits.jerk_max_mps3),
        "lat_accel_max_mps2": (s.accel_lat, limits.lat_accel_max_mps2),
        "curvature_max_1pm": (np.nan_to_num(kappa), limits.curvature_max_1pm),
        # Differentiate only where the curvature is defined on both sides: zero-filling first
        # would report a jump to 0 at the low-speed threshold as a curvature-rate violation.
        "curvature_rate_max_1pms": (np.nan_to_num(np.gradient(kappa, t)),
                                    limits.curvature_rate_max_1pms),
    }
    # A small tolerance keeps drives generated exactly at a limit from being reported.
    out = []
    for name, (q, bound) in quantities.items():
        over = np.abs(q) > bound * (1.0 + 1e-3) + 1e-9
        if not over.any():
            continue
        k = int(np.argmax(np.abs(q)))
        out.append(Violation(name, bound, float(q[k]), float(t[k]), float(s.p_W_V[k, 0]),
                             float(s.p_W_V[k, 1]), float(over.sum() / rate_hz)))
    return out
