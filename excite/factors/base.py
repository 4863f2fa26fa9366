"""What every factor shares: the nominal states it is linearised at, and its Jacobian blocks.

The nuisance state of keyframe k is ``x_k = [δθ (3), δp (3), δv (3)]``: a right perturbation of
the body orientation ``R_W_B · Exp(δθ)``, and additive world position and velocity of B. The
calibration vector θ has one column per :class:`~excite.rig.Coordinate` of the rig, in its order.
Every factor returns *whitened* Jacobians: one row per residual component divided by its σ
(or multiplied by the inverse Cholesky factor of its covariance).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rig import Rig
from ..trajectory import BodySamples, Trajectory

STATE_DIM = 9
ROT, POS, VEL = slice(0, 3), slice(3, 6), slice(6, 9)


@dataclass(frozen=True)
class Nominal:
    """The nominal motion a rig sees on a drive, at the IMU rate and at the keyframes.

    ``imu`` holds the body (IMU frame) motion at every IMU sample; keyframe ``k`` is IMU sample
    ``k · imu_per_keyframe``. ``R_V_A`` is the suspension tilt at the keyframes, ``R_V_B, p_V_B``
    the IMU pose in the vehicle frame.
    """

    imu: BodySamples
    imu_per_keyframe: int
    R_V_A: np.ndarray
    R_V_B: np.ndarray
    p_V_B: np.ndarray

    @property
    def n_keyframes(self) -> int:
        return (self.imu.t.size - 1) // self.imu_per_keyframe + 1

    def _kf(self, a: np.ndarray) -> np.ndarray:
        return a[:: self.imu_per_keyframe]

    @property
    def t(self) -> np.ndarray:
        return self._kf(self.imu.t)

    @property
    def R(self) -> np.ndarray:
        return self._kf(self.imu.R_W_B)

    @property
    def p(self) -> np.ndarray:
        return self._kf(self.imu.p_W_B)

    @property
    def v(self) -> np.ndarray:
        return self._kf(self.imu.v_W)

    @property
    def omega(self) -> np.ndarray:
        return self._kf(self.imu.omega_B)

    @classmethod
    def of(cls, traj: Trajectory, rig: Rig, t_start: float | None = None,
           t_end: float | None = None) -> "Nominal":
        """Sample ``traj`` for ``rig`` on whole keyframe intervals within ``[t_start, t_end]``."""
        imu_rate = rig.config.imu.update_rate
        n = int(round(imu_rate / rig.keyframe_rate_hz))
        t0 = traj.t_start if t_start is None else max(t_start, traj.t_start)
        t1 = traj.t_end if t_end is None else min(t_end, traj.t_end)
        n_intervals = int(np.floor((t1 - t0) * rig.keyframe_rate_hz + 1e-9))
        t = t0 + np.arange(n_intervals * n + 1) / imu_rate
        s = traj.sample(t)
        pose = rig.config.vehicle.T_V_B
        body = s.body(pose.R, pose.p)
        return cls(imu=body, imu_per_keyframe=n, R_V_A=s.R_V_A[::n], R_V_B=pose.R, p_V_B=pose.p)


@dataclass(frozen=True)
class FactorBlock:
    """Whitened Jacobians of N factors of one kind.

    Factor ``f`` touches the keyframes ``first[f] + stride · m`` for ``m < n_states`` through
    ``Jx[f]`` (r × 9·n_states) and the calibration vector through ``Jt[f]`` (r × len(θ)).
    """

    name: str
    first: np.ndarray
    stride: int
    n_states: int
    Jx: np.ndarray
    Jt: np.ndarray

    @property
    def n_factors(self) -> int:
        return self.first.size

    @property
    def n_rows(self) -> int:
        return self.Jx.shape[1]

    def select(self, mask: np.ndarray) -> "FactorBlock":
        return FactorBlock(self.name, self.first[mask], self.stride, self.n_states, self.Jx[mask], self.Jt[mask])
