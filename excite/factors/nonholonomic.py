"""Non-holonomic constraint: the rear axle neither slides sideways nor lifts off the road.

At every keyframe, the velocity of V's origin ``v_V = v + R_W_B (ω_B × p_B_V)`` expressed in the
road-aligned axle frame A has zero lateral and vertical components, up to the slip σ:

    r = [e_y, e_z]ᵀ R_W_Aᵀ v_V

Without it nothing ties the body's heading to its direction of travel on straight roads. The body
rate ω_B is the nominal one (the IMU measures it far better than this constraint could).

In a turn the rear tyres run at a slip angle ``β = slip_angle·a_lat/g`` and the axle slides
outwards at ``u·β`` (``u`` its forward speed). With ``vehicle.slip`` estimated, the lateral row
is ``e_yᵀ R_W_Aᵀ v_V + slip_angle·u·(u·ψ̇)/g`` with ``a_lat ≈ u·ψ̇`` (ψ̇ the yaw rate about A's
normal): ``slip_angle`` (``vehicle.slip_angle``, the slip angle at 1 g, rad) is a nuisance of the
drive, linearised at zero (:func:`lateral_slip_regressor`).
"""

from __future__ import annotations

import numpy as np

from .. import so3
from ..rig import Rig
from .base import FactorBlock, Nominal, theta_columns
from .wheel import G_MPS2, _geometry, axle_velocity


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
    sig = np.array(rig.nonholonomic_sigma_mps)
    Jx = J[:, 1:3] / sig[None, :, None]
    if not rig.config.vehicle.slip.estimate:
        return FactorBlock("nonholonomic", np.arange(K), 1, 1, Jx, np.zeros((K, 2, 0)), np.zeros(0, dtype=int))
    _, p_BV, _ = _geometry(nom)
    Jt = np.zeros((K, 2, 1))
    Jt[:, 0, 0] = lateral_slip_regressor(R @ R_BA, axle_velocity(R, v, nom.omega, p_BV), nom.omega, R_BA) / sig[0]
    return FactorBlock("nonholonomic", np.arange(K), 1, 1, Jx, Jt, theta_columns(rig, ["vehicle.slip_angle"]))


def lateral_slip_regressor(R_W_A, v_V, omega_B, R_BA) -> np.ndarray:
    """``u·(u·ψ̇)/g`` at every keyframe [m/s]: the rear axle's outward slide per unit slip angle at
    1 g, ``u`` its forward speed (from its world velocity ``v_V``, :func:`~excite.factors.wheel.axle_velocity`)
    and ψ̇ the yaw rate about A's normal (stacks (K,3,3), (K,3), (K,3), (K,3,3) → (K,))."""
    u = np.einsum("kj,kj->k", R_W_A[:, :, 0], v_V)  # e_xᵀ R_W_Aᵀ v_V
    yaw_rate = np.einsum("kj,kj->k", R_BA[:, :, 2], omega_B)  # e_zᵀ R_BAᵀ ω_B
    return u * u * yaw_rate / G_MPS2


def residual(R, v, omega_B, R_BA, p_BV, slip_angle: float = 0.0) -> np.ndarray:
    """Unwhitened lateral and vertical velocity of the rear axle in the axle frame [m/s], less the
    outward slide of a slip angle of ``slip_angle`` at 1 g (one keyframe)."""
    v_V = axle_velocity(R[None], v[None], omega_B[None], p_BV)
    R_W_A = R[None] @ R_BA[None]
    r = (R_W_A[0].T @ v_V[0])[1:3]
    r[0] += slip_angle * lateral_slip_regressor(R_W_A, v_V, omega_B[None], R_BA[None])[0]
    return r
