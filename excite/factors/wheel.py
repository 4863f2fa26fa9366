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

import numba as nb
import numpy as np

from ..core import kernels
from ..core.bounds import Range
from ..core.lazy import ca
from ..core.schema import Model, PositiveFloat
from ..motion.trajectory import GRAVITY, Trajectory
from .base import FactorBlock, Kind, Nominal, Quantity, RigView, theta_columns
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


class Wheel(Kind):
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

    def quantities(self, cfg, wc: WheelConfig) -> list[Quantity]:
        on = wc.estimate
        return [Quantity("wheel", "radius", 1, "m", wc.radius_left_m, on, names=("wheel.radius_left",),
                         key="radius_left", axis=0),
                Quantity("wheel", "radius", 1, "m", wc.radius_right_m, on, names=("wheel.radius_right",),
                         key="radius_right", axis=1),
                Quantity("wheel", "track", 1, "m", wc.track_m, on),
                Quantity("wheel", "slip", 1, "1", 0.0, cfg.vehicle.slip.estimate, nuisance=True),
                Quantity("wheel", "scrub", 1, "1", 0.0, cfg.vehicle.slip.estimate, nuisance=True)]

    # --- the math ---

    def measurement(self, f):
        tr = axle_travel(f)
        b = f.q["track"]
        inc = ca.vertcat((tr.ds - 0.5 * b * tr.dpsi) / f.q["radius_left"], (tr.ds + 0.5 * b * tr.dpsi) / f.q["radius_right"])
        lateral = lateral_g(tr.ds, tr.dpsi, f.dT)
        return inc * (1.0 + f.q["slip"] * tr.along + f.q["scrub"] * lateral * lateral)

    def residual(self, f, meas):
        return self.measurement(f) - meas

    def sqrt_information(self, f):
        return ca.DM([1.0 / increment_sigma_rad(f.entry, f.rig.keyframe_rate_hz)] * 2)

    # --- the compiled kernel ---

    def blocks(self, nom: Nominal, rig: RigView, wc: WheelConfig) -> FactorBlock:
        """Whitened Jacobians of the left/right wheel increments of every keyframe interval."""
        names = ["wheel.radius_left", "wheel.radius_right", "wheel.track"] if wc.estimate else []
        slip = rig.config.vehicle.slip.estimate
        p_BV, R_BA, v_V = axle_geometry(nom, slip)
        dT = nom.t[1] - nom.t[0] if nom.n_keyframes > 1 else 1.0
        Jx, Jt = _jacobians(nom.R, nom.p, R_BA, p_BV, wc.radius_left_m, wc.radius_right_m,
                            wc.track_m, increment_sigma_rad(wc, rig.keyframe_rate_hz), wc.estimate, slip, v_V, dT)
        cols = (theta_columns(rig, names + (["wheel.slip", "wheel.scrub"] if slip else [])) if names or slip
                else np.zeros(0, dtype=int))
        return FactorBlock("wheel", np.arange(nom.n_keyframes - 1), 1, 2, Jx, Jt, cols)

    # --- simulation ---

    def simulate(self, sim, wc: WheelConfig) -> np.ndarray:
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


def axle_travel(f) -> Travel:
    """What the rear axle did between the two keyframes of factor ``f`` (see the module
    docstring): the one statement of the arc that the wheel kinds read."""
    R_BV = ca.DM(f.R_V_B.T)
    p_BV = ca.DM(-f.R_V_B.T @ f.p_V_B)
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


def axle_geometry(nom: Nominal, slip: bool = False):
    """The rear axle seen from B: ``p_BV`` (origin of V in B), ``R_BA = R_BV R_V_A`` at every
    keyframe and, with ``slip``, the axle's world velocity ``v + R (ω_B × p_BV)`` (else an empty
    stack); compiled (:func:`_axle`), as these run per keyframe on every evaluation."""
    R_BV = np.ascontiguousarray(nom.R_V_B.T)
    p_BV = -R_BV @ nom.p_V_B  # origin of V in B
    R_BA, v_V = _axle(nom.R, nom.v, nom.omega, np.ascontiguousarray(nom.R_V_A), R_BV, p_BV, slip)
    return p_BV, R_BA, v_V


@nb.njit(cache=True, nogil=True)
def _axle(R, v, omega_B, R_V_A, R_BV, p_BV, velocity):
    """``R_BA = R_BV R_V_A`` per keyframe and, if ``velocity``, ``v + R (ω_B × p_BV)``
    (``v + R (ω_B × p_BV)``; else (0, 3))."""
    K = R.shape[0]
    R_BA = np.empty((K, 3, 3))
    v_V = np.empty((K if velocity else 0, 3))
    a, b = np.empty(3), np.empty(3)
    for k in range(K):
        kernels.mul(R_BV, R_V_A[k], R_BA[k])
        if velocity:
            kernels.cross(omega_B[k], p_BV, a)
            kernels.mulv(R[k], a, b)
            for c in range(3):
                v_V[k, c] = v[k, c] + b[c]
    return R_BA, v_V


@nb.njit(cache=True, inline="always")
def arc_ratio(x):
    """``a(x) = (x/2)/sin(x/2)`` (arc over chord of a turn by x) and its derivative ``a′(x)``."""
    h = 0.5 * x
    if abs(h) < 1e-3:
        h2 = h * h
        return 1.0 + h2 / 6.0 + 7.0 * h2 * h2 / 360.0, 0.5 * (h / 3.0 + 7.0 * h2 * h / 90.0)
    s, c = np.sin(h), np.cos(h)
    return h / s, 0.5 * (s - h * c) / (s * s)


@nb.njit(cache=True, nogil=True)
def _jacobians(R, p, R_BA, p_BV, rl, rr, track, sigma, estimate, slip, v_V, dT):
    """Per interval i → j, with ``R_A = R R_BA``, ``φ = Log(R_A,iᵀ R_A,j)`` (Δψ = φ_z),
    ``c = R_A,iᵀ (p_V,j − p_V,i)`` and ``Δs = mᵀc``::

        ∂φ/∂θ_i = −J_l⁻¹(φ) R_BA,iᵀ        ∂φ/∂θ_j = J_r⁻¹(φ) R_BA,jᵀ
        ∂c/∂θ_i = R_BA,iᵀ [R_iᵀ(p_j + R_j p_BV − p_i)]×    ∂c/∂p_i = −R_A,iᵀ
        ∂c/∂θ_j = −R_A,iᵀ R_j [p_BV]×       ∂c/∂p_j = R_A,iᵀ
        ∂(mᵀc) = mᵀ ∂c + (m′ᵀ c) ∂Δψ,   m′ = ½(−sin Δψ/2, cos Δψ/2, 0)
        ∂Δs = a ∂(mᵀc) + a′ (mᵀc) ∂Δψ

    and the wheel angles ``(Δs ∓ ½ b Δψ)/r`` differentiated in the states and in (r_l, r_r, b)
    and, with ``slip``, in the slip at 1 g and the scrub at 1 g² (the angles times
    ``1 + slip·ā/g + scrub·(a_y/g)²`` at zero, ā from the axle velocities ``v_V``,
    ``a_y = Δs·Δψ/ΔT²``); everything divided by σ."""
    N = R.shape[0] - 1
    Jx = np.empty((N, 2, 18))  # every entry written below
    ns = 2 if slip else 0
    Jt = np.empty((N, 2, (3 if estimate else 0) + ns))  # zeroed per factor, in cache
    RAi, RAj, X, Y, M = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    phi, a, cc, q, qb = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    Jpsi = np.empty(18)
    Js = np.empty(18)
    Jc = np.empty((3, 18))
    hp = np.empty((3, 3))
    kernels.hat(p_BV, hp)
    for n in range(N):
        i, j = n, n + 1
        Jt[n] = 0.0
        Ri, Rj = R[i], R[j]
        kernels.mul(Ri, R_BA[i], RAi)
        kernels.mul(Rj, R_BA[j], RAj)
        kernels.tmul(RAi, RAj, X)
        kernels.log(X, phi)
        dpsi = phi[2]
        kernels.mulv(Rj, p_BV, a)
        for k in range(3):
            q[k] = p[j, k] + a[k] - p[i, k]  # p_V,j − p_i
        kernels.mulv(Ri, p_BV, a)
        for k in range(3):
            a[k] = q[k] - a[k]  # p_V,j − p_V,i
        kernels.tmulv(RAi, a, cc)
        kernels.tmulv(Ri, q, qb)  # R_iᵀ(p_j + R_j p_BV − p_i)
        # ∂Δψ: row z of ∓J⁻¹(φ) R_BAᵀ
        for k in range(3):
            a[k] = -phi[k]
        kernels.right_jacobian_inv(a, M)  # J_l⁻¹(φ)
        for k in range(18):
            Jpsi[k] = 0.0
        for k in range(3):
            Jpsi[k] = -(M[2, 0] * R_BA[i, k, 0] + M[2, 1] * R_BA[i, k, 1] + M[2, 2] * R_BA[i, k, 2])
        kernels.right_jacobian_inv(phi, M)
        for k in range(3):
            Jpsi[9 + k] = M[2, 0] * R_BA[j, k, 0] + M[2, 1] * R_BA[j, k, 1] + M[2, 2] * R_BA[j, k, 2]
        # ∂c
        for r in range(3):
            for k in range(18):
                Jc[r, k] = 0.0
        kernels.hat(qb, X)
        kernels.tmul(R_BA[i], X, Y)
        kernels.put(Jc, 0, 0, Y, 1.0)
        for r in range(3):
            for k in range(3):
                Jc[r, 3 + k] = -RAi[k, r]
                Jc[r, 12 + k] = RAi[k, r]
        kernels.tmul(RAi, Rj, X)
        kernels.mul(X, hp, Y)
        kernels.put(Jc, 0, 9, Y, -1.0)
        cs, sn = np.cos(0.5 * dpsi), np.sin(0.5 * dpsi)
        chord = cs * cc[0] + sn * cc[1]
        dmc = 0.5 * (-sn * cc[0] + cs * cc[1])
        ar, dar = arc_ratio(dpsi)
        ds = ar * chord
        for k in range(18):
            Js[k] = ar * (cs * Jc[0, k] + sn * Jc[1, k] + dmc * Jpsi[k]) + dar * chord * Jpsi[k]
            Jx[n, 0, k] = (Js[k] - 0.5 * track * Jpsi[k]) / (rl * sigma)
            Jx[n, 1, k] = (Js[k] + 0.5 * track * Jpsi[k]) / (rr * sigma)
        if estimate:
            Jt[n, 0, 0] = -(ds - 0.5 * track * dpsi) / (rl * rl * sigma)
            Jt[n, 1, 1] = -(ds + 0.5 * track * dpsi) / (rr * rr * sigma)
            Jt[n, 0, 2] = -0.5 * dpsi / (rl * sigma)
            Jt[n, 1, 2] = 0.5 * dpsi / (rr * sigma)
        if slip:
            for k in range(3):
                a[k] = v_V[j, k] - v_V[i, k]
            kernels.tmulv(RAi, a, q)
            along = (cs * q[0] + sn * q[1]) / (dT * G_MPS2)
            lat2 = (ds * dpsi / (dT * dT * G_MPS2)) ** 2  # lateral_g squared
            c = Jt.shape[2] - 2
            Jt[n, 0, c] = (ds - 0.5 * track * dpsi) / rl * along / sigma
            Jt[n, 1, c] = (ds + 0.5 * track * dpsi) / rr * along / sigma
            Jt[n, 0, c + 1] = (ds - 0.5 * track * dpsi) / rl * lat2 / sigma
            Jt[n, 1, c + 1] = (ds + 0.5 * track * dpsi) / rr * lat2 / sigma
    return Jx, Jt


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


