"""A car's CAN wheel speeds and steering angle (Ackermann geometry), over each keyframe interval.

Four wheels roll where the body takes them. Between keyframes i and j the rear axle (origin of V)
travels ``Δs`` along its arc and turns by ``Δψ`` about the road normal (the wheel kinds' one
statement of the arc, :func:`excite.factors.wheel.axle_travel`). A contact point at ``(x, y)`` in
the road-aligned axle frame A (the rear wheels at ``(0, ±track_rear/2)``, the front ones at
``(wheelbase, ±track_front/2)``, y to the left) then travels

    d = √((Δs − y·Δψ)² + (x·Δψ)²)

(exact on an arc with no sideways slip of the rear axle: the front wheels run a longer path in a
turn, by ``½·wheelbase²·κ²`` per metre, which is what determines the wheelbase from the wheel
speeds). A wheel-speed reading is the wheel's angular rate times a radius: the interval's mean
reading is ``s·d/ΔT`` with ``speeds: mps`` (a speed the ECU computed with its own radius; ``s``
the wheel's scale factor ``wheel.scale_fl/fr/rl/rr``, nominally 1: its effective-radius error),
or ``d/(r·ΔT)`` with ``speeds: radps`` (``r`` its effective radius ``wheel.radius_fl/fr/rl/rr``).

The steering-wheel reading is ``ratio·δ + offset`` with the road-wheel angle of the bicycle model
``δ = atan(wheelbase·κ)``, ``κ = Δψ/Δs`` the curvature of the rear axle's path
(``steering.ratio``, ``steering.offset`` the reading when driving straight, positive to the left);
its interval mean is weighted by distance (what :func:`interval_means` computes from the
readings). Its residual is the kinematic relation itself, ``L·Δψ − Δs·tan((read − offset)/ratio)``
[m]: at speed the reading's difference to first order (its σ the reading's), at a standstill the
statement that the car does not yaw, and smooth in between (the reading's own form,
``atan(L·Δψ/Δs)``, is singular there); below ``steering.min_speed_mps`` its σ in that form no
longer shrinks with the travel (tyre scrub and compliance at walking pace).

One CAN stream carries both: ``wheel.time_offset`` shifts every reading (stamped t, it describes
the motion at ``t + t_d``), to first order through the change of each instantaneous reading over
the interval (its speed and yaw rate at the two keyframes; the steering's instantaneous curvature
``ω·u/(u² + v_min²)``, which fades below ``steering.min_speed_mps``). With ``vehicle.slip`` estimated the
speeds are multiplied by ``1 + slip·ā/g + scrub·(a_y/g)²``: ``wheel.slip`` as the encoders' (the
driven or braking tyre's slip ratio at 1 g of the interval's mean longitudinal acceleration ā)
and ``wheel.scrub``, the loaded tyres' shorter rolling radius in a turn, at 1 g of lateral
acceleration ``a_y = (Δs/ΔT)·(Δψ/ΔT)`` (CAN wheel speeds are precise enough to see it: a
physical simulator's 1 %/g² moved the scale factors by 4.5 σ when it was not modelled); both
nuisances of the drive, linearised at zero.

Noise is a density, so the information per second does not depend on the keyframe rate: white
noise of ``speed_noise_density`` [m/s/√Hz, or rad/s/√Hz] on each wheel's reading, and each
reading quantised to ``speed_quantum`` (a CAN wheel speed: 0.01 km/h); quantisation errors of
independent readings at ``rate_hz`` add ``quantum²/(12·rate_hz)`` to the density squared. The
interval mean then has ``σ² = (density² + quantum²/(12·rate))/ΔT``. The steering's likewise
(``noise_density_deg``, ``quantum_deg``). The steering's density also carries what the
kinematic relation leaves out (understeer and compliance at speed): on the comma2k19 minute the
reading scatters 0.4° about it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from ..core.bounds import Range
from ..core.lazy import ca
from ..core.schema import Model, PositiveFloat
from ..errors import RigError
from .base import ConfigView, Expr, FactorInputs, Kind, Quantity, RigView, SimulationView, Variant
from .wheel import G_MPS2, Travel, axle_travel, lateral_g

WHEELS = ("fl", "fr", "rl", "rr")  # the order of the readings, of the rows and of the coordinates
_EPS_M = 1e-6  # regularises a front wheel's path and the curvature at a standstill [m]
_EPS_SMOOTH = 1e-4  # [m per interval, or m/s]: the smooth |a| of a front wheel's path at a standstill


class SteeringConfig(Model):
    """The steering-wheel angle on CAN: ``ratio`` (steering-wheel angle per road-wheel angle),
    ``offset_deg`` (what it reads driving straight; positive to the left), white noise
    ``noise_density_deg`` [deg/√Hz] on the reading and its resolution ``quantum_deg``; below
    ``min_speed_mps`` a reading tells less and less about the motion. ``estimate``: the ratio and
    the offset. ``rate_max_deg_per_s``: how fast the steering wheel may turn (the driver's or the
    actuator's limit); the optimizer's curvature-rate limit is then the vehicle's
    (:func:`curvature_rate_max_1pms`). None: the planner's generic limit."""

    ratio: PositiveFloat
    offset_deg: float = Field(default=0.0, ge=-90.0, le=90.0)
    noise_density_deg: PositiveFloat
    quantum_deg: float = Field(default=0.0, ge=0.0, allow_inf_nan=False)
    min_speed_mps: PositiveFloat = 0.5
    rate_max_deg_per_s: PositiveFloat | None = None
    estimate: bool = True


class AckermannEstimate(Model):
    """What of the wheels is estimated: the four scale factors (or radii), the two tracks, the
    wheelbase and the CAN stream's time offset."""

    wheels: bool = True
    tracks: bool = True
    wheelbase: bool = True
    time_offset: bool = True


class AckermannConfig(Model):
    """Four wheel speeds (and the steering angle) on a car's CAN bus. ``speeds``: ``mps`` (the ECU
    reports speeds in m/s; their scale factors are estimated) or ``radps`` (angular rates; the
    effective radii ``radius_m``, one value or four [fl, fr, rl, rr], are estimated).
    ``rate_hz``: the stream's rate; ``speed_noise_density`` [m/s/√Hz or rad/s/√Hz]: white noise
    on each reading; ``speed_quantum`` [m/s or rad/s]: a reading's resolution (0: none)."""

    wheelbase_m: PositiveFloat
    track_front_m: PositiveFloat
    track_rear_m: PositiveFloat
    speeds: Literal["mps", "radps"] = "mps"
    radius_m: PositiveFloat | tuple[PositiveFloat, PositiveFloat, PositiveFloat, PositiveFloat] | None = None
    rate_hz: PositiveFloat
    speed_noise_density: PositiveFloat
    speed_quantum: float = Field(default=0.0, ge=0.0, allow_inf_nan=False)
    steering: SteeringConfig | None = None
    estimate: AckermannEstimate = AckermannEstimate()

    @model_validator(mode="after")
    def _radius_with_radps(self) -> "AckermannConfig":
        if self.speeds == "radps" and self.radius_m is None:
            raise ValueError("speeds: radps reads angular rates: give the wheels' radius_m (one value or "
                             "[fl, fr, rl, rr])")
        if self.speeds == "mps" and self.radius_m is not None:
            raise ValueError("radius_m applies to speeds: radps (with speeds: mps the scale factors are "
                             "estimated, nominally 1)")
        return self

    @property
    def radii_m(self) -> tuple[float, float, float, float]:
        r = self.radius_m
        return tuple(float(x) for x in (r if isinstance(r, tuple) else (r,) * 4))

    def geometry(self) -> np.ndarray:
        """``(x, y)`` of each contact point in A [m], in the order of :data:`WHEELS`."""
        L, f, r = self.wheelbase_m, 0.5 * self.track_front_m, 0.5 * self.track_rear_m
        return np.array([[L, f], [L, -f], [0.0, r], [0.0, -r]])


def curvature_rate_max_1pms(ac: AckermannConfig) -> float | None:
    """The largest curvature rate [1/(m·s)] that never turns the steering wheel faster than
    ``steering.rate_max_deg_per_s`` (None without one). The bicycle model's reading
    ``ratio·atan(L·κ)`` changes at ``ratio·L·κ̇/(1 + L²κ²)``, fastest for a given κ̇ when driving
    straight: ``κ̇_max = rate_max/(ratio·L)`` is the vehicle's limit there, and conservative in a
    turn (by ``1 + L²κ²``: 24 % at κ = 0.18 1/m on a 2.7 m wheelbase)."""
    st = ac.steering
    if st is None or st.rate_max_deg_per_s is None:
        return None
    return math.radians(st.rate_max_deg_per_s) / (st.ratio * ac.wheelbase_m)


def speed_sigma(ac: AckermannConfig, interval_s: float) -> float:
    """σ of one wheel's mean reading over ``interval_s`` (white noise and quantisation)."""
    return math.sqrt((ac.speed_noise_density ** 2 + ac.speed_quantum ** 2 / (12.0 * ac.rate_hz)) / interval_s)


def steering_sigma_rad(ac: AckermannConfig, interval_s: float) -> float:
    """σ of the steering reading's mean over ``interval_s`` at speed [rad at the steering wheel]."""
    st = ac.steering
    d, q = math.radians(st.noise_density_deg), math.radians(st.quantum_deg)
    return math.sqrt((d * d + q * q / (12.0 * ac.rate_hz)) / interval_s)


def contact_distance(x, y, ds, dpsi, lat=0.0):
    """How far a contact point at ``(x, y)`` in A rolls when the axle travels ``ds`` forward and
    ``lat`` sideways and turns by ``dpsi`` (SX; or rates: its speed): ``√(a² + b²)`` with
    ``a = ds − y·dpsi``, ``b = lat + x·dpsi``, written ``a + b²/(|a| + √(a² + b²))`` with smooth
    absolute values (exact when moving forward; linear in ``a`` through a standstill, where a
    noisy travel may be slightly negative: no kink for a solver to stall on; reversing is not
    modelled)."""
    a = ds - y * dpsi
    b = lat + x * dpsi
    eps2 = _EPS_SMOOTH ** 2
    return a + b * b / (ca.sqrt(a * a + eps2) + ca.sqrt(a * a + b * b + eps2))


@dataclass(frozen=True)
class CanRecording:
    """What the CAN stream recorded: readings stamped ``t`` [s], each the mean over the time since
    the previous stamp (``first_period_s`` for the first): wheel ``speeds`` (M × 4, [fl, fr, rl,
    rr], the rig's unit) and the steering-wheel angle ``steering_rad`` (M, or None)."""

    t: np.ndarray
    speeds: np.ndarray
    steering_rad: np.ndarray | None
    first_period_s: float


def interval_means(rec: CanRecording, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """The readings' means over the intervals between consecutive ``edges`` [s]: the wheel
    speeds weighted by time (each reading holds over the time since the previous stamp), the
    steering weighted by the distance the rear wheels report (the model's curvature is the path's,
    ``Δψ/Δs``), by time where they report none. Intervals the readings do not cover are NaN."""
    t = np.asarray(rec.t, dtype=float)
    edges = np.asarray(edges, dtype=float)
    start = np.r_[t[0] - rec.first_period_s, t[:-1]]
    k = np.clip(np.searchsorted(t, edges, side="left"), 0, t.size - 1)  # the reading covering each edge
    inside = np.clip(edges - start[k], 0.0, None)

    def integral(values: np.ndarray) -> np.ndarray:
        """∫ of the piecewise-constant readings from the first one's start to each edge."""
        v = values.reshape(t.size, -1)
        cum = np.concatenate([np.zeros((1, v.shape[1])), np.cumsum(v * (t - start)[:, None], axis=0)])
        return cum[k] + v[k] * inside[:, None]

    covered = (edges >= start[0] - 1e-9) & (edges <= t[-1] + 1e-9)
    ok = covered[:-1] & covered[1:]
    dT = np.diff(edges)
    speeds = np.diff(integral(rec.speeds), axis=0) / dT[:, None]
    speeds[~ok] = np.nan
    if rec.steering_rad is None:
        return speeds, None
    rear = 0.5 * (rec.speeds[:, 2] + rec.speeds[:, 3])
    dist = np.diff(integral(rear), axis=0)[:, 0]
    timed = np.diff(integral(rec.steering_rad), axis=0)[:, 0] / dT
    weighted = np.diff(integral(rec.steering_rad * rear), axis=0)[:, 0]
    moving = np.abs(dist) > 1e-6 * dT
    steer = np.where(moving, weighted / np.where(moving, dist, 1.0), timed)
    steer[~ok] = np.nan
    return speeds, steer


_ADVICE = {
    ("scale_factor", None): ("wheel scale factors: drive at several speeds and several curvatures, left, right "
                             "and straight; one constant curvature couples them with the tracks and the wheelbase",
                             "needs several curvatures: turn left, turn right, drive straight"),
    ("radius", None): ("wheel radii: drive at several speeds and several curvatures, left, right and straight; one "
                       "constant curvature couples them with the tracks and the wheelbase",
                       "needs several curvatures: turn left, turn right, drive straight"),
    ("track", None): ("wheel track: turn both ways; straight driving says nothing about it",
                      "needs turns: turn both ways"),
    ("wheelbase", None): ("wheelbase: turn at speed (the front wheels run a longer path in a turn); straight "
                          "driving says nothing about it", "needs turns at speed"),
    ("ratio", None): ("steering ratio: turn at several curvatures; straight driving says nothing about it",
                      "needs turns of several curvatures"),
    ("offset", None): ("steering offset: drive straight and turn both ways; turns one way couple it with the "
                       "steering ratio", "needs straight driving and turns both ways"),
    ("time_offset", None): ("CAN time offset: change speed and turn rate (stop-and-go, a slalom); constant "
                            "velocity hides it", "needs changing speed and turn rate: stop-and-go, a slalom"),
}


class Ackermann(Kind[AckermannConfig]):
    name = "ackermann"
    arity = 2
    rows = 5  # four wheel speeds, the steering angle (4 without steering)
    section = "ackermann"
    config = AckermannConfig
    ranges = {"wheelbase_m": Range(0.3, 20.0, "m"), "track_front_m": Range(0.1, 5.0, "m"),
              "track_rear_m": Range(0.1, 5.0, "m"), "radius_m": Range(0.05, 5.0, "m"),
              **{f"radius_m.{i}": Range(0.05, 5.0, "m") for i in range(4)},
              "rate_hz": Range(1.0, 10_000.0, "Hz"), "speed_noise_density": Range(1e-7, 10.0, "(m/s or rad/s)/√Hz"),
              "speed_quantum": Range(0.0, 1.0, "m/s or rad/s"), "steering.ratio": Range(1.0, 100.0),
              "steering.offset_deg": Range(-90.0, 90.0, "deg"),
              "steering.noise_density_deg": Range(1e-6, 90.0, "deg/√Hz"), "steering.quantum_deg": Range(0.0, 10.0, "deg"),
              "steering.offset_deg": Range(-90.0, 90.0, "deg"),
              "steering.min_speed_mps": Range(0.01, 50.0, "m/s"),
              "steering.rate_max_deg_per_s": Range(1.0, 3600.0, "deg/s")}
    advice = _ADVICE

    def quantities(self, cfg: ConfigView, ac: AckermannConfig) -> list[Quantity]:
        if getattr(cfg, "wheels", None) is not None:
            raise RigError("ackermann: a rig has rear-axle encoders (wheels) or a car's CAN wheel speeds "
                           "(ackermann), not both")
        est = ac.estimate
        if ac.speeds == "mps":
            wheels = [Quantity("wheel", "scale_factor", 1, "1", 1.0, est.wheels, names=(f"wheel.scale_{w}",),
                               key=f"scale_{w}", axis=i, per_entry=False) for i, w in enumerate(WHEELS)]
        else:
            wheels = [Quantity("wheel", "radius", 1, "m", r, est.wheels, names=(f"wheel.radius_{w}",),
                               key=f"radius_{w}", axis=i) for i, (w, r) in enumerate(zip(WHEELS, ac.radii_m))]
        out = wheels + [
            Quantity("wheel", "track", 1, "m", ac.track_front_m, est.tracks, names=("wheel.track_front",),
                     key="track_front", axis=0),
            Quantity("wheel", "track", 1, "m", ac.track_rear_m, est.tracks, names=("wheel.track_rear",),
                     key="track_rear", axis=1),
            Quantity("wheel", "wheelbase", 1, "m", ac.wheelbase_m, est.wheelbase)]
        st = ac.steering
        if st is not None:
            out += [Quantity("steering", "ratio", 1, "1", st.ratio, st.estimate),
                    Quantity("steering", "offset", 1, "rad", math.radians(st.offset_deg), st.estimate)]
        return out + [Quantity("wheel", "time_offset", 1, "s", 0.0, est.time_offset, per_entry=False),
                      Quantity("wheel", "slip", 1, "1", 0.0, cfg.vehicle.slip.estimate, nuisance=True, per_entry=False),
                      Quantity("wheel", "scrub", 1, "1", 0.0, cfg.vehicle.slip.estimate, nuisance=True,
                               per_entry=False)]

    # --- the math ---

    def variant(self, ac: AckermannConfig) -> Variant:
        """The readings' unit (``mps``: scale factors; ``radps``: radii) and whether the steering is read."""
        return (ac.speeds, "steering" if ac.steering is not None else "no_steering")

    def constants(self, rig: RigView, ac: AckermannConfig) -> dict[str, float]:
        dT = 1.0 / rig.keyframe_rate_hz
        out = {"sigma_speed": speed_sigma(ac, dT)}
        if ac.steering is not None:
            out.update(sigma_steering=steering_sigma_rad(ac, dT), min_speed=ac.steering.min_speed_mps)
        return out

    def _gain(self, f: FactorInputs, i: int) -> Expr:
        """Reading per m/s of contact-point speed of wheel ``i``."""
        w = WHEELS[i]
        return f.q[f"scale_{w}"] if f.variant[0] == "mps" else 1.0 / f.q[f"radius_{w}"]

    def _speeds(self, f: FactorInputs, tr: Travel) -> list:
        """The four wheels' mean readings over the interval (the measurement's first rows)."""
        L, dT = f.q["wheelbase"], f.dT
        xy = [(L, 0.5 * f.q["track_front"]), (L, -0.5 * f.q["track_front"]),
              (0.0, 0.5 * f.q["track_rear"]), (0.0, -0.5 * f.q["track_rear"])]
        td = f.q["time_offset"]
        lateral = lateral_g(tr.ds, tr.dpsi, dT)  # the interval's lateral acceleration in g
        slip = 1.0 + f.q["slip"] * tr.along + f.q["scrub"] * lateral * lateral
        out = []
        for i, (x, y) in enumerate(xy):
            mean = contact_distance(x, y, tr.ds, tr.dpsi, tr.lat) / dT
            ends = [contact_distance(x, y, tr.u[a], tr.yaw_rate[a], tr.v_lat[a]) for a in range(2)]  # instantaneous
            out.append(self._gain(f, i) * (mean + td * (ends[1] - ends[0]) / dT) * slip)
        return out

    @staticmethod
    def _curvature(f: FactorInputs, tr: Travel) -> tuple[Expr, Expr]:
        """The path's curvature the reading sees, ``Δψ/Δs`` moved by ``t_d`` along its change
        (the instantaneous curvatures at the two keyframes), and that change per second. The
        instantaneous curvature ``ω·u/(u² + v_min²)`` fades below ``steering.min_speed_mps``:
        ``ω/u`` of a crawling car is a ratio of two noises (an estimate at 1 cm/s off a
        standstill made the time-offset term, and the calibrator's cost, swing by whole units
        within a hundredth of its step)."""
        v_min = f.c["min_speed"]
        ends = [tr.yaw_rate[a] * tr.u[a] / (tr.u[a] * tr.u[a] + v_min ** 2) for a in range(2)]
        rate = (ends[1] - ends[0]) / f.dT
        return tr.dpsi * tr.ds / (tr.ds * tr.ds + _EPS_M ** 2) + f.q["time_offset"] * rate, rate

    def measurement(self, f: FactorInputs) -> Expr:
        tr = axle_travel(f)
        out = self._speeds(f, tr)
        if f.variant[1] == "steering":
            kappa, _ = self._curvature(f, tr)
            out.append(f.q["ratio"] * ca.atan(f.q["wheelbase"] * kappa) + f.q["offset"])
        return ca.vertcat(*out)

    def residual(self, f: FactorInputs, meas: Expr) -> Expr:
        """The speeds' ``predicted − read``; the steering's in the kinematic form
        ``L·(Δψ + t_d·Δs·κ̇) − Δs·tan((read − offset)/ratio)`` [m], zero at its measurement like
        the reading's difference and, unlike it, smooth at a standstill (where the reading says
        only that the car does not yaw)."""
        tr = axle_travel(f)
        speeds = ca.vertcat(*self._speeds(f, tr)) - meas[0:4]
        if f.variant[1] != "steering":
            return speeds
        _, rate = self._curvature(f, tr)
        L = f.q["wheelbase"]
        turn = L * (tr.dpsi * tr.ds * tr.ds / (tr.ds * tr.ds + _EPS_M ** 2) + f.q["time_offset"] * tr.ds * rate)
        return ca.vertcat(speeds, turn - tr.ds * ca.tan((meas[4] - f.q["offset"]) / f.q["ratio"]))

    def sqrt_information(self, f: FactorInputs) -> Expr:
        """The speeds' ``1/σ``; the steering row's ``ratio·cos²δ / (σ·√(Δs² + (v_min·ΔT)²))``: at
        speed the reading's ``1/σ`` (the form's derivative in the reading is ``−Δs·sec²δ/ratio``),
        below ``v_min`` a turn-per-interval whose σ no longer shrinks with the travel."""
        w = [1.0 / f.c["sigma_speed"]] * 4
        if f.variant[1] != "steering":
            return ca.vertcat(*w)
        tr = axle_travel(f)
        kappa, _ = self._curvature(f, tr)
        cos2 = 1.0 / (1.0 + (f.q["wheelbase"] * kappa) ** 2)
        floor = f.c["min_speed"] * f.dT
        return ca.vertcat(*w, f.q["ratio"] * cos2 / (f.c["sigma_steering"] * ca.sqrt(tr.ds * tr.ds + floor * floor)))

    # --- simulation ---

    def simulate(self, sim: SimulationView, ac: AckermannConfig) -> np.ndarray:
        """Every keyframe interval's mean readings (N × 4, or 5 with the steering). Physical: the
        CAN stream at ``rate_hz`` (:func:`physical_stream`), each reading the mean of its wheel's
        true contact-point speed over its period (tyre slip as the encoders' physical simulator has
        it: linear in the longitudinal acceleration plus a scrub with the square of the lateral
        one), the steering the true ratio times the bicycle model's road-wheel angle of the true
        path's curvature plus the offset, all seen at ``t + t_d``, with white noise of the densities
        and each reading quantised; then their means over the intervals (:func:`interval_means`).
        Model: the measurement model at the truth plus white noise of its σ (the steering's at most
        10 σ at a standstill, where the model's grows without bound)."""
        nom, rng = sim.nom, sim.rng
        if sim.settings.physical:
            speeds, steer = interval_means(physical_stream(sim, ac), nom.t)
            return speeds if steer is None else np.column_stack([speeds, steer])
        m = sim.measured(self, ac)
        if not sim.noisy:
            return m
        dT = float(nom.t[1] - nom.t[0])
        sig = np.full(m.shape, speed_sigma(ac, dT))
        if ac.steering is not None:
            ds = _travel(nom, np.arange(m.shape[0]))
            floor = ac.steering.min_speed_mps * dT
            # at a near standstill the model's σ grows without bound (the reading tells nothing
            # there); drawing that noise would make a residual the calibrator can only shrink by
            # moving the weight (the travel): the draw is capped at 10 σ, the weight stays the model's
            base = steering_sigma_rad(ac, dT)
            sig[:, 4] = np.minimum(base * np.sqrt(1.0 + (floor / np.maximum(np.abs(ds), 1e-9)) ** 2), 10.0 * base)
        return m + rng.normal(0.0, 1.0, m.shape) * sig


def _travel(nom, first: np.ndarray) -> np.ndarray:
    """The rear axle's travel over the intervals starting at ``first`` (numpy, the nominal
    motion's chord along A: what sets the steering's weight)."""
    from .wheel import axle_geometry

    p_BV, R_BA = axle_geometry(nom)
    RA = nom.R @ R_BA
    pV = nom.p + np.einsum("kij,j->ki", nom.R, p_BV)
    return np.einsum("kji,kj->ki", RA[first], pV[first + 1] - pV[first])[:, 0]


def physical_stream(sim, ac: AckermannConfig) -> CanRecording:
    """The physical simulator's CAN stream (see :meth:`Ackermann.simulate`)."""
    nom, rng, truth, settings = sim.nom, sim.rng, sim.truth, sim.settings
    h = 1.0 / ac.rate_hz
    t0, t1 = float(nom.t[0]), float(nom.t[-1])
    stamps = t0 + h * np.arange(1, int(np.ceil((t1 - t0) / h - 1e-9)) + 1)  # the last covers the drive's end
    td = truth.scalar("wheel", "time_offset")
    over = max(settings.imu_oversampling, 8)
    fine = np.linspace(t0 + td - h, stamps[-1] + td, stamps.size * over + over + 1)
    smp = sim.traj.sample(fine)
    u = np.einsum("nji,nj->ni", smp.R_W_A, smp.v_W)
    yaw = smp.yaw_rate
    g = G_MPS2
    kappa_slip = settings.wheel_slip_per_g * smp.accel_long / g + settings.wheel_scrub_per_g2 * (smp.accel_lat / g) ** 2
    L = truth.scalar("wheel", "wheelbase")
    xy = [(L, 0.5 * truth.scalar("wheel", "track_front")), (L, -0.5 * truth.scalar("wheel", "track_front")),
          (0.0, 0.5 * truth.scalar("wheel", "track_rear")), (0.0, -0.5 * truth.scalar("wheel", "track_rear"))]
    speed = np.stack([np.hypot(u[:, 0] - y * yaw, u[:, 1] + x * yaw) for x, y in xy], axis=1) * (1.0 + kappa_slip)[:, None]
    if ac.speeds == "mps":
        gain = np.array([truth.scalar("wheel", f"scale_{w}") for w in WHEELS])
    else:
        gain = 1.0 / np.array([truth.scalar("wheel", f"radius_{w}") for w in WHEELS])

    def boxcar(x: np.ndarray) -> np.ndarray:
        """Means over (stamp − h, stamp] seen at stamp + t_d, of ``x`` on the fine grid."""
        v = x.reshape(fine.size, -1)
        cum = np.concatenate([np.zeros((1, v.shape[1])), np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(fine)[:, None], axis=0)])
        at = lambda s: np.column_stack([np.interp(s, fine, c) for c in cum.T])  # noqa: E731
        return ((at(stamps + td) - at(stamps + td - h)) / h).reshape((stamps.size,) + x.shape[1:])

    readings = boxcar(speed) * gain
    if sim.noisy:
        readings = readings + rng.normal(0.0, ac.speed_noise_density / math.sqrt(h), readings.shape)
    if ac.speed_quantum > 0:
        readings = np.round(readings / ac.speed_quantum) * ac.speed_quantum
    steer = None
    st = ac.steering
    if st is not None:
        v = u[:, 0]
        kappa = yaw * v / (v * v + 0.005 ** 2)  # at a standstill the driver holds it straight
        delta = np.arctan(L * kappa)
        steer = truth.scalar("steering", "ratio") * boxcar(delta) + truth.scalar("steering", "offset")
        if sim.noisy:
            steer = steer + rng.normal(0.0, math.radians(st.noise_density_deg) / math.sqrt(h), steer.shape)
        if st.quantum_deg > 0:
            q = math.radians(st.quantum_deg)
            steer = np.round(steer / q) * q
    return CanRecording(stamps, readings, steer, h)
