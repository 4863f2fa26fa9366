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
drive, linearised at zero.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..core import kernels
from ..core.lazy import ca
from ..core.schema import Model, PositiveFloat
from .base import FactorBlock, Kind, Nominal, Quantity, RigView, theta_columns
from .wheel import G_MPS2, axle_geometry


class NonHolonomic(Model):
    """The rear axle neither slides sideways nor lifts: lateral and vertical velocity ≈ 0, up to a
    white slip velocity of density ``*_noise_density`` [m/s/√Hz] (its information per second does
    not depend on how often the constraint is applied)."""

    lateral_noise_density: PositiveFloat = 0.05 / math.sqrt(10.0)
    vertical_noise_density: PositiveFloat = 0.05 / math.sqrt(10.0)


def sigma_mps(nh: NonHolonomic, keyframe_rate_hz: float) -> tuple[float, float]:
    """σ of the lateral and vertical velocity of the rear axle sampled at every keyframe [m/s]:
    a white slip of density q sampled at rate f has σ = q·√f."""
    f = math.sqrt(keyframe_rate_hz)
    return nh.lateral_noise_density * f, nh.vertical_noise_density * f


class NonHolonomicConstraint(Kind):
    name = "nonholonomic"
    arity = 1
    rows = 2

    def entries(self, rig: RigView) -> list:
        return [rig.config.vehicle.nonholonomic]

    def quantities(self, cfg, nh: NonHolonomic) -> list[Quantity]:
        return [Quantity("vehicle", "slip_angle", 1, "rad", 0.0, cfg.vehicle.slip.estimate, nuisance=True)]

    # --- the math ---

    def measurement(self, f):
        R_BV = ca.DM(f.R_V_B.T)
        p_BV = ca.DM(-f.R_V_B.T @ f.p_V_B)
        R, v, w = f.R[0], f.v[0], f.omega[0]
        R_BA = ca.mtimes(R_BV, f.R_V_A[0])
        R_W_A = ca.mtimes(R, R_BA)
        along = ca.mtimes(R_W_A.T, v + ca.mtimes(R, ca.cross(w, p_BV)))
        u, yaw_rate = along[0], ca.dot(R_BA[:, 2], w)
        return ca.vertcat(along[1] + f.q["slip_angle"] * u * u * yaw_rate / G_MPS2, along[2])

    def residual(self, f, meas):
        return self.measurement(f) - meas

    def sqrt_information(self, f):
        lat, vert = sigma_mps(f.entry, f.rig.keyframe_rate_hz)
        return ca.DM([1.0 / lat, 1.0 / vert])

    # --- the compiled kernel ---

    def blocks(self, nom: Nominal, rig: RigView, nh: NonHolonomic) -> FactorBlock:
        """Whitened Jacobians of the constraint at every keyframe."""
        slip = rig.config.vehicle.slip.estimate
        p_BV, R_BA, v_V = axle_geometry(nom, slip)
        sig_lat, sig_vert = sigma_mps(nh, rig.keyframe_rate_hz)
        Jx, Jt = _jacobians(nom.R, nom.v, nom.omega, R_BA, v_V, sig_lat, sig_vert, slip)
        cols = theta_columns(rig, ["vehicle.slip_angle"]) if slip else np.zeros(0, dtype=int)
        return FactorBlock("nonholonomic", np.arange(nom.n_keyframes), 1, 1, Jx, Jt, cols)

    # --- simulation ---

    def simulate(self, sim, nh: NonHolonomic) -> np.ndarray:
        """The pseudo-measurement of zero lateral and vertical axle velocity, with white slip of
        the configured σ (physical: the body also yaws into every turn by the rear tyres' slip
        angle, so the axle really slides outwards; that is the simulated drive's, not this)."""
        K = sim.nom.n_keyframes
        if not (sim.noisy and sim.settings.slip_noise):
            return np.zeros((K, 2))
        return sim.rng.normal(0.0, 1.0, (K, 2)) * np.array(sigma_mps(nh, sim.rig.keyframe_rate_hz))


@nb.njit(cache=True, nogil=True)
def _jacobians(R, v, omega_B, R_BA, v_V, sig_lat, sig_vert, slip):
    """Per keyframe, the lateral and vertical rows (e_y, e_z) of ``R_W_Aᵀ v_V`` w.r.t. the state
    ``[δθ, δp, δv]`` (the body rate is nominal), with ``v_body = Rᵀ v``::

        ∂/∂θ = R_BAᵀ [v_body]×     ∂/∂v = R_BAᵀ Rᵀ

    and, with ``slip``, the slip angle's column ``u·(u·ψ̇)/g`` (:meth:`NonHolonomicConstraint.measurement`'s
    derivative, from the axle velocities ``v_V``) in the lateral row; rows divided by their σ."""
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


