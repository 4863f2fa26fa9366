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

from .. import kernels, so3
from ..rig import Rig
from ..trajectory import GRAVITY
from .base import ROT, FactorBlock, Nominal, theta_columns

# residual row order: rotation, velocity, position (state columns are rotation, position, velocity)
VEL_R, POS_R = slice(3, 6), slice(6, 9)


def preintegration(nom: Nominal, sigma_g: float, sigma_a: float) -> dict[str, np.ndarray]:
    """Bias Jacobians and covariance of every interval's preintegrated measurement.

    Returns ``dR (N,3,3) = R_iᵀR_j``, ``G_R = ∂r_R/∂b_g``, ``V_g, V_a, P_g, P_a`` (∂Δv, ∂Δp
    w.r.t. gyro and accelerometer bias) and ``cov (N,9,9)`` ordered (rotation, velocity, position).

    Sample s of an interval (n samples of dt) acts over ``[τ_s, τ_s + dt)`` with ``ΔR_s = R_iᵀR(τ_s)``
    and ``A_s = [ΔR_s f_s]× dt``. A rotation error w entering after sample s (gyro noise, or
    ``−ΔR_s dt δb_g``) reaches the end of the interval as ``[−I; SA_{s+1}; SP_{s+1}] w`` with
    ``SA_m = Σ_{q≥m} A_q`` and ``SP_m = Σ_{q≥m} w_q A_q``, ``w_q = (n − 1 − q + ½) dt``; an
    accelerometer error u as ``[0; −I; −w_s I] u``. Every Jacobian and the covariance are sums
    over s of these terms.
    """
    n = nom.imu_per_keyframe
    N = nom.n_keyframes - 1
    dt = (nom.t[1] - nom.t[0]) / n
    dR, G_R, V_g, P_g, P_a, cov = kernels.preintegration(nom.imu_R, nom.imu_f, n, N, dt, sigma_g, sigma_a)
    V_a = -G_R
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
    dv = (RiT @ (v[1:] - v[:-1] - GRAVITY * dT)[:, :, None])[..., 0]
    dp = (RiT @ (p[1:] - p[:-1] - v[:-1] * dT - 0.5 * GRAVITY * dT**2)[:, :, None])[..., 0]

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

    if imu.estimate_biases:
        cols = theta_columns(rig, [f"imu.{k}_bias_{a}" for k in ("gyro", "accel") for a in "xyz"])
        Jt = np.zeros((N, 9, 6))
        Jt[:, ROT, 0:3] = pre["G_R"]
        Jt[:, VEL_R, 0:3] = -pre["V_g"]
        Jt[:, POS_R, 0:3] = -pre["P_g"]
        Jt[:, VEL_R, 3:6] = -pre["V_a"]
        Jt[:, POS_R, 3:6] = -pre["P_a"]
    else:
        cols, Jt = np.zeros(0, dtype=int), np.zeros((N, 9, 0))

    # whiten with the inverse Cholesky factor of the covariance: W = L⁻¹, WᵀW = Σ⁻¹
    W = kernels.inverse_cholesky(pre["cov"])
    Jx = W @ Jx
    Jt = W @ Jt
    return FactorBlock("imu", np.arange(N), 1, 2, Jx, Jt, cols)


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
