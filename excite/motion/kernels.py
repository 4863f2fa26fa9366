"""Sampling a trajectory's splines (C: ``motion/kernels.c`` of :mod:`excite.core.native`): the
segment of each time, orientations from the rotation spline, and the IMU's body rate and specific
force at the IMU rate (:meth:`excite.motion.trajectory.Trajectory.rotation`,
:meth:`~excite.motion.trajectory.Trajectory.imu`; held to scipy's RotationSpline and Rotation by the
tests).

On segment k the rotation is ``R_key[k] · Exp(φ(τ))``, φ a cubic PPoly in ``τ = t − x[k]``; the
body rate is ``ω = J_r(φ) φ̇`` and the angular acceleration ``α = J_r φ̈ + J̇_r φ̇``, with
``J_r(φ) = I − b [φ]× + c [φ]×²`` (``b = (1 − cos θ)/θ²``, ``c = (θ − sin θ)/θ³``, by series below
1e-2 rad). An IMU at ``(R_V_B, p_V_B)`` in V reads ``R_W_B = R_W_V R_V_B``, ``ω_B = R_V_Bᵀ ω`` and
``f_B = R_V_Bᵀ (R_W_Vᵀ(a − g) + α × p + ω × (ω × p))``.
"""

from __future__ import annotations

import numpy as np

from ..core.native import module


def segments(breaks: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index of the piecewise-polynomial segment (between ``breaks``, increasing) that holds every
    time: ``clip(searchsorted(breaks, t, "right") − 1, 0, breaks.size − 2)``, walking along the
    breaks while the times increase (a binary search only where they do not)."""
    out = np.empty(t.size, dtype=np.int64)
    module().segments(np.ascontiguousarray(breaks, dtype=float), np.ascontiguousarray(t, dtype=float), out)
    return out


def rotation_samples(t, seg_rot, x_rot, c_rot, R_key) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orientation, body rate and angular acceleration of a rotation spline ``R_key[k] · Exp(φ(t))``
    (φ a cubic PPoly ``x_rot, c_rot``; ``seg_rot`` the segment of every time)."""
    n = t.size
    R, w, a = np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 3))
    module().rotation_samples(_f(t), _i(seg_rot), _f(x_rot), _f(c_rot), _f(R_key), R, w, a)
    return R, w, a


def imu_samples(t, seg_rot, x_rot, c_rot, R_key, seg_acc, x_acc, c_acc, gravity, R_V_B,
                p_V_B) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orientation R_W_B, body rate ω_B and specific force f_B of an IMU at ``(R_V_B, p_V_B)`` in V:
    V's orientation, body rate and angular acceleration as in :func:`rotation_samples`, its
    acceleration a PPoly (``x_acc, c_acc``; ``seg_acc`` the segment of every time)."""
    n = t.size
    R, w, f = np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 3))
    module().imu_samples(_f(t), _i(seg_rot), _f(x_rot), _f(c_rot), _f(R_key), _i(seg_acc), _f(x_acc), _f(c_acc),
                         _f(gravity), _f(R_V_B), _f(p_V_B), R, w, f)
    return R, w, f


def _f(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float)


def _i(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=np.int64)
