"""validate in a scene: the simulator's lidar pairs, the calibrator's weights, and the
evaluator's scene-aware σ held to the trials.

Two simulators. The model's (``SimulationSettings.model()``) gives each lidar pair the
registration error the scene's information predicts and the road plane the error of its fit; the
physical one (the default) ray-casts each pair's scans on the lidar's real pattern and measures
what registering them gives (:mod:`excite.validate.scans`), and the calibrator weighs those pairs
by what their registration reports. The pieces first — what a registered pair reports along the
directions its scans do not see, what the registration covariance the simulator draws from
leaves unseen — then Monte Carlo: the model's data in a street (the
lidar's height, which planar driving leaves to the road in view), the physical data in the open
lot (every pair leaves x, y and yaw to the registration, which reports no motion there).
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.stats import chi2

from excite.core import so3
from excite.errors import ValidateError
from excite.factors.odometry import registered
from excite.factors.optics import LIDAR_PRESETS
from excite.motion.maneuvers import figure_eight
from excite.motion.vehicle import Suspension, drive
from excite.rig.config import RIGS_DIR, build_rig
from excite.scene import lidar, shapes
from excite.scene.along import seen
from excite.scene.files import load_scene
from excite.scene.model import Scene
from excite.score.evaluate import evaluate
from excite.validate.monte_carlo import MonteCarloSettings, monte_carlo
from excite.validate.scans import PairNoise, pair_covariance, scan_pattern
from excite.validate.simulate import SimulationSettings
from helpers import hilly

STREET = Scene.combine([shapes.ground(-150, -150, 150, 150), shapes.wall((-150, 40), (150, 40), 6.0),
                        shapes.wall((150, -40), (-150, -40), 6.0)])


def _planar_rig():
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
    rig = _planar_rig()
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


@pytest.fixture(scope="module")
def rig():
    data = yaml.safe_load((RIGS_DIR / "robotaxi.yaml").read_text())
    data["imu"]["update_rate"] = 100  # coarse and cheap; the models hold at any rate
    return build_rig(data)


def _pairs(null: np.ndarray, n: int) -> PairNoise:
    z = np.zeros((n, 6, 6))
    return PairNoise(np.arange(n), z, np.broadcast_to(null, (n, 6, 6)).copy(), z)


def test_a_registered_pair_reports_no_motion_where_its_scans_see_nothing():
    rng = np.random.default_rng(0)
    n = 20
    R_rel = so3.exp(rng.normal(0.0, 0.02, (n, 3)))
    t_rel = np.column_stack([rng.uniform(0.3, 1.5, n), rng.normal(0, 0.05, n), rng.normal(0, 0.02, n)])
    # a tunnel along scan j's x: the translation along it, as seen from scan i, is gone; the rest stays
    R, t = registered(R_rel, t_rel, _pairs(np.diag([0, 0, 0, 1.0, 0, 0]), n), np.arange(n), None)
    axis_i = R_rel[:, :, 0]  # the axis in scan i's frame
    assert np.allclose(np.einsum("ni,ni->n", axis_i, t), 0.0, atol=1e-15)
    assert np.allclose(t - np.einsum("ni,ni->n", axis_i, t_rel)[:, None] * -axis_i, t_rel, atol=1e-15)
    assert np.array_equal(R, R_rel)
    # a flat lot: the yaw about its normal and the translation along it; a pair moving in the plane
    # and turning about its normal reports nothing at all
    yaw = rng.normal(0.0, 0.05, n)
    R_flat = so3.exp(np.column_stack([np.zeros(n), np.zeros(n), yaw]))
    t_flat = t_rel * [1.0, 1.0, 0.0]
    R, t = registered(R_flat, t_flat, _pairs(np.diag([0, 0, 1.0, 1.0, 1.0, 0]), n), np.arange(n), None)
    assert np.allclose(R, np.eye(3), atol=1e-15) and np.allclose(t, 0.0, atol=1e-15)
    with pytest.raises(ValueError, match="another drive"):
        registered(R_rel, t_rel, _pairs(np.eye(6), n), np.arange(n) + 1, None)


def test_the_registration_covariance_leaves_exactly_what_the_scan_does_not_see():
    """A scan of the open lot (a vlp16 on the real pattern): the flat ground tells nothing of x, y
    and yaw — the projector onto what is not seen is onto exactly those — and on the rest the
    covariance is the information's inverse."""
    scan = scan_pattern(LIDAR_PRESETS["vlp16"])
    pts, nrm, _, _ = lidar.cast_scan(load_scene("open_lot"), np.eye(3), np.array([0.0, 10.0, 1.8]), scan)
    C, N = pair_covariance(pts, nrm, scan.range_noise_m)
    assert np.allclose(N, np.diag([0, 0, 1.0, 1.0, 1.0, 0]), atol=1e-9)
    H = lidar.point_information(pts, nrm, scan.range_noise_m)
    seen = [0, 1, 5]  # roll, pitch, height
    assert np.allclose(C[np.ix_(seen, seen)] @ H[np.ix_(seen, seen)], np.eye(3), atol=1e-9)
    assert np.allclose(np.delete(C, seen, 0), 0.0, atol=1e-15)


def test_a_drive_that_sees_a_scene_needs_the_scene_itself(rig):
    traj = seen(drive(figure_eight(6.0), rig.suspension), rig, shapes.ground(-100, -100, 100, 100))
    with pytest.raises(ValidateError, match="give the scene itself"):
        monte_carlo(traj, rig, MonteCarloSettings(runs=2))


@pytest.mark.slow
@pytest.mark.montecarlo
def test_monte_carlo_in_the_open_lot_matches_the_scene_aware_sigma(rig):
    """30 trials of 20 s of a figure-eight over undulating ground in the open lot, the physical
    simulator: every lidar pair's scans leave x, y and yaw unseen (the registration reports no
    motion there), the road plane is fitted per frame. The mean NEES lies in its 99 % interval, and
    the noise-free trial calibrates to the truth (the pairs' unseen motion carries no weight)."""
    traj = drive(hilly(figure_eight(20.0)), rig.suspension).transformed(np.eye(3), np.array([-16.0, 18.0, 0.0]))
    scene = load_scene("open_lot")
    n = 30
    res = monte_carlo(traj, rig, MonteCarloSettings(runs=n, seed=11, simulation=SimulationSettings()), scene=scene)
    assert res.report.nullity == 0 and res.failures == 0
    lo, hi = chi2.ppf([0.005, 0.995], n * res.dof) / n
    print(f"open lot: NEES {res.nees_mean:.2f} over {n} trials (99 % interval {lo:.2f} … {hi:.2f}, dof {res.dof})")
    assert lo <= res.nees_mean <= hi
    assert max(abs(v) for v in res.systematic.values()) < 0.2, res.systematic
    # the scene made the lidar's horizontal lever arm and yaw weaker than a blind score says
    blind = {p.name: p.sigma for p in evaluate(traj, rig.with_constant_biases()).parameters}
    in_scene = {p.name: p.predicted_sigma for p in res.parameters}
    assert in_scene["lidar.trans_x"] > 1.5 * blind["lidar.trans_x"]
