"""Drift densities from an odometry against a reference: known densities recovered from a
simulated odometry within their stated uncertainty.

The simulator is more physical than the estimator's model: the reference is a 100 Hz ground truth
with white pose noise, interpolated by the estimator at the odometry's jittered 10 Hz stamps (so
its error is not the model's constant white variance); the odometry runs on another clock (a
time offset), in another frame (a camera's optical axes, a lever arm), at another scale (a
monocular odometry) and in another world, its relative poses corrupted by independent
rotation and translation errors with the densities to recover. Written with scipy's rotations,
not excite's."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from excite.errors import RigError
from excite.rig.noise import TimedPoses, estimate_drift

ROT_DENSITY_DEG = 0.05  # deg/√s
TRANS_DENSITY_M = 0.02  # m/√s
REF_NOISE_DEG, REF_NOISE_M = 0.01, 0.002  # the reference's white error per pose and axis
TIME_OFFSET_S = 0.07
X = Rotation.from_euler("xyz", [-90, 0, -90], degrees=True)  # optical axes of a forward camera
LEVER_M = np.array([1.2, -0.3, 0.5])
SCALE = 0.8  # odometry units per metre


def _truth(t: np.ndarray) -> tuple[Rotation, np.ndarray]:
    """A car-like drive, in closed form (the same at any stamps): yaw varying both ways, a little
    pitch and roll, speed changing."""
    yaw = 0.6 * np.sin(0.11 * t) + 0.3 * np.sin(0.37 * t + 1.0)
    pitch = 0.02 * np.sin(0.5 * t)
    roll = 0.03 * np.sin(0.43 * t + 0.5)
    R = Rotation.from_euler("ZYX", np.c_[yaw, pitch, roll])
    p = np.c_[8.0 * t + 40.0 * np.sin(0.07 * t), 60.0 * np.sin(0.05 * t) + 5.0 * np.sin(0.3 * t),
              0.5 * np.sin(0.2 * t)]
    return R, p


def _simulate(seed: int, duration_s: float = 400.0) -> tuple[TimedPoses, TimedPoses]:
    rng = np.random.default_rng(seed)
    t_ref = np.arange(0.0, duration_s, 0.01)
    R_ref, p_ref = _truth(t_ref)
    ref_R = R_ref * Rotation.from_rotvec(rng.normal(0.0, np.radians(REF_NOISE_DEG), (t_ref.size, 3)))
    ref_p = p_ref + rng.normal(0.0, REF_NOISE_M, (t_ref.size, 3))
    reference = TimedPoses(t_ref + 1000.0, ref_R.as_matrix(), ref_p)

    # the odometry frame E on the vehicle: pose X, LEVER_M in the reference's frame; stamped on its
    # own clock (the reference at t + offset is the odometry at t)
    t_true = np.arange(5.0, duration_s - 5.0, 0.1)
    t_true = t_true + rng.uniform(-0.003, 0.003, t_true.size)
    R_b, p_b = _truth(t_true)
    R_e = R_b * X
    p_e = p_b + R_b.apply(LEVER_M)
    # relative poses of E, corrupted, accumulated in the odometry's own world
    dt = np.diff(t_true)
    R_rel = R_e[:-1].inv() * R_e[1:]
    t_rel = R_e[:-1].inv().apply(p_e[1:] - p_e[:-1])
    R_rel = R_rel * Rotation.from_rotvec(rng.normal(0.0, 1.0, (dt.size, 3))
                                         * np.radians(ROT_DENSITY_DEG) * np.sqrt(dt)[:, None])
    t_rel = t_rel + rng.normal(0.0, 1.0, (dt.size, 3)) * TRANS_DENSITY_M * np.sqrt(dt)[:, None]
    W = Rotation.from_euler("xyz", [0.3, -0.2, 2.0])  # the odometry's world
    R_out, p_out = [W], [np.array([5.0, -3.0, 1.0])]
    for Rk, tk in zip(R_rel, t_rel):
        p_out.append(p_out[-1] + R_out[-1].apply(tk) * SCALE)
        R_out.append(R_out[-1] * Rk)
    odom = TimedPoses(t_true + 1000.0 - TIME_OFFSET_S, Rotation.concatenate(R_out).as_matrix(), np.array(p_out))
    return odom, reference


def test_known_densities_are_recovered_within_their_stated_uncertainty():
    odom, ref = _simulate(1)
    est = estimate_drift(odom, ref)
    assert est.time_offset_s == pytest.approx(TIME_OFFSET_S, abs=6e-3)  # ±4 ms over seeds
    assert est.scale == pytest.approx(1.0 / SCALE, rel=1e-3)
    assert np.degrees((Rotation.from_matrix(est.frame_rotation) * X.inv()).magnitude()) < 0.05
    # the vertical lever arm is seen only through the little pitch and roll of the drive
    assert np.all(np.abs(est.lever_arm_m - LEVER_M) < [0.1, 0.1, 0.3])
    for got, true in ((est.rotation, ROT_DENSITY_DEG), (est.translation, TRANS_DENSITY_M)):
        assert 0 < got.sigma < 0.1 * true  # a stated uncertainty that says something
        assert abs(got.value - true) < 3 * got.sigma, (got, true)
        # the white part (the reference's error, interpolated) is told apart, not added
        assert got.over_1s == pytest.approx(true, rel=0.25)
        # Gaussian errors: no heavy tails, and the robust bulk density agrees with the variance's
        assert got.kurtosis == pytest.approx(3.0, abs=0.3) and got.bulk == pytest.approx(true, rel=0.1)
    assert est.rotation.white_sigma > 0.3 * REF_NOISE_DEG
    lines = est.rig_lines()
    pasted = yaml.safe_load(lines)["noise"]
    assert pasted == {"rotation_density_deg_per_sqrt_s": float(f"{est.rotation.value:.3g}"),
                      "translation_density_m_per_sqrt_s": float(f"{est.translation.value:.3g}")}


def test_without_the_white_term_the_reference_noise_would_bias_the_density():
    """The naive estimate (variance of consecutive pair errors over Δt) is biased up by the
    reference's own noise; the estimator's is not (an independent check of why c is modelled)."""
    odom, ref = _simulate(2)
    est = estimate_drift(odom, ref)
    naive = np.sqrt(ROT_DENSITY_DEG ** 2 + 2 * est.rotation.white_sigma ** 2 / 0.1)
    assert naive > ROT_DENSITY_DEG * 1.1
    assert abs(est.rotation.value - ROT_DENSITY_DEG) < 3 * est.rotation.sigma


@pytest.mark.montecarlo
def test_the_stated_uncertainty_covers_the_truth_as_often_as_it_says():
    """Over 16 simulated drives the errors in units of the stated σ have a spread near 1."""
    z = []
    for seed in range(16):
        est = estimate_drift(*_simulate(100 + seed, duration_s=200.0))
        z += [(est.rotation.value - ROT_DENSITY_DEG) / est.rotation.sigma,
              (est.translation.value - TRANS_DENSITY_M) / est.translation.sigma]
    z = np.array(z)
    assert abs(z.mean()) < 0.75  # no bias beyond what 32 draws allow
    assert 0.6 < z.std() < 1.5
    assert np.mean(np.abs(z) < 2) >= 0.8


def test_an_odometry_that_does_not_overlap_its_reference(tmp_path):
    odom, ref = _simulate(3, duration_s=60.0)
    far = TimedPoses(odom.t_s + 1e4, odom.R, odom.p)
    with pytest.raises(RigError, match="do not overlap in time"):
        estimate_drift(far, ref)
