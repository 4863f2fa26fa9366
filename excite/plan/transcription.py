"""The transcription of a :class:`~.problem.Problem` into a finite NLP that is cheap for IPOPT.

Decision vector z (:mod:`.kinematics`): the B-spline coefficients of speed and curvature (knots
every ``knot_step_s``), the start pose, and the shooting nodes (x, y, ψ every ``shooting_s``:
multiple shooting). Every row of the constraint Jacobian is local — a B-spline value depends on
four coefficients, a position on its shooting segment — and each constraint is imposed where
it binds and no more often:

- **speed, acceleration, curvature, curvature rate**: at every ``limits_every``-th model sample
  (every one, 8 Hz: with knots every 1.5 s a spline's extremes between samples exceed them by
  < 1 %, inside the margins; at 4 Hz IPOPT needed 44 % more iterations from seed 0's start and
  did not converge from the slalom in 1500); linear rows with ≤ 4 nonzeros, their Jacobian a
  constant (the speed at every sample whatever ``limits_every``: a spline that dipped below zero
  between samples would be clipped on playback);
- **jerk**: at the knots, exactly (the cubic's second derivative is piecewise linear);
- **lateral acceleration** u²κ (and a bump's speed cap): at every ``lat_accel_every``-th sample
  (8 Hz: its peaks are sharp);
- **the lot's clearance**: its smooth signed distance at the rate the lot's geometry needs
  (:func:`clearance_every`: 2 Hz on a convex lot, 4 Hz with keep-out zones);
- **continuity** of the shooting nodes; the closure (``closed``); the entry pose (bounds).

The constraint Jacobian is built once, in scalar operations (:attr:`Transcription.jac_g`):
3 ms per evaluation on the 90 s problem. ``hull_refine`` > 0 bounds the linear quantities by the
B-spline convex hull instead (sufficient everywhere; IPOPT converged far more slowly on it:
``benchmarks/bench_ipopt.py``).

The objective's information matrix M(z) = S Λ S is the coarse model (:func:`.model.build_model`)
of the body samples (:func:`.kinematics.body_samples`); both run compiled when :mod:`.compiled`
has (or can build) them, in CasADi's virtual machine otherwise (:class:`Information`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
from scipy import sparse

from ..motion.vehicle import Limits
from . import compiled
from .kinematics import Grid, Scales, body_samples, layout, sparse_dm, terrain_path
from .model import build_model, coarse_rig
from .problem import CLOSURE_TOL_M, CLOSURE_TOL_RAD, LOT_BUFFER_M, Bound, Problem

SHOOTING_TOL_M, SHOOTING_TOL_RAD = 0.5, 0.02  # continuity of an iterate worth the check (which drives
# the profile from the start pose: the check decides)


@dataclass(frozen=True)
class TranscriptionOptions:
    """How the problem becomes an NLP. ``knot_step_s``: spacing of the spline knots;
    ``keyframe_rate_hz`` and ``imu_substeps``: the coarse information model's grid;
    ``hull_refine``: knot intervals are split this many times for the convex-hull bounds;
    ``lat_accel_every``: the lateral acceleration (and bump caps) at every n-th model sample;
    ``compile``: ``"auto"`` (compiled when cached, else CasADi's virtual machine, with a note),
    ``"wait"`` (compile now on a miss), ``"never"``."""

    knot_step_s: float = 1.5
    keyframe_rate_hz: float = 2.0
    imu_substeps: int = 4
    hull_refine: int = 0
    limits_every: int = 1
    lat_accel_every: int = 1
    shooting_s: float | None = 3.0
    compile: str = "auto"

    def __post_init__(self) -> None:
        if self.compile not in ("auto", "wait", "never"):
            raise ValueError(f"compile must be auto, wait or never, got {self.compile!r}")


class Information:
    """z → M = S Λ S (numpy) of the coarse model, its vector-Jacobian product and (for an exact
    Hessian) its second-order derivatives.

    ``body``: ``(z, scales) → the body samples``, ``scales`` the constant vector ``consts``
    (the decision vector's scales: a compiled body serves every lot size and limit);
    ``model``: the samples → M (the function :func:`.model.build_model` makes). Either may be
    given as a function that builds it: it is then built only when the virtual machine needs it
    (nothing compiled for it, or the exact Hessian). ``fast``: the compiled ``body``,
    ``body_rev``, ``model``, ``model_rev``, where there are. Without ``body`` the model takes z
    itself (small test problems)."""

    def __init__(self, model, body=None, consts: np.ndarray | None = None,
                 fast: dict[str, ca.Function] | None = None, mode: str = "virtual machine", note: str = ""):
        self._build = {"model": model, "body": body}
        self._vm: dict[str, ca.Function] = {}
        fast = fast or {}
        self.consts = [] if consts is None else [np.asarray(consts, dtype=float)]
        self.has_body = body is not None
        self.model = fast["model"] if "model" in fast else self.model_vm
        self.model_rev = fast["model_rev"] if "model_rev" in fast else self.model_vm.reverse(1)
        self.body = self.body_rev = None
        if self.has_body:
            self.body = fast["body"] if "body" in fast else self.body_vm
            self.body_rev = fast["body_rev"] if "body_rev" in fast else self.body_vm.reverse(1)
        self.mode, self.note = mode, note
        self.seconds: dict[str, float] = {}
        self._second: tuple[ca.Function, ca.Function] | None = None

    def _get(self, name: str) -> ca.Function | None:
        if name not in self._vm:
            f = self._build[name]
            self._vm[name] = f if f is None or isinstance(f, ca.Function) else f()
        return self._vm[name]

    @property
    def model_vm(self) -> ca.Function:
        return self._get("model")

    @property
    def body_vm(self) -> ca.Function | None:
        return self._get("body")

    def _samples(self, z):
        return [z] if self.body is None else list(self.body(z, *self.consts))

    def __call__(self, z: np.ndarray) -> np.ndarray:
        return np.array(self.model(*self._samples(z)))

    def vjp(self, z: np.ndarray, M: np.ndarray, seed: np.ndarray) -> np.ndarray:
        """∂⟨seed, M(z)⟩/∂z (``M`` = M(z), given)."""
        s = self._samples(z)
        adj = self.model_rev(*s, M, seed)
        adj = adj if isinstance(adj, (list, tuple)) else [adj]
        if self.body is None:
            return np.array(adj[0]).ravel()
        out = self.body_rev(z, *self.consts, *s, *adj)
        return np.array(out[0] if isinstance(out, (list, tuple)) else out).ravel()

    def second_order(self, z: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(∂M/∂z as (n, p, p), ∂²⟨G, M(z)⟩/∂z²)`` by CasADi's automatic differentiation in the
        virtual machine (forward over reverse)."""
        n = np.asarray(z).size
        p = self.model_vm.size1_out(0)
        if self._second is None:
            zs = ca.MX.sym("z", n)
            Gs = ca.MX.sym("G", p, p)
            Ms = self.model_vm(*([zs] if self.body_vm is None else self.body_vm(zs, *self.consts)))
            self._second = (ca.Function("jac_M", [zs], [ca.jacobian(ca.vec(Ms), zs)]),
                            ca.Function("hess_GM", [zs, Gs], [ca.hessian(ca.dot(Gs, Ms), zs)[0]]))
        J = np.array(self._second[0](z)).reshape(p, p, n, order="F").transpose(2, 0, 1)
        return J, np.array(self._second[1](z, G))


@dataclass
class Transcription:
    """The NLP: decision vector bounds, constraints ``g(z)`` with the optimizer's bounds and
    the limits' (wider) bounds, and the information map of the objective."""

    problem: Problem | None
    grid: Grid | None
    scales: Scales | None
    info: Information
    g_kin: ca.Function
    lbg_kin: np.ndarray
    ubg_kin: np.ndarray
    lbg_ok: np.ndarray  # the limits themselves (the optimizer's bounds are inside them)
    ubg_ok: np.ndarray
    lbz: np.ndarray
    ubz: np.ndarray
    n_params: int
    rows: dict[str, slice] = field(default_factory=dict)
    options: TranscriptionOptions = field(default_factory=TranscriptionOptions)
    jac_g: ca.Function | None = None  # (x, p) → (g, ∂g/∂x), built once: CasADi's own is slower
    n_linear: int = 0  # the first rows are linear in z

    @property
    def n_z(self) -> int:
        return self.lbz.size

    @property
    def n_g(self) -> int:
        return self.lbg_kin.size

    @property
    def closed(self) -> bool:
        return bool(self.problem is not None and self.problem.closed)

    @property
    def limits(self) -> Limits | None:
        return None if self.problem is None else self.problem.limits

    @property
    def site(self) -> Any:
        return None if self.problem is None else self.problem.site

    def M(self, z: np.ndarray) -> np.ndarray:
        """S Λ S of the coarse model at z."""
        return self.info(np.asarray(z, dtype=float))


def _convex_without_holes(site) -> bool:
    if len(site.lot.holes):
        return False
    p = np.asarray(site.lot.polygon_m, dtype=float)
    e = np.roll(p, -1, axis=0) - p
    cross = e[:, 0] * np.roll(e[:, 1], -1) - e[:, 1] * np.roll(e[:, 0], -1)
    return bool(np.all(cross >= -1e-9) or np.all(cross <= 1e-9))


def clearance_every(problem: Problem, grid: Grid) -> int:
    """Every how many model samples the lot's clearance is imposed (see the module docstring):
    on a convex lot without keep-out zones, the spacing at which the path's largest bulge
    between two samples, ``a_lat,max·h²/8``, is half the optimizer's buffer; elsewhere 4 Hz."""
    if _convex_without_holes(problem.site):
        h = math.sqrt(4.0 * LOT_BUFFER_M / problem.limits.lat_accel_max_mps2)
    else:
        h = 0.25
    return max(int(h / grid.dt + 1e-9), 1)


def _model_sources() -> list[Path]:
    """The source files the information model is built from (part of the compiled cache key)."""
    pkg = Path(__file__).resolve().parents[1]
    out = [pkg / "plan" / "model.py", pkg / "information.py", pkg / "errors.py"]
    for d in ("factors", "information", "rig", "core"):
        out += sorted((pkg / d).rglob("*.py"))
    return [p for p in out if p.is_file()]


def _scales_vector(sc: Scales) -> np.ndarray:
    return np.array([sc.speed_mps, sc.curvature_1pm, sc.position_m])


def body_function(problem: Problem, grid: Grid, options: TranscriptionOptions) -> ca.Function:
    """``(z, scales) → the body samples`` of ``problem`` on ``grid`` (:func:`.kinematics.body_samples`)."""
    crig = coarse_rig(problem.rig, options.keyframe_rate_hz, options.imu_substeps)
    pose = crig.config.vehicle.T_V_B
    z = ca.MX.sym("z", layout(grid).size)
    v = ca.MX.sym("scales", 3)
    sc = Scales(v[0], v[1], v[2])
    return ca.Function("body", [z, v], list(body_samples(grid, sc, z, crig.suspension, pose.R, pose.p,
                                                         problem.site.terrain)))


def information(problem: Problem, grid: Grid, sc: Scales, options: TranscriptionOptions) -> Information:
    """The information map of ``problem`` on ``grid``: the body samples and the model, each
    compiled where possible (:mod:`.compiled`; two libraries: the model depends on the rig and
    the keyframes only, the body on the grid, the vehicle and the terrain). A cached library is
    found by its key alone: the functions it was compiled from are not even built."""
    crig = coarse_rig(problem.rig, options.keyframe_rate_hz, options.imu_substeps)
    consts = _scales_vector(sc)
    built: dict[str, ca.Function] = {}

    def body() -> ca.Function:
        if "body" not in built:
            built["body"] = body_function(problem, grid, options)
        return built["body"]

    def model() -> ca.Function:
        if "model" not in built:
            built["model"] = build_model(crig, grid.n_keyframes).scaled
        return built["model"]

    if options.compile == "never":
        return Information(model, body, consts)
    wait = options.compile == "wait"
    body_key = compiled.key_of("body", repr(grid.t_knots.tolist()), grid.n_samples, grid.imu_substeps,
                               repr(grid.segments.tolist()), crig.config.model_dump_json(),
                               repr([(f.role, np.asarray(f.polygon_m).round(6).tolist(), f.direction, f.slope,
                                      f.height_m) for f in problem.site.terrain.features]),
                               sources=[Path(__file__).with_name("kinematics.py"), Path(__file__).with_name("terrain.py")])
    b = compiled.load("body", ["body", "adj1_body"], body_key, lambda: [body(), body().reverse(1)], wait=wait,
                      what="the optimizer's kinematics")
    key = compiled.key_of("information", crig.config.model_dump_json(), grid.n_keyframes,
                          options.imu_substeps, sources=_model_sources())
    m = compiled.load("information", ["scaled", "adj1_scaled"], key, lambda: [model(), model().reverse(1)],
                      wait=wait)  # CasADi's names of build_model's `scaled` and its reverse sweep
    fast = {}
    if b.mode == "compiled":
        fast.update(body=b.functions["body"], body_rev=b.functions["adj1_body"])
    if m.mode == "compiled":
        fast.update(model=m.functions["scaled"], model_rev=m.functions["adj1_scaled"])
    mode = "compiled" if len(fast) == 4 else "virtual machine" if not fast else "partly compiled"
    info = Information(model, body, consts, fast, mode, "; ".join(n for n in (m.note, b.note) if n))
    info.seconds = {**{f"model_{k}": v for k, v in m.seconds.items()}, **{f"body_{k}": v for k, v in b.seconds.items()}}
    return info


def prepare(rig, settings, options: TranscriptionOptions = TranscriptionOptions()) -> tuple[str, dict[str, float]]:
    """Compile the information model of ``settings``' problem shape (the rig and the duration:
    not the lot) into the cache now, unless it is there: ``(mode, seconds per step)``."""
    from dataclasses import replace

    problem = Problem.of(rig, settings)
    grid = Grid.make(problem.duration_s, options.knot_step_s, options.keyframe_rate_hz, options.imu_substeps,
                     options.shooting_s)
    lo, hi = problem.site.lot.polygon_m.min(axis=0), problem.site.lot.polygon_m.max(axis=0)
    sc = Scales.of(problem.limits, float(np.abs(np.concatenate([lo, hi])).max()))
    info = information(problem, grid, sc, replace(options, compile="wait"))
    return info.mode, info.seconds


def transcribe(problem: Problem, options: TranscriptionOptions = TranscriptionOptions()) -> Transcription:
    """The NLP of ``problem`` (see the module docstring)."""
    site, limits = problem.site, problem.limits
    grid = Grid.make(problem.duration_s, options.knot_step_s, options.keyframe_rate_hz, options.imu_substeps,
                     options.shooting_s)
    lo = site.lot.polygon_m.min(axis=0)
    hi = site.lot.polygon_m.max(axis=0)
    sc = Scales.of(limits, float(np.abs(np.concatenate([lo, hi])).max()))
    lay = layout(grid)
    # the objective's body samples in matrix symbols: the graph stays small (sparse products,
    # sums, a map of the per-sample body function), so its reverse sweep builds in milliseconds;
    # expanded to scalar operations it evaluates faster but takes seconds and 150 MB to build
    info = information(problem, grid, sc, options)
    z = ca.SX.sym("z", lay.size)  # the constraints: scalar operations, each row local to its segment
    b = problem.bounds()

    names: dict[str, slice] = {}
    lin: list[sparse.csr_matrix] = []
    nonlin: list[ca.SX] = []
    bounds: list[tuple[int, object]] = []

    def add(name: str, part, bound) -> None:
        """A block of rows: a sparse matrix on z (linear) or SX expressions (nonlinear)."""
        linear = sparse.issparse(part)
        if linear:
            part = part[np.flatnonzero(abs(part).max(axis=1).toarray().ravel() > 0)]  # identically zero rows
            lin.append(part)
        else:
            nonlin.append(part)
        bounds.append((part.shape[0], bound, name, linear))

    # linear in z (sparse rows with ≤ 4 nonzeros): the speed's and curvature's values and rates
    E = sparse.lil_matrix((grid.n_coefficients, lay.size))
    E[2:-2, lay.speed] = sparse.identity(lay.n_speed) * sc.speed_mps
    K = sparse.lil_matrix((grid.n_coefficients, lay.size))
    K[:, lay.curv] = sparse.identity(lay.n_curv) * sc.curvature_1pm
    E, K = E.tocsr(), K.tocsr()
    r = options.hull_refine
    if r > 0:  # the convex hulls of the derivative splines (sufficient everywhere)
        def on(d: int, C):
            return sparse.csr_matrix(grid.hull(d, r)) @ C
    else:  # sampled at every ``limits_every``-th model sample
        def on(d: int, C):
            return grid.C[d][::options.limits_every] @ C
    # the speed at every sample: a spline that dips below zero between samples is clipped when
    # played back, a jerk spike the check rejects
    add("speed", grid.C[0] @ E if r == 0 else on(0, E), b["speed"])
    add("accel", on(1, E), b["accel"])
    # the jerk is piecewise linear: its values at the knots bound it exactly
    add("jerk", sparse.csr_matrix(grid.hull(2)) @ E, b["jerk"])
    add("curvature", on(0, K), b["curvature"])
    add("curvature_rate", on(1, K), b["curvature_rate"])

    # nonlinear: the lateral acceleration and bump caps at every ``lat_accel_every``-th sample,
    # the lot at the rate its geometry needs, the closure
    e = options.lat_accel_every
    ue = ca.mtimes(sparse_dm(grid.C[0][::e] @ E), z)
    ke = ca.mtimes(sparse_dm(grid.C[0][::e] @ K), z)
    add("lat_accel", ue * ue * ke, b["lat_accel"])
    (u, a, j, jd, k, kd, kdd, psi, x, y, _), defects = terrain_path(grid, sc, z, site.terrain, with_defects=True)
    if defects is not None:
        tol = np.tile([SHOOTING_TOL_M / sc.position_m, SHOOTING_TOL_M / sc.position_m, SHOOTING_TOL_RAD],
                      grid.n_segments - 1)
        nonlin.append(defects)
        bounds.append((defects.shape[0], (np.zeros(tol.size), np.zeros(tol.size), -tol, tol), "continuity", False))
    c = clearance_every(problem, grid)
    clear = site.clearance()
    add("clearance", clear(ca.horzcat(x[::c], y[::c]).T).T, b["clearance"])
    for i, ((cap_expr, _), bound) in enumerate(zip(site.terrain.speed_limits(u[::e], x[::e], y[::e]),
                                                   problem.bump_caps())):
        add(f"bump_{i + 1}", cap_expr, bound)
    lay_pose = z[lay.pose]
    if problem.closed:
        add("closure_xy", ca.vertcat(x[-1] - lay_pose[0] * sc.position_m, y[-1] - lay_pose[1] * sc.position_m),
            Bound(0.0, 0.0, -CLOSURE_TOL_M, CLOSURE_TOL_M))
        # heading: the winding number is fixed by the start (see solver.solve); compared via sin/cos
        add("closure_sin", ca.sin(psi[-1] - lay_pose[2]), Bound(0.0, 0.0, -CLOSURE_TOL_RAD, CLOSURE_TOL_RAD))
        add("closure_cos", ca.cos(psi[-1] - lay_pose[2]), Bound(0.99, 1.0, 0.98, 1.0))

    # the rows: linear first, then nonlinear; the Jacobian of the linear ones is a constant
    A = sparse.vstack(lin).tocsr()
    g_nl = ca.vertcat(*nonlin)
    A_dm = sparse_dm(A)
    g_expr = ca.densify(ca.vertcat(ca.mtimes(A_dm, z), g_nl))
    g_kin = ca.Function("g_kin", [z], [g_expr])
    p = ca.SX.sym("p", 0)
    jac_g = ca.Function("jac_g", [z, p], [g_expr, ca.vertcat(A_dm, ca.jacobian(g_nl, z))], ["x", "p"],
                        ["g", "jac_g_x"])
    lb, ub, lb_ok, ub_ok = [], [], [], []
    start = 0
    for linear in (True, False):
        for n, bound, name, is_lin in bounds:
            if is_lin != linear:
                continue
            names[name] = slice(start, start + n)
            start += n
            vals = bound if isinstance(bound, tuple) else (bound.lo, bound.hi, bound.lo_ok, bound.hi_ok)
            for out, v in zip((lb, ub, lb_ok, ub_ok), vals):
                out.append(np.broadcast_to(np.asarray(v, dtype=float), (n,)))

    lbz = np.full(lay.size, -np.inf)
    ubz = np.full(lay.size, np.inf)
    # the coefficients themselves are held by the refined hull rows; these bounds only keep
    # IPOPT's steps in a sane range
    lbz[lay.speed], ubz[lay.speed] = -0.5, 1.5
    lbz[lay.curv], ubz[lay.curv] = -2.0, 2.0
    lbz[lay.pose] = [lo[0] / sc.position_m, lo[1] / sc.position_m, -4 * np.pi]
    ubz[lay.pose] = [hi[0] / sc.position_m, hi[1] / sc.position_m, 4 * np.pi]
    if lay.n_shoot:  # the nodes' positions inside the lot's bounding box, their headings free
        lbz[lay.shoot] = np.tile([lo[0] / sc.position_m, lo[1] / sc.position_m, -np.inf], lay.n_shoot)
        ubz[lay.shoot] = np.tile([hi[0] / sc.position_m, hi[1] / sc.position_m, np.inf], lay.n_shoot)
    if site.entry is not None:
        ex, ey, eh = site.entry
        lbz[lay.pose] = ubz[lay.pose] = [ex / sc.position_m, ey / sc.position_m, eh]
    crig = coarse_rig(problem.rig, options.keyframe_rate_hz, options.imu_substeps)
    return Transcription(problem, grid, sc, info, g_kin, np.concatenate(lb), np.concatenate(ub),
                         np.concatenate(lb_ok), np.concatenate(ub_ok), lbz, ubz, len(crig.scored), names, options,
                         jac_g=jac_g, n_linear=A.shape[0])


def violation(tr: Transcription, z: np.ndarray, g: np.ndarray | None = None, within_limits: bool = False) -> float:
    """Largest violation at z of the optimizer's constraints (or, ``within_limits``, of the
    limits themselves: the wider bounds) and of the variable bounds."""
    gv = np.array(tr.g_kin(z)).ravel() if g is None else g
    lo, hi = (tr.lbg_ok, tr.ubg_ok) if within_limits else (tr.lbg_kin, tr.ubg_kin)
    v = max(np.maximum(lo - gv, 0.0).max(initial=0.0), np.maximum(gv - hi, 0.0).max(initial=0.0))
    v = max(v, np.maximum(tr.lbz - z, 0.0).max(initial=0.0), np.maximum(z - tr.ubz, 0.0).max(initial=0.0))
    return float(v)


def problem_key(problem: Problem, options: TranscriptionOptions) -> str:
    """What a transcription is built from, as text (the criterion does not enter it)."""
    site = problem.site
    feats = [(f.role, np.asarray(f.polygon_m).round(6).tolist(), f.direction, f.slope, f.height_m, f.max_speed_mps)
             for f in site.terrain.features]
    return json.dumps([problem.rig.config.model_dump_json(), problem.duration_s, repr(problem.limits),
                       site.outline(), repr(feats), problem.closed, repr(options)], default=str)


_CACHE: dict[str, Transcription] = {}
_CACHE_SIZE = 4


def cached(problem: Problem, options: TranscriptionOptions = TranscriptionOptions()) -> Transcription:
    """:func:`transcribe`, kept per process for the last few problems (a process forked from
    one that transcribed the problem finds it already built)."""
    key = problem_key(problem, options)
    tr = _CACHE.pop(key, None)
    if tr is None:
        tr = transcribe(problem, options)
    _CACHE[key] = tr  # most recent last
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.pop(next(iter(_CACHE)))
    return tr
