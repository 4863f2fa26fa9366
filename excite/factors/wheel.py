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
``noise_density·√Δt`` (:attr:`excite.rig.config.Rig.wheel_increment_sigma_rad`).

Tyres slip: a driven wheel turns faster than it travels, a braking one slower. With
``vehicle.slip`` estimated, both angles are multiplied by ``1 + slip·ā/g``, ``ā`` the interval's
mean longitudinal acceleration (:func:`longitudinal_accel_g`) and ``slip`` (``wheel.slip``, the
slip ratio at 1 g) a nuisance of the drive, linearised at zero.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..core import kernels, so3
from ..rig.config import Rig
from ..motion.trajectory import GRAVITY
from .base import FactorBlock, Nominal, theta_columns


G_MPS2 = float(-GRAVITY[2])  # [m/s²]: slip is stated per g


def _geometry(nom: Nominal, slip: bool = False):
    """The rear axle seen from B: ``p_BV`` (origin of V in B), ``R_BA = R_BV R_V_A`` at every
    keyframe and, with ``slip``, the axle's world velocity :func:`axle_velocity` (else an empty
    stack); compiled (:func:`_axle`), as these run per keyframe on every evaluation."""
    R_BV = np.ascontiguousarray(nom.R_V_B.T)
    p_BV = -R_BV @ nom.p_V_B  # origin of V in B
    R_BA, v_V = _axle(nom.R, nom.v, nom.omega, np.ascontiguousarray(nom.R_V_A), R_BV, p_BV, slip)
    return p_BV, R_BA, v_V


@nb.njit(cache=True, nogil=True)
def _axle(R, v, omega_B, R_V_A, R_BV, p_BV, velocity):
    """``R_BA = R_BV R_V_A`` per keyframe and, if ``velocity``, ``v + R (ω_B × p_BV)``
    (:func:`axle_velocity`; else (0, 3))."""
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


def blocks(nom: Nominal, rig: Rig) -> FactorBlock | None:
    """Whitened Jacobians of the left/right wheel increments of every keyframe interval."""
    wc = rig.config.wheels
    if wc is None:
        return None
    names = ["wheel.radius_left", "wheel.radius_right", "wheel.track"] if wc.estimate else []
    slip = rig.config.vehicle.slip.estimate
    p_BV, R_BA, v_V = _geometry(nom, slip)
    dT = nom.t[1] - nom.t[0] if nom.n_keyframes > 1 else 1.0
    Jx, Jt = _jacobians(nom.R, nom.p, R_BA, p_BV, wc.radius_left_m, wc.radius_right_m,
                        wc.track_m, rig.wheel_increment_sigma_rad, wc.estimate, slip, v_V, dT)
    cols = theta_columns(rig, names + (["wheel.slip"] if slip else [])) if names or slip else np.zeros(0, dtype=int)
    return FactorBlock("wheel", np.arange(nom.n_keyframes - 1), 1, 2, Jx, Jt, cols)


def axle_velocity(R: np.ndarray, v: np.ndarray, omega_B: np.ndarray, p_BV: np.ndarray) -> np.ndarray:
    """World velocity of the rear axle's centre ``v + R (ω_B × p_B_V)`` (stacks (K,3,3), (K,3), (K,3))."""
    return v + np.einsum("kij,kj->ki", R, np.cross(omega_B, p_BV))


def longitudinal_accel_g(R_W_A: np.ndarray, v_V: np.ndarray, dT: float) -> np.ndarray:
    """The axle's mean longitudinal acceleration over each keyframe interval in g, the regressor
    of the wheel slip: ``mᵀ R_W_A,iᵀ (v_V,j − v_V,i) / (ΔT·g)`` along the interval's mean heading
    ``m`` (the chord's); stacks (K,3,3), (K,3) → (K−1,)."""
    RAi, RAj = R_W_A[:-1], R_W_A[1:]
    h = 0.5 * so3.log(np.swapaxes(RAi, 1, 2) @ RAj)[:, 2]
    dv = np.einsum("nji,nj->ni", RAi, v_V[1:] - v_V[:-1])
    return (np.cos(h) * dv[:, 0] + np.sin(h) * dv[:, 1]) / (dT * G_MPS2)


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
    and, with ``slip``, in the slip at 1 g (the angles times ``1 + slip·ā/g`` at slip 0, ā of
    :func:`longitudinal_accel_g` from the axle velocities ``v_V``); everything divided by σ."""
    N = R.shape[0] - 1
    Jx = np.empty((N, 2, 18))  # every entry written below
    ns = 1 if slip else 0
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
            c = Jt.shape[2] - 1
            Jt[n, 0, c] = (ds - 0.5 * track * dpsi) / rl * along / sigma
            Jt[n, 1, c] = (ds + 0.5 * track * dpsi) / rr * along / sigma
    return Jx, Jt


def increments(Ri, pi, Rj, pj, R_BA_i, R_BA_j, p_BV, radius_left, radius_right, track) -> np.ndarray:
    """Left and right wheel rotation [rad] between two body poses (the nonlinear model); poses
    may be stacks (N,3,3), (N,3), giving (N, 2)."""
    RAi, RAj = Ri @ R_BA_i, Rj @ R_BA_j
    dpsi = so3.log(np.swapaxes(RAi, -1, -2) @ RAj)[..., 2]
    c = np.einsum("...ji,...j->...i", RAi, pj + Rj @ p_BV - pi - Ri @ p_BV)
    h = 0.5 * dpsi
    safe = np.where(np.abs(h) < 1e-3, 1.0, h)
    arc = np.where(np.abs(h) < 1e-3, 1.0 + h * h / 6.0 + 7.0 * h**4 / 360.0, safe / np.sin(safe))
    ds = arc * (np.cos(h) * c[..., 0] + np.sin(h) * c[..., 1])
    return np.stack([(ds - 0.5 * track * dpsi) / radius_left, (ds + 0.5 * track * dpsi) / radius_right], axis=-1)
