"""GNSS fixes of an antenna: its lever arm and time offset, with an error correlated over time.

The fix stamped t is the antenna's phase centre at ``t + t_d``: to first order in the body's
motion (as the odometry's frames),

    a = p + v t_d + R Exp(ω t_d) l

with ``l = p_B_A`` the lever arm (``gnss.trans_x/y/z``, in B; an antenna has no orientation) and
``t_d`` the time offset (``gnss.time_offset``). A fix is ``z = a + e`` in the world frame, and
its error e is a first-order Gauss–Markov process per axis (``e_k = φ e_{k−1} + w_k``,
``φ = exp(−Δt/τ)``, stationary σ: ``horizontal_sigma_m`` on east and north, ``vertical_sigma_m``
up): multipath and the atmosphere move slowly, so ten fixes a second are not ten independent
fixes. τ = 0 is white noise.

**Why differencing (Bryson–Henrikson), not error states.** ``z_k − φ z_{k−1}`` has the white
noise ``w_k`` (σ²(1 − φ²)): the factor between consecutive fixes (:class:`Gnss`, arity 2) is the
differenced residual

    r = W [(z_j − a_j) − φ (z_i − a_i)],   W = diag(σ)⁻¹ / √(1 − φ²)

(the residual is both fixes' errors, the whitening ``[W, −φW]`` differences them)

and the first fix of a drive enters at the stationary variance (:class:`GnssFirstFix`, the
kind's :attr:`~excite.factors.base.OpensChain.opening`, added where a drive or a window closed as one
starts). Together they are the exact likelihood of the correlated fixes, with no state beyond the
trajectory's: GNSS error states (3 per keyframe) would grow every keyframe's state from 9 (15
with drifting biases) to 12 (18) and the elimination's cost with its cube, and the optimizer's
model works on 9-wide states. As the fix rate grows, φ → 1 and the information converges (the
continuous-time limit is finite), instead of growing with the number of fixes as white fixes
would.

**Outages** come from the log (:attr:`excite.factors.base.Nominal.logs`): factors only between
consecutive fixes the log holds. A fix after an outage enters through its differences with the
fixes after it only, and the chain opens at the stationary variance only at a drive's (or
window's) first keyframe: the correlation across the outage would add at most one fix's worth
of information, which is left out (a lower bound; a factor across the outage would couple
keyframes an outage apart and widen the band the elimination works on).

**Reported covariance.** With ``noise.use_reported_covariance``, a fix whose log carries the
receiver's covariance C_k (NavSatFix, ENU) is whitened by it: the normalised error
``u_k = L_k⁻¹ e_k`` (``C_k = L_k L_kᵀ``) is the unit Gauss–Markov process, so a fix in a bad
geometry (a high HDOP) counts less (:meth:`Gnss.whitening`); the optimizer's planned drives and
the simulator use the configured σ.

Both σ are in the world frame (east/north, up), so the fix breaks the translation symmetry and,
with the antenna off the body's origin or a direction of travel, the yaw about the vertical: a
rig with GNSS has no gauge and keeps world trajectory states (:mod:`excite.information.closure`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from pydantic import Field, model_validator

from ..core.bounds import Range
from ..core.lazy import ca
from ..core.schema import Model, PositiveFloat, SensorEntry
from . import base
from .base import ConfigView, Expr, FactorInputs, Kind, Nominal, Quantity, RigView, SimulationView
from .symbolic import exp

# Receivers' error processes. RTK fixed: ~1–2 cm horizontal, twice that vertical, the multipath
# of the base and rover correlated over about half a minute. Standalone (SPS/SBAS, a u-blox M8 or
# the Husky's receiver): 2.5 m CEP is ~2 m per horizontal axis; the Husky's reports 0.8–1.7 m with
# 4× the variance up, wandering over 30–60 s (shared/data notes, 7); 1.5 m / 3 m / 60 s.
PRESETS: dict[str, dict[str, float]] = {
    "rtk": {"horizontal_sigma_m": 0.02, "vertical_sigma_m": 0.04, "correlation_time_s": 30.0},
    "standalone": {"horizontal_sigma_m": 1.5, "vertical_sigma_m": 3.0, "correlation_time_s": 60.0},
}


class GnssNoise(Model):
    """The fix error: a first-order Gauss–Markov process per world axis with stationary σ
    ``horizontal_sigma_m`` (east, north) and ``vertical_sigma_m`` (up) and correlation time
    ``correlation_time_s`` (0: white, independent fixes). ``use_reported_covariance``: where a log
    carries the receiver's covariance of a fix, it replaces these σ for that fix."""

    horizontal_sigma_m: PositiveFloat
    vertical_sigma_m: PositiveFloat
    correlation_time_s: float = Field(ge=0, allow_inf_nan=False)
    use_reported_covariance: bool = False

    @model_validator(mode="before")
    @classmethod
    def _preset(cls, data: Any) -> Any:
        """``noise: rtk`` or ``noise: {preset: standalone, correlation_time_s: 30}``: a preset,
        with any key of it overridden."""
        if isinstance(data, str):
            data = {"preset": data}
        if isinstance(data, dict) and "preset" in data:
            name = data["preset"]
            if name not in PRESETS:
                raise ValueError(f"preset {name!r} is not a GNSS noise preset (presets: {', '.join(PRESETS)})")
            data = {**PRESETS[name], **{k: v for k, v in data.items() if k != "preset"}}
        return data

    def sigmas(self) -> np.ndarray:
        """σ per world axis (east, north, up) [m]."""
        return np.array([self.horizontal_sigma_m, self.horizontal_sigma_m, self.vertical_sigma_m])

    def phi(self, dt_s: float) -> float:
        """The error's correlation between fixes ``dt_s`` apart."""
        return math.exp(-dt_s / self.correlation_time_s) if self.correlation_time_s > 0 else 0.0


class GnssSensor(SensorEntry):
    """A GNSS antenna: its phase centre at ``T_B_S.translation_m`` in B (no rotation), fixes at
    ``rate_hz``; ``estimate.extrinsic`` estimates the lever arm (``NAME.trans_x/y/z``),
    ``estimate.time_offset`` the fix's time offset (``NAME.time_offset``)."""

    kind: Literal["gnss"]
    noise: GnssNoise

    @model_validator(mode="after")
    def _no_rotation(self) -> "GnssSensor":
        if self.T_B_S.rpy_deg is not None or self.T_B_S.matrix is not None:
            raise ValueError("T_B_S: an antenna has no orientation: give its translation_m only "
                             "(its lever arm is NAME.trans_x/y/z)")
        return self


@dataclass(frozen=True)
class GnssFixes:
    """What a GNSS antenna recorded on a simulated drive: the keyframes of its fixes and the
    fixes (world positions, m)."""

    keyframes: np.ndarray
    z: np.ndarray

    def at(self, k: np.ndarray) -> np.ndarray:
        where = {int(x): i for i, x in enumerate(self.keyframes)}
        return self.z[[where[int(x)] for x in k]] if len(k) else np.zeros((0, 3))


def _antenna(f: FactorInputs, a: int) -> Expr:
    """The antenna's world position the fix of keyframe ``a`` of the factor sees (first order in t_d)."""
    t_d = f.q["time_offset"]
    return f.p[a] + f.v[a] * t_d + ca.mtimes(ca.mtimes(f.R[a], exp(f.omega[a] * t_d)), f.q["trans"])


def _available(nom: Nominal | None, entry: GnssSensor, n: int) -> np.ndarray:
    """Which of ``n`` keyframes hold a fix the log has (all of them without a log)."""
    log = None if nom is None else nom.logs.get(entry.name)
    return np.ones(n, dtype=bool) if log is None else log.available[:n]


_HORIZONTAL = ("antenna lever arm (horizontal): change heading, turns both ways; at constant heading "
               "it cannot be told from a position offset", "needs heading changes: turn left and right")


def _quantities(s: GnssSensor) -> list[Quantity]:
    return [Quantity(s.name, "trans", 3, "m", s.T_B_S.p, s.estimate.extrinsic),
            Quantity(s.name, "time_offset", 1, "s", 0.0, s.estimate.time_offset, per_entry=False)]


class GnssFirstFix(Kind[GnssSensor]):
    """The first fix of a drive at the error's stationary variance: what opens the chain of
    differenced fixes (:class:`Gnss`). Not registered: the closure adds it at a drive's first
    keyframe, where the log has a fix there."""

    name = "gnss_first_fix"
    arity = 1
    rows = 3
    breaks = frozenset({"position", "yaw"})
    config = GnssSensor

    def block_name(self, entry: GnssSensor) -> str:
        return f"{entry.name}.first_fix"

    def quantities(self, cfg: ConfigView, s: GnssSensor) -> list[Quantity]:
        return _quantities(s)

    def factor_keyframes(self, rig: RigView, entry: GnssSensor, n_keyframes: int, nom: Nominal | None = None) -> np.ndarray:
        """Keyframe 0, if it holds a fix."""
        return np.zeros(1 if n_keyframes and _available(nom, entry, 1)[0] else 0, dtype=int)

    def constants(self, rig: RigView, s: GnssSensor) -> dict[str, np.ndarray]:
        return {"sigma": s.noise.sigmas()}

    def measurement(self, f: FactorInputs) -> Expr:
        return _antenna(f, 0)

    def residual(self, f: FactorInputs, meas: Expr) -> Expr:
        return meas - _antenna(f, 0)

    def sqrt_information(self, f: FactorInputs) -> Expr:
        return 1.0 / f.c["sigma"]

    def whitening(self, nom: Nominal, rig: RigView, s: GnssSensor, first: np.ndarray) -> np.ndarray | None:
        """``L⁻¹`` of the receiver's covariance of the first fix, where it reports one."""
        return fix_whitening(nom, s, first) if reports_covariance(nom, s) else None

    def prepare_recording(self, rig: RigView, s: GnssSensor, recorded: GnssFixes,
                          values: dict[str, Any]) -> tuple[np.ndarray, dict[str, Any]]:
        k = recorded.keyframes[:1] if recorded.keyframes.size and recorded.keyframes[0] == 0 else np.zeros(0, int)
        return recorded.at(k), values


class Gnss(Kind[GnssSensor]):
    name = "gnss"
    arity = 2
    rows = 3
    breaks = frozenset({"position", "yaw"})
    sensor_kinds = ("gnss",)
    config = GnssSensor
    opening = GnssFirstFix()
    ranges = {"noise.horizontal_sigma_m": Range(1e-4, 100.0, "m"), "noise.vertical_sigma_m": Range(1e-4, 100.0, "m"),
              "noise.correlation_time_s": Range(0.0, 86_400.0, "s")}
    advice = {
        ("trans", 0): _HORIZONTAL,
        ("trans", 1): _HORIZONTAL,
        ("trans", 2): ("antenna lever arm (vertical): add roll and pitch (brisk cornering, hard braking, "
                       "ramps); planar driving leaves it to the suspension",
                       "needs roll and pitch: brisk cornering, hard braking, a ramp"),
        ("time_offset", None): ("GNSS time offset: change speed (accelerate, brake, stop and go); at "
                                "constant velocity it is a shift along the track, like the lever arm",
                                "needs speed changes: accelerate and brake"),
    }

    def quantities(self, cfg: ConfigView, s: GnssSensor) -> list[Quantity]:
        return _quantities(s)

    def factor_keyframes(self, rig: RigView, entry: GnssSensor, n_keyframes: int, nom: Nominal | None = None) -> np.ndarray:
        """Every fix whose successor (``stride`` keyframes on) the log holds too."""
        first = base.frames(self, rig, entry, n_keyframes)
        if not first.size:
            return first
        ok = _available(nom, entry, n_keyframes)
        s = base.stride(self, rig, entry)
        return first[ok[first] & ok[first + s]]

    def at_rate(self, entry: dict, rate_hz: float) -> dict:
        """The same error process at another fix rate (its information converges with the rate);
        white fixes (τ = 0) keep their information per second: σ × √(new rate / old rate)."""
        noise = dict(entry["noise"])
        if not noise.get("correlation_time_s"):
            f = math.sqrt(rate_hz / entry["rate_hz"])
            noise["horizontal_sigma_m"] *= f
            noise["vertical_sigma_m"] *= f
        return dict(entry, rate_hz=rate_hz, noise=noise)

    # --- the math ---

    def constants(self, rig: RigView, s: GnssSensor) -> dict[str, Any]:
        return {"sigma": s.noise.sigmas(), "phi": s.noise.phi(base.stride(self, rig, s) / rig.keyframe_rate_hz)}

    def measurement(self, f: FactorInputs) -> Expr:
        return ca.vertcat(_antenna(f, 0), _antenna(f, 1))

    def residual(self, f: FactorInputs, meas: Expr) -> Expr:
        """Both fixes' errors, ``[z_j − a_j; z_i − a_i]``: the whitening differences them."""
        return ca.vertcat(meas[3:6] - _antenna(f, 1), meas[0:3] - _antenna(f, 0))

    def sqrt_information(self, f: FactorInputs) -> Expr:
        """``[W, −φ W] / √(1 − φ²)`` with ``W = diag(σ)⁻¹``: the differenced fixes, whitened."""
        W = ca.diag(1.0 / f.c["sigma"]) / ca.sqrt(1.0 - f.c["phi"] ** 2)
        return ca.horzcat(W, -f.c["phi"] * W)

    def whitening(self, nom: Nominal, rig: RigView, s: GnssSensor, first: np.ndarray) -> np.ndarray | None:
        """``[L_j⁻¹, −φ L_i⁻¹] / √(1 − φ²)`` of every pair where the receiver reports the fixes'
        covariance (the configured σ for a fix without one)."""
        if not reports_covariance(nom, s):
            return None
        stride = base.stride(self, rig, s)
        phi = s.noise.phi(stride / rig.keyframe_rate_hz)
        c = math.sqrt(1.0 - phi * phi)
        return np.concatenate([fix_whitening(nom, s, first + stride), -phi * fix_whitening(nom, s, first)], axis=2) / c

    # --- simulation and calibration ---

    def simulate(self, sim: SimulationView, s: GnssSensor) -> GnssFixes:
        """Fixes at every fix keyframe the drive holds (all of them without a log): the antenna at
        its time ``t + t_d`` (physical: the drive's exact pose; model: to first order, as the
        factor) plus a Gauss–Markov error of the configured σ and correlation time, continuing
        across outages with their length."""
        nom, truth = sim.nom, sim.truth
        K = nom.n_keyframes
        stride = base.stride(self, sim.rig, s)
        k = np.arange(0, K, stride)
        k = k[_available(nom, s, K)[k]]
        l, t_d = truth.vector(s.name, "trans"), truth.scalar(s.name, "time_offset")
        if sim.settings.physical:
            R, p = sim.body_at(nom.t[k] + t_d)
            z = p + np.einsum("nij,j->ni", R, l)
        else:
            from ..core import so3

            R = nom.R[k] @ so3.exp(nom.omega[k] * t_d)
            z = nom.p[k] + nom.v[k] * t_d + np.einsum("nij,j->ni", R, l)
        if sim.noisy and k.size:
            sig = s.noise.sigmas()
            e = np.empty((k.size, 3))
            e[0] = sim.rng.normal(0.0, 1.0, 3) * sig
            dt = np.diff(nom.t[k])
            for n in range(1, k.size):
                phi = s.noise.phi(float(dt[n - 1]))
                e[n] = phi * e[n - 1] + sim.rng.normal(0.0, 1.0, 3) * sig * math.sqrt(1.0 - phi * phi)
            z = z + e
        return GnssFixes(k, z)

    def prepare_recording(self, rig: RigView, s: GnssSensor, recorded: GnssFixes,
                          values: dict[str, Any]) -> tuple[np.ndarray, dict[str, Any]]:
        """The pairs of consecutive fixes (``[z_i, z_j]`` per factor of :meth:`factor_keyframes`)."""
        stride = base.stride(self, rig, s)
        have = set(recorded.keyframes.tolist())
        first = np.array([k for k in recorded.keyframes.tolist() if k + stride in have], dtype=int)
        return np.hstack([recorded.at(first), recorded.at(first + stride)]), values


def reports_covariance(nom: Nominal, s: GnssSensor) -> bool:
    """Whether the rig asks for the receiver's covariance and the drive's log of ``s`` carries it."""
    log = nom.logs.get(s.name)
    return s.noise.use_reported_covariance and log is not None and log.covariance is not None


def fix_whitening(nom: Nominal, s: GnssSensor, k: np.ndarray) -> np.ndarray:
    """``L_k⁻¹`` of every fix at keyframes ``k`` (N × 3 × 3): the configured σ, or the reported
    covariance where the log has one and the rig asks for it."""
    W = np.broadcast_to(np.diag(1.0 / s.noise.sigmas()), (k.size, 3, 3)).copy()
    log = nom.logs.get(s.name)
    if reports_covariance(nom, s):
        C = log.covariance[k]
        ok = np.all(np.isfinite(C), axis=(1, 2))
        if ok.any():
            L = np.linalg.cholesky(C[ok])
            W[ok] = np.linalg.inv(L)
    return W
