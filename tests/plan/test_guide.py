"""Live guidance that follows a drivable plan: the element being driven and the next, and a drive
that skips the second half of its plan gets a proposal that reaches the goal in simulation where
the plan's own remainder does not."""

from __future__ import annotations

import numpy as np
import pytest

from excite.motion.vehicle import ControlProfile, Limits, drive
from excite.plan.drivable.guide import PlanStream, concatenated, end_pose
from excite.plan.drivable.plan import DrivablePlan, Element, build
from excite.rig.config import load_rig
from excite.score.evaluate import evaluate

LIM = Limits()


def _plan(laps: int, promise: float | None = None) -> DrivablePlan:
    return DrivablePlan((Element("slalom", dict(spacing_m=16.3, cones=2, offset_m=1.5, speed_mps=13.5, laps=laps,
                                                mirror=0, stops_per_lap=0), (0.0, -5.0, 0.0)),), 90.0,
                        name="slalom", expected_score=promise)


def _poses(traj, t0: float, t1: float, rate_hz: float = 10.0):
    t = np.arange(t0, t1, 1.0 / rate_hz)
    s = traj.sample(t)
    return t, s.p_W_V, s.R_W_V


def _standstill(profile: ControlProfile, seconds: float) -> ControlProfile:
    n = int(seconds * 20)
    t = np.concatenate([profile.t_s, profile.t_s[-1] + 0.05 * np.arange(1, n + 1)])
    z = np.zeros(n)
    return ControlProfile(t, np.concatenate([profile.speed_mps, z]),
                          np.concatenate([profile.curvature_1pm, z + profile.curvature_1pm[-1]]), start=profile.start)


@pytest.fixture(scope="module")
def rig():
    return load_rig("robotaxi")


def test_a_drive_that_skips_the_second_half_gets_a_proposal_that_reaches_the_goal(rig):
    """The plan: three laps of a slalom, promising 80 % of its score as instructed. The driver
    drives one lap and stops (skipping the rest). The guide says which element is being driven,
    sees it left after one of three laps, and proposes what to repeat; driven after the first lap
    (the drive simulated end to end and scored by the full evaluator), the proposal reaches the
    goal and the plan's own remainder (nothing: the driver has passed it) does not."""
    full = build(_plan(3), LIM)
    nominal = evaluate(drive(full.timed().profile, rig.suspension), rig).score
    plan = _plan(3, promise=0.8 * nominal)
    skipped = build(_plan(1), LIM)  # what the driver does: one lap, then a stop
    so_far = _standstill(skipped.course.timed(LIM, 0.9).profile, 12.0)
    traj = drive(so_far, rig.suspension)

    stream = PlanStream(rig, plan, LIM, cutoff_hz=np.inf)
    events = []
    for a in np.arange(0.0, traj.t_end, 1.0):
        events += stream.add(*_poses(traj, a, min(a + 1.0, traj.t_end)))
    kinds = [e["type"] for e in events]
    assert kinds[0] == "element" and events[0]["element"] == 1 and "Slalom" in events[0]["instruction"]
    short = [e for e in events if e["type"] == "element_short"]
    assert short and short[0]["laps_planned"] == 3 and 0.7 < short[0]["laps_done"] < 1.3
    proposals = [e for e in events if e["type"] == "proposal"]
    assert len(proposals) == 1
    prop = proposals[0]
    assert prop["remainder"] and prop["remainder"][0]["element"] == 1
    assert prop["predicted_score"] >= prop["goal"] > prop["predicted_score_original"]

    # simulate both remainders after the drive so far, end to end, by the full evaluator
    here = end_pose(so_far, rig)
    rest = stream.guide.remainder_plan([(r["element"] - 1, r["laps"]) for r in prop["remainder"]], here, 200.0)
    rest_profile = build(rest, LIM).course.timed(LIM, 0.9).profile
    with_proposal = evaluate(drive(concatenated(so_far, rest_profile), rig.suspension), rig).score
    original = evaluate(traj, rig).score  # the plan has nothing left after its only element
    assert with_proposal >= plan.expected_score > original, (with_proposal, plan.expected_score, original)


def test_the_guide_names_the_next_element(rig):
    plan = DrivablePlan((Element("circles", dict(radius_m=8, speed_mps=6, laps=1), (-20.0, 0.0, 0.0)),
                         Element("circles", dict(radius_m=8, speed_mps=6, laps=1, mirror=1), (20.0, 0.0, 0.0))),
                        90.0, name="two circles")
    built = build(plan, LIM)
    traj = drive(built.timed().profile, rig.suspension)
    stream = PlanStream(rig, plan, LIM, cutoff_hz=np.inf)
    events = []
    for a in np.arange(0.0, traj.t_end, 1.0):
        events += stream.add(*_poses(traj, a, min(a + 1.0, traj.t_end)))
    els = [e for e in events if e["type"] == "element"]
    assert [e["element"] for e in els] == [1, 2]
    assert els[0]["next"]["element"] == 2 and els[1]["next"] is None
    assert [e["type"] for e in events if e["type"].startswith("element_")] == ["element_done", "element_done"] or \
        [e["type"] for e in events if e["type"].startswith("element_")] == ["element_done"]
