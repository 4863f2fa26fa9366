"""The NLP: maximise λ_min(S Λ S) of the coarse information model over feasible control splines.

Statement (:class:`Transcription`): decision vector z (:mod:`.kinematics`), constraints at the
sample points (speed, acceleration, deceleration, jerk, lateral acceleration, curvature,
curvature rate, the lot's inner rectangle, optionally the end pose equal to the start pose) and
the objective. Solution (:func:`solve_softmin`): IPOPT with exact first derivatives (CasADi) and
limited-memory Hessian approximation, maximising the soft minimum
``−(μ/β) log Σ exp(−β λ_i/μ)`` of the scaled spectrum: a smooth spectral function of S Λ S
(within μ·log(p)/β of λ_min; β = 20, μ = the start's λ_min) whose gradient is one reverse sweep
of the model seeded with ``Σ π_i v_i v_iᵀ``. One IPOPT run, ~0.4 s per iteration on the 90 s
problem; the best feasible iterate by the *true* λ_min is kept. (An epigraph restricted to the
weakest eigenspace, exact at coalescing eigenvalues, needed m(m+1)/2 reverse sweeps per
iteration and got less far within a minute; it was removed.)
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import casadi as ca
import numpy as np

from ..rig import Rig
from ..vehicle import Limits
from .kinematics import Grid, Scales, body_samples, layout, path
from .model import build_model, coarse_rig

LIMIT_MARGIN = 0.95  # fraction of every limit the optimizer may use (sampling, PCHIP playback)
JERK_MARGIN = 0.8  # drive() plays speed back shape-preservingly (PCHIP), which adds up to ~20 % jerk
CONSTRAINT_EVERY = 2  # constraints at every 2nd IMU sample of the model (4 Hz)


@dataclass
class Transcription:
    """The optimal-control problem on a grid and its CasADi functions."""

    grid: Grid
    scales: Scales
    limits: Limits
    half_x_m: float
    half_y_m: float
    closed: bool
    M: ca.Function  # z → S Λ S (coarse model)
    kin: ca.Function  # z → (u, a, j, κ, κ', x, y, ψ) at the constraint samples
    g_kin: ca.Function
    lbg_kin: np.ndarray
    ubg_kin: np.ndarray
    lbz: np.ndarray
    ubz: np.ndarray
    n_params: int

    @property
    def n_z(self) -> int:
        return self.lbz.size


def transcribe(rig: Rig, duration_s: float, limits: Limits, half_x_m: float, half_y_m: float,
               closed: bool = False, knot_step_s: float = 1.5, keyframe_rate_hz: float = 2.0,
               imu_substeps: int = 4) -> Transcription:
    """State the problem for ``rig`` (the model runs on :func:`coarse_rig` of it)."""
    grid = Grid.make(duration_s, knot_step_s, keyframe_rate_hz, imu_substeps)
    crig = coarse_rig(rig, keyframe_rate_hz, imu_substeps)
    sc = Scales.of(limits, max(half_x_m, half_y_m))
    lay = layout(grid)
    model = build_model(crig, grid.n_keyframes)
    z = ca.MX.sym("z", lay.size)
    pose = crig.config.vehicle.T_V_B
    M = model.scaled(*body_samples(grid, sc, z, crig.suspension, pose.R, pose.p))
    M_fun = ca.Function("M", [z], [M])

    u, a, j, jd, k, kd, kdd, psi, x, y = path(grid, sc, z)
    e = CONSTRAINT_EVERY
    sel = lambda q: q[::e]  # noqa: E731
    m = LIMIT_MARGIN
    n = grid.n_samples
    ns = len(range(0, n, e))
    rows, lb, ub = [], [], []

    def add(expr, lo, hi):
        rows.append(expr)
        lb.append(np.broadcast_to(lo, (expr.shape[0],)))
        ub.append(np.broadcast_to(hi, (expr.shape[0],)))

    add(sel(u), 0.0, m * limits.speed_max_mps)
    add(sel(a), -m * limits.decel_max_mps2, m * limits.accel_max_mps2)
    add(sel(j), -JERK_MARGIN * limits.jerk_max_mps3, JERK_MARGIN * limits.jerk_max_mps3)
    add(sel(k), -m * limits.curvature_max_1pm, m * limits.curvature_max_1pm)
    add(sel(kd), -m * limits.curvature_rate_max_1pms, m * limits.curvature_rate_max_1pms)
    # lateral acceleration at every sample: it peaks sharply in fast slaloms
    add(u * u * k, -m * limits.lat_accel_max_mps2, m * limits.lat_accel_max_mps2)
    add(sel(x), -half_x_m, half_x_m)
    add(sel(y), -half_y_m, half_y_m)
    if closed:
        p0 = z[lay.pose]
        add(ca.vertcat(x[-1] - p0[0] * sc.position_m, y[-1] - p0[1] * sc.position_m), 0.0, 0.0)
        # heading: the winding number is fixed by the start (see solve); compared via sin/cos
        add(ca.sin(psi[-1] - p0[2]), 0.0, 0.0)
        add(ca.cos(psi[-1] - p0[2]), 0.99, 1.0)
    g = ca.vertcat(*rows)
    g_kin = ca.Function("g_kin", [z], [g])
    kin = ca.Function("kin", [z], [ca.horzcat(u, a, j, k, kd, x, y, psi)])

    lbz = np.full(lay.size, -np.inf)
    ubz = np.full(lay.size, np.inf)
    lbz[lay.speed], ubz[lay.speed] = 0.0, m
    lbz[lay.curv], ubz[lay.curv] = -m, m
    lbz[lay.pose] = [-half_x_m / sc.position_m, -half_y_m / sc.position_m, -4 * np.pi]
    ubz[lay.pose] = [half_x_m / sc.position_m, half_y_m / sc.position_m, 4 * np.pi]
    del ns
    return Transcription(grid, sc, limits, half_x_m, half_y_m, closed, M_fun, kin, g_kin,
                         np.concatenate(lb), np.concatenate(ub), lbz, ubz, len(crig.scored))


class _IterationCallback(ca.Callback):
    """Forwards IPOPT's iterations to a Python function; a True return stops IPOPT."""

    def __init__(self, nx: int, ng: int, np_: int, fn: Callable[[np.ndarray, float, np.ndarray], bool]):
        ca.Callback.__init__(self)
        self.nx, self.ng, self.np_ = nx, ng, np_
        self.fn = fn
        self.construct("iter_cb", {})

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        n = ca.nlpsol_out(i)
        if n in ("f",):
            return ca.Sparsity.scalar()
        if n in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nx)
        if n in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity.dense(self.np_)

    def eval(self, arg):
        stop = self.fn(np.array(arg[0]).ravel(), float(arg[1]), np.array(arg[2]).ravel())
        return [1 if stop else 0]


@dataclass
class Outcome:
    """What :func:`solve_softmin` returns: the best feasible z (None if none), its model score, the
    number of IPOPT iterations, and why it stopped."""

    z: np.ndarray | None
    score: float
    iterations: int
    status: str
    history: list[tuple[int, float, float, float]]  # (iteration, λ_min, violation, elapsed)


def violation(tr: Transcription, z: np.ndarray) -> float:
    """Largest violation of the kinematic constraints and the variable bounds at z."""
    gv = np.array(tr.g_kin(z)).ravel()
    v = np.maximum(tr.lbg_kin - gv, 0.0).max(initial=0.0)
    v = max(v, np.maximum(gv - tr.ubg_kin, 0.0).max(initial=0.0))
    v = max(v, np.maximum(tr.lbz - z, 0.0).max(initial=0.0), np.maximum(z - tr.ubz, 0.0).max(initial=0.0))
    return float(v)


def score(tr: Transcription, z: np.ndarray) -> float:
    """λ_min of the coarse model at z."""
    return float(np.linalg.eigvalsh(np.array(tr.M(z)))[0])


FEASIBLE_TOL = 1e-5


# --- smooth spectral objective ------------------------------------------------------------------

SOFTMIN_BETA = 20.0  # sharpness of the soft minimum, in units of the start's λ_min
MAX_ITERATIONS: int | None = None  # optional iteration cap (deterministic runs regardless of load)


class _SoftMin(ca.Callback):
    """``f(z) = (1/β) log Σ exp(−β λ_i(M(z))/μ)`` = −softmin of the scaled spectrum, and its exact
    gradient: ``∂f/∂M = −Σ π_i v_i v_iᵀ / μ`` (π the soft-min weights) pushed through one reverse
    sweep of the CasADi model. A smooth spectral function of M, so IPOPT's line search and
    L-BFGS see a smooth objective even where eigenvalues cross."""

    def __init__(self, M: ca.Function, n_z: int, mu: float, beta: float = SOFTMIN_BETA, grad: bool = False):
        ca.Callback.__init__(self)
        self.Mf, self.n_z, self.mu, self.beta, self.grad = M, n_z, mu, beta, grad
        self.Mrev = M.reverse(1) if grad else None
        self._revs: list[_SoftMin] = []  # CasADi holds raw pointers: keep them alive
        self.construct("softmin_grad" if grad else "softmin", {})

    def get_n_in(self):
        return 3 if self.grad else 1

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.n_z) if i == 0 else ca.Sparsity.scalar()

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(self.n_z) if self.grad else ca.Sparsity.scalar()

    def _spectrum(self, z):
        M = np.array(self.Mf(z))
        w, V = np.linalg.eigh(M)
        x = -self.beta * w / self.mu
        c = x.max()
        e = np.exp(x - c)
        return M, w, V, (c + np.log(e.sum())) / self.beta, e / e.sum()

    def eval(self, arg):
        z = np.array(arg[0]).ravel()
        M, w, V, f, pi = self._spectrum(z)
        if not self.grad:
            return [f]
        seed = -float(arg[2]) * (V * pi) @ V.T / self.mu
        return [self.Mrev(z, M, seed)]

    def has_reverse(self, nadj):
        return not self.grad and nadj == 1

    def get_reverse(self, nadj, name, inames, onames, opts):
        rev = _SoftMin(self.Mf, self.n_z, self.mu, self.beta, grad=True)
        self._revs.append(rev)
        return rev


def solve_softmin(tr: Transcription, z0: np.ndarray, deadline: float,
                  should_stop: Callable[[], bool] | None = None,
                  progress: Callable[[int, float, float, float], None] | None = None,
                  t_start: float | None = None) -> Outcome:
    """Maximise the soft minimum of the scaled spectrum with one IPOPT run (until converged,
    ``deadline`` or ``should_stop()``); the best feasible iterate by the true λ_min is kept."""
    t_start = time.perf_counter() if t_start is None else t_start
    z0 = np.asarray(z0, dtype=float)
    w0 = np.linalg.eigvalsh(np.array(tr.M(z0)))
    mu = max(abs(w0[0]), 1e-8 * abs(w0[-1]), 1e-12)  # the scale of the weakest eigenvalue
    obj = _SoftMin(tr.M, tr.n_z, mu)
    z = ca.MX.sym("z", tr.n_z)
    state = {"it": 0, "stop": False, "best": None, "best_s": -np.inf}
    hist: list[tuple[int, float, float, float]] = []

    def on_iter(x, f, g):
        state["it"] += 1
        viol = float(max(np.maximum(tr.lbg_kin - g, 0).max(initial=0), np.maximum(g - tr.ubg_kin, 0).max(initial=0),
                         np.maximum(tr.lbz - x, 0).max(initial=0), np.maximum(x - tr.ubz, 0).max(initial=0)))
        s = score(tr, x)
        if viol <= FEASIBLE_TOL and s > state["best_s"]:
            state["best"], state["best_s"] = x.copy(), s
        el = time.perf_counter() - t_start
        hist.append((state["it"], s, viol, el))
        if progress is not None:
            progress(state["it"], s, viol, el)
        if should_stop is not None and should_stop():
            state["stop"] = True
        capped = MAX_ITERATIONS is not None and state["it"] >= MAX_ITERATIONS
        return state["stop"] or capped or time.perf_counter() > deadline

    cb = _IterationCallback(tr.n_z, tr.lbg_kin.size, 0, on_iter)
    opts = {
        "ipopt.hessian_approximation": "limited-memory",
        "ipopt.limited_memory_max_history": 20,
        "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-7, "ipopt.max_iter": 100000,
        "ipopt.mu_strategy": "adaptive", "print_time": False, "iteration_callback": cb,
    }
    solver = ca.nlpsol("softmin", "ipopt", {"x": z, "f": obj(z), "g": tr.g_kin(z)}, opts)
    solver._keep = (obj, cb)  # noqa: SLF001 — the callbacks must outlive the solver
    v0 = violation(tr, z0)
    if v0 <= FEASIBLE_TOL:
        state["best"], state["best_s"] = z0.copy(), score(tr, z0)
    sol = solver(x0=z0, lbx=tr.lbz, ubx=tr.ubz, lbg=tr.lbg_kin, ubg=tr.ubg_kin)
    zf = np.array(sol["x"]).ravel()
    sf = score(tr, zf)
    if violation(tr, zf) <= FEASIBLE_TOL and sf > state["best_s"]:
        state["best"], state["best_s"] = zf, sf
    rs = solver.stats().get("return_status", "")
    status = "cancelled" if state["stop"] else ("optimal" if rs == "Solve_Succeeded" else "time_budget")
    return Outcome(state["best"], float(state["best_s"]), state["it"], status, hist)
