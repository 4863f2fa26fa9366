"""Timed poses to a trajectory of V: the smoothing-spline fit every pose reader shares (files,
bags, live streams), and the checks a sequence of timed poses must pass first.

Times and positions are re-based on the first sample before any math (UTM coordinates and epoch
times lose no precision). Positions and (sign-unwrapped) unit quaternions are fitted with cubic
smoothing splines (Reinsch), whose penalty makes them a low-pass of bandwidth ``cutoff_hz``
(-3 dB frequency; capped at a quarter of the poses' rate); the fit is resampled on a uniform
grid and the velocity is the position spline's derivative, not a finite difference of noisy
poses. A gap between poses longer than :data:`MAX_GAP_PERIODS` periods of the cutoff is refused:
the spline would invent the motion there.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.linalg import solveh_banded
from scipy.spatial.transform import Rotation

from ..core import bounds
from ..errors import RouteError
from ..motion.trajectory import Trajectory

QUAT_NORM_TOL = 1e-3
ROTATION_TOL = 1e-3
MIN_POSES = 6
DEFAULT_CUTOFF_HZ = 1.0  # vehicle motion lives below ~1 Hz; logged poses jitter above

# KITTI camera (x right, y down, z forward) → vehicle (x forward, y left, z up): columns are V's
# axes expressed in camera coordinates.
R_CAM_VEH = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


MAX_GAP_PERIODS = 5.0  # the widest gap between poses, in periods of the smoothing's cutoff (5 s at 1 Hz)


def check_range(values: np.ndarray, kind: str, what: str, source: str | None,
                 lines: list[int] | None) -> None:
    """Every value within the sane range ``bounds.ROUTE[kind]``, else the first one outside."""
    sane = bounds.ROUTE[kind]
    bad = ~((values >= sane.lo) & (values <= sane.hi))
    if bad.any():
        k = int(np.argwhere(bad)[0][0])
        raise RouteError(f"{what} {np.asarray(values)[bad][0]:.6g} is outside the sane range {sane}",
                         source=source, line=None if lines is None else lines[k])


def cutoff_for(cutoff_hz: float, h: float) -> float:
    """The smoothing's bandwidth for poses ``h`` seconds apart: ``cutoff_hz``, at most a quarter
    of their rate."""
    return min(cutoff_hz, 0.25 / h)


def check_timed(t: np.ndarray, p: np.ndarray, rate_hz: float | None, source: str | None = None,
                 lines: list[int] | None = None, cutoff_hz: float = DEFAULT_CUTOFF_HZ) -> None:
    """Timed poses a drive can be made of: times and positions in range, a resampling grid
    within the work bounds (checked before the grid is allocated), and no gap the smoothing
    would fill with motion of its own (``MAX_GAP_PERIODS`` periods of its cutoff)."""
    if not cutoff_hz > 0:  # ∞: the widest band the poses' rate allows (poses already smooth)
        raise RouteError(f"the smoothing cutoff must be positive, got {cutoff_hz!r}", source=source)
    check_range(t, "t_s", "time", source, lines)
    check_range(p, "position_m", "position", source, lines)
    if len(t) < 2:
        return
    rate = 1.0 / float(np.median(np.diff(t))) if rate_hz is None else rate_hz
    if not (math.isfinite(rate) and rate > 0):
        raise RouteError(f"the resampling rate must be positive and finite, got {rate!r}", source=source)
    too_much = bounds.work_problem(float(t[-1] - t[0]), rate, bounds.MAX_SAMPLES, "samples")
    if too_much:
        raise RouteError(too_much, source=source)
    dt = np.diff(t)
    widest = int(np.argmax(dt))
    longest = MAX_GAP_PERIODS / cutoff_for(cutoff_hz, float(np.median(dt)))
    if dt[widest] > longest:
        raise RouteError(f"a gap of {dt[widest]:.3g} s before the pose at t = {t[widest + 1]:.3f} s: the "
                         f"smoothing would invent the motion over more than "
                         f"{longest:g} s; split the log at the gap (each part a drive of its own) or crop it",
                         source=source, line=None if lines is None else lines[widest + 1])


def trajectory_from_poses(t_s: np.ndarray, p_m: np.ndarray, R: np.ndarray, *,
                          cutoff_hz: float = DEFAULT_CUTOFF_HZ, rate_hz: float | None = None,
                          name: str = "route") -> Trajectory:
    """A smooth trajectory of V through noisy timed poses ``(t_s, p_m, R)``.

    Times and positions are re-based on the first sample before any math (the first position is
    kept as the trajectory's ``origin``: a scene in the poses' frame is seen from there). Positions and
    (sign-unwrapped) quaternions are fitted with cubic smoothing splines whose penalty makes them
    a low-pass of bandwidth ``cutoff_hz`` (``λ = 1 / (h (2π f_c)⁴)`` for sample spacing ``h``); the
    fit is resampled on a uniform grid at ``rate_hz`` (default: the median input rate) and the
    velocity is the derivative of the position spline.
    """
    check_timed(np.asarray(t_s, dtype=float), np.asarray(p_m, dtype=float), rate_hz, cutoff_hz=cutoff_hz)
    t = np.asarray(t_s, dtype=float) - float(t_s[0])
    p = np.asarray(p_m, dtype=float) - np.asarray(p_m, dtype=float)[0]
    q = Rotation.from_matrix(R).as_quat()  # x, y, z, w
    flips = np.concatenate([[1.0], np.sign(np.sum(q[1:] * q[:-1], axis=1))])
    flips[flips == 0] = 1.0
    q *= np.cumprod(flips)[:, None]
    h = float(np.median(np.diff(t)))
    f_c = cutoff_for(cutoff_hz, h)
    lam = 1.0 / (h * (2.0 * np.pi * f_c) ** 4)
    pos = smoothing_spline(t, p, lam)
    quat = smoothing_spline(t, q, lam)
    rate = 1.0 / h if rate_hz is None else rate_hz
    grid = np.linspace(0.0, t[-1], max(int(round(t[-1] * rate)) + 1, MIN_POSES))
    qg = quat(grid)
    qg /= np.linalg.norm(qg, axis=1, keepdims=True)
    out = Trajectory(grid, Rotation.from_quat(qg).as_matrix(), pos(grid),
                     velocity=pos.derivative(1)(grid), name=name)
    out.origin = np.asarray(p_m, dtype=float)[0].copy()  # where the re-based positions start
    return out


def smoothing_spline(x: np.ndarray, y: np.ndarray, lam: float) -> CubicSpline:
    """The cubic smoothing spline: of all twice-differentiable ``g``, the minimiser of
    ``Σ |y_i − g(x_i)|² + λ ∫ |g''|²`` (the function of ``scipy.interpolate.make_smoothing_spline``).

    Reinsch's algorithm: with ``Q`` the second-difference operator and ``R`` the tridiagonal
    Gram matrix of the hat functions, ``(R + λ QᵀQ) γ = Qᵀ y`` for the second derivatives γ at
    the interior knots, and ``g(x_i) = y_i − λ Q γ``; ``g`` is then the natural cubic spline
    through those values. One banded (pentadiagonal) solve, no per-point Python loop.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    n = x.size
    h = np.diff(x)
    inv = 1.0 / h
    # Q (n × n-2): column j holds 1/h_j, −1/h_j − 1/h_{j+1}, 1/h_{j+1} at rows j, j+1, j+2
    q0, q1, q2 = inv[:-1], -inv[:-1] - inv[1:], inv[1:]
    m = n - 2
    ab = np.zeros((3, m))  # upper form of the symmetric pentadiagonal R + λ QᵀQ
    ab[2] = (h[:-1] + h[1:]) / 3.0 + lam * (q0**2 + q1**2 + q2**2)
    ab[1, 1:] = h[1:-1] / 6.0 + lam * (q1[:-1] * q0[1:] + q2[:-1] * q1[1:])
    ab[0, 2:] = lam * q2[:-2] * q0[2:]
    Y = y.reshape(n, -1)
    rhs = q0[:, None] * Y[:-2] + q1[:, None] * Y[1:-1] + q2[:, None] * Y[2:]
    gamma = solveh_banded(ab, rhs)
    Qg = np.zeros_like(Y)
    Qg[:-2] += q0[:, None] * gamma
    Qg[1:-1] += q1[:, None] * gamma
    Qg[2:] += q2[:, None] * gamma
    fit = (Y - lam * Qg).reshape(y.shape)
    return CubicSpline(x, fit, bc_type="natural")
