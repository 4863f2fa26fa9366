"""What every factor shares: the nominal states it is linearised at, and its Jacobian blocks.

The nuisance state of keyframe k is ``x_k = [δθ (3), δp (3), δv (3)]``: a right perturbation of
the body orientation ``R_W_B · Exp(δθ)``, and additive world position and velocity of B. The
calibration vector θ has one column per :class:`~excite.rig.config.Coordinate` of the rig, in its order.
Every factor returns *whitened* Jacobians: one row per residual component divided by its σ
(or multiplied by the inverse Cholesky factor of its covariance).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..rig.config import Rig
from ..motion.trajectory import Trajectory, rigid_body

STATE_DIM = 9
ROT, POS, VEL = slice(0, 3), slice(3, 6), slice(6, 9)
# with random-walk IMU biases every keyframe also carries the bias deviations [δb_g, δb_a]
BIAS_STATE_DIM = 15
BIAS = slice(9, 15)


@dataclass(frozen=True)
class Nominal:
    """The nominal motion a rig sees on a drive: the IMU's at every IMU sample, the body's at the
    keyframes.

    Keyframe ``k`` is IMU sample ``k · imu_per_keyframe``. At the keyframes: time ``t``, body
    (IMU frame) orientation ``R``, world position ``p`` and velocity ``v``, body rate ``omega``
    and the suspension tilt ``R_V_A``. At the IMU rate: orientation ``imu_R``, body rate
    ``imu_omega`` and specific force ``imu_f``. ``R_V_B, p_V_B`` is the IMU pose in the vehicle frame.
    """

    t: np.ndarray
    R: np.ndarray
    p: np.ndarray
    v: np.ndarray
    omega: np.ndarray
    R_V_A: np.ndarray
    imu_R: np.ndarray
    imu_omega: np.ndarray
    imu_f: np.ndarray
    imu_per_keyframe: int
    R_V_B: np.ndarray
    p_V_B: np.ndarray
    length_m: float = 0.0  # path length of the rear axle (trapezoid over the keyframes)

    @property
    def n_keyframes(self) -> int:
        return self.t.size

    def window(self, k0: int, k1: int) -> "Nominal":
        """Keyframes ``k0..k1`` (inclusive) and the IMU samples between them (views, no copies)."""
        n = self.imu_per_keyframe
        kf = slice(k0, k1 + 1)
        imu = slice(k0 * n, k1 * n + 1)
        return Nominal(t=self.t[kf], R=self.R[kf], p=self.p[kf], v=self.v[kf], omega=self.omega[kf],
                       R_V_A=self.R_V_A[kf], imu_R=self.imu_R[imu], imu_omega=self.imu_omega[imu],
                       imu_f=self.imu_f[imu], imu_per_keyframe=n, R_V_B=self.R_V_B, p_V_B=self.p_V_B)

    @staticmethod
    def grid(traj: Trajectory, rig: Rig, t_start: float | None = None,
             t_end: float | None = None) -> tuple[float, int]:
        """Start time and number of keyframes of the whole keyframe intervals of ``traj`` within
        ``[t_start, t_end]``."""
        t0 = traj.t_start if t_start is None else max(t_start, traj.t_start)
        t1 = traj.t_end if t_end is None else min(t_end, traj.t_end)
        return t0, int(np.floor((t1 - t0) * rig.keyframe_rate_hz + 1e-9)) + 1

    @staticmethod
    def keyframe_times(traj: Trajectory, rig: Rig) -> np.ndarray:
        """The times of the keyframes of ``traj`` (those of :meth:`of`, bit for bit)."""
        t0, K = Nominal.grid(traj, rig)
        imu_rate = rig.config.imu.update_rate
        n = int(round(imu_rate / rig.keyframe_rate_hz))
        return np.clip(t0 + np.arange(K) * n / imu_rate, traj.t_start, traj.t_end)

    @classmethod
    def of(cls, traj: Trajectory, rig: Rig, t_start: float | None = None, t_end: float | None = None,
           keyframes: tuple[int, int] | None = None) -> "Nominal":
        """Sample ``traj`` for ``rig`` on the whole keyframe intervals within ``[t_start, t_end]``
        (:meth:`grid`), or on its keyframes ``k0 … k1`` only: the same samples as those of the
        whole, bit for bit."""
        t0, K = cls.grid(traj, rig, t_start, t_end)
        k0, k1 = (0, K - 1) if keyframes is None else keyframes
        imu_rate = rig.config.imu.update_rate
        n = int(round(imu_rate / rig.keyframe_rate_hz))
        t_imu = t0 + np.arange(k0 * n, k1 * n + 1) / imu_rate
        R_V_B, p_V_B = rig.config.vehicle.T_V_B.R, rig.config.vehicle.T_V_B.p
        imu_R, imu_w, imu_f = traj.imu(t_imu, R_V_B, p_V_B)
        # the keyframes: what :meth:`Trajectory.sample` and ``body`` give, less the accelerations
        t = np.clip(t_imu[::n], traj.t_start, traj.t_end)
        R_W_V, omega_V, _ = traj.rotation(t)
        p_V, v_V, R_V_A = traj.translation(t)
        R, p, v, omega = rigid_body(R_W_V, p_V, v_V, omega_V, R_V_B, p_V_B)
        length = float(np.trapezoid(np.linalg.norm(v_V, axis=1), t))
        return cls(t=t, R=R, p=p, v=v, omega=omega, R_V_A=R_V_A, imu_R=imu_R, imu_omega=imu_w, imu_f=imu_f,
                   imu_per_keyframe=n, R_V_B=R_V_B, p_V_B=p_V_B, length_m=length)


@dataclass(frozen=True)
class FactorBlock:
    """Whitened Jacobians of N factors of one kind.

    Factor ``f`` touches the keyframes ``first[f] + stride · m`` for ``m < n_states`` through
    ``Jx[f]`` (r × 9·n_states), and the calibration columns ``cols`` through ``Jt[f]``
    (r × len(cols)). ``xcols``, where known: the columns of ``Jx`` that may be non-zero (every other
    one is zero for every factor), which :func:`excite.core.kernels.accumulate` can skip.
    """

    name: str
    first: np.ndarray
    stride: int
    n_states: int
    Jx: np.ndarray
    Jt: np.ndarray
    cols: np.ndarray
    xcols: np.ndarray | None = None

    def nonzero_columns(self) -> np.ndarray:
        """``xcols``, or every column of ``Jx`` where they are not known."""
        return np.arange(self.Jx.shape[2]) if self.xcols is None else self.xcols

    @property
    def n_factors(self) -> int:
        return self.first.size

    @property
    def n_rows(self) -> int:
        return self.Jx.shape[1]

    def Jt_full(self, n_params: int) -> np.ndarray:
        """The calibration Jacobian over all ``n_params`` columns (N × r × n_params)."""
        out = np.zeros(self.Jt.shape[:2] + (n_params,))
        out[:, :, self.cols] = self.Jt
        return out

    def select(self, mask: np.ndarray) -> "FactorBlock":
        return replace(self, first=self.first[mask], Jx=self.Jx[mask], Jt=self.Jt[mask])

    def shifted(self, by: int) -> "FactorBlock":
        """The same factors with keyframe indices moved by ``by``."""
        return replace(self, first=self.first + by)

    def within(self, k0: int, k1: int) -> "FactorBlock | None":
        """The factors that lie entirely within keyframes ``k0 … k1``, indexed from ``k0``; None
        if there are none (a window's factors: :meth:`excite.information.Problem.window`)."""
        inside = (self.first >= k0) & (self.first + self.stride * (self.n_states - 1) <= k1)
        return self.select(inside).shifted(-k0) if inside.any() else None


def theta_columns(rig: Rig, names: list[str]) -> np.ndarray:
    """Column indices of the named calibration coordinates."""
    return np.array([rig.index(n) for n in names], dtype=int)
