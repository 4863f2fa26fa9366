"""The contract of every registered measurement kind (:mod:`excite.factors`).

For every kind and every entry of two rigs (the robotaxi's with a GNSS antenna: both odometry
sensors and the antenna, at the keyframe rate and at half of it, the IMU, the wheels, the
non-holonomic constraint; the sedan's: a car's four CAN wheel speeds and steering angle, a 3-D and
a 2-D Doppler radar, at the keyframe rate and at half of it; the CAN wheel speeds as angular rates
too), and every kind's opening factor (a GNSS antenna's first fix):

- the derivative of its one residual (CasADi's automatic differentiation) equals central finite
  differences of the same residual, evaluated numerically;
- the evaluator's kernel generated from that statement (:mod:`excite.factors.generate`, compiled
  into the native module) equals the derivative evaluated in CasADi's virtual machine;
- the residual is zero at the noise-free measurement of the nominal motion;
- the gauge symmetries it claims not to break (translation, yaw about the vertical) leave its
  residual unchanged: the Jacobian annihilates their generators.

The drive is fully 3-D (speed, curvature, grade and bank all vary, suspension on) and the rig's
IMU and sensors are mounted with non-trivial rotations, so that no Jacobian term hides behind a
zero. Perturbations follow the library's conventions: right-multiplicative on rotations, additive
on positions, velocities and scalar parameters. Then the physics the factors stand for: the
IMU's propagated covariance against a Monte Carlo of noisy samples, the preintegration's fold
(as the evaluator runs it) against the sums over the samples' noise written out here, the wheel
model against integrated wheel speeds, the slip columns against the drive's own accelerations.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from excite.scene import shapes
from excite.scene.along import seen

from excite.core import so3
from excite.factors import base as registry
from excite.factors import imu, kernels, layout, symbolic, wheel
from excite.factors.base import Nominal
from excite.factors.nonholonomic import sigma_mps
from excite.motion.vehicle import ControlProfile, drive
from excite.rig.config import RIGS_DIR, build_rig

EPS = 1e-6


GNSS = {"name": "gnss", "kind": "gnss", "rate_hz": 10.0, "T_B_S": {"translation_m": [0.4, -0.3, 1.6]},
        "noise": {"horizontal_sigma_m": 0.02, "vertical_sigma_m": 0.05, "correlation_time_s": 3.0}}


def _data():
    """The bundled rig's YAML with a GNSS antenna (a kind no bundled rig has)."""
    data = yaml.safe_load((RIGS_DIR / "robotaxi.yaml").read_text())
    data["sensors"].append(dict(GNSS))
    return data


def _instances(rig):
    """Every instance of ``rig`` and every opening factor of its kinds (unregistered kinds that the
    closure adds where a drive starts)."""
    return list(registry.instances(rig)) + list(registry.openings(rig))


@pytest.fixture(scope="module")
def rig():
    data = _data()
    data["imu"]["update_rate"] = 1000  # fine IMU sampling: the bias Jacobians are O(dt) exact
    data["vehicle"]["T_V_B"] = {"translation_m": [1.3, 0.2, 0.5], "rpy_deg": [3.0, -2.0, 10.0]}
    data["sensors"][0]["T_B_S"] = {"translation_m": [0.3, -0.4, 1.1], "rpy_deg": [1.0, 4.0, -30.0]}
    return build_rig(data)


@pytest.fixture(scope="module")
def slow_rig(rig):
    """The same rig with both sensors at 5 Hz: frames every second keyframe."""
    data = rig.config.model_dump()
    for s in data["sensors"]:
        s["rate_hz"] = 5.0
    return build_rig(data)


def _car_data(speeds: str = "mps") -> dict:
    """The bundled sedan, its IMU and radars mounted with non-trivial rotations, a 2-D radar added."""
    data = yaml.safe_load((RIGS_DIR / "sedan.yaml").read_text())
    data["imu"]["update_rate"] = 1000
    data["vehicle"]["T_V_B"] = {"translation_m": [1.3, 0.2, 0.5], "rpy_deg": [3.0, -2.0, 10.0]}
    data["sensors"][0]["T_B_S"] = {"translation_m": [2.1, -0.3, 0.2], "rpy_deg": [2.0, -3.0, 25.0]}
    data["sensors"].append({"name": "radar_corner", "kind": "radar", "rate_hz": 10, "dimensions": 2,
                            "T_B_S": {"translation_m": [2.0, 0.8, 0.1], "rpy_deg": [1.0, 2.0, 60.0]},
                            "noise": {"doppler_sigma_mps": 0.1, "stationary_targets": 4}})
    data["ackermann"]["track_front_m"] = 1.61  # the two tracks apart
    if speeds == "radps":
        data["ackermann"].update(speeds="radps", radius_m=[0.33, 0.331, 0.332, 0.334], speed_noise_density=0.015,
                                 speed_quantum=0.008)
        data["targets"]["wheel.radius_*"] = "0.3 mm"
        del data["targets"]["wheel.scale_*"]
    return data


@pytest.fixture(scope="module")
def car_rig():
    return build_rig(_car_data())


@pytest.fixture(scope="module")
def slow_car_rig():
    data = _car_data()
    for s in data["sensors"]:
        s["rate_hz"] = 5.0
    return build_rig(data)


@pytest.fixture(scope="module")
def radps_car_rig():
    return build_rig(_car_data("radps"))


_T = np.linspace(0.0, 6.0, 13)
_PROFILE = ControlProfile(_T, 5 + 2 * np.sin(_T), 0.1 * np.cos(0.7 * _T), grade_rad=0.05 * np.sin(_T),
                          bank_rad=0.04 * np.cos(1.3 * _T))


def _nominal(rig, inst=None):
    """The nominal of the test drive; for a kind whose factors need a scene (a lidar's road
    plane), the drive seeing an open lot."""
    traj = drive(_PROFILE, rig.suspension)
    if inst is not None and inst.kind.name == "ground_plane":
        traj = seen(traj, rig, shapes.ground(-300.0, -300.0, 300.0, 300.0))
    return Nominal.of(traj, rig)


def _cases():
    """(id, which rig, instance index) of every instance of the rigs."""
    out = []
    for base, which in ((build_rig(_data()), ""), (build_rig(_car_data()), "car")):
        out += [(f"{i.name}", which or "rig", k) for k, i in enumerate(_instances(base))
                if not which or i.kind.name in ("ackermann", "radar")]
        out += [(f"{i.name} at 5 Hz", f"slow{which}", k) for k, i in enumerate(_instances(base))
                if i.kind.sensor_kinds]
    out += [("ackermann in rad/s", "radps", k) for k, i in enumerate(_instances(build_rig(_car_data("radps"))))
            if i.kind.name == "ackermann"]
    return out


CASES = _cases()


def _instance(request, rig, slow_rig, which, k):
    r = {"rig": rig, "slow": slow_rig}.get(which) or request.getfixturevalue(
        {"car": "car_rig", "slowcar": "slow_car_rig", "radps": "radps_car_rig"}[which])
    return r, _instances(r)[k]


def _assert_close(analytic, numeric, rtol):
    scale = max(np.abs(numeric).max(), 1e-12)
    err = np.abs(analytic - numeric).max() / scale
    assert err < rtol, f"relative error {err:.2e}\nanalytic\n{analytic}\nnumeric\n{numeric}"


def _factor_inputs(nom, rig, inst, f):
    """The flat inputs of factor ``f`` of ``inst`` (see :mod:`excite.factors.symbolic`)."""
    kind, entry = inst.kind, inst.entry
    lay = symbolic.layout(kind, rig, entry)
    first = registry.factor_keyframes(kind, rig, entry, nom.n_keyframes)[f:f + 1]
    return (lay, symbolic.keyframe_inputs(nom, first, lay.arity, registry.stride(kind, rig, entry))[0],
            symbolic.sample_inputs(nom, first, lay)[0], symbolic.quantity_inputs(lay))


def _moved(x: np.ndarray, q: np.ndarray, lay, dx: np.ndarray, dq: np.ndarray):
    """Inputs moved by a world-state step ``dx`` (exact: ``R Exp(δθ)``) and a coordinate step ``dq``."""
    x, q = x.copy(), q.copy()
    for a in range(lay.arity):
        o = symbolic.KEYFRAME_INPUTS * a
        d = dx[9 * a:9 * (a + 1)]
        x[o:o + 9] = (x[o:o + 9].reshape(3, 3) @ so3.exp(d[0:3][None])[0]).ravel()
        x[o + 9:o + 12] += d[3:6]
        x[o + 12:o + 15] += d[6:9]
    o = e = 0
    for qt in lay.quantities:
        size = qt.nominal_vector().size
        if qt.estimated:
            if qt.rotation:
                q[o:o + 9] = (q[o:o + 9].reshape(3, 3) @ so3.exp(dq[e:e + 3][None])[0]).ravel()
            else:
                q[o:o + size] += dq[e:e + qt.size]
            e += qt.size
        o += size
    return x, q


@pytest.mark.parametrize("name, which, k", CASES, ids=[c[0] for c in CASES])
def test_the_derivative_of_the_residual_equals_finite_differences(request, rig, slow_rig, name, which, k):
    r, inst = _instance(request, rig, slow_rig, which, k)
    nom = _nominal(r, inst)
    f = min(5, registry.factor_keyframes(inst.kind, r, inst.entry, nom.n_keyframes).size - 1)
    lay, x, s, q = _factor_inputs(nom, r, inst, f)
    Jx, Jt = (np.array(a) for a in symbolic.linearisation(inst.kind, r, inst.entry)(x, s, q))
    meas = np.array(symbolic.measurement_function(inst.kind, r, inst.entry)(x, s, q)).ravel()
    res = symbolic.residual_function(inst.kind, r, inst.entry)
    n_x, n_t = 9 * lay.arity, lay.n_theta

    def at(d):
        xm, qm = _moved(x, q, lay, d[:n_x], d[n_x:])
        return np.array(res(xm, s, qm, meas)).ravel()

    cols = []
    for i in range(n_x + n_t):
        d = np.zeros(n_x + n_t)
        d[i] = EPS
        cols.append((at(d) - at(-d)) / (2 * EPS))
    fd = np.stack(cols, axis=1)
    _assert_close(Jx, fd[:, :n_x], 1e-6)
    if n_t:
        _assert_close(Jt, fd[:, n_x:], 1e-6)
    assert np.abs(at(np.zeros(n_x + n_t))).max() < 1e-9  # zero at its own measurement


@pytest.mark.parametrize("name, which, k", CASES, ids=[c[0] for c in CASES])
def test_the_generated_kernel_equals_the_derivative_of_the_residual(request, rig, slow_rig, name, which, k):
    r, inst = _instance(request, rig, slow_rig, which, k)
    nom = _nominal(r, inst)
    lay = layout.layout(inst.kind, r, inst.entry)
    assert lay.name("lin") in kernels.compiled(), f"{lay.name('lin')} is not compiled in"
    fast = kernels.jacobians(inst.kind, nom, r, inst.entry)
    first = registry.factor_keyframes(inst.kind, r, inst.entry, nom.n_keyframes, nom)
    ref = symbolic.blocks(inst.kind, nom, r, inst.entry,
                          whitening=inst.kind.whitening(nom, r, inst.entry, first))
    assert np.array_equal(fast.first, ref.first) and fast.stride == ref.stride and fast.n_states == ref.n_states
    P = len(r.coordinates)
    _assert_close(fast.Jx, ref.Jx, 1e-12)
    _assert_close(fast.Jt_full(P), ref.Jt_full(P), 1e-12)


@pytest.mark.parametrize("name, which, k", CASES, ids=[c[0] for c in CASES])
def test_the_symmetries_a_kind_keeps_leave_its_residual_unchanged(request, rig, slow_rig, name, which, k):
    """A kind that does not break translation sees positions through differences only (the
    evaluator's local states rely on it); one that does not break yaw is invariant to a rotation
    of the whole drive about the vertical."""
    r, inst = _instance(request, rig, slow_rig, which, k)
    nom = _nominal(r, inst)
    blk = symbolic.blocks(inst.kind, nom, r, inst.entry)
    ks = blk.first[:, None] + blk.stride * np.arange(blk.n_states)[None, :]
    Jx = blk.Jx.reshape(blk.n_factors, blk.n_rows, blk.n_states, 9)
    scale = np.abs(Jx).max()
    if "position" not in inst.kind.breaks:
        assert np.abs(Jx[..., 3:6].sum(axis=2)).max() <= 1e-9 * scale
    if "yaw" not in inst.kind.breaks:
        ez = np.array([0.0, 0.0, 1.0])
        g = np.concatenate([np.einsum("nkji,j->nki", nom.R[ks], ez), np.cross(ez, nom.p[ks]), np.cross(ez, nom.v[ks])],
                           axis=2)  # (N, states, 9): δθ = Rᵀe_z, δp = e_z × p, δv = e_z × v
        assert np.abs(np.einsum("nrsc,nsc->nr", Jx, g)).max() <= 1e-9 * scale * max(1.0, np.abs(nom.p).max())


def test_the_unwhitened_derivative_of_the_road_plane_equals_finite_differences(rig):
    """The road plane's rows are whitened by the scene only (its statement's whitening is zero):
    its derivative, not whitened, against finite differences of its measurement."""
    inst = next(i for i in registry.instances(rig) if i.kind.name == "ground_plane")
    nom = _nominal(rig, inst)
    lay, x, s, q = _factor_inputs(nom, rig, inst, 5)
    Jx, Jt = (np.array(a) for a in symbolic.raw_linearisation(inst.kind, rig, inst.entry)(x, s, q))
    meas = symbolic.measurement_function(inst.kind, rig, inst.entry)
    n_x, n_t = 9 * lay.arity, lay.n_theta
    cols = []
    for i in range(n_x + n_t):
        d = np.zeros(n_x + n_t)
        d[i] = EPS
        up, dn = _moved(x, q, lay, d[:n_x], d[n_x:]), _moved(x, q, lay, -d[:n_x], -d[n_x:])
        cols.append((np.array(meas(up[0], s, up[1])) - np.array(meas(dn[0], s, dn[1]))).ravel() / (2 * EPS))
    fd = np.stack(cols, axis=1)
    assert np.abs(fd[:, n_x:]).max() > 0.1  # it sees the lidar's extrinsic
    _assert_close(Jt, fd[:, n_x:], 1e-6)
    assert np.abs(Jx).max() == 0.0 and np.abs(fd[:, :n_x]).max() < 1e-9  # and no state


def test_every_registered_kind_is_covered(rig, car_rig):
    covered = {i.kind.name for r in (rig, car_rig) for i in registry.instances(r)}
    assert covered == {k.name for k in registry.kinds()}


# --- the physics ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def nom(rig):
    return _nominal(rig)


def _noise_propagation(nom, f: int, dt: float, sg: float, sa: float) -> dict[str, np.ndarray]:
    """The preintegrated measurement's bias Jacobians and covariance of interval ``f``, written
    out from their definitions (not from the library's fold): with ``ΔR_s = R_iᵀR(τ_s)``,
    ``A_s = [ΔR_s f_s dt]×`` and ``G_s = Σ_{q<s} ΔR_q dt``: ``G_R = Σ ΔR_s dt``, ``V_g = Σ A_s G_s``,
    ``P_g = Σ (V_g,s dt + ½ A_s G_s dt)`` (``V_g,s`` the partial sum before s),
    ``P_a = −Σ (G_s dt + ½ ΔR_s dt²)``; a gyro noise sample at s (variance σ_g² dt) reaches the end
    as ``[−I; Σ_{q>s} A_q; Σ_{q>s} w_q A_q]``, an accelerometer one (σ_a² dt) as ``[0; −I; −w_s I]``,
    ``w_q = (n − 1 − q + ½) dt``; the covariance is the sum of their outer products."""
    n = nom.imu_per_keyframe
    i0 = f * n
    dR = [nom.imu_R[i0].T @ nom.imu_R[i0 + s] for s in range(n)]
    A = [so3.hat(dR[s] @ nom.imu_f[i0 + s] * dt) for s in range(n)]
    w = [(n - 1 - q + 0.5) * dt for q in range(n)]
    G = np.zeros((3, 3))
    V_g, P_g, P_a = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3))
    for s in range(n):
        P_g += V_g * dt + 0.5 * dt * A[s] @ G
        P_a -= G * dt + 0.5 * dt * dt * dR[s]
        V_g += A[s] @ G
        G += dR[s] * dt
    cov = np.zeros((9, 9))
    for s in range(n):
        B = np.vstack([-np.eye(3), sum((A[q] for q in range(s + 1, n)), np.zeros((3, 3))),
                       sum((w[q] * A[q] for q in range(s + 1, n)), np.zeros((3, 3)))])
        C = np.vstack([np.zeros((3, 3)), -np.eye(3), -w[s] * np.eye(3)])
        cov += sg * sg * dt * B @ B.T + sa * sa * dt * C @ C.T
    return {"G_R": G, "V_g": V_g, "P_g": P_g, "P_a": P_a, "cov": cov}


def _fold(rig, nom, f: int, sg: float | None = None, sa: float | None = None) -> dict[str, np.ndarray]:
    """The summary of interval ``f`` as the evaluator computes it (the generated fold), with the
    rig's noise densities or ``sg``, ``sa``."""
    inst = next(i for i in registry.instances(rig) if i.kind.name == "imu")
    lay = layout.layout(inst.kind, rig, inst.entry)
    values = layout.constant_values(inst.kind, rig, inst.entry)
    if sg is not None:
        values.update(sigma_g=np.array(sg), sigma_a=np.array(sa))
    c = layout.constant_inputs(lay, values)
    flat = kernels.summaries(nom, np.array([f]), lay, ("step_imu", "step2_imu", "finish_imu"), c)[0]
    out, o = {}, 0
    for key, shape in inst.kind.summary_fields:
        size = int(np.prod(shape))
        out[key] = flat[o:o + size].reshape(shape)
        o += size
    return out


def test_the_preintegration_fold_equals_the_noise_propagation(rig, nom):
    cfg = rig.config.imu
    for f in (3, 17):
        got = _fold(rig, nom, f)
        want = _noise_propagation(nom, f, 1.0 / cfg.update_rate, cfg.gyroscope_noise_density,
                                  cfg.accelerometer_noise_density)
        for key in want:
            _assert_close(got[key], want[key], 1e-11)


def test_the_imu_bias_jacobian_is_the_derivative_of_preintegrating_again(rig, nom):
    """The residual corrects the preintegrated measurement for the biases to first order; that is
    the derivative of preintegrating the samples again with the biases subtracted (to O(ω·dt):
    the Jacobians take the attitude at a sample's start, the measurement its middle)."""
    inst = next(i for i in registry.instances(rig) if i.kind.name == "imu")
    blk = kernels.jacobians(inst.kind, nom, rig, inst.entry)
    f, n = 23, nom.imu_per_keyframe
    cfg = rig.config.imu
    dt = 1.0 / cfg.update_rate
    W = np.linalg.inv(np.linalg.cholesky(_fold(rig, nom, f)["cov"]))
    w_s, f_s = nom.imu_omega[f * n:(f + 1) * n], nom.imu_f[f * n:(f + 1) * n]
    ref = imu.preintegrate_all(w_s, f_s, n, dt, np.zeros(3), np.zeros(3))

    def r_b(d):
        m = imu.preintegrate_all(w_s, f_s, n, dt, d[0:3], d[3:6])
        return W @ np.r_[so3.log(ref[0][0] @ m[0][0].T), ref[1][0] - m[1][0], ref[2][0] - m[2][0]]

    fd = np.stack([(r_b(e) - r_b(-e)) / (2 * EPS) for e in np.eye(6) * EPS], axis=1)
    g0 = rig.index("imu.gyro_bias_x")
    _assert_close(blk.Jt_full(len(rig.coordinates))[f][:, g0:g0 + 6], fd, 2e-3)


@pytest.mark.montecarlo
def test_imu_covariance_matches_monte_carlo(rig, nom):
    """The propagated covariance is the covariance of preintegrating noisy samples."""
    cfg = rig.config.imu
    f, n = 11, nom.imu_per_keyframe
    dt = 1.0 / cfg.update_rate
    w_s = nom.imu_omega[f * n:(f + 1) * n]
    f_s = nom.imu_f[f * n:(f + 1) * n]
    # inflate the noise so that the sample covariance is far above rounding, still linear regime
    sg, sa = 100 * cfg.gyroscope_noise_density, 100 * cfg.accelerometer_noise_density
    rng = np.random.default_rng(0)
    M = 2000
    wn = w_s[None] + rng.normal(0, sg / np.sqrt(dt), (M,) + w_s.shape)
    fn = f_s[None] + rng.normal(0, sa / np.sqrt(dt), (M,) + f_s.shape)
    ref = imu.preintegrate_all(w_s, f_s, n, dt, np.zeros(3), np.zeros(3))
    m = imu.preintegrate_all(wn.reshape(-1, 3), fn.reshape(-1, 3), n, dt, np.zeros(3), np.zeros(3))
    errs = np.hstack([so3.log(m[0] @ ref[0][0].T), m[1] - ref[1][0], m[2] - ref[2][0]])
    emp = np.cov(errs.T)
    cov = _fold(rig, nom, f, sg, sa)["cov"]
    d = np.sqrt(np.diag(cov))
    # correlation-normalised comparison; 2000 samples give ~3 % sampling error per entry
    assert np.abs(emp / np.outer(d, d) - cov / np.outer(d, d)).max() < 0.1
    assert np.allclose(np.sqrt(np.diag(emp)), d, rtol=0.1)


def _measured(rig, nom, name):
    inst = next(i for i in registry.instances(rig) if i.name == name)
    first = registry.factor_keyframes(inst.kind, rig, inst.entry, nom.n_keyframes)
    return inst, symbolic.measurements(inst.kind, nom, rig, inst.entry, first)


def test_wheel_increments_match_wheel_speeds(rig, nom):
    """The chord model's increments equal the integrated wheel speeds of the trajectory model."""
    wc = rig.config.wheels
    _, inc = _measured(rig, nom, "wheel")
    f = 40
    t = np.linspace(nom.t[f], nom.t[f + 1], 201)
    s = drive(_PROFILE, rig.suspension).sample(t)
    integ = np.trapezoid(s.wheel_speeds(wc.radius_left_m, wc.radius_right_m, wc.track_m), t, axis=0)
    assert np.allclose(inc[f], integ, rtol=2e-3), (inc[f], integ)


def test_the_generated_drive_satisfies_the_nonholonomic_constraint(rig, nom):
    _, v = _measured(rig, nom, "nonholonomic")
    assert np.abs(v).max() < 1e-3


def test_wheel_slip_column_is_the_drives_longitudinal_acceleration(rig, nom):
    """``wheel.slip``: the angles times ``1 + slip·ā/g``; its column is ``inc · ā/g`` with ā the
    drive's mean longitudinal acceleration over the interval (integrated independently from the
    drive's own acceleration)."""
    inst, inc = _measured(rig, nom, "wheel")
    blk = kernels.jacobians(inst.kind, nom, rig, inst.entry)
    col = blk.Jt_full(len(rig.coordinates))[:, :, rig.index("wheel.slip")] * wheel.increment_sigma_rad(
        rig.config.wheels, rig.keyframe_rate_hz)
    f = 31
    t = np.linspace(nom.t[f], nom.t[f + 1], 201)
    a_long = np.trapezoid(drive(_PROFILE, rig.suspension).sample(t).accel_long, t) / (t[-1] - t[0])
    assert np.abs(col).max() > 0.1 * wheel.increment_sigma_rad(rig.config.wheels, rig.keyframe_rate_hz)
    _assert_close(col[f], inc[f] * a_long / wheel.G_MPS2, 2e-3)


def test_wheel_scrub_column_is_the_square_of_the_drives_lateral_acceleration(rig, nom):
    """``wheel.scrub``: the angles times ``1 + scrub·(a_y/g)²``; its column is ``inc · (a_y/g)²``
    with a_y the drive's lateral acceleration over the interval (the generated drive's own
    ``accel_lat`` averaged, independently of the factor's Δs·Δψ/ΔT²); zero on a straight."""
    inst, inc = _measured(rig, nom, "wheel")
    blk = kernels.jacobians(inst.kind, nom, rig, inst.entry)
    col = blk.Jt_full(len(rig.coordinates))[:, :, rig.index("wheel.scrub")] * wheel.increment_sigma_rad(
        rig.config.wheels, rig.keyframe_rate_hz)
    s = drive(_PROFILE, rig.suspension)
    worst = 0.0
    for f in (12, 31, 47):
        t = np.linspace(nom.t[f], nom.t[f + 1], 201)
        a_lat = np.trapezoid(s.sample(t).accel_lat, t) / (t[-1] - t[0])
        _assert_close(col[f], inc[f] * (a_lat / wheel.G_MPS2) ** 2, 2e-2)
        worst = max(worst, abs(a_lat))
    assert worst > 0.5  # the intervals turn (m/s²)


def test_slip_angle_column_is_the_drives_lateral_acceleration(rig, nom):
    """``vehicle.slip_angle``: the lateral row plus ``slip_angle·u·(u·ψ̇)/g``; ``u·ψ̇`` is the
    drive's lateral acceleration (no sideways slide in the generated drive, so the centripetal part
    is all of it, up to grade and bank)."""
    inst = next(i for i in registry.instances(rig) if i.name == "nonholonomic")
    blk = kernels.jacobians(inst.kind, nom, rig, inst.entry)
    lat, _ = sigma_mps(rig.config.vehicle.nonholonomic, rig.keyframe_rate_hz)
    Jt = blk.Jt_full(len(rig.coordinates))[:, :, rig.index("vehicle.slip_angle")]
    s = drive(_PROFILE, rig.suspension).sample(nom.t)
    assert np.abs(Jt[:, 1]).max() == 0.0  # the vertical row does not slide
    a_lat = Jt[:, 0] * lat * wheel.G_MPS2 / s.speed
    assert np.abs(a_lat - s.accel_lat).max() < 0.05 * np.abs(s.accel_lat).max() + 0.02
