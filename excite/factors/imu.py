"""IMU preintegration between consecutive keyframes (Forster et al. 2017, errors in frame i).

Residuals of the interval ``i → j`` (ΔT long, n IMU samples of dt each, held constant over dt):

    r_R = Log(R_iᵀ R_j · ΔR(b)ᵀ)
    r_v = R_iᵀ (v_j − v_i − g ΔT) − Δv(b)
    r_p = R_iᵀ (p_j − p_i − v_i ΔT − ½ g ΔT²) − Δp(b)

with ``ΔR, Δv, Δp`` preintegrated from the gyro and accelerometer samples corrected by the
biases b (constant over the drive: they are calibration parameters). The nonlinear model
(:func:`preintegrate`) applies each sample's specific force in the attitude of the sample's
middle (a sample is the mean over its interval); the Jacobians and the covariance take the
attitude at its start, which differs from it by O(ω·dt). The covariance of the
preintegrated measurement is propagated from the Kalibr noise densities at the IMU rate
(discrete white noise σ²/dt per sample); the bias Jacobians are the exact sums of the same
discrete scheme. Both are computed for all intervals at once from running sums over the samples.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..core import kernels, so3
from ..rig.config import Rig
from ..motion.trajectory import GRAVITY
from .base import FactorBlock, Nominal, theta_columns



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
    dT = nom.t[1] - nom.t[0]
    # whiten with the inverse Cholesky factor of the covariance: W = L⁻¹, WᵀW = Σ⁻¹
    W = kernels.inverse_cholesky(pre["cov"])
    Jx, Jt = _jacobians(nom.R, nom.p, nom.v, dT, GRAVITY, pre["dR"], pre["G_R"], pre["V_g"], pre["P_g"],
                        pre["P_a"], W, imu.estimate_biases)
    cols = (theta_columns(rig, [f"imu.{k}_bias_{a}" for k in ("gyro", "accel") for a in "xyz"])
            if imu.estimate_biases else np.zeros(0, dtype=int))
    return FactorBlock("imu", np.arange(Jx.shape[0]), 1, 2, Jx, Jt, cols)


@nb.njit(cache=True, nogil=True)
def _jacobians(R, p, v, dT, g, dR, G_R, V_g, P_g, P_a, W, estimate):
    """Whitened Jacobians ``W J`` of the residuals (rotation, velocity, position rows) w.r.t. the
    states i, j ``[δθ, δp, δv]`` and the biases (b_g, b_a); with ``Δv' = R_iᵀ(v_j − v_i − g ΔT)``
    and ``Δp' = R_iᵀ(p_j − p_i − v_i ΔT − ½ g ΔT²)``::

        r_R:  ∂θ_i = −I        ∂θ_j = ΔR              ∂b_g = G_R
        r_v:  ∂θ_i = [Δv']×    ∂v_i = −R_iᵀ  ∂v_j = R_iᵀ   ∂b_g = −V_g   ∂b_a = −V_a = G_R
        r_p:  ∂θ_i = [Δp']×    ∂p_i = −R_iᵀ  ∂v_i = −R_iᵀ ΔT   ∂p_j = R_iᵀ   ∂b_g = −P_g   ∂b_a = −P_a
    """
    N = R.shape[0] - 1
    Jx = np.empty((N, 9, 18))  # every entry written below
    Jt = np.empty((N, 9, 6 if estimate else 0))
    A = np.zeros((9, 18))
    B = np.zeros((9, 6))
    X = np.empty((3, 3))
    a, dv, dp = np.empty(3), np.empty(3), np.empty(3)
    for n in range(N):
        i, j = n, n + 1
        Ri = R[i]
        for k in range(3):
            a[k] = v[j, k] - v[i, k] - g[k] * dT
        kernels.tmulv(Ri, a, dv)
        for k in range(3):
            a[k] = p[j, k] - p[i, k] - v[i, k] * dT - 0.5 * g[k] * dT * dT
        kernels.tmulv(Ri, a, dp)
        for r in range(3):
            A[r, r] = -1.0
            for c in range(3):
                A[r, 9 + c] = dR[n, r, c]
                A[3 + r, 6 + c] = -Ri[c, r]
                A[3 + r, 15 + c] = Ri[c, r]
                A[6 + r, 3 + c] = -Ri[c, r]
                A[6 + r, 6 + c] = -Ri[c, r] * dT
                A[6 + r, 12 + c] = Ri[c, r]
                B[r, c] = G_R[n, r, c]
                B[3 + r, c] = -V_g[n, r, c]
                B[6 + r, c] = -P_g[n, r, c]
                B[3 + r, 3 + c] = G_R[n, r, c]
                B[6 + r, 3 + c] = -P_a[n, r, c]
        kernels.hat(dv, X)
        kernels.put(A, 3, 0, X, 1.0)
        kernels.hat(dp, X)
        kernels.put(A, 6, 0, X, 1.0)
        Wn = W[n]
        for r in range(9):  # W is lower triangular; the inner loops run along rows of A and B
            Jr, Tr = Jx[n, r], Jt[n, r]
            w0 = Wn[r, 0]
            for c in range(18):
                Jr[c] = w0 * A[0, c]
            if estimate:
                for c in range(6):
                    Tr[c] = w0 * B[0, c]
            for k in range(1, r + 1):
                wk = Wn[r, k]
                for c in range(18):
                    Jr[c] += wk * A[k, c]
                if estimate:
                    for c in range(6):
                        Tr[c] += wk * B[k, c]
    return Jx, Jt


# --- nonlinear model (finite-difference tests, simulation, batch calibration) -----------------

def preintegrate(omega: np.ndarray, f: np.ndarray, dt: float, b_g: np.ndarray, b_a: np.ndarray):
    """``(ΔR, Δv, Δp)`` of IMU samples ``omega, f`` (n,3) held over ``dt``, minus biases. A sample
    is the mean over its interval (what an IMU outputs): its specific force is applied in the
    attitude of the interval's middle, ``ΔR_s Exp(ω_s dt/2)`` (in the attitude at its start, the
    error ½·ω·dt of attitude on the specific force shows up as an accelerometer bias)."""
    dR = np.eye(3)
    dv = np.zeros(3)
    dp = np.zeros(3)
    for w, a in zip(omega - b_g, f - b_a):
        h = so3.exp(0.5 * w * dt)  # Exp(ω dt) = Exp(ω dt/2)²
        half = dR @ h  # the mid-sample attitude
        acc = half @ a
        dp = dp + dv * dt + 0.5 * acc * dt * dt
        dv = dv + acc * dt
        dR = half @ h
    return dR, dv, dp


def residual(Ri, pi, vi, Rj, pj, vj, meas, dT: float) -> np.ndarray:
    """Unwhitened 9-vector residual (rotation, velocity, position) of one interval."""
    dR, dv, dp = meas
    rR = so3.log(Ri.T @ Rj @ dR.T)
    rv = Ri.T @ (vj - vi - GRAVITY * dT) - dv
    rp = Ri.T @ (pj - pi - vi * dT - 0.5 * GRAVITY * dT**2) - dp
    return np.concatenate([rR, rv, rp])
