"""SO(3) helpers, batched over a leading axis.

Conventions (DESIGN.md): rotations act on column vectors, perturbations are right-multiplicative
(``R · Exp(δθ)``), and ``Exp``/``Log`` map between rotation vectors and rotation matrices.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

_SMALL = 1e-8
_SERIES = 1e-2


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


def _coefficients(theta: np.ndarray):
    """(sin θ/θ, (1 − cos θ)/θ², (θ − sin θ)/θ³), by series below 1e-2 rad (exact to 1e-16)."""
    theta = np.asarray(theta, dtype=float)
    t2 = theta * theta
    a = np.array(1.0 - t2 / 6.0 + t2 * t2 / 120.0)  # 0-d arrays too: masked assignment below
    b = np.array(0.5 - t2 / 24.0 + t2 * t2 / 720.0)
    c = np.array(1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0)
    big = theta >= _SERIES
    if big.any():
        t = theta[big]
        a[big], b[big], c[big] = np.sin(t) / t, (1.0 - np.cos(t)) / t**2, (t - np.sin(t)) / t**3
    return a, b, c


def exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` from rotation vectors ``(..., 3)`` (Rodrigues:
    ``cos θ·I + sin θ/θ·[φ]× + (1 − cos θ)/θ²·φφᵀ``)."""
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)
    a, b, _ = _coefficients(theta)
    R = (b[..., None, None] * phi[..., :, None]) * phi[..., None, :]
    cos = 1.0 - b * theta * theta
    ax, ay, az = (a * phi[..., i] for i in range(3))
    R[..., 0, 0] += cos
    R[..., 1, 1] += cos
    R[..., 2, 2] += cos
    R[..., 0, 1] -= az
    R[..., 1, 0] += az
    R[..., 0, 2] += ay
    R[..., 2, 0] -= ay
    R[..., 1, 2] -= ax
    R[..., 2, 1] += ax
    return R


def body_rate(phi: np.ndarray, phi_dot: np.ndarray, phi_ddot: np.ndarray | None = None):
    """Body rate ``ω = J_r(φ) φ̇`` of ``Exp(φ(t))`` and, given ``φ̈``, its derivative
    ``J_r φ̈ + J̇_r φ̇``, with vector algebra only (``[φ]×x = φ × x``)."""
    theta = np.linalg.norm(phi, axis=-1)
    _, b, c = _coefficients(theta)
    pxd = np.cross(phi, phi_dot)
    ppxd = np.cross(phi, pxd)
    w = phi_dot - b[..., None] * pxd + c[..., None] * ppxd
    if phi_ddot is None:
        return w
    eb, ec = _derivative_coefficients(theta)
    pd = np.einsum("...i,...i->...", phi, phi_dot)[..., None]
    pxdd = np.cross(phi, phi_ddot)
    alpha = (phi_ddot - b[..., None] * pxdd + c[..., None] * np.cross(phi, pxdd)
             - (eb[..., None] * pd) * pxd + (ec[..., None] * pd) * ppxd + c[..., None] * np.cross(phi_dot, pxd))
    return w, alpha


def _derivative_coefficients(theta: np.ndarray):
    """(b′(θ)/θ, c′(θ)/θ) for b, c of :func:`_coefficients` (the θ̇θ = φ·φ̇ factor is the caller's)."""
    theta = np.asarray(theta, dtype=float)
    t2 = theta * theta
    eb = np.array(-1.0 / 12.0 + t2 / 180.0)
    ec = np.array(-1.0 / 60.0 + t2 / 1260.0)
    big = theta >= _SERIES
    if big.any():
        t = theta[big]
        eb[big] = (t * np.sin(t) - 2.0 * (1.0 - np.cos(t))) / t**4
        ec[big] = (t * (1.0 - np.cos(t)) - 3.0 * (t - np.sin(t))) / t**5
    return eb, ec


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
