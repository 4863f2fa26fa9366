"""Non-holonomic constraint: the rear axle neither slides sideways nor lifts off the road.

At every keyframe, the velocity of V's origin ``v_V = v + R_W_B (ω_B × p_B_V)`` expressed in the
road-aligned axle frame A has zero lateral and vertical components, up to the slip σ:

    r = [e_y, e_z]ᵀ R_W_Aᵀ v_V

Without it nothing ties the body's heading to its direction of travel on straight roads. The body
rate ω_B is the nominal one (the IMU measures it far better than this constraint could).
"""

from __future__ import annotations

import numpy as np

from .. import so3
from ..rig import Rig
from .base import FactorBlock, Nominal
from .wheel import _geometry


def blocks(nom: Nominal, rig: Rig) -> FactorBlock:
    """Whitened Jacobians of the constraint at every keyframe."""
    R, v = nom.R, nom.v
    _, _, R_BA = _geometry(nom)
    K = nom.n_keyframes
    R_AB = np.swapaxes(R_BA, 1, 2)
    v_body = np.einsum("nji,nj->ni", R, v)  # R_W_Bᵀ v
    J = np.zeros((K, 3, 9))
    J[:, :, 0:3] = R_AB @ so3.hat(v_body)
    J[:, :, 6:9] = R_AB @ np.swapaxes(R, 1, 2)
    Jx = J[:, 1:3] / np.array(rig.nonholonomic_sigma_mps)[None, :, None]
    return FactorBlock("nonholonomic", np.arange(K), 1, 1, Jx, np.zeros((K, 2, 0)), np.zeros(0, dtype=int))


def residual(R, v, omega_B, R_BA, p_BV) -> np.ndarray:
    """Unwhitened lateral and vertical velocity of the rear axle in the axle frame [m/s]."""
    v_V = v + R @ np.cross(omega_B, p_BV)
    return ((R @ R_BA).T @ v_V)[1:3]
