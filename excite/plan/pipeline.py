"""The optimization pipeline: never worse than what it has seen, within one time budget.

Within ``time_budget_s`` of wall time, all of it:

1. **start** (main process): state the NLP; generate the first random candidates and the
   reference maneuvers; choose IPOPT's start among them by the optimizer's model. A worker
   process starts at once and, next to IPOPT, scores the reference maneuvers (full evaluator),
   screens the random candidates chunk by chunk (evaluator on the coarse rig), then runs COBYLA
   from the same start (:data:`COBYLA_SHARE` of the budget).
2. **optimize**: IPOPT until it converges, or until the budget less the time kept for the
   checks (:func:`finish_reserve_s`); every iterate that satisfies its constraints is kept.
3. **check**: the best kept iterates (by the model) go through the independent check
   (:func:`.candidates.check`, the same one every other candidate passed) until
   :data:`KEEP_ITERATES` passed; the worker's finished work is collected (unfinished chunks are
   dropped: the comparison says how many random candidates were scored); the feasible
   iterates, COBYLA, the start and the best screened random candidates are scored by the full
   evaluator.

The result is the best candidate by the criterion among *all* that passed the check — an IPOPT
iterate, or else whatever was better (its ``source`` says which). The returned profile is the
one that was checked, rounded as the control CSV writes it.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import sys
import time
from typing import Any, Callable

import numpy as np

from ..score.evaluate import evaluate
from ..rig.config import Rig
from ..motion.vehicle import ControlProfile, drive
from . import candidates as cand
from .candidates import Candidate, as_written, check
from .kinematics import layout, profile_from_z, z_from_profile
from ..errors import OptimizeError
from .settings import OptimizeResult, OptimizeSettings, Progress
from .solver import model_value, restore, solve, transcribe, violation

NEAR_FEASIBLE = 1.0  # largest violation of the optimizer's constraints of a start used as it is
START_RANDOM = 10  # random candidates (the first chunks) IPOPT's start is chosen among, with the references
CHUNK = 5  # random candidates per worker task (a finished chunk counts, an unfinished one not)
COBYLA_SHARE = 0.15  # of the budget, for the derivative-free baseline (in the worker)
CHECK_ITERATES = 15  # IPOPT iterates checked at most, best model value first ...
KEEP_ITERATES = 2  # ... until this many passed (each is then scored by the full evaluator)
SCORE_RANDOM = 2  # best screened random candidates scored by the full evaluator


def finish_reserve_s(budget_s: float) -> float:
    """Wall time kept after IPOPT for the checks, the full evaluations and the worker's results."""
    return 3.0 + 0.12 * budget_s


class _Worker:
    """One process next to IPOPT for the comparison candidates (spawned: the caller may hold
    threads, and forking it would copy held locks)."""

    def __init__(self, rig: Rig, settings: OptimizeSettings, site: Any):
        self.args = (rig, settings, site)
        self.pool = cf.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
        # A spawned child re-imports the parent's __main__ script unless it is hidden: a script
        # calling optimize() without an `if __name__ == "__main__"` guard would run again in it.
        # The worker needs nothing from __main__ (its tasks live in excite.plan.candidates).
        main = sys.modules["__main__"]
        hidden = {k: main.__dict__.get(k) for k in ("__file__", "__spec__") if k in main.__dict__}
        main.__dict__.pop("__file__", None)
        main.__spec__ = None
        try:
            self.refs = self.pool.submit(cand.references, *self.args)  # starts the process
        finally:
            main.__dict__.pop("__spec__", None)
            main.__dict__.update(hidden)
        self.cobyla: cf.Future | None = None
        self.chunks: list[cf.Future] = []

    def start_rest(self, z_start: np.ndarray, cobyla_s: float, n_random: int,
                   drawn: list[list[ControlProfile]]) -> None:
        """``drawn``: the first chunks' random profiles, already drawn as IPOPT's possible starts
        (sent along rather than drawn again)."""
        # the random candidates first: the comparison the result is held to; COBYLA last
        for c, (first, size) in enumerate(_chunks(n_random)):
            if c < len(drawn):
                self.chunks.append(self.pool.submit(cand.screened, *self.args, drawn[c]))
            else:
                self.chunks.append(self.pool.submit(cand.randoms, *self.args, c, size, first))
        self.cobyla = self.pool.submit(cand.cobyla, *self.args, z_start, cobyla_s)

    def close(self) -> None:
        """Drop the worker's unfinished work at once: a task it is running (COBYLA, a chunk) is
        cut short, so that neither this call nor the interpreter's exit waits for it."""
        procs = list((self.pool._processes or {}).values())  # noqa: SLF001 — no public handle before 3.14
        self.pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            if p.is_alive():
                p.terminate()


def _chunks(n_random: int) -> list[tuple[int, int]]:
    """(first index, size) of every chunk of random candidates (the first START_RANDOM are also
    IPOPT's possible starts)."""
    return [(first, min(CHUNK, n_random - first)) for first in range(0, n_random, CHUNK)]


def _result(fut: cf.Future | None, timeout_s: float):
    """The future's result, or None if it is not there in time, was cancelled, or failed (a
    comparison candidate that failed is not a reason to withhold the result)."""
    if fut is None:
        return None
    try:
        return fut.result(timeout=max(timeout_s, 0.0))
    except Exception:  # noqa: BLE001 — timeout, cancelled, or the worker broke
        return None


def optimize(rig: Rig, settings: OptimizeSettings = OptimizeSettings(),
             progress: Callable[[Progress], None] | None = None,
             should_stop: Callable[[], bool] | None = None) -> OptimizeResult:
    """The best drive within ``settings`` that this run has seen (see the module docstring).

    ``progress`` is called after every IPOPT iteration and at each phase; when ``should_stop()``
    returns True, IPOPT stops, the worker's unfinished work is dropped and the best checked
    drive so far is returned (``cancelled=True``).
    """
    t0 = time.perf_counter()
    settings = settings.for_rig(rig)  # within the vehicle's own limits (a car's steering rate)
    budget = settings.time_budget_s
    stop = should_stop or (lambda: False)
    site = settings.lot
    crit = settings.criterion
    timings: dict[str, float] = {}

    def report(it: int, s: float, v: float, phase: str) -> None:
        if progress is not None:
            progress(Progress(it, float(s), float(v), time.perf_counter() - t0, phase, budget))

    def remaining() -> float:
        return t0 + budget - time.perf_counter()

    report(0, float("nan"), float("nan"), "start")
    worker = _Worker(rig, settings, site)
    try:
        return _run(rig, settings, site, crit, worker, t0, timings, report, remaining, stop)
    finally:
        worker.close()


def _run(rig, settings, site, crit, worker: _Worker, t0, timings, report, remaining, stop) -> OptimizeResult:
    budget = settings.time_budget_s
    tr = transcribe(rig, settings, site)
    lay = layout(tr.grid)

    # --- start: the reference maneuvers and the first random candidates, by the model
    starts = [c.profile for c in cand.reference_profiles(rig, settings, site) if c.name != "highway_run"]
    drawn = [cand.random_profiles(rig, settings, site, c, size, first)
             for c, (first, size) in enumerate(_chunks(settings.n_random)) if first < START_RANDOM]
    starts += [p for chunk in drawn for p in chunk]
    ranked = []
    for i, c in enumerate(starts):
        z = z_from_profile(tr.grid, tr.scales, c)
        if site.entry is not None:
            z[lay.pose] = [site.entry[0] / tr.scales.position_m, site.entry[1] / tr.scales.position_m,
                           site.entry[2]]
        v = violation(tr, z)
        s = model_value(tr, z, crit)
        near = v < NEAR_FEASIBLE
        ranked.append((near, s if near else -v, -i, z, c))
        report(0, s, v, "start")
    if not ranked:
        raise OptimizeError("no reference maneuver or random candidate fits this lot and these limits "
                            "to start from")
    # the best by the model among the starts that nearly satisfy the optimizer's constraints
    # (with the small monotone barrier IPOPT regains feasibility within a few iterations and keeps
    # the excitation; a better start counts more than a feasible one: benchmarks/bench_ipopt.py);
    # when none does, the least violating one, moved to the nearest point that satisfies them
    ranked.sort(key=lambda r: (r[0], r[1], r[2]), reverse=True)
    near, _, _, z_start, start = ranked[0]
    start_note = ""
    if not near:  # e.g. every candidate starts elsewhere than the lot's entry: move to the nearest feasible
        z_start, restored = restore(tr, z_start, time.perf_counter() + 0.25 * remaining())
        start_note = (f"no candidate satisfied the optimizer's constraints: IPOPT started from {start.name} moved "
                      f"to the nearest drive that does ({restored})")
        report(0, model_value(tr, z_start, crit), violation(tr, z_start), "start")
    timings["start"] = time.perf_counter() - t0
    worker.start_rest(z_start, COBYLA_SHARE * budget, settings.n_random, drawn)

    # --- optimize
    out = solve(tr, z_start, time.perf_counter() + remaining() - finish_reserve_s(budget), crit,
                settings.max_iterations, should_stop=stop, t_start=t0,
                progress=lambda it, s, v, el: report(it, s, v, "optimize"))
    timings["optimize"] = time.perf_counter() - t0 - timings["start"]
    cancelled = out.status == "cancelled" or stop()
    report(out.iterations, out.score, 0.0, "check")

    # --- check the best iterates independently
    passed: list[Candidate] = []
    first_failure = ""
    n_checked = 0
    for value, z in out.feasible[:CHECK_ITERATES]:
        if len(passed) >= KEEP_ITERATES or (passed and remaining() < 1.0):
            break
        n_checked += 1
        prof = as_written(profile_from_z(tr.grid, tr.scales, z, terrain=site.terrain))
        traj, bad = check(prof, rig, settings, site)
        if bad:
            first_failure = first_failure or bad[0]
            continue
        passed.append(Candidate("optimized", "optimized", prof, bad, model=value, rotation=cand.rotation_min(traj)))
    timings["check"] = time.perf_counter() - t0 - timings["start"] - timings["optimize"]

    # --- collect the worker's work: what it finishes while the budget lasts (less the time the
    # full evaluations below take), all of it when IPOPT finished early
    pending = [f for f in [worker.refs, worker.cobyla, *worker.chunks] if f is not None]
    if not cancelled:
        cf.wait(pending, timeout=max(remaining() - 0.6 * finish_reserve_s(budget), 0.0))
    refs: list[Candidate] = _result(worker.refs, 0.0) or []
    cob = _result(worker.cobyla, 0.0)
    chunks = [f for f in worker.chunks if f.done() and not f.cancelled()]
    randoms = [c for f in chunks for c in (_result(f, 0.0) or [])]
    worker.close()

    # --- score by the full evaluator what can win (most important first, while time lasts)
    pool: list[Candidate] = [cand.full(c, rig, crit) for c in passed]
    pool.extend(c for c in refs if c.feasible)
    start_c = next((c for c in refs + randoms if c.name == start.name), None)
    if start_c is None:
        start_c = Candidate(start.name, "start", start, check(start, rig, settings, site)[1])
    if start_c.feasible:  # always: the optimized drive is never worse than where it started
        pool.append(cand.full(start_c, rig, crit))
    cobc = None
    if cob is not None and cob["profile"] is not None and remaining() > 0:
        prof = as_written(cob["profile"])
        traj, bad = check(prof, rig, settings, site)
        cobc = Candidate("cobyla", "cobyla", prof, bad, model=cob["model"], rotation=cand.rotation_min(traj),
                         extra={"evaluations": cob["evaluations"]})
        if cobc.feasible:
            pool.append(cand.full(cobc, rig, crit))
    feas_random = sorted((c for c in randoms if c.feasible and c.model is not None), key=lambda c: -c.model)
    top_random = []
    for c in feas_random[:SCORE_RANDOM]:
        if remaining() > 0 or not pool:
            top_random.append(cand.full(c, rig, crit))
    pool.extend(top_random)
    # the LI-Init heuristic's pick: the candidate with the most rotation excitation
    heur = max((c for c in refs + randoms if c.feasible and c.rotation is not None),
               key=lambda c: c.rotation, default=None)
    if heur is not None and not heur.row and remaining() > 0:
        pool.append(cand.full(heur, rig, crit))
    if not pool:
        raise OptimizeError("no drive passed the limit and lot check (IPOPT: "
                            f"{out.ipopt_status}, {out.iterations} iterations"
                            + (f"; its best iterate: {first_failure}" if first_failure else "") + ")")
    best = max(pool, key=lambda c: (c.row["value"], c.kind == "optimized"))

    profile = ControlProfile(best.profile.t_s, best.profile.speed_mps, best.profile.curvature_1pm,
                             best.profile.grade_rad, best.profile.bank_rad, best.profile.start, name="optimized")
    traj = drive(profile, rig.suspension)
    rep = best.report if best.report is not None else evaluate(traj, rig)

    # --- the comparison
    rows: list[dict[str, Any]] = []

    def row(name: str, kind: str, c: Candidate | None, **extra: Any) -> None:
        if c is None:
            return
        r = {"name": name, "kind": kind, **c.row, "model_value": c.model, "rotation_excitation": c.rotation,
             "feasible": c.feasible, "violations": c.violations, "result": c is best, **c.extra, **extra}
        r.setdefault("score", None)
        rows.append(r)

    if passed:
        row("optimized", "optimized", max(passed, key=lambda c: c.row["value"]))
    else:
        rows.append({"name": "optimized", "kind": "optimized", "score": None, "feasible": False, "result": False,
                     "violations": [first_failure or f"IPOPT kept no feasible iterate ({out.ipopt_status})"]})
    for c in refs:
        row(c.name, "reference", c)
    if top_random:
        top = max(top_random, key=lambda c: c.row["value"])
        row(f"best of {len(randoms)} random", "random", top, candidate=top.name,
            scored=len(randoms), requested=settings.n_random)
    if cobc is not None:
        row("cobyla", "cobyla", cobc)
    if start_c.row:
        row(f"start ({start.name})", "start", start_c)
    if heur is not None and heur.row:
        row(f"LI-Init heuristic ({heur.name})", "heuristic", heur)
    for r in rows:
        s = r.get("score")
        r["ratio"] = (rep.score / s) if s else None
    rows.sort(key=lambda r: -(r.get("score") or 0.0))

    message = [start_note] if start_note else []
    if best.kind != "optimized":
        message.append(f"the result is {best.name} ({best.kind}): no IPOPT iterate that passed the check "
                       "was better")
    if first_failure:
        message.append(f"{n_checked - len(passed)} of {n_checked} checked IPOPT iterates failed the "
                       f"independent check, e.g. {first_failure}")
    if len(randoms) < settings.n_random:
        message.append(f"{len(randoms)} of {settings.n_random} random candidates were scored within the budget")
    timings["compare"] = time.perf_counter() - t0 - sum(timings.values())
    elapsed = time.perf_counter() - t0
    report(out.iterations, rep.score, 0.0, "done")  # the last word: the result's score
    return OptimizeResult(profile, traj, rep, rows, "cancelled" if cancelled else out.status, out.iterations,
                          elapsed, cancelled, model_score=float(out.score),
                          timings_s={k: round(v, 3) for k, v in timings.items()}, message="; ".join(message),
                          ipopt_status=out.ipopt_status, source=best.name if best.kind != "optimized" else "optimized",
                          criterion=crit, lot=site.outline())


