"""The optimizer's control parametrisation and the vehicle kinematics it implies, in CasADi.

Decision variables (scaled to order one): the speed at knots every ``knot_step_s`` (zero at both
ends: the maneuver runs from rest to rest), the curvature at every knot, and the start pose
``(x0, y0, ψ0)``. Speed and curvature are C2 cubic splines through the knots (speed clamped with
zero acceleration at both ends, curvature natural), so that the acceleration, jerk, curvature and
curvature rate at any time are *linear* maps of the knots (:class:`Grid` holds them as matrices).
Heading and position are integrated on the sample grid with the end-corrected trapezoid rule
(Euler–Maclaurin: the derivatives of the integrands are known in closed form), fourth order.

On the sample grid (the optimizer's IMU rate) :func:`body_samples` gives what the information
model needs, exactly as :meth:`excite.motion.trajectory.MotionSamples.body` defines it for a drive of
:func:`excite.motion.vehicle.drive` on flat ground: the body pose, velocity, angular rate, specific force
and the suspension tilt (pitch ``−k_p·a``, roll ``k_r·u²κ``), with the angular acceleration of
the tilting body in the lever-arm terms.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.interpolate import CubicSpline

from ..motion.trajectory import GRAVITY
from ..motion.vehicle import ControlProfile, Limits, Suspension
from .terrain import Terrain


@dataclass(frozen=True)
class Grid:
    """Knots, samples and the linear maps from knot values to spline values and derivatives.

    Samples: ``n_keyframes`` keyframes at ``keyframe_rate_hz`` with ``imu_substeps`` IMU samples
    per keyframe interval. ``U[d]`` (n_samples × (M−1)) maps the interior speed knots to the d-th
    derivative of speed at the samples, ``C[d]`` (n_samples × (M+1)) the curvature knots.
    """

    duration_s: float
    knot_step_s: float
    keyframe_rate_hz: float
    imu_substeps: int
    t_knots: np.ndarray
    t: np.ndarray
    U: tuple[np.ndarray, ...]
    C: tuple[np.ndarray, ...]

    @classmethod
    def make(cls, duration_s: float, knot_step_s: float = 1.5, keyframe_rate_hz: float = 2.0,
             imu_substeps: int = 4) -> "Grid":
        M = max(int(round(duration_s / knot_step_s)), 3)
        t_knots = np.linspace(0.0, duration_s, M + 1)
        n_int = int(np.floor(duration_s * keyframe_rate_hz + 1e-9))
        t = np.arange(n_int * imu_substeps + 1) / (keyframe_rate_hz * imu_substeps)
        U = _basis(t_knots, t, ((1, 0.0), (1, 0.0)))
        U = tuple(B[:, 1:-1] for B in U)  # speed is zero at both ends
        C = _basis(t_knots, t, "natural")
        return cls(float(duration_s), float(t_knots[1] - t_knots[0]), float(keyframe_rate_hz),
                   int(imu_substeps), t_knots, t, U, C)

    @property
    def n_knots(self) -> int:
        return self.t_knots.size

    @property
    def n_samples(self) -> int:
        return self.t.size

    @property
    def n_keyframes(self) -> int:
        return (self.t.size - 1) // self.imu_substeps + 1

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])


def _basis(t_knots: np.ndarray, t: np.ndarray, bc) -> tuple[np.ndarray, ...]:
    """Derivatives 0..3 at ``t`` of the cubic splines through each unit vector of knot values."""
    n = t_knots.size
    if not isinstance(bc, str):
        bc = tuple((order, np.zeros(n)) for order, _ in bc)
    sp = CubicSpline(t_knots, np.eye(n), bc_type=bc)
    # the third derivative jumps at knots: take the right-hand value (left at the end)
    out = [sp(t, d) for d in range(3)]
    t3 = np.minimum(t + 1e-9, t_knots[-1] - 1e-9)
    out.append(sp(t3, 3))
    return tuple(np.asarray(o) for o in out)


@dataclass(frozen=True)
class Scales:
    """Scales of the decision variables: speed, curvature, position, heading."""

    speed_mps: float
    curvature_1pm: float
    position_m: float

    @classmethod
    def of(cls, limits: Limits, lot_half_m: float) -> "Scales":
        return cls(limits.speed_max_mps, limits.curvature_max_1pm, lot_half_m)


@dataclass(frozen=True)
class Layout:
    """Where each part of the decision vector z sits."""

    n_speed: int
    n_curv: int

    @property
    def speed(self) -> slice:
        return slice(0, self.n_speed)

    @property
    def curv(self) -> slice:
        return slice(self.n_speed, self.n_speed + self.n_curv)

    @property
    def pose(self) -> slice:
        return slice(self.n_speed + self.n_curv, self.n_speed + self.n_curv + 3)

    @property
    def size(self) -> int:
        return self.n_speed + self.n_curv + 3


def layout(grid: Grid) -> Layout:
    return Layout(grid.n_knots - 2, grid.n_knots)


def controls(grid: Grid, sc: Scales, z):
    """Speed (and derivatives 1..3) and curvature (and derivatives 1..3) at the samples, each an
    (n_samples, 1) expression linear in ``z``; plus the start pose."""
    lay = layout(grid)
    zu = z[lay.speed] * sc.speed_mps
    zk = z[lay.curv] * sc.curvature_1pm
    u = [ca.mtimes(ca.DM(B), zu) for B in grid.U]
    k = [ca.mtimes(ca.DM(B), zk) for B in grid.C]
    pose = z[lay.pose]
    x0, y0, psi0 = pose[0] * sc.position_m, pose[1] * sc.position_m, pose[2]
    return u, k, (x0, y0, psi0)


def _cumtrap_corrected(f, df, h: float):
    """∫₀^{t_i} f for every sample: trapezoid rule with the Euler–Maclaurin end correction."""
    trap = ca.vertcat(0, ca.cumsum(0.5 * h * (f[:-1] + f[1:])))
    return trap - h * h / 12.0 * (df - df[0])


def path(grid: Grid, sc: Scales, z):
    """(u, a, j, j', κ, κ', κ'', ψ, x, y) at the samples, each (n_samples, 1)."""
    (u, a, j, jd), (k, kd, kdd, _), (x0, y0, psi0) = controls(grid, sc, z)
    h = grid.dt
    g = u * k
    dg = a * k + u * kd
    psi = psi0 + _cumtrap_corrected(g, dg, h)
    c, s = ca.cos(psi), ca.sin(psi)
    x = x0 + _cumtrap_corrected(u * c, a * c - u * s * g, h)
    y = y0 + _cumtrap_corrected(u * s, a * s + u * c * g, h)
    return u, a, j, jd, k, kd, kdd, psi, x, y


def _rot_x(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))


def _rot_y(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(c, 0, s), ca.horzcat(0, 1, 0), ca.horzcat(-s, 0, c))


def _rot_z(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


def _vee(W):
    return ca.vertcat(W[2, 1], W[0, 2], W[1, 0])


def body_function(suspension: Suspension, R_V_B: np.ndarray, p_V_B: np.ndarray, terrain: Terrain) -> ca.Function:
    """SX function of one sample's (u, a, j, j', κ, κ', κ'', ψ, x, y, z) → body motion.

    The road frame A is ``Rz(ψ) Ry(−grade) Rx(bank)`` with the terrain's grade and bank at
    (x, y, ψ) (:mod:`.terrain`; zero on a flat lot), the body V is tilted in it by the suspension
    (pitch ``−k_p·a``, roll ``k_r·u²κ``), exactly as :func:`excite.motion.vehicle.drive`. The angular
    rate and acceleration of V are exact time derivatives of that rotation (CasADi ``jtimes``
    along the known rates of every angle).

    Outputs ``R_W_B`` (3×3), ``p`` (3), ``v`` (3), ``ω_B`` (3), ``f_B`` (3), ``R_V_A`` (3×3).
    """
    q = ca.SX.sym("q", 11)
    u, a, j, jd, k, kd, kdd, psi, x, y, zz = (q[i] for i in range(11))
    kp = np.deg2rad(suspension.pitch_deg_per_mps2)
    kr = np.deg2rad(suspension.roll_deg_per_mps2)
    # positions and heading with their first and second time derivatives
    ps1, ps2 = u * k, a * k + u * kd
    c, s = ca.cos(psi), ca.sin(psi)
    pos, pos1 = ca.vertcat(x, y, psi), ca.vertcat(u * c, u * s, ps1)
    pos2 = ca.vertcat(a * c - u * s * ps1, a * s + u * c * ps1, ps2)
    gb = ca.vertcat(*terrain.grade_bank(x, y, psi))
    gb1 = ca.jtimes(gb, pos, pos1)
    gb2 = ca.jtimes(gb1, pos, pos1) + ca.jtimes(gb, pos, pos2)
    # every angle of R_W_V = Rz(ψ) Ry(−G) Rx(B) Ry(θ) Rx(φ), with its rates
    th, th1, th2 = -kp * a, -kp * j, -kp * jd
    ph = kr * u * u * k
    ph1 = kr * (2 * u * a * k + u * u * kd)
    ph2 = kr * (2 * a * a * k + 2 * u * j * k + 4 * u * a * kd + u * u * kdd)
    ang = ca.vertcat(psi, gb, th, ph)
    ang1 = ca.vertcat(ps1, gb1, th1, ph1)
    ang2 = ca.vertcat(ps2, gb2, th2, ph2)
    A = ca.SX.sym("A", 5)
    A1 = ca.SX.sym("A1", 5)
    R_W_A_s = ca.mtimes([_rot_z(A[0]), _rot_y(-A[1]), _rot_x(A[2])])
    R_A_V_s = ca.mtimes(_rot_y(A[3]), _rot_x(A[4]))
    R_W_V_s = ca.mtimes(R_W_A_s, R_A_V_s)
    w_s = _vee(ca.mtimes(R_W_V_s.T, ca.jtimes(R_W_V_s, A, A1)))  # body rate of V, in V
    wA_s = _vee(ca.mtimes(R_W_A_s.T, ca.jtimes(R_W_A_s, A, A1)))  # rate of A, in A
    rates = ca.Function("rates", [A, A1], [w_s, wA_s])
    A2s = ca.SX.sym("A2", 5)
    acc_f = ca.Function("acc", [A, A1, A2s], [ca.jtimes(w_s, ca.vertcat(A, A1), ca.vertcat(A1, A2s))])
    w, wA = rates(ang, ang1)
    al = acc_f(ang, ang1, ang2)
    R_W_A = ca.mtimes([_rot_z(psi), _rot_y(-gb[0]), _rot_x(gb[1])])
    R_A_V = ca.mtimes(_rot_y(th), _rot_x(ph))
    R_W_V = ca.mtimes(R_W_A, R_A_V)
    ex = ca.DM([1, 0, 0])
    fwd = ca.mtimes(R_W_A, ex)
    v_W = fwd * u
    a_W = fwd * a + ca.mtimes(R_W_A, ca.cross(wA, ex)) * u
    p_W = ca.vertcat(x, y, zz)
    pB = ca.DM(p_V_B)
    RVB = ca.DM(R_V_B)
    lever_v = ca.cross(w, pB)
    lever_a = ca.cross(al, pB) + ca.cross(w, lever_v)
    R_W_B = ca.mtimes(R_W_V, RVB)
    p = p_W + ca.mtimes(R_W_V, pB)
    v = v_W + ca.mtimes(R_W_V, lever_v)
    acc = a_W + ca.mtimes(R_W_V, lever_a)
    w_B = ca.mtimes(RVB.T, w)
    f_B = ca.mtimes(R_W_B.T, acc - ca.DM(GRAVITY))
    return ca.Function("body", [q], [ca.vec(R_W_B), p, v, w_B, f_B, ca.vec(R_A_V.T)],
                       ["q"], ["R", "p", "v", "w", "f", "R_V_A"])


def terrain_path(grid: Grid, sc: Scales, z, terrain: Terrain):
    """:func:`path` on the terrain: the horizontal speed is u·cos(grade) (grade taken on the
    flat path, a second-order error), and the height z = ∫ u sin(grade) dt. Returns
    (u, a, j, j', κ, κ', κ'', ψ, x, y, z)."""
    u, a, j, jd, k, kd, kdd, psi, x, y = path(grid, sc, z)
    if not terrain:
        return u, a, j, jd, k, kd, kdd, psi, x, y, ca.MX.zeros(x.shape)
    h = grid.dt
    g, _ = terrain.grade_bank(x, y, psi)

    def cum(f):
        return ca.vertcat(0, ca.cumsum(0.5 * h * (f[:-1] + f[1:])))

    c, s = ca.cos(psi), ca.sin(psi)
    x = x - cum(u * (1 - ca.cos(g)) * c)
    y = y - cum(u * (1 - ca.cos(g)) * s)
    g, _ = terrain.grade_bank(x, y, psi)
    return u, a, j, jd, k, kd, kdd, psi, x, y, cum(u * ca.sin(g))


def body_samples(grid: Grid, sc: Scales, z, suspension: Suspension, R_V_B, p_V_B, terrain: Terrain = Terrain()):
    """Body motion at every sample as (9×N, 3×N, 3×N, 3×N, 3×N, 9×N) expressions of ``z``;
    matrices column-major (``ca.vec``)."""
    cols = terrain_path(grid, sc, z, terrain)
    Q = ca.horzcat(*cols).T  # 11 × N
    F = body_function(suspension, R_V_B, p_V_B, terrain).map(grid.n_samples)
    return F(Q)


def profile_from_z(grid: Grid, sc: Scales, z: np.ndarray, rate_hz: float = 20.0,
                   name: str = "optimized", terrain: Terrain = Terrain()) -> ControlProfile:
    """The control profile of ``z``: speed and curvature splines sampled at ``rate_hz`` knots
    (:func:`~excite.motion.vehicle.drive` interpolates them shape-preservingly), with the terrain's
    grade and bank under the path (as :func:`terrain_path` integrates it)."""
    lay = layout(grid)
    z = np.asarray(z, dtype=float).ravel()
    uk = np.concatenate([[0.0], z[lay.speed] * sc.speed_mps, [0.0]])
    kk = z[lay.curv] * sc.curvature_1pm
    t = np.linspace(0.0, grid.duration_s, int(round(grid.duration_s * rate_hz)) + 1)
    u = np.maximum(CubicSpline(grid.t_knots, uk, bc_type=((1, 0.0), (1, 0.0)))(t), 0.0)
    k = CubicSpline(grid.t_knots, kk, bc_type="natural")(t)
    x0, y0, psi0 = z[lay.pose] * np.array([sc.position_m, sc.position_m, 1.0])
    g = b = None
    if terrain:
        psi = psi0 + cumulative_trapezoid(u * k, t, initial=0.0)
        horiz = np.ones_like(t)
        for _ in range(2):
            x = x0 + cumulative_trapezoid(u * horiz * np.cos(psi), t, initial=0.0)
            y = y0 + cumulative_trapezoid(u * horiz * np.sin(psi), t, initial=0.0)
            g, b = terrain.grade_bank_np(np.column_stack([x, y]), psi)
            horiz = np.cos(g)
    return ControlProfile(t_s=t, speed_mps=u, curvature_1pm=k, grade_rad=g, bank_rad=b,
                          start=(float(x0), float(y0), float(psi0)), name=name)


def z_from_profile(grid: Grid, sc: Scales, profile: ControlProfile) -> np.ndarray:
    """The decision vector that best reproduces a control profile (knot values sampled from it;
    the profile is shifted to start at t = 0 and clipped to the grid's duration)."""
    lay = layout(grid)
    tk = profile.t_s[0] + np.minimum(grid.t_knots, profile.duration_s)
    c = profile.at(tk)
    z = np.zeros(lay.size)
    z[lay.speed] = c["speed_mps"][1:-1] / sc.speed_mps
    z[lay.curv] = c["curvature_1pm"] / sc.curvature_1pm
    x0, y0, psi0 = profile.start
    z[lay.pose] = [x0 / sc.position_m, y0 / sc.position_m, psi0]
    return z
