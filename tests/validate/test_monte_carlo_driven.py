"""A Monte Carlo whose trials each drive the plan differently: the statistics against each trial's
own drive, checked on errors drawn from known covariances; the machinery end to end on a short plan."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from excite.validate.monte_carlo import MonteCarloSettings, Trial, statistics_driven


@dataclass
class _P:
    name: str
    unit: str
    sigma: float


@dataclass
class _Report:
    information: np.ndarray
    parameters: list
    nullity: int = 0


@dataclass
class _Coord:
    name: str
    target: float
    nuisance: bool = False


class _Rig:
    def __init__(self, coords):
        self.coordinates = coords
        self.scored = [c for c in coords if not c.nuisance]


def test_errors_drawn_from_each_drives_own_covariance_pass_the_per_drive_nees_and_sigma():
    """Drives of different information (a person drives a plan differently every time): errors
    drawn from each drive's own Λᵢ⁻¹. The per-drive NEES mean lies in its interval and the RMS of
    the per-drive σ is each parameter's spread; one covariance for all (the nominal's) is not."""
    rng = np.random.default_rng(3)
    d, N = 3, 400
    coords = [_Coord(f"p{i}", 1.0) for i in range(d)]
    reports, trials = [], []
    for k in range(N):
        A = rng.normal(size=(d, d))
        scale = np.exp(rng.normal(0, 0.7, d))  # drives differ a lot
        L = A @ A.T + np.diag(scale * 3)
        C = np.linalg.inv(L)
        e = rng.multivariate_normal(np.zeros(d), C)
        reports.append(_Report(L, [_P(c.name, "m", math.sqrt(C[i, i])) for i, c in enumerate(coords)]))
        trials.append(Trial(k, e, e, "converged", "", 1, 0.0, 1, 0.0))
    nominal = reports[0]
    res = statistics_driven(reports, _Rig(coords), trials, MonteCarloSettings(runs=N), nominal)
    assert res.nees_consistent, (res.nees_mean, res.nees_interval)
    for i, p in enumerate(res.parameters):
        # mean of eᵢ² estimates mean σᵢ²; with different σᵢ its standard error is √(Σ 2σᵢ⁴)/N
        s2 = np.array([r.parameters[i].sigma ** 2 for r in reports])
        se = math.sqrt(np.sum(2 * s2 ** 2)) / N
        assert abs(p.empirical_sigma ** 2 - p.predicted_sigma ** 2) < 3 * se
    # against one drive's information the same errors are far off
    nees_one = np.mean([t.error @ nominal.information @ t.error for t in trials])
    assert not res.nees_interval[0] <= nees_one <= res.nees_interval[1]


@pytest.mark.montecarlo
@pytest.mark.slow
def test_a_driven_plan_goes_through_simulation_and_calibration():
    from excite.cli.validate import with_imu_rate
    from excite.motion.driver import DriverModel, drive_course
    from excite.motion.vehicle import Limits, drive
    from excite.plan.drivable.plan import DrivablePlan, Element, build
    from excite.rig.config import load_rig
    from excite.validate.monte_carlo import monte_carlo_driven
    from excite.validate.simulate import SimulationSettings

    rig = with_imu_rate(load_rig("robotaxi"), 50.0)
    plan = DrivablePlan((Element("figure_eight", dict(radius_m=7, spacing_m=17, speed_mps=8, laps=1,
                                                       stops_per_lap=2), (0.0, 0.0, 0.0)),), 30.0)
    built = build(plan, Limits())
    nominal = drive(built.timed().profile, rig.suspension)

    def drives(i):
        return drive(drive_course(built.course, Limits(), DriverModel(), np.random.default_rng([5, i]),
                                  duration_s=30.0).profile, rig.suspension)

    res = monte_carlo_driven(drives, rig, nominal, MonteCarloSettings(runs=2, simulation=SimulationSettings.model()))
    assert len(res.trials) == 2 and res.convergence_rate == 1.0
    assert all(p.predicted_sigma > 0 for p in res.parameters)
    # the prediction is the drives', not the nominal's
    nominal_sigma = {p.name: p.sigma for p in res.report.parameters}
    assert any(abs(p.predicted_sigma / nominal_sigma[p.name] - 1) > 1e-3 for p in res.parameters)
