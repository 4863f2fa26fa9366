"""Relative pose of an exteroceptive sensor (lidar or camera odometry) between its consecutive frames.

The sensor's pose at frame i is ``T_W_B(t_i + t_d) · T_B_S``; the body pose at ``t_i + t_d`` is
taken to first order from keyframe i through the body's angular and linear velocity
(``R Exp(ω t_d)``, ``p + v t_d``). Frames coincide with every ``stride``-th keyframe. Residual
(rotation, translation) in frame ``S_i``:

    r_R = Log(R_measᵀ R_rel),   r_t = s · t_rel − t_meas

with ``R_rel = R_S_iᵀ R_S_j``, ``t_rel = R_S_iᵀ (p_S_j − p_S_i)`` and s the unknown scale of a
monocular camera (1 otherwise). Extrinsic perturbations are right-multiplicative on ``R_B_S`` and
additive on ``p_B_S``.

Noise is a drift density: the odometry's pose error grows as a random walk in time, so a relative
pose over Δt has σ = density·√Δt (``rotation_density_deg_per_sqrt_s``,
``translation_density_m_per_sqrt_s``), and consecutive frame pairs are independent. The
information per second then does not depend on the frame rate: a 20 Hz lidar of the same quality
is told what a 10 Hz one is (with σ per frame pair, at the same σ a faster sensor came out
*worse*, its lever-arm signal per pair shrinking with Δt). No per-frame floor is kept: a white
error of each frame's pose makes consecutive relative poses correlated (a moving average), not
independent, and a white floor per pair would bring the rate dependence back.

**Reported covariance.** With ``noise.use_reported_covariance``, where the drive carries a log of
the sensor with the odometry's own covariance (``nav_msgs/Odometry``,
``PoseWithCovarianceStamped``: :mod:`excite.io.bags.covariance`), each frame pair is whitened by
it instead of by the densities, so that a stretch where the odometry reports itself worse (a
tunnel, a featureless highway) shows in σ. The approximation, to first order: the log holds per
message the covariance per second Q_k of the odometry's increment since its previous message (its
reported covariance over that interval), in the world frame; the pair ``i → j`` (Δt apart) has

    Σ_ij = Δt · Bᵀ Q_j B,   B = diag(R_W_S(t_i), R_W_S(t_i)),   R_W_S = R_W_B R_B_S

the covariance of the message at frame j (the one that closes the pair) over the pair's
interval, turned from the world into the frame S_i of the residual at the nominal orientation
(small rotations within a pair); the pair's increments are taken as independent, as with the
densities, so the pairs stay independent and σ does not depend on the frame rate. A pair whose
closing frame has no message with a covariance keeps the densities. The evaluator applies it to
the pairs' rows (:meth:`Odometry.whitening`); the optimizer's planned drives and the simulator use
the densities.

**The scene.** Where the drive sees a scene (:mod:`excite.scene`), a lidar's or a camera's frame
pair is told only what the surfaces in view can tell: scan j registered against scan i by
point-to-plane ICP holds the information ``A`` of scan j's points about the relative pose
(:mod:`excite.scene.lidar`), a camera's pair the information of its features' bearings with the
landmarks eliminated (:mod:`excite.scene.camera`) — both about a right perturbation ``δ = [φ, ρ]``
of ``T_ij`` in S_j, which in the residual's coordinates
(``r_R = φ``, ``r_t = R_rel ρ``) is ``A_r = Mᵀ A M`` with ``M = diag(I, R_relᵀ)``. The
registration's error and the odometry's drift add up (covariance ``A⁻¹ + Q``, Q the densities'
or the reported covariance of the pair), so the pair's information is

    Λ = A_r (I + Q A_r)⁻¹ = (A_r⁻¹ + Q)⁻¹,

written so that it holds for a singular ``A_r``: a direction no surface constrains (a tunnel's
axis, the open lot's x, y and yaw) has no information at all — an exact zero the rank test sees —
and a rich scene approaches the densities' ``Q⁻¹`` (the drift a real odometry has bounds what a
scene can give). Each pair is scan j registered against the surfaces the earlier scan saw, taken
as exact (what an odometry's local map makes of them), on its own: the map's noise and the ties
a scan-to-map odometry makes between pairs are not modelled. A camera's pair is
bearing-only: the length of its translation is not in its bearings, and is taken as known as
well as the translation's other two directions (the odometry keeps one scale from pair to pair
through its landmarks; a monocular camera's overall scale stays the drive's nuisance ``s``:
:mod:`excite.scene.camera`). The scan's or pair's information is ray-cast at samples along the
drive (:func:`excite.scene.along.seen`) and taken from the sample nearest each frame.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import model_validator

from ..core import so3
from ..core.bounds import Range
from ..core.lazy import ca
from ..core.schema import Model, PositiveFloat, SensorEntry
from .optics import LIDAR_PRESETS, CameraOptics, LidarBeams
from . import base
from .base import ConfigView, Expr, FactorInputs, Kind, Nominal, Quantity, RigView, SimulationView
from .symbolic import exp, residual_log


class OdometryNoise(Model):
    """Drift densities of the odometry: the σ of a relative pose over Δt is density·√Δt, per axis
    (rotation [deg/√s], translation [m/√s]); ``use_reported_covariance``: where a log carries the
    odometry's own covariance, it replaces them for the frame pairs it covers (see the module
    docstring)."""

    rotation_density_deg_per_sqrt_s: PositiveFloat
    translation_density_m_per_sqrt_s: PositiveFloat
    use_reported_covariance: bool = False


class GroundPlaneConfig(Model):
    """A lidar's fit of the road plane (:mod:`excite.factors.ground`): what the road adds to each
    fit — its tilt and height under a patch of ``patch_length_m`` against the plane the vehicle
    stands on — and how well the suspension's tilt is known (a fraction of itself)."""

    enabled: bool = True
    road_tilt_sigma_deg: PositiveFloat = 0.1
    road_height_sigma_m: PositiveFloat = 0.005
    patch_length_m: PositiveFloat = 5.0
    suspension_uncertainty: float = 0.3


class OdometrySensor(SensorEntry):
    """A lidar or camera whose odometry gives the relative pose between its frames."""

    kind: Literal["lidar", "camera"]
    noise: OdometryNoise
    monocular: bool = False
    beams: LidarBeams | str | None = None  # a lidar's pattern, or a preset's name (:mod:`excite.factors.optics`)
    optics: CameraOptics | None = None  # a camera's image, focal length and noise (:mod:`excite.factors.optics`)
    ground_plane: GroundPlaneConfig = GroundPlaneConfig()  # a lidar's: the road plane it sees

    @model_validator(mode="after")
    def _mono_is_camera(self) -> "OdometrySensor":
        if self.monocular and self.kind != "camera":
            raise ValueError("monocular applies to cameras only")
        if self.beams is not None and self.kind != "lidar":
            raise ValueError("beams applies to lidars only")
        if self.optics is not None and self.kind != "camera":
            raise ValueError("optics applies to cameras only")
        if isinstance(self.beams, str) and self.beams not in LIDAR_PRESETS:
            raise ValueError(f"beams: {self.beams!r} is not a preset ({', '.join(LIDAR_PRESETS)}); "
                             "or give vertical_angles_deg or channels and vertical_fov_deg")
        return self


def pair_sigmas(sensor: "OdometrySensor") -> tuple[float, float]:
    """σ of one relative pose between consecutive frames of ``sensor``: rotation [rad] and
    translation [m] per axis, density·√(1/rate)."""
    root_dt = math.sqrt(1.0 / sensor.rate_hz)
    n = sensor.noise
    return math.radians(n.rotation_density_deg_per_sqrt_s * root_dt), n.translation_density_m_per_sqrt_s * root_dt


_LEVER = ("horizontal lever arm: add yaw at changing speed (turns both ways, figure-eight, slalom)",
          "needs turns both ways at changing speed: a figure-eight, a slalom")


class Odometry(Kind[OdometrySensor]):
    name = "odometry"
    arity = 2
    rows = 6
    sensor_kinds = ("lidar", "camera")
    config = OdometrySensor
    ranges = {"noise.rotation_density_deg_per_sqrt_s": Range(1e-6, 90.0, "deg/√s"),
              "noise.translation_density_m_per_sqrt_s": Range(1e-6, 100.0, "m/√s"),
              "ground_plane.road_tilt_sigma_deg": Range(1e-4, 10.0, "deg"),
              "ground_plane.road_height_sigma_m": Range(1e-5, 1.0, "m"),
              "ground_plane.patch_length_m": Range(0.1, 100.0, "m"),
              "ground_plane.suspension_uncertainty": Range(0.0, 1.0, "1"),
              "beams.channels": Range(1, 512, "1"),
              "beams.horizontal_resolution_deg": Range(1e-3, 10.0, "deg"),
              "beams.horizontal_fov_deg": Range(1.0, 360.0, "deg"),
              "beams.min_range_m": Range(0.0, 100.0, "m"),
              "beams.max_range_m": Range(1.0, 2000.0, "m"),
              "beams.range_noise_m": Range(1e-5, 1.0, "m"),
              "beams.correlation_deg": Range(1e-3, 10.0, "deg"),
              "optics.width_px": Range(16, 20000, "px"),
              "optics.height_px": Range(16, 20000, "px"),
              "optics.focal_px": Range(1.0, 1e5, "px"),
              "optics.pixel_noise_px": Range(1e-3, 100.0, "px"),
              "optics.min_range_m": Range(0.0, 100.0, "m"),
              "optics.max_range_m": Range(1.0, 2000.0, "m"),
              "optics.max_features": Range(1, 100000, "1")}
    advice = {
        ("trans", 2): ("vertical lever arm: add pitch and roll (hard braking and acceleration, ramps, "
                       "brisk cornering); planar driving leaves it nearly undetermined — a lidar's is set by "
                       "the road it sees (score it in its scene, with --scene; stop on level ground with the "
                       "road in view)",
                       "needs pitch and roll: a ramp, hard braking, brisk cornering; or a stop on level ground"),
        ("trans", 0): _LEVER,
        ("trans", 1): _LEVER,
        ("rot", 0): ("extrinsic rotation about the travel direction: add turns; straight driving "
                     "leaves it undetermined (a lidar's roll: also a stop on level ground with the road in view)",
                     "needs turns: straight driving cannot reach it"),
        ("rot", 1): ("extrinsic rotation about the lateral axis: add turns and pitch (braking, ramps; a lidar's "
                     "pitch: also a stop on level ground with the road in view)",
                     "needs turns and pitch: braking, a ramp"),
        ("rot", 2): ("extrinsic rotation about the vertical axis: add straight runs and turns",
                     "needs straight runs and turns"),
        ("time_offset", None): ("time offset: vary angular rate and acceleration (slalom, stop-and-go); "
                                "constant velocity hides it",
                                "needs changing turn rate and speed: a slalom, stop-and-go"),
        ("scale", None): ("monocular scale: accelerate and decelerate", "needs speed changes: accelerate and brake"),
    }

    def quantities(self, cfg: ConfigView, s: OdometrySensor) -> list[Quantity]:
        ext = s.estimate.extrinsic
        return [Quantity(s.name, "rot", 3, "rad", s.T_B_S.R, ext),
                Quantity(s.name, "trans", 3, "m", s.T_B_S.p, ext),
                Quantity(s.name, "time_offset", 1, "s", 0.0, s.estimate.time_offset, per_entry=False),
                Quantity(s.name, "scale", 1, "1", 1.0, s.monocular, nuisance=True, per_entry=False)]

    # --- the math ---

    @staticmethod
    def _relative(f: FactorInputs) -> tuple[Expr, Expr]:
        """``R_rel``, ``t_rel`` of the sensor between the factor's two frames."""
        R_BS, p_BS, t_d = f.q["rot"], f.q["trans"], f.q["time_offset"]
        poses = []
        for a in range(2):
            Rb = ca.mtimes(f.R[a], exp(f.omega[a] * t_d))
            pb = f.p[a] + f.v[a] * t_d
            poses.append((ca.mtimes(Rb, R_BS), pb + ca.mtimes(Rb, p_BS)))
        (Ri, pi), (Rj, pj) = poses
        return ca.mtimes(Ri.T, Rj), ca.mtimes(Ri.T, pj - pi)

    def measurement(self, f: FactorInputs) -> Expr:
        R_rel, t_rel = self._relative(f)
        return ca.vertcat(ca.reshape(R_rel.T, 9, 1), f.q["scale"] * t_rel)

    def residual(self, f: FactorInputs, meas: Expr) -> Expr:
        R_rel, t_rel = self._relative(f)
        R_meas = ca.reshape(meas[0:9], 3, 3).T
        return ca.vertcat(residual_log(ca.mtimes(R_meas.T, R_rel)), f.q["scale"] * t_rel - meas[9:12])

    def constants(self, rig: RigView, s: OdometrySensor) -> dict[str, np.ndarray]:
        sig_r, sig_t = pair_sigmas(s)
        return {"sigma": np.array([sig_r] * 3 + [sig_t] * 3)}

    def sqrt_information(self, f: FactorInputs) -> Expr:
        return 1.0 / f.c["sigma"]

    def whitening(self, nom: Nominal, rig: RigView, s: OdometrySensor, first: np.ndarray) -> np.ndarray | None:
        """Every frame pair's whitening from data: the scene's information combined with the drift
        (:func:`scene_whitening`) where the drive sees a scene, the reported covariance's
        (:func:`reported_whitening`) where the rig asks for it and the drive's log carries one."""
        stride = base.stride(self, rig, s)
        reported = reported_whitening(nom, s, first, stride)
        if s.name not in nom.scene:
            return reported
        return scene_whitening(nom, s, first, stride, reported)

    # --- simulation ---

    def simulate(self, sim: SimulationView, s: OdometrySensor) -> np.ndarray:
        """Relative poses between the sensor's frames at its own clock: the frame stamped ``t``
        shows the body at ``t + t_d`` (the exact pose of the drive; the factor takes it to first
        order); a monocular camera's translations carry its true scale. A lidar whose scans the
        simulator ray-cast in a scene (``sim.scan_pairs``: :mod:`excite.validate.scans`) measures
        each pair as registering its two scans does (:func:`registered`), the drift added."""
        first = base.factor_keyframes(self, sim.rig, s, sim.nom.n_keyframes)
        frames = np.r_[first, first[-1] + base.stride(self, sim.rig, s)] if first.size else first
        if frames.size < 2:
            return np.zeros((0, 12))
        truth = sim.truth
        R_BS, p_BS = truth.rotation(s.name), truth.vector(s.name, "trans")
        R_b, p_b = sim.body_at(sim.nom.t[frames] + truth.scalar(s.name, "time_offset"))
        R_S = R_b @ R_BS
        p_S = p_b + R_b @ p_BS
        R_iT = np.swapaxes(R_S[:-1], 1, 2)
        R_rel = R_iT @ R_S[1:]
        t_rel = np.einsum("nij,nj->ni", R_iT, p_S[1:] - p_S[:-1]) * truth.scalar(s.name, "scale")
        pairs = getattr(sim, "scan_pairs", {}).get(s.name)
        if pairs is not None:
            R_rel, t_rel = registered(R_rel, t_rel, pairs, first, sim.rng if sim.noisy else None)
        if sim.noisy:
            F = frames.size - 1
            sig_r, sig_t = pair_sigmas(s)
            R_rel = R_rel @ so3.exp(sim.rng.normal(0.0, sig_r, (F, 3)))
            t_rel = t_rel + sim.rng.normal(0.0, sig_t, (F, 3))
        return np.hstack([R_rel.reshape(-1, 9), t_rel])


def registered(R_rel: np.ndarray, t_rel: np.ndarray, pairs, first: np.ndarray,
               rng: np.random.Generator | None) -> tuple[np.ndarray, np.ndarray]:
    """The relative poses ``R_rel, t_rel`` (F × 3 × 3, F × 3) of the pairs starting at keyframes
    ``first`` as scan-to-scan registration in the scene reports them
    (:class:`~excite.validate.scans.PairNoise`): along the directions its scans do not see, no
    motion (the perturbation that takes the pair to no motion, projected on those directions:
    exact for a translation, to second order in the pair's rotation for a rotation); elsewhere, with
    ``rng``, an error drawn from the registration's covariance — a right perturbation
    ``δ = [φ, ρ]`` of the pair's pose in S_j: ``R_rel Exp(φ)``, ``t_rel + R_rel ρ``."""
    if not np.array_equal(pairs.first, first):
        raise ValueError("the scan pairs were cast for another drive or rate")
    # the perturbation that takes the pair's pose to no motion: R_rel Exp(φ) = I, t_rel + R_rel ρ = 0
    back = -np.hstack([so3.log(R_rel), np.einsum("nji,nj->ni", R_rel, t_rel)])
    delta = np.einsum("nij,nj->ni", pairs.null, back)
    if rng is not None:
        delta = delta + np.einsum("nij,nj->ni", pairs.root, rng.normal(size=back.shape))
    return R_rel @ so3.exp(delta[:, :3]), t_rel + np.einsum("nij,nj->ni", R_rel, delta[:, 3:])


def reported_whitening(nom: Nominal, s: OdometrySensor, first: np.ndarray, stride: int) -> np.ndarray | None:
    """``W_n`` (N × 6 × 6, ``W_nᵀW_n = Σ_n⁻¹``) of the frame pairs starting at keyframes ``first``
    where the rig asks for the reported covariance and the drive's log of ``s`` carries one (the
    module docstring's Σ_ij; the densities' diagonal elsewhere); None where it does not apply."""
    log = nom.logs.get(s.name)
    if not s.noise.use_reported_covariance or log is None or log.covariance is None:
        return None
    sig_r, sig_t = pair_sigmas(s)
    W = np.broadcast_to(np.diag([1.0 / sig_r] * 3 + [1.0 / sig_t] * 3), (first.size, 6, 6)).copy()
    i = np.asarray(first)
    Q = log.covariance[i + stride]
    ok = np.all(np.isfinite(Q), axis=(1, 2))
    if ok.any():
        dt = nom.t[i[ok] + stride] - nom.t[i[ok]]
        R_S = nom.R[i[ok]] @ s.T_B_S.R  # R_W_S at frame i
        B = np.zeros((R_S.shape[0], 6, 6))
        B[:, :3, :3] = B[:, 3:, 3:] = R_S
        Sigma = dt[:, None, None] * np.swapaxes(B, 1, 2) @ Q[ok] @ B
        W[ok] = np.linalg.inv(np.linalg.cholesky(0.5 * (Sigma + np.swapaxes(Sigma, 1, 2))))
    return W


def sqrt_psd(Lam: np.ndarray, floor: float = 1e-12) -> np.ndarray:
    """``W`` (… × 6 × 6) with ``WᵀW = Λ`` for symmetric positive semi-definite ``Λ`` (… × 6 × 6):
    ``diag(√λ) Vᵀ`` of its eigen-decomposition, an eigenvalue below ``floor`` × the largest set to
    exactly zero (a direction without information stays one, not a rounding error's worth)."""
    lam, V = np.linalg.eigh(0.5 * (Lam + np.swapaxes(Lam, -1, -2)))
    top = np.maximum(lam[..., -1:], 0.0)
    lam = np.where(lam > floor * top, lam, 0.0)
    return np.sqrt(lam)[..., :, None] * np.swapaxes(V, -1, -2)


def scene_whitening(nom: Nominal, s: OdometrySensor, first: np.ndarray, stride: int,
                    reported: np.ndarray | None = None) -> np.ndarray:
    """``W_n`` (N × 6 × 6) of the frame pairs starting at keyframes ``first`` that see the scene
    (the module docstring's ``Λ = A_r (I + Q A_r)⁻¹``), with Q the pair's drift covariance: the
    densities', or ``(W_rᵀW_r)⁻¹`` of the ``reported`` whitening."""
    return drift_whitening(s, scene_information(nom, s, first, stride), reported)


def drift_whitening(s: OdometrySensor, A_r: np.ndarray, reported: np.ndarray | None = None) -> np.ndarray:
    """``W_n`` of frame pairs whose registration holds ``A_r`` (N × 6 × 6, residual coordinates),
    its error and the drift added: ``Λ = A_r (I + Q A_r)⁻¹`` (see :func:`scene_whitening`)."""
    if reported is None:
        sig_r, sig_t = pair_sigmas(s)
        Q = np.broadcast_to(np.diag([sig_r**2] * 3 + [sig_t**2] * 3), A_r.shape)
    else:
        Q = np.linalg.inv(np.swapaxes(reported, 1, 2) @ reported)
    Lam = A_r @ np.linalg.inv(np.eye(6) + Q @ A_r)
    return sqrt_psd(Lam)


def scene_information(nom: Nominal, s: OdometrySensor, first: np.ndarray, stride: int) -> np.ndarray:
    """``A_r`` (N × 6 × 6): the scene's information about each frame pair starting at keyframes
    ``first``, in the odometry residual's coordinates (the module docstring's ``Mᵀ A M``)."""
    j = np.asarray(first) + stride
    R_Sj = nom.R[j] @ s.T_B_S.R
    B = np.zeros((j.size, 6, 6))
    B[:, :3, :3] = B[:, 3:, 3:] = R_Sj
    A = np.swapaxes(B, 1, 2) @ nom.scene[s.name][j] @ B  # scan j's information, in S_j
    return residual_information(nom, s, first, stride, A)


def residual_information(nom: Nominal, s: OdometrySensor, first: np.ndarray, stride: int,
                         A: np.ndarray) -> np.ndarray:
    """``A_r = Mᵀ A M`` (N × 6 × 6): the information ``A`` of scan j about each frame pair (a right
    perturbation of its pose in S_j, [rotation, translation]) in the odometry residual's
    coordinates, ``M = diag(I, R_relᵀ)`` at the orientations of ``nom``."""
    i = np.asarray(first)
    j = i + stride
    R_BS = s.T_B_S.R
    R_Si = nom.R[i] @ R_BS
    R_Sj = nom.R[j] @ R_BS
    M = np.zeros((j.size, 6, 6))
    M[:, :3, :3] = np.eye(3)
    M[:, 3:, 3:] = np.swapaxes(R_Sj, 1, 2) @ R_Si  # R_relᵀ
    return np.swapaxes(M, 1, 2) @ A @ M
