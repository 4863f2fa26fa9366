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

import numpy as np

from .. import so3
from ..rig import Rig, SensorConfig
from .base import FactorBlock, Nominal, theta_columns


def blocks(nom: Nominal, rig: Rig, sensor: SensorConfig) -> FactorBlock | None:
    """Whitened Jacobians of every relative-pose measurement of ``sensor`` (None if < 2 frames)."""
    stride = int(round(rig.keyframe_rate_hz / sensor.rate_hz))
    frames = np.arange(0, nom.n_keyframes, stride)
    if frames.size < 2:
        return None
    i, j = frames[:-1], frames[1:]
    N = i.size
    R, p, v, w = nom.R, nom.p, nom.v, nom.omega
    R_BS, p_BS = sensor.T_B_S.R, sensor.T_B_S.p
    R_SB = R_BS.T
    Ri, Rj = R[i], R[j]
    RiT = np.swapaxes(Ri, 1, 2)
    Rij = RiT @ Rj
    e = np.einsum("nij,nj->ni", RiT, p[j] - p[i]) + Rij @ p_BS  # d + p_BS
    d = e - p_BS
    t_rel = d @ R_SB.T
    R_rel = R_SB @ Rij @ R_BS
    hat_pBS = so3.hat(p_BS)

    Jx = np.zeros((N, 6, 18))
    Jx[:, 0:3, 0:3] = -R_SB @ np.swapaxes(Rij, 1, 2)
    Jx[:, 0:3, 9:12] = R_SB
    Jx[:, 3:6, 0:3] = R_SB @ so3.hat(e)
    Jx[:, 3:6, 3:6] = -R_SB @ RiT
    Jx[:, 3:6, 9:12] = -R_SB @ Rij @ hat_pBS
    Jx[:, 3:6, 12:15] = R_SB @ RiT

    name = sensor.name
    names = [c.name for c in rig.coordinates if c.block == name]
    cols = theta_columns(rig, names)
    Jt = np.zeros((N, 6, len(names)))
    if sensor.estimate.extrinsic:
        r0 = names.index(f"{name}.rot_x")
        t0 = names.index(f"{name}.trans_x")
        Jt[:, 0:3, r0:r0 + 3] = np.eye(3) - np.swapaxes(R_rel, 1, 2)
        Jt[:, 3:6, r0:r0 + 3] = so3.hat(t_rel)
        Jt[:, 3:6, t0:t0 + 3] = R_SB @ (Rij - np.eye(3))
    if sensor.estimate.time_offset:
        k = names.index(f"{name}.time_offset")
        wi, wj = w[i], w[j]
        Jt[:, 0:3, k] = (wj - np.einsum("nji,nj->ni", Rij, wi)) @ R_SB.T
        dt_t = (np.cross(e, wi) + np.einsum("nji,nj->ni", Ri, v[j] - v[i])
                + np.einsum("nij,nj->ni", Rij, np.cross(wj, p_BS)))
        Jt[:, 3:6, k] = dt_t @ R_SB.T
    if sensor.monocular:
        Jt[:, 3:6, names.index(f"{name}.scale")] = t_rel

    sig_r = np.deg2rad(sensor.noise.rotation_sigma_deg)
    sig_t = sensor.noise.translation_sigma_m
    Jx[:, 0:3] /= sig_r
    Jt[:, 0:3] /= sig_r
    Jx[:, 3:6] /= sig_t
    Jt[:, 3:6] /= sig_t
    return FactorBlock(name, i, stride, 2, Jx, Jt, cols)


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
