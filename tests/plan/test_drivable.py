"""Drivable plans: elements, the plan as data, its cones read back and driven, bad input, the design."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from excite.errors import OptimizeError
from excite.motion.vehicle import Limits, check_limits, drive
from excite.plan.drivable.design import e_design, lambda_min, repetitions
from excite.plan.drivable.elements import KINDS, MARGIN, Slalom, kind, turning_radius_m
from excite.plan.drivable.plan import (DrivablePlan, Element, build, cones_geojson, plan_from_dict, read_cones,
                                       violations)
from excite.plan.site import Site

LIM = Limits()
SITE = Site.rectangle(110, 80)


def _plan() -> DrivablePlan:
    """One element of every kind, placed by the layout search in a 110 × 80 m lot."""
    from excite.plan.drivable.search import layout

    els = [Element("figure_eight", dict(radius_m=7, spacing_m=18, speed_mps=8, laps=1, mirror=0, stops_per_lap=2),
                   (0.0, 0.0, 0.0), 2.0),
           Element("slalom", dict(spacing_m=13, cones=2, offset_m=1.8, speed_mps=9, laps=1, mirror=1,
                                  stops_per_lap=1), (0.0, 0.0, 0.0), 0.0),
           Element("circles", dict(radius_m=7, speed_mps=7, laps=1, mirror=1, stops_per_lap=1), (0.0, 0.0, 0.0), 0.0),
           Element("straight_run", dict(length_m=25, speed_mps=12, laps=1, mirror=0), (0.0, 0.0, 0.0), 1.0)]
    placed = layout(els, LIM, SITE, np.random.default_rng(0))
    assert placed is not None
    return DrivablePlan(tuple(placed), 200.0, name="test plan")


@pytest.mark.parametrize("name", list(KINDS))
def test_every_element_ends_where_it_ended_with_one_lap_so_laps_change_nothing_around_it(name):
    space = {p.name: (p.lo + p.hi) / 2 if not p.integer else p.lo for p in kind(name).space(LIM, 70.0)}
    ends = []
    for laps in (1, 3):
        g = kind(name).geometry({**space, "laps": laps}, LIM)
        ends.append(g.end)
        # and it leaves heading the way it came in (the next transit starts straight)
        assert math.remainder(g.end[2] - g.start[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-6)
    assert ends[0][:2] == pytest.approx(ends[1][:2], abs=0.02)


def test_a_plan_round_trips_through_json_and_builds_within_the_limits_and_lot():
    plan = _plan()
    again = plan_from_dict(json.loads(json.dumps(plan.to_dict())))
    assert again.to_dict() == plan.to_dict()
    built = build(again, LIM)
    timed = built.timed()
    assert timed.duration_s <= plan.duration_s + 0.05
    assert not violations(built, timed, SITE)
    traj = drive(timed.profile)
    assert not check_limits(traj, LIM)
    assert len(built.instructions) == 4 and len(built.cones) == 4 + 4 + 2 + 3  # 8, slalom, circles, run
    assert [c.label for c in built.cones] == [str(i + 1) for i in range(len(built.cones))]


@pytest.mark.parametrize("origin", [None, (11.5, 48.1)])
def test_the_cone_layout_read_back_is_passed_on_the_side_the_instructions_say(tmp_path, origin):
    """Every cone, read back from the GeoJSON layout, is passed on the side the instructions give
    and never closer than 1 m (half a car and a little), by the drive the instructions describe."""
    built = build(_plan(), LIM)
    path = tmp_path / "cones.geojson"
    path.write_text(json.dumps(cones_geojson(built, origin)))
    cones = read_cones(path)
    assert len(cones) == len(built.cones)
    if origin is not None:  # the lon/lat and the lot metres agree
        from excite.plan.site import Projection

        doc = json.loads(path.read_text())
        ll = np.array([f["geometry"]["coordinates"] for f in doc["features"] if f["properties"]["role"] == "cone"])
        xy = Projection(origin).to_local(ll)
        assert np.abs(xy - [[c.x, c.y] for c in cones]).max() < 0.01
    timed = built.timed()
    traj = drive(timed.profile)
    checked = 0
    for c in cones:
        side = c.sides[0]
        t0, t1 = timed.leg_intervals[built.element_legs[c.element]]
        t = np.linspace(t0, t1, int((t1 - t0) * 20) + 1)
        s = traj.sample(t)
        rel = np.array([c.x, c.y]) - s.p_W_V[:, :2]
        d = np.linalg.norm(rel, axis=1)
        moving = s.speed > 0.5
        k = int(np.argmin(np.where(moving, d, np.inf)))
        heading = s.v_W[k, :2] / np.linalg.norm(s.v_W[k, :2])
        cross = heading[0] * rel[k, 1] - heading[1] * rel[k, 0]
        assert d[k] > 1.0, f"cone {c.label} is run over ({d[k]:.2f} m)"
        assert ("left" if cross > 0 else "right") == side, f"cone {c.label} ({c.role}) on the wrong side"
        checked += 1
    assert checked == len(cones)
    # the instructions say the same sides: the slalom's first cone on the left (mirrored)
    kinds = [e.kind for e in built.plan.elements]
    assert "first cone on your left" in built.instructions[kinds.index("slalom")]
    eight = built.cones[[c.element for c in built.cones].index(kinds.index("figure_eight"))].label
    assert f"clockwise around {eight}, counter-clockwise around {int(eight) + 1}" in \
        built.instructions[kinds.index("figure_eight")]


def test_bad_plans_are_refused_naming_the_limit():
    r = turning_radius_m(LIM)
    with pytest.raises(OptimizeError, match="turning radius"):
        kind("circles").geometry(dict(radius_m=0.5 * r, speed_mps=5, laps=1), LIM)
    with pytest.raises(OptimizeError, match="cone spacing .* below twice the vehicle's turning radius"):
        kind("figure_eight").geometry(dict(radius_m=r, spacing_m=1.5 * r, speed_mps=5, laps=1), LIM)
    d_min = Slalom.min_spacing_m(2.0, LIM)
    with pytest.raises(OptimizeError, match="cone spacing .* below .* turning radius"):
        kind("slalom").geometry(dict(spacing_m=0.8 * d_min, cones=3, offset_m=2.0, speed_mps=5, laps=1), LIM)
    with pytest.raises(OptimizeError, match="speed limit"):
        kind("straight_run").geometry(dict(length_m=30, speed_mps=LIM.speed_max_mps, laps=1), LIM)
    doc = _plan().to_dict()
    doc["elements"][0]["params"]["laps"] = "many"
    with pytest.raises(OptimizeError, match=r"elements\[0\]\.params\.laps must be a finite number"):
        plan_from_dict(doc)
    doc["elements"][0]["params"]["laps"] = 1
    doc["elements"][0]["params"]["radius_m"] = 5
    with pytest.raises(OptimizeError, match=r"elements\[0\]\.params: unknown radius_m"):
        plan_from_dict(doc)
    doc = _plan().to_dict()
    doc["elements"][1]["kind"] = "donut"
    with pytest.raises(OptimizeError, match=r"elements\[1\]\.kind must be one of"):
        plan_from_dict(doc)


def test_a_lot_too_small_for_any_element_is_refused():
    from excite.plan.drivable.search import DrivableSettings, optimize_drivable
    from excite.rig.config import load_rig

    with pytest.raises(OptimizeError, match="too small for any element"):
        optimize_drivable(load_rig("robotaxi"), DrivableSettings(lot_x_m=16, lot_y_m=16, time_budget_s=5))


def test_a_speed_above_the_lots_safe_speed_is_refused():
    from excite.plan.drivable.search import DrivableSettings, optimize_drivable, safe_speed_mps
    from excite.rig.config import load_rig

    site = Site.rectangle(40, 30)
    safe, straight_m = safe_speed_mps(site, LIM)
    # the longest straight inside the 3 m margin is the diagonal of 34 × 24 m
    assert straight_m == pytest.approx(math.hypot(34, 24), rel=0.05)
    a, b = MARGIN * LIM.accel_max_mps2, MARGIN * LIM.decel_max_mps2
    assert safe == pytest.approx(math.sqrt(2 * straight_m * a * b / (a + b)), rel=1e-9)
    with pytest.raises(OptimizeError, match="above the lot's safe speed"):
        optimize_drivable(load_rig("robotaxi"), DrivableSettings(site=site, speed_max_mps=safe + 1, time_budget_s=5))


def test_the_e_design_finds_the_analytic_optimum():
    """Two elements each strong in one direction and a dominated third: the best time split gives
    both directions the same information, λ = T·(1 + 0.1)/2."""
    rates = [np.diag([1.0, 0.1]), np.diag([0.1, 1.0]), np.diag([0.3, 0.3])]
    d = e_design(rates, 10.0)
    assert d.value == pytest.approx(5.5, rel=1e-3)
    assert d.weights[:2] == pytest.approx([0.5, 0.5], abs=0.01)
    # with what is known already, the time goes where it is missing
    d = e_design(rates, 10.0, prior=np.diag([0.0, 6.0]))
    assert d.value == pytest.approx(lambda_min(np.diag([0.0, 6.0]) + 10 * (d.weights[0] * rates[0]
                                                                           + d.weights[1] * rates[1]
                                                                           + d.weights[2] * rates[2])))
    assert d.weights[0] > 0.7


def test_repetitions_fit_the_time():
    from excite.plan.drivable.design import Candidate

    cands = [Candidate("circles", {}, np.eye(2), 20.0), Candidate("circles", {}, np.eye(2), 13.0)]
    reps = repetitions(cands, np.array([0.6, 0.4]), 75.0)
    assert sum(n * cands[i].duration_s for i, n in reps) <= 75.0
    assert 75.0 - sum(n * cands[i].duration_s for i, n in reps) < 13.0


def test_the_sheet_is_drawn_within_two_seconds():
    import time

    from excite.plan.drivable.sheet import sheet

    built = build(_plan(), LIM)
    sheet(built, SITE, "png")  # fonts and matplotlib's first use
    for fmt, magic in (("png", b"\x89PNG"), ("pdf", b"%PDF")):
        t0 = time.process_time()
        data = sheet(built, SITE, fmt)
        assert time.process_time() - t0 < 2.0
        assert data.startswith(magic)


def test_the_search_scores_a_plan_as_its_document_states_it():
    """A plan is scored in its written form (poses to 1 mm and 0.001°, parameters to six decimals),
    so the plan handed over, read back from its document, builds and drives as scored: a plan placed
    between those steps, as the search's continuous variables place it, could otherwise turn
    infeasible when read back (a transit that fitted by less than the rounding)."""
    from excite.plan.drivable.search import score_plan
    from excite.rig.config import load_rig

    plan = _plan()
    rng = np.random.default_rng(3)
    off = plan.with_elements([Element(e.kind, e.params, (e.pose[0] + rng.uniform(-4e-4, 4e-4),
                                                        e.pose[1] + rng.uniform(-4e-4, 4e-4),
                                                        e.pose[2] + rng.uniform(-7e-6, 7e-6)), e.dwell_s)
                              for e in plan.elements])
    assert plan_from_dict(off.to_dict()) != off
    scored = score_plan(off, load_rig("robotaxi"), LIM, SITE)
    assert scored.penalty == 0
    assert plan_from_dict(json.loads(json.dumps(scored.plan.to_dict()))) == scored.plan
