"""A rig with GNSS through every consumer (issue 27): live guidance, mining, the optimizer's
CasADi model, the simulator and calibrator, and a Monte Carlo whose NEES lies in its interval.

A GNSS antenna breaks the gauge (world position and yaw are observed): every consumer closes its
drives through :mod:`excite.information.closure` (world states with the drive's origin, no gauge,
the first fix opening the error's chain), and each must agree with the evaluator.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from excite.information.closure import marginalise_nuisance
from excite.information.problem import columns
from excite.motion.maneuvers import figure_eight
from excite.motion.trajectory import SensorLog
from excite.motion.vehicle import drive
from excite.score.evaluate import evaluate
from test_gnss import gnss_rig, sigmas
from test_optimize import model_samples


def _sigma(Lam, rig, n_drives=1):
    names, nuisance = columns(rig, n_drives)
    L = marginalise_nuisance(Lam, ~nuisance)
    scored = [n for n, nu in zip(names, nuisance) if not nu]
    C = np.linalg.pinv(L)
    return {n: float(np.sqrt(C[i, i])) for i, n in enumerate(scored)}


@pytest.fixture(scope="module")
def rig():
    return gnss_rig(lidar=True)


@pytest.fixture(scope="module")
def traj(rig):
    return drive(figure_eight(40.0), rig.suspension)


def test_live_guidance_ends_at_the_evaluators_answer(rig, traj):
    from excite.score.live import Incremental, chunks

    inc = Incremental(rig)
    for c in chunks(traj, rig):
        inc.append(c)
    got = _sigma(inc.information().information, rig)
    want = sigmas(evaluate(traj, rig))
    for n in ("gnss.trans_x", "gnss.trans_z", "gnss.time_offset", "lidar.trans_z"):
        assert got[n] == pytest.approx(want[n], rel=1e-7), n


def test_live_guidance_with_an_outage_from_the_log(rig, traj):
    """The log's outage and the first fix: the drive so far closes as the evaluator's."""
    from excite.score.live import Incremental, chunks

    t = np.arange(traj.t_start, traj.t_end, 0.1)
    logged = traj.with_logs({"gnss": SensorLog(t[(t < traj.t_start + 12) | (t > traj.t_start + 20)])})
    inc = Incremental(rig)
    for c in chunks(logged, rig):
        inc.append(c)
    got, want = _sigma(inc.information().information, rig), sigmas(evaluate(logged, rig))
    assert got["gnss.trans_y"] == pytest.approx(want["gnss.trans_y"], rel=1e-7)


@pytest.mark.parametrize("outage", [False, True])
def test_a_mined_window_is_the_evaluators_crop(rig, traj, outage):
    """A window closed as a drive of its own: its own origin, its first fix opening the chain (or,
    where the window starts in an outage, no opening)."""
    from excite.fleet import mine

    log = traj
    if outage:
        t = np.arange(traj.t_start, traj.t_end, 0.1)
        log = traj.with_logs({"gnss": SensorLog(t[(t < traj.t_start + 8) | (t > traj.t_start + 13)])})
    s = mine.summarise(log, rig, chunk_s=10.0)
    Lam, diag = mine.window_information(s, 2, first=1)  # chunks 1 and 2: 10 … 30 s
    crop = mine.crop(log, s.time(int(s.edges[1])), s.time(int(s.edges[3])))
    rep = evaluate(crop, rig)
    got, want = _sigma(Lam[0], rig), sigmas(rep)
    for n in ("gnss.trans_x", "gnss.trans_y", "gnss.time_offset", "lidar.rot_z"):
        assert got[n] == pytest.approx(want[n], rel=1e-6), n
    assert len(columns(rig, 1)[0]) == Lam.shape[1]


def test_the_optimizers_model_is_the_evaluators_information(rig, traj):
    from excite.factors.base import Nominal
    from excite.information import elimination, problem
    from excite.plan.model import build_model, coarse_rig

    coarse = coarse_rig(rig, 2.0, 4)
    nom = Nominal.of(traj, coarse)
    _, args = model_samples(traj, coarse)
    model = build_model(coarse, nom.n_keyframes)
    got = np.array(model.marginal(*args))  # plain world states, over the rig's coordinates
    ref = elimination.marginal(problem.build(nom, coarse))  # the drive's origin among the nuisances
    P = len(coarse.coordinates)
    nuisance = np.array([c.nuisance for c in coarse.coordinates])
    a = marginalise_nuisance(got, ~nuisance)
    r = marginalise_nuisance(ref, ~columns(coarse, 1)[1])
    assert np.abs(a - r).max() <= 1e-6 * np.abs(r).max()
    assert got.shape == (P, P)
    i = [c.name for c in coarse.scored].index("gnss.time_offset")
    assert r[i, i] > 0


def test_the_simulator_and_calibrator_recover_the_antenna(rig, traj):
    from excite.validate.calibrate import calibrate, initialise
    from excite.validate.simulate import Calibration, SimulationSettings, simulate

    r = rig.with_constant_biases()
    sigma = sigmas(evaluate(traj, r))
    nominal = Calibration.nominal(r)
    delta = np.zeros(len(r.coordinates))
    delta[r.index("gnss.trans_x")] = 0.05  # 5 targets
    delta[r.index("gnss.time_offset")] = 0.004
    truth = nominal.plus(r, delta)
    data = simulate(traj, r, truth, np.random.default_rng(4), SimulationSettings.model())
    assert data.recorded["gnss"].z.shape == (data.n_keyframes, 3)
    init = initialise(data, r, nominal, data.truth.R[0], data.truth.p[0])
    res = calibrate(data, r, init.calibration, init.states)
    assert res.converged, res.reason
    assert 0.7 < res.residual_rms["gnss"] < 1.3  # its whitened (differenced) residuals are its noise
    for key, name in (("trans", "gnss.trans_x"), ("time_offset", "gnss.time_offset")):
        got = res.calibration.vector("gnss", "trans")[0] if key == "trans" else res.calibration.scalar("gnss", key)
        want = truth.vector("gnss", "trans")[0] if key == "trans" else truth.scalar("gnss", key)
        assert abs(got - want) < 4 * sigma[name], (name, got - want, sigma[name])


def test_monte_carlo_on_a_planned_drive_with_gnss_is_consistent():
    """40 trials on a planned figure-eight over undulating ground with an RTK-class antenna whose
    error is correlated over 5 s (simulated as a Gauss–Markov process, calibrated with the
    differenced factor): the mean NEES in its 99 % chi-square interval and no parameter's
    empirical σ off the predicted beyond chance. Model data (the estimator's own assumptions)."""
    from excite.validate.monte_carlo import MonteCarloSettings, monte_carlo
    from excite.validate.simulate import SimulationSettings
    from test_validate import hilly

    rig = gnss_rig(tau=5.0, lidar=True)
    data = rig.config.model_dump()
    data["imu"]["update_rate"] = 100  # coarse and cheap, as test_validate's
    from excite.rig.config import build_rig

    rig = build_rig(data)
    traj = drive(hilly(figure_eight(20.0)), rig.suspension)
    n = 40
    res = monte_carlo(traj, rig, MonteCarloSettings(runs=n, seed=27, simulation=SimulationSettings.model()))
    assert res.report.nullity == 0 and res.failures == 0, res.stop_reasons
    d = res.dof
    lo, hi = chi2.ppf(0.005, n * d) / n, chi2.ppf(0.995, n * d) / n
    assert lo <= res.nees_mean <= hi, (res.nees_mean, lo, hi)
    # per parameter: empirical/predicted σ within its 99 % chi-square range (Bonferroni over d)
    a = 0.01 / d
    rlo, rhi = np.sqrt(chi2.ppf(a / 2, n) / n), np.sqrt(chi2.ppf(1 - a / 2, n) / n)
    gnss = {p.name: p.ratio for p in res.parameters if p.name.startswith("gnss")}
    assert len(gnss) == 4 and all(rlo <= r <= rhi for r in gnss.values()), (gnss, rlo, rhi)


def test_the_service_scores_a_rig_with_gnss(tmp_path, rig, traj):
    """The HTTP service takes the rig as it takes any (a new kind needs no change there): the
    report's σ are the library's."""
    from excite.io.routes import write_tum
    from test_api_support import LiveServer

    rig_dict = rig.config.model_dump(mode="json")
    tum = write_tum(traj, tmp_path / "eight.tum")
    (tmp_path / "srv").mkdir()
    srv = LiveServer(tmp_path / "srv", workers=1, score_workers=1, max_job_time_budget_s=60).start()
    try:
        with srv.client() as c:
            r = c.post("/v1/score", json={"route": {"name": "eight", "format": "tum", "text": tum.read_text()},
                                          "rig": rig_dict})
    finally:
        srv.stop()
    assert r.status_code == 200, r.text
    got = {p["name"]: p["sigma"] for p in r.json()["parameters"]}
    from excite.io.routes import read_route

    want = sigmas(evaluate(read_route(tum), rig))
    for n in ("gnss.trans_x", "gnss.trans_y", "gnss.time_offset"):
        assert got[n] == pytest.approx(want[n], rel=1e-9), n
