"""GNSS antennas (:mod:`excite.factors.gnss`): the lever arm and time offset of an antenna whose fixes have an error
correlated over time, scored against independent computations, its degenerate motions, its
convergence with the fix rate, outages from the log, and its rig entry.

- σ against a dense reference built independently of the factor: the antenna's position
  differentiated numerically here, every fix's error whitened by the *full* Gauss–Markov
  covariance of all fixes (no differencing), the rest of the problem as the evaluator's;
  and, with white fixes, GTSAM's ``GPSFactorArmCalib`` linearised by GTSAM (when installed).
- The degenerate motions of docs/DESIGN.md's table, exactly (rank, the null directions, the
  advice), confirmed on the dense reference.
- 1/2/5/10 Hz fixes of one error process: σ converges (white fixes would not).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from excite.core import so3
from excite.errors import RigError
from excite.factors import base as registry
from excite.factors.base import Nominal
from excite.factors.gnss import PRESETS
from excite.information import dense, elimination, problem
from excite.information.closure import marginalise_nuisance
from excite.motion.maneuvers import figure_eight
from excite.motion.trajectory import SensorLog
from excite.motion.vehicle import ControlProfile, drive
from excite.rig.config import build_rig
from excite.score import spectrum
from excite.score.evaluate import evaluate
from helpers import LEVER, gnss_rig, sigmas

@pytest.fixture(scope="module")
def eight():
    return drive(figure_eight(30.0), gnss_rig().suspension)


# --- σ against independent computations ------------------------------------------------------


def _antenna(nom, k, d):
    """The antenna's world position at the fix of keyframe k, the states moved by ``d`` =
    ``[δθ, δp, δv]`` and the lever arm and time offset by ``d[9:13]`` (numpy, first order in
    the time offset as the model states it)."""
    l = np.asarray(LEVER) + d[9:12]
    t_d = d[12]
    R = nom.R[k] @ so3.exp(d[None, 0:3])[0]
    return nom.p[k] + d[3:6] + (nom.v[k] + d[6:9]) * t_d + R @ so3.exp((nom.omega[k] * t_d)[None])[0] @ l


def _dense_with(prob, rig, rows_of_fixes):
    """Λ over the problem's columns from its non-GNSS blocks and ``rows_of_fixes``: a whitened
    Jacobian of the fixes over the same columns (states, then θ), formed independently."""
    others = replace(prob, blocks=tuple(b for b in prob.blocks if not b.name.startswith("gnss")))
    J, _ = dense.jacobian(others)
    J = np.vstack([J.toarray(), rows_of_fixes])
    H = J.T @ J
    nx = prob.n_states
    return H[nx:, nx:] - H[nx:, :nx] @ np.linalg.solve(H[:nx, :nx], H[:nx, nx:])


def _sigma_of(Lam, rig, prob):
    names, nuisance = problem.columns(rig, 1)
    L = marginalise_nuisance(Lam, ~nuisance)
    scored = [n for n, nu in zip(names, nuisance) if not nu]
    C = np.linalg.inv(L)
    return {n: float(np.sqrt(C[i, i])) for i, n in enumerate(scored)}


def _fix_jacobian(prob, rig, nom, keyframes):
    """Numerical Jacobian of every fix's antenna position (3 per fix) over the problem's columns:
    the world position of keyframe k is ``c + q_k`` (the drive's origin and the state)."""
    names = problem.columns(rig, 1)[0]
    sd, nx = prob.state_dim, prob.n_states
    cols = [names.index(n) for n in ("gnss.trans_x", "gnss.trans_y", "gnss.trans_z", "gnss.time_offset")]
    origin = [names.index(f"drive.origin_{a}@0") for a in "xyz"]
    G = np.zeros((3 * len(keyframes), nx + len(names)))
    eps = 1e-6
    for n, k in enumerate(keyframes):
        D = np.stack([(_antenna(nom, k, e) - _antenna(nom, k, -e)) / (2 * eps) for e in np.eye(13) * eps], axis=1)
        rows = slice(3 * n, 3 * n + 3)
        G[rows, sd * k:sd * k + 9] = D[:, :9]
        G[rows, nx + np.array(cols)] = D[:, 9:13]
        G[rows, nx + np.array(origin)] = D[:, 3:6]
    return G


def test_sigma_equals_a_dense_reference_with_the_full_gauss_markov_covariance():
    """No differencing here: every fix's error is whitened by the Cholesky factor of the whole
    Gauss–Markov covariance σ²·φ^|i−j| (per axis), the antenna differentiated numerically."""
    tau = 4.0  # strongly correlated at 10 Hz (φ = 0.975), short enough that the drive holds several τ
    rig = gnss_rig(tau=tau, constant_biases=True)
    traj = drive(figure_eight(15.0), rig.suspension)
    nom = Nominal.of(traj, rig)
    prob = problem.build(nom, rig)
    keyframes = np.arange(nom.n_keyframes)  # a fix at every keyframe (10 Hz)
    G = _fix_jacobian(prob, rig, nom, keyframes)
    t = nom.t[keyframes]
    sig = np.array([0.02, 0.02, 0.04])
    W = np.zeros_like(G)
    corr = np.exp(-np.abs(t[:, None] - t[None, :]) / tau)
    for a in range(3):
        L = np.linalg.cholesky(sig[a] ** 2 * corr)
        W[a::3] = np.linalg.solve(L, G[a::3])
    ref = _sigma_of(_dense_with(prob, rig, W), rig, prob)
    got = sigmas(evaluate(traj, rig))
    for name in ("gnss.trans_x", "gnss.trans_y", "gnss.trans_z", "gnss.time_offset", "imu.accel_bias_z"):
        assert got[name] == pytest.approx(ref[name], rel=1e-6), name
    # and the differencing is what makes it so: taking the fixes as independent tells another story
    white = np.vstack([G[a::3] / sig[a] for a in range(3)])
    naive = _sigma_of(_dense_with(prob, rig, white), rig, prob)
    assert abs(naive["gnss.trans_z"] / ref["gnss.trans_z"] - 1) > 0.1


def test_sigma_equals_gtsams_gps_factor_with_a_lever_arm():
    """White fixes (τ = 0), the time offset not estimated (GTSAM's factor has none): the fixes'
    Jacobians from GTSAM's ``GPSFactorArmCalib`` (pose, lever arm) linearised by GTSAM, its pose
    tangent ``[ω, v]`` (body-frame translation) mapped to the world position ``δp = R v``."""
    gtsam = pytest.importorskip("gtsam")
    rig = gnss_rig(tau=0.0, constant_biases=True, estimate={"extrinsic": True, "time_offset": False})
    traj = drive(figure_eight(15.0), rig.suspension)
    nom = Nominal.of(traj, rig)
    prob = problem.build(nom, rig)
    names = problem.columns(rig, 1)[0]
    sd, nx = prob.state_dim, prob.n_states
    lever = [names.index(f"gnss.trans_{a}") for a in "xyz"]
    origin = [names.index(f"drive.origin_{a}@0") for a in "xyz"]
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.02, 0.02, 0.04]))
    rows = []
    for k in range(nom.n_keyframes):
        values = gtsam.Values()
        values.insert(0, gtsam.Pose3(gtsam.Rot3(nom.R[k]), nom.p[k]))
        values.insert(1, np.asarray(LEVER, dtype=float))
        a = nom.p[k] + nom.R[k] @ np.asarray(LEVER)
        A, _ = gtsam.GPSFactorArmCalib(0, 1, a, noise).linearize(values).jacobian()
        J = np.zeros((3, nx + len(names)))
        J[:, sd * k:sd * k + 3] = A[:, 0:3]
        Jp = A[:, 3:6] @ nom.R[k].T
        J[:, sd * k + 3:sd * k + 6] = Jp
        J[:, nx + np.array(origin)] = Jp
        J[:, nx + np.array(lever)] = A[:, 6:9]
        rows.append(J)
    ref = _sigma_of(_dense_with(prob, rig, np.vstack(rows)), rig, prob)
    got = sigmas(evaluate(traj, rig))
    for name in ("gnss.trans_x", "gnss.trans_y", "gnss.trans_z"):
        assert got[name] == pytest.approx(ref[name], rel=1e-6), name


def test_the_streamed_evaluator_equals_the_dense_marginal():
    rig = gnss_rig(constant_biases=True)
    traj = drive(figure_eight(15.0), rig.suspension)
    prob = problem.build(Nominal.of(traj, rig), rig)
    ref = dense.marginal_dense(prob)
    for Lam in (elimination.marginal(prob), elimination.drive_information([traj], rig).information):
        assert np.abs(Lam - ref).max() <= 1e-8 * np.abs(ref).max()
    # the marginal of the calibration does not depend on where the positions' gauge is fixed (the
    # origin takes the drive's translation)
    _, nuisance = problem.columns(rig, 1)
    a = marginalise_nuisance(ref, ~nuisance)
    b = marginalise_nuisance(elimination.marginal(problem.build(Nominal.of(traj, rig), rig, gauge_keyframe=77)),
                             ~nuisance)
    assert np.abs(a - b).max() <= 1e-8 * np.abs(a).max()


def test_the_score_does_not_depend_on_where_the_drive_is(eight):
    """Fixes are in a local world frame: moving and turning the whole drive (east/north far from
    the origin, about the vertical) changes nothing."""
    rig = gnss_rig()
    a = evaluate(eight, rig)
    b = evaluate(eight.transformed(so3.rot_z(1.234), np.array([4.6e5, 5.4e6, 120.0])), rig)
    assert b.nullity == a.nullity == 0
    for n, s in sigmas(a).items():
        assert sigmas(b)[n] == pytest.approx(s, rel=1e-6), n


# --- degenerate motions ----------------------------------------------------------------------

T = np.linspace(0.0, 20.0, 41)
MOTIONS = {
    # name: (profile, suspension, the GNSS coordinates left undetermined)
    "no rotation at all": (ControlProfile(T, 8 + 3 * np.sin(T / 2), 0 * T), False,
                           {"gnss.trans_x", "gnss.trans_y", "gnss.trans_z"}),
    "constant heading, pitching under braking": (ControlProfile(T, 8 + 3 * np.sin(T / 2), 0 * T), True,
                                                 {"gnss.trans_y"}),
    "constant velocity": (ControlProfile(T, 8 + 0 * T, 0 * T), False,
                          {"gnss.trans_x", "gnss.trans_y", "gnss.trans_z", "gnss.time_offset"}),
    "planar, turns both ways": (None, False, {"gnss.trans_z"}),
    "planar with suspension": (None, True, set()),
}


def _null_coordinates(Lam, diag, rig, names, nuisance):
    """Coordinates with a component in the null space the rank test finds."""
    L = marginalise_nuisance(Lam, ~nuisance)
    scored = [n for n, nu in zip(names, nuisance) if not nu]
    S = np.array([rig.coordinates[rig.index(n)].target for n in scored])
    spec = spectrum.analyse(L, diag[~nuisance], S)
    Z = spec.null_space
    return {n for i, n in enumerate(scored) if np.linalg.norm(Z[i]) > 1e-3}, spec


@pytest.mark.parametrize("motion", list(MOTIONS))
def test_the_degenerate_motions_of_the_antenna(motion):
    prof, suspension, undetermined = MOTIONS[motion]
    rig = gnss_rig(suspension=suspension, constant_biases=True)  # (the dense reference: 9-wide states)
    traj = drive(prof or figure_eight(20.0), rig.suspension)
    rep = evaluate(traj, rig)
    null = {n for m in rep.weak_modes if m.status == "unobservable" for n, w in m.coordinates if abs(w) > 1e-3}
    assert {n for n in null if n.startswith("gnss")} == undetermined
    for n in ("gnss.trans_x", "gnss.trans_y", "gnss.trans_z", "gnss.time_offset"):
        assert (sigmas(rep)[n] is None) == (n in undetermined), n
    # confirmed on the dense reference: the same null directions
    names, nuisance = problem.columns(rig, 1)
    prob = problem.build(Nominal.of(traj, rig), rig)
    dense_null, spec = _null_coordinates(dense.marginal_dense(prob), elimination.theta_diagonal(prob), rig,
                                         names, nuisance)
    assert dense_null == null and spec.nullity == rep.nullity
    # and the advice names the motion that fixes each
    advice = " ".join(m.advice for m in rep.weak_modes if m.status == "unobservable").lower()
    if {"gnss.trans_x", "gnss.trans_y"} & undetermined:
        assert "heading" in advice
    if "gnss.trans_z" in undetermined:
        assert "roll and pitch" in advice and "suspension" in advice
    if "gnss.time_offset" in undetermined:
        assert "speed" in advice


def test_one_circle_at_constant_speed_couples_the_time_offset_with_the_lever_arm():
    """Constant linear and angular velocity: the fix's time offset is a shift along the velocity,
    which turns with the car as the forward lever arm does: one null combination of the two."""
    rig = gnss_rig(suspension=False)
    rep = evaluate(drive(ControlProfile(T, 8 + 0 * T, 0.05 + 0 * T), rig.suspension), rig)
    modes = [dict(m.coordinates) for m in rep.weak_modes if m.status == "unobservable"]
    coupled = [m for m in modes if "gnss.time_offset" in m]
    assert len(coupled) == 1 and abs(coupled[0].get("gnss.trans_x", 0.0)) > 0.3
    assert any(set(m) == {"gnss.trans_z"} for m in modes)


# --- the fix rate ----------------------------------------------------------------------------


def test_sigma_converges_as_the_fix_rate_grows(eight):
    """1, 2, 5, 10 Hz fixes of one error process (σ 2/4 cm, τ 30 s): from 5 to 10 Hz no σ moves by
    3 %. White fixes of the same σ would be told they calibrate ever better (σ ∝ 1/√rate)."""
    out = {f: sigmas(evaluate(eight, gnss_rig(rate_hz=f))) for f in (1.0, 2.0, 5.0, 10.0)}
    for name, s10 in out[10.0].items():
        assert abs(s10 / out[5.0][name] - 1) < 0.03, (name, {f: o[name] for f, o in out.items()})
        assert out[1.0][name] >= s10 * (1 - 1e-9), name  # fewer fixes never tell more
    white = {f: sigmas(evaluate(eight, gnss_rig(rate_hz=f, tau=0.0))) for f in (5.0, 10.0)}
    assert white[10.0]["gnss.trans_z"] < 0.85 * white[5.0]["gnss.trans_z"]


# --- outages ---------------------------------------------------------------------------------


def test_an_outage_from_the_log_removes_its_fixes(eight):
    rig = gnss_rig()
    t = np.arange(eight.t_start, eight.t_end, 0.1)
    gap = (t > eight.t_start + 8.0) & (t < eight.t_start + 22.0)  # no fix for 14 s, most of the turns
    logged = eight.with_logs({"gnss": SensorLog(t[~gap])})
    nom = Nominal.of(logged, rig)
    kind = registry.kind_of_sensor("gnss")
    first = registry.factor_keyframes(kind, rig, rig.config.sensors[0], nom.n_keyframes, nom)
    assert first.size == nom.n_keyframes - 1 - int(gap.sum()) - 1  # no pair into, within or out of the gap
    assert not np.any((nom.t[first] > eight.t_start + 7.95) & (nom.t[first] < eight.t_start + 22.0))
    full, cut = sigmas(evaluate(eight, rig)), sigmas(evaluate(logged, rig))
    assert all(cut[n] > full[n] for n in ("gnss.trans_x", "gnss.trans_y", "gnss.time_offset"))
    # a log that holds every fix is the planned drive
    assert sigmas(evaluate(eight.with_logs({"gnss": SensorLog(t)}), rig)) == pytest.approx(full, rel=1e-12)


def test_a_fix_stamped_off_the_keyframe_counts_within_half_a_frame():
    rig = gnss_rig(rate_hz=2.5)  # a fix every 4th keyframe (0.4 s)
    traj = drive(figure_eight(10.0), rig.suspension)
    t0 = traj.t_start
    log = SensorLog(np.array([t0 + 0.03, t0 + 0.4 + 0.19, t0 + 0.8 + 0.21, t0 + 1.6]))
    nom = Nominal.of(traj.with_logs({"gnss": log}), rig)
    got = np.flatnonzero(nom.logs["gnss"].available)
    # a fix 0.21 s after keyframe 8 is 0.19 s before keyframe 12: it is 12's, and 8 has none
    assert got.tolist() == [0, 4, 12, 16]


def test_the_reported_covariance_weighs_each_fix():
    """With use_reported_covariance, fixes reported 10× worse are scored as a receiver of 10× the
    σ; without it the configured σ holds. (A reported covariance whitens the factors' rows after
    their kernel, the configured σ inside it: the same numbers, rounded differently, which the
    weakly determined lever arm's σ amplify to a few 1e-9.)"""
    rig = gnss_rig(tau=0.0)
    data = rig.config.model_dump()
    data["sensors"][0]["noise"]["use_reported_covariance"] = True
    reported = build_rig(data)
    traj = drive(figure_eight(20.0), rig.suspension)
    t = np.arange(traj.t_start, traj.t_end + 1e-9, 0.1)
    same = np.broadcast_to(np.diag([0.02, 0.02, 0.04]) ** 2, (t.size, 3, 3)).copy()
    log = traj.with_logs({"gnss": SensorLog(t, same)})
    base = sigmas(evaluate(traj, rig))
    assert sigmas(evaluate(log, reported)) == pytest.approx(base, rel=1e-8)
    worse = sigmas(evaluate(log.with_logs({"gnss": SensorLog(t, same * 100)}), reported))
    assert worse == pytest.approx(sigmas(evaluate(traj, gnss_rig(tau=0.0, h=0.2, v=0.4))), rel=1e-8)
    assert worse["gnss.trans_x"] > 3 * base["gnss.trans_x"]
    assert sigmas(evaluate(log.with_logs({"gnss": SensorLog(t, same * 100)}), rig)) == pytest.approx(base, rel=1e-9)


# --- the rig entry ---------------------------------------------------------------------------


def test_the_rig_entry():
    rig = gnss_rig()
    assert [c.name for c in rig.coordinates[:4]] == ["gnss.trans_x", "gnss.trans_y", "gnss.trans_z", "gnss.time_offset"]
    assert [c.unit for c in rig.coordinates[:4]] == ["m", "m", "m", "s"]
    data = rig.config.model_dump()
    data["sensors"][0]["noise"] = "rtk"
    assert build_rig(data).config.sensors[0].noise.model_dump(exclude={"use_reported_covariance"}) == PRESETS["rtk"]
    data["sensors"][0]["noise"] = {"preset": "standalone", "correlation_time_s": 20.0}
    n = build_rig(data).config.sensors[0].noise
    assert (n.horizontal_sigma_m, n.correlation_time_s) == (PRESETS["standalone"]["horizontal_sigma_m"], 20.0)
    data["sensors"][0]["noise"] = "ppp"
    with pytest.raises(RigError, match=r"sensors\.0\.noise: preset 'ppp' is not a GNSS noise preset"):
        build_rig(data)
    data["sensors"][0]["noise"] = "rtk"
    data["sensors"][0]["T_B_S"] = {"translation_m": LEVER, "rpy_deg": [0, 0, 90]}
    with pytest.raises(RigError, match=r"sensors\.0.*an antenna has no orientation"):
        build_rig(data)
    data["sensors"][0]["T_B_S"] = {"translation_m": LEVER}
    data["sensors"][0]["noise"] = {"horizontal_sigma_m": 0.02, "vertical_sigma_m": 0.04, "correlation_time_s": -1}
    with pytest.raises(RigError, match=r"sensors\.0\.noise\.correlation_time_s"):
        build_rig(data)


def test_the_optimizers_coarse_rig_keeps_the_error_process():
    kind = registry.kind_of_sensor("gnss")
    entry = gnss_rig().config.model_dump()["sensors"][0]
    assert registry.at_rate(kind, entry, 2.0)["noise"] == entry["noise"]  # correlated: the same process
    white = dict(entry, noise=dict(entry["noise"], correlation_time_s=0.0))
    coarse = registry.at_rate(kind, white, 2.5)["noise"]
    assert coarse["horizontal_sigma_m"] == pytest.approx(0.02 * math.sqrt(2.5 / 10.0))  # the same information per second
