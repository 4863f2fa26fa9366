"""A Doppler radar's ego-velocity: the sensor's own velocity in its own frame, as radars estimate it
from the range rates of stationary targets.

A stationary target in direction ``u`` (a unit vector in the radar's frame S) closes at the range
rate ``ṙ = −uᵀ v_S``; a least-squares fit over the stationary targets of one radar cycle gives the
ego-velocity ``v_S``. It is the velocity of the sensor's origin in S:

    v_S = R_B_Sᵀ (R_W_Bᵀ v + ω_B × p_B_S)

at the time the measurement describes, ``t + t_d`` (a radar cycle stamped t sees the motion at
``t + t_d``), taken to first order from the factor's two keyframes (``v_S(t_i) + t_d·(v_S(t_j) −
v_S(t_i))/ΔT``; ω_B is the nominal body rate, which the IMU measures far better). So the radar
sees its rotation ``R_B_S`` through the direction of travel in its frame, its lever arm ``p_B_S``
only through ``ω × p`` (no yaw rate, no horizontal lever arm) and its time offset through
acceleration. A 2-D radar (``dimensions: 2``, no elevation) measures the components in its own
x-y plane only: its roll and pitch enter through the sensor's vertical velocity alone, which
planar driving gives it only through the suspension (pitch and roll rates times the lever arm),
and its height only through roll and pitch rates.

Noise per measurement: each stationary target's range rate has σ ``doppler_sigma_mps``; with
``stationary_targets`` targets per measurement spread uniformly over the field of view
(``azimuth_fov_deg`` wide, ``elevation_fov_deg`` high) the fit's covariance is
``σ²/(n·E[u uᵀ])``, diagonal: the forward component is determined far better than the lateral
and vertical ones (a radar's field of view is narrow). A log may carry the count per cycle;
the rig states the mean (the information is additive over targets, so the mean count gives the
mean information).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field

from ..core.bounds import Range
from ..core.lazy import ca
from ..core.schema import Model, PositiveFloat, SensorEntry
from . import base
from .base import ConfigView, Expr, FactorInputs, Kind, Quantity, RigView, SimulationView, Variant


class RadarNoise(Model):
    """What sets the ego-velocity's noise: the Doppler σ of one target's range rate [m/s], the
    mean number of stationary targets per measurement, and the field of view they are spread over
    (full widths [deg])."""

    doppler_sigma_mps: PositiveFloat
    stationary_targets: PositiveFloat
    azimuth_fov_deg: float = Field(default=90.0, gt=0.0, le=360.0)
    elevation_fov_deg: float = Field(default=15.0, gt=0.0, le=180.0)


class RadarSensor(SensorEntry):
    """A Doppler radar whose ego-velocity (from stationary targets) is the measurement."""

    kind: Literal["radar"]
    dimensions: Literal[2, 3] = 3
    noise: RadarNoise


def _spread(width_deg: float) -> tuple[float, float]:
    """``E[cos² a]`` and ``E[sin² a]`` for ``a`` uniform over a full width ``width_deg``."""
    a = math.radians(width_deg) / 2.0
    sinc = math.sin(2 * a) / (2 * a)
    return 0.5 * (1 + sinc), 0.5 * (1 - sinc)


def velocity_sigma_mps(noise: RadarNoise, dimensions: int = 3) -> np.ndarray:
    """σ of the ego-velocity's components in the radar frame [m/s] (x forward, y left, z up)."""
    ca_, sa = _spread(noise.azimuth_fov_deg)
    if dimensions == 2:
        info = np.array([ca_, sa])
    else:
        ce, se = _spread(noise.elevation_fov_deg)
        info = np.array([ce * ca_, ce * sa, se])
    return noise.doppler_sigma_mps / np.sqrt(noise.stationary_targets * info)


_LEVER = ("radar lever arm: turn (the ego-velocity sees it only through yaw rate × lever arm); "
          "straight driving leaves it undetermined", "needs turns: yaw rate")


class Radar(Kind[RadarSensor]):
    name = "radar"
    arity = 2  # the measurement is at the first keyframe; the second gives its rate of change
    rows = 3  # a 2-D radar's: 2
    sensor_kinds = ("radar",)
    config = RadarSensor
    ranges = {"dimensions": Range(2, 3), "noise.doppler_sigma_mps": Range(1e-5, 10.0, "m/s"), "noise.stationary_targets": Range(0.01, 10_000.0),
              "noise.azimuth_fov_deg": Range(0.1, 360.0, "deg"), "noise.elevation_fov_deg": Range(0.1, 180.0, "deg")}
    advice = {
        ("trans", 0): _LEVER,
        ("trans", 1): _LEVER,
        ("trans", 2): ("radar height: add pitch and roll rates (hard braking, brisk cornering, bumps); planar "
                       "driving leaves it undetermined", "needs pitch and roll: hard braking, brisk cornering"),
        ("rot", 0): ("radar roll: turn at speed (a 3-D radar), or pitch and roll the body (a 2-D radar sees it "
                     "only through its vertical velocity)", "needs turns at speed, braking and cornering"),
        ("rot", 1): ("radar pitch: drive (a 3-D radar); a 2-D radar sees it only through its vertical velocity: "
                     "hard braking and acceleration, bumps", "needs hard braking and acceleration"),
        ("rot", 2): ("radar yaw: drive straight and turn; its lateral velocity is weakly measured across a narrow "
                     "field of view", "needs distance: drive on"),
        ("time_offset", None): ("radar time offset: accelerate and brake, change the turn rate; constant velocity "
                                "hides it", "needs speed changes: accelerate and brake"),
    }

    def quantities(self, cfg: ConfigView, s: RadarSensor) -> list[Quantity]:
        ext = s.estimate.extrinsic
        return [Quantity(s.name, "rot", 3, "rad", s.T_B_S.R, ext),
                Quantity(s.name, "trans", 3, "m", s.T_B_S.p, ext),
                Quantity(s.name, "time_offset", 1, "s", 0.0, s.estimate.time_offset, per_entry=False)]

    def at_rate(self, entry: dict, rate_hz: float) -> dict:
        """The same information per second at ``rate_hz``: the targets of the measurements merged."""
        noise = dict(entry["noise"])
        noise["stationary_targets"] = noise["stationary_targets"] * entry["rate_hz"] / rate_hz
        return dict(entry, rate_hz=rate_hz, noise=noise)

    # --- the math ---

    @staticmethod
    def _ego(f: FactorInputs, a: int) -> Expr:
        """The radar's velocity in its frame at keyframe ``a`` of the factor."""
        R_BS, p_BS = f.q["rot"], f.q["trans"]
        return ca.mtimes(R_BS.T, ca.mtimes(f.R[a].T, f.v[a]) + ca.cross(f.omega[a], p_BS))

    def variant(self, s: RadarSensor) -> Variant:
        """A 2-D radar measures two components, a 3-D one three."""
        return (f"{s.dimensions}d",)

    def constants(self, rig: RigView, s: RadarSensor) -> dict[str, np.ndarray]:
        return {"sigma": velocity_sigma_mps(s.noise, s.dimensions)}

    def measurement(self, f: FactorInputs) -> Expr:
        v0, v1 = self._ego(f, 0), self._ego(f, 1)
        v = v0 + f.q["time_offset"] * (v1 - v0) / f.dT
        return v[0:int(f.variant[0][0])]

    def residual(self, f: FactorInputs, meas: Expr) -> Expr:
        return self.measurement(f) - meas

    def sqrt_information(self, f: FactorInputs) -> Expr:
        return 1.0 / f.c["sigma"]

    # --- simulation ---

    def simulate(self, sim: SimulationView, s: RadarSensor) -> np.ndarray:
        """The ego-velocity at every measurement (its factors' first keyframes): physical, the
        sensor's exact velocity at ``t + t_d`` (the drive's motion, the true body rate); model,
        the measurement model at the truth; each plus white noise of its σ."""
        first = base.factor_keyframes(self, sim.rig, s, sim.nom.n_keyframes)
        if sim.settings.physical:
            truth = sim.truth
            R_BS, p_BS = truth.rotation(s.name), truth.vector(s.name, "trans")
            t = sim.nom.t[first] + truth.scalar(s.name, "time_offset")
            tc = np.clip(t, sim.traj.t_start, sim.traj.t_end)
            b = sim.traj.sample(tc).body(sim.nom.R_V_B, sim.nom.p_V_B)
            v_B = np.einsum("nji,nj->ni", b.R_W_B, b.v_W) + np.cross(b.omega_B, p_BS)
            m = (v_B @ R_BS)[:, :s.dimensions]
        else:
            m = sim.measured(self, s)
        if sim.noisy:
            m = m + sim.rng.normal(0.0, 1.0, m.shape) * velocity_sigma_mps(s.noise, s.dimensions)
        return m
