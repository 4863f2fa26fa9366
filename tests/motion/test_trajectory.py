"""Kinematic consistency of generated and real drives."""

from __future__ import annotations

import numpy as np
import pytest

from excite.io import routes
from excite.motion.vehicle import ControlProfile, Suspension, drive
from helpers import orientation_error_from_rates, specific_force_error, weave_drive

# Tolerances: orientation reproduced by integrating the body rate at 1 kHz within 1e-3 rad
# (0.06 deg) over the whole drive; specific force equal to Rᵀ(p̈ − g) from second differences of
# positions at 200 Hz within 1e-3 m/s² (generated) / 2e-2 m/s² (real drives, sharper features).


@pytest.mark.parametrize("suspension", [Suspension(), Suspension.rigid()], ids=["sprung", "rigid"])
def test_generated_drive_is_kinematically_consistent(suspension):
    traj = weave_drive(suspension)
    assert orientation_error_from_rates(traj) < 1e-3
    err, scale = specific_force_error(traj)
    assert err < 1e-3 and scale > 9.0


def test_circle_speed_and_yaw_rate_equal_the_controls():
    t = np.linspace(0.0, 20.0, 201)
    prof = ControlProfile(t_s=t, speed_mps=np.full(t.size, 6.0), curvature_1pm=np.full(t.size, 0.05))
    s = drive(prof, Suspension()).sample(np.linspace(1.0, 19.0, 50))
    np.testing.assert_allclose(s.speed, 6.0, atol=1e-6)
    np.testing.assert_allclose(s.yaw_rate, 0.3, atol=1e-6)
    # Steady cornering rolls the body outwards (to the right in a left turn): positive roll.
    assert np.all(s.specific_force_V[:, 1] > 0)


def test_generated_heading_is_the_trapezoid_integral_of_the_yaw_rate():
    """The heading of a generated drive at its grid times is the start heading plus the
    trapezoid-rule integral of speed × curvature, as scipy's ``cumulative_trapezoid`` computes it
    (excite integrates it with numpy so that scoring does not import scipy.integrate)."""
    from scipy.integrate import cumulative_trapezoid

    from excite.core import so3

    t = np.linspace(0.0, 12.0, 25)
    prof = ControlProfile(t_s=t, speed_mps=4.0 + np.sin(t), curvature_1pm=0.08 * np.cos(0.7 * t),
                          start=(0.0, 0.0, 0.4))
    traj = drive(prof, Suspension.rigid())
    grid = np.linspace(0.0, 12.0, 1201)  # the drive's 100 Hz integration grid
    c = prof.at(grid)
    want = 0.4 + cumulative_trapezoid(c["speed_mps"] * c["curvature_1pm"], grid, initial=0.0)
    yaw = so3.yaw_pitch_roll(traj.sample(grid).R_W_A)[:, 0]
    np.testing.assert_allclose(np.angle(np.exp(1j * (yaw - want))), 0.0, atol=1e-9)


@pytest.fixture(scope="module")
def real_drives(data_dir):
    return {
        "kitti": routes.read_kitti(data_dir / "kitti_00_poses.txt", data_dir / "kitti_00_times.txt"),
        "euroc": routes.read_euroc(data_dir / "euroc_v102_groundtruth.csv"),
        "utm": routes.read_tum(data_dir / "georeferenced_utm.tum"),
    }


@pytest.mark.parametrize("name", ["kitti", "euroc", "utm"])
def test_real_drive_is_kinematically_consistent(real_drives, name):
    traj = real_drives[name]
    # A 60 s window (the whole drive if shorter) keeps the dense integration fast.
    t0 = traj.t_start + 0.3 * traj.duration
    window = (t0, t0 + min(60.0, 0.5 * traj.duration))
    assert orientation_error_from_rates(traj, rate_hz=1000.0, window_s=window) < 1e-3
    err, _ = specific_force_error(traj, rate_hz=200.0, window_s=window)
    assert err < 2e-2


def test_kitti_vehicle_axes(real_drives):
    traj = real_drives["kitti"]
    s = traj.sample(traj.times(5.0))
    moving = np.linalg.norm(s.v_W, axis=1) > 2.0
    v_V = np.einsum("nji,nj->ni", s.R_W_V, s.v_W)[moving]
    # Forward along +x of V, hardly any sideways or vertical velocity.
    assert np.median(v_V[:, 0]) > 5.0 and np.all(v_V[:, 0] > 0)
    assert np.percentile(np.abs(v_V[:, 1:]), 95) < 1.0
    # z up: V's z axis stays within ~7 deg of the world's, gravity shows as +9.8 on V's z.
    assert np.all(s.R_W_V[:, 2, 2] > np.cos(np.radians(7.0)))
    assert np.median(s.specific_force_V[:, 2]) == pytest.approx(9.8, abs=0.2)
    # A 3.7 km drive in a plane: horizontal extent dwarfs the vertical one.
    assert np.ptp(s.p_W_V[:, 0]) > 300 and np.ptp(s.p_W_V[:, 2]) < 30
    assert traj.length_m() == pytest.approx(3720, rel=0.02)


def test_utm_is_recentred(real_drives):
    s = real_drives["utm"].sample(np.array([real_drives["utm"].t_start]))
    assert real_drives["utm"].t_start == 0.0
    assert np.abs(s.p_W_V).max() < 1.0


def test_segment_index_equals_a_binary_search():
    """The compiled segment lookup (a walk along the breaks while the times increase) gives
    numpy's binary search, clipped to the segments, for increasing, decreasing and random times,
    times on the breaks and times outside them."""
    from excite.motion import kernels

    rng = np.random.default_rng(3)
    for trial in range(60):
        breaks = np.unique(np.round(rng.uniform(0.0, 10.0, rng.integers(2, 40)), 1 if trial % 2 else 6))
        if breaks.size < 2:
            breaks = np.array([0.0, 1.0])
        t = np.concatenate([rng.uniform(-1.0, 11.0, 50), breaks, breaks[::-1]])
        for times in (t, np.sort(t), np.sort(t)[::-1].copy()):
            ref = np.clip(np.searchsorted(breaks, times, side="right") - 1, 0, breaks.size - 2)
            np.testing.assert_array_equal(kernels.segments(breaks, times), ref)


def test_the_imu_sampled_four_at_a_time_is_each_sample_taken_alone():
    """The compiled IMU sampling takes four samples at once (vectors of their numbers, the same
    arithmetic): every sample is bit for bit the one taken alone, at a dense and a sparse rate, with
    a lever arm and a tilted mounting, and the samples left over past the last four."""
    traj = weave_drive(Suspension())
    R_V_B = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]) @ np.array(
        [[1.0, 0.0, 0.0], [0.0, np.cos(0.1), -np.sin(0.1)], [0.0, np.sin(0.1), np.cos(0.1)]])
    p_V_B = np.array([1.2, -0.3, 0.8])
    for rate in (200.0, 3.0):
        t = traj.times(rate)[:4 * 9 + 3]
        together = traj.imu(t, R_V_B, p_V_B)
        alone = [traj.imu(t[i:i + 1], R_V_B, p_V_B) for i in range(t.size)]
        for q, got in enumerate(together):
            assert np.abs(got).max() > 0
            np.testing.assert_array_equal(got, np.concatenate([a[q] for a in alone]))


def test_threads_sampling_the_imu_at_once_build_the_acceleration_polynomial_once(monkeypatch):
    """The evaluator's two sweeps sample a fresh drive's IMU at the same moment: the acceleration's
    piecewise polynomial (a lazily built part of the trajectory) is built once, not once per
    thread. The conversion is slowed down here so that both threads ask while it runs."""
    import threading
    import time

    from excite.motion import trajectory

    traj = weave_drive(Suspension())
    calls = []
    real = trajectory.PPoly.from_spline

    class SlowPPoly:
        @staticmethod
        def from_spline(spline):
            calls.append(threading.get_ident())
            time.sleep(0.05)
            return real(spline)

    monkeypatch.setattr(trajectory, "PPoly", SlowPPoly)
    both = threading.Barrier(2)
    out = []

    def sample():
        both.wait()
        out.append(traj.imu(traj.times(50.0), np.eye(3), np.zeros(3)))

    threads = [threading.Thread(target=sample) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(calls) == 3  # one per axis, by one thread
    np.testing.assert_array_equal(out[0][2], out[1][2])
