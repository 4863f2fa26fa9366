"""A car's CAN wheel speeds and steering angle (:mod:`excite.factors.ackermann`): the rig entry and
its errors, the model against the drive's own kinematics (integrated contact-point speeds, the
bicycle model's steering), the readings' interval means, the degenerate motions of docs/DESIGN.md
on the dense reference, and σ of every new parameter against it.

The contract tests (derivative = finite differences, residual zero at its measurement, the
symmetries kept) run over this kind in ``tests/factors/test_symbolic.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from excite.errors import RigError
from excite.factors import ackermann, kernels, symbolic
from excite.factors import base as registry
from excite.factors.ackermann import CanRecording, interval_means
from excite.factors.base import Nominal
from excite.motion.vehicle import ControlProfile, Suspension, drive
from excite.rig.config import build_rig, load_rig
from excite.score.evaluate import evaluate
from helpers import KNOTS, VARIED_SPEED, BOTH_WAYS, profile, car_data, dense_analysis, null_weights

@pytest.fixture(scope="module")
def car():
    return build_rig(car_data())


def assert_null_space_is(traj, rig, expected: set[str]):
    """On the dense reference and in the evaluator: the null space is exactly the span of the
    named coordinate axes."""
    spec, _ = dense_analysis(traj, rig)
    w = null_weights(spec, rig)
    assert spec.nullity == len(expected), (spec.nullity, {k: round(v, 3) for k, v in w.items() if v > 1e-6})
    for name, wgt in w.items():
        assert (wgt > 1 - 1e-6) if name in expected else (wgt < 1e-6), (name, wgt)
    rep = evaluate(traj, rig)
    assert rep.nullity == spec.nullity
    assert {p.name for p in rep.parameters if p.sigma is None} == expected
    return spec


# --- the rig entry ---------------------------------------------------------------------------


def test_the_coordinates_have_the_stable_names():
    rig = load_rig("sedan")
    names = [c.name for c in rig.coordinates]
    for n in ("wheel.scale_fl", "wheel.scale_fr", "wheel.scale_rl", "wheel.scale_rr", "wheel.track_front",
              "wheel.track_rear", "wheel.wheelbase", "steering.ratio", "steering.offset", "wheel.time_offset"):
        assert n in names
    assert next(c for c in rig.coordinates if c.name == "wheel.slip").nuisance
    units = {c.name: c.unit for c in rig.coordinates}
    assert units["steering.offset"] == "rad" and units["steering.ratio"] == "1" and units["wheel.scale_fl"] == "1"
    data = car_data()
    data["ackermann"].update(speeds="radps", radius_m=0.33)
    data["targets"] = {**{k: v for k, v in data["targets"].items() if k != "wheel.scale_*"},
                       "wheel.radius_*": "0.5 mm"}
    radii = build_rig(data)
    assert [c.name for c in radii.coordinates if c.quantity == "radius"] == [f"wheel.radius_{w}" for w in ackermann.WHEELS]
    assert {c.unit for c in radii.coordinates if c.quantity == "radius"} == {"m"}


@pytest.mark.parametrize("change, message", [
    (lambda a: a.update(speeds="radps"), "ackermann: speeds: radps reads angular rates: give the wheels' radius_m"),
    (lambda a: a.update(radius_m=0.3), "ackermann: radius_m applies to speeds: radps"),
    (lambda a: a.update(wheelbase_m=-2.7), "ackermann.wheelbase_m: Input should be greater than 0"),
    (lambda a: a.update(wheelbase_m=40.0), "ackermann.wheelbase_m: 40.0 is outside the sane range [0.3, 20] m"),
    (lambda a: a["steering"].update(ratio=0.5), "ackermann.steering.ratio: 0.5 is outside the sane range [1, 100]"),
    (lambda a: a["steering"].update(gain=1), "ackermann.steering.gain: not a key of a rig file here"),
    (lambda a: a.pop("rate_hz"), "ackermann.rate_hz: Field required"),
    (lambda a: a.update(speeds="kph"), "ackermann.speeds: Input should be 'mps' or 'radps'"),
])
def test_a_bad_entry_is_a_clear_error_naming_the_key(change, message):
    data = car_data()
    change(data["ackermann"])
    with pytest.raises(RigError) as e:
        build_rig(data)
    assert message in str(e.value)


def test_rear_encoders_and_can_wheel_speeds_are_not_both_a_rig():
    data = car_data()
    data["wheels"] = {"radius_left_m": 0.3, "radius_right_m": 0.3, "track_m": 1.6, "noise_density": 0.03}
    with pytest.raises(RigError, match="not both"):
        build_rig(data)


def test_the_steering_is_optional():
    data = car_data()
    data["ackermann"]["steering"] = None
    data["targets"] = {k: v for k, v in data["targets"].items() if not k.startswith("steering")}
    rig = build_rig(data)
    assert not any(c.block == "steering" for c in rig.coordinates)
    inst = next(i for i in registry.instances(rig) if i.kind.name == "ackermann")
    nom = Nominal.of(drive(profile(VARIED_SPEED, BOTH_WAYS)), rig)
    assert kernels.jacobians(inst.kind, nom, rig, inst.entry).n_rows == 4  # the four wheels


# --- the model against the drive's kinematics -------------------------------------------------


@pytest.fixture(scope="module")
def turning():
    """Speeds from 2 to 10 m/s, turns both ways up to 0.12 1/m, suspension on."""
    k = np.linspace(0.0, 40.0, 41)
    return drive(ControlProfile(k, 6 + 4 * np.sin(k / 4), 0.12 * np.sin(k / 3)), Suspension())


def _measured(rig, nom):
    inst = next(i for i in registry.instances(rig) if i.kind.name == "ackermann")
    first = registry.factor_keyframes(inst.kind, rig, inst.entry, nom.n_keyframes)
    return inst, symbolic.measurements(inst.kind, nom, rig, inst.entry, first)


def test_wheel_speeds_are_the_integrated_contact_point_speeds(car, turning):
    """Each wheel's interval mean is the mean speed of its contact point (x, y) in the axle frame
    over the interval, |(u − y·ψ̇, x·ψ̇)|, integrated from the drive's samples in numpy; the front
    wheels run faster than the rear ones in a turn by their longer path."""
    nom = Nominal.of(turning, car)
    _, m = _measured(car, nom)
    ac = car.config.ackermann
    xy = ac.geometry()
    for f in (37, 81, 150):
        t = np.linspace(nom.t[f], nom.t[f + 1], 401)
        s = turning.sample(t)
        speed = np.stack([np.hypot(s.speed - y * s.yaw_rate, x * s.yaw_rate) for x, y in xy], axis=1)
        mean = np.trapezoid(speed, t, axis=0) / (t[-1] - t[0])
        # the rear wheels exactly; the front ones to second order in the change of curvature over
        # an interval (a 0.2-s interval at 7 m/s² of lateral acceleration: 2 mm/s, a fifth of σ)
        assert np.allclose(m[f, 2:4], mean[2:4], rtol=2e-5), (m[f, 2:4], mean[2:4])
        assert np.allclose(m[f, :2], mean[:2], rtol=5e-4), (m[f, :2], mean[:2])
    front_excess = m[:, :2].mean(axis=1) - m[:, 2:4].mean(axis=1)
    s = turning.sample(nom.t[:-1])
    expected = 0.5 * ac.wheelbase_m ** 2 * (s.yaw_rate / s.speed) ** 2 * s.speed  # ½ L² κ² u
    assert np.abs(front_excess - expected).max() < 0.05 * np.abs(expected).max()


def test_the_steering_is_the_bicycle_model_of_the_drives_curvature(car, turning):
    nom = Nominal.of(turning, car)
    _, m = _measured(car, nom)
    st, L = car.config.ackermann.steering, car.config.ackermann.wheelbase_m
    tm = 0.5 * (nom.t[:-1] + nom.t[1:])
    s = turning.sample(tm)
    expected = st.ratio * np.arctan(L * s.yaw_rate / s.speed) + math.radians(st.offset_deg)
    assert np.abs(m[:, 4] - expected).max() < 2e-3 * np.abs(expected).max()


def test_the_time_offset_is_the_readings_of_a_later_motion(car, turning):
    """With ``wheel.time_offset = t_d`` the model's readings are those of the motion ``t_d`` later
    (to first order): against the readings on keyframes ``t_d`` later."""
    nom = Nominal.of(turning, car)
    inst, m0 = _measured(car, nom)
    td = 0.02
    first = registry.factor_keyframes(inst.kind, car, inst.entry, nom.n_keyframes)
    m = symbolic.measurements(inst.kind, nom, car, inst.entry, first, {"time_offset": td})
    later = Nominal.of(turning, car, t_start=turning.t_start + td)
    _, m_later = _measured(car, later)
    n = min(len(m), len(m_later))
    m0, m, m_later = m0[:n], m[:n], m_later[:n]
    inner = slice(5, -5)
    change = np.abs(m0 - m_later)[inner].max(axis=0)
    err = np.abs(m - m_later)[inner].max(axis=0)
    assert np.all(err < 0.1 * change), (err, change)


def test_interval_means_of_readings_are_exact_for_piecewise_constant_readings():
    t = np.array([0.1, 0.2, 0.35, 0.4, 0.5, 0.6])
    speeds = np.arange(24, dtype=float).reshape(6, 4)
    rec = CanRecording(t, speeds, np.full(6, 0.2), 0.1)
    sp, st = interval_means(rec, np.array([0.0, 0.3, 0.6]))
    # (0, 0.3]: readings 0 (0.1 s), 1 (0.1 s), 2 for 0.1 of its 0.15 s
    assert np.allclose(sp[0], (0.1 * speeds[0] + 0.1 * speeds[1] + 0.1 * speeds[2]) / 0.3)
    assert np.allclose(sp[1], (0.05 * speeds[2] + 0.05 * speeds[3] + 0.1 * speeds[4] + 0.1 * speeds[5]) / 0.3)
    assert np.allclose(st, 0.2)
    sp, _ = interval_means(rec, np.array([0.3, 0.6, 0.9]))
    assert np.isnan(sp[1]).all() and not np.isnan(sp[0]).any()  # not covered: NaN


def test_the_steering_mean_is_weighted_by_distance():
    t = np.array([0.1, 0.2])
    speeds = np.array([[1.0] * 4, [3.0] * 4])
    rec = CanRecording(t, speeds, np.array([0.1, 0.5]), 0.1)
    _, st = interval_means(rec, np.array([0.0, 0.2]))
    assert st[0] == pytest.approx((0.1 * 1 + 0.5 * 3) / 4)
    rest = CanRecording(t, np.zeros((2, 4)), np.array([0.1, 0.5]), 0.1)
    assert interval_means(rest, np.array([0.0, 0.2]))[1][0] == pytest.approx(0.3)  # at rest: by time


def test_the_physical_stream_agrees_with_the_model_to_its_noise(car, turning):
    """Noise-free, no tyre slip: the simulated CAN stream (readings at 100 Hz, quantised, boxcar
    means of the true contact-point speeds) averaged over the keyframe intervals is the model's
    measurement to far below its σ."""
    from excite.validate.simulate import Calibration, SimulationSettings, simulate

    settings = SimulationSettings(noise=False, wheel_slip_per_g=0.0, wheel_scrub_per_g2=0.0, slip_angle_deg_per_mps2=0.0)
    data = simulate(turning, car, Calibration.nominal(car), np.random.default_rng(0), settings)
    nom = Nominal.of(turning, car)
    _, m = _measured(car, nom)
    err = data.recorded["ackermann"] - m
    dT = 1.0 / car.keyframe_rate_hz
    ac = car.config.ackermann
    assert np.sqrt(np.mean(err[:, :4] ** 2)) < 0.1 * ackermann.speed_sigma(ac, dT)
    moving = nom.v[:-1, 0] ** 2 + nom.v[:-1, 1] ** 2 > 1.0
    assert np.sqrt(np.mean(err[moving, 4] ** 2)) < 0.1 * ackermann.steering_sigma_rad(ac, dT)


def test_noise_is_a_density_the_information_does_not_depend_on_the_keyframe_rate(car):
    traj = drive(profile(VARIED_SPEED, BOTH_WAYS), Suspension())
    sig = {}
    for kf in (5, 10):
        data = car.config.model_dump()
        data.update(keyframe_rate_hz=kf, imu=dict(data["imu"], update_rate=20 * kf))
        sig[kf] = {p.name: p.sigma for p in evaluate(traj, build_rig(data)).parameters}
    for name in ("wheel.scale_fl", "wheel.track_rear", "wheel.wheelbase", "steering.ratio", "steering.offset"):
        assert sig[10][name] == pytest.approx(sig[5][name], rel=0.05), name


# --- degenerate motions (docs/DESIGN.md), suspension off, on the dense reference ---------------


def test_straight_driving_leaves_the_wheelbase_ratio_and_tracks(car):
    """No turn: the steering reads its offset (determined), nothing tells the ratio, the
    wheelbase or the tracks; the accelerometer's horizontal bias stays with roll and pitch."""
    assert_null_space_is(drive(profile(VARIED_SPEED, 0.0), Suspension.rigid()), car, {
        "wheel.track_front", "wheel.track_rear", "wheel.wheelbase", "steering.ratio",
        "imu.accel_bias_x", "imu.accel_bias_y"})


def test_turns_both_ways_determine_everything(car):
    assert_null_space_is(drive(profile(VARIED_SPEED, BOTH_WAYS), Suspension.rigid()), car, set())


def test_one_constant_curvature_leaves_four_combinations(car):
    """Each reading is then one number: the rear wheels' two of (scale_rl, scale_rr, track_rear),
    the front ones' two of (scale_fl, scale_fr, track_front, wheelbase), the steering's one of
    (ratio, offset, wheelbase): 9 unknowns, 5 numbers, 4 combinations undetermined; none of them
    the scale factors alone (the speed changes scale them)."""
    spec, _ = dense_analysis(drive(profile(VARIED_SPEED, 0.08), Suspension.rigid()), car)
    names = [c.name for c in car.scored]
    wheel = [n for n in names if n.startswith(("wheel.", "steering."))]
    N = spec.null_space
    assert spec.nullity == 4
    outside = [names.index(n) for n in names if n not in wheel]
    assert (N[outside] ** 2).sum(axis=1).max() < 1e-6  # within the wheels' coordinates
    w = null_weights(spec, car)
    assert w["steering.offset"] > 0.9 and w["wheel.wheelbase"] > 0.5
    assert 0.05 < w["wheel.scale_fl"] < 0.9  # coupled, not undetermined alone
    assert w["wheel.time_offset"] < 1e-6


def test_turns_one_way_determine_the_offset_by_extrapolation(car):
    """Turns one way only (0.05–0.07 1/m, never straight) leave nothing undetermined, but the
    offset (the reading at κ = 0) is extrapolated from the curvatures driven: its σ is 2.5 × that
    of turns both ways over the same time; a straight stretch brings it back."""
    sig = {}
    for label, curv in (("both", BOTH_WAYS), ("one way", 0.06 + 0.01 * np.sin(KNOTS / 5)),
                        ("straight and one way", 0.04 + 0.04 * np.sin(KNOTS / 5))):
        spec, _ = dense_analysis(drive(profile(VARIED_SPEED, curv), Suspension.rigid()), car)
        assert spec.nullity == 0
        sig[label] = spec.sigma[[c.name for c in car.scored].index("steering.offset")]
    assert 2.2 < sig["one way"] / sig["both"] < 3.2, sig
    assert sig["straight and one way"] < 1.1 * sig["both"], sig


def test_the_wheelbase_needs_turns_at_speed(car):
    """The front wheels' longer path in a turn, ½·L²·κ² per metre, is a speed difference that
    grows with speed at the same curvatures: σ of the wheelbase (and of the ratio, which the
    steering sees only through ratio · wheelbase) falls as 1/speed."""
    sig = {}
    for u in (3.0, 12.0):
        spec, _ = dense_analysis(drive(profile(u * (1 + 0.3 * np.sin(KNOTS / 3)), BOTH_WAYS), Suspension.rigid()), car)
        names = [c.name for c in car.scored]
        sig[u] = {n: spec.sigma[names.index(n)] for n in ("wheel.wheelbase", "steering.ratio")}
    for n in ("wheel.wheelbase", "steering.ratio"):
        assert 3.4 < sig[3.0][n] / sig[12.0][n] < 4.6, (n, sig)


# --- σ of every new parameter against the dense reference -------------------------------------


def _new_sigmas_equal_the_dense_references(rig) -> list[str]:
    """The car's and the radar's scored parameters (on a varied drive both ways over a grade): the
    evaluator's σ equal the dense reference's; their names."""
    traj = drive(profile(VARIED_SPEED, BOTH_WAYS, grade_rad=0.03 * np.sin(KNOTS / 7)), rig.suspension)
    spec, _ = dense_analysis(traj, rig)
    rep = evaluate(traj, rig)
    assert rep.nullity == 0 == spec.nullity
    names = [c.name for c in rig.scored]
    new = [n for n in names if n.startswith(("wheel.", "steering.", "radar_front."))]
    for p in rep.parameters:
        if p.name in new:
            assert p.sigma == pytest.approx(spec.sigma[names.index(p.name)], rel=1e-7), p.name
    return new


def test_sigma_of_every_new_parameter_is_the_dense_references():
    new = _new_sigmas_equal_the_dense_references(build_rig(car_data(radar=True)))
    assert len(new) == 10 + 7


def test_sigma_of_the_radii_and_a_2d_radar_is_the_dense_references():
    """The other two forms: wheel speeds as angular rates (``speeds: radps``, the four radii
    estimated) and a 2-D radar (no elevation)."""
    data = car_data(radar=True)
    data["ackermann"].update(speeds="radps", radius_m=[0.33, 0.331, 0.332, 0.334], speed_noise_density=0.015,
                             speed_quantum=0.0)
    data["sensors"][0]["dimensions"] = 2
    data["targets"]["wheel.radius_*"] = "0.3 mm"
    del data["targets"]["wheel.scale_*"]
    new = _new_sigmas_equal_the_dense_references(build_rig(data))
    assert {f"wheel.radius_{w}" for w in ("fl", "fr", "rl", "rr")} <= set(new) and len(new) == 10 + 7
