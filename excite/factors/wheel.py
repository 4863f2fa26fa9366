"""Wheel-encoder increments over each keyframe interval.

The rear axle (origin of V) travels ``Δs`` forward and turns ``Δψ`` about the road normal between
keyframes i and j, both taken in the road-aligned axle frame A (the body frame without its
suspension tilt):

    Δψ = e_zᵀ Log(R_W_A,iᵀ R_W_A,j),   Δs = a(Δψ) · m(Δψ)ᵀ R_W_A,iᵀ (p_V,j − p_V,i)

with ``m = (cos Δψ/2, sin Δψ/2, 0)`` along the mean heading (``mᵀc`` is the chord) and
``a(Δψ) = (Δψ/2) / sin(Δψ/2)`` the ratio of a circular arc to its chord: wheels roll along the arc.
(With the chord, a constant-curvature drive — whose radii/track combination is exactly
undetermined — came out weakly determined by an O(Δψ²) artefact that shrank with the keyframe
rate.) The left and right wheels
turn by ``(Δs ∓ ½·track·Δψ) / radius_{left,right}`` radians, each with noise
``noise_density·√Δt``.

Tyres slip: a driven wheel turns faster than it travels, a braking one slower. With
``vehicle.slip`` estimated, both angles are multiplied by ``1 + slip·ā/g``, ``ā`` the interval's
mean longitudinal acceleration ``mᵀ R_W_A,iᵀ (v_V,j − v_V,i) / ΔT`` along the interval's mean
heading (the axle's velocity ``v_V = v + R_W_B (ω_B × p_B_V)``) and ``slip`` (``wheel.slip``, the
slip ratio at 1 g) a nuisance of the drive, linearised at zero. Loaded sideways, a tyre rolls on a
shorter radius: the factor is also ``1 + … + scrub·(a_y/g)²`` with the interval's lateral
acceleration ``a_y = (Δs/ΔT)·(Δψ/ΔT)`` and ``scrub`` (``wheel.scrub``, at 1 g) a second nuisance,
as the Ackermann kind's. Unmodelled, the physical simulator's 1 %/g² biased both radii of an
optimized 90 s plan by −2 σ (its NEES 30.5 for 23): the constant radii absorbed the drive's
distance-weighted mean (a_y/g)².
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.bounds import Range
from ..core.lazy import ca
from ..core.schema import Model, PositiveFloat
from ..motion.trajectory import GRAVITY, Trajectory
from .base import ConfigView, Expr, FactorInputs, Kind, Nominal, Quantity, RigView, SimulationView
from .symbolic import log

G_MPS2 = float(-GRAVITY[2])  # [m/s²]: slip is stated per g


class WheelConfig(Model):
    """Wheel encoders on the rear axle. ``noise_density`` [rad/s/√Hz]: white noise on each
    wheel's measured rate (quantisation, slip), so that a rotation increment over Δt has
    σ = noise_density·√Δt whatever the keyframe rate (the gyroscope's convention, Kalibr's units)."""

    radius_left_m: PositiveFloat
    radius_right_m: PositiveFloat
    track_m: PositiveFloat
    noise_density: PositiveFloat
    estimate: bool = True


def increment_sigma_rad(wheels: WheelConfig, keyframe_rate_hz: float) -> float:
    """σ of one wheel's rotation increment over a keyframe interval [rad]."""
    return wheels.noise_density / float(np.sqrt(keyframe_rate_hz))


class Wheel(Kind[WheelConfig]):
    name = "wheel"
    arity = 2
    rows = 2
    section = "wheels"
    config = WheelConfig
    ranges = {"radius_left_m": Range(0.05, 5.0, "m"), "radius_right_m": Range(0.05, 5.0, "m"),
              "track_m": Range(0.1, 20.0, "m"), "noise_density": Range(1e-7, 10.0, "rad/s/√Hz")}
    advice = {
        ("radius", None): ("wheel radii: drive several curvatures, left, right and straight; one "
                           "constant curvature leaves a radii/track combination undetermined",
                           "needs several curvatures: turn left, turn right, drive straight"),
        ("track", None): ("wheel track: turn both ways; straight driving says nothing about it",
                          "needs turns: turn both ways"),
    }

    def quantities(self, cfg: ConfigView, wc: WheelConfig) -> list[Quantity]:
        on = wc.estimate
        return [Quantity("wheel", "radius", 1, "m", wc.radius_left_m, on, names=("wheel.radius_left",),
                         key="radius_left", axis=0),
                Quantity("wheel", "radius", 1, "m", wc.radius_right_m, on, names=("wheel.radius_right",),
                         key="radius_right", axis=1),
                Quantity("wheel", "track", 1, "m", wc.track_m, on),
                Quantity("wheel", "slip", 1, "1", 0.0, cfg.vehicle.slip.estimate, nuisance=True, per_entry=False),
                Quantity("wheel", "scrub", 1, "1", 0.0, cfg.vehicle.slip.estimate, nuisance=True, per_entry=False)]

    # --- the math ---

    def measurement(self, f: FactorInputs) -> Expr:
        tr = axle_travel(f)
        b = f.q["track"]
        inc = ca.vertcat((tr.ds - 0.5 * b * tr.dpsi) / f.q["radius_left"], (tr.ds + 0.5 * b * tr.dpsi) / f.q["radius_right"])
        lateral = lateral_g(tr.ds, tr.dpsi, f.dT)
        return inc * (1.0 + f.q["slip"] * tr.along + f.q["scrub"] * lateral * lateral)

    def residual(self, f: FactorInputs, meas: Expr) -> Expr:
        return self.measurement(f) - meas

    def constants(self, rig: RigView, wc: WheelConfig) -> dict[str, float]:
        return {"sigma": increment_sigma_rad(wc, rig.keyframe_rate_hz)}

    def sqrt_information(self, f: FactorInputs) -> Expr:
        return ca.vertcat(1.0, 1.0) / f.c["sigma"]

    # --- simulation ---

    def simulate(self, sim: SimulationView, wc: WheelConfig) -> np.ndarray:
        """Each wheel's rotation over every keyframe interval as its encoder counts it: ticks
        (quantisation ``2π/ticks_per_rev``) of the cumulative angle plus white noise, so that the
        total noise of one increment (white + two quantisation errors) equals the rig's.
        Physical: the angle integrates the wheel's contact-point speed with a slip ratio that grows
        linearly with longitudinal acceleration (what ``wheel.slip`` models) and with the square of
        the lateral one (what ``wheel.scrub`` models); model: the increments of the measurement model."""
        nom, settings, rng, truth = sim.nom, sim.settings, sim.rng, sim.truth
        K, n = nom.n_keyframes, nom.imu_per_keyframe
        rl, rr = truth.scalar("wheel", "radius_left"), truth.scalar("wheel", "radius_right")
        track = truth.scalar("wheel", "track")
        if settings.wheel_slip_per_g or settings.wheel_scrub_per_g2:
            over = max(settings.imu_oversampling, 1)
            dt = 1.0 / sim.rig.config.imu.update_rate
            t_fine = nom.t[0] + np.arange((K - 1) * n * over + 1) * (dt / over)
            inc = np.diff(_wheel_angles(sim.traj, t_fine, nom.t, (rl, rr), track, settings.wheel_slip_per_g,
                                        settings.wheel_scrub_per_g2), axis=0)
        else:
            inc = sim.measured(self, wc)  # the measurement model at the truth, slip aside
        tpr = settings.wheel_ticks_per_rev
        q = 2 * np.pi / tpr if tpr else 0.0
        sigma = increment_sigma_rad(wc, sim.rig.keyframe_rate_hz)
        white2 = sigma ** 2 - q ** 2 / 6.0  # an increment differences two quantisation errors
        if white2 <= 0:
            raise ValueError(f"wheel quantisation of {tpr} ticks/rev alone exceeds the wheel noise "
                             f"per keyframe ({sigma:g} rad): use more ticks per revolution")
        if sim.noisy:
            inc = inc + rng.normal(0.0, np.sqrt(white2), inc.shape)
        if not tpr:
            return inc
        angle = np.vstack([np.zeros((1, 2)), np.cumsum(inc, axis=0)])
        phase = rng.uniform(0.0, 1.0, 2) if sim.noisy else np.full(2, 0.5)
        ticks = np.floor(angle / q + phase) - np.floor(phase)
        return np.diff(ticks, axis=0) * q


@dataclass
class Travel:
    """The rear axle over a pair of keyframes (CasADi SX, :func:`axle_travel`): its turn ``dpsi``
    [rad] about the road normal, its travel ``ds`` [m] along the arc and ``lat`` [m] across the
    interval's mean heading (a sideways slide: zero on an arc), its mean longitudinal acceleration
    along the mean heading in g (``along``), and at each keyframe its forward and lateral speed
    ``u``, ``v_lat`` [m/s] and its yaw rate ``yaw_rate`` [rad/s] about the road normal (the
    nominal body rate)."""

    dpsi: object
    ds: object
    lat: object
    along: object
    u: list
    v_lat: list
    yaw_rate: list


def lateral_g(ds, dpsi, dT):
    """An interval's lateral acceleration in g, ``(Δs/ΔT)·(Δψ/ΔT)/g``: what the scrub of the
    wheel kinds grows with (CasADi symbols; the kernel writes it out)."""
    return ds * dpsi / (dT * dT * G_MPS2)


def axle_travel(f: FactorInputs) -> Travel:
    """What the rear axle did between the two keyframes of factor ``f`` (see the module
    docstring): the one statement of the arc that the wheel kinds read."""
    R_BV = f.R_V_B.T
    p_BV = -ca.mtimes(R_BV, f.p_V_B)
    R_BA = [ca.mtimes(R_BV, f.R_V_A[a]) for a in range(2)]
    RAi, RAj = ca.mtimes(f.R[0], R_BA[0]), ca.mtimes(f.R[1], R_BA[1])
    dpsi = log(ca.mtimes(RAi.T, RAj))[2]
    c = ca.mtimes(RAi.T, f.p[1] + ca.mtimes(f.R[1], p_BV) - f.p[0] - ca.mtimes(f.R[0], p_BV))
    h = 0.5 * dpsi
    small = ca.fabs(h) < 1e-3
    hs = ca.if_else(small, 1.0, h)
    arc = ca.if_else(small, 1.0 + h * h / 6.0 + 7.0 * h ** 4 / 360.0, hs / ca.sin(hs))
    ds = arc * (ca.cos(h) * c[0] + ca.sin(h) * c[1])
    lat = ca.cos(h) * c[1] - ca.sin(h) * c[0]  # the chord of an arc lies along the mean heading
    # the axle's velocity v_V = v + R (ω × p_BV): its mean acceleration, and its speed at each end
    vV = [f.v[a] + ca.mtimes(f.R[a], ca.cross(f.omega[a], p_BV)) for a in range(2)]
    dv = ca.mtimes(RAi.T, vV[1] - vV[0])
    along = (ca.cos(h) * dv[0] + ca.sin(h) * dv[1]) / (f.dT * G_MPS2)
    RA = (RAi, RAj)
    u = [ca.dot(RA[a][:, 0], vV[a]) for a in range(2)]
    v_lat = [ca.dot(RA[a][:, 1], vV[a]) for a in range(2)]
    yaw_rate = [ca.dot(R_BA[a][:, 2], f.omega[a]) for a in range(2)]
    return Travel(dpsi, ds, lat, along, u, v_lat, yaw_rate)


def axle_geometry(nom: Nominal) -> tuple[np.ndarray, np.ndarray]:
    """The rear axle seen from B: ``p_BV`` (origin of V in B) and ``R_BA = R_BV R_V_A`` at every
    keyframe."""
    R_BV = nom.R_V_B.T
    return -R_BV @ nom.p_V_B, R_BV @ nom.R_V_A


def _wheel_angles(traj: Trajectory, t: np.ndarray, t_keyframes: np.ndarray, radii: tuple[float, float],
                  track: float, slip_per_g: float, scrub_per_g2: float) -> np.ndarray:
    """Cumulative left/right wheel angles at ``t_keyframes`` [rad]: each wheel's contact-point speed
    along its heading (the axle's forward speed ∓ half the track times the yaw rate), times
    ``1 + κ`` with the slip ratio ``κ = slip_per_g·a_long/g + scrub_per_g2·(a_lat/g)²``, over its
    true radius, integrated (trapezoid) on the fine grid ``t``."""
    smp = traj.sample(t)
    g = float(np.linalg.norm(GRAVITY))
    kappa = slip_per_g * smp.accel_long / g + scrub_per_g2 * (smp.accel_lat / g) ** 2
    u, r = smp.speed, smp.yaw_rate
    rate = np.stack([(u - 0.5 * track * r) / radii[0], (u + 0.5 * track * r) / radii[1]], axis=1)
    rate *= (1.0 + kappa)[:, None]
    angle = np.vstack([np.zeros((1, 2)), np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t)[:, None], axis=0)])
    return np.stack([np.interp(t_keyframes, t, angle[:, i]) for i in range(2)], axis=1)


