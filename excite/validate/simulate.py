"""Raw noisy sensor data of a drive, from a true rig: physical by default, or exactly as the
information model assumes it (:meth:`SimulationSettings.model`).

:func:`simulate` turns a nominal drive and a true :class:`Calibration` into what the rig's
sensors record: every measurement kind simulates its own entries
(:meth:`excite.factors.base.Kind.simulate`, given a :class:`Simulation`). The physical simulator
is more physical than the model it checks: the IMU integrates the true motion and outputs
boxcar means, its biases random-walk; wheels integrate their contact point's speed with tyre
slip (linear in the longitudinal acceleration, and a scrub with the square of the lateral one);
the body yaws into every turn by the rear tyres' slip angle, so the axle really slides outwards
(:func:`_with_slip_angle`). The model simulator gives the measurements the factors predict.

The suspension tilt ``R_V_A`` and the IMU pose in the vehicle frame are known inputs, as in the
information model.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core import so3
from ..errors import ValidateError
from ..factors import base as registry
from ..factors import symbolic
from ..factors.base import Kind, Nominal
from ..motion.trajectory import Trajectory
from ..rig.config import Rig


# ------------------------------------------------------------------------------------------------
# The calibration as a value (nominal rig ⊞ offset)


@dataclass(frozen=True)
class Calibration:
    """Values of every calibration quantity of a rig: ``values[block][key]`` (a rotation as its
    3 × 3 matrix, a vector, a scalar), for every quantity of every entry (:meth:`nominal`: the
    rig's configured values, zero time offsets and biases, unit scales). Offsets over the rig's
    coordinates follow the library's conventions: right perturbation of a rotation, additive
    elsewhere (:meth:`plus`, :meth:`minus`)."""

    values: dict[str, dict[str, Any]]

    @classmethod
    def nominal(cls, rig: Rig) -> "Calibration":
        out: dict[str, dict[str, Any]] = {}
        for _, _, q in registry.quantities(rig.config):
            v = np.array(q.nominal, dtype=float) if np.ndim(q.nominal) else float(q.nominal)
            out.setdefault(q.block, {})[q.name] = v
        return cls(out)

    def rotation(self, block: str) -> np.ndarray:
        return self.values[block]["rot"]

    def vector(self, block: str, key: str) -> np.ndarray:
        return self.values[block][key]

    def scalar(self, block: str, key: str) -> float:
        return float(self.values[block][key])

    def for_entry(self, kind: Kind, rig: Rig, entry: Any) -> dict[str, Any]:
        """The values of one entry's quantities by key (what :mod:`excite.factors.symbolic` takes)."""
        return {q.name: self.values[q.block][q.name] for q in kind.quantities(rig.config, entry)}

    def with_values(self, block: str, **values: Any) -> "Calibration":
        """This calibration with some of ``block``'s values replaced."""
        return Calibration({**self.values, block: {**self.values[block], **values}})

    @staticmethod
    def _slots(rig: Rig) -> list[tuple[str, str, bool, int | None]]:
        """(block, key, rotation, component) of every coordinate of ``rig``, in column order."""
        out = []
        for _, _, q in registry.quantities(rig.config):
            if q.estimated:
                out += [(q.block, q.name, q.rotation, i if q.size == 3 else None) for i in range(q.size)]
        return out

    def plus(self, rig: Rig, delta: np.ndarray) -> "Calibration":
        """This calibration moved by ``delta`` (one entry per ``rig.coordinates``)."""
        delta = np.asarray(delta, dtype=float)
        if delta.shape != (len(rig.coordinates),):
            raise ValidateError(f"a calibration offset needs {len(rig.coordinates)} entries, got {delta.shape}")
        vals = {b: {k: np.array(v, dtype=float) if np.ndim(v) else float(v) for k, v in d.items()}
                for b, d in self.values.items()}
        rot: dict[str, np.ndarray] = {}
        for (block, key, is_rot, i), d in zip(self._slots(rig), delta):
            if is_rot:
                rot.setdefault(block, np.zeros(3))[i] = d
            elif i is None:
                vals[block][key] = vals[block][key] + d
            else:
                vals[block][key][i] += d
        for block, phi in rot.items():
            vals[block]["rot"] = vals[block]["rot"] @ so3.exp(phi[None])[0]  # (so3.exp needs a batch axis)
        return Calibration(vals)

    def minus(self, other: "Calibration", rig: Rig) -> np.ndarray:
        """``self ⊟ other`` over ``rig.coordinates`` (rotations: ``Log(R_otherᵀ R_self)``)."""
        out = []
        for block, key, is_rot, i in self._slots(rig):
            a, b = self.values[block][key], other.values[block][key]
            if is_rot:
                out.append(so3.log(b.T @ a)[i])
            else:
                out.append(float(a - b) if i is None else float(a[i] - b[i]))
        return np.array(out)


def offset_sigma(rig: Rig, in_targets: float, scale_sigma: float = 0.01) -> np.ndarray:
    """σ per coordinate of a random calibration offset: ``in_targets`` × target (scale: ``scale_sigma``;
    tyre slip: none, the simulator's physics sets it)."""
    return np.array([scale_sigma if c.quantity == "scale" else 0.0 if c.nuisance else in_targets * c.target
                     for c in rig.coordinates])


# ------------------------------------------------------------------------------------------------
# Simulation


@dataclass(frozen=True)
class SimulationSettings:
    """What the simulator adds to the ideal measurements. The defaults are the *physical*
    simulator, more physical than the information model it checks; :meth:`model` gives the data
    the model itself assumes (a consistency check of the evaluator and the estimator).

    ``imu_oversampling``: the IMU integrates the true motion at this multiple of its output rate
    and outputs the mean rate and specific force over each sample (a boxcar anti-aliasing filter,
    as delta-angle/delta-velocity IMUs do, without coning or sculling compensation); the model
    holds each sample over its interval in the attitude at its start, a discretisation error of
    about ``½·ω·dt`` in attitude it does not carry. 0: increment-equivalent samples, which the
    model's preintegration reproduces (see the module docstring).
    ``bias_random_walk``: the IMU biases random-walk per the Kalibr random-walk keys (the
    estimator takes them constant).
    ``wheel_ticks_per_rev``: encoder resolution (0: no quantisation); the white part of the wheel
    noise is reduced so that the total per increment equals the rig's
    (:func:`excite.factors.wheel.increment_sigma_rad`).
    ``wheel_slip_per_g``: longitudinal slip ratio of the rear wheels per g of longitudinal
    acceleration (a braking wheel turns slower than it travels, a driven one faster), plus
    ``wheel_scrub_per_g2`` × (lateral acceleration/g)² (the tyre's shorter rolling radius when it
    is loaded sideways). 0: the wheels turn exactly with the model's chord of the axle's travel;
    otherwise each wheel's angle integrates its contact point's speed at the internal IMU rate.
    ``slip_angle_deg_per_mps2``: the rear tyres' slip angle per m/s² of lateral acceleration; the
    body yaws into the turn relative to the axle's travel, so the axle slides outwards (the
    non-holonomic constraint is violated by ``v·tan β``).
    ``slip_noise``: the non-holonomic pseudo-measurement with white slip of its σ.
    ``noise``: False gives noise-free data (the estimator must then return the truth).
    ``ray_cast``: where the drive sees a scene, each lidar frame pair is what registering its two
    ray-cast scans gives (:mod:`excite.validate.scans`: the scene itself is needed); False: the
    registration error the scene's information predicts, as the model assumes.
    """

    noise: bool = True
    imu_oversampling: int = 8
    bias_random_walk: bool = True
    wheel_ticks_per_rev: int = 2048
    wheel_slip_per_g: float = 0.01
    wheel_scrub_per_g2: float = 0.01
    slip_angle_deg_per_mps2: float = 0.15
    slip_noise: bool = True
    ray_cast: bool = True

    @classmethod
    def model(cls, **changes) -> "SimulationSettings":
        """Data as the information model assumes it: increment-equivalent IMU samples, constant
        biases, wheels turning with the model's chord, no tyre slip angle, lidar pairs in a scene
        with the error its information predicts."""
        base = dict(imu_oversampling=0, bias_random_walk=False, wheel_slip_per_g=0.0, wheel_scrub_per_g2=0.0,
                    slip_angle_deg_per_mps2=0.0, ray_cast=False)
        return cls(**{**base, **changes})

    @property
    def physical(self) -> bool:
        return (self.imu_oversampling > 0 or self.bias_random_walk or self.wheel_slip_per_g != 0
                or self.wheel_scrub_per_g2 != 0 or self.slip_angle_deg_per_mps2 != 0 or self.ray_cast)

    def __post_init__(self) -> None:
        if self.wheel_ticks_per_rev < 0:
            raise ValidateError(f"wheel_ticks_per_rev must be ≥ 0, got {self.wheel_ticks_per_rev}")
        if not 0 <= self.imu_oversampling <= 100:
            raise ValidateError(f"imu_oversampling must be between 0 and 100, got {self.imu_oversampling}")
        for name in ("wheel_slip_per_g", "wheel_scrub_per_g2", "slip_angle_deg_per_mps2"):
            v = getattr(self, name)
            if not (np.isfinite(v) and abs(v) <= 1.0):
                raise ValidateError(f"{name} must be finite and at most 1 in magnitude, got {v!r}")


@dataclass(frozen=True)
class Truth:
    """What the data was generated from: body states at the keyframes, the calibration, and the
    IMU's bias tracks (constant unless they random-walk)."""

    R: np.ndarray
    p: np.ndarray
    v: np.ndarray
    calibration: Calibration
    gyro_bias: np.ndarray  # (samples, 3)
    accel_bias: np.ndarray


@dataclass(frozen=True)
class SensorData:
    """Raw data of one drive, on the keyframe grid of the rig (IMU sample ``k·n`` is keyframe k).

    ``recorded[name]``: what each entry of the rig recorded (by its block name, :meth:`Kind.simulate`:
    the IMU's samples, an array of measurements per factor for the others). ``R_V_A`` (K, 3, 3)
    is the known suspension tilt, ``R_V_B, p_V_B`` the known IMU pose in the vehicle frame;
    ``logs``: which measurements the drive's log held (:attr:`excite.factors.base.Nominal.logs`:
    a GNSS outage), as the simulation saw them.
    """

    t: np.ndarray
    imu_per_keyframe: int
    recorded: dict[str, Any]
    R_V_A: np.ndarray
    R_V_B: np.ndarray
    p_V_B: np.ndarray
    truth: Truth = field(repr=False)
    logs: dict = field(default_factory=dict, repr=False)
    scene: dict = field(default_factory=dict, repr=False)  # what a scene shows the lidars (Nominal.scene)
    ground: dict = field(default_factory=dict, repr=False)  # and the road plane they fit (Nominal.ground)
    # per lidar whose scans were ray-cast in a scene: the information each pair's registration
    # reports (N × 6 × 6 in S_j: excite.validate.scans.PairNoise), what a calibrator weighs it by
    registration: dict = field(default_factory=dict, repr=False)

    @property
    def n_keyframes(self) -> int:
        return self.t.size

    @property
    def imu(self):
        """The IMU's samples (:class:`excite.factors.imu.ImuData`)."""
        return self.recorded["imu"]

    @property
    def dt_imu(self) -> float:
        return float(self.t[1] - self.t[0]) / self.imu_per_keyframe


@dataclass
class Simulation:
    """What a kind's :meth:`~excite.factors.base.Kind.simulate` reads: the (physical) drive
    ``traj`` and its nominal motion ``nom`` for ``rig``, the true calibration, the random stream,
    the settings and whether to add noise, and where the simulator ray-cast a scene its lidars'
    frame pairs (``scan_pairs``, by name: :mod:`excite.validate.scans`)."""

    traj: Trajectory
    nom: Nominal
    rig: Rig
    truth: Calibration
    rng: np.random.Generator
    settings: "SimulationSettings"
    scan_pairs: dict = field(default_factory=dict)

    @property
    def noisy(self) -> bool:
        return self.settings.noise

    def body_at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Body pose at ``t``; beyond the ends of the drive, extended at the end's velocity and rate
        (what a sensor stamped near the ends with a time offset sees; the factor's own model)."""
        tc = np.clip(t, self.traj.t_start, self.traj.t_end)
        b = self.traj.sample(tc).body(self.nom.R_V_B, self.nom.p_V_B)
        dt = (t - tc)[:, None]
        return b.R_W_B @ so3.exp(b.omega_B * dt), b.p_W_B + b.v_W * dt

    def measured(self, kind: Kind, entry: Any) -> np.ndarray:
        """The noise-free measurements of ``entry`` as its kind's model predicts them at the true
        calibration, on the nominal motion (the model simulator's)."""
        first = registry.factor_keyframes(kind, self.rig, entry, self.nom.n_keyframes, self.nom)
        return symbolic.measurements(kind, self.nom, self.rig, entry, first, self.truth.for_entry(kind, self.rig, entry))


def _with_slip_angle(traj: Trajectory, deg_per_mps2: float, rate_hz: float = 50.0) -> Trajectory:
    """``traj`` with the body yawed into every turn by the rear tyres' slip angle
    ``β = deg_per_mps2 · a_lat`` about the road normal, the path and speed unchanged (re-fitted
    from samples at ``rate_hz``; the suspension tilt kept)."""
    t = traj.times(rate_hz)
    smp = traj.sample(t)
    beta = np.deg2rad(deg_per_mps2) * smp.accel_lat
    R_A_V = np.swapaxes(smp.R_V_A, 1, 2)
    R = smp.R_W_V @ smp.R_V_A @ so3.rot_z(beta) @ R_A_V
    tilt = so3.yaw_pitch_roll(R_A_V)[:, 1:3] if traj.has_tilt else None
    out = Trajectory(t, R, smp.p_W_V, tilt_pitch_roll=tilt, velocity=smp.v_W, name=traj.name)
    out.origin = traj.origin
    return out.with_scene(traj.scene)  # the yaw of a slip angle turns no 360° scan's world-aligned view


def simulate(traj: Trajectory, rig: Rig, truth: Calibration, rng: np.random.Generator,
             settings: SimulationSettings = SimulationSettings(), scan_pairs: dict | None = None) -> SensorData:
    """Noisy raw data of ``traj`` driven with ``rig`` whose true calibration is ``truth``.

    ``rig`` gives the noise levels, rates and known geometry; ``truth`` the values the data is
    generated with. Same ``rng`` state, same data. Where ``traj`` sees a scene, ``scan_pairs``
    holds its lidars' frame pairs ray-cast in it (:func:`excite.validate.scans.pair_noise`, by
    name); a lidar without them has the registration error the scene's information predicts.
    """
    if settings.slip_angle_deg_per_mps2:
        traj = _with_slip_angle(traj, settings.slip_angle_deg_per_mps2)
    nom = Nominal.of(traj, rig)
    if nom.n_keyframes < 3:
        raise ValidateError(f"the drive is too short to simulate: {nom.n_keyframes} keyframes")
    scan_pairs = dict(scan_pairs or {})
    sim = Simulation(traj, nom, rig, truth, rng, settings, scan_pairs)
    recorded = {}
    for inst in registry.instances(rig):
        try:
            recorded[inst.name] = inst.kind.simulate(sim, inst.entry)
        except ValueError as exc:
            raise ValidateError(f"{inst.name}: {exc}") from None
        if (settings.noise and inst.kind.name == "odometry" and inst.entry.name in nom.scene
                and inst.entry.name not in scan_pairs):
            recorded[inst.name] = _registration_noise(sim, inst.kind, inst.entry, recorded[inst.name])
    imu = recorded["imu"]
    return SensorData(t=nom.t, imu_per_keyframe=nom.imu_per_keyframe, recorded=recorded, R_V_A=nom.R_V_A,
                      R_V_B=nom.R_V_B, p_V_B=nom.p_V_B,
                      truth=Truth(nom.R, nom.p, nom.v, truth, imu.gyro_bias, imu.accel_bias), logs=nom.logs,
                      scene=nom.scene, ground=nom.ground,
                      registration={k: v.information for k, v in scan_pairs.items()})


def _registration_noise(sim: Simulation, kind: Kind, entry: Any, pairs: np.ndarray) -> np.ndarray:
    """A lidar's frame pairs (``[R_rel, t_rel]`` rows) in a scene, with each pair's registration
    error added to the drift the odometry simulated: drawn from the scene's information about the
    pair (:func:`excite.factors.odometry.scene_information`, its pseudo-inverse: none along the
    directions it does not see), so that the pair's error has the covariance ``A_r⁻¹ + Q`` whose
    inverse the model weighs it by. The registration is the model's, not a ray-cast scan's."""
    from ..factors.odometry import scene_information

    first = registry.factor_keyframes(kind, sim.rig, entry, sim.nom.n_keyframes)
    if first.size == 0:
        return pairs
    A = scene_information(sim.nom, entry, first, registry.stride(kind, sim.rig, entry))
    lam, V = np.linalg.eigh(0.5 * (A + np.swapaxes(A, 1, 2)))
    keep = lam > 1e-12 * np.maximum(lam[:, -1:], 0.0)
    scale = np.where(keep, 1.0 / np.sqrt(np.where(keep, lam, 1.0)), 0.0)
    e = np.einsum("nij,nj->ni", V * scale[:, None, :], sim.rng.normal(size=(first.size, 6)))
    out = pairs.copy()
    R = out[:, :9].reshape(-1, 3, 3) @ so3.exp(e[:, :3])
    out[:, :9] = R.reshape(-1, 9)
    out[:, 9:12] += e[:, 3:]
    return out
