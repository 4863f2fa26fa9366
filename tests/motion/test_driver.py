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
