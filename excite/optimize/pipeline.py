"""The optimization pipeline: start, optimize, baseline, re-score, compare."""

from __future__ import annotations

import time
from typing import Callable

from ..evaluate import evaluate
from ..maneuvers import Lot, random_candidates, reference_maneuvers, EDGE_MARGIN_M
from ..rig import Rig
from ..vehicle import check_limits, drive
from .settings import OptimizeResult, OptimizeSettings, Progress


def _lot(settings: OptimizeSettings) -> Lot:
    return Lot.rectangle(length_m=settings.lot_width_m, width_m=settings.lot_length_m)


def optimize(rig: Rig, settings: OptimizeSettings = OptimizeSettings(),
             progress: Callable[[Progress], None] | None = None,
             should_stop: Callable[[], bool] | None = None) -> OptimizeResult:
    """The drive within ``settings`` that maximises the rig's score (see the package docstring).

    ``progress`` is called after every optimizer iteration; when ``should_stop()`` returns True the
    best feasible drive found so far is returned promptly with ``cancelled=True``.
    """
    t0 = time.perf_counter()
    lot = _lot(settings)
    cands = reference_maneuvers(settings.duration_s, width_m=settings.lot_length_m,
                                length_m=settings.lot_width_m, limits=settings.limits)
    rows = []
    best = None
    for name, prof in cands.items():
        traj = drive(prof, rig.suspension)
        rep = evaluate(traj, rig)
        inside = bool(lot.contains(traj.sample(traj.times(5.0)).p_W_V).all()) or name == "highway_run"
        feasible = not check_limits(traj, settings.limits) and inside
        rows.append({"name": name, "kind": "reference", "score": rep.score, "feasible": feasible})
        if feasible and name != "highway_run" and (best is None or rep.score > best[2].score):
            best = (prof, traj, rep)
        if progress:
            progress(Progress(0, rep.score, 0.0, time.perf_counter() - t0, "start"))
        if should_stop and should_stop():
            break
    prof, traj, rep = best
    rows.sort(key=lambda r: -r["score"])
    return OptimizeResult(prof, traj, rep, rows, "start_only", 0, time.perf_counter() - t0, False)
