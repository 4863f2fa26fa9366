"""Raw noisy sensor data of a drive, from a true rig: physical by default, or exactly as the
information model assumes it (:meth:`SimulationSettings.model`).

:func:`simulate` turns a nominal drive and a true :class:`Calibration` into what the rig's
sensors record:

- **IMU** samples at its rate with white noise of discrete σ = density·√rate (Kalibr keys) and
  the true biases, which random-walk per the Kalibr random-walk keys (physical) or stay constant
  (model). Physical: the IMU integrates the true motion at a multiple of its output rate and
  outputs the mean rate and specific force over each sample, which the calibrator's
  preintegration applies in the attitude of the sample's middle. Model: sample ``s`` is the *increment-equivalent*
  rate over ``[τ_s, τ_s + dt)`` (``ω_s = Log(R_sᵀR_{s+1})/dt``, accelerations that reproduce the
  keyframe states), which the preintegration of :mod:`excite.factors.imu` turns exactly into the
  drive's keyframe states.
- **Each exteroceptive sensor**: the relative pose between its consecutive frames with its
  rotation/translation noise, at its own clock: the frame stamped ``t`` shows the body at
  ``t + t_d`` (the exact pose from the drive; the factor takes it to first order). A monocular
  camera's translations carry its true scale.
- **Wheel encoders**: cumulative ticks (quantisation ``2π/ticks_per_rev``) of each wheel's angle
  plus white noise, so that the total noise of one increment (white + two quantisation errors)
  equals the rig's (:attr:`excite.rig.config.Rig.wheel_increment_sigma_rad`). Physical: the angle integrates the wheel's contact-point speed
  with a slip ratio that grows linearly with longitudinal acceleration (what the rig's
  ``wheel.slip`` nuisance models) and with the square of the lateral one (which nothing models);
  model: the increments of :func:`excite.factors.wheel.increments`.
- **Non-holonomic constraint**: a pseudo-measurement of zero lateral/vertical axle velocity with
  white slip of the configured σ. Physical: the body also yaws into every turn by the rear tyres'
  slip angle, so the axle really slides outwards (what the rig's ``vehicle.slip_angle`` nuisance
  models, to first order in the angle and with the lateral acceleration taken as u·ψ̇).

The suspension tilt ``R_V_A`` and the IMU pose in the vehicle frame are known inputs, as in the
information model.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core import so3
from ..errors import ValidateError
from ..factors import wheel
from ..factors.base import Nominal
from ..rig.config import Rig, build_rig
from ..motion.trajectory import GRAVITY, Trajectory


# ------------------------------------------------------------------------------------------------
# The calibration as a value (nominal rig ⊞ offset)


@dataclass(frozen=True)
class Calibration:
    """Values of every calibration quantity of a rig.

    ``extrinsics[name] = (R_B_S, p_B_S)``, ``time_offsets[name]`` [s] (stamp t shows the body at
    t + t_d), ``scales[name]`` (monocular cameras; 1 otherwise), IMU biases [rad/s, m/s²] and
    ``wheel = (radius_left, radius_right, track)`` [m] (None without wheels), ``slip`` the tyre
    slip nuisances ``(wheel.slip, vehicle.slip_angle)`` [1, rad] at 1 g. Offsets over the
    rig's coordinates follow the library's conventions: right perturbation of ``R_B_S``, additive
    elsewhere (:meth:`plus`, :meth:`minus`).
    """

    extrinsics: dict[str, tuple[np.ndarray, np.ndarray]]
    time_offsets: dict[str, float]
    scales: dict[str, float]
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    wheel: tuple[float, float, float] | None
    slip: tuple[float, float] = (0.0, 0.0)

    @classmethod
    def nominal(cls, rig: Rig) -> "Calibration":
        """The rig's configured values: zero time offsets and biases, unit scales."""
        cfg = rig.config
        w = cfg.wheels
        return cls(extrinsics={s.name: (s.T_B_S.R, s.T_B_S.p) for s in cfg.sensors},
                   time_offsets={s.name: 0.0 for s in cfg.sensors},
                   scales={s.name: 1.0 for s in cfg.sensors},
                   gyro_bias=np.zeros(3), accel_bias=np.zeros(3),
                   wheel=None if w is None else (w.radius_left_m, w.radius_right_m, w.track_m))

    def plus(self, rig: Rig, delta: np.ndarray) -> "Calibration":
        """This calibration moved by ``delta`` (one entry per ``rig.coordinates``)."""
        delta = np.asarray(delta, dtype=float)
        if delta.shape != (len(rig.coordinates),):
            raise ValidateError(f"a calibration offset needs {len(rig.coordinates)} entries, got {delta.shape}")
        ext = {k: (R.copy(), p.copy()) for k, (R, p) in self.extrinsics.items()}
        t_d, scale = dict(self.time_offsets), dict(self.scales)
        bg, ba = self.gyro_bias.copy(), self.accel_bias.copy()
        wh = None if self.wheel is None else list(self.wheel)
        slip = list(self.slip)
        rot: dict[str, np.ndarray] = {}
        for c, d in zip(rig.coordinates, delta):
            if c.kind == "rot":
                rot.setdefault(c.block, np.zeros(3))[c.axis] = d
            elif c.kind == "trans":
                ext[c.block][1][c.axis] += d
            elif c.kind == "time_offset":
                t_d[c.block] += d
            elif c.kind == "scale":
                scale[c.block] += d
            elif c.kind == "gyro_bias":
                bg[c.axis] += d
            elif c.kind == "accel_bias":
                ba[c.axis] += d
            elif c.kind == "radius":
                wh[c.axis] += d
            elif c.kind == "track":
                wh[2] += d
            elif c.kind == "slip":
                slip[0] += d
            elif c.kind == "slip_angle":
                slip[1] += d
        for name, phi in rot.items():
            R, p = ext[name]
            ext[name] = (R @ so3.exp(phi[None])[0], p)  # (so3.exp needs a batch axis)
        return Calibration(ext, t_d, scale, bg, ba, None if wh is None else tuple(wh), tuple(slip))

    def minus(self, other: "Calibration", rig: Rig) -> np.ndarray:
        """``self ⊟ other`` over ``rig.coordinates`` (rotations: ``Log(R_otherᵀ R_self)``)."""
        out = np.zeros(len(rig.coordinates))
        rot = {k: so3.log(other.extrinsics[k][0].T @ R) for k, (R, _) in self.extrinsics.items()}
        for i, c in enumerate(rig.coordinates):
            if c.kind == "rot":
                out[i] = rot[c.block][c.axis]
            elif c.kind == "trans":
                out[i] = self.extrinsics[c.block][1][c.axis] - other.extrinsics[c.block][1][c.axis]
            elif c.kind == "time_offset":
                out[i] = self.time_offsets[c.block] - other.time_offsets[c.block]
            elif c.kind == "scale":
                out[i] = self.scales[c.block] - other.scales[c.block]
            elif c.kind == "gyro_bias":
                out[i] = self.gyro_bias[c.axis] - other.gyro_bias[c.axis]
            elif c.kind == "accel_bias":
                out[i] = self.accel_bias[c.axis] - other.accel_bias[c.axis]
            elif c.kind == "radius":
                out[i] = self.wheel[c.axis] - other.wheel[c.axis]
            elif c.kind == "track":
                out[i] = self.wheel[2] - other.wheel[2]
            elif c.kind == "slip":
                out[i] = self.slip[0] - other.slip[0]
            elif c.kind == "slip_angle":
                out[i] = self.slip[1] - other.slip[1]
        return out

    def rig(self, rig: Rig) -> Rig:
        """``rig`` with these extrinsics and wheel values (time offsets, scales and biases are not
        rig fields: the factors take them as zero, one and zero)."""
        data = rig.config.model_dump()
        for s in data["sensors"]:
            R, p = self.extrinsics[s["name"]]
            s["T_B_S"] = {"translation_m": [float(x) for x in p], "matrix": R.tolist()}
        if self.wheel is not None:
            data["wheels"].update(radius_left_m=self.wheel[0], radius_right_m=self.wheel[1],
                                  track_m=self.wheel[2])
        return build_rig(data)


def offset_sigma(rig: Rig, in_targets: float, scale_sigma: float = 0.01) -> np.ndarray:
    """σ per coordinate of a random calibration offset: ``in_targets`` × target (scale: ``scale_sigma``;
    tyre slip: none, the simulator's physics sets it)."""
    return np.array([scale_sigma if c.kind == "scale" else 0.0 if c.nuisance else in_targets * c.target
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
    (:attr:`excite.rig.config.Rig.wheel_increment_sigma_rad`).
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
    """

    noise: bool = True
    imu_oversampling: int = 8
    bias_random_walk: bool = True
    wheel_ticks_per_rev: int = 2048
    wheel_slip_per_g: float = 0.01
    wheel_scrub_per_g2: float = 0.01
    slip_angle_deg_per_mps2: float = 0.15
    slip_noise: bool = True

    @classmethod
    def model(cls, **changes) -> "SimulationSettings":
        """Data as the information model assumes it: increment-equivalent IMU samples, constant
        biases, wheels turning with the model's chord, no tyre slip angle."""
        base = dict(imu_oversampling=0, bias_random_walk=False, wheel_slip_per_g=0.0, wheel_scrub_per_g2=0.0,
                    slip_angle_deg_per_mps2=0.0)
        return cls(**{**base, **changes})

    @property
    def physical(self) -> bool:
        return (self.imu_oversampling > 0 or self.bias_random_walk or self.wheel_slip_per_g != 0
                or self.wheel_scrub_per_g2 != 0 or self.slip_angle_deg_per_mps2 != 0)

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
class OdometryData:
    """Relative poses of one sensor between its consecutive frames (keyframe indices ``frames``)."""

    frames: np.ndarray
    R_rel: np.ndarray  # (F−1, 3, 3)
    t_rel: np.ndarray  # (F−1, 3)


@dataclass(frozen=True)
class Truth:
    """What the data was generated from: body states at the keyframes and the calibration."""

    R: np.ndarray
    p: np.ndarray
    v: np.ndarray
    calibration: Calibration
    gyro_bias: np.ndarray  # (samples, 3): the bias track (constant unless random walk)
    accel_bias: np.ndarray


@dataclass(frozen=True)
class SensorData:
    """Raw data of one drive, on the keyframe grid of the rig (IMU sample ``k·n`` is keyframe k).

    ``gyro``/``accel`` (n_intervals·n, 3): sample s acts over ``[t_imu[s], t_imu[s] + dt)``.
    ``wheel_ticks`` (K, 2) cumulative left/right counts at the keyframes (None without wheels),
    ``slip`` (K, 2) the non-holonomic pseudo-measurement, ``R_V_A`` (K, 3, 3) the known suspension
    tilt, ``R_V_B, p_V_B`` the known IMU pose in the vehicle frame.
    """

    t: np.ndarray
    t_imu: np.ndarray
    imu_per_keyframe: int
    gyro: np.ndarray
    accel: np.ndarray
    odometry: dict[str, OdometryData]
    wheel_ticks: np.ndarray | None
    ticks_per_rev: int
    slip: np.ndarray
    R_V_A: np.ndarray
    R_V_B: np.ndarray
    p_V_B: np.ndarray
    truth: Truth = field(repr=False)

    @property
    def n_keyframes(self) -> int:
        return self.t.size

    @property
    def dt_imu(self) -> float:
        return float(self.t[1] - self.t[0]) / self.imu_per_keyframe

    @property
    def wheel_increments(self) -> np.ndarray | None:
        """Left/right wheel rotation [rad] over each keyframe interval, from the ticks."""
        if self.wheel_ticks is None:
            return None
        q = 2 * np.pi / self.ticks_per_rev if self.ticks_per_rev else 1.0
        return np.diff(self.wheel_ticks, axis=0) * q


def _body(traj: Trajectory, t: np.ndarray, R_V_B: np.ndarray, p_V_B: np.ndarray):
    return traj.sample(t).body(R_V_B, p_V_B)


def _body_at(traj: Trajectory, t: np.ndarray, R_V_B: np.ndarray, p_V_B: np.ndarray):
    """Body pose at ``t``; beyond the ends of the drive, extended at the end's velocity and rate
    (what a sensor stamped near the ends with a time offset sees; the factor's own model)."""
    tc = np.clip(t, traj.t_start, traj.t_end)
    b = _body(traj, tc, R_V_B, p_V_B)
    dt = (t - tc)[:, None]
    return b.R_W_B @ so3.exp(b.omega_B * dt), b.p_W_B + b.v_W * dt


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
    return Trajectory(t, R, smp.p_W_V, tilt_pitch_roll=tilt, velocity=smp.v_W, name=traj.name)


def _imu_boxcar(traj: Trajectory, t_imu: np.ndarray, dt: float, m: int, R_V_B: np.ndarray, p_V_B: np.ndarray):
    """Mean true body rate and specific force over each IMU sample interval, from ``m`` internal
    samples at the interval's sub-step midpoints."""
    sub = (np.arange(m) + 0.5) * dt / m
    t = (t_imu[:-1, None] + sub[None, :]).ravel()
    _, w, f = traj.imu(t, R_V_B, p_V_B)
    return w.reshape(-1, m, 3).mean(axis=1), f.reshape(-1, m, 3).mean(axis=1)


def _wheel_angles(traj: Trajectory, t: np.ndarray, t_keyframes: np.ndarray, radii: tuple[float, float],
                  track: float, slip_per_g: float, scrub_per_g2: float) -> np.ndarray:
    """Cumulative left/right wheel angles at ``t_keyframes`` [rad]: each wheel's contact-point speed
    along its heading (the axle's forward speed ∓ half the track times the yaw rate), times
    ``1 + κ`` with the slip ratio ``κ = slip_per_g·a_long/g + scrub_per_g2·(a_lat/g)²``, over its
    true radius, integrated (trapezoid) on the fine grid ``t``."""
    smp = traj.sample(t)
    g = float(np.linalg.norm(GRAVITY))
    kappa = slip_per_g * smp.accel_long / g + scrub_per_g2 * (smp.accel_lat / g) ** 2
    u, r = smp.speed, smp.yaw_rate
    rate = np.stack([(u - 0.5 * track * r) / radii[0], (u + 0.5 * track * r) / radii[1]], axis=1)
    rate *= (1.0 + kappa)[:, None]
    angle = np.vstack([np.zeros((1, 2)), np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t)[:, None], axis=0)])
    return np.stack([np.interp(t_keyframes, t, angle[:, i]) for i in range(2)], axis=1)


def _imu_increment_equivalent(traj: Trajectory, nom: Nominal, t_imu: np.ndarray, dt: float, R_V_B: np.ndarray,
                              p_V_B: np.ndarray):
    """Increment-equivalent IMU samples (see the module docstring): the rates over each sample
    interval that the model's held-sample preintegration turns into the drive's keyframe states."""
    n, K = nom.imu_per_keyframe, nom.n_keyframes
    b = _body(traj, t_imu, R_V_B, p_V_B)
    R_s, v_s = b.R_W_B, b.v_W
    omega = so3.log(np.swapaxes(R_s[:-1], 1, 2) @ R_s[1:]) / dt
    a_s = (v_s[1:] - v_s[:-1]) / dt  # world acceleration held over each sample
    # Held samples reproduce the keyframe positions only to the trapezoid error dt²·Δa/12, which
    # on a jerky drive reaches several σ of the preintegrated position. A zero-mean ramp across
    # each interval's samples removes it without changing the velocity increment, so the samples
    # are exactly those of a motion through the drive's keyframe states (it departs from the
    # drive between keyframes by less than that error).
    w = (n - 1 - np.arange(n) + 0.5) * dt
    a_int = a_s.reshape(K - 1, n, 3)
    e_p = (nom.p[1:] - nom.p[:-1] - nom.v[:-1] * (n * dt)) - np.einsum("s,nsi->ni", w, a_int) * dt
    wc_ = w - w.mean()
    a_int = a_int + (e_p / (dt * (wc_**2).sum()))[:, None, :] * wc_[None, :, None]
    R_mid = R_s[:-1] @ so3.exp(0.5 * omega * dt)  # the preintegration applies f mid-sample
    f = np.einsum("nji,nj->ni", R_mid, a_int.reshape(-1, 3) - GRAVITY)
    return omega, f


def simulate(traj: Trajectory, rig: Rig, truth: Calibration, rng: np.random.Generator,
             settings: SimulationSettings = SimulationSettings()) -> SensorData:
    """Noisy raw data of ``traj`` driven with ``rig`` whose true calibration is ``truth``.

    ``rig`` gives the noise levels, rates and known geometry; ``truth`` the values the data is
    generated with. Same ``rng`` state, same data.
    """
    if settings.slip_angle_deg_per_mps2:
        traj = _with_slip_angle(traj, settings.slip_angle_deg_per_mps2)
    nom = Nominal.of(traj, rig)
    if nom.n_keyframes < 3:
        raise ValidateError(f"the drive is too short to simulate: {nom.n_keyframes} keyframes")
    cfg = rig.config
    n = nom.imu_per_keyframe
    K = nom.n_keyframes
    rate = cfg.imu.update_rate
    dt = 1.0 / rate
    t_imu = nom.t[0] + np.arange((K - 1) * n + 1) * dt
    R_V_B, p_V_B = nom.R_V_B, nom.p_V_B
    noisy = settings.noise

    if settings.imu_oversampling:
        omega, f = _imu_boxcar(traj, t_imu, dt, settings.imu_oversampling, R_V_B, p_V_B)
    else:
        omega, f = _imu_increment_equivalent(traj, nom, t_imu, dt, R_V_B, p_V_B)
    m = omega.shape[0]
    imu = cfg.imu
    bg = np.broadcast_to(truth.gyro_bias, (m, 3)).copy()
    ba = np.broadcast_to(truth.accel_bias, (m, 3)).copy()
    if settings.bias_random_walk and noisy:
        bg += np.cumsum(rng.normal(0.0, imu.gyroscope_random_walk * np.sqrt(dt), (m, 3)), axis=0)
        ba += np.cumsum(rng.normal(0.0, imu.accelerometer_random_walk * np.sqrt(dt), (m, 3)), axis=0)
    gyro = omega + bg
    accel = f + ba
    if noisy:
        gyro += rng.normal(0.0, imu.gyroscope_noise_density * np.sqrt(rate), (m, 3))
        accel += rng.normal(0.0, imu.accelerometer_noise_density * np.sqrt(rate), (m, 3))

    # exteroceptive sensors: relative poses at their own (offset) clocks
    odo: dict[str, OdometryData] = {}
    for s in cfg.sensors:
        stride = int(round(rig.keyframe_rate_hz / s.rate_hz))
        frames = np.arange(0, K, stride)
        if frames.size < 2:
            continue
        R_BS, p_BS = truth.extrinsics[s.name]
        R_b, p_b = _body_at(traj, nom.t[frames] + truth.time_offsets[s.name], R_V_B, p_V_B)
        R_S = R_b @ R_BS
        p_S = p_b + R_b @ p_BS
        R_iT = np.swapaxes(R_S[:-1], 1, 2)
        R_rel = R_iT @ R_S[1:]
        t_rel = np.einsum("nij,nj->ni", R_iT, p_S[1:] - p_S[:-1]) * truth.scales[s.name]
        if noisy:
            F = frames.size - 1
            R_rel = R_rel @ so3.exp(rng.normal(0.0, np.deg2rad(s.noise.rotation_sigma_deg), (F, 3)))
            t_rel = t_rel + rng.normal(0.0, s.noise.translation_sigma_m, (F, 3))
        odo[s.name] = OdometryData(frames, R_rel, t_rel)

    # wheel encoders: ticks of the cumulative wheel angle
    R_BV = R_V_B.T
    p_BV = -R_BV @ p_V_B
    R_BA = R_BV @ nom.R_V_A
    ticks, tpr = None, settings.wheel_ticks_per_rev
    wc = cfg.wheels
    if wc is not None:
        rl, rr, track = truth.wheel
        if settings.wheel_slip_per_g or settings.wheel_scrub_per_g2:
            t_fine = nom.t[0] + np.arange((K - 1) * n * max(settings.imu_oversampling, 1) + 1) * (
                dt / max(settings.imu_oversampling, 1))
            inc = np.diff(_wheel_angles(traj, t_fine, nom.t, (rl, rr), track, settings.wheel_slip_per_g,
                                        settings.wheel_scrub_per_g2), axis=0)
        else:
            inc = np.stack([wheel.increments(nom.R[k], nom.p[k], nom.R[k + 1], nom.p[k + 1], R_BA[k], R_BA[k + 1],
                                             p_BV, rl, rr, track) for k in range(K - 1)])
        q = 2 * np.pi / tpr if tpr else 0.0
        white2 = rig.wheel_increment_sigma_rad**2 - q**2 / 6.0  # an increment differences two quantisation errors
        if white2 <= 0:
            raise ValidateError(f"wheel quantisation of {tpr} ticks/rev alone exceeds the wheel noise "
                                f"per keyframe ({rig.wheel_increment_sigma_rad:g} rad): use more ticks per revolution")
        if noisy:
            inc = inc + rng.normal(0.0, np.sqrt(white2), inc.shape)
        angle = np.vstack([np.zeros((1, 2)), np.cumsum(inc, axis=0)])
        if tpr:
            phase = rng.uniform(0.0, 1.0, 2) if noisy else np.full(2, 0.5)
            ticks = np.floor(angle / q + phase) - np.floor(phase)
        else:
            ticks = angle

    slip = np.zeros((K, 2))
    if noisy and settings.slip_noise:
        slip = rng.normal(0.0, 1.0, (K, 2)) * np.array(rig.nonholonomic_sigma_mps)

    return SensorData(t=nom.t, t_imu=t_imu, imu_per_keyframe=n, gyro=gyro, accel=accel, odometry=odo,
                      wheel_ticks=ticks, ticks_per_rev=tpr, slip=slip, R_V_A=nom.R_V_A, R_V_B=R_V_B,
                      p_V_B=p_V_B,
                      truth=Truth(nom.R, nom.p, nom.v, truth, bg, ba))
