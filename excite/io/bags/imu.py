"""Measured IMU: its samples, a trajectory whose IMU is the measured one, and how well the
measurement agrees with the poses."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ...errors import BagError, RouteError
from ...motion.trajectory import Trajectory
from .stream import check_stamps


@dataclass(frozen=True)
class ImuSeries:
    """Measured angular rate ``omega`` [rad/s] and specific force ``accel`` [m/s²] in ``frame``."""

    t_ns: np.ndarray
    omega: np.ndarray
    accel: np.ndarray
    frame: str


def imu_series(path: Path, topic: str, t_ns: np.ndarray, d: np.ndarray, frame: str) -> ImuSeries:
    if t_ns.size < 2:
        raise BagError(path, f"{t_ns.size} IMU messages: need at least 2", topic)
    check_stamps(path, topic, t_ns)
    omega, accel = d[:, :3], d[:, 3:]
    if not (np.all(np.isfinite(omega)) and np.all(np.isfinite(accel))):
        raise BagError(path, "an IMU sample is NaN or infinite", topic)
    return ImuSeries(t_ns, omega, accel, frame)


class ImuTrajectory(Trajectory):
    """A logged trajectory whose IMU samples are measured: :meth:`imu` returns the orientation of
    B from the poses and the *measured* angular rate and specific force (interpolated linearly;
    the IMU frame is the rig's B, so the rig's mounting is not applied to them again)."""

    t_imu: np.ndarray  # seconds on the trajectory's clock
    omega_B: np.ndarray
    f_B: np.ndarray
    imu_frame: str

    @classmethod
    def of(cls, traj: Trajectory, t_imu: np.ndarray, omega_B: np.ndarray, f_B: np.ndarray,
           imu_frame: str) -> "ImuTrajectory":
        out = cls.__new__(cls)
        out.__dict__.update(traj.__dict__)
        out.t_imu, out.omega_B, out.f_B, out.imu_frame = t_imu, omega_B, f_B, imu_frame
        return out

    def imu(self, t, R_V_B, p_V_B):
        R_W_B, _, _ = super().imu(t, R_V_B, p_V_B)
        t = np.clip(np.asarray(t, dtype=float), self.t_start, self.t_end)
        w = np.column_stack([np.interp(t, self.t_imu, self.omega_B[:, i]) for i in range(3)])
        f = np.column_stack([np.interp(t, self.t_imu, self.f_B[:, i]) for i in range(3)])
        return R_W_B, w, f

    def modelled_imu(self, t, R_V_B, p_V_B):
        """What the poses alone predict (the base trajectory's IMU)."""
        return super().imu(t, R_V_B, p_V_B)


@dataclass(frozen=True)
class ImuAgreement:
    """Measured IMU against the poses' prediction, over 1-s means (the band both resolve).

    ``gyro_offset_radps``/``accel_offset_mps2``: mean measured − predicted (biases, mounting);
    ``gyro_rms_radps``/``accel_rms_mps2``: RMS of what is left; ``misalignment_deg``: the angle of
    the rotation that best maps predicted onto measured rates and specific forces (0 when the
    rig's mounting is the IMU's; None when the drive does not determine it); ``seconds``: time
    both cover.
    """

    seconds: float
    gyro_offset_radps: np.ndarray
    gyro_rms_radps: float
    accel_offset_mps2: np.ndarray
    accel_rms_mps2: float
    misalignment_deg: float | None

    def text(self) -> str:
        mis = "—" if self.misalignment_deg is None else f"{self.misalignment_deg:.2f} deg"
        return (f"measured IMU vs poses over {self.seconds:.0f} s (1-s means): gyro "
                f"{np.degrees(self.gyro_rms_radps):.3g} deg/s RMS, offset "
                f"{np.degrees(np.linalg.norm(self.gyro_offset_radps)):.3g} deg/s; accel "
                f"{self.accel_rms_mps2:.3g} m/s² RMS, offset "
                f"{np.linalg.norm(self.accel_offset_mps2):.3g} m/s²; mounting mismatch {mis}")


def imu_agreement(traj: ImuTrajectory, R_V_B: np.ndarray, p_V_B: np.ndarray) -> ImuAgreement:
    """How well the measured IMU of ``traj`` agrees with its poses for a rig mounted at
    ``(R_V_B, p_V_B)`` (see :class:`ImuAgreement`)."""
    t = traj.t_imu[(traj.t_imu >= traj.t_start) & (traj.t_imu <= traj.t_end)]
    n_blocks = int((t[-1] - t[0]) // 1.0) if t.size else 0
    if n_blocks < 1:
        raise RouteError("the IMU overlaps the poses for less than 1 s")
    _, w_m, f_m = traj.imu(t, R_V_B, p_V_B)
    _, w_p, f_p = traj.modelled_imu(t, R_V_B, p_V_B)
    block = np.minimum(((t - t[0]) // 1.0).astype(int), n_blocks - 1)
    counts = np.bincount(block, minlength=n_blocks)[:, None]

    def means(x):
        return np.stack([np.bincount(block, x[:, i], n_blocks) for i in range(3)], axis=1) / counts

    wm, wp, fm, fp = means(w_m), means(w_p), means(f_m), means(f_p)
    gw, gf = (wm - wp).mean(axis=0), (fm - fp).mean(axis=0)
    rw = float(np.sqrt(np.mean(np.sum((wm - wp - gw) ** 2, axis=1))))
    rf = float(np.sqrt(np.mean(np.sum((fm - fp - gf) ** 2, axis=1))))
    # The mounting rotation from both vector sets at once (1-s means of specific force, gravity
    # included, and of angular rate scaled to the same size): a planar drive turns about one
    # axis only, its accelerations and gravity give the other two.
    scale = 9.80665 / max(float(np.sqrt(np.mean(np.sum(wp ** 2, axis=1)))), 1e-6)
    pred, meas = np.vstack([fp, wp * scale]), np.vstack([fm - gf, (wm - gw) * scale])
    mis = None
    if np.linalg.matrix_rank(pred, tol=0.05 * np.sqrt(pred.shape[0])) >= 2:
        rot, _ = Rotation.align_vectors(meas, pred)
        mis = float(np.degrees(rot.magnitude()))
    return ImuAgreement(float(t[-1] - t[0]), gw, rw, gf, rf, mis)
