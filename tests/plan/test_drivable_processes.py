"""The drivable search's element sets and robust choice run side by side in supervised workers
(excite.core.processes): every worker ends with the search — stopped early, interrupted or done —
and what a worker computes is what the same call computes in the search's own process."""

from __future__ import annotations

import os
from multiprocessing import resource_tracker
from dataclasses import replace
from pathlib import Path

import pytest

from excite.core import processes
from excite.plan.drivable.elements import MARGIN
from excite.plan.drivable.plan import build, plan_from_dict
from excite.plan.drivable.robust import robust_scores
from excite.plan.drivable.search import DrivableSettings, Scorer, optimize_drivable
from excite.plan.settings import vehicle_limits
from excite.rig.config import load_rig

SETTINGS = DrivableSettings(duration_s=60.0, max_elements=3, draws=5, time_budget_s=24.0, workers=2, seed=3)


def _below() -> set[int]:
    """The processes below this one; multiprocessing's resource tracker (one per interpreter, for
    its life, started with the first spawned process) is started first so that it is among them."""
    resource_tracker.ensure_running()
    return set(processes.descendants(os.getpid()))


def _alive(pids: set[int]) -> set[int]:
    def state(pid: int) -> str:
        try:
            return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return "gone"
    return {p for p in pids if state(p) not in ("Z", "X", "gone")}


class _Watch:
    """The progress callback: the supervised workers seen in each phase; ``interrupt`` raises
    KeyboardInterrupt in the refinement once both its workers are seen; :meth:`stop` stops the
    refinement once two of its three element sets are done."""

    def __init__(self, interrupt: bool = False):
        self.interrupt = interrupt
        self.seen: dict[str, set[int]] = {}
        self.sets_done = 0

    def __call__(self, p) -> None:
        self.seen.setdefault(p.phase, set()).update(w.pid for w in processes.running("excite-worker"))
        if p.phase == "refine" and p.detail.endswith("element sets done"):
            self.sets_done = int(p.detail.split("/")[0])
            if self.interrupt and len(self.seen["refine"]) == 2:
                raise KeyboardInterrupt

    def stop(self) -> bool:
        return self.sets_done >= 2  # of 3: the third one's worker still running


@pytest.mark.slow
def test_a_search_stopped_in_its_refinement_ends_every_worker_and_its_robust_choice_is_the_in_process_one():
    rig = load_rig("robotaxi")
    before = _below()
    watch = _Watch()
    res = optimize_drivable(rig, SETTINGS, progress=watch, should_stop=watch.stop)
    # both parallel phases ran in supervised workers, and none is left
    assert len(res.design) == 3 and len(res.rows) >= 2, (res.design, res.rows)  # sets to refine, plans to choose from
    assert len(watch.seen["refine"]) == 2 and watch.seen["robust"], watch.seen
    assert _below() <= before and not _alive(watch.seen["refine"] | watch.seen["robust"])
    # the chosen plan's quantile over the choosing drivers, computed in a worker, equals the same
    # seeded drives scored here
    limits = vehicle_limits(rig, SETTINGS.limits)
    limits_plan = replace(limits, speed_max_mps=MARGIN * limits.speed_max_mps / MARGIN)  # as the search's
    chosen = next(r for r in res.rows if r["chosen"])
    here = robust_scores(build(plan_from_dict(res.plan.to_dict()), limits_plan).course, rig, limits_plan, SETTINGS.draws, chosen["score"],
                         SETTINGS.seed, SETTINGS.driver, duration_s=SETTINGS.duration_s, quantile=SETTINGS.quantile,
                         evaluate=Scorer(rig, None))
    assert chosen["score_quantile"] == pytest.approx(here.low, rel=1e-12)


@pytest.mark.slow
def test_a_search_interrupted_in_its_refinement_leaves_no_process():
    before = _below()
    watch = _Watch(interrupt=True)
    with pytest.raises(KeyboardInterrupt):
        optimize_drivable(load_rig("robotaxi"), SETTINGS, progress=watch)
    assert len(watch.seen["refine"]) == 2
    assert _below() <= before and not _alive(watch.seen["refine"])
