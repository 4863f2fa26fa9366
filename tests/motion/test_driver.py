"""The driver model: an exact driver drives the nominal path; a person's drives scatter as stated."""

from __future__ import annotations

import math

import numpy as np
import pytest

from excite.motion.course import Course, Leg, straight, trace, turn
from excite.motion.driver import DriverModel, course_of, drive_course
from excite.motion.vehicle import Limits, drive


def _course() -> Course:
    path = trace(straight(10) + turn(2 * math.pi, 0.1, 0.03) + straight(10) + turn(-2 * math.pi, 0.1, 0.03)
                 + straight(20))
    return Course((Leg(path, np.full(path.s_m.size, 7.0), dwell_s=2.0),))


def _deviation(course: Course, traj) -> np.ndarray:
    from scipy.spatial import cKDTree

    p = course.legs[0].path
    d, _ = cKDTree(p.xyz_m[:, :2]).query(traj.sample(traj.times(10.0)).p_W_V[:, :2])
    return d


def test_an_exact_driver_drives_the_nominal_path_and_time():
    lim, c = Limits(), _course()
    nominal = c.timed(lim, duration_s=60.0)
    driven = drive_course(c, lim, DriverModel.exact(), np.random.default_rng(0), duration_s=60.0)
    assert driven.profile.duration_s == pytest.approx(nominal.duration_s, abs=0.05)
    assert _deviation(c, drive(driven.profile)).max() < 0.1
    assert driven.leg_intervals[0][1] == pytest.approx(nominal.leg_intervals[0][1], abs=0.05)


def test_a_person_scatters_about_the_path_by_the_stated_amount():
    lim, c = Limits(), _course()
    rms, speeds = [], []
    nominal_speed = drive(c.timed(lim).profile).sample(np.linspace(5, 20, 50)).speed.mean()
    for i in range(12):
        d = drive_course(c, lim, DriverModel(), np.random.default_rng([7, i]), duration_s=60.0)
        traj = drive(d.profile)
        rms.append(float(np.sqrt(np.mean(_deviation(c, traj) ** 2))))
        speeds.append(traj.sample(np.linspace(5, 20, 50)).speed.mean() / nominal_speed)
    # lateral: the aim offset's σ 0.5 m and the lag, not metres more, not centimetres
    assert 0.15 < np.median(rms) < 1.2
    # speed: the per-leg bias (5 %) and fluctuation (3 %) spread the held speed by several per cent
    assert 0.02 < np.std(speeds) < 0.15


def _offset_response(model: DriverModel, speed_mps: float, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """The lateral position of a driver who starts 1 m left of a straight line along x, heading
    along it, at a constant ``speed_mps``, without delay or offset: the steering loop's curvature
    integrated as exact arcs (independently of the loop's own integration)."""
    from excite.motion.driver import STEP_S, _extended, _steer

    lim = Limits()
    p = _extended(trace(straight(speed_mps * seconds + 20.0)))
    n = int(round(seconds / STEP_S))
    kap, *_ = _steer(p.xyz_m[:, 0], p.xyz_m[:, 1], p.heading_rad, p.curvature_1pm, float(p.s_m[1] - p.s_m[0]),
                     np.zeros(p.s_m.size), np.full(n, speed_mps), STEP_S, 0.0, 1.0, 0.0, 0.0, 0, 0.0,
                     model.bandwidth_rad_s, model.damping_ratio, lim.curvature_max_1pm, lim.curvature_rate_max_1pms)
    y, h, ys = 1.0, 0.0, np.empty(n)
    for i, k in enumerate(kap):
        ys[i] = y
        dh = speed_mps * k * STEP_S
        y += speed_mps * STEP_S * (math.sin(h + dh / 2) * (1.0 if abs(dh) < 1e-12 else math.sin(dh / 2) / (dh / 2)))
        h += dh
    return STEP_S * np.arange(n), ys


def _second_order(t: np.ndarray, omega: float, zeta: float) -> np.ndarray:
    """ey'' + 2ζω ey' + ω² ey = 0 from ey = 1, ey' = 0 (ζ < 1)."""
    wd = omega * math.sqrt(1.0 - zeta * zeta)
    return np.exp(-zeta * omega * t) * (np.cos(wd * t) + zeta * omega / wd * np.sin(wd * t))


def test_the_steering_loop_removes_an_offset_as_its_documented_second_order_response():
    # the module docstring's natural frequency and damping (from the driver literature, not from
    # the code): at constant speed the curvature command is a lateral acceleration v²κ, so the
    # lateral error of a driver 1 m off a straight line decays as ey'' + 2ζω ey' + ω² ey = 0
    t, ey = _offset_response(DriverModel(), 10.0, 12.0)
    assert np.abs(ey - _second_order(t, 1.2, 0.7)).max() < 0.02
    # and the loop follows whatever natural frequency and damping it is given
    t, ey = _offset_response(DriverModel(bandwidth_rad_s=0.8, damping_ratio=0.5), 10.0, 12.0)
    assert np.abs(ey - _second_order(t, 0.8, 0.5)).max() < 0.02


def test_the_course_of_a_free_form_profile_drives_it_back():
    lim = Limits()
    c = _course()
    prof = c.timed(lim).profile
    back = course_of(prof)
    again = drive(back.timed(lim, margin=1.0).profile)
    orig = drive(prof)
    assert abs(again.length_m() - orig.length_m()) / orig.length_m() < 0.02


def test_bad_driver_parameters_are_refused():
    from excite.errors import LimitError

    with pytest.raises(LimitError, match="driver.reaction_s"):
        DriverModel(reaction_s=5.0)
    with pytest.raises(LimitError, match="lateral_sigma_m"):
        DriverModel(lateral_sigma_m=-1.0)
    with pytest.raises(LimitError, match="damping_ratio"):
        DriverModel(damping_ratio=0.0)
