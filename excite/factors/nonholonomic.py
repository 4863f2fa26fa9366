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

import numpy as np

from ..core.lazy import ca
from ..core.schema import Model, PositiveFloat
from .base import ConfigView, Expr, FactorInputs, Kind, Quantity, RigView, SimulationView
from .wheel import G_MPS2


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


class NonHolonomicConstraint(Kind[NonHolonomic]):
    name = "nonholonomic"
    arity = 1
    rows = 2

    def entries(self, rig: RigView) -> list[NonHolonomic]:
        return [rig.config.vehicle.nonholonomic]

    def quantities(self, cfg: ConfigView, nh: NonHolonomic) -> list[Quantity]:
        return [Quantity("vehicle", "slip_angle", 1, "rad", 0.0, cfg.vehicle.slip.estimate, nuisance=True,
                         per_entry=False)]

    # --- the math ---

    def measurement(self, f: FactorInputs) -> Expr:
        R_BV = f.R_V_B.T
        p_BV = -ca.mtimes(R_BV, f.p_V_B)
        R, v, w = f.R[0], f.v[0], f.omega[0]
        R_BA = ca.mtimes(R_BV, f.R_V_A[0])
        R_W_A = ca.mtimes(R, R_BA)
        along = ca.mtimes(R_W_A.T, v + ca.mtimes(R, ca.cross(w, p_BV)))
        u, yaw_rate = along[0], ca.dot(R_BA[:, 2], w)
        return ca.vertcat(along[1] + f.q["slip_angle"] * u * u * yaw_rate / G_MPS2, along[2])

    def residual(self, f: FactorInputs, meas: Expr) -> Expr:
        return self.measurement(f) - meas

    def constants(self, rig: RigView, nh: NonHolonomic) -> dict[str, np.ndarray]:
        return {"sigma": np.array(sigma_mps(nh, rig.keyframe_rate_hz))}

    def sqrt_information(self, f: FactorInputs) -> Expr:
        return 1.0 / f.c["sigma"]

    # --- simulation ---

    def simulate(self, sim: SimulationView, nh: NonHolonomic) -> np.ndarray:
        """The pseudo-measurement of zero lateral and vertical axle velocity, with white slip of
        the configured σ (physical: the body also yaws into every turn by the rear tyres' slip
        angle, so the axle really slides outwards; that is the simulated drive's, not this)."""
        K = sim.nom.n_keyframes
        if not (sim.noisy and sim.settings.slip_noise):
            return np.zeros((K, 2))
        return sim.rng.normal(0.0, 1.0, (K, 2)) * np.array(sigma_mps(nh, sim.rig.keyframe_rate_hz))
