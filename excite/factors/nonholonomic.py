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

import numba as nb
import numpy as np

from ..core import kernels
from ..rig.config import Rig
from .base import FactorBlock, Nominal, theta_columns
from .wheel import G_MPS2, _geometry, axle_velocity


def blocks(nom: Nominal, rig: Rig) -> FactorBlock:
    """Whitened Jacobians of the constraint at every keyframe."""
    slip = rig.config.vehicle.slip.estimate
    p_BV, R_BA, v_V = _geometry(nom, slip)
    sig_lat, sig_vert = rig.nonholonomic_sigma_mps
    Jx, Jt = _jacobians(nom.R, nom.v, nom.omega, R_BA, v_V, sig_lat, sig_vert, slip)
    K = nom.n_keyframes
    cols = theta_columns(rig, ["vehicle.slip_angle"]) if slip else np.zeros(0, dtype=int)
    return FactorBlock("nonholonomic", np.arange(K), 1, 1, Jx, Jt, cols)


@nb.njit(cache=True, nogil=True)
def _jacobians(R, v, omega_B, R_BA, v_V, sig_lat, sig_vert, slip):
    """Per keyframe, the lateral and vertical rows (e_y, e_z) of ``R_W_Aᵀ v_V`` w.r.t. the state
    ``[δθ, δp, δv]`` (the body rate is nominal), with ``v_body = Rᵀ v``::

        ∂/∂θ = R_BAᵀ [v_body]×     ∂/∂v = R_BAᵀ Rᵀ

    and, with ``slip``, the slip angle's column :func:`lateral_slip_regressor` (from the axle
    velocities ``v_V``) in the lateral row; rows divided by their σ."""
    K = R.shape[0]
    Jx = np.empty((K, 2, 9))  # zeroed per keyframe, in cache
    Jt = np.empty((K, 2, 1 if slip else 0))
    sig = (sig_lat, sig_vert)
    vb = np.empty(3)
    X, Y, RA = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    for k in range(K):
        Jx[k] = 0.0
        Jt[k] = 0.0
        kernels.tmulv(R[k], v[k], vb)
        kernels.hat(vb, X)
        kernels.tmul(R_BA[k], X, Y)  # R_BAᵀ [v_body]×
        kernels.mul(R[k], R_BA[k], RA)  # R_W_A; R_BAᵀ Rᵀ = R_W_Aᵀ
        for r in range(2):
            for c in range(3):
                Jx[k, r, c] = Y[1 + r, c] / sig[r]
                Jx[k, r, 6 + c] = RA[c, 1 + r] / sig[r]
        if slip:
            u = RA[0, 0] * v_V[k, 0] + RA[1, 0] * v_V[k, 1] + RA[2, 0] * v_V[k, 2]
            yaw_rate = R_BA[k, 0, 2] * omega_B[k, 0] + R_BA[k, 1, 2] * omega_B[k, 1] + R_BA[k, 2, 2] * omega_B[k, 2]
            Jt[k, 0, 0] = u * u * yaw_rate / G_MPS2 / sig_lat
    return Jx, Jt


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
