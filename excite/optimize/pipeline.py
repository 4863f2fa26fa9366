"""The optimization pipeline: start, optimize, baseline, re-score with the full evaluator, compare.

The time budget covers the *optimization* (problem statement, start selection, IPOPT). The
comparison that follows (the COBYLA baseline with the same budget as IPOPT used, the full
evaluator on every reference maneuver and random candidate) is extra; cancelling skips it.
"""

from __future__ import annotations

import time
from typing import Any, Callable

import numpy as np

from ..errors import LimitError
from ..evaluate import evaluate
from ..maneuvers import EDGE_MARGIN_M, REFERENCE_MANEUVERS, Lot, random_candidates
from ..rig import Rig
from ..vehicle import ControlProfile, check_limits, drive
from . import baselines
from .kinematics import profile_from_z, z_from_profile
from .settings import OptimizeError, OptimizeResult, OptimizeSettings, Progress
from .solver import score, solve_softmin, transcribe, violation

START_RANDOM = 20  # random candidates considered as starts (the comparison scores all n_random)
_FINISH_S = 2.0  # kept from the budget for turning the result into a drive


def lot_of(settings: OptimizeSettings) -> Lot:
    """The settings' lot: ``lot_x_m`` along x, ``lot_y_m`` along y, centred."""
    return Lot.rectangle(length_m=settings.lot_x_m, width_m=settings.lot_y_m)


def feasibility(traj, settings: OptimizeSettings, lot: Lot | None = None) -> list[str]:
    """Every limit and lot violation of a drive, by code independent of the optimizer
    (:func:`~excite.vehicle.check_limits` and point-in-polygon on the path at 20 Hz)."""
    out = [str(v) for v in check_limits(traj, settings.limits)]
    lot = lot_of(settings) if lot is None else lot
    p = traj.sample(traj.times(20.0)).p_W_V
    inside = lot.contains(p)
    if not inside.all():
        k = int(np.argmin(inside))
        out.append(f"lot: the path leaves the lot at t={traj.times(20.0)[k]:.2f} s "
                   f"(x={p[k, 0]:.1f} m, y={p[k, 1]:.1f} m)")
    return out


def _references(settings: OptimizeSettings) -> dict[str, ControlProfile]:
    """Every reference maneuver that fits the lot and the limits."""
    out = {}
    for name, gen in REFERENCE_MANEUVERS.items():
        try:
            if name == "highway_run":
                out[name] = gen(settings.duration_s, limits=settings.limits)
            else:
                out[name] = gen(settings.duration_s, width_m=settings.lot_y_m,
                                length_m=settings.lot_x_m, limits=settings.limits)
        except LimitError:
            continue
    return out


def _randoms(settings: OptimizeSettings, rig: Rig, n: int) -> list[ControlProfile]:
    if n <= 0:
        return []
    try:
        return random_candidates(n, settings.duration_s, lot_of(settings), settings.limits,
                                 seed=settings.seed, suspension=rig.suspension)
    except LimitError:
        return []


def optimize(rig: Rig, settings: OptimizeSettings = OptimizeSettings(),
             progress: Callable[[Progress], None] | None = None,
             should_stop: Callable[[], bool] | None = None) -> OptimizeResult:
    """The drive within ``settings`` that maximises the rig's score (see the package docstring).

    ``progress`` is called after every optimizer iteration (and during the comparison); when
    ``should_stop()`` returns True the best feasible drive found so far is returned promptly,
    with ``cancelled=True`` and only the reference maneuvers in the comparison.
    """
    t0 = time.perf_counter()
    stop = should_stop or (lambda: False)
    timings: dict[str, float] = {}

    def report(it: int, s: float, v: float, phase: str) -> None:
        if progress is not None:
            progress(Progress(it, float(s), float(v), time.perf_counter() - t0, phase))

    lot = lot_of(settings)
    half_x = 0.5 * settings.lot_x_m - EDGE_MARGIN_M
    half_y = 0.5 * settings.lot_y_m - EDGE_MARGIN_M
    if min(half_x, half_y) < 5.0:
        raise OptimizeError(f"a {settings.lot_x_m:g} × {settings.lot_y_m:g} m lot leaves less than "
                            f"5 m either side of the centre inside its {EDGE_MARGIN_M:g} m edge margin")
    tr = transcribe(rig, settings.duration_s, settings.limits, half_x, half_y, settings.closed)

    # --- start: the best reference maneuver or random candidate by the optimizer's model
    refs = _references(settings)
    starts = [p for n, p in refs.items() if n != "highway_run"]
    starts += _randoms(settings, rig, min(START_RANDOM, settings.n_random))
    ranked = []
    for i, prof in enumerate(starts):
        z = z_from_profile(tr.grid, tr.scales, prof)
        ranked.append((score(tr, z), -violation(tr, z), i, z, prof))
        report(0, ranked[-1][0], -ranked[-1][1], "start")
    if not ranked:
        raise OptimizeError("no reference maneuver or random candidate fits this lot and these limits")
    # prefer starts that nearly satisfy the optimizer's constraints; among those the best score
    # (a little over a limit or the lot's inner edge: IPOPT restores that)
    near = [r for r in ranked if -r[1] < 1.0] or ranked
    near.sort(key=lambda r: (-r[0], r[2]))
    start_score, _, _, z_start, start_prof = near[0]
    timings["start"] = time.perf_counter() - t0

    # --- optimize (multi-start when the budget allows about 40 s per start)
    deadline = t0 + settings.time_budget_s - _FINISH_S
    n_starts = max(1, min(len(near), int((deadline - time.perf_counter()) // 40.0)))
    best_z, best_s, iterations, status = None, -np.inf, 0, "start_only"
    t_opt = time.perf_counter()
    for k in range(n_starts):
        if stop():
            break
        share = (deadline - time.perf_counter()) / (n_starts - k)
        out = solve_softmin(tr, near[k][3], time.perf_counter() + share, should_stop=stop, t_start=t0,
                    progress=lambda it, s, v, el, base=iterations: report(base + it, s, v, "optimize"))
        iterations += out.iterations
        if out.z is not None and out.score > best_s:
            best_z, best_s, status = out.z, out.score, out.status
        if out.status == "cancelled":
            status = "cancelled"
            break
    ipopt_s = time.perf_counter() - t_opt
    timings["optimize"] = ipopt_s
    cancelled = stop()
    if cancelled:
        status = "cancelled"

    # --- the result as a drive, checked independently
    message = ""
    profile, traj = None, None
    if best_z is not None:
        profile = profile_from_z(tr.grid, tr.scales, best_z)
        traj = drive(profile, rig.suspension)
        bad = feasibility(traj, settings, lot)
        if bad:
            message = "optimized drive failed the independent check (" + "; ".join(bad) + "); returned the start"
            profile = None
    if profile is not None and evaluate(traj, rig).score < evaluate(drive(start_prof, rig.suspension), rig).score:
        # cut short before it got past its start (e.g. cancelled early): the start is better
        message = message or "the optimizer had not improved on its start; returned the start"
        profile = None
    if profile is None:
        profile, best_s = start_prof, start_score
        traj = drive(profile, rig.suspension)
        if status != "cancelled":
            status = "start_only"
    profile = ControlProfile(profile.t_s, profile.speed_mps, profile.curvature_1pm, profile.grade_rad,
                             profile.bank_rad, profile.start, name="optimized")
    traj = drive(profile, rig.suspension)
    report_full = evaluate(traj, rig)
    timings["result"] = time.perf_counter() - t0 - timings["start"] - ipopt_s

    # --- comparison, re-scored by the full evaluator
    rows: list[dict[str, Any]] = []

    def row(name: str, kind: str, prof: ControlProfile, model: float | None = None) -> dict[str, Any]:
        tj = drive(prof, rig.suspension)
        bad = feasibility(tj, settings, lot) if kind != "reference" or name != "highway_run" \
            else [str(v) for v in check_limits(tj, settings.limits)]
        r = {"name": name, "kind": kind, "score": evaluate(tj, rig).score, "model_score": model,
             "feasible": not bad, "violations": bad}
        rows.append(r)
        return r

    rows.append({"name": "optimized", "kind": "optimized", "score": report_full.score, "model_score": best_s,
                 "feasible": not feasibility(traj, settings, lot), "violations": feasibility(traj, settings, lot)})
    for name, prof in refs.items():
        row(name, "reference", prof)
    t_cmp = time.perf_counter()
    if not cancelled:
        row(f"start ({start_prof.name})", "start", start_prof, start_score)
        zc, sc_, nev = baselines.cobyla(tr, z_start, max(ipopt_s, 1.0), should_stop=stop,
                                        progress=lambda n, s: report(n, s, 0.0, "baseline") if n % 20 == 0 else None)
        if zc is not None:
            r = row("cobyla", "cobyla", profile_from_z(tr.grid, tr.scales, zc, name="cobyla"), sc_)
            r["evaluations"] = nev
        else:
            rows.append({"name": "cobyla", "kind": "cobyla", "score": 0.0, "model_score": None,
                         "feasible": False, "violations": ["no feasible point found"], "evaluations": nev})
        timings["baseline"] = time.perf_counter() - t_cmp
        best_rand = None
        for i, prof in enumerate(_randoms(settings, rig, settings.n_random)):
            if stop():
                cancelled = True
                break
            s = evaluate(drive(prof, rig.suspension), rig).score
            if best_rand is None or s > best_rand[0]:
                best_rand = (s, prof)
            report(i + 1, s, 0.0, "rescore")
        if best_rand is not None:
            r = row(f"best of {settings.n_random} random", "random", best_rand[1])
            r["candidate"] = best_rand[1].name
    best_score = report_full.score
    for r in rows:
        r["ratio"] = (best_score / r["score"]) if r["score"] > 0 else None
    rows.sort(key=lambda r: -r["score"])
    timings["compare"] = time.perf_counter() - t_cmp
    elapsed = time.perf_counter() - t0
    report(iterations, best_s, 0.0, "done")
    return OptimizeResult(profile, traj, report_full, rows, status, iterations, elapsed, cancelled,
                          model_score=float(best_s), timings_s={k: round(v, 3) for k, v in timings.items()},
                          message=message)
