"""Courses of clothoid pieces: exact turns, the connector, the timed drive."""

from __future__ import annotations

import math

import numpy as np
import pytest

from excite.motion.course import Course, Leg, bulb, connect, end_pose, length_of, straight, trace, turn
from excite.motion.vehicle import Limits, check_limits, drive


@pytest.mark.parametrize("delta", [0.3, math.pi / 2, math.pi, 2 * math.pi, -5.0])
def test_a_turn_turns_by_its_angle_with_continuous_bounded_curvature(delta):
    pieces = turn(delta, 0.12, 0.05)
    assert sum(p.turn_rad for p in pieces) == pytest.approx(delta, abs=1e-12)
    path = trace(pieces)
    assert path.heading_rad[-1] - path.heading_rad[0] == pytest.approx(delta, abs=1e-9)
    assert np.abs(path.curvature_1pm).max() <= 0.12 + 1e-12
    # curvature continuous: its steps between samples bounded by the sharpness
    assert np.abs(np.diff(path.curvature_1pm)).max() <= 0.05 * (path.s_m[1] - path.s_m[0]) * 1.0001
    assert path.curvature_1pm[0] == 0 and abs(path.curvature_1pm[-1]) < 1e-12


def test_a_quarter_circle_without_clothoids_ends_where_geometry_says():
    # an infinitely sharp clothoid is an arc: radius 10 m, 90° left from the origin heading east
    pieces = turn(math.pi / 2, 0.1, 1e9)
    x, y, h = end_pose(pieces)
    assert (x, y, h) == pytest.approx((10.0, 10.0, math.pi / 2), abs=1e-6)
    p = trace(pieces, step_m=0.01)
    assert p.xyz_m[-1, :2] == pytest.approx([10.0, 10.0], abs=1e-4)


@pytest.mark.parametrize("b", [(30.0, 10.0, 0.5), (-20.0, 5.0, 2.0), (5.0, 0.0, 0.0), (0.0, 40.0, -math.pi)])
def test_connect_reaches_the_pose(b):
    pieces = connect((1.0, 2.0, 0.3), b, 0.12, 0.05)
    assert pieces is not None
    x, y, h = end_pose(pieces, (1.0, 2.0, 0.3))
    assert (x, y) == pytest.approx(b[:2], abs=1e-6)
    assert math.remainder(h - b[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    # the traced path agrees with the exact end
    p = trace(pieces, (1.0, 2.0, 0.3), step_m=0.05)
    assert np.hypot(*(p.xyz_m[-1, :2] - b[:2])) < 0.01


def test_bulb_returns_to_its_start_facing_back():
    x, y, h = end_pose(bulb(0.13, 0.05))
    assert (x, y) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert h == pytest.approx(math.pi, abs=1e-12)


def test_a_timed_course_stays_within_the_limits_and_lasts_its_duration():
    lim = Limits()
    path = trace(straight(10) + turn(2 * math.pi, 0.1, 0.03) + straight(15))
    speed = np.full(path.s_m.size, 7.0)
    speed[path.s_m.size // 2] = 0.0  # a stop half way
    c = Course((Leg(path, speed, dwell_s=2.0), Leg(trace(straight(20), (path.xyz_m[-1, 0], path.xyz_m[-1, 1],
                                                                       path.heading_rad[-1])), np.full(201, 5.0))))
    timed = c.timed(lim, duration_s=60.0)
    assert timed.duration_s == pytest.approx(60.0, abs=0.06)
    traj = drive(timed.profile)
    assert not check_limits(traj, lim)
    # the drive follows the path: its end where the path ends
    end = traj.sample(np.array([traj.t_end])).p_W_V[0, :2]
    assert np.hypot(*(end - c.legs[-1].path.xyz_m[-1, :2])) < 0.3
    assert length_of(straight(3.0)) == 3.0
