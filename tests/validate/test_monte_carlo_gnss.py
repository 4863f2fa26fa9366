"""A rig with a GNSS antenna in the simulator and the calibrator: the antenna is recovered from
noise-free data, and a Monte Carlo on a planned drive has its NEES in its interval.

A GNSS antenna breaks the gauge (world position and yaw are observed): every consumer closes its
drives through :mod:`excite.information.closure` (world states with the drive's origin, no gauge,
the first fix opening the error's chain), and each must agree with the evaluator.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2
from excite.motion.maneuvers import figure_eight
from excite.motion.vehicle import drive
from excite.score.evaluate import evaluate
from helpers import gnss_rig, sigmas


@pytest.fixture(scope="module")
def rig():
    return gnss_rig(lidar=True)


@pytest.fixture(scope="module")
def traj(rig):
    return drive(figure_eight(40.0), rig.suspension)


def test_the_simulator_and_calibrator_recover_the_antenna(rig, traj):
    from excite.validate.calibrate import calibrate, initialise
    from excite.validate.simulate import Calibration, SimulationSettings, simulate

    r = rig.with_constant_biases()
    sigma = sigmas(evaluate(traj, r))
    nominal = Calibration.nominal(r)
    delta = np.zeros(len(r.coordinates))
    delta[r.index("gnss.trans_x")] = 0.05  # 5 targets
    delta[r.index("gnss.time_offset")] = 0.004
    truth = nominal.plus(r, delta)
    data = simulate(traj, r, truth, np.random.default_rng(4), SimulationSettings.model())
    assert data.recorded["gnss"].z.shape == (data.n_keyframes, 3)
    init = initialise(data, r, nominal, data.truth.R[0], data.truth.p[0])
    res = calibrate(data, r, init.calibration, init.states)
    assert res.converged, res.reason
    assert 0.7 < res.residual_rms["gnss"] < 1.3  # its whitened (differenced) residuals are its noise
    for key, name in (("trans", "gnss.trans_x"), ("time_offset", "gnss.time_offset")):
        got = res.calibration.vector("gnss", "trans")[0] if key == "trans" else res.calibration.scalar("gnss", key)
        want = truth.vector("gnss", "trans")[0] if key == "trans" else truth.scalar("gnss", key)
        assert abs(got - want) < 4 * sigma[name], (name, got - want, sigma[name])


@pytest.mark.slow
@pytest.mark.montecarlo
def test_monte_carlo_on_a_planned_drive_with_gnss_is_consistent():
    """40 trials on a planned figure-eight over undulating ground with an RTK-class antenna whose
    error is correlated over 5 s (simulated as a Gauss–Markov process, calibrated with the
    differenced factor): the mean NEES in its 99 % chi-square interval and no parameter's
    empirical σ off the predicted beyond chance. Model data (the estimator's own assumptions)."""
    from excite.validate.monte_carlo import MonteCarloSettings, monte_carlo
    from excite.validate.simulate import SimulationSettings
    from helpers import hilly

    rig = gnss_rig(tau=5.0, lidar=True)
    data = rig.config.model_dump()
    data["imu"]["update_rate"] = 100  # coarse and cheap, as test_validate's
    from excite.rig.config import build_rig

    rig = build_rig(data)
    traj = drive(hilly(figure_eight(20.0)), rig.suspension)
    n = 40
    res = monte_carlo(traj, rig, MonteCarloSettings(runs=n, seed=27, simulation=SimulationSettings.model()))
    assert res.report.nullity == 0 and res.failures == 0, res.stop_reasons
    d = res.dof
    lo, hi = chi2.ppf(0.005, n * d) / n, chi2.ppf(0.995, n * d) / n
    assert lo <= res.nees_mean <= hi, (res.nees_mean, lo, hi)
    # per parameter: empirical/predicted σ within its 99 % chi-square range (Bonferroni over d)
    a = 0.01 / d
    rlo, rhi = np.sqrt(chi2.ppf(a / 2, n) / n), np.sqrt(chi2.ppf(1 - a / 2, n) / n)
    gnss = {p.name: p.ratio for p in res.parameters if p.name.startswith("gnss")}
    assert len(gnss) == 4 and all(rlo <= r <= rhi for r in gnss.values()), (gnss, rlo, rhi)
