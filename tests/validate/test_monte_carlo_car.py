"""The car's kinds through the simulator and the calibrator: noise-free data calibrates to the
truth, and a Monte Carlo on a car drive (four CAN wheels, steering, a radar) has its NEES in its
interval. The 60-s planned drive of the README (examples/sedan_planned_60s_control.csv, 100
trials in the physical simulator) is the long version of the last test."""

from __future__ import annotations

import numpy as np
import pytest

from excite.motion.vehicle import ControlProfile, drive
from excite.rig.config import load_rig
from excite.score.evaluate import evaluate
from excite.validate.calibrate import calibrate, initialise
from excite.validate.monte_carlo import MonteCarloSettings, monte_carlo
from excite.validate.simulate import Calibration, SimulationSettings, simulate


@pytest.fixture(scope="module")
def rig():
    r = load_rig("sedan")
    return r.with_config(imu=dict(r.config.imu.model_dump(), update_rate=100))


@pytest.fixture(scope="module")
def traj(rig):
    """25 s from rest to rest: speeds to 8 m/s, turns both ways, a slope."""
    t = np.linspace(0.0, 25.0, 26)
    speed = 7 * np.sin(np.pi * t / 25) ** 2 + 1.5 * np.sin(t / 2) * np.sin(np.pi * t / 25)
    return drive(ControlProfile(t, np.maximum(speed, 0.0), 0.1 * np.sin(t / 2.5), grade_rad=0.04 * np.sin(t / 6)),
                 rig.suspension)


def test_noise_free_data_calibrates_to_the_truth(rig, traj):
    sigma = {p.name: p.sigma for p in evaluate(traj, rig.with_constant_biases()).parameters}
    nominal = Calibration.nominal(rig)
    delta = np.zeros(len(rig.coordinates))
    for name, x in (("wheel.scale_fl", 0.004), ("wheel.track_rear", 0.03), ("wheel.wheelbase", -0.03),
                    ("steering.ratio", 0.3), ("steering.offset", np.radians(0.3)), ("wheel.time_offset", 0.004),
                    ("radar_front.rot_z", np.radians(0.5)), ("radar_front.trans_y", 0.05)):
        delta[rig.index(name)] = x
    truth = nominal.plus(rig, delta)
    data = simulate(traj, rig, truth, np.random.default_rng(0), SimulationSettings.model(noise=False))
    init = initialise(data, rig, nominal, data.truth.R[0], data.truth.p[0])
    res = calibrate(data, rig, init.calibration, init.states)
    assert res.converged, res.reason
    err = res.calibration.minus(truth, rig)
    for i, c in enumerate(rig.coordinates):
        if not c.nuisance:
            assert abs(err[i]) < 0.05 * sigma[c.name], (c.name, err[i], sigma[c.name])


@pytest.mark.slow
@pytest.mark.montecarlo
def test_monte_carlo_on_a_car_drive_is_consistent(rig, traj):
    """24 trials in the model's own data: the empirical errors have the predicted covariance
    (NEES in its 95 % interval) and every trial converges."""
    res = monte_carlo(traj, rig, MonteCarloSettings(runs=24, seed=1, simulation=SimulationSettings.model()))
    assert res.failures == 0
    assert res.report.nullity == 0
    assert res.nees_interval[0] <= res.nees_mean <= res.nees_interval[1], (res.nees_mean, res.nees_interval)
    ratios = {p.name: p.ratio for p in res.parameters}
    for n in ("wheel.scale_rl", "wheel.wheelbase", "steering.ratio", "steering.offset", "wheel.time_offset",
              "radar_front.rot_z"):
        assert 0.5 < ratios[n] < 1.6, (n, ratios[n])
