"""SO(3) helpers, batched over a leading axis.

Conventions (DESIGN.md): rotations act on column vectors, perturbations are right-multiplicative
(``R · Exp(δθ)``), and ``Exp``/``Log`` map between rotation vectors and rotation matrices.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

_SMALL = 1e-8


def hat(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``[v]×`` of vectors ``(..., 3)`` → ``(..., 3, 3)``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` from rotation vectors ``(..., 3)``."""
    phi = np.asarray(phi, dtype=float)
    flat = phi.reshape(-1, 3)
    return Rotation.from_rotvec(flat).as_matrix().reshape(phi.shape[:-1] + (3, 3))


def log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` of rotation matrices ``(..., 3, 3)``."""
    R = np.asarray(R, dtype=float)
    flat = R.reshape(-1, 3, 3)
    return Rotation.from_matrix(flat).as_rotvec().reshape(R.shape[:-2] + (3,))


def right_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """``J_r⁻¹(φ)``: ``Log(Exp(φ)·Exp(δ)) ≈ φ + J_r⁻¹(φ) δ``."""
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = hat(phi)
    K2 = K @ K
    small = theta < _SMALL
    t = np.where(small, 1.0, theta)
    coef = np.where(small, 1.0 / 12.0, 1.0 / t**2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    return np.eye(3) + 0.5 * K + coef * K2


def left_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """``J_l⁻¹(φ)``: ``Log(Exp(δ)·Exp(φ)) ≈ φ + J_l⁻¹(φ) δ``."""
    return right_jacobian_inv(-np.asarray(phi, dtype=float))


def rot_x(a: np.ndarray) -> np.ndarray:
    """Rotations about x by angles ``a`` (any shape) → ``(..., 3, 3)``."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 0, 0] = 1.0
    R[..., 1, 1], R[..., 1, 2] = c, -s
    R[..., 2, 1], R[..., 2, 2] = s, c
    return R


def rot_y(a: np.ndarray) -> np.ndarray:
    """Rotations about y by angles ``a`` (any shape) → ``(..., 3, 3)``."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 1, 1] = 1.0
    R[..., 0, 0], R[..., 0, 2] = c, s
    R[..., 2, 0], R[..., 2, 2] = -s, c
    return R


def rot_z(a: np.ndarray) -> np.ndarray:
    """Rotations about z by angles ``a`` (any shape) → ``(..., 3, 3)``."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 2, 2] = 1.0
    R[..., 0, 0], R[..., 0, 1] = c, -s
    R[..., 1, 0], R[..., 1, 1] = s, c
    return R


def yaw_pitch_roll(R: np.ndarray) -> np.ndarray:
    """Z-Y-X Euler angles ``(..., 3)`` = (yaw, pitch, roll) with ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    R = np.asarray(R, dtype=float)
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    pitch = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    return np.stack([yaw, pitch, roll], axis=-1)
