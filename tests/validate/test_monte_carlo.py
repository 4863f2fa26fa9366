"""The predicted σ against simulation: sensor simulator, nonlinear batch calibration, Monte Carlo.

Contract tests first (the estimator's models are the factors' models, its Jacobian is the
derivative of its residual, noise-free data is explained exactly and calibrates to the truth),
then two small Monte Carlo runs with statistically justified bounds: a full-rank drive whose
empirical σ must match the evaluator's, and a planar drive without suspension whose vertical
lever arms must stay exactly where the start put them while the rest matches. The N ≥ 100 runs
of the README come from ``benchmarks/bench_validate.py``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp
import yaml
from scipy.stats import chi2

from excite.cli.app import main as cli
from excite.core import so3
from excite.score.evaluate import evaluate
from excite.factors.imu import preintegrate_all
from excite.factors.wheel import increment_sigma_rad
from excite.motion.maneuvers import figure_eight
from excite.rig.config import RIGS_DIR, build_rig, load_rig
from excite.io.routes import write_control_csv
from excite.validate.calibrate import SolverSettings, States, _Normal, _Problem, calibrate, initialise, perturbed_states
from excite.validate.monte_carlo import MonteCarloSettings, monte_carlo, run_trial
from excite.errors import FactorisationError, ValidateError
from excite.validate.simulate import Calibration, SimulationSettings, offset_sigma, simulate
from excite.motion.vehicle import ControlProfile, Suspension, drive
from helpers import hilly
from helpers import REPO

N_SCORED = 23


def _rig(suspension: bool = True):
    data = yaml.safe_load((RIGS_DIR / "robotaxi.yaml").read_text())
    data["imu"]["update_rate"] = 100  # coarse and cheap; the models hold at any rate
    if not suspension:
        data["vehicle"]["suspension"] = {"pitch_deg_per_mps2": 0.0, "roll_deg_per_mps2": 0.0}
    return build_rig(data)


@pytest.fixture(scope="module")
def rig():
    return _rig()


@pytest.fixture(scope="module")
def short_drive(rig):
    t = np.linspace(0.0, 4.0, 9)
    prof = ControlProfile(t, 5 + 2 * np.sin(t), 0.1 * np.cos(0.7 * t), grade_rad=0.05 * np.sin(t),
                          bank_rad=0.04 * np.cos(1.3 * t))
    return drive(prof, rig.suspension)


def _offset(rig, rng, in_targets=3.0):
    return rng.normal(0.0, 1.0, len(rig.coordinates)) * offset_sigma(rig, in_targets, 0.02)


# --- the calibration value -------------------------------------------------------------------

def test_calibration_plus_minus_round_trip(rig):
    rng = np.random.default_rng(0)
    nom = Calibration.nominal(rig)
    d = _offset(rig, rng, 50.0)
    cal = nom.plus(rig, d)
    assert np.allclose(cal.minus(nom, rig), d, atol=1e-12)
    assert np.allclose(nom.minus(nom, rig), 0.0)
    # rotations on the right, the rest additive
    i = rig.index("lidar.rot_x")
    assert np.allclose(cal.rotation("lidar"), nom.rotation("lidar") @ so3.exp(d[None, i:i + 3])[0], atol=1e-12)
    assert cal.scalar("wheel", "track") == pytest.approx(nom.scalar("wheel", "track") + d[rig.index("wheel.track")])
    with pytest.raises(ValidateError):
        nom.plus(rig, np.zeros(3))


# --- the estimator's models are the factors' models ---------------------------------------------

def test_the_imu_measurement_is_the_sample_by_sample_preintegration(rig, short_drive):
    """The estimator's measurement of the IMU (all intervals at once, vectorised) is the plain
    loop over samples: each held over dt, its specific force applied in the attitude of the
    sample's middle, the biases subtracted."""
    rng = np.random.default_rng(1)
    cal = Calibration.nominal(rig).plus(rig, _offset(rig, rng))
    data = simulate(short_drive, rig, cal, rng)
    n, dt = data.imu_per_keyframe, data.dt_imu
    b_g, b_a = cal.vector("imu", "gyro_bias"), cal.vector("imu", "accel_bias")
    pre = preintegrate_all(data.imu.gyro, data.imu.accel, n, dt, b_g, b_a)
    for k in (0, 7, 23, 38):
        dR, dv, dp = np.eye(3), np.zeros(3), np.zeros(3)
        for w, a in zip(data.imu.gyro[k * n:(k + 1) * n] - b_g, data.imu.accel[k * n:(k + 1) * n] - b_a):
            half = dR @ so3.exp((0.5 * w * dt)[None])[0]
            acc = half @ a
            dp, dv = dp + dv * dt + 0.5 * acc * dt * dt, dv + acc * dt
            dR = half @ so3.exp((0.5 * w * dt)[None])[0]
        assert np.allclose(pre[0][k], dR, atol=1e-13) and np.allclose(pre[1][k], dv, atol=1e-13)
        assert np.allclose(pre[2][k], dp, atol=1e-13)


def test_noise_free_data_is_explained_at_the_truth(rig, short_drive):
    """Without noise, every whitened residual at the true states and calibration is far below 1:
    the simulator measures what the factors predict (the IMU samples are increment-equivalent, the
    time offset's first-order model and the trapezoid position are the only approximations)."""
    rng = np.random.default_rng(2)
    cal = Calibration.nominal(rig).plus(rig, _offset(rig, rng))
    data = simulate(short_drive, rig, cal, rng, SimulationSettings.model(noise=False, wheel_ticks_per_rev=0))
    tr = data.truth
    prob = _Problem(data, rig, tr.R[0])
    r, _ = prob.evaluate(States(tr.R, tr.p, tr.v), cal, jacobian=False)
    assert np.abs(r).max() < 0.02, np.abs(r).max()


@pytest.mark.parametrize("rig_name", ["robotaxi", "sedan"])
def test_jacobian_is_the_derivative_of_the_residual(rig_name):
    """The estimator's step Jacobian at a perturbed estimate (every kind's residual differentiated
    at the recorded measurement; the IMU biases, which reach every factor through the corrected
    samples, by differences of the whole residual) against central differences of its residual:
    equal to the differences' accuracy, on the robotaxi (lidar, camera, rear wheels) and on the
    sedan (CAN wheels, steering, radar). The evaluator's linearisation (at the noise-free
    measurement of the estimate) agrees up to O(residual)."""
    rig = _rig() if rig_name == "robotaxi" else load_rig("sedan")
    rig = rig.with_config(imu=dict(rig.config.imu.model_dump(), update_rate=100))
    t = np.linspace(0.0, 2.0, 5)
    traj = drive(ControlProfile(t, 5 + 2 * np.sin(t), 0.1 * np.cos(0.7 * t), grade_rad=0.05 * np.sin(t),
                                bank_rad=0.04 * np.cos(1.3 * t)), rig.suspension)
    rng = np.random.default_rng(3)
    truth = Calibration.nominal(rig).plus(rig, _offset(rig, rng))
    data = simulate(traj, rig, truth, rng)
    X = perturbed_states(States(data.truth.R, data.truth.p, data.truth.v), rng, 1e-3, 1e-2, 1e-2)
    cal = truth.plus(rig, _offset(rig, rng, 1.0))
    prob = _Problem(data, rig, X.R[0])
    r, lin = prob.evaluate(X, cal, jacobian=True)
    J, Jp = lin.recorded.toarray(), lin.predicted.toarray()
    eps, nx = 1e-6, prob.n_x
    num = np.empty_like(J)
    for c in range(J.shape[1]):
        d = np.zeros(J.shape[1])
        d[c] = eps
        plus = prob.evaluate(X.plus_local(d[:nx]), cal.plus(rig, d[nx:]), False)[0]
        minus = prob.evaluate(X.plus_local(-d[:nx]), cal.plus(rig, -d[nx:]), False)[0]
        num[:, c] = (plus - minus) / (2 * eps)
    # the last keyframe's increment has no successor: a placeholder column held at zero by its
    # own row (the evaluator's local states), which the residual does not depend on
    assert np.array_equal(num[:, nx - 3:nx], np.zeros((J.shape[0], 3)))
    keep = np.r_[np.arange(nx - 3), np.arange(nx, J.shape[1])]
    bias = np.array([False] * (nx - 3) + ["_bias_" in c.name for c in rig.coordinates])
    names = [None] * (nx - 3) + [c.name for c in rig.coordinates]
    scale = np.abs(num[:, keep]).max(axis=0) + 1e-12
    rel = np.abs(J[:, keep] - num[:, keep]).max(axis=0) / scale
    worst = {names[i] or f"state column {i}": float(rel[i]) for i in np.argsort(rel)[-3:]}
    assert rel.max() < 1e-5, worst
    rel_p = np.abs(Jp[:, keep] - num[:, keep]).max(axis=0) / scale
    assert rel_p[:nx - 3].max() < 5e-3
    assert rel_p[~bias].max() > 10 * rel[~bias].max()  # the noise is visible in the evaluator's one


def test_noise_free_calibration_returns_the_truth(rig):
    traj = drive(hilly(figure_eight(20.0)), rig.suspension)
    rep = evaluate(traj, rig)
    rng = np.random.default_rng(4)
    nominal = Calibration.nominal(rig)
    truth = nominal.plus(rig, _offset(rig, rng))
    data = simulate(traj, rig, truth, rng, SimulationSettings.model(noise=False, wheel_ticks_per_rev=0))
    init = initialise(data, rig, nominal, data.truth.R[0], data.truth.p[0])
    res = calibrate(data, rig, init.calibration, init.states)
    assert res.converged, res.reason
    scored = np.array([not c.nuisance for c in rig.coordinates])
    err = res.calibration.minus(truth, rig)[scored]
    sigma = np.array([p.sigma for p in rep.parameters])
    # what noise-free data leaves at the truth (≤ 0.006 whitened: the drive's own non-holonomic
    # slip, the time offset taken to first order) moves the estimate by a small fraction of σ
    assert np.abs(err / sigma).max() < 0.1, dict(zip([p.name for p in rep.parameters], np.round(err / sigma, 3)))
    assert np.abs(nominal.minus(truth, rig)[scored] / sigma).max() > 0.5  # it did have to move
    # and the information at the estimate, the monocular scale eliminated, is the evaluator's
    L = res.information
    A, B, C = L[np.ix_(scored, scored)], L[np.ix_(scored, ~scored)], L[np.ix_(~scored, ~scored)]
    sigma_at_estimate = np.sqrt(np.diag(np.linalg.inv(A - B @ np.linalg.solve(C, B.T))))
    assert np.allclose(sigma_at_estimate, sigma, rtol=0.05)  # linearised elsewhere: the true offsets


# --- the simulator's noise -------------------------------------------------------------------

def test_simulated_noise_levels(rig):
    """IMU white noise σ = density·√rate, wheel increments σ = noise_density/√rate (white + quantisation),
    bias random walk only when asked."""
    traj = drive(figure_eight(20.0), rig.suspension)
    cal = Calibration.nominal(rig)
    clean = simulate(traj, rig, cal, np.random.default_rng(5),
                     SimulationSettings.model(noise=False, wheel_ticks_per_rev=0))
    noisy = simulate(traj, rig, cal, np.random.default_rng(5), SimulationSettings.model())
    ic = rig.config.imu
    assert np.std(noisy.imu.gyro - clean.imu.gyro) == pytest.approx(ic.gyroscope_noise_density * 10.0, rel=0.03)
    assert np.std(noisy.imu.accel - clean.imu.accel) == pytest.approx(ic.accelerometer_noise_density * 10.0, rel=0.03)
    q = 2 * np.pi / 2048  # whole ticks
    assert np.allclose(noisy.recorded["wheel"] / q, np.round(noisy.recorded["wheel"] / q), atol=1e-9)
    inc_err = noisy.recorded["wheel"] - clean.recorded["wheel"]
    assert np.std(inc_err) == pytest.approx(increment_sigma_rad(rig.config.wheels, rig.keyframe_rate_hz), rel=0.06)
    assert np.ptp(noisy.truth.gyro_bias, axis=0).max() == 0.0
    rw = simulate(traj, rig, cal, np.random.default_rng(5), SimulationSettings.model(bias_random_walk=True))
    # the bias tracks random-walk with the Kalibr densities: σ of a step = density·√dt
    for track, density in ((rw.truth.gyro_bias, ic.gyroscope_random_walk),
                           (rw.truth.accel_bias, ic.accelerometer_random_walk)):
        assert np.std(np.diff(track, axis=0)) == pytest.approx(density * np.sqrt(0.01), rel=0.03)
    with pytest.raises(ValidateError, match="ticks"):
        simulate(traj, rig, cal, np.random.default_rng(5), SimulationSettings.model(wheel_ticks_per_rev=100))


# --- Monte Carlo -------------------------------------------------------------------------------

def _ratio_bounds(n: int, family: int, alpha: float = 0.01) -> tuple[float, float]:
    """Where RMS/σ of n errors lies with probability 1 − alpha/family (Bonferroni over the
    parameters: n·(RMS/σ)² ~ χ²(n))."""
    a = alpha / family
    return float(np.sqrt(chi2.ppf(a / 2, n) / n)), float(np.sqrt(chi2.ppf(1 - a / 2, n) / n))


def _nees_bounds(n: int, dof: int, alpha: float = 0.01) -> tuple[float, float]:
    return float(chi2.ppf(alpha / 2, n * dof) / n), float(chi2.ppf(1 - alpha / 2, n * dof) / n)


@pytest.mark.slow
@pytest.mark.montecarlo
def test_monte_carlo_matches_the_predicted_sigma_on_a_well_excited_drive(rig):
    """60 trials on 20 s of a figure-eight over undulating ground (full rank, every parameter
    determined). With 60 trials each parameter's empirical/predicted σ lies in [0.69, 1.33] with
    probability 1 − 0.01/23 if the evaluator is right (N ≥ 100 in the benchmark tightens this to
    the issue's 25 %), and the mean NEES in its 99 % chi-square interval."""
    traj = drive(hilly(figure_eight(20.0)), rig.suspension)
    n = 60
    res = monte_carlo(traj, rig, MonteCarloSettings(runs=n, seed=11, simulation=SimulationSettings.model()))
    assert res.report.nullity == 0 and res.null_space is None
    assert res.failures == 0
    lo, hi = _ratio_bounds(n, N_SCORED)
    ratios = {p.name: round(p.ratio, 3) for p in res.parameters}
    assert all(lo <= r <= hi for r in ratios.values()), ratios
    assert res.dof == N_SCORED
    nlo, nhi = _nees_bounds(n, N_SCORED)
    assert nlo <= res.nees_mean <= nhi, (res.nees_mean, (nlo, nhi))
    # no parameter is biased beyond chance (|mean|/s.e. is Student-t; 3.9 ≈ the 1e-4 two-sided point)
    assert all(abs(p.bias) < 3.9 * p.bias_standard_error for p in res.parameters)
    d = res.to_dict()
    assert d["nees"]["dof"] == N_SCORED and len(d["parameters"]) == N_SCORED
    # trials are seeded one by one: any of them re-runs alone to the same numbers
    again = run_trial(traj, rig, 7, res.settings)
    assert np.allclose(again.error, res.trials[7].error, rtol=0, atol=1e-12)


@pytest.mark.slow
@pytest.mark.montecarlo
def test_degenerate_drive_wanders_exactly_along_the_null_space():
    """A planar figure-eight without suspension: the evaluator reports the two vertical lever arms
    as unobservable. The calibration must not move along them (the error there is the initial
    one, 2 targets RMS, not reduced), while every observable direction is estimated with
    the predicted σ (NEES over the rank, per-parameter σ as in the full-rank test)."""
    rig = _rig(suspension=False)
    traj = drive(figure_eight(20.0), Suspension.rigid())
    n = 40
    res = monte_carlo(traj, rig, MonteCarloSettings(runs=n, seed=12, simulation=SimulationSettings.model()))
    ns = res.null_space
    assert ns is not None and ns.nullity == 2
    assert {c[0][0] for c in ns.coordinates} == {"lidar.trans_z", "cam_front.trans_z"}
    # in targets: the data did not move them. The solver truncates the null directions of the
    # *estimate* (which differ from the nominal ones by the estimate's error), so they move by a
    # trace: 0.012 targets RMS here, 0.5 % of the initial spread
    assert ns.null_moved_rms < 0.03
    assert ns.null_rms == pytest.approx(ns.initial_null_rms, rel=0.01)
    assert ns.initial_null_rms > 1.5  # ~2 targets (the true offsets' spread): not determined at all
    assert res.dof == N_SCORED - 2
    nlo, nhi = _nees_bounds(n, res.dof)
    assert nlo <= res.nees_mean <= nhi, (res.nees_mean, (nlo, nhi))
    lo, hi = _ratio_bounds(n, N_SCORED - 2)
    ratios = {p.name: round(p.ratio, 3) for p in res.parameters if p.ratio is not None}
    assert len(ratios) == N_SCORED - 2
    assert all(lo <= r <= hi for r in ratios.values()), ratios
    unobs = [p for p in res.parameters if p.predicted_sigma is None]
    assert {p.name for p in unobs} == {"lidar.trans_z", "cam_front.trans_z"}
    # their error is whatever the start left: the true offset, 2 targets (2 cm) of spread
    assert all(p.empirical_sigma > 1.2e-2 for p in unobs)


def test_settings_are_validated():
    with pytest.raises(ValidateError, match="runs"):
        MonteCarloSettings(runs=1)
    with pytest.raises(ValidateError, match="max_iterations"):
        SolverSettings(max_iterations=0)
    with pytest.raises(ValidateError):
        SimulationSettings(wheel_ticks_per_rev=-1)


# --- the command line --------------------------------------------------------------------------

@pytest.mark.montecarlo
def test_cli_validate(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")  # the whole table, untruncated
    route = write_control_csv(hilly(figure_eight(12.0)), tmp_path / "hilly_control.csv")
    log = tmp_path / "solver.jsonl"
    code = cli(["validate", str(route), "--runs", "3", "--seed", "2", "--duration", "8", "--imu-rate", "100",
                "--simulator", "model", "--log", str(log), "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["runs"] == 3 and out["nees"]["dof"] == N_SCORED and out["failures"] == 0
    assert out["convergence_rate"] == 1.0 and sum(out["stop_reasons"].values()) == 3
    assert out["systematic_error_in_sigma"] is None  # the model's own data: nothing systematic
    records = [json.loads(line) for line in log.read_text().splitlines()]
    stops = [r for r in records if r["event"] == "stop"]
    assert [r["trial"] for r in stops] == [0, 1, 2] and all(r["status"] == "converged" for r in stops)
    steps = [r for r in records if r["event"] == "step"]
    assert steps and all(r["rank"] <= r["variables"] and r["linear_solver"] for r in steps)
    assert {p["name"] for p in out["parameters"]} >= {"lidar.trans_z", "wheel.track"}
    assert all(p["empirical_sigma"] > 0 for p in out["parameters"])
    code = cli(["validate", str(route), "--runs", "2", "--duration", "8", "--imu-rate", "100"])
    text = capsys.readouterr().out
    assert code == 0 and "NEES" in text and "emp/pred" in text and "lidar.time_offset" in text
    assert "Solver: 2 of 2 trials converged" in text and "Model check" in text and "noise-free trial" in text
    code = cli(["validate", str(route), "--runs", "1"])
    assert code == 1
    assert "runs must be at least 2" in capsys.readouterr().err
    code = cli(["validate", str(route), "--runs", "2", "--simulator", "exact"])
    assert code == 1
    assert "--simulator must be 'physical' or 'model'" in capsys.readouterr().err
    code = cli(["validate", str(route), "--runs", "2", "--log", str(tmp_path / "no" / "such" / "dir" / "x")])
    assert code == 1
    assert "--log: cannot write" in capsys.readouterr().err


# --- initialisation, solver, physical simulator -----------------------------------------------------

OPTIMIZED = "optimized_15s_control.csv"  # `excite optimize --duration 15 --seed 0` (5.5× the slalom's score)


@pytest.fixture(scope="module")
def optimized(rig):

    from excite.io.routes import read_route
    return read_route(REPO / "tests" / "data" / OPTIMIZED, suspension=rig.suspension)


def test_initialisation_recovers_rotation_time_offsets_and_gyro_bias_from_angular_rates(rig, optimized):
    """A start 1° off in every extrinsic rotation, 20 ms off in each time offset and 0.05 °/s in
    gyro bias (10–20 targets): the rotation-only alignment recovers what rotation increments
    determine (time offsets, the extrinsic tilt); the joint solve then converges, its
    log has one record per trial step and one stop record, and its errors are those of noise."""
    from excite.cli.validate import crop

    traj = crop(optimized, 10.0)
    rep = evaluate(traj, rig)
    nominal = Calibration.nominal(rig)
    off = np.zeros(len(rig.coordinates))
    for c in rig.coordinates:
        i = rig.index(c.name)
        if c.quantity == "rot":
            off[i] = np.deg2rad(1.0) * (-1) ** i
        elif c.quantity == "time_offset":
            off[i] = 0.02 * (-1) ** i
        elif c.quantity == "gyro_bias":
            off[i] = np.deg2rad(0.05)
    truth = nominal.plus(rig, off)
    # time offsets from the rate changes: 20 ms off → 2.5 ms RMS over noise draws (measured 2.3 ms
    # with the sensors' rotation noise of this rig; each draw within 3 of that)
    errs = []
    for seed in range(21, 27):
        data = simulate(traj, rig, truth, np.random.default_rng(seed), SimulationSettings.model())
        init = initialise(data, rig, nominal, data.truth.R[0], data.truth.p[0])
        errs += [init.calibration.scalar(n, "time_offset") - truth.scalar(n, "time_offset") for n in ("lidar", "cam_front")]
    errs = np.abs(errs)
    assert np.sqrt(np.mean(errs ** 2)) < 3.5e-3 and errs.max() < 7.5e-3, np.round(errs * 1e3, 2)
    # the extrinsic tilt from the yaw-rate axis (the lidar's axes are the body's): 1° → < 0.3°; its
    # yaw (about the only rotation axis of a flat lot) is not in rotation increments: the joint
    # solve gets it from the translations
    R_t, R_i = truth.rotation("lidar"), init.calibration.rotation("lidar")
    tilt = (R_t @ so3.log(R_t.T @ R_i))[:2]
    assert np.abs(tilt).max() < np.deg2rad(0.3), np.rad2deg(tilt)
    # the rotation alignment's residuals are those of the sensors' rotation noise
    assert all(0.8 < v < 1.2 for v in init.rotation_rms.values()), init.rotation_rms
    log: list[dict] = []
    res = calibrate(data, rig, init.calibration, init.states, log=log.append)
    assert res.converged, res.reason
    steps = [r for r in log if r["event"] == "step"]
    assert log[-1] == {"event": "stop", "status": res.status, "reason": res.reason, "iterations": res.iterations,
                       "step_trials": len(steps), "initial_cost": res.initial_cost, "cost": res.cost}
    for r in steps:
        assert {"variables", "residuals", "linear_solver", "lambda", "rank", "diag_H_min", "diag_H_max",
                "linear_residual", "cost_before", "cost_after", "accepted", "condition_calibration"} <= set(r)
        assert r["variables"] == res.n_unknowns and r["residuals"] == res.n_residuals
        assert r["rank"] == res.n_unknowns  # full rank: nothing truncated
        assert r["linear_residual"] < 1e-6  # the factorisation solves the damped system
        assert r["accepted"] == (r["cost_after"] < r["cost_before"])
    assert json.loads(json.dumps(log)) == log  # JSON as is (the CLI writes it as lines)
    scored = np.array([not c.nuisance for c in rig.coordinates])
    z = res.calibration.minus(truth, rig)[scored] / np.array([p.sigma for p in rep.parameters])
    assert np.abs(z).max() < 4.5, dict(zip([p.name for p in rep.parameters], np.round(z, 2)))


def test_a_singular_pivot_names_its_variable(rig):
    """A state no factor touches makes H_xx singular: the factorisation stops at its column, and
    the solver's names map that column to the keyframe and component."""
    rng = np.random.default_rng(0)
    n_x, n_t = 27, 2
    J = sp.random(60, n_x + n_t, density=0.5, random_state=1, format="csc").toarray()
    J[:, n_x:] = rng.normal(size=(60, n_t))
    J[:, 13] = 0.0  # keyframe 1, component 4
    with pytest.raises(FactorisationError) as err:
        _Normal(sp.csr_matrix(J), rng.normal(size=60), n_x, np.ones(n_t)).factor(0.0)
    assert err.value.column == 13
    from excite.validate.calibrate import _unknown_names
    assert _unknown_names(rig, 3, local=True)[13] == "x1.vel_body_y"


def _physics_effect(traj, rig, truth, sigma, settings):
    """Noise-free data of ``settings`` calibrated from the truth: the calibration error it causes
    (in predicted σ), the whitened cost 2·cost/dof it adds (what a noisy run's model check sees
    on top of 1) and the estimate."""
    data = simulate(traj, rig, truth, np.random.default_rng(0), settings)
    tr = data.truth
    res = calibrate(data, rig, truth, States(tr.R, tr.p, tr.v))
    assert res.converged, res.reason
    scored = np.array([not c.nuisance for c in rig.coordinates])
    return data, np.abs(res.calibration.minus(truth, rig)[scored] / sigma).max(), \
        2 * res.cost / (res.n_residuals - res.n_unknowns), res.calibration


def test_each_added_physics_changes_the_data_and_is_absorbed_or_flagged(rig, optimized):
    """Each physical effect alone, noise-free, on 10 s of an optimized plan (100 Hz IMU): it changes
    what the sensors record, and either the calibration absorbs it (it moves the estimate by less
    than half a predicted σ) or the Monte Carlo report flags it: its systematic run (this very
    computation, :func:`excite.validate.monte_carlo.systematic_error`) shows the move, and where
    the residuals see it, the model check too (the whitened cost it adds exceeds five standard
    deviations of a 50-trial check's mean, √(2/(50·dof))). Deterministic: no noise."""
    from excite.cli.validate import crop

    traj = crop(optimized, 10.0)
    sigma = np.array([p.sigma for p in evaluate(traj, rig).parameters])
    truth = Calibration.nominal(rig)
    base = dict(noise=False, wheel_ticks_per_rev=0)
    ref, err0, cost0, _ = _physics_effect(traj, rig, truth, sigma, SimulationSettings.model(**base))
    assert err0 < 0.05 and cost0 < 0.01  # the model's own data is explained: the baseline
    dof = ref.n_keyframes * 20  # ≈ residuals − unknowns of this drive
    flag = 5 * np.sqrt(2 / (50 * dof))
    q = 2 * np.pi / 2048
    # encoder quantisation: ticks are integers within one tick of the continuous angle; absorbed
    d, err, cost, _ = _physics_effect(traj, rig, truth, sigma, SimulationSettings.model(noise=False))
    angle = np.cumsum(ref.recorded["wheel"], axis=0) / q
    ticks = np.cumsum(d.recorded["wheel"], axis=0) / q
    assert np.allclose(ticks, np.round(ticks), atol=1e-9)
    assert 0.2 < np.abs(ticks - angle).max() <= 1.0
    assert err < 0.5 and cost - cost0 < flag, (err, cost)
    # IMU integrated at 8× its rate, output as the mean over each sample: different samples,
    # which the preintegration applies in the attitude of each sample's middle: absorbed (applied
    # in the attitude at the sample's start, they moved the estimate by 0.6 σ at 100 Hz on this
    # plan, and the residuals did not show it)
    d, err, cost, _ = _physics_effect(traj, rig, truth, sigma, SimulationSettings.model(imu_oversampling=8, **base))
    ic = rig.config.imu
    assert np.abs(d.imu.accel - ref.imu.accel).max() > ic.accelerometer_noise_density * 10.0  # > one sample's noise σ
    assert cost - cost0 < flag and err < 0.2, (err, cost)
    # wheel slip growing with longitudinal acceleration: increments differ by up to about a σ,
    # systematically (with the acceleration); the rig's tyre-slip nuisance takes it (it biased the
    # estimate by 2.5 σ before the model had it): the slip ratio at 1 g comes out as simulated
    d, err, cost, cal = _physics_effect(traj, rig, truth, sigma, SimulationSettings.model(wheel_slip_per_g=0.01, **base))
    sigma_w = increment_sigma_rad(rig.config.wheels, rig.keyframe_rate_hz)
    assert np.abs(d.recorded["wheel"] - ref.recorded["wheel"]).max() > 0.5 * sigma_w
    assert err < 0.5 and cost - cost0 < flag, (err, cost)
    assert cal.scalar("wheel", "slip") == pytest.approx(0.01, rel=0.01)
    # the loaded tyre's shorter rolling radius in turns (∝ a_lat²): it moved the wheel radii by
    # 0.5–1 σ, unseen by the residuals, before the rig's scrub nuisance took it; the scrub at 1 g²
    # comes out as simulated
    d, err, cost, cal = _physics_effect(traj, rig, truth, sigma, SimulationSettings.model(wheel_scrub_per_g2=0.01, **base))
    assert np.abs(d.recorded["wheel"] - ref.recorded["wheel"]).max() > 0.05 * sigma_w
    assert err < 0.5 and cost - cost0 < flag, (err, cost)
    assert cal.scalar("wheel", "scrub") == pytest.approx(0.01, rel=0.05)
    # tyre slip angle: the body yaws into the turns, the axle slides outwards; the slip-angle
    # nuisance takes it (before: 0.5 σ and the model check flagged it), at the simulated value
    d, err, cost, cal = _physics_effect(traj, rig, truth, sigma,
                                        SimulationSettings.model(slip_angle_deg_per_mps2=0.15, **base))
    yaw = so3.log(np.swapaxes(ref.truth.R, 1, 2) @ d.truth.R)[:, 2]
    assert np.abs(yaw).max() > np.deg2rad(0.2)
    assert err < 0.5 and cost - cost0 < flag, (err, cost)
    assert cal.scalar("vehicle", "slip_angle") == pytest.approx(np.deg2rad(0.15) * 9.80665, rel=0.02)


@pytest.mark.montecarlo
def test_convergence_on_a_short_optimized_plan_in_the_physical_simulator(rig, optimized):
    """The calibrator converges on the plans the optimizer sells, with the physical simulator's data
    (IMU at 8× its rate, random-walk biases, wheel slip, tyre slip angle): every trial of 8 here,
    ≥ 95 % in the benchmark's 50. With the tyre slip in the model the residuals are the model's
    (the model check flagged this data, 2·cost/dof > 1.025, while the model lacked slip); with the
    loaded tyres' scrub in the model too, what the physics alone moves the estimate by (the
    systematic run, noise-free) stays below 0.2 σ everywhere (0.5–1.5 σ on the wheel radii
    without the scrub)."""
    from excite.cli.validate import crop

    traj = crop(optimized, 10.0)
    res = monte_carlo(traj, rig, MonteCarloSettings(runs=8, seed=5))
    assert res.settings.simulation.physical
    assert res.failures == 0, res.stop_reasons
    assert all(t.status == "converged" and t.reason for t in res.trials)
    mc, (lo, hi) = res.model_check()
    assert lo <= mc <= hi, (mc, lo, hi)
    worst = max(abs(v) for v in res.systematic.values())
    assert worst < 0.2, res.systematic
