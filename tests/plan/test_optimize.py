"""The maneuver optimizer: its CasADi model is the evaluator's, it recovers known optima, and its
result is feasible (checked independently) and better than every baseline."""

from __future__ import annotations

import time

import casadi as ca
import numpy as np
import pytest

import excite.plan as opt
from excite.information import elimination, problem
from excite.errors import ExciteError
from excite.score.evaluate import evaluate
from excite.factors.base import Nominal
from excite.motion.maneuvers import Lot, slalom
from excite.plan import criteria
from excite.plan.candidates import check
from excite.plan.kinematics import Grid, Scales, body_samples, layout, profile_from_z, z_from_profile
from excite.plan.model import build_model, coarse_rig
from excite.plan.solver import solve
from excite.plan.transcription import Information, Transcription
from excite.rig.config import load_rig
from excite.rig.config import build_rig
from excite.io.routes import read_control_profile
from excite.motion.vehicle import ControlProfile, Limits, Suspension, check_limits, drive
from helpers import model_samples


@pytest.fixture(scope="module")
def rig():
    return load_rig("robotaxi")


@pytest.fixture(scope="module")
def coarse(rig):
    return coarse_rig(rig, 2.0, 4)


def test_public_interface():
    assert sorted(opt.__all__) == ["OptimizeError", "OptimizeResult", "OptimizeSettings", "Progress", "optimize"]
    assert issubclass(opt.OptimizeError, ExciteError)


@pytest.mark.parametrize("change", [dict(duration_s=-1.0), dict(duration_s=float("nan")), dict(lot_x_m=5.0),
                                    dict(time_budget_s=0.0), dict(seed=-1), dict(n_random=1.5),
                                    dict(limits="fast"), dict(closed="yes"), dict(criterion="F"),
                                    dict(max_iterations=0), dict(site="80x50")])
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
    K, args = model_samples(traj, coarse)
    model = build_model(coarse, K)
    Lam = np.array(model.marginal(*args))
    ref = elimination.marginal(problem.build(Nominal.of(traj, coarse), coarse))
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
    tk, tc = g.greville[2:-2], g.greville  # where the speed's and the curvature's coefficients sit
    z = np.zeros(lay.size)
    z[lay.speed] = (0.5 + 0.2 * np.sin(tk / 3)) * (1 - np.exp(-tk / 2)) * (1 - np.exp(-(30 - tk) / 2))
    z[lay.curv] = 0.5 * np.sin(tc / 4)
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
    return Transcription(problem=None, grid=None, scales=None, info=Information(ca.Function("M", [z], [M_of(z)])),
                         g_kin=ca.Function("g", [z], [g_of(z)]),
                         lbg_kin=np.array(lbg, float), ubg_kin=np.array(ubg, float),
                         lbg_ok=np.array(lbg, float), ubg_ok=np.array(ubg, float), lbz=np.array(lbz, float),
                         ubz=np.array(ubz, float), n_params=2)


def test_recovers_known_optimum_with_coalescing_eigenvalues():
    """max λ_min(diag(z1, z2)) s.t. z1 + z2 ≤ 2: both eigenvalues meet at the optimum (1, 1)."""
    tr = _toy(lambda z: ca.diag(z), lambda z: z[0] + z[1], [-np.inf], [2.0], [0.0, 0.0], [5.0, 5.0])
    out = solve(tr, np.array([1.8, 0.1]), time.perf_counter() + 20)
    assert out.status == "converged" and out.ipopt_status == "Solve_Succeeded"
    assert out.score == pytest.approx(1.0, abs=1e-4)
    assert out.z == pytest.approx([1.0, 1.0], abs=1e-3)
    # the time split the benchmarks report: IPOPT's own work is a part of the solve
    t = out.timings_s
    assert 0.0 <= t["ipopt_own"] <= t["solve"] and t["nlp_grad_f"] + t["ipopt_own"] <= t["solve"]


def test_recovers_known_optimum_at_a_constraint():
    """λ_min = 1 − |z| for [[1+z1, z2], [z2, 1−z1]]; with z1 ≥ 0.3 the optimum is (0.3, 0), 0.7."""
    tr = _toy(lambda z: ca.vertcat(ca.horzcat(1 + z[0], z[1]), ca.horzcat(z[1], 1 - z[0])),
              lambda z: z[0], [0.3], [np.inf], [-1.0, -1.0], [1.0, 1.0])
    out = solve(tr, np.array([0.9, 0.5]), time.perf_counter() + 20)
    assert out.score == pytest.approx(0.7, abs=1e-4)
    assert out.z == pytest.approx([0.3, 0.0], abs=1e-3)


def test_d_and_a_optimal_recover_known_optima():
    """D: max log(z1 z2) s.t. z1 + 2 z2 ≤ 3 → (1.5, 0.75) (AM–GM). A: min 1/z1 + 1/z2 s.t.
    z1 + 2 z2 ≤ 3 → z1 = √2 z2 (Lagrange), z1 = 3/(1 + √2)."""
    tr = _toy(lambda z: ca.diag(z), lambda z: z[0] + 2 * z[1], [-np.inf], [3.0], [1e-3, 1e-3], [5.0, 5.0])
    d = solve(tr, np.array([0.5, 0.5]), time.perf_counter() + 20, criterion="D")
    assert d.z == pytest.approx([1.5, 0.75], abs=1e-3)
    assert d.score == pytest.approx(np.log(1.5 * 0.75), abs=1e-5)
    a = solve(tr, np.array([0.5, 0.5]), time.perf_counter() + 20, criterion="A")
    z1 = 3 / (1 + np.sqrt(2))
    assert a.z == pytest.approx([z1, z1 / np.sqrt(2)], abs=1e-3)
    assert -a.score == pytest.approx(1 / z1 + np.sqrt(2) / z1, rel=1e-5)


def test_criteria_equal_their_textbook_definitions():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((6, 6))
    M = A @ A.T + 0.1 * np.eye(6)
    assert criteria.value(M, "E") == pytest.approx(np.linalg.eigvalsh(M).min())
    assert criteria.value(M, "D") == pytest.approx(np.linalg.slogdet(M)[1])
    assert criteria.value(M, "A") == pytest.approx(-np.trace(np.linalg.inv(M)))
    singular = np.diag([1.0, 2.0, 0.0])
    assert criteria.value(singular, "D") == -np.inf and criteria.value(singular, "A") == -np.inf
    w = rng.standard_normal((50, 3))
    hat = lambda v: np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])  # noqa: E731
    ref = sum(hat(v).T @ hat(v) for v in w) / len(w)
    assert criteria.rotation_excitation(w) == pytest.approx(np.linalg.eigvalsh(ref))


@pytest.mark.slow
def test_an_iteration_cap_still_returns_the_best_checked_drive(rig, tmp_path):
    """IPOPT cannot finish (2 iterations): the result is still the best drive the run saw —
    no candidate in the comparison that passed the check scores higher — and the files written
    for it read back to a drive that passes the same check with the same score. (The budget is
    generous so that the worker scores every comparison candidate even on a loaded machine; the
    run ends when they are done.)"""
    from excite.cli.optimize import write_outputs

    s = opt.OptimizeSettings(duration_s=30.0, lot_x_m=50.0, lot_y_m=35.0, time_budget_s=120.0,
                             n_random=6, max_iterations=2, starts=1, comparison=True)
    res = opt.optimize(rig, s)
    assert res.status == "time_budget" and res.ipopt_status == "Maximum_Iterations_Exceeded"
    assert res.iterations == 2
    feasible = [r for r in res.comparison if r["feasible"] and r.get("score") is not None]
    assert {r["kind"] for r in feasible} >= {"reference", "random"}
    assert res.report.score >= max(r["score"] for r in feasible) * (1 - 1e-9)
    chosen = [r for r in res.comparison if r["result"]]  # one drive (it may fill several rows)
    assert chosen and all(r["score"] == pytest.approx(res.report.score, rel=1e-9) for r in chosen)
    write_outputs(res, tmp_path)
    prof = read_control_profile(tmp_path / "control.csv")
    traj, bad = check(prof, rig, s, s.lot)
    assert bad == []
    assert evaluate(traj, rig).score == pytest.approx(res.report.score, rel=1e-9)
    assert feasible[0]["score"] <= res.report.score * (1 + 1e-9)


def test_cancel_returns_promptly_with_a_checked_drive(rig):
    calls = {"n": 0}

    def stop():
        calls["n"] += 1
        return calls["n"] > 3

    t0 = time.perf_counter()
    s = opt.OptimizeSettings(duration_s=40.0, time_budget_s=60.0, n_random=3)
    res = opt.optimize(rig, s, should_stop=stop)
    assert res.cancelled and res.status == "cancelled"
    assert time.perf_counter() - t0 < 40.0
    assert check(res.profile, rig, s, s.lot)[1] == []


@pytest.mark.slow
def test_optimized_maneuver_beats_every_baseline_and_is_feasible(rig):
    """The issue's claim on a smaller problem that fits the test suite: 45 s in a 60 × 40 m lot,
    6 random candidates, IPOPT capped at 40 iterations (so that the outcome does not depend on
    the machine's load) within a 120 s budget. The 90 s, 80 × 50 m, 200-candidate figures are
    measured by benchmarks/bench_optimize.py (README)."""
    s = opt.OptimizeSettings(duration_s=45.0, lot_x_m=60.0, lot_y_m=40.0, time_budget_s=120.0,
                             n_random=6, max_iterations=40, starts=1, comparison=True)
    seen = []
    t0 = time.perf_counter()
    res = opt.optimize(rig, s, progress=seen.append)
    assert time.perf_counter() - t0 <= 1.1 * s.time_budget_s
    assert res.status in ("converged", "time_budget") and not res.cancelled, res.message
    if res.status == "time_budget" and res.ipopt_status != "Maximum_Iterations_Exceeded":
        pytest.skip(f"the machine is too loaded: IPOPT ran {res.iterations} of 40 iterations within "
                    f"the {s.time_budget_s:g} s budget ({res.ipopt_status})")
    assert res.source == "optimized", res.message
    assert {p.phase for p in seen} >= {"start", "optimize", "check", "done"}
    # independent checks on the sampled result
    traj = drive(res.profile, rig.suspension)
    assert check_limits(traj, s.limits) == []
    assert Lot.rectangle(60.0, 40.0).contains(traj.sample(traj.times(20.0)).p_W_V, 3.0 - 1e-3).all()
    score = evaluate(traj, rig).score
    assert score == pytest.approx(res.report.score, rel=1e-9)
    rows = {r["name"]: r for r in res.comparison}
    best_ref = max(r["score"] for r in res.comparison if r["kind"] == "reference")
    best_rand = max(r["score"] for r in res.comparison if r["kind"] == "random")
    assert score >= 1.5 * best_ref
    assert score >= 1.5 * best_rand
    for r in res.comparison:  # the criteria side by side, from the full evaluator's information
        if r.get("score"):
            assert r["worst_sigma_ratio"] > 0 and r["trace_inv"] > 0
    if "cobyla" not in rows:  # COBYLA runs beside IPOPT on its share of the budget
        pytest.skip(f"the machine is too loaded: COBYLA did not finish within its share of the "
                    f"{s.time_budget_s:g} s budget")
    assert score > rows["cobyla"]["score"]


def test_kinematics_over_terrain_match_the_driven_profile(coarse):
    """Over a ramp and a bank: the optimizer's body motion of z (its own integration, grade and
    bank from the slope field, rates by jtimes) equals what drive() makes of the profile written
    from z (grade and bank sampled at 20 Hz, rotations differentiated by a rotation spline)."""
    from excite.plan.terrain import Feature, Terrain

    ramp = Feature("ramp", np.array([[5.0, -30.0], [25.0, -30.0], [25.0, 30.0], [5.0, 30.0]]), (1.0, 0.0),
                   slope=np.tan(np.radians(6.0)))
    bank = Feature("bank", np.array([[-30.0, -30.0], [-10.0, -30.0], [-10.0, 30.0], [-30.0, 30.0]]), (0.0, 1.0),
                   slope=np.tan(np.radians(4.0)))
    terrain = Terrain((ramp, bank))
    g = Grid.make(30.0, 1.5, 2.0, 4)
    sc = Scales.of(Limits(), 40.0)
    lay = layout(g)
    tk, tc = g.greville[2:-2], g.greville
    z = np.zeros(lay.size)
    z[lay.speed] = 0.5 * (1 - np.exp(-tk / 2)) * (1 - np.exp(-(30 - tk) / 2))
    z[lay.curv] = 0.3 * np.sin(tc / 5)
    z[lay.pose] = [-35.0 / 40.0, 0.0, 0.0]
    zs = ca.MX.sym("z", lay.size)
    pose = coarse.config.vehicle.T_V_B
    R, p, v, w, f, _ = (np.array(o) for o in ca.Function(
        "b", [zs], list(body_samples(g, sc, zs, coarse.suspension, pose.R, pose.p, terrain)))(z))
    prof = profile_from_z(g, sc, z, terrain=terrain)
    assert np.abs(prof.grade_rad).max() > np.radians(2.0) and np.abs(prof.bank_rad).max() > np.radians(2.0)
    b = drive(prof, coarse.suspension).sample(g.t).body(pose.R, pose.p)
    inner = slice(4, -4)  # away from the ends of the rotation spline
    assert np.abs(p.T - b.p_W_B).max() < 0.15  # metres, over a ~150 m drive climbing ~2 m
    # at a feature's soft edge (0.4 m) the grade changes within ~0.1 s, which the profile's 20 Hz
    # grade knots resolve only coarsely (the vertical acceleration u²·dG/ds peaks there): the
    # worst samples differ by several % of the peak, the typical one by far less
    dw = np.abs(w.T - b.omega_B)[inner]
    assert dw.max() < 0.01 + 0.08 * np.abs(b.omega_B).max()  # 7.3 % here, where it enters the bank
    assert np.percentile(dw, 95) < 0.002 + 0.01 * np.abs(b.omega_B).max()
    df = np.abs(f.T - b.specific_force_B)[inner]
    assert df.max() < 0.15 * np.abs(b.specific_force_B).max()
    assert np.percentile(df, 95) < 0.02 * np.abs(b.specific_force_B).max()


def test_bspline_hull_bounds_every_value_of_a_derivative():
    """The convex-hull bounds hold everywhere between the samples, and refining the knots
    tightens them towards the curve's own extremes; the jerk's bound is exact at the knots."""
    g = Grid.make(40.0, 1.5, 2.0, 4)
    rng = np.random.default_rng(5)
    c = rng.standard_normal(g.n_coefficients)
    s = g.spline(c)
    t = np.linspace(0.0, 40.0, 40001)
    for d in range(3):
        v = s.derivative(d)(t) if d else s(t)
        gaps = []
        for r in (1, 2, 4):
            h = g.hull(d, r) @ c
            assert h.min() <= v.min() + 1e-9 and h.max() >= v.max() - 1e-9
            gaps.append(h.max() - v.max() + v.min() - h.min())
        if d < 2:
            assert gaps[2] < gaps[0]
        else:  # piecewise linear: its values at the knots
            assert gaps[0] == pytest.approx(0.0, abs=1e-3 * np.ptp(v))


def test_multiple_shooting_is_the_single_shooting_path_at_continuity(rig, coarse):
    """With the nodes on the path (z_from_profile), the defects vanish and the path equals that
    of one segment (single shooting); moving a node breaks continuity at it and at the next node
    only, and the defects say by how much."""
    multi = Grid.make(30.0, 1.5, 2.0, 4, shooting_s=3.0)
    single = Grid.make(30.0, 1.5, 2.0, 4)
    sc = Scales.of(Limits(), 40.0)
    prof = profile_from_z(single, sc, np.r_[0.4 + 0.1 * np.sin(single.greville[2:-2]),
                                            0.5 * np.sin(single.greville / 4), [0.1, -0.2, 0.3]])
    zm, zs = z_from_profile(multi, sc, prof), z_from_profile(single, sc, prof)
    assert layout(multi).n_shoot == multi.n_segments - 1 >= 9
    from excite.plan.kinematics import terrain_path
    from excite.plan.terrain import Terrain

    def path_of(grid, z):
        zsym = ca.MX.sym("z", z.size)
        out, defects = terrain_path(grid, sc, zsym, Terrain(), with_defects=True)
        outs = list(out) + ([defects] if defects is not None else [])
        return [np.array(v).ravel() for v in ca.Function("p", [zsym], outs)(z)]

    m, s1 = path_of(multi, zm), path_of(single, zs)
    for a, b in zip(m[:10], s1[:10]):
        assert np.abs(a - b).max() < 1e-9
    assert np.abs(m[-1]).max() < 1e-12
    moved = zm.copy()
    moved[layout(multi).shoot.start] += 0.01  # the first node's x, by 0.4 m
    d = path_of(multi, moved)[-1]  # (x, y, ψ) of node 1, node 2, ...
    assert d[0] == pytest.approx(0.01) and d[3] == pytest.approx(-0.01)
    assert np.abs(np.delete(d, [0, 3])).max() < 1e-12


def test_exact_hessian_of_a_spectral_objective_matches_finite_differences():
    """The Hessian the exact-Hessian solver gives IPOPT (spectral curvature along ∂M/∂z plus
    ⟨∂f/∂M, ∂²M/∂z²⟩) is the objective's, for each criterion, also where eigenvalues coalesce."""
    from excite.plan.solver import SOFTMIN_BETA, Objective

    z = ca.MX.sym("z", 3)
    Mz = ca.vertcat(ca.horzcat(1 + z[0] ** 2, z[1] * z[2], 0), ca.horzcat(z[1] * z[2], 1 + ca.sin(z[1]), z[0]),
                    ca.horzcat(0, z[0], 2 + z[2] ** 3))
    info = Information(ca.Function("M", [z], [Mz]))
    for crit, z0 in (("E", [0.3, 0.2, -0.4]), ("D", [0.3, 0.2, -0.4]), ("A", [0.1, 0.5, 0.2]), ("E", [0.0, 0.0, 0.0])):
        obj = Objective(info, 3, crit, 0.5, SOFTMIN_BETA)
        f = lambda x: float(obj.eval([ca.DM(x)])[0])  # noqa: E731
        x0 = np.array(z0)
        H = obj.hessian(x0)
        h = 1e-4
        E = np.eye(3) * h
        fd = np.array([[(f(x0 + E[i] + E[j]) - f(x0 + E[i] - E[j]) - f(x0 - E[i] + E[j]) + f(x0 - E[i] - E[j]))
                        / (4 * h * h) for j in range(3)] for i in range(3)])
        assert np.abs(H - fd).max() <= 1e-4 * max(np.abs(fd).max(), 1.0), crit


def test_compiled_functions_are_cached_by_key_and_rebuilt_when_unloadable(tmp_path, monkeypatch):
    """A compiled library is built once per key into the cache, loaded from it afterwards without
    building the function again (its result bit-identical to the virtual machine's), rebuilt when
    the cached file cannot be loaded, and where no compiler may run the virtual machine is used
    with a one-line note."""
    from excite.plan import compiled

    monkeypatch.setenv("EXCITE_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("EXCITE_COMPILE", raising=False)
    if compiled.compiler() is None:
        pytest.skip("no C compiler on this machine")
    x = ca.MX.sym("x", 3)
    f = ca.Function("toy", [x], [ca.sin(x) * ca.sumsqr(x)])
    arg = [np.array([0.1, -0.7, 2.0])]
    first = compiled.load("toy", ["toy"], "k1", lambda: [f], wait=True)
    assert first.mode == "compiled" and "compile" in first.seconds
    assert np.array_equal(np.array(first.functions["toy"](*arg)), np.array(f(*arg)))
    again = compiled.load("toy", ["toy"], "k1", lambda: pytest.fail("built again"))
    assert again.mode == "compiled" and "load" in again.seconds
    (tmp_path / "casadi" / "toy_k3.so").write_bytes(b"not a library")  # a path never loaded before
    g = ca.Function("toy", [x], [2 * ca.sin(x) * ca.sumsqr(x)])
    rebuilt = compiled.load("toy", ["toy"], "k3", lambda: [g], wait=True)
    assert rebuilt.mode == "compiled" and "rebuilding" in rebuilt.note
    assert np.array_equal(np.array(rebuilt.functions["toy"](*arg)), np.array(g(*arg)))
    monkeypatch.setenv("EXCITE_COMPILE", "0")
    vm = compiled.load("toy", ["toy"], "k2", lambda: [f])
    assert vm.mode == "virtual machine" and "virtual machine" in vm.note and "\n" not in vm.note


@pytest.mark.slow
def test_starts_run_on_the_engine_and_say_which_converged(rig):
    """Two starts on two local processes: each comes back with its best iterates within the
    limits (at most KEEP), the one IPOPT finished says converged and beat its start, the one
    capped at 2 iterations does not."""
    import time as _time

    from excite.plan import multistart
    from excite.plan.problem import Problem
    from excite.plan.transcription import cached

    s = opt.OptimizeSettings(duration_s=12.0, lot_x_m=40.0, lot_y_m=30.0)
    problem = Problem.of(rig, s)
    tr = cached(problem)
    ref = next(c.profile for c in __import__("excite.plan.candidates", fromlist=["x"]).reference_profiles(rig, s, s.lot)
               if c.name == "stop_and_go")
    z0 = z_from_profile(tr.grid, tr.scales, ref)
    deadline = _time.time() + 600.0
    tasks = [multistart.StartTask(problem, "free", z0, deadline),
             multistart.StartTask(problem, "capped", z0, deadline, max_iterations=2)]
    seen = []
    results = multistart.run(tasks, jobs=2, progress=lambda *a: seen.append(a))
    assert [r.name for r in results] == ["free", "capped"]
    assert [r.converged for r in results] == [True, False], [r.outcome.ipopt_status for r in results]
    assert results[1].outcome.ipopt_status == "Maximum_Iterations_Exceeded"
    assert all(len(r.outcome.feasible) <= multistart.KEEP for r in results)
    free = results[0].outcome
    assert free.feasible and free.score > 2 * criteria.value(tr.M(z0), "E")
    assert free.score > results[1].outcome.score


def test_a_warm_start_continues_where_a_capped_run_stopped():
    """solve(warm=...) starts IPOPT from a previous outcome's point and multipliers: a run cut
    short at 3 iterations, continued, reaches the known optimum in fewer iterations than a cold
    run from the start needs."""
    tr = _toy(lambda z: ca.diag(z), lambda z: z[0] + 2 * z[1], [-np.inf], [3.0], [1e-3, 1e-3], [5.0, 5.0])
    cold = solve(tr, np.array([0.5, 0.5]), time.perf_counter() + 20, criterion="D")
    capped = solve(tr, np.array([0.5, 0.5]), time.perf_counter() + 20, criterion="D", max_iterations=3)
    assert capped.status == "time_budget" and capped.lam_g is not None
    warm = solve(tr, capped.z_final, time.perf_counter() + 20, criterion="D", warm=capped)
    assert warm.status == "converged" and warm.z == pytest.approx([1.5, 0.75], abs=1e-3)
    assert warm.iterations < cold.iterations


def test_compile_only_scores_the_references_once_for_that_problem(rig, tmp_path, monkeypatch, capsys):
    """``excite optimize --compile-only`` (a Docker image's build step) also scores the reference
    maneuvers of its problem into the cache: the rows read back are the full evaluator's scores
    of those maneuvers (scored again here, independently of the cache), a second call finds
    them, and another lot does not."""
    from excite.cli.app import main
    from excite.plan import candidates as cand

    monkeypatch.setenv("EXCITE_CACHE_DIR", str(tmp_path))
    args = ["optimize", "--compile-only", "--duration", "12", "--lot", "40x30", "-o", str(tmp_path / "out")]
    assert main(args) == 0
    assert "reference maneuvers scored" in " ".join(capsys.readouterr().out.split())  # wrapped when piped
    s = opt.OptimizeSettings(duration_s=12.0, lot_x_m=40.0, lot_y_m=30.0).for_rig(rig)
    rows = {c.name: c for c in cand.cached_references(rig, s, s.lot)}
    assert set(rows) == {c.name for c in cand.reference_profiles(rig, s, s.lot)}
    for c in cand.reference_profiles(rig, s, s.lot):
        traj, bad = check(c.profile, rig, s, s.lot)
        assert rows[c.name].violations == bad
        if not bad:
            assert rows[c.name].row["score"] == pytest.approx(evaluate(traj, rig).score, rel=1e-9)
    assert main(args) == 0
    assert "reference maneuvers cached" in " ".join(capsys.readouterr().out.split())
    other = opt.OptimizeSettings(duration_s=12.0, lot_x_m=45.0, lot_y_m=30.0).for_rig(rig)
    assert cand.cached_references(rig, other, other.lot) is None


def test_random_starts_are_drawn_only_while_the_start_share_lasts(rig):
    """Drawing feasible random drives is the start phase's cost (several times longer on a
    loaded machine): past ``until`` no chunk is drawn and the references alone are the starts;
    with time, the first START_RANDOM random candidates are ranked with them."""
    from excite.plan import candidates as cand
    from excite.plan.pipeline import CHUNK, START_RANDOM, rank_starts
    from excite.plan.problem import Problem
    from excite.plan.transcription import cached

    s = opt.OptimizeSettings(duration_s=12.0, lot_x_m=40.0, lot_y_m=30.0).for_rig(rig)
    tr = cached(Problem.of(rig, s, s.lot))
    refs = cand.reference_profiles(rig, s, s.lot)
    n_refs = sum(c.name != "highway_run" for c in refs)
    late, drawn = rank_starts(tr, s, s.lot, s.criterion, lambda *a: None, refs, until=time.perf_counter() - 1.0)
    assert drawn == [] and len(late) == n_refs
    full, drawn = rank_starts(tr, s, s.lot, s.criterion, lambda *a: None, refs)
    n_random = sum(len(c) for c in drawn)
    assert len(drawn) == START_RANDOM // CHUNK and n_random > 0 and len(full) == n_refs + n_random
