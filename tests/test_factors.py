"""Every factor's analytic Jacobian equals central finite differences of its nonlinear model.

The drive is fully 3-D (speed, curvature, grade and bank all vary, suspension on) and the rig's
IMU and sensors are mounted with non-trivial rotations, so that no Jacobian term hides behind a
zero. Perturbations follow the library's conventions: right-multiplicative on rotations, additive
on positions, velocities and scalar parameters.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from excite.core import so3
from excite.factors import imu, nonholonomic, odometry, wheel
from excite.factors.base import Nominal
from excite.rig.config import RIGS_DIR, build_rig
from excite.motion.vehicle import ControlProfile, drive

EPS = 1e-6


@pytest.fixture(scope="module")
def rig():
    data = yaml.safe_load((RIGS_DIR / "robotaxi.yaml").read_text())
    data["imu"]["update_rate"] = 1000  # fine IMU sampling: the bias Jacobians are O(dt) exact
    data["vehicle"]["T_V_B"] = {"translation_m": [1.3, 0.2, 0.5], "rpy_deg": [3.0, -2.0, 10.0]}
    data["sensors"][0]["T_B_S"] = {"translation_m": [0.3, -0.4, 1.1], "rpy_deg": [1.0, 4.0, -30.0]}
    return build_rig(data)


_T = np.linspace(0.0, 6.0, 13)
_PROFILE = ControlProfile(_T, 5 + 2 * np.sin(_T), 0.1 * np.cos(0.7 * _T), grade_rad=0.05 * np.sin(_T),
                          bank_rad=0.04 * np.cos(1.3 * _T))


@pytest.fixture(scope="module")
def nom(rig):
    return Nominal.of(drive(_PROFILE, rig.suspension), rig)


def _fd(fun, n: int) -> np.ndarray:
    cols = []
    for k in range(n):
        d = np.zeros(n)
        d[k] = EPS
        cols.append((fun(d) - fun(-d)) / (2 * EPS))
    return np.stack(cols, axis=1)


def _perturb(R, p, v, d):
    return R @ so3.exp(d[0:3]), p + d[3:6], v + d[6:9]


def _assert_close(analytic, numeric, rtol):
    scale = max(np.abs(numeric).max(), 1e-12)
    err = np.abs(analytic - numeric).max() / scale
    assert err < rtol, f"relative error {err:.2e}\nanalytic\n{analytic}\nnumeric\n{numeric}"


@pytest.fixture(scope="module")
def slow_rig(rig):
    """The same rig with both sensors at 5 Hz: frames every second keyframe."""
    data = rig.config.model_dump()
    for s in data["sensors"]:
        s["rate_hz"] = 5.0
    return build_rig(data)


@pytest.mark.parametrize("sensor_index, slow", [(0, False), (1, False), (0, True), (1, True)],
                         ids=["lidar", "camera optical frame", "lidar at 5 Hz", "camera at 5 Hz"])
def test_odometry_jacobian(rig, slow_rig, nom, sensor_index, slow):
    """Every mounting (a lidar turned 30° in yaw, a monocular camera in its optical frame) and
    every stride (sensor at the keyframe rate and at half of it): the compiled Jacobians equal
    central differences of the nonlinear residual."""
    if slow:
        rig = slow_rig
        nom = Nominal.of(drive(_PROFILE, rig.suspension), rig)
    sensor = rig.config.sensors[sensor_index]
    blk = odometry.blocks(nom, rig, sensor)
    assert blk.stride == (2 if slow else 1)
    f = 7
    i, j = blk.first[f], blk.first[f] + blk.stride
    R_BS, p_BS = sensor.T_B_S.R, sensor.T_B_S.p
    st = lambda k, d: (*_perturb(nom.R[k], nom.p[k], nom.v[k], d), nom.omega[k])
    zero = np.zeros(9)
    Ri, pi = nom.R[i] @ R_BS, nom.p[i] + nom.R[i] @ p_BS
    Rj, pj = nom.R[j] @ R_BS, nom.p[j] + nom.R[j] @ p_BS
    meas = (Ri.T @ Rj, Ri.T @ (pj - pi))
    sig = np.r_[np.full(3, np.deg2rad(sensor.noise.rotation_sigma_deg)), np.full(3, sensor.noise.translation_sigma_m)]

    def r_x(d):
        return odometry.residual(st(i, d[:9]), st(j, d[9:]), R_BS, p_BS, 0.0, 1.0, meas) / sig

    _assert_close(blk.Jx[f], _fd(r_x, 18), 1e-6)

    def r_t(d):
        return odometry.residual(st(i, zero), st(j, zero), R_BS @ so3.exp(d[0:3]), p_BS + d[3:6], d[6], 1.0,
                                 meas) / sig

    cols = [rig.index(f"{sensor.name}.{c}") for c in ("rot_x", "rot_y", "rot_z", "trans_x", "trans_y", "trans_z",
                                                      "time_offset")]
    _assert_close(blk.Jt_full(len(rig.coordinates))[f][:, cols], _fd(r_t, 7), 1e-6)
    others = np.setdiff1d(np.arange(len(rig.coordinates)), cols + ([rig.index(f"{sensor.name}.scale")]
                                                                   if sensor.monocular else []))
    assert np.all(blk.Jt_full(len(rig.coordinates))[f][:, others] == 0)


def test_monocular_scale_jacobian(rig, nom):
    cam = rig.config.sensors[1]
    assert cam.monocular
    blk = odometry.blocks(nom, rig, cam)
    f = 5
    i, j = blk.first[f], blk.first[f] + blk.stride
    R_BS, p_BS = cam.T_B_S.R, cam.T_B_S.p
    st = lambda k: (nom.R[k], nom.p[k], nom.v[k], nom.omega[k])
    RSi, pSi = odometry.sensor_pose(*st(i), R_BS, p_BS, 0.0)
    RSj, pSj = odometry.sensor_pose(*st(j), R_BS, p_BS, 0.0)
    meas = (RSi.T @ RSj, RSi.T @ (pSj - pSi))
    num = _fd(lambda d: odometry.residual(st(i), st(j), R_BS, p_BS, 0.0, 1.0 + d[0], meas), 1)[:, 0]
    num /= np.r_[np.full(3, np.deg2rad(cam.noise.rotation_sigma_deg)), np.full(3, cam.noise.translation_sigma_m)]
    _assert_close(blk.Jt_full(len(rig.coordinates))[f][:, rig.index("cam_front.scale")], num, 1e-6)


def test_imu_jacobian(rig, nom):
    blk = imu.blocks(nom, rig)
    cfg = rig.config.imu
    pre = imu.preintegration(nom, cfg.gyroscope_noise_density, cfg.accelerometer_noise_density)
    W = np.linalg.inv(np.linalg.cholesky(pre["cov"][0]))
    f = 23
    n = nom.imu_per_keyframe
    i, j = f, f + 1
    dT = nom.t[1] - nom.t[0]
    dt = dT / n
    w_s = nom.imu_omega[i * n:(i + 1) * n]
    f_s = nom.imu_f[i * n:(i + 1) * n]
    meas = imu.preintegrate(w_s, f_s, dt, np.zeros(3), np.zeros(3))
    W = np.linalg.inv(np.linalg.cholesky(pre["cov"][f]))

    def r_x(d):
        return W @ imu.residual(*_perturb(nom.R[i], nom.p[i], nom.v[i], d[:9]),
                                *_perturb(nom.R[j], nom.p[j], nom.v[j], d[9:]), meas, dT)

    _assert_close(blk.Jx[f], _fd(r_x, 18), 1e-5)

    def r_b(d):
        m = imu.preintegrate(w_s, f_s, dt, d[0:3], d[3:6])
        return W @ imu.residual(nom.R[i], nom.p[i], nom.v[i], nom.R[j], nom.p[j], nom.v[j], m, dT)

    g0 = rig.index("imu.gyro_bias_x")
    # the analytic bias Jacobian uses ΔR at the sample start: exact to O(ω·dt) (dt = 1 ms here)
    _assert_close(blk.Jt_full(len(rig.coordinates))[f][:, g0:g0 + 6], _fd(r_b, 6), 2e-3)


def test_imu_covariance_matches_monte_carlo(rig, nom):
    """The propagated covariance is the covariance of preintegrating noisy samples."""
    cfg = rig.config.imu
    f, n = 11, nom.imu_per_keyframe
    dT = nom.t[1] - nom.t[0]
    dt = dT / n
    w_s = nom.imu_omega[f * n:(f + 1) * n]
    f_s = nom.imu_f[f * n:(f + 1) * n]
    # inflate the noise so that the sample covariance is far above rounding, still linear regime
    sg, sa = 100 * cfg.gyroscope_noise_density, 100 * cfg.accelerometer_noise_density
    ref = imu.preintegrate(w_s, f_s, dt, np.zeros(3), np.zeros(3))
    rng = np.random.default_rng(0)
    errs = []
    for _ in range(2000):
        wn = w_s + rng.normal(0, sg / np.sqrt(dt), w_s.shape)
        fn = f_s + rng.normal(0, sa / np.sqrt(dt), f_s.shape)
        m = imu.preintegrate(wn, fn, dt, np.zeros(3), np.zeros(3))
        errs.append(np.r_[so3.log(m[0] @ ref[0].T), m[1] - ref[1], m[2] - ref[2]])
    emp = np.cov(np.array(errs).T)
    cov = imu.preintegration(nom, sg, sa)["cov"][f]
    d = np.sqrt(np.diag(cov))
    # correlation-normalised comparison; 2000 samples give ~3 % sampling error per entry
    assert np.abs(emp / np.outer(d, d) - cov / np.outer(d, d)).max() < 0.1
    assert np.allclose(np.sqrt(np.diag(emp)), d, rtol=0.1)


def test_wheel_jacobian(rig, nom):
    blk = wheel.blocks(nom, rig)
    wc = rig.config.wheels
    f = 31
    i, j = f, f + 1
    R_BV = nom.R_V_B.T
    p_BV = -R_BV @ nom.p_V_B
    R_BA = R_BV @ nom.R_V_A

    def r_x(d):
        Ri, pi, _ = _perturb(nom.R[i], nom.p[i], nom.v[i], d[:9])
        Rj, pj, _ = _perturb(nom.R[j], nom.p[j], nom.v[j], d[9:])
        return wheel.increments(Ri, pi, Rj, pj, R_BA[i], R_BA[j], p_BV, wc.radius_left_m, wc.radius_right_m,
                                wc.track_m) / rig.wheel_increment_sigma_rad

    _assert_close(blk.Jx[f], _fd(r_x, 18), 1e-6)

    def r_t(d):
        return wheel.increments(nom.R[i], nom.p[i], nom.R[j], nom.p[j], R_BA[i], R_BA[j], p_BV,
                                wc.radius_left_m + d[0], wc.radius_right_m + d[1], wc.track_m + d[2]) / rig.wheel_increment_sigma_rad

    cols = [rig.index(f"wheel.{k}") for k in ("radius_left", "radius_right", "track")]
    _assert_close(blk.Jt_full(len(rig.coordinates))[f][:, cols], _fd(r_t, 3), 1e-6)


def test_wheel_increments_match_wheel_speeds(rig, nom):
    """The chord model's increments equal the integrated wheel speeds of the trajectory model."""
    wc = rig.config.wheels
    R_BV = nom.R_V_B.T
    p_BV = -R_BV @ nom.p_V_B
    R_BA = R_BV @ nom.R_V_A
    f = 40
    inc = wheel.increments(nom.R[f], nom.p[f], nom.R[f + 1], nom.p[f + 1], R_BA[f], R_BA[f + 1], p_BV,
                           wc.radius_left_m, wc.radius_right_m, wc.track_m)
    # independent: integrate the wheel speeds of the vehicle-frame motion over the interval
    from excite.motion.vehicle import ControlProfile as _  # noqa: F401  (same drive as the fixture)
    t = np.linspace(nom.t[f], nom.t[f + 1], 201)
    ts = np.linspace(0.0, 6.0, 13)
    prof = ControlProfile(ts, 5 + 2 * np.sin(ts), 0.1 * np.cos(0.7 * ts), grade_rad=0.05 * np.sin(ts),
                          bank_rad=0.04 * np.cos(1.3 * ts))
    s = drive(prof, rig.suspension).sample(t)
    ws = s.wheel_speeds(wc.radius_left_m, wc.radius_right_m, wc.track_m)
    integ = np.trapezoid(ws, t, axis=0)
    assert np.allclose(inc, integ, rtol=2e-3), (inc, integ)


def test_nonholonomic_jacobian(rig, nom):
    blk = nonholonomic.blocks(nom, rig)
    k = 19
    R_BV = nom.R_V_B.T
    p_BV = -R_BV @ nom.p_V_B
    R_BA = R_BV @ nom.R_V_A[k]
    sig = np.array(rig.nonholonomic_sigma_mps)

    def r_x(d):
        R, _, v = _perturb(nom.R[k], nom.p[k], nom.v[k], d)
        return nonholonomic.residual(R, v, nom.omega[k], R_BA, p_BV) / sig

    _assert_close(blk.Jx[k], _fd(r_x, 9), 1e-6)
    # and the generated drive satisfies the constraint it linearises
    assert np.abs(nonholonomic.residual(nom.R[k], nom.v[k], nom.omega[k], R_BA, p_BV)).max() < 1e-3


def test_wheel_slip_column_is_the_derivative_of_the_slipping_wheels(rig, nom):
    """``wheel.slip``: the angles times ``1 + slip·ā/g`` (the calibrator's nonlinear model),
    differentiated at slip 0; and ā is the drive's mean longitudinal acceleration over the
    interval (integrated independently from the drive's own acceleration)."""
    from excite.validate.calibrate import States, wheel_increments

    blk = wheel.blocks(nom, rig)
    wc = rig.config.wheels
    R_BV = nom.R_V_B.T
    p_BV = -R_BV @ nom.p_V_B
    R_BA = R_BV @ nom.R_V_A
    dT = nom.t[1] - nom.t[0]
    X = States(nom.R, nom.p, nom.v)

    def r(d):
        return wheel_increments(X, nom.omega, R_BA, p_BV, wc.radius_left_m, wc.radius_right_m, wc.track_m, d[0],
                                dT) / rig.wheel_increment_sigma_rad

    col = rig.index("wheel.slip")
    fd = _fd(r, 1)[:, 0, :]  # (intervals, 2)
    _assert_close(blk.Jt_full(len(rig.coordinates))[:, :, col], fd, 1e-6)
    assert np.abs(fd).max() > 0.1  # the drive accelerates: the column is not zero
    f = 31
    t = np.linspace(nom.t[f], nom.t[f + 1], 201)
    a_long = drive(_PROFILE, rig.suspension).sample(t).accel_long
    along = wheel.longitudinal_accel_g(nom.R @ R_BA, wheel.axle_velocity(nom.R, nom.v, nom.omega, p_BV), dT)
    assert along[f] * wheel.G_MPS2 == pytest.approx(np.trapezoid(a_long, t) / dT, rel=1e-3)


def test_slip_angle_column_is_the_derivative_of_the_sliding_axle(rig, nom):
    """``vehicle.slip_angle``: the lateral row plus ``slip_angle·u·(u·ψ̇)/g`` (the nonlinear model),
    differentiated at zero; and ``u·ψ̇`` is the drive's lateral acceleration (no sideways slide in
    the generated drive, so the centripetal part is all of it, up to grade and bank)."""
    blk = nonholonomic.blocks(nom, rig)
    R_BV = nom.R_V_B.T
    p_BV = -R_BV @ nom.p_V_B
    sig = np.array(rig.nonholonomic_sigma_mps)
    col = rig.index("vehicle.slip_angle")
    Jt = blk.Jt_full(len(rig.coordinates))[:, :, col]
    for k in (7, 19, 44):
        R_BA = R_BV @ nom.R_V_A[k]
        fd = _fd(lambda d: nonholonomic.residual(nom.R[k], nom.v[k], nom.omega[k], R_BA, p_BV, d[0]) / sig, 1)
        _assert_close(Jt[k], fd[:, 0], 1e-6)
    s = drive(_PROFILE, rig.suspension).sample(nom.t)
    u = s.speed
    R_BA = R_BV @ nom.R_V_A
    reg = nonholonomic.lateral_slip_regressor(nom.R @ R_BA, wheel.axle_velocity(nom.R, nom.v, nom.omega, p_BV),
                                              nom.omega, R_BA)
    assert np.abs(Jt[:, 1]).max() == 0.0  # the vertical row does not slide
    assert np.abs(reg * wheel.G_MPS2 / u - s.accel_lat).max() < 0.05 * np.abs(s.accel_lat).max() + 0.02
