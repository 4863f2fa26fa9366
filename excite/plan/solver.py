"""The solver: IPOPT on a :class:`~.transcription.Transcription`.

IPOPT minimises a smooth spectral function of S Λ S (:func:`.criteria.smooth`: for the score,
the soft minimum ``−(μ/β) log Σ exp(−β λ_i/μ)``, within μ·log(p)/β of λ_min; μ = the start's
λ_min) whose gradient is one reverse sweep of the model seeded with ``V diag(∂f/∂λ) Vᵀ``
(:class:`Objective`). The Hessian of the Lagrangian is either IPOPT's limited-memory
approximation (the default) or exact (:class:`SolverOptions` ``hessian="exact"``: the spectral
function's curvature through ∂M/∂z plus ⟨∂f/∂M, ∂²M/∂z²⟩ by forward-over-reverse AD, and the
constraints' exact Hessians); ``benchmarks/bench_ipopt.py`` measures both.

Every iterate that keeps within the limits is kept (an IPOPT iteration callback), so that the
pipeline can check them independently, best first. IPOPT can be warm-started from a previous
outcome (its multipliers, :attr:`Outcome.lam_x` / :attr:`Outcome.lam_g`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import casadi as ca
import numpy as np

from . import criteria
from .transcription import Transcription, violation

FEASIBLE_TOL = 1e-5
SOFTMIN_BETA = 20.0  # sharpness of the soft minimum, in units of the start's λ_min


@dataclass(frozen=True)
class SolverOptions:
    """IPOPT's options for the maneuver NLP (``benchmarks/bench_ipopt.py`` measures them).

    ``hessian``: ``limited-memory`` (IPOPT's quasi-Newton approximation, ``history`` pairs,
    updated by ``update``) or ``exact``.
    ``update``: ``sr1`` or ``bfgs`` (IPOPT's ``limited_memory_update_type``). SR1, because it needs
    no positive curvature: BFGS skips an update whose curvature is not positive and IPOPT resets
    its memory after more than two skips in a row, so on this objective BFGS's memory holds few
    pairs whatever ``history`` says, and it takes about twice the iterations to a lower optimum
    (``benchmarks/bench_ipopt.py`` compares them from the same starts).
    ``tol``: IPOPT's convergence tolerance on its scaled optimality error; IPOPT's acceptable
    level also counts as converged: ``acceptable_iter`` consecutive iterations with the error
    below ``acceptable_tol`` and the objective changing by less than ``acceptable_obj_change_tol``
    (relative) — with L-BFGS the last digits of the dual infeasibility take hundreds of
    iterations that move the score by < 0.1 % (benchmarks/bench_ipopt.py).
    ``mu_init``: a small, monotone barrier — IPOPT's adaptive default starts at μ = 0.1, where the
    barrier of the constraint rows outweighs the objective and IPOPT first drives to the middle
    of the feasible set (the weakest excitation).
    ``mumps_scaling``: whether MUMPS scales the KKT system itself (IPOPT's default). Off: the NLP
    is scaled already (:class:`.kinematics.Scales`), and MUMPS's own scaling of the KKT system
    costs more than half of IPOPT's time per iteration for the same optimum
    (``benchmarks/bench_ipopt.py``, variant ``mumps_scaled``).
    """

    hessian: str = "limited-memory"
    history: int = 20
    update: str = "sr1"
    tol: float = 1e-7
    acceptable_tol: float = 1e-3
    acceptable_iter: int = 10
    acceptable_obj_change_tol: float = 1e-5
    mu_init: float = 1e-3
    softmin_beta: float = SOFTMIN_BETA
    mumps_scaling: bool = False
    extra: dict = field(default_factory=dict)  # further IPOPT options, e.g. {"print_level": 5}

    def __post_init__(self) -> None:
        if self.hessian not in ("limited-memory", "exact"):
            raise ValueError(f"hessian must be limited-memory or exact, got {self.hessian!r}")
        if self.update not in ("sr1", "bfgs"):
            raise ValueError(f"update must be sr1 or bfgs, got {self.update!r}")

    def ipopt(self) -> dict[str, object]:
        out: dict[str, object] = {
            "ipopt.hessian_approximation": self.hessian, "ipopt.print_level": 0, "ipopt.sb": "yes",
            "ipopt.tol": self.tol, "ipopt.acceptable_tol": self.acceptable_tol,
            "ipopt.acceptable_iter": self.acceptable_iter,
            "ipopt.acceptable_obj_change_tol": self.acceptable_obj_change_tol,
            "ipopt.mu_strategy": "monotone", "ipopt.mu_init": self.mu_init,
        }
        if not self.mumps_scaling:
            out.update({"ipopt.mumps_scaling": 0, "ipopt.mumps_permuting_scaling": 0})
        if self.hessian == "limited-memory":
            out["ipopt.limited_memory_max_history"] = self.history
            out["ipopt.limited_memory_update_type"] = self.update
        out.update({f"ipopt.{k}": v for k, v in self.extra.items()})
        return out


DEFAULT = SolverOptions()

# IPOPT's return status → ours. "Stopped" covers the time budget, the iteration cap and
# cancellation (the iteration callback asked IPOPT to stop).
CONVERGED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
INFEASIBLE = ("Infeasible_Problem_Detected",)
STOPPED = ("User_Requested_Stop", "Maximum_Iterations_Exceeded", "Maximum_CpuTime_Exceeded",
           "Maximum_WallTime_Exceeded", "Stopped_At_Deadline")  # the last: ours, inside an iteration

DEADLINE_GRACE_S = 0.5  # past the deadline, an objective evaluation aborts the IPOPT run


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


class Objective(ca.Callback):
    """A smooth spectral objective of M(z) (:func:`.criteria.smooth`) and its exact gradient:
    ``∂f/∂M = V diag(∂f/∂λ) Vᵀ`` pushed through one reverse sweep of the model. Smooth even
    where eigenvalues cross (a symmetric function of the spectrum)."""

    def __init__(self, info, n_z: int, criterion: str, mu: float, beta: float, deadline: float = np.inf,
                 grad: bool = False, last: dict | None = None):
        ca.Callback.__init__(self)
        self.info, self.n_z, self.criterion, self.mu, self.beta, self.grad = info, n_z, criterion, mu, beta, grad
        self.deadline = deadline
        self.last = {} if last is None else last  # the last z and M(z), shared with the gradient
        self._revs: list[Objective] = []  # CasADi holds raw pointers: keep them alive
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
        f, dw = criteria.smooth(w, self.criterion, self.mu, self.beta)
        if not self.grad:
            return [f]
        seed = float(arg[2]) * (V * dw) @ V.T
        return [self.info.vjp(z, M, seed)]

    def M(self, z: np.ndarray) -> np.ndarray:
        """M(z), computed once per point (IPOPT asks for f and ∇f at the same z)."""
        if self.last.get("z") is None or not np.array_equal(self.last["z"], z):
            self.last.update(z=z.copy(), M=self.info(z))
        return self.last["M"]

    def hessian(self, z: np.ndarray) -> np.ndarray:
        """∇²f(z): the spectral function's curvature along ∂M/∂z plus ⟨∂f/∂M, ∂²M/∂z²⟩."""
        M = self.M(z)
        w, V = np.linalg.eigh(M)
        d1, d2 = criteria.smooth_curvature(w, self.criterion, self.mu, self.beta)
        J, H2 = self.info.second_order(z, (V * d1) @ V.T)
        return criteria.spectral_hessian(w, V, d1, d2, J) + H2

    def has_jacobian_sparsity(self):
        return True

    def get_jacobian_sparsity(self):
        # without it CasADi probes the black box for its sparsity when the NLP is built, which
        # took 3–7 s on the 90 s problem
        return ca.Sparsity.dense(self.n_z if self.grad else 1, self.n_z)

    def has_reverse(self, nadj):
        return not self.grad and nadj == 1

    def get_reverse(self, nadj, name, inames, onames, opts):
        rev = Objective(self.info, self.n_z, self.criterion, self.mu, self.beta, self.deadline, grad=True,
                        last=self.last)
        self._revs.append(rev)
        return rev


class _ObjectiveAndGradient(ca.Callback):
    """IPOPT's ``grad_f``: ``(x, p) → (f, ∇f)`` of an :class:`Objective` in one call (CasADi's
    own composes the callback's value and reverse sweep, which costs more)."""

    def __init__(self, obj: Objective):
        ca.Callback.__init__(self)
        self.obj = obj
        self.construct("grad_f", {})

    def get_n_in(self):
        return 2

    def get_n_out(self):
        return 2

    def get_name_in(self, i):
        return ("x", "p")[i]

    def get_name_out(self, i):
        return ("f", "grad_f_x")[i]

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.obj.n_z) if i == 0 else ca.Sparsity(0, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.scalar() if i == 0 else ca.Sparsity.dense(self.obj.n_z)

    def eval(self, arg):
        o = self.obj
        if time.perf_counter() > o.deadline:
            o.last["past_deadline"] = True
            return [np.nan, np.full(o.n_z, np.nan)]
        z = np.array(arg[0]).ravel()
        M = o.M(z)
        w, V = np.linalg.eigh(M)
        f, dw = criteria.smooth(w, o.criterion, o.mu, o.beta)
        return [f, o.info.vjp(z, M, (V * dw) @ V.T)]


class _LagrangianHessian(ca.Callback):
    """The exact Hessian of IPOPT's Lagrangian ``σ f + λᵀ g`` (upper triangle, dense)."""

    def __init__(self, tr: Transcription, obj: Objective):
        ca.Callback.__init__(self)
        self.n, self.m, self.obj = tr.n_z, tr.n_g, obj
        z = ca.MX.sym("z", tr.n_z)
        lg = ca.MX.sym("lam_g", tr.n_g)
        self.hess_g = ca.Function("hess_g", [z, lg], [ca.densify(ca.hessian(ca.dot(lg, tr.g_kin(z)), z)[0])])
        self.construct("hess_lag", {})

    def get_n_in(self):
        return 4

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ("x", "p", "lam_f", "lam_g")[i]

    def get_name_out(self, i):
        return "hess_gamma_x_x"

    def get_sparsity_in(self, i):
        return (ca.Sparsity.dense(self.n), ca.Sparsity(0, 1), ca.Sparsity.scalar(), ca.Sparsity.dense(self.m))[i]

    def get_sparsity_out(self, i):
        return ca.Sparsity.upper(self.n)

    def eval(self, arg):
        z = np.array(arg[0]).ravel()
        H = np.array(self.hess_g(z, arg[3]))
        sigma = float(arg[2])
        if sigma != 0.0 and time.perf_counter() <= self.obj.deadline:
            H = H + sigma * self.obj.hessian(z)
        return [ca.triu(ca.DM(0.5 * (H + H.T)))]


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
    ``z_final``, ``lam_x``, ``lam_g``: IPOPT's last point and multipliers (a warm start).
    """

    feasible: list[tuple[float, np.ndarray]]
    iterations: int
    status: str
    ipopt_status: str
    history: list[tuple[int, float, float, float]]  # (iteration, model criterion, violation of the
    # optimizer's constraints, elapsed)
    z_final: np.ndarray | None = None
    lam_x: np.ndarray | None = None
    lam_g: np.ndarray | None = None
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def z(self) -> np.ndarray | None:
        return self.feasible[0][1] if self.feasible else None

    @property
    def score(self) -> float:
        return self.feasible[0][0] if self.feasible else -np.inf

    def best(self, n: int) -> "Outcome":
        """This outcome with only the ``n`` best feasible iterates (and no history): what a
        multi-start task sends back."""
        return replace(self, feasible=self.feasible[:n], history=self.history[-1:])


RESTORE_OPTIONS: dict[str, object] = {
    # the Hessian of ½‖z − z0‖² alone: most rows are linear, and the nonlinear ones' curvature
    # would cost seconds to build; IPOPT's line search does the rest
    "ipopt.hessian_constant": "yes", "ipopt.print_level": 0, "ipopt.sb": "yes",
    "ipopt.tol": 1e-8, "ipopt.mu_strategy": "adaptive", "print_time": False, "error_on_fail": False,
}


def restore(tr: Transcription, z0: np.ndarray, deadline: float) -> tuple[np.ndarray, str]:
    """The point nearest z0 (in the scaled decision vector) that satisfies the constraints, and
    IPOPT's return status. Cheap next to the optimization (no information model), and it spares
    the optimization from starting infeasible: from an infeasible start IPOPT spends its first
    iterations on feasibility and loses the excitation on the way. Returns z0 itself when the
    deadline passes first."""
    z = ca.MX.sym("z", tr.n_z)
    n, m = tr.n_z, tr.n_g
    x, p, lf, lg = ca.MX.sym("x", n), ca.MX.sym("p", 0), ca.MX.sym("lam_f"), ca.MX.sym("lam_g", m)
    hess = ca.Function("hess_lag", [x, p, lf, lg], [ca.triu(ca.DM.eye(n)) * lf],
                       ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])
    stop = _IterationCallback(n, m, 0, lambda x, f, g: time.perf_counter() > deadline)
    solver = ca.nlpsol("restore", "ipopt", {"x": z, "f": 0.5 * ca.sumsqr(z - z0), "g": tr.g_kin(z)},
                       {**RESTORE_OPTIONS, "iteration_callback": stop, "hess_lag": hess})
    solver._keep = stop  # noqa: SLF001 — the callback must outlive the solver
    sol = solver(x0=np.clip(z0, tr.lbz, tr.ubz), lbx=tr.lbz, ubx=tr.ubz, lbg=tr.lbg_kin, ubg=tr.ubg_kin)
    z1 = np.array(sol["x"]).ravel()
    status = str(solver.stats().get("return_status", "unknown"))
    return (z1 if violation(tr, z1) <= FEASIBLE_TOL else np.asarray(z0, dtype=float)), status


def model_value(tr: Transcription, z: np.ndarray, criterion: str = "E") -> float:
    """The criterion of the coarse model at z (λ_min for ``E``)."""
    return criteria.value(tr.M(z), criterion)


def solve(tr: Transcription, z0: np.ndarray, deadline: float, criterion: str = "E",
          max_iterations: int | None = None, should_stop: Callable[[], bool] | None = None,
          progress: Callable[[int, float, float, float, float], None] | None = None,
          t_start: float | None = None, options: SolverOptions = DEFAULT,
          warm: Outcome | None = None, mu: float | None = None) -> Outcome:
    """Maximise ``criterion`` of the model with one IPOPT run from ``z0`` (until converged,
    ``deadline``, ``max_iterations`` or ``should_stop()``), keeping every feasible iterate.
    ``progress(iteration, model value, violation, elapsed, best value within the limits so
    far)`` after every iteration, just before ``should_stop()``.

    ``warm``: a previous outcome on the same transcription whose multipliers start IPOPT (its
    barrier small: the warm start keeps the active set; e.g. to continue a run the budget cut
    short). ``mu``: the soft minimum's scale (default: the start's weakest eigenvalue)."""
    t_start = time.perf_counter() if t_start is None else t_start
    t_solve = time.perf_counter()
    z0 = np.asarray(z0, dtype=float)
    w0 = np.linalg.eigvalsh(tr.M(z0))
    if mu is None:
        mu = max(abs(w0[0]), 1e-8 * abs(w0[-1]), 1e-12)  # the scale of the weakest eigenvalue
    obj = Objective(tr.info, tr.n_z, criterion, mu, options.softmin_beta, deadline + DEADLINE_GRACE_S)
    z = ca.MX.sym("z", tr.n_z)
    state = {"it": 0, "stop": False, "calls": 0, "best": -np.inf}
    feasible: list[tuple[float, np.ndarray]] = []
    hist: list[tuple[int, float, float, float]] = []

    def keep(x: np.ndarray, g: np.ndarray | None = None) -> tuple[float, float]:
        g = np.array(tr.g_kin(x)).ravel() if g is None else g
        s = criteria.value(obj.M(x), criterion)
        if violation(tr, x, g, within_limits=True) <= FEASIBLE_TOL and np.isfinite(s):
            feasible.append((s, x.copy()))
            state["best"] = max(state["best"], s)
        return s, violation(tr, x, g)

    def on_iter(x, f, g):
        s, viol = keep(x, g)
        state["it"] = state["calls"]  # IPOPT reports its iteration 0 (the start) too
        state["calls"] += 1
        el = time.perf_counter() - t_start
        hist.append((state["it"], s, viol, el))
        if progress is not None:
            progress(state["it"], s, viol, el, state["best"])
        if should_stop is not None and should_stop():
            state["stop"] = True
        return state["stop"] or time.perf_counter() > deadline

    cb = _IterationCallback(tr.n_z, tr.n_g, 0, on_iter)
    opts = {**options.ipopt(), "ipopt.max_iter": 100000 if max_iterations is None else int(max_iterations),
            "print_time": False, "iteration_callback": cb, "error_on_fail": False, "show_eval_warnings": False}
    grad_f = _ObjectiveAndGradient(obj)
    opts["grad_f"] = grad_f
    if tr.jac_g is not None:
        opts["jac_g"] = tr.jac_g
    keep_alive: tuple = (obj, cb, grad_f)
    if options.hessian == "exact":
        hl = _LagrangianHessian(tr, obj)
        opts["hess_lag"] = hl
        keep_alive += (hl,)
    args = dict(x0=z0, lbx=tr.lbz, ubx=tr.ubz, lbg=tr.lbg_kin, ubg=tr.ubg_kin)
    if warm is not None and warm.lam_x is not None:
        opts.update({"ipopt.warm_start_init_point": "yes", "ipopt.warm_start_bound_push": 1e-9,
                     "ipopt.warm_start_mult_bound_push": 1e-9, "ipopt.mu_init": min(options.mu_init, 1e-6)})
        args.update(lam_x0=warm.lam_x, lam_g0=warm.lam_g)
    solver = ca.nlpsol("optimize", "ipopt", {"x": z, "f": obj(z), "g": tr.g_kin(z)}, opts)
    solver._keep = keep_alive  # noqa: SLF001 — the callbacks must outlive the solver
    keep(z0)
    z_final = lam_x = lam_g = None
    timings: dict[str, float] = {}
    try:
        t_call = time.perf_counter()
        sol = solver(**args)
        t_call = time.perf_counter() - t_call
        z_final = np.array(sol["x"]).ravel()
        lam_x, lam_g = np.array(sol["lam_x"]).ravel(), np.array(sol["lam_g"]).ravel()
        keep(z_final)
        stats = solver.stats()
        rs = str(stats.get("return_status", "unknown"))
        state["it"] = int(stats.get("iter_count", state["it"]))
        evals = {k[len("t_wall_nlp_"):]: float(v) for k, v in stats.items() if k.startswith("t_wall_nlp_")}
        timings.update({f"nlp_{k}": v for k, v in evals.items() if v})
        # IPOPT's own work: the call less the evaluations and the iteration callback (CasADi's
        # stats have no total wall time)
        timings["ipopt_own"] = t_call - sum(evals.values()) - float(stats.get("t_wall_callback_fun", 0.0))
        timings["iteration_callback"] = float(stats.get("t_wall_callback_fun", 0.0))
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
    timings["solve"] = time.perf_counter() - t_solve
    return Outcome(feasible, state["it"], status, rs, hist, z_final, lam_x, lam_g, timings)
