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

and the first fix of a drive enters at the stationary variance (:class:`GnssFirstFix`, the
kind's :attr:`~excite.factors.base.Kind.opening`, added where a drive or a window closed as one
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
geometry (a high HDOP) counts less. The compiled kernel reads it; the optimizer's planned drives
and the simulator use the configured σ.

Both σ are in the world frame (east/north, up), so the fix breaks the translation symmetry and,
with the antenna off the body's origin or a direction of travel, the yaw about the vertical: a
rig with GNSS has no gauge and keeps world trajectory states (:mod:`excite.information.closure`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numba as nb
import numpy as np
from pydantic import Field, model_validator

from ..core import kernels
from ..core.bounds import Range
from ..core.lazy import ca
from ..core.schema import Model, PositiveFloat, SensorEntry
from .base import FactorBlock, Kind, Nominal, Quantity, RigView, theta_columns
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


def _antenna(f, a: int):
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
            Quantity(s.name, "time_offset", 1, "s", 0.0, s.estimate.time_offset)]


class GnssFirstFix(Kind):
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

    def quantities(self, cfg, s: GnssSensor) -> list[Quantity]:
        return _quantities(s)

    def factor_keyframes(self, rig: RigView, entry: GnssSensor, n_keyframes: int, nom: Nominal | None = None) -> np.ndarray:
        """Keyframe 0, if it holds a fix."""
        return np.zeros(1 if n_keyframes and _available(nom, entry, 1)[0] else 0, dtype=int)

    def measurement(self, f):
        return _antenna(f, 0)

    def residual(self, f, meas):
        return meas - _antenna(f, 0)

    def sqrt_information(self, f):
        return ca.DM(1.0 / f.entry.noise.sigmas())

    def blocks(self, nom: Nominal, rig: RigView, s: GnssSensor) -> FactorBlock | None:
        first = self.factor_keyframes(rig, s, nom.n_keyframes, nom)
        if not first.size:
            return None
        W = _whitening(nom, s, first)
        A, T = _antenna_jacobians(nom, s, first)
        cols, Jt = _theta(rig, s, T)
        return FactorBlock(self.block_name(s), first, 1, 1, -np.einsum("nij,njk->nik", W, A),
                           -np.einsum("nij,njk->nik", W, Jt), cols)

    def measured(self, rig: RigView, s: GnssSensor, recorded: GnssFixes, values: dict) -> tuple[np.ndarray, dict]:
        k = recorded.keyframes[:1] if recorded.keyframes.size and recorded.keyframes[0] == 0 else np.zeros(0, int)
        return recorded.at(k), values


class Gnss(Kind):
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

    def quantities(self, cfg, s: GnssSensor) -> list[Quantity]:
        return _quantities(s)

    def factor_keyframes(self, rig: RigView, entry: GnssSensor, n_keyframes: int, nom: Nominal | None = None) -> np.ndarray:
        """Every fix whose successor (``stride`` keyframes on) the log holds too."""
        first = super().factor_keyframes(rig, entry, n_keyframes)
        if not first.size:
            return first
        ok = _available(nom, entry, n_keyframes)
        s = self.stride(rig, entry)
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

    def measurement(self, f):
        return ca.vertcat(_antenna(f, 0), _antenna(f, 1))

    def residual(self, f, meas):
        phi = f.entry.noise.phi(f.dT)
        return (meas[3:6] - _antenna(f, 1)) - phi * (meas[0:3] - _antenna(f, 0))

    def sqrt_information(self, f):
        phi = f.entry.noise.phi(f.dT)
        return ca.DM(1.0 / (f.entry.noise.sigmas() * math.sqrt(1.0 - phi * phi)))

    # --- the compiled kernel ---

    def blocks(self, nom: Nominal, rig: RigView, s: GnssSensor) -> FactorBlock | None:
        """Whitened Jacobians of every differenced pair of consecutive fixes (compiled:
        :func:`_pair_jacobians`)."""
        first = self.factor_keyframes(rig, s, nom.n_keyframes, nom)
        if not first.size:
            return None
        stride = self.stride(rig, s)
        phi = s.noise.phi(stride / rig.keyframe_rate_hz)
        log = nom.logs.get(s.name)
        reported = s.noise.use_reported_covariance and log is not None and log.covariance is not None
        k = np.arange(nom.n_keyframes) if reported else np.zeros(1, dtype=int)
        W = _whitening(nom, s, k) if reported else np.diag(1.0 / s.noise.sigmas())[None]
        cols, _ = _theta(rig, s, np.zeros((0, 3, 4)))
        Jx, Jt = _pair_jacobians(nom.R, nom.v, nom.omega, first.astype(np.int64), stride, s.T_B_S.p, W, reported,
                                 phi, s.estimate.extrinsic, s.estimate.time_offset)
        return FactorBlock(s.name, first, stride, 2, Jx, Jt, cols, _PAIR_XCOLS)

    # --- simulation and calibration ---

    def simulate(self, sim, s: GnssSensor) -> GnssFixes:
        """Fixes at every fix keyframe the drive holds (all of them without a log): the antenna at
        its time ``t + t_d`` (physical: the drive's exact pose; model: to first order, as the
        factor) plus a Gauss–Markov error of the configured σ and correlation time, continuing
        across outages with their length."""
        nom, truth = sim.nom, sim.truth
        K = nom.n_keyframes
        stride = self.stride(sim.rig, s)
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

    def measured(self, rig: RigView, s: GnssSensor, recorded: GnssFixes, values: dict) -> tuple[np.ndarray, dict]:
        """The pairs of consecutive fixes (``[z_i, z_j]`` per factor of :meth:`factor_keyframes`)."""
        stride = self.stride(rig, s)
        have = set(recorded.keyframes.tolist())
        first = np.array([k for k in recorded.keyframes.tolist() if k + stride in have], dtype=int)
        return np.hstack([recorded.at(first), recorded.at(first + stride)]), values


_PAIR_XCOLS = np.array([0, 1, 2, 3, 4, 5, 9, 10, 11, 12, 13, 14])  # no velocity at t_d = 0


@nb.njit(cache=True, nogil=True)
def _pair_jacobians(R, v, w, first, stride, l, W, reported, phi, c_trans, c_time):
    """Per pair i → j = i + stride of fixes, with ``c = √(1 − φ²)``, ``W_i = φ L_i⁻¹ / c`` and
    ``W_j = L_j⁻¹ / c`` (``L⁻¹``: ``W[k]`` per keyframe if ``reported``, else ``W[0]``), the
    differenced residual ``W_j (z_j − a_j) − W_i (z_i − a_i)`` differentiated (t_d = 0)::

        ∂/∂δθ_i = −W_i R_i [l]×   ∂/∂δp_i = W_i   ∂/∂δθ_j = W_j R_j [l]×   ∂/∂δp_j = −W_j
        ∂/∂l = W_i R_i − W_j R_j   ∂/∂t_d = W_i (v_i + R_i (ω_i × l)) − W_j (v_j + R_j (ω_j × l))

    (velocities do not enter at t_d = 0)."""
    N = first.size
    nc = (3 if c_trans else 0) + (1 if c_time else 0)
    Jx = np.zeros((N, 3, 18))
    Jt = np.zeros((N, 3, nc))
    c = np.sqrt(1.0 - phi * phi)
    hl = np.empty((3, 3))
    kernels.hat(l, hl)
    A, B, Wk = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    a, b, e = np.empty(3), np.empty(3), np.empty(3)
    for n in range(N):
        for side in range(2):
            k = first[n] + side * stride
            f = (phi if side == 0 else -1.0) / c  # W_i carries +φ, W_j −1
            Wsrc = W[k] if reported else W[0]
            for r in range(3):
                for q in range(3):
                    Wk[r, q] = f * Wsrc[r, q]
            kernels.mul(R[k], hl, A)  # R [l]×
            kernels.mul(Wk, A, B)
            o = 9 * side
            for r in range(3):
                for q in range(3):
                    Jx[n, r, o + q] = -B[r, q]
                    Jx[n, r, o + 3 + q] = Wk[r, q]
            if c_trans:
                kernels.mul(Wk, R[k], A)
                for r in range(3):
                    for q in range(3):
                        Jt[n, r, q] += A[r, q]
            if c_time:
                kernels.cross(w[k], l, a)
                kernels.mulv(R[k], a, b)
                for q in range(3):
                    e[q] = v[k, q] + b[q]
                kernels.mulv(Wk, e, a)
                for r in range(3):
                    Jt[n, r, nc - 1] += a[r]
    return Jx, Jt


def _whitening(nom: Nominal, s: GnssSensor, k: np.ndarray) -> np.ndarray:
    """``L_k⁻¹`` of every fix at keyframes ``k`` (N × 3 × 3): the configured σ, or the reported
    covariance where the log has one and the rig asks for it."""
    W = np.broadcast_to(np.diag(1.0 / s.noise.sigmas()), (k.size, 3, 3)).copy()
    log = nom.logs.get(s.name)
    if s.noise.use_reported_covariance and log is not None and log.covariance is not None:
        C = log.covariance[k]
        ok = np.all(np.isfinite(C), axis=(1, 2))
        if ok.any():
            L = np.linalg.cholesky(C[ok])
            W[ok] = np.linalg.inv(L)
    return W


def _antenna_jacobians(nom: Nominal, s: GnssSensor, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The antenna position's Jacobians at the fixes of keyframes ``k`` (t_d = 0), w.r.t. the
    world state ``[δθ, δp, δv]`` (N × 3 × 9) and to ``[l, t_d]`` (N × 3 × 4)::

        ∂a/∂δθ = −R [l]×,   ∂a/∂δp = I,   ∂a/∂δv = 0,   ∂a/∂l = R,   ∂a/∂t_d = v + R (ω × l)
    """
    l = s.T_B_S.p
    R = nom.R[k]
    N = k.size
    A = np.zeros((N, 3, 9))
    hl = np.array([[0.0, -l[2], l[1]], [l[2], 0.0, -l[0]], [-l[1], l[0], 0.0]])
    A[:, :, 0:3] = -R @ hl
    A[:, :, 3:6] = np.eye(3)
    T = np.zeros((N, 3, 4))
    T[:, :, 0:3] = R
    T[:, :, 3] = nom.v[k] + np.einsum("nij,nj->ni", R, np.cross(nom.omega[k], l))
    return A, T


def _theta(rig: RigView, s: GnssSensor, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The columns of θ the entry estimates and the Jacobian ``T`` (over ``[l, t_d]``) restricted to them."""
    keep = ([0, 1, 2] if s.estimate.extrinsic else []) + ([3] if s.estimate.time_offset else [])
    names = ([f"{s.name}.trans_{a}" for a in "xyz"] if s.estimate.extrinsic else []) + \
        ([f"{s.name}.time_offset"] if s.estimate.time_offset else [])
    cols = theta_columns(rig, names) if names else np.zeros(0, dtype=int)
    return cols, np.ascontiguousarray(T[:, :, keep])
