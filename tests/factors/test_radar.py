"""A Doppler radar's ego-velocity (:mod:`excite.factors.radar`): the model against an independent
rigid-body computation, its noise against a Monte Carlo of Doppler fits over stationary targets,
the rig entry, and the degenerate motions of docs/DESIGN.md on the dense reference.

The contract tests (derivative = finite differences, residual zero at its measurement, the
symmetries kept) run over this kind, 3-D and 2-D, in ``tests/factors/test_symbolic.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

from excite.errors import RigError
from excite.factors import base as registry
from excite.factors import symbolic
from excite.factors.base import Nominal
from excite.factors.radar import RadarNoise, velocity_sigma_mps
from excite.motion.vehicle import Suspension, drive
from excite.rig.config import build_rig
from excite.score.evaluate import evaluate

from helpers import BOTH_WAYS, KNOTS, VARIED_SPEED, car_data, dense_analysis, null_weights, profile


def radar_data(dimensions: int = 3) -> dict:
    data = car_data(radar=True)
    data["sensors"][0].update(dimensions=dimensions,
                              T_B_S={"translation_m": [2.3, 0.4, 0.1], "rpy_deg": [0.0, 0.0, 30.0]})
    return data


@pytest.fixture(scope="module")
def radar3():
    return build_rig(radar_data(3))


@pytest.fixture(scope="module")
def radar2():
    return build_rig(radar_data(2))


def test_the_ego_velocity_is_the_sensors_velocity_in_its_frame(radar3, radar2):
    """Against the sensor's velocity computed from the drive's samples in numpy: ``R_W_S`` of the
    sensor's frame, its world velocity ``v_B + R_W_B (ω_B × p_B_S)``."""
    traj = drive(profile(VARIED_SPEED, BOTH_WAYS), Suspension())
    for rig in (radar3, radar2):
        nom = Nominal.of(traj, rig)
        inst = next(i for i in registry.instances(rig) if i.kind.name == "radar")
        first = registry.factor_keyframes(inst.kind, rig, inst.entry, nom.n_keyframes)
        m = symbolic.measurements(inst.kind, nom, rig, inst.entry, first)
        b = traj.sample(nom.t[first]).body(nom.R_V_B, nom.p_V_B)
        R_BS, p_BS = inst.entry.T_B_S.R, inst.entry.T_B_S.p
        v_S_W = b.v_W + np.einsum("nij,nj->ni", b.R_W_B, np.cross(b.omega_B, p_BS))
        ref = np.einsum("nji,nj->ni", b.R_W_B @ R_BS, v_S_W)[:, :inst.entry.dimensions]
        assert m.shape == ref.shape
        assert np.abs(m - ref).max() < 1e-9 * np.abs(ref).max()


def test_the_time_offset_sees_the_later_velocity(radar3):
    """With ``t_d`` the model's ego-velocity is that of keyframes ``t_d`` later, to first order
    (the change over the factor's interval): typically within 5 % of the change. (Rigid
    suspension: the generated drives' pitch rate follows the jerk of a C1 speed profile, which
    jumps at its knots; no difference over an interval sees a jump.)"""
    traj = drive(profile(VARIED_SPEED, BOTH_WAYS), Suspension.rigid())
    nom = Nominal.of(traj, radar3)
    inst = next(i for i in registry.instances(radar3) if i.kind.name == "radar")
    first = registry.factor_keyframes(inst.kind, radar3, inst.entry, nom.n_keyframes)
    td = 0.03
    m0 = symbolic.measurements(inst.kind, nom, radar3, inst.entry, first)
    m = symbolic.measurements(inst.kind, nom, radar3, inst.entry, first, {"time_offset": td})
    later = Nominal.of(traj, radar3, t_start=traj.t_start + td)
    ml = symbolic.measurements(inst.kind, later, radar3, inst.entry, first[:-1])
    n = ml.shape[0]
    change = np.abs(m0[:n] - ml)[:, :2]
    rel = np.abs(m[:n] - ml)[:, :2] / change
    assert np.median(rel, axis=0).max() < 0.05 and change.max() > 0.01


@pytest.mark.montecarlo
def test_the_noise_is_that_of_a_doppler_fit_over_stationary_targets():
    """σ of the ego-velocity from ``n`` targets uniform over the field of view, each range rate
    with σ_d: a Monte Carlo of least-squares fits (many targets, where the fit's covariance is its
    expectation's inverse)."""
    rng = np.random.default_rng(1)
    noise = RadarNoise(doppler_sigma_mps=0.1, stationary_targets=400, azimuth_fov_deg=60, elevation_fov_deg=20)
    for dims in (3, 2):
        v = np.array([10.0, -0.5, 0.2])[:dims]
        est = []
        for _ in range(1500):
            az = rng.uniform(-np.pi / 6, np.pi / 6, 400)
            el = rng.uniform(-np.pi / 18, np.pi / 18, 400)
            u = (np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]) if dims == 3
                 else np.column_stack([np.cos(az), np.sin(az)]))
            rr = -u @ v + rng.normal(0.0, 0.1, 400)
            est.append(np.linalg.lstsq(-u, rr, rcond=None)[0])
        emp = np.std(np.array(est), axis=0)
        assert np.allclose(emp, velocity_sigma_mps(noise, dims), rtol=0.08), (dims, emp, velocity_sigma_mps(noise, dims))
    s = velocity_sigma_mps(noise)
    assert s[1] > 3 * s[0] and s[2] > 5 * s[0]  # a narrow field of view sees sideways motion poorly


@pytest.mark.parametrize("change, message", [
    (lambda s: s.update(dimensions=1), "sensors.0.dimensions: Input should be 2 or 3"),
    (lambda s: s["noise"].pop("stationary_targets"), "sensors.0.noise.stationary_targets: Field required"),
    (lambda s: s["noise"].update(doppler_sigma_mps=0.0), "sensors.0.noise.doppler_sigma_mps: Input should be greater than 0"),
    (lambda s: s["noise"].update(azimuth_fov_deg=400), "sensors.0.noise.azimuth_fov_deg: Input should be less than or equal to 360"),
    (lambda s: s["noise"].update(doppler_sigma_mps=50.0), "sensors.0.noise.doppler_sigma_mps: 50.0 is outside the sane range"),
])
def test_a_bad_entry_is_a_clear_error_naming_the_key(change, message):
    data = radar_data()
    change(data["sensors"][0])
    with pytest.raises(RigError) as e:
        build_rig(data)
    assert message in str(e.value)


def test_the_coarse_rig_keeps_the_information_per_second(radar3):
    from excite.plan.model import coarse_rig

    traj = drive(profile(VARIED_SPEED, BOTH_WAYS), Suspension())
    fine = {p.name: p.sigma for p in evaluate(traj, radar3).parameters}
    coarse = {p.name: p.sigma for p in evaluate(traj, coarse_rig(radar3, 2.5, 8)).parameters}
    for n in ("radar_front.rot_z", "radar_front.trans_x", "radar_front.time_offset"):
        assert coarse[n] == pytest.approx(fine[n], rel=0.25), n


# --- degenerate motions (docs/DESIGN.md), suspension off, on the dense reference ---------------


def _radar_nulls(traj, rig):
    spec, _ = dense_analysis(traj, rig)
    w = null_weights(spec, rig)
    rep = evaluate(traj, rig)
    assert rep.nullity == spec.nullity
    return {n for n, x in w.items() if x > 1 - 1e-6 and n.startswith("radar_front.")}, w


def test_no_yaw_rate_leaves_the_lever_arm(radar3, radar2):
    """Straight driving (speed varied, no rotation at all): ω × p = 0, the lever arm is not seen;
    a 3-D radar's roll about the travel direction neither (its velocity is along it); a 2-D one's
    roll and pitch enter through its vertical velocity only, which there is none of."""
    traj = drive(profile(VARIED_SPEED, 0.0), Suspension.rigid())
    nulls3, w3 = _radar_nulls(traj, radar3)
    # the 3-D radar is yawed 30° in B: its roll and pitch mix into the rotation about travel
    assert {"radar_front.trans_x", "radar_front.trans_y", "radar_front.trans_z"} <= nulls3
    assert w3["radar_front.rot_z"] < 1e-6 and w3["radar_front.time_offset"] < 1e-6
    nulls2, w2 = _radar_nulls(traj, radar2)
    assert nulls2 == {"radar_front.trans_x", "radar_front.trans_y", "radar_front.trans_z",
                      "radar_front.rot_x", "radar_front.rot_y"}
    assert w2["radar_front.rot_z"] < 1e-6 and w2["radar_front.time_offset"] < 1e-6


def test_no_rotation_leaves_a_3d_radar_exactly_its_lever_arm_and_its_roll_about_the_travel(radar3):
    """The 3-D radar (yawed 30° in B) on the straight drive: the null space is the car's six
    (tracks, wheelbase, ratio, horizontal accelerometer bias) and four of the radar's: its lever
    arm and the rotation about the travel direction, which is (cos 30°, −sin 30°, 0) in its frame."""
    spec, _ = dense_analysis(drive(profile(VARIED_SPEED, 0.0), Suspension.rigid()), radar3)
    assert spec.nullity == 6 + 4
    names = [c.name for c in radar3.scored]
    rot = spec.null_space[[names.index(f"radar_front.rot_{a}") for a in "xyz"]]
    travel = np.array([np.cos(np.radians(30.0)), -np.sin(np.radians(30.0)), 0.0])
    # the rotations' null part is one direction, along the travel
    u, sv, _ = np.linalg.svd(rot)
    assert sv[0] > 0.99 and sv[1] < 1e-6, sv
    assert abs(abs(u[:, 0] @ travel) - 1.0) < 1e-6, u[:, 0]


def test_planar_driving_leaves_a_3d_radars_height_and_a_2d_radars_pitch_roll_and_height(radar3, radar2):
    traj = drive(profile(VARIED_SPEED, BOTH_WAYS), Suspension.rigid())
    assert _radar_nulls(traj, radar3)[0] == {"radar_front.trans_z"}
    assert _radar_nulls(traj, radar2)[0] == {"radar_front.rot_x", "radar_front.rot_y", "radar_front.trans_z"}


def test_the_suspension_makes_a_2d_radars_pitch_and_height_weak_but_finite(radar2):
    traj = drive(profile(VARIED_SPEED, BOTH_WAYS), radar2.suspension)
    rep = evaluate(traj, radar2)
    assert rep.nullity == 0
    sig = {p.name: p for p in rep.parameters}
    for n in ("radar_front.rot_x", "radar_front.rot_y", "radar_front.trans_z"):
        assert sig[n].sigma > 10 * sig[n].target, n
    assert sig["radar_front.rot_z"].sigma < sig["radar_front.rot_z"].target
    weak = {m.coordinates[0][0] for m in rep.weak_modes[:3]}
    assert weak == {"radar_front.rot_x", "radar_front.rot_y", "radar_front.trans_z"}


def test_the_lever_arm_sigma_falls_with_yaw_rate(radar3):
    """ω × p: the lateral velocity a forward lever arm adds is ψ̇·x; twice the curvature at the
    same speeds, half the σ of the forward lever arm."""
    sig = {}
    for k in (0.04, 0.08):
        spec, _ = dense_analysis(drive(profile(VARIED_SPEED, k * np.sin(KNOTS / 5)), Suspension.rigid()), radar3)
        names = [c.name for c in radar3.scored]
        sig[k] = spec.sigma[names.index("radar_front.trans_x")]
    assert 1.6 < sig[0.04] / sig[0.08] < 2.4, sig


def test_the_advice_of_a_radars_weak_modes():
    rig = build_rig(radar_data(2))
    rep = evaluate(drive(profile(VARIED_SPEED, 0.0), Suspension.rigid()), rig)
    advice = " ".join(m.advice for m in rep.weak_modes if m.status == "unobservable").lower()
    assert "yaw rate" in advice or "turn" in advice


def test_constant_velocity_hides_the_can_and_radar_time_offsets(radar3):
    """Straight at constant speed every reading stays the same: a shift of the CAN stream's or the
    radar's clock changes nothing (each enters through the change of its readings over an
    interval). Speed changes bring both back."""
    spec, _ = dense_analysis(drive(profile(8.0, 0.0), Suspension.rigid()), radar3)
    w = null_weights(spec, radar3)
    assert w["wheel.time_offset"] > 1 - 1e-6 and w["radar_front.time_offset"] > 1 - 1e-6, w
    spec, _ = dense_analysis(drive(profile(VARIED_SPEED, 0.0), Suspension.rigid()), radar3)
    w = null_weights(spec, radar3)
    assert w["wheel.time_offset"] < 1e-6 and w["radar_front.time_offset"] < 1e-6, w
