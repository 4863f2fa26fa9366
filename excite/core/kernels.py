"""Compiled 3-vector and 3×3 helpers shared by every numba kernel of excite (inlined into the
callers: no allocation, no call overhead), and the inverse Cholesky factor of a stack of
covariances.

A 10-minute drive has 120 000 IMU samples at 200 Hz and 6 000 keyframes; evaluated with numpy,
every formula is a pass over arrays of that length, with the interpreter between passes. Fused
per sample or per factor, with 3-vectors and 3×3 matrices in scalars or small scratch arrays, the
kernels cost a few milliseconds and release the GIL, so that the chunks of a drive run in
parallel on threads. The kernels live with their math: :mod:`excite.motion.kernels` (sampling
the trajectory), each factor's module (:mod:`excite.factors`), :mod:`excite.information.kernels`
(the information matrix and its elimination).
"""

from __future__ import annotations

import numba as nb
import numpy as np

SERIES = 1e-2  # below this rotation angle, series expansions (exact to ~1e-16)


@nb.njit(cache=True, inline="always")
def cross_scalars(ux, uy, uz, vx, vy, vz):
    return uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx


@nb.njit(cache=True, nogil=True)
def inverse_cholesky(cov):
    """``W = L⁻¹`` with ``L Lᵀ = cov`` for every symmetric positive definite matrix of a stack
    (``WᵀW = cov⁻¹``: W whitens a residual of covariance cov)."""
    N, m, _ = cov.shape
    W = np.empty((N, m, m))  # zeroed per matrix, in cache
    L = np.empty((m, m))
    inv = np.empty(m)  # 1 / diag L
    for i in range(N):
        C = cov[i]
        for r in range(m):
            for c in range(r + 1):
                acc = C[r, c]
                for k in range(c):
                    acc -= L[r, k] * L[c, k]
                if r == c:
                    if acc <= 0.0:
                        raise ValueError("covariance is not positive definite")
                    L[r, r] = np.sqrt(acc)
                    inv[r] = 1.0 / L[r, r]
                else:
                    L[r, c] = acc * inv[c]
        Wi = W[i]
        Wi[:] = 0.0
        for c in range(m):  # forward substitution, column c of L⁻¹
            Wi[c, c] = inv[c]
            for r in range(c + 1, m):
                acc = 0.0
                for k in range(c, r):
                    acc -= L[r, k] * Wi[k, c]
                Wi[r, c] = acc * inv[r]
    return W


@nb.njit(cache=True, inline="always")
def mul(A, B, out):
    """out = A B"""
    for r in range(3):
        for c in range(3):
            out[r, c] = A[r, 0] * B[0, c] + A[r, 1] * B[1, c] + A[r, 2] * B[2, c]


@nb.njit(cache=True, inline="always")
def tmul(A, B, out):
    """out = Aᵀ B"""
    for r in range(3):
        for c in range(3):
            out[r, c] = A[0, r] * B[0, c] + A[1, r] * B[1, c] + A[2, r] * B[2, c]


@nb.njit(cache=True, inline="always")
def mulv(A, x, out):
    """out = A x"""
    for r in range(3):
        out[r] = A[r, 0] * x[0] + A[r, 1] * x[1] + A[r, 2] * x[2]


@nb.njit(cache=True, inline="always")
def tmulv(A, x, out):
    """out = Aᵀ x"""
    for r in range(3):
        out[r] = A[0, r] * x[0] + A[1, r] * x[1] + A[2, r] * x[2]


@nb.njit(cache=True, inline="always")
def hat(x, out):
    """out = [x]×"""
    out[0, 0] = 0.0
    out[0, 1] = -x[2]
    out[0, 2] = x[1]
    out[1, 0] = x[2]
    out[1, 1] = 0.0
    out[1, 2] = -x[0]
    out[2, 0] = -x[1]
    out[2, 1] = x[0]
    out[2, 2] = 0.0


@nb.njit(cache=True, inline="always")
def cross(x, y, out):
    """out = x × y"""
    out[0] = x[1] * y[2] - x[2] * y[1]
    out[1] = x[2] * y[0] - x[0] * y[2]
    out[2] = x[0] * y[1] - x[1] * y[0]


@nb.njit(cache=True, inline="always")
def put(J, r0, c0, A, scale):
    """J[r0:r0+3, c0:c0+3] = scale · A"""
    for r in range(3):
        for c in range(3):
            J[r0 + r, c0 + c] = scale * A[r, c]


@nb.njit(cache=True, inline="always")
def mult(A, B, out):
    """out = A Bᵀ"""
    for r in range(3):
        for c in range(3):
            out[r, c] = A[r, 0] * B[c, 0] + A[r, 1] * B[c, 1] + A[r, 2] * B[c, 2]


@nb.njit(cache=True, inline="always")
def log(R, out):
    """out = Log(R), the rotation vector of a rotation matrix (θ from atan2: accurate at every angle)."""
    vx = 0.5 * (R[2, 1] - R[1, 2])
    vy = 0.5 * (R[0, 2] - R[2, 0])
    vz = 0.5 * (R[1, 0] - R[0, 1])
    s = np.sqrt(vx * vx + vy * vy + vz * vz)  # sin θ
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)  # cos θ
    theta = np.arctan2(s, c)
    if c > -0.99:
        f = theta / s if s > 0.0 else 1.0  # θ = atan2(s, c) keeps θ/sin θ accurate down to 0
        out[0], out[1], out[2] = f * vx, f * vy, f * vz
        return
    # near π: (R + Rᵀ)/2 − cos θ I = (1 − cos θ) u uᵀ; the row of its largest diagonal entry ∝ u
    k = 0
    if R[1, 1] > R[k, k]:
        k = 1
    if R[2, 2] > R[k, k]:
        k = 2
    ux = 0.5 * (R[k, 0] + R[0, k]) - (c if k == 0 else 0.0)
    uy = 0.5 * (R[k, 1] + R[1, k]) - (c if k == 1 else 0.0)
    uz = 0.5 * (R[k, 2] + R[2, k]) - (c if k == 2 else 0.0)
    f = theta / np.sqrt(ux * ux + uy * uy + uz * uz)
    if ux * vx + uy * vy + uz * vz < 0.0:  # the sign of sin θ · u
        f = -f
    out[0], out[1], out[2] = f * ux, f * uy, f * uz


@nb.njit(cache=True, inline="always")
def right_jacobian_inv(phi, out):
    """out = J_r⁻¹(φ) = I + ½[φ]× + (1/θ² − (1 + cos θ)/(2θ sin θ)) [φ]×²  (J_l⁻¹(φ) = J_r⁻¹(−φ))."""
    t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    theta = np.sqrt(t2)
    coef = 1.0 / 12.0 + t2 / 720.0 if theta < SERIES else 1.0 / t2 - (1.0 + np.cos(theta)) / (2.0 * theta * np.sin(theta))
    hat(phi, out)  # ½[φ]× below; [φ]×² = φφᵀ − θ²I, so no scratch matrix is needed
    for r in range(3):
        for c in range(3):
            out[r, c] = (1.0 if r == c else 0.0) + 0.5 * out[r, c] + coef * (
                phi[r] * phi[c] - (t2 if r == c else 0.0))
