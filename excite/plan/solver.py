"""The NLP: maximise a criterion of the coarse information model over feasible control splines.

Statement (:class:`Transcription`): decision vector z (:mod:`.kinematics`), constraints at the
sample points (speed, acceleration, deceleration, jerk, lateral acceleration, curvature,
curvature rate, the lot's smooth clearance, bump speed caps, optionally the end pose equal to
the start pose; the start pose fixed at the lot's entry when it has one) and the objective.
Solution (:func:`solve`): IPOPT with exact first derivatives (CasADi) and limited-memory Hessian
approximation, minimising a smooth spectral function of S Λ S (:func:`.criteria.smooth`: for
the score, the soft minimum ``−(μ/β) log Σ exp(−β λ_i/μ)``, within μ·log(p)/β of λ_min; β = 20,
μ = the start's λ_min) whose gradient is one reverse sweep of the model seeded with
``V diag(∂f/∂λ) Vᵀ``. Every iterate that satisfies the constraints is kept (an IPOPT iteration
callback), so that the pipeline can check them independently, best first.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

import casadi as ca
import numpy as np

from ..rig.config import Rig
from ..motion.vehicle import Limits
from .kinematics import Grid, Scales, body_samples, layout, path
from . import criteria
from .model import build_model, coarse_rig

LIMIT_MARGIN = 0.95  # fraction of every limit the optimizer may use (sampling, PCHIP playback)
JERK_MARGIN = 0.8  # drive() plays speed back shape-preservingly (PCHIP), which adds up to ~20 % jerk
CONSTRAINT_EVERY = 2  # nonlinear constraints (the lot) at every 2nd IMU sample of the model (4 Hz)


LOT_BUFFER_M = 0.25  # the optimizer keeps this much more than the margin (path between samples)
CLOSURE_TOL_M, CLOSURE_TOL_RAD = 0.5, 0.02  # a closed maneuver's end pose, for the check's candidates


@dataclass
class Transcription:
    """The optimal-control problem on a grid and its CasADi functions."""

    grid: Grid
    scales: Scales
    limits: Limits
    site: Any
    closed: bool
    M: ca.Function  # z → S Λ S (coarse model)
    kin: ca.Function  # z → (u, a, j, κ, κ', x, y, ψ) at the samples
    g_kin: ca.Function
    lbg_kin: np.ndarray
    ubg_kin: np.ndarray
    lbg_ok: np.ndarray  # the limits themselves (the optimizer's bounds are inside them)
    ubg_ok: np.ndarray
    lbz: np.ndarray
    ubz: np.ndarray
    n_params: int

    @property
    def n_z(self) -> int:
        return self.lbz.size


def transcribe(rig: Rig, settings, site, knot_step_s: float = 1.5, keyframe_rate_hz: float = 2.0,
               imu_substeps: int = 4) -> Transcription:
    """State the problem of ``settings`` on ``site`` for ``rig`` (the model runs on
    :func:`coarse_rig` of it)."""
    limits = settings.limits
    grid = Grid.make(settings.duration_s, knot_step_s, keyframe_rate_hz, imu_substeps)
    crig = coarse_rig(rig, keyframe_rate_hz, imu_substeps)
    lo = site.lot.polygon_m.min(axis=0)
    hi = site.lot.polygon_m.max(axis=0)
    sc = Scales.of(limits, float(np.abs(np.concatenate([lo, hi])).max()))
    lay = layout(grid)
    model = build_model(crig, grid.n_keyframes)
    z = ca.MX.sym("z", lay.size)
    pose = crig.config.vehicle.T_V_B
    M = model.scaled(*body_samples(grid, sc, z, crig.suspension, pose.R, pose.p, site.terrain))
    M_fun = ca.Function("M", [z], [M])

    u, a, j, jd, k, kd, kdd, psi, x, y = path(grid, sc, z)
    e = CONSTRAINT_EVERY
    m = LIMIT_MARGIN
    rows, lb, ub, lb_ok, ub_ok = [], [], [], [], []

    def add(expr, lo, hi, lo_ok=None, hi_ok=None):
        """A constraint row block: the optimizer's bounds [lo, hi] and the wider bounds [lo_ok,
        hi_ok] within which an iterate is worth the independent check (the limits themselves)."""
        n = expr.shape[0]
        rows.append(expr)
        for out, v in ((lb, lo), (ub, hi), (lb_ok, lo if lo_ok is None else lo_ok), (ub_ok, hi if hi_ok is None else hi_ok)):
            out.append(np.broadcast_to(v, (n,)))

    def limit(expr, lo, hi, margin=m):
        add(expr, margin * lo, margin * hi, lo, hi)

    # linear in z (cheap): at every sample, so the spline cannot dip below zero speed between
    # constraint points (drive() clips negative speed: a jerk spike in the independent check)
    add(u, 0.0, m * limits.speed_max_mps, 0.0, limits.speed_max_mps)
    limit(a, -limits.decel_max_mps2, limits.accel_max_mps2)
    limit(j, -limits.jerk_max_mps3, limits.jerk_max_mps3, JERK_MARGIN)
    limit(k, -limits.curvature_max_1pm, limits.curvature_max_1pm)
    limit(kd, -limits.curvature_rate_max_1pms, limits.curvature_rate_max_1pms)
    # lateral acceleration at every sample: it peaks sharply in fast slaloms
    limit(u * u * k, -limits.lat_accel_max_mps2, limits.lat_accel_max_mps2)
    # the lot: smooth signed distance to the nearest edge or keep-out zone
    clear = site.clearance()
    add(clear(ca.horzcat(x[::e], y[::e]).T).T, site.margin_m + LOT_BUFFER_M, np.inf, site.margin_m, np.inf)
    for cap_expr, cap in site.terrain.speed_limits(u, x, y):
        add(cap_expr, -np.inf, m * cap, -np.inf, cap)
    lay_pose = z[lay.pose]
    if closed := settings.closed:
        add(ca.vertcat(x[-1] - lay_pose[0] * sc.position_m, y[-1] - lay_pose[1] * sc.position_m), 0.0, 0.0,
            -CLOSURE_TOL_M, CLOSURE_TOL_M)
        # heading: the winding number is fixed by the start (see solve); compared via sin/cos
        add(ca.sin(psi[-1] - lay_pose[2]), 0.0, 0.0, -CLOSURE_TOL_RAD, CLOSURE_TOL_RAD)
        add(ca.cos(psi[-1] - lay_pose[2]), 0.99, 1.0, 0.98, 1.0)
    g = ca.vertcat(*rows)
    g_kin = ca.Function("g_kin", [z], [g])
    kin = ca.Function("kin", [z], [ca.horzcat(u, a, j, k, kd, x, y, psi)])

    lbz = np.full(lay.size, -np.inf)
    ubz = np.full(lay.size, np.inf)
    lbz[lay.speed], ubz[lay.speed] = 0.0, m
    lbz[lay.curv], ubz[lay.curv] = -m, m
    lbz[lay.pose] = [lo[0] / sc.position_m, lo[1] / sc.position_m, -4 * np.pi]
    ubz[lay.pose] = [hi[0] / sc.position_m, hi[1] / sc.position_m, 4 * np.pi]
    if site.entry is not None:
        ex, ey, eh = site.entry
        lbz[lay.pose] = ubz[lay.pose] = [ex / sc.position_m, ey / sc.position_m, eh]
    return Transcription(grid, sc, limits, site, closed, M_fun, kin, g_kin,
                         np.concatenate(lb), np.concatenate(ub), np.concatenate(lb_ok), np.concatenate(ub_ok),
                         lbz, ubz, len(crig.scored))


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


def violation(tr: Transcription, z: np.ndarray, g: np.ndarray | None = None, within_limits: bool = False) -> float:
    """Largest violation at z of the optimizer's constraints (or, ``within_limits``, of the
    limits themselves: the wider bounds) and of the variable bounds."""
    gv = np.array(tr.g_kin(z)).ravel() if g is None else g
    lo, hi = (tr.lbg_ok, tr.ubg_ok) if within_limits else (tr.lbg_kin, tr.ubg_kin)
    v = max(np.maximum(lo - gv, 0.0).max(initial=0.0), np.maximum(gv - hi, 0.0).max(initial=0.0))
    v = max(v, np.maximum(tr.lbz - z, 0.0).max(initial=0.0), np.maximum(z - tr.ubz, 0.0).max(initial=0.0))
    return float(v)


FEASIBLE_TOL = 1e-5
SOFTMIN_BETA = 20.0  # sharpness of the soft minimum, in units of the start's λ_min

# IPOPT's options (benchmarks/bench_ipopt.py measures alternatives on the default problem)
IPOPT_OPTIONS: dict[str, object] = {
    "ipopt.hessian_approximation": "limited-memory", "ipopt.limited_memory_max_history": 20,
    "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-7,
    # a small, monotone barrier: the adaptive default starts at μ = 0.1, where the barrier of the
    # thousands of constraint rows outweighs the objective and IPOPT first drives to the middle of
    # the feasible set (the weakest excitation); measured in benchmarks/bench_ipopt.py
    "ipopt.mu_strategy": "monotone", "ipopt.mu_init": 1e-3,
}

# IPOPT's return status → ours. "Stopped" covers the time budget, the iteration cap and
# cancellation (the iteration callback asked IPOPT to stop).
CONVERGED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
INFEASIBLE = ("Infeasible_Problem_Detected",)
STOPPED = ("User_Requested_Stop", "Maximum_Iterations_Exceeded", "Maximum_CpuTime_Exceeded",
           "Maximum_WallTime_Exceeded", "Stopped_At_Deadline")  # the last: ours, inside an iteration


DEADLINE_GRACE_S = 0.5  # past the deadline, an objective evaluation aborts the IPOPT run


class _Objective(ca.Callback):
    """A smooth spectral objective of M(z) (:func:`.criteria.smooth`) and its exact gradient:
    ``∂f/∂M = V diag(∂f/∂λ) Vᵀ`` pushed through one reverse sweep of the CasADi model. Smooth
    even where eigenvalues cross (a symmetric function of the spectrum)."""

    def __init__(self, M: ca.Function, n_z: int, criterion: str, mu: float, deadline: float = np.inf,
                 grad: bool = False, last: dict | None = None):
        ca.Callback.__init__(self)
        self.Mf, self.n_z, self.criterion, self.mu, self.grad = M, n_z, criterion, mu, grad
        self.deadline = deadline
        self.last = {} if last is None else last  # the last z and M(z), shared with the gradient
        self.Mrev = M.reverse(1) if grad else None
        self._revs: list[_Objective] = []  # CasADi holds raw pointers: keep them alive
        self.construct("objective_grad" if grad else "objective", {})

    def get_n_in(self):
        return 3 if self.grad else 1

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.n_z) if i == 0 else ca.Sparsity.scalar()

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(self.n_z) if self.grad else ca.Sparsity.scalar()

    def eval(self, arg):
        if time.perf_counter() > self.deadline:
            # an iteration can take seconds on a loaded machine: stop inside it, not after it (a
            # NaN makes IPOPT give up at once; raising would print CasADi's traceback)
            self.last["past_deadline"] = True
            return [np.full(self.n_z, np.nan) if self.grad else np.nan]
        z = np.array(arg[0]).ravel()
        M = self.M(z)
        w, V = np.linalg.eigh(M)
        f, dw = criteria.smooth(w, self.criterion, self.mu, SOFTMIN_BETA)
        if not self.grad:
            return [f]
        seed = float(arg[2]) * (V * dw) @ V.T
        return [self.Mrev(z, M, seed)]

    def M(self, z: np.ndarray) -> np.ndarray:
        """M(z), computed once per point (IPOPT asks for f and ∇f at the same z)."""
        if self.last.get("z") is None or not np.array_equal(self.last["z"], z):
            self.last.update(z=z.copy(), M=np.array(self.Mf(z)))
        return self.last["M"]

    def has_reverse(self, nadj):
        return not self.grad and nadj == 1

    def get_reverse(self, nadj, name, inames, onames, opts):
        rev = _Objective(self.Mf, self.n_z, self.criterion, self.mu, self.deadline, grad=True, last=self.last)
        self._revs.append(rev)
        return rev


@dataclass
class Outcome:
    """What :func:`solve` returns.

    ``feasible``: every iterate (the start included) within the limits themselves (the
    optimizer's own bounds keep margins inside them, which an iterate on its way may not yet
    respect), as ``(model criterion value, z)``, best first — candidates for the independent
    check, which alone decides what is feasible.
    ``status``: ``converged``, ``time_budget`` (stopped by the deadline or the iteration cap),
    ``cancelled``, ``infeasible`` (IPOPT found the constraints infeasible) or ``failed``
    (any other IPOPT failure); ``ipopt_status``: IPOPT's own return status.
    """

    feasible: list[tuple[float, np.ndarray]]
    iterations: int
    status: str
    ipopt_status: str
    history: list[tuple[int, float, float, float]]  # (iteration, model criterion, violation of the
    # optimizer's constraints, elapsed)

    @property
    def z(self) -> np.ndarray | None:
        return self.feasible[0][1] if self.feasible else None

    @property
    def score(self) -> float:
        return self.feasible[0][0] if self.feasible else -np.inf


RESTORE_OPTIONS: dict[str, object] = {
    "ipopt.hessian_approximation": "limited-memory", "ipopt.print_level": 0, "ipopt.sb": "yes",
    "ipopt.tol": 1e-6, "print_time": False, "error_on_fail": False,
}


def restore(tr: Transcription, z0: np.ndarray, deadline: float) -> tuple[np.ndarray, str]:
    """The point nearest z0 (in the scaled decision vector) that satisfies the constraints, and
    IPOPT's return status. Cheap next to the optimization (no information model), and it spares
    the optimization from starting infeasible: from an infeasible start IPOPT spends its first
    iterations on feasibility and loses the excitation on the way (benchmarks/bench_ipopt.py).
    Returns z0 itself when the deadline passes first."""
    z = ca.MX.sym("z", tr.n_z)
    stop = _IterationCallback(tr.n_z, tr.lbg_kin.size, 0, lambda x, f, g: time.perf_counter() > deadline)
    solver = ca.nlpsol("restore", "ipopt", {"x": z, "f": 0.5 * ca.sumsqr(z - z0), "g": tr.g_kin(z)},
                       {**RESTORE_OPTIONS, "iteration_callback": stop})
    solver._keep = stop  # noqa: SLF001 — the callback must outlive the solver
    sol = solver(x0=z0, lbx=tr.lbz, ubx=tr.ubz, lbg=tr.lbg_kin, ubg=tr.ubg_kin)
    z1 = np.array(sol["x"]).ravel()
    status = str(solver.stats().get("return_status", "unknown"))
    return (z1 if violation(tr, z1) <= FEASIBLE_TOL else z0), status


def model_value(tr: Transcription, z: np.ndarray, criterion: str = "E") -> float:
    """The criterion of the coarse model at z (λ_min for ``E``)."""
    return criteria.value(np.array(tr.M(z)), criterion)


def solve(tr: Transcription, z0: np.ndarray, deadline: float, criterion: str = "E",
          max_iterations: int | None = None, should_stop: Callable[[], bool] | None = None,
          progress: Callable[[int, float, float, float], None] | None = None,
          t_start: float | None = None) -> Outcome:
    """Maximise ``criterion`` of the model with one IPOPT run from ``z0`` (until converged,
    ``deadline``, ``max_iterations`` or ``should_stop()``), keeping every feasible iterate."""
    t_start = time.perf_counter() if t_start is None else t_start
    z0 = np.asarray(z0, dtype=float)
    w0 = np.linalg.eigvalsh(np.array(tr.M(z0)))
    mu = max(abs(w0[0]), 1e-8 * abs(w0[-1]), 1e-12)  # the scale of the weakest eigenvalue
    obj = _Objective(tr.M, tr.n_z, criterion, mu, deadline + DEADLINE_GRACE_S)
    z = ca.MX.sym("z", tr.n_z)
    state = {"it": 0, "stop": False}
    feasible: list[tuple[float, np.ndarray]] = []
    hist: list[tuple[int, float, float, float]] = []

    def keep(x: np.ndarray, g: np.ndarray | None = None) -> tuple[float, float]:
        g = np.array(tr.g_kin(x)).ravel() if g is None else g
        s = criteria.value(obj.M(x), criterion)
        if violation(tr, x, g, within_limits=True) <= FEASIBLE_TOL and np.isfinite(s):
            feasible.append((s, x.copy()))
        return s, violation(tr, x, g)

    def on_iter(x, f, g):
        s, viol = keep(x, g)
        state["it"] = state.get("calls", 0)  # IPOPT reports its iteration 0 (the start) too
        state["calls"] = state["it"] + 1
        el = time.perf_counter() - t_start
        hist.append((state["it"], s, viol, el))
        if progress is not None:
            progress(state["it"], s, viol, el)
        if should_stop is not None and should_stop():
            state["stop"] = True
        return state["stop"] or time.perf_counter() > deadline

    cb = _IterationCallback(tr.n_z, tr.lbg_kin.size, 0, on_iter)
    opts = {**IPOPT_OPTIONS, "ipopt.max_iter": 100000 if max_iterations is None else int(max_iterations),
            "print_time": False, "iteration_callback": cb, "error_on_fail": False, "show_eval_warnings": False}
    solver = ca.nlpsol("optimize", "ipopt", {"x": z, "f": obj(z), "g": tr.g_kin(z)}, opts)
    solver._keep = (obj, cb)  # noqa: SLF001 — the callbacks must outlive the solver
    keep(z0)
    try:
        sol = solver(x0=z0, lbx=tr.lbz, ubx=tr.ubz, lbg=tr.lbg_kin, ubg=tr.ubg_kin)
        keep(np.array(sol["x"]).ravel())
        stats = solver.stats()
        rs = str(stats.get("return_status", "unknown"))
        state["it"] = int(stats.get("iter_count", state["it"]))
    except RuntimeError as exc:  # IPOPT or a callback raised: what was kept stays valid
        rs = f"error: {exc}".splitlines()[0][:200]
    if obj.last.get("past_deadline"):
        rs = "Stopped_At_Deadline"
    if state["stop"]:
        status = "cancelled"
    elif rs in CONVERGED:
        status = "converged"
    elif rs in STOPPED:
        status = "time_budget"
    elif rs in INFEASIBLE:
        status = "infeasible"
    else:
        status = "failed"
    feasible.sort(key=lambda r: -r[0])
    return Outcome(feasible, state["it"], status, rs, hist)

