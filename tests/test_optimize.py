"""The maneuver optimizer: its CasADi model is the evaluator's, it recovers known optima, and its
result is feasible (checked independently) and better than every baseline."""

from __future__ import annotations

import time

import casadi as ca
import numpy as np
import pytest

import excite.optimize as opt
from excite import information
from excite.errors import ExciteError
from excite.evaluate import evaluate
from excite.factors.base import Nominal
from excite.maneuvers import Lot, slalom
from excite.optimize.kinematics import Grid, Scales, body_samples, layout, profile_from_z, z_from_profile
from excite.optimize.model import build_model, coarse_rig
from excite.optimize.pipeline import feasibility
from excite.optimize.solver import Transcription, solve_softmin
from excite.rig import load_rig
from excite.rig import build_rig
from excite.vehicle import ControlProfile, Limits, Suspension, check_limits, drive


@pytest.fixture(scope="module")
def rig():
    return load_rig("robotaxi")


@pytest.fixture(scope="module")
def coarse(rig):
    return coarse_rig(rig, 2.0, 4)


def _colmajor(R: np.ndarray) -> np.ndarray:
    return R.transpose(0, 2, 1).reshape(len(R), 9).T


def _samples(traj, crig):
    """The body samples Nominal.of takes for ``crig``, in the CasADi model's layout."""
    n = int(round(crig.config.imu.update_rate / crig.keyframe_rate_hz))
    K = Nominal.of(traj, crig).n_keyframes
    t = traj.t_start + np.arange((K - 1) * n + 1) / crig.config.imu.update_rate
    s = traj.sample(t)
    pose = crig.config.vehicle.T_V_B
    b = s.body(pose.R, pose.p)
    return K, [_colmajor(b.R_W_B), b.p_W_B.T, b.v_W.T, b.omega_B.T, b.specific_force_B.T, _colmajor(s.R_V_A)]


def test_public_interface():
    assert sorted(opt.__all__) == ["OptimizeError", "OptimizeResult", "OptimizeSettings", "Progress", "optimize"]
    assert issubclass(opt.OptimizeError, ExciteError)


@pytest.mark.parametrize("change", [dict(duration_s=-1.0), dict(duration_s=float("nan")), dict(lot_x_m=5.0),
                                    dict(time_budget_s=0.0), dict(seed=-1), dict(n_random=1.5),
                                    dict(limits="fast"), dict(closed="yes")])
def test_settings_are_validated(change):
    with pytest.raises(opt.OptimizeError):
        opt.OptimizeSettings(**change)


def _contract_drive(kind: str, rig):
    t = np.linspace(0.0, 30.0, 31)
    if kind == "slalom":
        return drive(slalom(40.0), rig.suspension)
    if kind == "planar, rigid suspension":  # vertical lever arms unobservable
        return drive(ControlProfile(t, 6 + 3 * np.sin(t / 3), 0.08 * np.sin(t / 5)), Suspension.rigid())
    if kind == "hilly, banked":
        return drive(ControlProfile(t, 6 + 3 * np.sin(t / 3), 0.08 * np.sin(t / 5), grade_rad=0.06 * np.sin(t / 4),
                                    bank_rad=0.04 * np.cos(t / 3)), rig.suspension)
    if kind == "highway, constant speed":  # straight: lever arms, track, time offsets unobservable
        return drive(ControlProfile(t, np.full(t.shape, 25.0), np.zeros(t.shape)), Suspension.rigid())
    raise ValueError(kind)


def _with_priors_and_mounting(rig):
    """Priors (which never enter Λ) and a camera mounted askew in its optical frame."""
    data = rig.config.model_dump()
    data["priors"] = {"*.rot_*": "0.5 deg", "wheel.track": "2 cm"}
    data["sensors"][1]["T_B_S"] = {"translation_m": [1.4, 0.3, 0.8], "rpy_deg": [-95.0, 3.0, -85.0]}
    return build_rig(data)


@pytest.mark.parametrize("kind", ["slalom", "planar, rigid suspension", "hilly, banked", "highway, constant speed",
                                  "priors, skewed camera"])
def test_casadi_information_equals_the_evaluator(rig, coarse, kind):
    """Same drive, same coarse rig: the CasADi Λ_θ is the numpy evaluator's (to rounding), on
    planar, hilly and straight drives (the last two with unobservable directions), with priors and
    a camera mounted askew."""
    if kind == "priors, skewed camera":
        rig = _with_priors_and_mounting(rig)
        coarse = coarse_rig(rig, 2.0, 4)
        kind = "hilly, banked"
    traj = _contract_drive(kind, rig)
    K, args = _samples(traj, coarse)
    model = build_model(coarse, K)
    Lam = np.array(model.marginal(*args))
    ref = information.marginal(information.build(Nominal.of(traj, coarse), coarse))
    assert np.abs(Lam - ref).max() <= 1e-6 * np.abs(ref).max()
    M = np.array(model.scaled(*args))
    rep = evaluate(traj, coarse)
    assert np.abs(M - rep.information_scaled).max() <= 1e-6 * np.abs(rep.information_scaled).max()
    if kind.startswith(("planar", "highway")):
        assert rep.nullity > 0
    else:
        assert np.linalg.eigvalsh(M)[0] == pytest.approx(rep.score, rel=1e-6)


def test_kinematics_match_the_driven_profile(rig, coarse):
    """The optimizer's own kinematics of z agree with drive() of the profile written from z."""
    g = Grid.make(30.0, 1.5, 2.0, 4)
    sc = Scales.of(Limits(), 20.0)
    lay = layout(g)
    tk = g.t_knots[1:-1]
    z = np.zeros(lay.size)
    z[lay.speed] = (0.5 + 0.2 * np.sin(tk / 3)) * (1 - np.exp(-tk / 2)) * (1 - np.exp(-(30 - tk) / 2))
    z[lay.curv] = 0.5 * np.sin(g.t_knots / 4)
    z[lay.pose] = [0.1, -0.2, 0.3]
    zs = ca.MX.sym("z", lay.size)
    pose = coarse.config.vehicle.T_V_B
    model = build_model(coarse, g.n_keyframes)
    M = np.array(ca.Function("M", [zs], [model.scaled(*body_samples(g, sc, zs, coarse.suspension,
                                                                      pose.R, pose.p))])(z))
    rep = evaluate(drive(profile_from_z(g, sc, z), rig.suspension), coarse)
    assert np.linalg.eigvalsh(M)[0] == pytest.approx(rep.score, rel=0.05)
    # the profile round-trips through z
    assert np.allclose(z_from_profile(g, sc, profile_from_z(g, sc, z)), z, atol=1e-6)


def _toy(M_of, g_of, lbg, ubg, lbz, ubz) -> Transcription:
    z = ca.MX.sym("z", len(lbz))
    return Transcription(grid=None, scales=None, limits=None, half_x_m=0, half_y_m=0, closed=False,
                         M=ca.Function("M", [z], [M_of(z)]), kin=None, g_kin=ca.Function("g", [z], [g_of(z)]),
                         lbg_kin=np.array(lbg, float), ubg_kin=np.array(ubg, float),
                         lbz=np.array(lbz, float), ubz=np.array(ubz, float), n_params=2)


def test_recovers_known_optimum_with_coalescing_eigenvalues():
    """max λ_min(diag(z1, z2)) s.t. z1 + z2 ≤ 2: both eigenvalues meet at the optimum (1, 1)."""
    tr = _toy(lambda z: ca.diag(z), lambda z: z[0] + z[1], [-np.inf], [2.0], [0.0, 0.0], [5.0, 5.0])
    out = solve_softmin(tr, np.array([1.8, 0.1]), time.perf_counter() + 20)
    assert out.score == pytest.approx(1.0, abs=1e-4)
    assert out.z == pytest.approx([1.0, 1.0], abs=1e-3)


def test_recovers_known_optimum_at_a_constraint():
    """λ_min = 1 − |z| for [[1+z1, z2], [z2, 1−z1]]; with z1 ≥ 0.3 the optimum is (0.3, 0), 0.7."""
    tr = _toy(lambda z: ca.vertcat(ca.horzcat(1 + z[0], z[1]), ca.horzcat(z[1], 1 - z[0])),
              lambda z: z[0], [0.3], [np.inf], [-1.0, -1.0], [1.0, 1.0])
    out = solve_softmin(tr, np.array([0.9, 0.5]), time.perf_counter() + 20)
    assert out.score == pytest.approx(0.7, abs=1e-4)
    assert out.z == pytest.approx([0.3, 0.0], abs=1e-3)


def test_cancel_returns_promptly_with_a_feasible_drive(rig):
    calls = {"n": 0}

    def stop():
        calls["n"] += 1
        return calls["n"] > 40

    t0 = time.perf_counter()
    s = opt.OptimizeSettings(duration_s=40.0, time_budget_s=60.0, n_random=3)
    res = opt.optimize(rig, s, should_stop=stop)
    assert res.cancelled and res.status == "cancelled"
    assert time.perf_counter() - t0 < 30.0
    assert feasibility(res.trajectory, s) == []
    assert {r["kind"] for r in res.comparison} <= {"optimized", "reference"}


def test_optimized_maneuver_beats_every_baseline_and_is_feasible(rig, monkeypatch):
    """The issue's claim on a smaller problem that fits the test suite: 45 s in a 60 × 40 m lot,
    10 random candidates, IPOPT capped at 40 iterations (so that the outcome does not depend on
    the machine's load) within a 30 s budget; COBYLA gets the same wall time IPOPT took. The 90 s,
    80 × 50 m, 200-candidate figures are measured by benchmarks/bench_optimize.py (README)."""
    monkeypatch.setattr("excite.optimize.solver.MAX_ITERATIONS", 40)
    s = opt.OptimizeSettings(duration_s=45.0, lot_x_m=60.0, lot_y_m=40.0, time_budget_s=30.0,
                             n_random=10)
    seen = []
    res = opt.optimize(rig, s, progress=seen.append)
    assert res.status in ("optimal", "time_budget") and not res.cancelled, res.message
    assert {p.phase for p in seen} >= {"start", "optimize", "baseline", "done"}
    # independent checks on the sampled result
    traj = drive(res.profile, rig.suspension)
    assert check_limits(traj, s.limits) == []
    assert Lot.rectangle(60.0, 40.0).contains(traj.sample(traj.times(20.0)).p_W_V).all()
    score = evaluate(traj, rig).score
    assert score == pytest.approx(res.report.score, rel=1e-9)
    rows = {r["name"]: r for r in res.comparison}
    best_ref = max(r["score"] for r in res.comparison if r["kind"] == "reference")
    best_rand = max(r["score"] for r in res.comparison if r["kind"] == "random")
    assert score >= 1.5 * best_ref
    assert score >= 1.5 * best_rand
    assert score > rows["cobyla"]["score"]
