"""IMU preintegration between consecutive keyframes (Forster et al. 2017, errors in frame i).

Residuals of the interval ``i → j`` (ΔT long, n IMU samples of dt each, held constant over dt):

    r_R = Log(R_iᵀ R_j · ΔR(b)ᵀ)
    r_v = R_iᵀ (v_j − v_i − g ΔT) − Δv(b)
    r_p = R_iᵀ (p_j − p_i − v_i ΔT − ½ g ΔT²) − Δp(b)

with ``ΔR, Δv, Δp`` preintegrated from the gyro and accelerometer samples corrected by the
biases b (constant over the drive: they are calibration parameters). The covariance of the
preintegrated measurement is propagated from the Kalibr noise densities at the IMU rate
(discrete white noise σ²/dt per sample); the bias Jacobians are the exact sums of the same
discrete scheme. Both are computed for all intervals at once from running sums over the samples.
"""

from __future__ import annotations

import numpy as np

from .. import so3
from ..rig import Rig
from ..trajectory import GRAVITY
from .base import ROT, FactorBlock, Nominal

# residual row order: rotation, velocity, position (state columns are rotation, position, velocity)
VEL_R, POS_R = slice(3, 6), slice(6, 9)


def _excl_cumsum(a: np.ndarray, axis: int = 1) -> np.ndarray:
    """Exclusive cumulative sum: ``out[s] = Σ_{q<s} a[q]``."""
    c = np.cumsum(a, axis=axis)
    return c - a


def preintegration(nom: Nominal, sigma_g: float, sigma_a: float) -> dict[str, np.ndarray]:
    """Bias Jacobians and covariance of every interval's preintegrated measurement.

    Returns ``dR (N,3,3) = R_iᵀR_j``, ``G_R = ∂r_R/∂b_g``, ``V_g, V_a, P_g, P_a`` (∂Δv, ∂Δp
    w.r.t. gyro and accelerometer bias) and ``cov (N,9,9)`` ordered (rotation, velocity, position).
    """
    n = nom.imu_per_keyframe
    N = nom.n_keyframes - 1
    dt = (nom.t[1] - nom.t[0]) / n
    R_all = nom.imu.R_W_B
    f_all = nom.imu.specific_force_B
    R_i = R_all[: N * n : n]  # (N,3,3)
    # samples s = 0..n-1 of each interval
    Rs = R_all[: N * n].reshape(N, n, 3, 3)
    fs = f_all[: N * n].reshape(N, n, 3)
    dRs = np.einsum("nji,nsjk->nsik", R_i, Rs)  # ΔR_s = R_iᵀ R(τ_s)
    a_i = np.einsum("nsij,nsj->nsi", dRs, fs)  # specific force in frame i
    A = so3.hat(a_i) * dt  # [a]× dt

    # Bias Jacobians (left-rectangle scheme: sample s acts over [τ_s, τ_s + dt)).
    G_s = _excl_cumsum(dRs * dt)  # ∂(rotation error in frame i)/∂b_g before sample s (negated)
    G_R = G_s[:, -1] + dRs[:, -1] * dt
    AG = A @ G_s
    Vg_s = _excl_cumsum(AG)
    V_g = Vg_s[:, -1] + AG[:, -1]
    P_g = (Vg_s * dt + 0.5 * dt * AG).sum(axis=1)
    V_a = -G_R
    Va_s = -G_s
    P_a = (Va_s * dt - 0.5 * dt * dt * dRs).sum(axis=1)

    # Covariance. Gyro noise w entering at sample s reaches the end as
    # [−I; SA_{s+1}; SP_{s+1}] w with SA_m = Σ_{q≥m} A_q and SP_m = dt Σ_{q≥m} (n−1−q+½) A_q.
    q = np.arange(n)
    SA = np.cumsum(A[:, ::-1], axis=1)[:, ::-1]  # SA_s = Σ_{q≥s}
    w = (n - 1 - q + 0.5) * dt
    SP = np.cumsum((A * w[None, :, None, None])[:, ::-1], axis=1)[:, ::-1]
    zero = np.zeros((N, 1, 3, 3))
    SA1 = np.concatenate([SA[:, 1:], zero], axis=1)  # SA_{s+1}
    SP1 = np.concatenate([SP[:, 1:], zero], axis=1)
    # stack as (N, 3, 3n) so that Σ_s X_s Y_sᵀ is one batched product
    flatA = SA1.transpose(0, 2, 1, 3).reshape(N, 3, 3 * n)
    flatP = SP1.transpose(0, 2, 1, 3).reshape(N, 3, 3 * n)
    g2 = sigma_g**2 * dt
    cov = np.zeros((N, 9, 9))
    eye = np.eye(3)
    cov[:, ROT, ROT] = g2 * n * eye
    cov[:, VEL_R, ROT] = -g2 * SA1.sum(axis=1)
    cov[:, POS_R, ROT] = -g2 * SP1.sum(axis=1)
    cov[:, VEL_R, VEL_R] = g2 * flatA @ flatA.transpose(0, 2, 1)
    cov[:, POS_R, VEL_R] = g2 * flatP @ flatA.transpose(0, 2, 1)
    cov[:, POS_R, POS_R] = g2 * flatP @ flatP.transpose(0, 2, 1)
    # Accelerometer noise u = ΔR_s η dt (isotropic) reaches the end as [0; −I; −(n−1−s+½) dt I] u.
    a2 = sigma_a**2 * dt
    cov[:, VEL_R, VEL_R] += a2 * n * eye
    cov[:, POS_R, VEL_R] += a2 * w.sum() * eye
    cov[:, POS_R, POS_R] += a2 * (w**2).sum() * eye
    cov[:, ROT, VEL_R] = np.swapaxes(cov[:, VEL_R, ROT], 1, 2)
    cov[:, ROT, POS_R] = np.swapaxes(cov[:, POS_R, ROT], 1, 2)
    cov[:, VEL_R, POS_R] = np.swapaxes(cov[:, POS_R, VEL_R], 1, 2)
    dR = np.einsum("nji,njk->nik", R_i, R_all[n::n][:N])
    return dict(dR=dR, G_R=G_R, V_g=V_g, V_a=V_a, P_g=P_g, P_a=P_a, cov=cov)


def blocks(nom: Nominal, rig: Rig) -> FactorBlock:
    """Whitened Jacobians of every keyframe interval's preintegrated IMU factor."""
    imu = rig.config.imu
    pre = preintegration(nom, imu.gyroscope_noise_density, imu.accelerometer_noise_density)
    N = nom.n_keyframes - 1
    dT = nom.t[1] - nom.t[0]
    R, p, v = nom.R, nom.p, nom.v
    Ri, Rj = R[:-1], R[1:]
    RiT = np.swapaxes(Ri, 1, 2)
    dv = np.einsum("nji,nj->ni", Ri, v[1:] - v[:-1] - GRAVITY * dT)
    dp = np.einsum("nji,nj->ni", Ri, p[1:] - p[:-1] - v[:-1] * dT - 0.5 * GRAVITY * dT**2)

    Jx = np.zeros((N, 9, 18))
    eye = np.eye(3)
    # state i at columns 0..8, state j at 9..17; within a state: rot, pos, vel
    Jx[:, ROT, 0:3] = -eye
    Jx[:, ROT, 9:12] = pre["dR"]
    Jx[:, VEL_R, 0:3] = so3.hat(dv)
    Jx[:, VEL_R, 6:9] = -RiT
    Jx[:, VEL_R, 15:18] = RiT
    Jx[:, POS_R, 0:3] = so3.hat(dp)
    Jx[:, POS_R, 3:6] = -RiT
    Jx[:, POS_R, 6:9] = -RiT * dT
    Jx[:, POS_R, 12:15] = RiT

    Jt = np.zeros((N, 9, len(rig.coordinates)))
    if imu.estimate_biases:
        g = rig.index("imu.gyro_bias_x")
        a = rig.index("imu.accel_bias_x")
        Jt[:, ROT, g:g + 3] = pre["G_R"]
        Jt[:, VEL_R, g:g + 3] = -pre["V_g"]
        Jt[:, POS_R, g:g + 3] = -pre["P_g"]
        Jt[:, VEL_R, a:a + 3] = -pre["V_a"]
        Jt[:, POS_R, a:a + 3] = -pre["P_a"]

    # whiten with the inverse Cholesky factor of the covariance: W = L⁻¹, WᵀW = Σ⁻¹
    L = np.linalg.cholesky(pre["cov"])
    Jx = np.linalg.solve(L, Jx)
    Jt = np.linalg.solve(L, Jt)
    return FactorBlock("imu", np.arange(N), 1, 2, Jx, Jt)


# --- nonlinear model (finite-difference tests, simulation, batch calibration) -----------------

def preintegrate(omega: np.ndarray, f: np.ndarray, dt: float, b_g: np.ndarray, b_a: np.ndarray):
    """``(ΔR, Δv, Δp)`` of IMU samples ``omega, f`` (n,3) held over ``dt``, minus biases."""
    dR = np.eye(3)
    dv = np.zeros(3)
    dp = np.zeros(3)
    for w, a in zip(omega - b_g, f - b_a):
        acc = dR @ a
        dp = dp + dv * dt + 0.5 * acc * dt * dt
        dv = dv + acc * dt
        dR = dR @ so3.exp(w * dt)
    return dR, dv, dp


def residual(Ri, pi, vi, Rj, pj, vj, meas, dT: float) -> np.ndarray:
    """Unwhitened 9-vector residual (rotation, velocity, position) of one interval."""
    dR, dv, dp = meas
    rR = so3.log(Ri.T @ Rj @ dR.T)
    rv = Ri.T @ (vj - vi - GRAVITY * dT) - dv
    rp = Ri.T @ (pj - pi - vi * dT - 0.5 * GRAVITY * dT**2) - dp
    return np.concatenate([rR, rv, rp])
