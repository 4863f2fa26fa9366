"""The optimizer plans a car within its steering: the curvature (the optimizer's input, which the
steering reads through the bicycle model) changes no faster than the steering wheel may turn
(``ackermann.steering.rate_max_deg_per_s``), so the curvature-rate limit is the vehicle's."""

from __future__ import annotations

import math

import numpy as np
import pytest

from excite.motion.vehicle import ControlProfile, Limits, drive
from excite.plan import pipeline
from excite.plan.settings import OptimizeSettings, vehicle_limits
from excite.rig.config import load_rig


@pytest.fixture(scope="module")
def sedan():
    return load_rig("sedan")


def _through_straight(rate_1pms: float) -> ControlProfile:
    """At 6 m/s, the curvature swung from −0.1 to +0.1 1/m as a tanh whose steepest slope, driving
    straight (κ = 0 at t = 10 s), is ``rate_1pms``."""
    t = np.arange(0.0, 20.0 + 1e-9, 0.05)
    tau = 0.1 / rate_1pms
    return ControlProfile(t, np.full_like(t, 6.0), 0.1 * np.tanh((t - 10.0) / tau))


def test_the_curvature_rate_limit_turns_the_steering_wheel_at_its_limit(sedan):
    """Driven at the derived limit, the steering wheel (the bicycle model's reading
    ratio·atan(L·ψ̇/u) of the drive's own yaw rate and speed, differentiated numerically) turns at
    the rig's rate when driving straight and never faster."""
    limit = OptimizeSettings().for_rig(sedan).limits.curvature_rate_max_1pms
    ac = sedan.config.ackermann
    assert limit < Limits().curvature_rate_max_1pms  # the sedan's steering is the tighter limit
    traj = drive(_through_straight(limit), sedan.suspension)
    t = np.arange(2.0, 18.0, 0.005)
    s = traj.sample(t)
    steering_deg = np.degrees(ac.steering.ratio * np.arctan(ac.wheelbase_m * s.yaw_rate / s.speed))
    rate = np.abs(np.gradient(steering_deg, t))
    assert rate.max() <= 1.01 * ac.steering.rate_max_deg_per_s, rate.max()
    assert rate.max() >= 0.97 * ac.steering.rate_max_deg_per_s, rate.max()


def test_the_check_refuses_a_drive_the_steering_cannot_follow(sedan):
    """A curvature rate within the generic limit (0.25 1/(m·s)) but beyond the sedan's steering is
    refused by the optimizer's check with the vehicle's limits, and only with them."""
    from excite.plan.candidates import check

    generic = OptimizeSettings()
    prof = _through_straight(0.245)
    assert not check(prof, sedan, generic, generic.lot)[1]
    problems = check(prof, sedan, generic.for_rig(sedan), generic.lot)[1]
    assert problems and all(p.startswith("curvature_rate_max_1pms") for p in problems), problems


def test_the_tighter_limit_wins_and_other_rigs_keep_theirs(sedan):
    tight = Limits(curvature_rate_max_1pms=0.1)
    assert vehicle_limits(sedan, tight) == tight
    derived = vehicle_limits(sedan, Limits())
    ac = sedan.config.ackermann
    assert derived.curvature_rate_max_1pms == pytest.approx(
        math.radians(540.0) / (15.0 * 2.7), rel=1e-12)  # the bundled rig's 540 deg/s, ratio 15, L 2.7 m
    assert derived == Limits(curvature_rate_max_1pms=math.radians(ac.steering.rate_max_deg_per_s)
                             / (ac.steering.ratio * ac.wheelbase_m))
    for name in ("robotaxi",):
        assert vehicle_limits(load_rig(name), Limits()) == Limits()
    no_rate = sedan.with_config(ackermann=dict(sedan.config.ackermann.model_dump(),
                                               steering=dict(ac.steering.model_dump(), rate_max_deg_per_s=None)))
    assert vehicle_limits(no_rate, Limits()) == Limits()


def test_optimize_plans_within_the_vehicles_limits(sedan, monkeypatch):
    """``optimize`` hands its run (the transcription, the starts, the comparison worker and the
    checks are all made from these settings) the vehicle's limits (the run itself stubbed: this
    is about what it is given)."""
    seen = {}

    def run(rig, settings, *args):
        seen["run"] = settings
        return "result"

    monkeypatch.setattr(pipeline, "_run", run)
    assert pipeline.optimize(sedan, OptimizeSettings()) == "result"
    want = vehicle_limits(sedan, Limits()).curvature_rate_max_1pms
    assert want < Limits().curvature_rate_max_1pms  # the sedan's steering is the tighter limit
    assert seen["run"].limits.curvature_rate_max_1pms == want


def test_a_steering_rate_out_of_range_is_a_clear_error(sedan):
    from excite.errors import RigError
    from excite.rig.config import build_rig

    data = sedan.config.model_dump()
    data["ackermann"]["steering"]["rate_max_deg_per_s"] = 50_000
    with pytest.raises(RigError) as e:
        build_rig(data)
    assert "ackermann.steering.rate_max_deg_per_s: 50000" in str(e.value) and "sane range" in str(e.value)


def test_a_steering_too_slow_to_plan_with_names_the_rigs_setting(sedan):
    """1 deg/s at the wheel, ratio 100, a 20 m wheelbase (each within its own range): the curvature
    may change by 8.7e-6 1/(m·s), below what a plan needs; the error names the rig's setting, not
    the planner's derived limit."""
    from excite.errors import OptimizeError

    ac = sedan.config.ackermann
    slow = sedan.with_config(ackermann=dict(ac.model_dump(), wheelbase_m=20.0,
                                            steering=dict(ac.steering.model_dump(), ratio=100.0, rate_max_deg_per_s=1.0)))
    with pytest.raises(OptimizeError) as e:
        vehicle_limits(slow, Limits())
    msg = str(e.value)
    assert msg.startswith("ackermann.steering.rate_max_deg_per_s: 1 deg/s at ratio 100 and wheelbase 20 m"), msg
    assert "8.73e-06" in msg
