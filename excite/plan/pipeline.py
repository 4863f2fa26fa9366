"""The optimization pipeline: never worse than what it has seen, within one time budget.

Within ``time_budget_s`` of wall time, all of it:

1. **start** (this process): the problem statement (:mod:`.problem`) and its transcription
   (:mod:`.transcription`; the information model compiled, :mod:`.compiled`); the reference
   maneuvers and the first random candidates (drawn while :data:`START_SHARE` of the budget
   lasts), each fitted to the splines and ranked by the optimizer's model; the
   :data:`~.settings.OptimizeSettings.starts` best of them are IPOPT's starts. How many cores
   are free is measured over this phase (:class:`_Cores`).
2. **optimize**: IPOPT from every start on the engine (:mod:`.multistart`: as many local
   processes as cores are free, or the Dask cluster), until each converges or the budget less
   the time kept for the checks (:func:`finish_reserve_s`) runs out.
3. **compare** (a worker process, *next to* IPOPT only when a core is left for it): the
   reference maneuvers scored by the full evaluator — once per problem, then read from the
   cache (:mod:`.candidates`) —, the random candidates screened chunk by chunk, and COBYLA from
   the best start (:data:`COBYLA_SHARE` of the budget). When no core is free the screen and
   COBYLA are skipped (the message says so) and only the references are scored, after IPOPT.
4. **check**: the best iterates of every start (by the model) go through the independent check
   (:func:`.candidates.check`, the same one every other candidate passed) until
   :data:`KEEP_ITERATES` passed; they, the start, COBYLA and the best screened random
   candidates are scored by the full evaluator.

The run ends when the starts are done and checked: the worker's unfinished work is dropped (the
comparison says how many random candidates were scored). The result is the best candidate by
the criterion among *all* that passed the check — an IPOPT iterate, or else whatever was
better (its ``source`` says which). The returned profile is the one that was checked, rounded as
the control CSV writes it.
"""

from __future__ import annotations

import os
import time
from typing import Any, Callable

import numpy as np

from ..core import processes
from ..errors import WorkerDied, WorkTimeout
from ..score.evaluate import evaluate
from ..rig.config import Rig
from ..motion.vehicle import ControlProfile, drive
from . import candidates as cand
from . import multistart
from .candidates import Candidate, as_written, check
from .kinematics import layout, profile_from_z, with_nodes, z_from_profile
from ..errors import OptimizeError
from .problem import Problem
from .settings import OptimizeResult, OptimizeSettings, Progress
from .solver import DEFAULT as SOLVER, model_value, restore
from .transcription import TranscriptionOptions, cached, violation

NEAR_FEASIBLE = 1.0  # largest violation of the optimizer's constraints of a start used as it is
START_RANDOM = 10  # random candidates (the first chunks) IPOPT's starts are chosen among, with the references
START_SHARE = 0.15  # of the budget, at most, for drawing them (a chunk is drawn only while it lasts)
CHUNK = 5  # random candidates per worker task (a finished chunk counts, an unfinished one not)
COBYLA_SHARE = 0.15  # of the budget, for the derivative-free baseline (in the worker)
CHECK_ITERATES = 15  # IPOPT iterates checked at most, best model value first ...
KEEP_ITERATES = 2  # ... until this many passed (each is then scored by the full evaluator)
SCORE_RANDOM = 2  # best screened random candidates scored by the full evaluator
TRANSCRIPTION = TranscriptionOptions()


def finish_reserve_s(budget_s: float) -> float:
    """Wall time kept after IPOPT for the checks, the full evaluations and the worker's results."""
    return 1.5 + 0.05 * budget_s


class _Cores:
    """How many cores are idle, measured from ``/proc/stat`` between :meth:`__init__` and
    :meth:`free` (the load average lags by a minute: a run right after another would see the
    first run's load). This process's own core counts as free. Elsewhere: from the load average."""

    def __init__(self) -> None:
        self.n = os.cpu_count() or 1
        self.t0, self.idle0 = time.monotonic(), self._idle_s()

    @staticmethod
    def _idle_s() -> float | None:
        try:
            with open("/proc/stat") as f:
                parts = f.readline().split()
            return (int(parts[4]) + int(parts[5])) / os.sysconf("SC_CLK_TCK")  # idle + iowait
        except (OSError, ValueError, IndexError):
            return None

    def free(self) -> int:
        idle1, dt = self._idle_s(), time.monotonic() - self.t0
        if self.idle0 is not None and idle1 is not None and dt >= 0.2:
            idle = (idle1 - self.idle0) / dt
        else:
            try:
                idle = self.n - os.getloadavg()[0]
            except OSError:
                idle = self.n - 1.0
        return int(min(max(round(idle + 1.0), 1), self.n))


class _Worker:
    """One process next to IPOPT for the comparison candidates (:class:`~excite.core.processes.Worker`,
    spawned: the caller may hold threads, and forking it would copy held locks). It runs its
    tasks in order: the references (when not cached), the random chunks, COBYLA."""

    def __init__(self, rig: Rig, settings: OptimizeSettings, site: Any, refs: bool):
        self.args = (rig, settings, site)
        self.worker = processes.Worker(context="spawn", name="excite-comparison")
        self.kinds: list[str] = []
        if refs:
            self._submit("refs", cand.references)

    def _submit(self, kind: str, fn: Callable[..., Any], *args: Any) -> None:
        self.worker.submit(fn, *self.args, *args)
        self.kinds.append(kind)

    def start_rest(self, z_start: np.ndarray, cobyla_s: float, n_random: int,
                   drawn: list[list[ControlProfile]]) -> None:
        """``drawn``: the first chunks' random profiles, already drawn as IPOPT's possible starts
        (sent along rather than drawn again)."""
        # the random candidates first: the comparison the result is held to; COBYLA last
        for c, (first, size) in enumerate(_chunks(n_random)):
            if c < len(drawn):
                self._submit("chunk", cand.screened, drawn[c])
            else:
                self._submit("chunk", cand.randoms, c, size, first)
        self._submit("cobyla", cand.cobyla, z_start, cobyla_s)

    def collect(self, until: float, refs_until: float) -> dict[str, Any]:
        """What the worker finished: the references by ``refs_until``, the rest by ``until``
        (time.monotonic()); a task that failed gives nothing, and the first not done in time
        ends the collection (and the worker)."""
        out: dict[str, Any] = {"refs": None, "chunk": [], "cobyla": None}
        for kind in self.kinds:
            try:
                value = self.worker.result(refs_until if kind == "refs" else until)
            except (WorkTimeout, WorkerDied):
                break
            except Exception:  # noqa: BLE001 — a comparison candidate that failed is no reason to withhold the result
                value = None
            if kind == "chunk":
                out["chunk"] += value or []
            else:
                out[kind] = value
        return out

    def close(self) -> None:
        """Drop the worker's unfinished work at once (its process and what it started end)."""
        self.worker.stop()


def _chunks(n_random: int) -> list[tuple[int, int]]:
    """(first index, size) of every chunk of random candidates (the first START_RANDOM are also
    IPOPT's possible starts)."""
    return [(first, min(CHUNK, n_random - first)) for first in range(0, n_random, CHUNK)]


def optimize(rig: Rig, settings: OptimizeSettings = OptimizeSettings(),
             progress: Callable[[Progress], None] | None = None,
             should_stop: Callable[[], bool] | None = None) -> OptimizeResult:
    """The best drive within ``settings`` that this run has seen (see the module docstring).

    ``progress`` is called after IPOPT's iterations and at each phase; when ``should_stop()``
    returns True, IPOPT stops, the worker's unfinished work is dropped and the best checked
    drive so far is returned (``cancelled=True``).
    """
    t0 = time.perf_counter()
    settings = settings.for_rig(rig)  # within the vehicle's own limits (a car's steering rate)
    budget = settings.time_budget_s
    stop = should_stop or (lambda: False)
    cores = _Cores()

    def report(it: int, s: float, v: float, phase: str) -> None:
        if progress is not None:
            progress(Progress(it, float(s), float(v), time.perf_counter() - t0, phase, budget))

    def remaining() -> float:
        return t0 + budget - time.perf_counter()

    report(0, float("nan"), float("nan"), "start")
    workers: list[_Worker] = []
    try:
        return _run(rig, settings, t0, report, remaining, stop, cores, workers.append)
    finally:
        for w in workers:  # also when the run raised or was interrupted
            w.close()


def prepare(rig: Rig, settings: OptimizeSettings) -> dict[str, Any]:
    """The start-up work that does not depend on the seed or the budget, done now and cached
    (``excite optimize --compile-only``, a Docker image's build step): the optimizer's model
    compiled (:func:`.transcription.prepare`) and the reference maneuvers scored by the full
    evaluator (:func:`.candidates.references`), unless the cache has them. Returns what was
    done: ``{"mode", "seconds": {step: s}, "references": "cached" | "scored"}``."""
    from .transcription import prepare as compile_model

    settings = settings.for_rig(rig)
    mode, seconds = compile_model(rig, settings)
    generated = cand.reference_profiles(rig, settings, settings.lot)
    if cand.cached_references(rig, settings, settings.lot, generated) is not None:
        return {"mode": mode, "seconds": seconds, "references": "cached"}
    t0 = time.perf_counter()
    cand.store_references(rig, settings, settings.lot, cand.references(rig, settings, settings.lot))
    return {"mode": mode, "seconds": {**seconds, "references": time.perf_counter() - t0}, "references": "scored"}


def rank_starts(tr, settings, site, crit, report, generated: list[Candidate],
                until: float = np.inf) -> tuple[list, list[list[ControlProfile]]]:
    """The candidates IPOPT may start from, best first (:func:`rank`), and the first chunks of
    random profiles drawn for it — each chunk only while
    ``time.perf_counter() < until`` (drawing a feasible random drive takes ~0.1 s, several times
    that on a loaded machine: under a tight budget the references alone are the starts)."""
    refs = [c.profile for c in generated if c.name != "highway_run"]
    drawn = []
    for c, (first, size) in enumerate(_chunks(settings.n_random)):
        if first >= START_RANDOM or (time.perf_counter() >= until and (refs or any(drawn))):
            break
        drawn.append(cand.random_profiles(tr.problem.rig, settings, site, c, size, first))
    return rank(tr, site, crit, refs + [p for chunk in drawn for p in chunk], report), drawn


def rank(tr, site, crit, profiles: list[ControlProfile], report=lambda *a: None) -> list:
    """``profiles`` as IPOPT's starts, best first: ``(near, score or −violation, −index, z,
    profile)`` — those that nearly satisfy the optimizer's constraints first, by the model."""
    lay = layout(tr.grid)
    ranked = []
    for i, c in enumerate(profiles):
        z = z_from_profile(tr.grid, tr.scales, c, terrain=site.terrain)
        if site.entry is not None:
            z[lay.pose] = [site.entry[0] / tr.scales.position_m, site.entry[1] / tr.scales.position_m,
                           site.entry[2]]
            z = with_nodes(tr.grid, tr.scales, z, site.terrain)
        v = violation(tr, z)
        s = model_value(tr, z, crit)
        near = v < NEAR_FEASIBLE
        ranked.append((near, s if near else -v, -i, z, c))
        report(0, s, v, "start")
    # the best by the model among the starts that nearly satisfy the optimizer's constraints
    # (with the small monotone barrier IPOPT regains feasibility within a few iterations and keeps
    # the excitation; a better start counts more than a feasible one: benchmarks/bench_ipopt.py)
    ranked.sort(key=lambda r: (r[0], r[1], r[2]), reverse=True)
    return ranked


def _run(rig, settings, t0, report, remaining, stop, cores: _Cores, keep_worker) -> OptimizeResult:
    budget = settings.time_budget_s
    site = settings.lot
    crit = settings.criterion
    timings: dict[str, float] = {}
    problem = Problem.of(rig, settings, site)
    tr = cached(problem, TRANSCRIPTION)
    notes = [tr.info.note] if tr.info.note else []
    timings["transcription"] = time.perf_counter() - t0
    generated = cand.reference_profiles(rig, settings, site)
    cached_refs = cand.cached_references(rig, settings, site, generated)
    ranked, drawn = rank_starts(tr, settings, site, crit, report, generated, until=t0 + START_SHARE * budget)
    if not ranked:
        raise OptimizeError("no reference maneuver or random candidate fits this lot and these limits "
                            "to start from")
    if not ranked[0][0]:  # e.g. every candidate starts elsewhere than the lot's entry: move to the nearest feasible
        z, restored = restore(tr, ranked[0][3], time.perf_counter() + 0.25 * remaining())
        ranked[0] = (True, model_value(tr, z, crit), ranked[0][2], z, ranked[0][4])
        notes.append(f"no candidate satisfied the optimizer's constraints: IPOPT started from {ranked[0][4].name} "
                     f"moved to the nearest drive that does ({restored})")
    free = cores.free()
    scheduler = multistart.engine.scheduler_address(settings.scheduler)
    # local starts run at once on the free cores (a start queued behind another would get what
    # is left of the budget); the cluster takes them all
    n_starts = settings.starts if scheduler is not None else min(settings.starts, free)
    starts = [r for r in ranked if r[0]][:n_starts] or ranked[:1]
    if len(starts) < settings.starts:
        notes.append(f"{len(starts)} of the {settings.starts} IPOPT starts asked for ran ({free} core"
                     f"{'s' if free != 1 else ''} free)")
    jobs = len(starts)
    spare = free - jobs if scheduler is None else free - 1
    timings["start"] = time.perf_counter() - t0 - timings["transcription"]

    # the comparison worker: next to IPOPT when a core is left for it; the references only
    # (after IPOPT, in this process) when none is and they are not cached
    worker = None
    compare = settings.comparison if settings.comparison is not None else spare >= 1
    if compare:
        worker = _Worker(rig, settings, site, refs=cached_refs is None)
        keep_worker(worker)
        worker.start_rest(starts[0][3], COBYLA_SHARE * budget, settings.n_random, drawn)
    elif settings.comparison is None:
        notes.append(f"no core was free for the random screen and COBYLA ({free} free for {jobs} IPOPT start"
                     f"{'s' if jobs != 1 else ''}): they were skipped")

    # --- optimize: every start on the engine
    deadline = time.time() + remaining() - finish_reserve_s(budget)
    tasks = [multistart.StartTask(problem, r[4].name, r[3], deadline, TRANSCRIPTION, SOLVER, settings.max_iterations)
             for r in starts]
    results = multistart.run(tasks, jobs, scheduler, progress=lambda it, s, v: report(it, s, v, "optimize"),
                             should_stop=stop)
    timings["optimize"] = time.perf_counter() - t0 - sum(timings.values())
    outcomes = [r.outcome for r in results if r.outcome is not None]
    cancelled = stop() or any(o.status == "cancelled" for o in outcomes)
    n_conv = sum(r.converged for r in results)
    errors = [f"{r.name}: {r.error}" for r in results if r.error]
    win = max(outcomes, key=lambda o: o.score, default=None)
    report(0 if win is None else win.iterations, -np.inf if win is None else win.score, 0.0, "check")

    # --- check the best iterates of every start independently, best first
    iterates = sorted(((v, z) for o in outcomes for v, z in o.feasible), key=lambda r: -r[0])
    passed: list[Candidate] = []
    first_failure = ""
    n_checked = 0
    for value, z in iterates[:CHECK_ITERATES]:
        if len(passed) >= KEEP_ITERATES or (passed and remaining() < 1.0):
            break
        n_checked += 1
        prof = as_written(profile_from_z(tr.grid, tr.scales, z, terrain=site.terrain))
        traj, bad = check(prof, rig, settings, site)
        if bad:
            first_failure = first_failure or bad[0]
            continue
        passed.append(Candidate("optimized", "optimized", prof, bad, model=value, rotation=cand.rotation_min(traj)))
    timings["check"] = time.perf_counter() - t0 - sum(timings.values())

    # --- collect the worker's finished work (a short grace: the checks ran meanwhile)
    refs: list[Candidate] = cached_refs or []
    cob, randoms = None, []
    if worker is not None:
        now = time.monotonic()
        wait = max(remaining() - 0.6 * finish_reserve_s(budget), 0.0) if settings.comparison and not cancelled else 0.0
        got = worker.collect(now + wait, now + max(wait, min(remaining() - 0.5 * finish_reserve_s(budget), 30.0)))
        if "refs" in worker.kinds:
            refs = got["refs"] or []
            cand.store_references(rig, settings, site, refs)
        cob, randoms = got["cobyla"], got["chunk"]
        worker.close()
    elif cached_refs is None and not cancelled:
        refs = cand.references(rig, settings, site)
        cand.store_references(rig, settings, site, refs)
    if not randoms:  # the random starts were screened by the model here: check them for the comparison
        for p in (p for chunk in drawn for p in chunk):  # (while the budget lasts)
            if remaining() <= 0:
                break
            c = Candidate(p.name, "random", p, [],
                          model=model_value(tr, z_from_profile(tr.grid, tr.scales, p, terrain=site.terrain), crit))
            traj, c.violations = check(c.profile, rig, settings, site)
            c.rotation = cand.rotation_min(traj)
            randoms.append(c)

    # --- score by the full evaluator what can win (most important first, while time lasts)
    pool: list[Candidate] = [cand.full(c, rig, crit) for c in passed]
    pool.extend(c for c in refs if c.feasible)
    start = starts[0][4]
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
        why = win.ipopt_status if win is not None else "; ".join(errors) or "no start ran"
        raise OptimizeError("no drive passed the limit and lot check (IPOPT: "
                            f"{why}, {0 if win is None else win.iterations} iterations"
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
        why = win.ipopt_status if win is not None else "no start ran"
        rows.append({"name": "optimized", "kind": "optimized", "score": None, "feasible": False, "result": False,
                     "violations": [first_failure or f"IPOPT kept no feasible iterate ({why})"]})
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

    message = list(notes)
    message.append(f"{n_conv} of {len(results)} IPOPT start{'s' if len(results) != 1 else ''} converged"
                   + (f" ({', '.join(errors)})" if errors else ""))
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
    statuses = [o.status for o in outcomes]
    if cancelled:
        status = "cancelled"
    elif results and n_conv == len(results):
        status = "converged"
    elif any(s == "time_budget" for s in statuses):
        status = "time_budget"
    elif win is not None:
        status = win.status
    else:
        status = "failed"
    report(0 if win is None else win.iterations, rep.score, 0.0, "done")  # the last word: the result's score
    return OptimizeResult(profile, traj, rep, rows, status, 0 if win is None else win.iterations,
                          elapsed, cancelled, model_score=float(-np.inf if win is None else win.score),
                          timings_s={k: round(v, 3) for k, v in timings.items()}, message="; ".join(message),
                          ipopt_status="" if win is None else win.ipopt_status,
                          source=best.name if best.kind != "optimized" else "optimized",
                          criterion=crit, lot=site.outline(), starts=len(results), starts_converged=n_conv,
                          compiled=tr.info.mode == "compiled")
