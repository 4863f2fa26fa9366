"""Monte Carlo in a scene: the simulated lidar pairs carry the registration error the scene's
information predicts, the road plane the error of its fit, and the calibrator weighs both as the
evaluator does; the empirical σ then match the predicted ones (where the scene changes them most:
the lidar's height, which planar driving leaves to the road in view)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.stats import chi2

from excite.motion.maneuvers import figure_eight
from excite.motion.vehicle import Suspension, drive
from excite.rig.config import RIGS_DIR, build_rig
from excite.scene import shapes
from excite.scene.along import seen
from excite.scene.model import Scene
from excite.score.evaluate import evaluate
from excite.validate.monte_carlo import MonteCarloSettings, monte_carlo
from excite.validate.simulate import SimulationSettings

STREET = Scene.combine([shapes.ground(-150, -150, 150, 150), shapes.wall((-150, 40), (150, 40), 6.0),
                        shapes.wall((150, -40), (-150, -40), 6.0)])


def _rig():
    data = yaml.safe_load((RIGS_DIR / "robotaxi.yaml").read_text())
    data["imu"]["update_rate"] = 100  # coarse and cheap; the models hold at any rate
    data["vehicle"]["suspension"] = {"pitch_deg_per_mps2": 0.0, "roll_deg_per_mps2": 0.0}  # planar: no tilt
    return build_rig(data)


@pytest.mark.slow
@pytest.mark.montecarlo
def test_monte_carlo_in_a_street_matches_the_prediction():
    """A planar figure-eight between two walls along x: scene-blind, the lidar's height and the
    camera's are unobservable; in the street the road sets the lidar's to millimetres. 40 trials
    (the model simulator): every observable parameter's empirical/predicted σ within its
    Bonferroni interval (n·(RMS/σ)² ~ χ²(n)), the mean NEES within its 99 % interval, and the
    lidar's height among them."""
    rig = _rig()
    traj = drive(figure_eight(20.0), Suspension.rigid())
    blind = {p.name: p.sigma for p in evaluate(traj, rig).parameters}
    assert blind["lidar.trans_z"] is None  # planar driving, no road in view: undetermined
    street = seen(traj, rig, STREET)
    n = 40
    res = monte_carlo(street, rig, MonteCarloSettings(runs=n, seed=21, simulation=SimulationSettings.model()))
    assert res.failures == 0
    z = next(p for p in res.parameters if p.name == "lidar.trans_z")
    assert z.predicted_sigma is not None and z.predicted_sigma < 0.005  # the road's 5 mm per patch, and better
    observable = [p for p in res.parameters if p.ratio is not None]
    a = 0.01 / len(observable)
    lo, hi = np.sqrt(chi2.ppf(a / 2, n) / n), np.sqrt(chi2.ppf(1 - a / 2, n) / n)
    ratios = {p.name: round(p.ratio, 3) for p in observable}
    assert all(lo <= r <= hi for r in ratios.values()), ratios
    nlo, nhi = chi2.ppf(0.005, n * res.dof) / n, chi2.ppf(0.995, n * res.dof) / n
    assert nlo <= res.nees_mean <= nhi, (res.nees_mean, (nlo, nhi))
    # the whitened residuals of the lidar's pairs and of the road plane are what the model says
    # (the rows a scene whitens by zero, the directions it does not see, not counted)
    rms = {k: np.mean([t.residual_rms[k] for t in res.trials]) for k in ("lidar", "lidar_ground")}
    assert rms == pytest.approx({"lidar": 1.0, "lidar_ground": 1.0}, abs=0.03)
