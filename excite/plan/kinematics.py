"""The optimizer's control parametrisation and the vehicle kinematics it implies, in CasADi.

Decision variables (scaled to order one): the B-spline coefficients of the speed and the
curvature, and the start pose ``(x0, y0, ψ0)``. Both are cubic B-splines (C2) on uniform knots
every ``knot_step_s`` with clamped ends; the speed's first two and last two coefficients are zero
(the maneuver runs from rest to rest with zero acceleration at both ends). The speed, the
curvature and every derivative of them at any time are *linear* maps of the coefficients with at
most four nonzeros per row (:class:`Grid` holds them as sparse matrices), and the B-spline's
convex-hull property bounds a derivative everywhere by the coefficients of its own spline
(:meth:`Grid.hull`): the optimizer bounds a handful of coefficients instead of every sample.
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
from scipy.interpolate import BSpline
from scipy import sparse

from ..motion.trajectory import GRAVITY
from ..motion.vehicle import ControlProfile, Limits, Suspension
from .terrain import Terrain

DEGREE = 3


@dataclass(frozen=True)
class Grid:
    """Knots, samples and the linear maps from B-spline coefficients to values and derivatives.

    Samples: ``n_keyframes`` keyframes at ``keyframe_rate_hz`` with ``imu_substeps`` IMU samples
    per keyframe interval. ``U[d]`` (n_samples × n_speed) maps the free speed coefficients to the
    d-th derivative of speed at the samples, ``C[d]`` (n_samples × n_curv) the curvature
    coefficients (scipy sparse, CSR). The third derivative jumps at knots: the right-hand value
    is taken (the left one at the end).
    """

    duration_s: float
    knot_step_s: float
    keyframe_rate_hz: float
    imu_substeps: int
    t_knots: np.ndarray
    t: np.ndarray
    knots: np.ndarray  # the B-spline knot vector (clamped: the ends repeated DEGREE + 1 times)
    U: tuple[sparse.csr_matrix, ...]
    C: tuple[sparse.csr_matrix, ...]
    segments: np.ndarray  # first sample of every shooting segment (the first is 0)

    @classmethod
    def make(cls, duration_s: float, knot_step_s: float = 1.5, keyframe_rate_hz: float = 2.0,
             imu_substeps: int = 4, shooting_s: float | None = None) -> "Grid":
        M = max(int(round(duration_s / knot_step_s)), 3)
        t_knots = np.linspace(0.0, duration_s, M + 1)
        n_int = int(np.floor(duration_s * keyframe_rate_hz + 1e-9))
        t = np.arange(n_int * imu_substeps + 1) / (keyframe_rate_hz * imu_substeps)
        knots = np.r_[[0.0] * DEGREE, t_knots, [float(duration_s)] * DEGREE]
        C = _basis(knots, t)
        U = tuple(B @ _speed_embedding(knots.size - DEGREE - 1) for B in C)
        n_seg = 1 if not shooting_s else max(int(round(t[-1] / shooting_s)), 1)
        segments = np.unique(np.round(np.linspace(0, t.size - 1, n_seg + 1)[:-1]).astype(int))
        return cls(float(duration_s), float(t_knots[1] - t_knots[0]), float(keyframe_rate_hz),
                   int(imu_substeps), t_knots, t, knots, tuple(sparse.csr_matrix(B) for B in U), C, segments)

    @property
    def n_knots(self) -> int:
        return self.t_knots.size

    @property
    def n_segments(self) -> int:
        """Shooting segments: the path's heading and position restart at each segment's first
        sample from decision variables, held equal to the previous segment's end (multiple
        shooting: a late position no longer depends on every earlier control)."""
        return self.segments.size

    @property
    def n_coefficients(self) -> int:
        """B-spline coefficients of one control (the curvature's are all free)."""
        return self.knots.size - DEGREE - 1

    @property
    def n_samples(self) -> int:
        return self.t.size

    @property
    def greville(self) -> np.ndarray:
        """Where each coefficient sits in time (the Greville abscissae): a B-spline whose
        coefficients are samples of a smooth function there approximates it to second order."""
        t = self.knots
        return np.array([t[i + 1:i + DEGREE + 1].mean() for i in range(self.n_coefficients)])

    @property
    def n_keyframes(self) -> int:
        return (self.t.size - 1) // self.imu_substeps + 1

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    def spline(self, coefficients: np.ndarray) -> BSpline:
        """The B-spline with these (all) coefficients."""
        return BSpline(self.knots, np.asarray(coefficients, dtype=float), DEGREE, extrapolate=False)

    def hull(self, derivative: int, refine: int = 2) -> np.ndarray:
        """The coefficients of the ``derivative``-th derivative spline of a control, as a matrix
        of its (all) coefficients, after inserting ``refine − 1`` knots in every knot interval.

        Every value of the derivative lies within the range of these coefficients (the
        B-spline convex-hull property); the refinement tightens that bound towards the curve's
        own extremes. A piecewise-linear derivative (the second, for cubic controls) needs no
        refinement: its coefficients are its values at the knots, the bound is exact.
        """
        n = self.n_coefficients
        k = DEGREE - derivative
        D = np.eye(n)
        t = self.knots
        for d in range(derivative):  # the derivative of a B-spline is a B-spline of one degree less
            p = DEGREE - d
            dt = t[p + 1:p + 1 + D.shape[0] - 1] - t[1:D.shape[0]]
            D = p * (D[1:] - D[:-1]) / dt[:, None]
            t = t[1:-1]
        if k <= 1 or refine <= 1:
            return D
        inner = np.unique(t[k:-k])
        extra = np.concatenate([np.linspace(a, b, refine + 1)[1:-1] for a, b in zip(inner[:-1], inner[1:])])
        t2 = np.sort(np.r_[t, extra])
        n2 = t2.size - k - 1
        # the refined spline represents the same function: its coefficients follow from
        # collocation at the refined Greville abscissae (Schoenberg–Whitney holds there)
        g = np.array([t2[i + 1:i + k + 1].mean() for i in range(n2)])
        B2 = BSpline.design_matrix(g, t2, k).toarray()
        B1 = BSpline.design_matrix(g, t, k).toarray()
        T = np.linalg.solve(B2, B1)
        T[np.abs(T) < 1e-12] = 0.0
        return T @ D


def _speed_embedding(n: int) -> np.ndarray:
    """The speed's coefficients from its free ones: the first and last two are zero (rest with
    zero acceleration at both ends)."""
    E = np.zeros((n, n - 4))
    E[2:n - 2] = np.eye(n - 4)
    return E


def _basis(knots: np.ndarray, t: np.ndarray) -> tuple[sparse.csr_matrix, ...]:
    """Derivatives 0..3 at ``t`` of every cubic B-spline basis function (sparse, CSR)."""
    n = knots.size - DEGREE - 1
    sp = BSpline(knots, np.eye(n), DEGREE)
    end = knots[-1]
    out = []
    for d in range(DEGREE + 1):
        # the third derivative jumps at knots: take the right-hand value (left at the end)
        td = np.minimum(t + 1e-9, end - 1e-9) if d == DEGREE else t
        B = np.asarray(sp(td, d))
        B[np.abs(B) < 1e-13] = 0.0
        out.append(sparse.csr_matrix(B))
    return tuple(out)


def sparse_dm(A) -> ca.DM:
    """A scipy sparse (or dense) matrix as a sparse CasADi DM."""
    A = sparse.csc_matrix(A)
    A.eliminate_zeros()
    sp = ca.Sparsity(A.shape[0], A.shape[1], A.indptr.tolist(), A.indices.tolist())
    return ca.DM(sp, A.data.tolist())


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
    n_shoot: int = 0  # shooting nodes after the start (each x, y, ψ)

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
    def shoot(self) -> slice:
        """The shooting nodes' (x, y, ψ), node after node (x and y scaled like the start's)."""
        a = self.n_speed + self.n_curv + 3
        return slice(a, a + 3 * self.n_shoot)

    @property
    def size(self) -> int:
        return self.n_speed + self.n_curv + 3 + 3 * self.n_shoot


def layout(grid: Grid) -> Layout:
    return Layout(grid.n_coefficients - 4, grid.n_coefficients, grid.n_segments - 1)


def speed_coefficients(grid: Grid, sc: Scales, z):
    """All the speed's B-spline coefficients [m/s] of ``z`` (numpy)."""
    return _speed_embedding(grid.n_coefficients) @ (np.asarray(z, dtype=float)[layout(grid).speed] * sc.speed_mps)


def controls(grid: Grid, sc: Scales, z):
    """Speed (and derivatives 1..3) and curvature (and derivatives 1..3) at the samples, each an
    (n_samples, 1) expression linear in ``z``; plus the start pose."""
    lay = layout(grid)
    zu = z[lay.speed] * sc.speed_mps
    zk = z[lay.curv] * sc.curvature_1pm
    u = [ca.mtimes(sparse_dm(B), zu) for B in grid.U]
    k = [ca.mtimes(sparse_dm(B), zk) for B in grid.C]
    pose = z[lay.pose]
    x0, y0, psi0 = pose[0] * sc.position_m, pose[1] * sc.position_m, pose[2]
    return u, k, (x0, y0, psi0)


def _segment_integral(grid: Grid, f, df, h: float):
    """``∫ f`` from the start of each sample's shooting segment to the sample (trapezoid rule
    with the Euler–Maclaurin end correction, fourth order), and over every segment to the first
    sample of the next: ``(per sample (n, 1), per segment but the last (S − 1, 1))``. Each
    segment's sums are its own, so that a sample depends on its segment's controls only."""
    bounds = list(grid.segments) + [grid.n_samples - 1]
    within, ends = [], []
    for k in range(len(bounds) - 1):
        a, b = bounds[k], bounds[k + 1]  # the segment's samples a..b (b: the next one's first)
        fk = f[a:b + 1]
        trap = ca.vertcat(0, ca.cumsum(0.5 * h * (fk[:-1] + fk[1:])))
        seg = trap - h * h / 12.0 * (df[a:b + 1] - df[a])
        last = k == len(bounds) - 2
        within.append(seg if last else seg[:-1])
        if not last:
            ends.append(seg[-1])
    return ca.vertcat(*within), (ca.vertcat(*ends) if ends else None)


def _member(grid: Grid) -> ca.DM:
    """(n_samples × segments): which segment each sample belongs to."""
    n = grid.n_samples
    member = np.searchsorted(grid.segments, np.arange(n), side="right") - 1
    return sparse_dm(sparse.csr_matrix((np.ones(n), (np.arange(n), member)), shape=(n, grid.n_segments)))


def nodes(grid: Grid, sc: Scales, z):
    """The shooting nodes' (x, y, ψ) [m, m, rad] as three (segments, 1) expressions: the start
    pose, then the nodes of ``z``."""
    lay = layout(grid)
    pose = z[lay.pose]
    xs, ys, ps = [pose[0] * sc.position_m], [pose[1] * sc.position_m], [pose[2]]
    if lay.n_shoot:
        node = ca.reshape(z[lay.shoot], 3, lay.n_shoot)
        xs.append(node[0, :].T * sc.position_m)
        ys.append(node[1, :].T * sc.position_m)
        ps.append(node[2, :].T)
    return ca.vertcat(*xs), ca.vertcat(*ys), ca.vertcat(*ps)


def path(grid: Grid, sc: Scales, z, with_defects: bool = False):
    """(u, a, j, j', κ, κ', κ'', ψ, x, y) at the samples, each (n_samples, 1); with
    ``with_defects`` also the continuity defects of the shooting nodes (each node's (x, y, ψ)
    minus the previous segment's end), a (3·(S − 1), 1) expression (None with one segment)."""
    (u, a, j, jd), (k, kd, kdd, _), _ = controls(grid, sc, z)
    h = grid.dt
    X0, Y0, P0 = nodes(grid, sc, z)
    W = _member(grid)
    g = u * k
    dg = a * k + u * kd
    ipsi, epsi = _segment_integral(grid, g, dg, h)
    psi = ca.mtimes(W, P0) + ipsi
    c, s = ca.cos(psi), ca.sin(psi)
    ix, ex = _segment_integral(grid, u * c, a * c - u * s * g, h)
    iy, ey = _segment_integral(grid, u * s, a * s + u * c * g, h)
    x = ca.mtimes(W, X0) + ix
    y = ca.mtimes(W, Y0) + iy
    out = (u, a, j, jd, k, kd, kdd, psi, x, y)
    if not with_defects:
        return out
    if epsi is None:
        return out, None
    defects = ca.vertcat(((X0[1:] - X0[:-1] - ex) / sc.position_m).T, ((Y0[1:] - Y0[:-1] - ey) / sc.position_m).T,
                         (P0[1:] - P0[:-1] - epsi).T)
    return out, ca.vec(defects)


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


def terrain_path(grid: Grid, sc: Scales, z, terrain: Terrain, with_defects: bool = False):
    """:func:`path` on the terrain: the horizontal speed is u·cos(grade) (grade taken on the
    flat path, a second-order error), and the height z = ∫ u sin(grade) dt. Returns
    (u, a, j, j', κ, κ', κ'', ψ, x, y, z) (and the defects, as :func:`path`)."""
    (u, a, j, jd, k, kd, kdd, psi, x, y), defects = path(grid, sc, z, with_defects=True)
    if not terrain:
        out = (u, a, j, jd, k, kd, kdd, psi, x, y, 0 * x)
        return (out, defects) if with_defects else out
    h = grid.dt
    g, _ = terrain.grade_bank(x, y, psi)
    c, s = ca.cos(psi), ca.sin(psi)
    zero = 0 * x
    cx, ex = _segment_integral(grid, u * (1 - ca.cos(g)) * c, zero, h)
    cy, ey = _segment_integral(grid, u * (1 - ca.cos(g)) * s, zero, h)
    x, y = x - cx, y - cy
    if defects is not None:  # the node's position against the previous segment's corrected end
        S1 = grid.n_segments - 1
        fix = ca.vec(ca.vertcat(ex.T / sc.position_m, ey.T / sc.position_m, ca.DM.zeros(1, S1)))
        defects = defects + fix
    g, _ = terrain.grade_bank(x, y, psi)
    height = ca.vertcat(0, ca.cumsum(0.5 * h * (u[:-1] * ca.sin(g[:-1]) + u[1:] * ca.sin(g[1:]))))
    out = (u, a, j, jd, k, kd, kdd, psi, x, y, height)
    return (out, defects) if with_defects else out


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
    t = np.linspace(0.0, grid.duration_s, int(round(grid.duration_s * rate_hz)) + 1)
    u = np.maximum(grid.spline(speed_coefficients(grid, sc, z))(t), 0.0)
    k = grid.spline(z[lay.curv] * sc.curvature_1pm)(t)
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


def _cumtrap_np(f: np.ndarray, df: np.ndarray | None, h: float) -> np.ndarray:
    out = np.concatenate([[0.0], np.cumsum(0.5 * h * (f[:-1] + f[1:]))])
    return out if df is None else out - h * h / 12.0 * (df - df[0])


def shooting_nodes(grid: Grid, sc: Scales, z: np.ndarray, terrain: Terrain = Terrain()) -> np.ndarray:
    """The shooting nodes (scaled, as :attr:`Layout.shoot`) that make ``z``'s path continuous:
    the path integrated from the start pose alone (as :func:`terrain_path` integrates it)."""
    lay = layout(grid)
    z = np.asarray(z, dtype=float)
    zu, zk = z[lay.speed] * sc.speed_mps, z[lay.curv] * sc.curvature_1pm
    u, a = grid.U[0] @ zu, grid.U[1] @ zu
    k, kd = grid.C[0] @ zk, grid.C[1] @ zk
    x0, y0, psi0 = z[lay.pose] * np.array([sc.position_m, sc.position_m, 1.0])
    h = grid.dt
    g = u * k
    psi = psi0 + _cumtrap_np(g, a * k + u * kd, h)
    c, s = np.cos(psi), np.sin(psi)
    x = x0 + _cumtrap_np(u * c, a * c - u * s * g, h)
    y = y0 + _cumtrap_np(u * s, a * s + u * c * g, h)
    if terrain:
        gr, _ = terrain.grade_bank_np(np.column_stack([x, y]), psi)
        x = x - _cumtrap_np(u * (1 - np.cos(gr)) * c, None, h)
        y = y - _cumtrap_np(u * (1 - np.cos(gr)) * s, None, h)
    i = grid.segments[1:]
    return np.column_stack([x[i] / sc.position_m, y[i] / sc.position_m, psi[i]]).ravel()


def z_from_profile(grid: Grid, sc: Scales, profile: ControlProfile, rate_hz: float = 20.0,
                   terrain: Terrain = Terrain()) -> np.ndarray:
    """The decision vector whose splines fit a control profile best (least squares on its
    values at ``rate_hz``: a profile written by :func:`profile_from_z` comes back exactly), its
    shooting nodes on the splines' own path. The profile is shifted to start at t = 0 and
    clipped to the grid's duration."""
    lay = layout(grid)
    t = np.linspace(0.0, grid.duration_s, int(round(grid.duration_s * rate_hz)) + 1)
    c = profile.at(profile.t_s[0] + np.minimum(t, profile.duration_s))
    B = BSpline.design_matrix(np.minimum(t, grid.duration_s), grid.knots, DEGREE).toarray()
    E = _speed_embedding(grid.n_coefficients)
    z = np.zeros(lay.size)
    z[lay.speed] = np.linalg.lstsq(B @ E, c["speed_mps"], rcond=None)[0] / sc.speed_mps
    z[lay.curv] = np.linalg.lstsq(B, c["curvature_1pm"], rcond=None)[0] / sc.curvature_1pm
    x0, y0, psi0 = profile.start
    z[lay.pose] = [x0 / sc.position_m, y0 / sc.position_m, psi0]
    return with_nodes(grid, sc, z, terrain)


def with_nodes(grid: Grid, sc: Scales, z: np.ndarray, terrain: Terrain = Terrain()) -> np.ndarray:
    """``z`` with its shooting nodes on its own path (after a change of the controls or the
    start pose)."""
    z = np.array(z, dtype=float)
    lay = layout(grid)
    if lay.n_shoot:
        z[lay.shoot] = shooting_nodes(grid, sc, z, terrain)
    return z
