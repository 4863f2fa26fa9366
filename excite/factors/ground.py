"""The road plane a lidar sees: its height, roll and pitch against the vehicle, where driving
cannot reach them.

Planar driving leaves a lidar's height (``trans_z``) and, without brisk pitching and rolling,
its roll and pitch nearly undetermined by odometry. A lidar that sees the road measures them
directly: per frame, the road plane fitted to its returns from the ground — in the sensor frame
S, the plane ``{x : nᵀx + h = 0}`` of upward unit normal ``n`` and the sensor's height ``h``
above it. Predicted from the calibration, with the road-aligned axle frame A (origin at the rear
axle's centre, ``vehicle.axle_height_m`` above the road, tilted from the body by the suspension
``R_V_A``):

    R_A_S = R_V_Aᵀ R_V_B R_B_S,   p_A_S = R_V_Aᵀ (p_V_B + R_V_B p_B_S)
    n = R_A_Sᵀ e_z,               h = e_zᵀ p_A_S + axle_height

and the residual is ``[n, h]`` predicted less measured (four rows; the normal's component along
itself is no direction of the plane and carries no information).

**Information.** The fit of a frame's ground returns (points ``p`` in S, range noise σ_r, weights
``w`` of the scan's quadrature: :mod:`excite.scene.lidar`) holds ``F = Pᵀ (Σ w/σ_r² [p; 1][p; 1]ᵀ) P``
about ``[δn, δh]``, ``P = diag(I − nnᵀ, 1)``. What the fit measures is the road under the
sensor's view, not the plane the vehicle stands on: the road's own tilt and height under a
patch of ``patch_length_m`` (``road_tilt_sigma_deg``, ``road_height_sigma_m``) and the
suspension's tilt, known to a fraction ``suspension_uncertainty`` of itself, add the covariance
``Q``. The frames within one patch share its road (the m frames of the drive within half a
patch of a frame's position), so a frame holds ``Λ = F (I + m Q F)⁻¹``: m frames together hold
``mF (I + Q mF)⁻¹``, the patch's worth and no more. Standing still on level ground, the whole
stop is one patch: the lidar's height and tilt to the road's σ; driving over a level road, every
patch adds its own.

The factor exists only where the drive sees a scene with ground (:func:`excite.scene.along.seen`);
its statement's whitening is zero, so the optimizer's planned drives, which see no scene, ignore it.
"""

from __future__ import annotations

import numpy as np

from ..core import so3
from ..core.lazy import ca
from . import base
from .base import ConfigView, Expr, FactorInputs, Kind, Nominal, Quantity, RigView, SimulationView
from .odometry import OdometrySensor, sqrt_psd


def _lidars(rig) -> list[OdometrySensor]:
    return [s for s in rig.config.sensors if s.kind == "lidar" and s.ground_plane.enabled]


class GroundPlane(Kind[OdometrySensor]):
    name = "ground_plane"
    arity = 1
    rows = 4
    def entries(self, rig: RigView) -> list[OdometrySensor]:
        return _lidars(rig)

    def block_name(self, entry: OdometrySensor) -> str:
        return f"{entry.name}_ground"

    def quantities(self, cfg: ConfigView, s: OdometrySensor) -> list[Quantity]:
        ext = s.estimate.extrinsic
        return [Quantity(s.name, "rot", 3, "rad", s.T_B_S.R, ext), Quantity(s.name, "trans", 3, "m", s.T_B_S.p, ext)]

    # --- the math ---

    def measurement(self, f: FactorInputs) -> Expr:
        R_AV = f.R_V_A[0].T
        R_AS = ca.mtimes(R_AV, ca.mtimes(f.R_V_B, f.q["rot"]))
        p_AS = ca.mtimes(R_AV, f.p_V_B + ca.mtimes(f.R_V_B, f.q["trans"]))
        return ca.vertcat(R_AS[2, :].T, p_AS[2] + f.c["axle_height"])

    def residual(self, f: FactorInputs, meas: Expr) -> Expr:
        return self.measurement(f) - meas

    def constants(self, rig: RigView, s: OdometrySensor) -> dict[str, np.ndarray]:
        return {"axle_height": np.array(rig.config.vehicle.axle_height_m)}

    def sqrt_information(self, f: FactorInputs) -> Expr:
        return ca.DM.zeros(4, 1)  # only a scene's whitening (:meth:`whitening`) informs it

    def factor_keyframes(self, rig: RigView, s: OdometrySensor, n_keyframes: int,
                         nom: Nominal | None = None) -> np.ndarray:
        """The lidar's frames where the drive sees ground (none on a drive without a scene; every
        frame where no drive is given)."""
        k = base.frames(self, rig, s, n_keyframes)
        if nom is None:
            return k
        if s.name not in nom.ground:
            return np.zeros(0, dtype=int)
        G = nom.ground[s.name]
        return k[G[k, 3, 3] > 0]

    def whitening(self, nom: Nominal, rig: RigView, s: OdometrySensor, first: np.ndarray) -> np.ndarray:
        return sqrt_psd(information(nom, rig, s, first))

    # --- simulation ---

    def simulate(self, sim: SimulationView, s: OdometrySensor) -> np.ndarray:
        """The plane each frame's fit finds: the true extrinsic's, with an error of the frame's
        covariance (``Λ⁺``: none along the directions it does not see) — as the model assumes."""
        k = self.factor_keyframes(sim.rig, s, sim.nom.n_keyframes, sim.nom)
        if k.size == 0:
            return np.zeros((0, 4))
        truth = sim.truth
        R_BS, p_BS = truth.rotation(s.name), truth.vector(s.name, "trans")
        R_AV = np.swapaxes(sim.nom.R_V_A[k], 1, 2)
        R_AS = R_AV @ (sim.nom.R_V_B @ R_BS)
        p_AS = R_AV @ (sim.nom.p_V_B + sim.nom.R_V_B @ p_BS)
        out = np.hstack([R_AS[:, 2, :], p_AS[:, 2:3] + sim.rig.config.vehicle.axle_height_m])
        if sim.noisy:
            Lam = information(sim.nom, sim.rig, s, k)
            cov = np.linalg.pinv(Lam, hermitian=True)
            lam, V = np.linalg.eigh(cov)
            out = out + np.einsum("nij,nj->ni", V * np.sqrt(np.maximum(lam, 0.0))[:, None, :],
                                  sim.rng.normal(size=(k.size, 4)))
        return out


def information(nom: Nominal, rig: RigView, s: OdometrySensor, first: np.ndarray) -> np.ndarray:
    """``Λ`` (N × 4 × 4) of the frames ``first`` of lidar ``s`` (the module docstring's
    ``F (I + m Q F)⁻¹``)."""
    k = np.asarray(first)
    cfg = s.ground_plane
    R_BS = s.T_B_S.R
    R_W_S = nom.R[k] @ R_BS
    B = np.zeros((k.size, 4, 4))
    B[:, :3, :3] = R_W_S
    B[:, 3, 3] = 1.0
    G = np.swapaxes(B, 1, 2) @ nom.ground[s.name][k] @ B  # in S
    R_AS = np.swapaxes(nom.R_V_A[k], 1, 2) @ (nom.R_V_B @ R_BS)
    n = R_AS[:, 2, :]
    P = np.zeros((k.size, 4, 4))
    P[:, :3, :3] = np.eye(3) - n[:, :, None] * n[:, None, :]
    P[:, 3, 3] = 1.0
    F = np.swapaxes(P, 1, 2) @ G @ P
    tilt = np.linalg.norm(so3.log(nom.R_V_A[k]), axis=1)
    var_n = np.radians(cfg.road_tilt_sigma_deg) ** 2 + (cfg.suspension_uncertainty * tilt) ** 2
    Q = np.zeros((k.size, 4, 4))
    Q[:, :3, :3] = var_n[:, None, None] * P[:, :3, :3]
    Q[:, 3, 3] = cfg.road_height_sigma_m ** 2
    # the frames sharing each frame's patch of road: within half a patch of its position
    from scipy.spatial import cKDTree

    x = nom.p[k]
    m = np.asarray(cKDTree(x).query_ball_point(x, 0.5 * cfg.patch_length_m, return_length=True), dtype=float)
    Lam = F @ np.linalg.inv(np.eye(4) + m[:, None, None] * Q @ F)
    return 0.5 * (Lam + np.swapaxes(Lam, 1, 2))
