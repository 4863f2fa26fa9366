"""Compiled sampling of a trajectory's splines (numba): the segment of each time, orientations
from the rotation spline, and the IMU's body rate and specific force at the IMU rate
(:meth:`excite.motion.trajectory.Trajectory.rotation`, :meth:`~excite.motion.trajectory.Trajectory.imu`;
held to scipy's RotationSpline and Rotation by the tests)."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..core.kernels import SERIES, cross_scalars


@nb.njit(cache=True, inline="always")
def _coeffs(t2):
    """sin θ/θ, (1−cos θ)/θ², (θ−sin θ)/θ³ and (b′/θ, c′/θ) of the last two, from t2 = θ²: below
    the series threshold without the square root, with the series' constants as reciprocals
    (a multiplication, not a division, per term)."""
    if t2 < SERIES * SERIES:
        a = 1.0 - t2 * (1.0 / 6.0) + t2 * t2 * (1.0 / 120.0)
        b = 0.5 - t2 * (1.0 / 24.0) + t2 * t2 * (1.0 / 720.0)
        c = 1.0 / 6.0 - t2 * (1.0 / 120.0) + t2 * t2 * (1.0 / 5040.0)
        eb = -1.0 / 12.0 + t2 * (1.0 / 180.0)
        ec = -1.0 / 60.0 + t2 * (1.0 / 1260.0)
    else:
        theta = np.sqrt(t2)
        s, co = np.sin(theta), np.cos(theta)
        a = s / theta
        b = (1.0 - co) / t2
        c = (theta - s) / (t2 * theta)
        eb = (theta * s - 2.0 * (1.0 - co)) / (t2 * t2)
        ec = (theta * (1.0 - co) - 3.0 * (theta - s)) / (t2 * t2 * theta)
    return a, b, c, eb, ec


@nb.njit(cache=True, inline="always")
def _horner(c, k, tau):
    """The three components of PPoly segment k at tau, in one pass (three independent chains)."""
    x = y = z = 0.0
    for m in range(c.shape[0]):
        x = x * tau + c[m, k, 0]
        y = y * tau + c[m, k, 1]
        z = z * tau + c[m, k, 2]
    return x, y, z


@nb.njit(cache=True, inline="always")
def _horner2(c, k, tau):
    """Value, first and second derivative of the three components of PPoly segment k at tau, in
    one pass."""
    px, py, pz = c[0, k, 0], c[0, k, 1], c[0, k, 2]
    dx = dy = dz = 0.0
    ddx = ddy = ddz = 0.0  # half the second derivative
    for m in range(1, c.shape[0]):
        ddx = ddx * tau + dx
        ddy = ddy * tau + dy
        ddz = ddz * tau + dz
        dx = dx * tau + px
        dy = dy * tau + py
        dz = dz * tau + pz
        px = px * tau + c[m, k, 0]
        py = py * tau + c[m, k, 1]
        pz = pz * tau + c[m, k, 2]
    return px, py, pz, dx, dy, dz, 2.0 * ddx, 2.0 * ddy, 2.0 * ddz


@nb.njit(cache=True, nogil=True)
def segments(breaks, t):
    """Index of the piecewise-polynomial segment (between ``breaks``, increasing) that holds every
    time: ``clip(searchsorted(breaks, t, "right") − 1, 0, breaks.size − 2)``, walking along the
    breaks while the times increase (a binary search only where they do not)."""
    out = np.empty(t.size, dtype=np.int64)
    last = breaks.size - 2
    k = 0
    for i in range(t.size):
        if i == 0 or t[i] < t[i - 1]:
            k = min(max(np.searchsorted(breaks, t[i], side="right") - 1, 0), last)
        while k < last and breaks[k + 1] <= t[i]:
            k += 1
        out[i] = k
    return out


@nb.njit(cache=True, inline="always")
def _rotation_at(c_rot, k, tau, R_key, R):
    """Write ``R_key[k] · Exp(φ(τ))`` to R (φ: segment k of the cubic PPoly ``c_rot``) and return
    the body rate ``ω = J_r(φ) φ̇`` and angular acceleration ``α = J_r φ̈ + J̇_r φ̇``, in vector
    form (``[φ]× x = φ × x``)."""
    fx, fy, fz, dx, dy, dz, ddx, ddy, ddz = _horner2(c_rot, k, tau)
    t2 = fx * fx + fy * fy + fz * fz
    a, b, c, eb, ec = _coeffs(t2)
    cos = 1.0 - b * t2
    # Exp(φ) = cos θ I + a [φ]× + b φ φᵀ
    e00, e01, e02 = cos + b * fx * fx, b * fx * fy - a * fz, b * fx * fz + a * fy
    e10, e11, e12 = b * fy * fx + a * fz, cos + b * fy * fy, b * fy * fz - a * fx
    e20, e21, e22 = b * fz * fx - a * fy, b * fz * fy + a * fx, cos + b * fz * fz
    for r in range(3):
        k0, k1, k2 = R_key[k, r, 0], R_key[k, r, 1], R_key[k, r, 2]
        R[r, 0] = k0 * e00 + k1 * e10 + k2 * e20
        R[r, 1] = k0 * e01 + k1 * e11 + k2 * e21
        R[r, 2] = k0 * e02 + k1 * e12 + k2 * e22
    pdx, pdy, pdz = cross_scalars(fx, fy, fz, dx, dy, dz)
    ppx, ppy, ppz = cross_scalars(fx, fy, fz, pdx, pdy, pdz)
    wx, wy, wz = dx - b * pdx + c * ppx, dy - b * pdy + c * ppy, dz - b * pdz + c * ppz
    pd = fx * dx + fy * dy + fz * dz
    qx, qy, qz = cross_scalars(fx, fy, fz, ddx, ddy, ddz)
    qqx, qqy, qqz = cross_scalars(fx, fy, fz, qx, qy, qz)
    rx, ry, rz = cross_scalars(dx, dy, dz, pdx, pdy, pdz)
    alx = ddx - b * qx + c * qqx - eb * pd * pdx + ec * pd * ppx + c * rx
    aly = ddy - b * qy + c * qqy - eb * pd * pdy + ec * pd * ppy + c * ry
    alz = ddz - b * qz + c * qqz - eb * pd * pdz + ec * pd * ppz + c * rz
    return wx, wy, wz, alx, aly, alz


@nb.njit(cache=True, nogil=True)
def rotation_samples(t, seg_rot, x_rot, c_rot, R_key):
    """Orientation, body rate and angular acceleration of a rotation spline ``R_key[k] · Exp(φ(t))``
    (φ a cubic PPoly ``x_rot, c_rot``; ``seg_rot`` the segment of every time)."""
    n = t.size
    out_R = np.empty((n, 3, 3))
    out_w = np.empty((n, 3))
    out_a = np.empty((n, 3))
    for i in range(n):
        k = seg_rot[i]
        wx, wy, wz, alx, aly, alz = _rotation_at(c_rot, k, t[i] - x_rot[k], R_key, out_R[i])
        out_w[i, 0], out_w[i, 1], out_w[i, 2] = wx, wy, wz
        out_a[i, 0], out_a[i, 1], out_a[i, 2] = alx, aly, alz
    return out_R, out_w, out_a


@nb.njit(cache=True, nogil=True)
def imu_samples(t, seg_rot, x_rot, c_rot, R_key, seg_acc, x_acc, c_acc, gravity, R_V_B, p_V_B):
    """Orientation R_W_B, body rate ω_B and specific force f_B of an IMU at ``(R_V_B, p_V_B)`` in V.

    V's orientation, body rate and angular acceleration as in :func:`rotation_samples`; its
    acceleration a PPoly (``x_acc, c_acc``; ``seg_acc`` the segment of every time).
    """
    n = t.size
    out_R = np.empty((n, 3, 3))
    out_w = np.empty((n, 3))
    out_f = np.empty((n, 3))
    px, py, pz = p_V_B[0], p_V_B[1], p_V_B[2]
    R = np.empty((3, 3))
    for i in range(n):
        k = seg_rot[i]
        wx, wy, wz, alx, aly, alz = _rotation_at(c_rot, k, t[i] - x_rot[k], R_key, R)
        j = seg_acc[i]
        tj = t[i] - x_acc[j]
        ax, ay, az = _horner(c_acc, j, tj)
        ax -= gravity[0]
        ay -= gravity[1]
        az -= gravity[2]
        # specific force at the IMU point, in V: Rᵀ(a − g) + α × p + ω × (ω × p)
        l1x, l1y, l1z = cross_scalars(alx, aly, alz, px, py, pz)
        wpx, wpy, wpz = cross_scalars(wx, wy, wz, px, py, pz)
        l2x, l2y, l2z = cross_scalars(wx, wy, wz, wpx, wpy, wpz)
        fVx = R[0, 0] * ax + R[1, 0] * ay + R[2, 0] * az + l1x + l2x
        fVy = R[0, 1] * ax + R[1, 1] * ay + R[2, 1] * az + l1y + l2y
        fVz = R[0, 2] * ax + R[1, 2] * ay + R[2, 2] * az + l1z + l2z
        for r in range(3):
            for q in range(3):
                out_R[i, r, q] = R[r, 0] * R_V_B[0, q] + R[r, 1] * R_V_B[1, q] + R[r, 2] * R_V_B[2, q]
            out_w[i, r] = R_V_B[0, r] * wx + R_V_B[1, r] * wy + R_V_B[2, r] * wz
            out_f[i, r] = R_V_B[0, r] * fVx + R_V_B[1, r] * fVy + R_V_B[2, r] * fVz
    return out_R, out_w, out_f
