"""SO(3) helpers, batched over a leading axis.

Conventions (DESIGN.md): rotations act on column vectors, perturbations are right-multiplicative
(``R · Exp(δθ)``), and ``Exp``/``Log`` map between rotation vectors and rotation matrices.
"""

from __future__ import annotations

import numpy as np

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
    """(sin θ/θ, (1 − cos θ)/θ²), by series below 1e-2 rad (exact to 1e-16)."""
    theta = np.asarray(theta, dtype=float)
    t2 = theta * theta
    a = np.array(1.0 - t2 / 6.0 + t2 * t2 / 120.0)  # 0-d arrays too: masked assignment below
    b = np.array(0.5 - t2 / 24.0 + t2 * t2 / 720.0)
    big = theta >= _SERIES
    if big.any():
        t = theta[big]
        a[big], b[big] = np.sin(t) / t, (1.0 - np.cos(t)) / t**2
    return a, b


def exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` from rotation vectors ``(..., 3)`` (Rodrigues:
    ``cos θ·I + sin θ/θ·[φ]× + (1 − cos θ)/θ²·φφᵀ``)."""
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)
    a, b = _coefficients(theta)
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


def to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` (x, y, z, w; w ≥ 0) of rotation matrices ``(..., 3, 3)``: from the
    largest of the trace and the diagonal (Markley 2008, as scipy's ``Rotation.from_matrix``), so
    every angle is accurate, and normalised (a matrix slightly off SO(3) gives its nearest rotation's)."""
    R = np.asarray(R, dtype=float)
    M = R.reshape(-1, 3, 3)
    d = np.stack([M[:, 0, 0], M[:, 1, 1], M[:, 2, 2], M[:, 0, 0] + M[:, 1, 1] + M[:, 2, 2]], axis=1)
    choice = np.argmax(d, axis=1)
    q = np.empty((M.shape[0], 4))
    tr = choice == 3
    q[tr, 0] = M[tr, 2, 1] - M[tr, 1, 2]
    q[tr, 1] = M[tr, 0, 2] - M[tr, 2, 0]
    q[tr, 2] = M[tr, 1, 0] - M[tr, 0, 1]
    q[tr, 3] = 1.0 + d[tr, 3]
    for i in range(3):
        sel = choice == i
        if not sel.any():
            continue
        j, k = (i + 1) % 3, (i + 2) % 3
        q[sel, i] = 1.0 - d[sel, 3] + 2.0 * M[sel, i, i]
        q[sel, j] = M[sel, j, i] + M[sel, i, j]
        q[sel, k] = M[sel, k, i] + M[sel, i, k]
        q[sel, 3] = M[sel, k, j] - M[sel, j, k]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1.0
    return q.reshape(R.shape[:-2] + (4,))


def log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` of rotation matrices ``(..., 3, 3)`` (angle in [0, π]), through
    their quaternion (:func:`to_quat`): ``θ = 2 atan2(|v|, w)``, ``φ = θ v/|v|``, by series below
    1e-3 rad."""
    q = to_quat(R)
    v, w = q[..., :3], q[..., 3]
    n = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(n, w)
    small = angle <= 1e-3
    a2 = angle * angle
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(small, 2.0 + a2 / 12.0 + 7.0 * a2 * a2 / 2880.0, angle / np.sin(0.5 * angle))
    return scale[..., None] * v


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
