"""Reference maneuvers and random candidates stay within the limits and the lot."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from excite.motion import maneuvers
from excite.io import references, routes
from excite.errors import LimitError
from excite.motion.maneuvers import REFERENCE_MANEUVERS, Lot
from excite.motion.vehicle import Limits, Suspension, check_limits, drive
from helpers import REPO

TRAJECTORIES = REPO / "trajectories"


@pytest.fixture(scope="module")
def reference():
    return maneuvers.reference_maneuvers(90.0)


@pytest.mark.parametrize("name", list(REFERENCE_MANEUVERS))
def test_reference_maneuver_is_feasible(reference, name):
    prof = reference[name]
    assert prof.name == name
    assert prof.duration_s == pytest.approx(90.0, abs=0.05)
    traj = drive(prof, Suspension())
    assert check_limits(traj, Limits()) == []
    s = traj.sample(traj.times(10.0))
    assert s.speed[0] == pytest.approx(0.0, abs=1e-3) and s.speed[-1] == pytest.approx(0.0, abs=0.05)
    if name != "highway_run":
        assert Lot.rectangle(80, 50).contains(s.p_W_V, margin_m=1.0).all()


def test_maneuvers_do_what_their_names_say(reference):
    def sample(name):
        traj = drive(reference[name])
        return traj.sample(traj.times(10.0))

    assert np.all(sample("circle_left").yaw_rate >= -1e-6)
    assert np.all(sample("circle_right").yaw_rate <= 1e-6)
    highway = sample("highway_run")
    assert np.abs(highway.p_W_V[:, 1]).max() < 1e-6 and highway.p_W_V[-1, 0] > 1000
    for name in ("figure_eight", "slalom"):
        r = sample(name).yaw_rate
        assert r.min() < -0.1 and r.max() > 0.1
    stops = sample("stop_and_go").speed
    moving = stops > 0.5
    assert np.sum(moving[1:] & ~moving[:-1]) >= 5  # at least five drive-offs


def test_tighter_limits_are_respected():
    limits = Limits(speed_max_mps=6.0, accel_max_mps2=1.5, decel_max_mps2=2.0, jerk_max_mps3=3.0,
                    lat_accel_max_mps2=2.0)
    for gen in (maneuvers.slalom, maneuvers.stop_and_go, maneuvers.figure_eight):
        prof = gen(60.0, limits=limits)
        assert check_limits(drive(prof), limits) == []


def test_too_small_a_lot_is_refused():
    with pytest.raises(LimitError, match="too small"):
        maneuvers.figure_eight(60.0, width_m=30.0, length_m=40.0)


def test_lot_contains():
    lot = Lot(np.array([[0, 0], [10, 0], [10, 10], [5, 4], [0, 10]]))  # not convex
    pts = np.array([[1, 1], [5, 6], [9.5, 9], [-1, 1], [5, 3.9]])
    assert lot.contains(pts).tolist() == [True, False, True, False, True]
    assert lot.contains(np.array([[1, 1]]), margin_m=2.0).tolist() == [False]


def test_random_candidates_are_feasible_and_seeded():
    lot = Lot(np.array([[0, 0], [70, 0], [80, 40], [10, 50]]))
    limits = Limits()
    a = maneuvers.random_candidates(3, 60.0, lot, limits, seed=7)
    b = maneuvers.random_candidates(3, 60.0, lot, limits, seed=7)
    for pa, pb in zip(a, b):
        np.testing.assert_array_equal(pa.speed_mps, pb.speed_mps)
        traj = drive(pa)
        assert check_limits(traj, limits) == []
        assert lot.contains(traj.sample(traj.times(10.0)).p_W_V).all()
        assert pa.duration_s == pytest.approx(60.0, abs=0.05)
    c = maneuvers.random_candidates(3, 60.0, lot, limits, seed=8)
    assert not np.array_equal(a[0].speed_mps, c[0].speed_mps)


def _table(path: Path) -> np.ndarray:
    """The numbers of a TUM or control CSV file (comments and the CSV header skipped)."""
    if path.suffix == ".csv":
        return np.loadtxt(path, delimiter=",", comments="#", skiprows=3, ndmin=2)
    return np.loadtxt(path, comments="#", ndmin=2)


def test_committed_reference_files_are_regenerated(tmp_path):
    """The files in trajectories/ equal what ``python -m excite.io.references --write`` makes."""
    written = references.write_reference_files(tmp_path)
    assert len(written) == 2 * len(REFERENCE_MANEUVERS)
    for path in written:
        committed = TRAJECTORIES / path.name
        assert committed.exists(), f"{committed} missing: run python -m excite.io.references --write trajectories/"
        # the header too: the TUM files stand for logs, unmarked (read_tum smooths them as logs)
        assert path.read_text().splitlines()[0] == committed.read_text().splitlines()[0], path.name
        new, old = _table(path), _table(committed)
        assert new.shape == old.shape, path.name
        np.testing.assert_allclose(new, old, atol=1e-5, err_msg=path.name)


def test_reference_files_read_back(reference):
    traj = routes.read_route(TRAJECTORIES / "circle_left_control.csv")
    assert traj.duration == pytest.approx(90.0, abs=0.05)
    assert check_limits(traj, Limits()) == []
    tum = routes.read_route(TRAJECTORIES / "circle_left.tum")
    assert tum.length_m() == pytest.approx(traj.length_m(), rel=0.01)
