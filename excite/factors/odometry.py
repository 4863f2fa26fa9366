"""Relative pose of an exteroceptive sensor (lidar or camera odometry) between consecutive frames.

The sensor's pose at frame i is ``T_W_B(t_i + t_d) · T_B_S``; the body pose at ``t_i + t_d`` is
taken to first order from keyframe i through the body's angular and linear velocity. Frames
coincide with every ``stride``-th keyframe. Residual (rotation, translation) in frame ``S_i``:

    r_R = Log(R_measᵀ R_rel),   r_t = s · t_rel − t_meas

with ``R_rel = R_S_iᵀ R_S_j``, ``t_rel = R_S_iᵀ (p_S_j − p_S_i)`` and s the unknown scale of a
monocular camera (1 otherwise). Extrinsic perturbations are right-multiplicative on ``R_B_S`` and
additive on ``p_B_S``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..core import kernels, so3
from ..rig.config import Rig, SensorConfig
from .base import FactorBlock, Nominal, theta_columns


def blocks(nom: Nominal, rig: Rig, sensor: SensorConfig) -> FactorBlock | None:
    """Whitened Jacobians of every relative-pose measurement of ``sensor`` (None if < 2 frames)."""
    stride = int(round(rig.keyframe_rate_hz / sensor.rate_hz))
    N = (nom.n_keyframes - 1) // stride
    if N < 1:
        return None
    name = sensor.name
    names = [c.name for c in rig.coordinates if c.block == name]
    at = lambda key, on: names.index(f"{name}.{key}") if on else -1  # noqa: E731
    Jx, Jt = _jacobians(nom.R, nom.p, nom.v, nom.omega, stride, sensor.T_B_S.R, sensor.T_B_S.p,
                        at("rot_x", sensor.estimate.extrinsic), at("trans_x", sensor.estimate.extrinsic),
                        at("time_offset", sensor.estimate.time_offset), at("scale", sensor.monocular), len(names),
                        np.deg2rad(sensor.noise.rotation_sigma_deg), sensor.noise.translation_sigma_m)
    return FactorBlock(name, np.arange(N) * stride, stride, 2, Jx, Jt, theta_columns(rig, names))


@nb.njit(cache=True, nogil=True)
def _jacobians(R, p, v, w, stride, R_BS, p_BS, c_rot, c_trans, c_time, c_scale, n_cols, sig_r, sig_t):
    """Per frame pair ``i → j = i + stride``, with ``R_ij = R_iᵀR_j``, ``e = R_iᵀ(p_j − p_i) + R_ij p_BS``
    and ``t_rel = R_SB (e − p_BS)``: the Jacobians of ``r_R`` and ``r_t`` w.r.t. the states i, j
    ``[δθ, δp, δv]`` and the sensor's columns (``c_*``: position among them, −1 if not estimated)::

        ∂r_R/∂θ_i = −R_SB R_ijᵀ    ∂r_R/∂θ_j = R_SB
        ∂r_t/∂θ_i = R_SB [e]×      ∂r_t/∂p_i = −R_SB R_iᵀ
        ∂r_t/∂θ_j = −R_SB R_ij [p_BS]×    ∂r_t/∂p_j = R_SB R_iᵀ
        ∂r_R/∂rot = I − R_relᵀ     ∂r_t/∂rot = [t_rel]×     ∂r_t/∂trans = R_SB (R_ij − I)
        ∂r_R/∂t_d = R_SB (ω_j − R_ijᵀ ω_i)
        ∂r_t/∂t_d = R_SB (e × ω_i + R_iᵀ(v_j − v_i) + R_ij (ω_j × p_BS))
        ∂r_t/∂s = t_rel

    rows divided by their σ."""
    N = (R.shape[0] - 1) // stride
    Jx = np.empty((N, 6, 18))  # each factor's rows are zeroed where they are written (in cache)
    Jt = np.empty((N, 6, n_cols))
    R_SB = R_BS.T.copy()
    hp = np.empty((3, 3))
    kernels.hat(p_BS, hp)
    Rij, X, Y, M = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    e, t_rel, a, b, c = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    ir, it = 1.0 / sig_r, 1.0 / sig_t
    for n in range(N):
        i = n * stride
        j = i + stride
        Ri, Rj = R[i], R[j]
        J, T = Jx[n], Jt[n]
        J[:] = 0.0
        T[:] = 0.0
        kernels.tmul(Ri, Rj, Rij)
        for k in range(3):
            a[k] = p[j, k] - p[i, k]
        kernels.tmulv(Ri, a, e)
        kernels.mulv(Rij, p_BS, b)
        for k in range(3):
            e[k] += b[k]
            b[k] = e[k] - p_BS[k]
        kernels.mulv(R_SB, b, t_rel)
        kernels.mul(Rij, R_BS, X)  # (R_SB R_ijᵀ)ᵀ
        for r in range(3):
            for k in range(3):
                J[r, k] = -X[k, r] * ir
        kernels.put(J, 0, 9, R_SB, ir)
        kernels.hat(e, M)
        kernels.mul(R_SB, M, Y)
        kernels.put(J, 3, 0, Y, it)
        kernels.mult(R_SB, Ri, Y)  # R_SB R_iᵀ
        kernels.put(J, 3, 3, Y, -it)
        kernels.put(J, 3, 12, Y, it)
        kernels.mul(R_SB, Rij, M)
        kernels.mul(M, hp, Y)
        kernels.put(J, 3, 9, Y, -it)
        if c_rot >= 0:
            kernels.mul(M, R_BS, Y)  # R_rel
            for r in range(3):
                for k in range(3):
                    T[r, c_rot + k] = ((1.0 if r == k else 0.0) - Y[k, r]) * ir
            kernels.hat(t_rel, Y)
            for r in range(3):
                for k in range(3):
                    T[3 + r, c_rot + k] = Y[r, k] * it
        if c_trans >= 0:
            for r in range(3):
                for k in range(3):
                    T[3 + r, c_trans + k] = (M[r, k] - R_SB[r, k]) * it
        if c_time >= 0:
            kernels.tmulv(Rij, w[i], a)
            for k in range(3):
                a[k] = w[j, k] - a[k]
            kernels.mulv(R_SB, a, b)
            for r in range(3):
                T[r, c_time] = b[r] * ir
            kernels.cross(e, w[i], a)
            for k in range(3):
                c[k] = v[j, k] - v[i, k]
            kernels.tmulv(Ri, c, b)
            for k in range(3):
                a[k] += b[k]
            kernels.cross(w[j], p_BS, c)
            kernels.mulv(Rij, c, b)
            for k in range(3):
                a[k] += b[k]
            kernels.mulv(R_SB, a, b)
            for r in range(3):
                T[3 + r, c_time] = b[r] * it
        if c_scale >= 0:
            for r in range(3):
                T[3 + r, c_scale] = t_rel[r] * it
    return Jx, Jt


# --- nonlinear model ---------------------------------------------------------------------------

def sensor_pose(R, p, v, w, R_BS, p_BS, t_d):
    """Pose of the sensor at body time ``t + t_d`` (first order in ``t_d``)."""
    Rb = R @ so3.exp(w * t_d)
    pb = p + v * t_d
    return Rb @ R_BS, pb + Rb @ p_BS


def residual(state_i, state_j, R_BS, p_BS, t_d, scale, meas) -> np.ndarray:
    """Unwhitened 6-vector residual; ``state = (R, p, v, omega_B)``, ``meas = (R_rel, t_rel)``."""
    RSi, pSi = sensor_pose(*state_i, R_BS, p_BS, t_d)
    RSj, pSj = sensor_pose(*state_j, R_BS, p_BS, t_d)
    R_rel = RSi.T @ RSj
    t_rel = RSi.T @ (pSj - pSi)
    return np.concatenate([so3.log(meas[0].T @ R_rel), scale * t_rel - meas[1]])
