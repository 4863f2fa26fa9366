"""Live guidance (excite.score.live, `excite live`, /v1/live): the incremental evaluator against the
batch evaluator, progress and advice while driving, done, and the bounds of the WebSocket."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse.linalg as spla
from typer.testing import CliRunner

import excite.cli.live  # registers `excite live` on the app
import excite.cli.score  # noqa: F401  (and `excite score`)
from excite.information import dense, elimination, problem
from excite.score import live
from excite.motion import maneuvers, vehicle
from excite.cli.app import app
from excite.score.evaluate import evaluate, report_of
from excite.factors.base import Nominal
from excite.rig.config import load_rig
from excite.io.routes import read_kitti, read_tum
from helpers import REPO

ROOT = REPO
FIGURE_EIGHT = ROOT / "trajectories" / "figure_eight.tum"

# A lidar + IMU + wheels rig with targets a minute and a half of figure-eight can meet.
TEST_RIG = """\
name: live_test
keyframe_rate_hz: 10
imu:
  accelerometer_noise_density: 1.0e-3
  accelerometer_random_walk: 1.0e-4
  gyroscope_noise_density: 1.5e-4
  gyroscope_random_walk: 2.0e-6
  update_rate: 100
  estimate_biases: true
vehicle:
  T_V_B: {translation_m: [1.40, 0.00, 0.60], rpy_deg: [0, 0, 0]}
  suspension: {pitch_deg_per_mps2: 0.3, roll_deg_per_mps2: 0.5}
  nonholonomic: {lateral_noise_density: 0.01581, vertical_noise_density: 0.01581}
sensors:
  - name: lidar
    kind: lidar
    rate_hz: 10
    T_B_S: {translation_m: [0.10, 0.00, 1.20], rpy_deg: [0, 0, 0]}
    noise: {rotation_density_deg_per_sqrt_s: 0.15811388300841897, translation_density_m_per_sqrt_s: 0.06324555320336758}
    estimate: {extrinsic: true, time_offset: true}
wheels:
  radius_left_m: 0.34
  radius_right_m: 0.34
  track_m: 1.60
  noise_density: 0.03162
  estimate: true
targets:
  "*.rot_*": 0.1 deg
  "lidar.trans_x": 3 cm
  "lidar.trans_y": 3 cm
  "lidar.trans_z": 60 cm
  "*.time_offset": 3 ms
  "imu.gyro_bias_*": 0.05 deg/s
  "imu.accel_bias_*": 0.02 m/s^2
  "wheel.radius_*": 1 mm
  "wheel.track": 1 cm
"""


def _rel(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


@pytest.fixture(scope="module")
def kitti(data_dir):
    return data_dir / "kitti_00_poses.txt", data_dir / "kitti_00_times.txt"


@pytest.fixture(scope="module")
def kitti_report(kitti):
    """`excite score` of KITTI 00 with the default rig (the library call the command makes)."""
    return evaluate(read_kitti(*kitti), load_rig("robotaxi"))


@pytest.fixture(scope="module")
def test_rig(tmp_path_factory):
    path = tmp_path_factory.mktemp("rig") / "live_test.yaml"
    path.write_text(TEST_RIG)
    return load_rig(path)


def _batch_prefix(traj, rig, k1: int):
    """The batch evaluator's report of keyframes 0..k1 of ``traj`` taken as a whole drive: its
    whole linearised problem (:func:`problem.build`, which closes a drive at its last
    keyframe itself) and :func:`elimination.marginal`."""
    prob = problem.build(Nominal.of(traj, rig, keyframes=(0, k1)), rig)
    drive = elimination.DriveInformation(elimination.marginal(prob), elimination.theta_diagonal(prob),
                                         problem.columns(rig, 1)[1], k1 + 1, k1 / rig.keyframe_rate_hz,
                                         0.0, {})
    return report_of(drive, rig, route="prefix")


# --- the incremental evaluator -------------------------------------------------------------------


U = 2.0 ** -53  # unit round-off of float64


def _roundoff_amplification(prob: problem.Problem) -> tuple[np.ndarray, np.ndarray, int]:
    """Per parameter column j of ``prob``: κ_j (see the test below), σ_j from a sparse LU solution
    of the whole ``H = JᵀJ`` (SuperLU and numpy, none of excite's elimination), and m, the most
    nonzeros in a trajectory column of H (the longest inner product of its elimination)."""
    J, _ = dense.jacobian(prob)
    H = (J.T @ J).tocsc()
    nx = prob.n_states
    Hxt = H[:nx, nx:].toarray()
    X = spla.splu(H[:nx, :nx].tocsc(), permc_spec="NATURAL").solve(Hxt)
    Z_tt = np.linalg.inv(H[nx:, nx:].toarray() - Hxt.T @ X)  # (H⁻¹)_θθ
    Z = np.vstack([-X @ Z_tt, Z_tt])  # H⁻¹ e_j for every θ column j
    h = H.diagonal()
    Zh = Z * np.sqrt(h)[:, None] * np.sqrt(h[nx:])[None, :]  # ẑ = Ĥ⁻¹ e_j, Ĥ = diag(H)^-½ H diag(H)^-½
    zjj = np.diag(Zh[nx:])  # = H_jj σ_j²
    pattern = H.copy()
    pattern.data[:] = 1.0
    kappa = np.sqrt(np.einsum("ij,ij->j", Zh ** 2, pattern @ Zh ** 2)) / zjj
    m = int(np.diff(H.indptr)[:nx].max())
    return kappa, np.sqrt(np.diag(Z_tt)), m


def test_incremental_equals_batch_on_kitti_00(kitti, kitti_report):
    """KITTI 00 appended chunk by chunk (one second each) ends with the σ of the batch evaluator
    (which sweeps the drive in chunks of ~2000 keyframes from both ends), and both with σ from a
    sparse LU solution of the whole H, to within what round-off allows each parameter.

    The bound comes from the arithmetic, not from observed gaps. Each way of eliminating the
    trajectory returns the exact σ of a slightly perturbed information matrix: in the Jacobi
    scaling Ĥ = diag(H)^-½ H diag(H)^-½ (unit diagonal, entries ≤ 1 by Cauchy–Schwarz; the
    componentwise backward error of Cholesky, |E| ≤ γ_m |Rᵀ||R|, does not depend on the scaling),
    Cholesky-type elimination and the accumulation of JᵀJ are backward stable with a perturbation
    E on H's nonzero pattern whose entries are sums of at most m rounded terms (m: the longest
    column of H's band, at most 3 keyframe states + θ): |E_ik| ≤ m·u, and ~√m·u for rounding errors
    of random sign (Higham & Mary's probabilistic analysis). σ_j² = (Ĥ⁻¹)_jj / H_jj, and to first order
    Δσ_j²/σ_j² = −ẑᵀEẑ / ẑ_j with ẑ = Ĥ⁻¹e_j. So

        κ_j = √(Σ_{(i,k) ∈ pattern(H)} ẑ_i² ẑ_k²) / ẑ_j,

    the standard deviation of ẑᵀEẑ/ẑ_j per unit entry of E, is how much parameter j amplifies
    round-off. ẑ_j = H_jj σ_j² is its information before marginalisation over the information
    left after marginalising everything else (trajectory and other parameters); κ_j ≥ ẑ_j counts
    also the trajectory's part of the direction that compensates θ_j, whose information cancels
    in ẑᵀĤẑ: KITTI 00's gyro z bias trades against the heading of every keyframe (ẑ_j ≈ 1.5e2,
    κ_j ≈ 6e8), while a lidar translation has κ_j ≈ 1e2–1e5. Per computation |Δσ/σ| ≈ ½·√m·u·κ_j;
    two independent computations differ by √2 times that; three standard deviations:

        |Δσ_j/σ_j| ≤ max(1e-9, C·u·κ_j),  C = 3·(√2/2)·√m  (≈ 17: m = 62).

    The worst case (all m·u rounding errors aligned with ẑ) would replace √m by m and the pattern
    sum by (Σ_i |ẑ_i|)² and bound nothing useful (≈ 0.35 for the gyro z bias). The floor 1e-9 is
    the claim for every well-conditioned parameter (C·u·κ_j < 1e-9 for κ_j < ~5e5); it also covers
    θ's own sums over the whole drive (≤ √(70 000)·u ≈ 3e-14)."""
    rig = load_rig("robotaxi")
    traj = read_kitti(*kitti)
    inc = live.Incremental(rig)
    for nom in live.chunks(traj, rig):
        inc.append(nom)
    rep = report_of(inc.information(), rig, route=traj.name)
    assert rep.n_keyframes == kitti_report.n_keyframes
    assert _rel(rep.length_m, kitti_report.length_m) < 1e-12

    prob = problem.build(Nominal.of(traj, rig), rig)
    kappa, sigma_lu, m = _roundoff_amplification(prob)
    names, nuisance = problem.columns(rig, 1)
    kappa, sigma_lu = kappa[~nuisance], sigma_lu[~nuisance]
    C = 3 * np.sqrt(2) / 2 * np.sqrt(m)
    print(f"\nKITTI 00 round-off: m = {m}, C = {C:.1f}, u = 2^-53; |Δσ/σ| and bound per parameter")
    print(f"{'parameter':22s} {'κ':>8s} {'bound':>8s} {'inc-batch':>9s} {'inc-LU':>8s} {'batch-LU':>8s}")
    for a, b, k, s_lu in zip(rep.parameters, kitti_report.parameters, kappa, sigma_lu):
        assert a.name == b.name and (a.sigma is None) == (b.sigma is None)
        if b.sigma is None:
            continue
        bound = max(1e-9, C * U * k)
        gaps = _rel(a.sigma, b.sigma), _rel(a.sigma, s_lu), _rel(b.sigma, s_lu)
        print(f"{a.name:22s} {k:8.1e} {bound:8.1e} " + " ".join(f"{g:8.1e}" for g in gaps))
        assert max(gaps) <= bound, (a.name, gaps, bound, k)
        assert a.ok == b.ok


def test_every_prefix_closes_like_a_whole_drive(test_rig):
    """The information "so far" after any chunk equals the batch evaluator's on that prefix taken
    as a whole drive (its end keyframe closed: the non-holonomic factor there, no increment,
    the bias deviation anchored), in information, not only in σ."""
    rig = load_rig("robotaxi")
    traj = read_tum(FIGURE_EIGHT)
    inc = live.Incremental(rig)
    seen = 0
    for nom in live.chunks(traj, rig, chunk_s=2.0):
        inc.append(nom)
        if inc.n_keyframes - 1 in (20, 220, 520):
            k1 = inc.n_keyframes - 1
            Lam = inc.information().information
            ref = elimination.marginal(problem.build(Nominal.of(traj, rig, keyframes=(0, k1)), rig))
            assert np.abs(Lam - ref).max() <= 1e-9 * np.abs(ref).max()
            seen += 1
    assert seen == 3
    with pytest.raises(Exception, match="multiple of 1 keyframe"):
        live.Incremental(rig).append(Nominal.of(traj, rig, keyframes=(0, 0)))


LONG_STRAIGHT_S = 120.0


def _straight_then_eight(rig, straight_s: float = 15.0):
    """A straight (accelerate to 5 m/s, cruise, stop: 15 s by default), then 90 s of figure-eight."""
    fe = maneuvers.figure_eight(90.0)
    S = straight_s
    t = np.concatenate([[0, 4, 8, S - 4, S] if S > 16 else [0, 4, 8, 12, 15], fe.t_s[1:] + S])
    v = np.concatenate([[0, 3, 5, 5, 0] if S > 16 else [0, 3, 5, 3, 0], fe.speed_mps[1:]])
    k = np.concatenate([[0] * 5, fe.curvature_1pm[1:]])
    return vehicle.drive(vehicle.ControlProfile(t, v, k, start=fe.start, name="straight_then_eight"),
                         rig.suspension)


def test_straight_then_figure_eight_progress_advice_and_done(test_rig):
    rig = test_rig
    traj = _straight_then_eight(rig)
    events = list(live.updates_of(traj, rig))
    updates = [e for e in events if e["type"] == "update"]
    track = [(u["t_s"], next(p for p in u["parameters"] if p["name"] == "wheel.track")) for u in updates]
    straight = [p for t, p in track if t <= 15.0]
    assert len(straight) >= 12
    assert all(p["progress"] == 0.0 and p["status"] == "needs" and "turn both ways" in p["advice"]
               for p in straight)
    later = [p["progress"] for t, p in track if t > 15.0]
    assert later[-1] == 1.0 and max(later[:10]) > 0.0
    # the vertical lever arm is out of reach on the straight too: the motion it needs is named
    tz = next(p for p in updates[5]["parameters"] if p["name"] == "lidar.trans_z")
    assert tz["status"] == "needs" and "pitch" in tz["advice"]
    assert updates[5]["weakest"]["advice"].startswith("Needs")
    # done fires once, at the first update whose prefix the batch evaluator passes
    done = [i for i, e in enumerate(events) if e["type"] == "done"]
    assert len(done) == 1 and events[done[0]]["passed"]
    at = events[done[0] - 1]
    assert at["type"] == "update" and at["passed"] and events[done[0]]["t_s"] == at["t_s"]
    first_pass = next(i for i, u in enumerate(updates) if u["passed"])
    assert updates[first_pass] is at and at["t_s"] < traj.duration - 5
    for u in updates[max(0, first_pass - 3):first_pass + 2] + updates[::15]:
        k1 = u["n_keyframes"] - 1
        assert _batch_prefix(traj, rig, k1).passed == u["passed"], u["t_s"]


def test_a_straight_long_enough_stalls_then_the_figure_eight_passes(test_rig):
    """Two minutes of straight driving, then a figure-eight. Once the rotations a straight can
    determine are within target, nothing more is gained from driving on straight: a ``done``
    with ``passed`` false fires (a whole rate window later), naming exactly the parameters the
    batch evaluator still fails on that prefix, each with the motion it needs, and they still
    fail at the end of the straight (driving on did not help). The figure-eight then brings the
    passed ``done``, once."""
    rig = test_rig
    S = LONG_STRAIGHT_S
    traj = _straight_then_eight(rig, S)
    events = list(live.updates_of(traj, rig))
    done = [(i, e) for i, e in enumerate(events) if e["type"] == "done"]
    assert [e["passed"] for _, e in done] == [False, True], [(e["t_s"], e["passed"]) for _, e in done]
    (i_stall, stall), (i_pass, passed) = done
    assert live.RATE_WINDOW_S <= stall["t_s"] < S - 8  # while cruising straight
    named = {n["name"]: n["advice"] for n in stall["needs"]}
    assert "turn" in named["wheel.track"] and "pitch" in named["lidar.trans_z"]
    at_stall = _batch_prefix(traj, rig, events[i_stall - 1]["n_keyframes"] - 1)
    assert {p.name for p in at_stall.parameters if not p.ok} == set(named)
    end_of_straight = _batch_prefix(traj, rig, int((S - 8) * rig.keyframe_rate_hz))
    assert {p.name for p in end_of_straight.parameters if not p.ok} == set(named)
    assert passed["t_s"] > S and events[i_pass - 1]["passed"]


def test_the_stall_needs_a_whole_window_without_gain(monkeypatch, test_rig):
    """The "nothing more to gain" done fires only after a whole rate window in which no update
    had a gaining parameter, counted from the last one that had, and once per stall."""
    from types import SimpleNamespace

    class Scripted(live.Guide):
        def describe(self, rep, t, kind="update"):
            state = "gaining" if t in gaining else "needs"
            return {"type": kind, "t_s": t, "parameters": [{"name": "wheel.track", "status": "ok", "advice": None},
                                                          {"name": "lidar.trans_z", "status": state, "advice": "Needs pitch"}]}

    monkeypatch.setattr(live, "report_of", lambda *a, **k: SimpleNamespace(passed=False, score=0.0))
    W = live.RATE_WINDOW_S
    gaining = {1.0, 2.0, 20.0, 55.0, 70.0}
    guide = Scripted(test_rig)
    fired = [t for t in np.arange(1.0, 140.0) for e in guide.update(SimpleNamespace(duration_s=t))
             if e["type"] == "done"]
    # after the gain at 20 s: a stall at 20 + W; the gains at 55 and 70 s re-arm it: 70 + W
    assert fired == [20.0 + W, 70.0 + W]


# --- excite live ---------------------------------------------------------------------------------


def test_cli_exits_0_when_done(test_rig, tmp_path):
    """The straight-then-figure-eight logged as TUM and replayed: `done` ends the command with 0
    at the first update where every parameter is within target."""
    from excite.io.routes import write_tum

    rig_file = tmp_path / "rig.yaml"
    rig_file.write_text(TEST_RIG)
    tum = write_tum(_straight_then_eight(test_rig), tmp_path / "drive.tum")
    r = CliRunner().invoke(app, ["live", str(tum), "--rig", str(rig_file), "--replay", "1000x", "--json"])
    assert r.exit_code == 0, r.output
    events = _json_lines(r.stdout)
    assert events[-1]["type"] == "done" and events[-2]["type"] == "update" and events[-2]["passed"]
    assert not any(e["passed"] for e in events[:-2]) and events[-1]["t_s"] > 15


@pytest.mark.slow
def test_cli_says_what_a_stalled_drive_needs_and_goes_on(test_rig, tmp_path):
    """A long straight before the figure-eight: `excite live` prints the non-passed done (which
    parameters need which motion), keeps reading, and exits 0 at the passed done. Replayed at
    20x, so that updates come every second or few of drive (at 1000x one batch of poses spans
    most of the straight: too few updates to see a whole window without gain)."""
    from excite.io.routes import write_tum

    rig_file = tmp_path / "rig.yaml"
    rig_file.write_text(TEST_RIG)
    straight = 150.0  # the stall comes ~92 s in (see the test above): room for late updates
    tum = write_tum(_straight_then_eight(test_rig, straight), tmp_path / "drive.tum")
    args = ["live", str(tum), "--rig", str(rig_file), "--replay", "20x"]
    r = CliRunner().invoke(app, args + ["--json"])
    assert r.exit_code == 0, r.output
    events = _json_lines(r.stdout)
    done = [e for e in events if e["type"] == "done"]
    assert [e["passed"] for e in done] == [False, True], [(e["t_s"], e["passed"]) for e in done]
    assert done[0]["t_s"] < straight - 4 < straight < done[1]["t_s"]
    r = CliRunner().invoke(app, args)  # the log form: one line per update, and what is needed
    assert r.exit_code == 0, r.output
    assert "nothing more to gain" in r.output and "wheel.track: Needs turns" in r.output


def _json_lines(text: str) -> list[dict]:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def test_cli_kitti_00_replay_ends_with_excite_score(kitti):
    poses, times = kitti
    runner = CliRunner()
    r = runner.invoke(app, ["live", str(poses), "--times", str(times), "--replay", "1000x", "--json"])
    assert r.exit_code == 1, r.output  # KITTI 00 never lifts the lidar: the source ends first
    events = _json_lines(r.stdout)
    final, updates = events[-1], [e for e in events if e["type"] == "update"]
    assert final["type"] == "final" and not final["done"]
    assert not any(e["type"] == "done" for e in events)
    # one update per batch of poses the replay hands over (as many as the evaluator keeps up with)
    assert len(updates) >= 3 and all(a["t_s"] < b["t_s"] for a, b in zip(updates, updates[1:]))
    s = runner.invoke(app, ["score", str(poses), "--times", str(times), "--json"])
    assert s.exit_code == 0, s.output
    score = json.loads(s.stdout)
    assert final["report"]["score"] == pytest.approx(score["score"], rel=1e-9)
    for a, b, c in zip(final["parameters"], score["parameters"], updates[-1]["parameters"]):
        assert a["name"] == b["name"]
        assert (a["sigma"] is None) == (b["sigma"] is None)
        if b["sigma"] is not None:
            assert _rel(a["sigma"], b["sigma"]) <= 1e-9
            # the last live update (5 s lookahead short of the end, fitted from nearby poses
            # only) already said nearly the same
            assert _rel(c["sigma"], b["sigma"]) < 0.05, a["name"]
    tz = next(p for p in updates[-1]["parameters"] if p["name"] == "lidar.trans_z")
    assert tz["status"] == "needs" and "pitch" in tz["advice"]
    assert all(0.0 <= p["progress"] <= 1.0 for u in updates for p in u["parameters"])


def test_cli_follows_a_growing_file_and_reads_stdin(tmp_path):
    lines = FIGURE_EIGHT.read_text().splitlines(keepends=True)[:402]  # 40 s
    whole = tmp_path / "whole.tum"
    whole.write_text("".join(lines))
    score = evaluate(read_tum(whole), load_rig("robotaxi"))
    growing = tmp_path / "drive.tum"
    growing.write_text("".join(lines[:100]))

    def writer():
        with open(growing, "a") as fh:
            for i in range(100, len(lines), 50):
                time.sleep(0.05)
                fh.write("".join(lines[i:i + 50]))
                fh.flush()

    th = threading.Thread(target=writer)
    th.start()
    r = CliRunner().invoke(app, ["live", str(growing), "--idle", "1", "--json"])
    th.join()
    outs = [r]
    outs.append(CliRunner().invoke(app, ["live", "-", "--json"], input="".join(lines)))
    for out in outs:
        assert out.exit_code in (0, 1), out.output
        final = _json_lines(out.stdout)[-1]
        assert final["type"] == "final"
        for a, b in zip(final["parameters"], score.parameters):
            assert (a["sigma"] is None) == (b.sigma is None)
            assert b.sigma is None or _rel(a["sigma"], b.sigma) <= 1e-9
        assert out.exit_code == (0 if final["done"] else 1)


def test_cli_replays_a_bag_like_excite_score(data_dir):
    bag = str(data_dir / "nav2_turtlebot.mcap")
    runner = CliRunner()
    r = runner.invoke(app, ["live", bag, "--topic", "/odom", "--replay", "1000x", "--json"])
    assert r.exit_code in (0, 1), r.output
    final = _json_lines(r.stdout)[-1]
    s = runner.invoke(app, ["score", bag, "--topic", "/odom", "--json"])
    assert s.exit_code == 0, s.output
    for a, b in zip(final["parameters"], json.loads(s.stdout)["parameters"]):
        assert (a["sigma"] is None) == (b["sigma"] is None)
        assert b["sigma"] is None or _rel(a["sigma"], b["sigma"]) <= 1e-9
    assert r.exit_code == (0 if final["done"] else 1)


def test_replay_hands_poses_over_at_the_chosen_speed():
    from excite.cli.live import _paced

    t = np.arange(101) * 0.1  # 10 s of poses
    c0 = time.monotonic()
    got = [tb for tb, _, _ in _paced(t, np.zeros((101, 3)), np.zeros((101, 3, 3)), 25.0)]
    wall = time.monotonic() - c0
    assert np.array_equal(np.concatenate(got), t)
    assert 10 / 25 - 0.01 <= wall < 10 / 25 + 1.0


def test_cli_errors_are_one_line(tmp_path):
    bad = tmp_path / "bad.tum"
    bad.write_text("0 0 0 0 0 0 0 1\n0.1 0 0 zero 0 0 0 1\n")
    for args in (["live", str(bad), "--replay", "10x"], ["live", str(bad), "--replay", "fast"],
                 ["live", str(tmp_path / "missing.tum"), "--replay", "2x"]):
        r = CliRunner().invoke(app, args)
        assert r.exit_code != 0
        assert "Traceback" not in r.output
    import contextlib
    import io

    from excite.cli.app import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["live", str(bad), "--replay", "10x"])
    assert code == 1 and err.getvalue().startswith("excite: error:") and "line 2" in err.getvalue()
    assert "'zero'" in err.getvalue() and len(err.getvalue().strip().splitlines()) == 1


# --- /v1/live ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ws_client(tmp_path_factory):
    from fastapi.testclient import TestClient

    from api.app import create_app
    from api.settings import Settings

    app = create_app(Settings(db_path=tmp_path_factory.mktemp("live") / "j.sqlite3", workers=0, score_workers=1))
    return TestClient(app, base_url="http://localhost")  # no lifespan: the WebSocket needs neither workers nor the job store


def _tum_rows(path: Path) -> list[list[float]]:
    return np.loadtxt(path).tolist()


def _stream(ws, rows: list[list[float]], per_message: int = 200) -> list[dict]:
    events = []
    for i in range(0, len(rows), per_message):
        ws.send_text(json.dumps({"type": "poses", "poses": rows[i:i + per_message]}))
    ws.send_text(json.dumps({"type": "end"}))
    while True:
        e = ws.receive_json()
        events.append(e)
        if e["type"] in ("final", "error"):
            return events


def test_websocket_kitti_00_ends_with_excite_score(ws_client, kitti, kitti_report, tmp_path):
    """KITTI 00, converted to TUM rows as the KITTI reader converts it, over the WebSocket: the
    final update is `excite score` of the same rows, and the drive's σ are KITTI 00's."""
    from scipy.spatial.transform import Rotation

    from excite.io.poses import R_CAM_VEH

    poses, times = kitti
    T = np.loadtxt(poses).reshape(-1, 3, 4)
    R = Rotation.from_matrix(R_CAM_VEH.T @ T[:, :, :3] @ R_CAM_VEH)
    rows = np.column_stack([np.loadtxt(times), T[:, :, 3] @ R_CAM_VEH, R.as_quat()])
    tum = tmp_path / "kitti_00.tum"
    np.savetxt(tum, rows, fmt="%.17g")
    score = evaluate(read_tum(tum), load_rig("robotaxi"))
    with ws_client.websocket_connect("ws://localhost/v1/live") as ws:
        ws.send_text(json.dumps({"type": "start", "rig": "robotaxi", "name": "kitti_00"}))
        assert ws.receive_json()["type"] == "started"
        events = _stream(ws, rows.tolist())
    final = events[-1]
    assert final["type"] == "final" and sum(e["type"] == "update" for e in events) >= 20
    for a, b, c in zip(final["parameters"], score.parameters, kitti_report.parameters):
        assert (a["sigma"] is None) == (b.sigma is None) == (c.sigma is None)
        if b.sigma is not None:
            assert _rel(a["sigma"], b.sigma) <= 1e-9, a["name"]
            assert _rel(a["sigma"], c.sigma) <= 1e-6, a["name"]  # quaternions vs matrices: last bits


def test_websocket_sessions_are_independent_and_freed(ws_client):
    rows = _tum_rows(FIGURE_EIGHT)
    score = evaluate(read_tum(FIGURE_EIGHT), load_rig("robotaxi"))
    slow = [[t * 2, x, y, z, qx, qy, qz, qw] for t, x, y, z, qx, qy, qz, qw in rows]  # same path, half speed
    score_slow = evaluate(read_tum(_write(slow)), load_rig("robotaxi"))
    with ws_client.websocket_connect("ws://localhost/v1/live") as a, ws_client.websocket_connect("ws://localhost/v1/live") as b:
        for ws in (a, b):
            ws.send_text(json.dumps({"type": "start"}))
            ws.receive_json()
        assert sum(ws_client.app.state.ctx.live_sessions.values()) == 2
        for i in range(0, len(rows), 300):  # interleaved
            a.send_text(json.dumps({"type": "poses", "poses": rows[i:i + 300]}))
            b.send_text(json.dumps({"type": "poses", "poses": slow[i:i + 300]}))
        ea, eb = _stream(a, []), _stream(b, [])
    for events, ref in ((ea, score), (eb, score_slow)):
        for p, q in zip(events[-1]["parameters"], ref.parameters):
            assert q.sigma is None or _rel(p["sigma"], q.sigma) <= 1e-9
    # a client that goes away mid-drive leaves nothing behind
    with ws_client.websocket_connect("ws://localhost/v1/live") as ws:
        ws.send_text(json.dumps({"type": "start"}))
        ws.receive_json()
        ws.send_text(json.dumps({"type": "poses", "poses": rows[:300]}))
    for _ in range(100):
        if not ws_client.app.state.ctx.live_sessions:
            break
        time.sleep(0.02)
    assert not ws_client.app.state.ctx.live_sessions


def _write(rows) -> Path:
    import tempfile

    path = Path(tempfile.mkdtemp()) / "slow.tum"
    np.savetxt(path, np.asarray(rows), fmt="%.9f")
    return path


def _refused(ws_client, messages, status: int, field: str, code: int) -> dict:
    from starlette.websockets import WebSocketDisconnect

    with ws_client.websocket_connect("ws://localhost/v1/live") as ws:
        for m in messages:
            ws.send_text(m if isinstance(m, str) else json.dumps(m))
        reply = ws.receive_json()
        while reply["type"] != "error":
            reply = ws.receive_json()
        problem = reply["problem"]
        assert problem["status"] == status and problem["errors"][0]["field"] == field, problem
        assert {"type", "title", "status", "detail"} <= problem.keys()
        with pytest.raises(WebSocketDisconnect) as closed:
            ws.receive_json()
        assert closed.value.code == code
    return problem


def test_websocket_refuses_bad_input_with_problems(ws_client, monkeypatch):
    from api.routers import live as router

    start = {"type": "start"}
    _refused(ws_client, ["{not json"], 400, "message", 1008)
    _refused(ws_client, [{"type": "poses", "poses": []}], 422, "type", 1008)
    _refused(ws_client, [{"type": "start", "rig": "no_such_rig"}], 422, "rig", 1008)
    _refused(ws_client, [start, {"type": "poses", "poses": [[0, 0, 0, 0, 0, 0, 0]]}], 422, "poses[0]", 1008)
    _refused(ws_client, [start, {"type": "poses", "poses": [[0, 0, 0, 0, 0, 0, 0, 2]]}], 422, "poses[0]", 1008)
    _refused(ws_client, [start, {"type": "poses", "poses": [[0, 0, 0, 0, 0, 0, 0, 1]],
                                 "imu": [[0, 1, 2]]}], 422, "imu[0]", 1008)
    p = _refused(ws_client, [start, {"type": "poses", "poses": [[1, 0, 0, 0, 0, 0, 0, 1], [0, 0, 0, 0, 0, 0, 0, 1]]}],
                 422, "poses", 1008)
    assert "increasing" in p["detail"]
    monkeypatch.setattr(router, "MAX_MESSAGE_BYTES", 200)
    _refused(ws_client, [start, {"type": "poses", "poses": [[0, 0, 0, 0, 0, 0, 0, 1]] * 10}], 413, "message", 1009)
    monkeypatch.setattr(router, "BURST", 3)
    monkeypatch.setattr(router, "MAX_MESSAGES_PER_S", 0.01)
    _refused(ws_client, [start] + [{"type": "poses", "poses": [[i, 0, 0, 0, 0, 0, 0, 1]]} for i in range(5)],
             429, "message", 1008)
    monkeypatch.setattr(router, "BURST", 100)
    monkeypatch.setattr(router, "IDLE_S", 0.2)
    _refused(ws_client, [start], 408, "session", 1008)  # then silence
    monkeypatch.setattr(router, "MAX_SESSIONS", 1)
    with ws_client.websocket_connect("ws://localhost/v1/live") as first:
        first.send_text(json.dumps(start))
        first.receive_json()
        from starlette.websockets import WebSocketDisconnect

        with ws_client.websocket_connect("ws://localhost/v1/live") as second:
            reply = second.receive_json()
            assert reply["type"] == "error" and reply["problem"]["status"] == 503
            with pytest.raises(WebSocketDisconnect) as closed:
                second.receive_json()
            assert closed.value.code == 1013


def test_websocket_over_a_real_connection(tmp_path):
    """The service behind uvicorn on loopback, its WebSocket configured as `excite serve` configures
    it: a drive streamed over a real WebSocket ends with `excite score`; a frame over the size bound
    is cut off by the protocol (1009) and the server serves on."""
    import socket

    import uvicorn
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    from api.app import create_app
    from api.routers import live as router
    from api.settings import Settings

    app = create_app(Settings(db_path=tmp_path / "j.sqlite3", workers=0, score_workers=1))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning",
                                           ws_max_size=router.MAX_MESSAGE_BYTES))
    th = threading.Thread(target=server.run, daemon=True)
    th.start()
    rows = _tum_rows(FIGURE_EIGHT)
    score = evaluate(read_tum(FIGURE_EIGHT), load_rig("robotaxi"))
    try:
        started_by = time.monotonic() + 120  # its lifespan warms the scoring worker first
        while not server.started and time.monotonic() < started_by:
            time.sleep(0.05)
        url = f"ws://127.0.0.1:{port}/v1/live"
        for attempt in ("drive", "oversize", "drive"):
            with connect(url, max_size=None) as ws:
                ws.send(json.dumps({"type": "start"}))
                assert json.loads(ws.recv(10))["type"] == "started"
                if attempt == "oversize":
                    ws.send(json.dumps({"type": "poses", "poses": [[0.0] * 8] * (router.MAX_MESSAGE_BYTES // 30)}))
                    with pytest.raises(ConnectionClosed) as closed:
                        ws.recv(10)
                    assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009
                    continue
                for i in range(0, len(rows), 100):
                    ws.send(json.dumps({"type": "poses", "poses": rows[i:i + 100]}))
                ws.send(json.dumps({"type": "end"}))
                events = []
                while not events or events[-1]["type"] != "final":
                    events.append(json.loads(ws.recv(30)))
            for p, q in zip(events[-1]["parameters"], score.parameters):
                assert q.sigma is None or _rel(p["sigma"], q.sigma) <= 1e-9
        for _ in range(100):
            if not app.state.ctx.live_sessions:
                break
            time.sleep(0.02)
        assert not app.state.ctx.live_sessions
    finally:
        server.should_exit = True
        th.join(10)


def test_cli_final_is_the_score_of_a_file_excite_wrote(tmp_path):
    """A crop written by write_tum (its poses already smooth) replayed: the final update is
    `excite score` of the same file, which does not smooth it a second time (that attenuated the
    motion: the final read 3.4 % under the score)."""
    from excite.score.evaluate import evaluate
    from excite.rig.config import load_rig
    from excite.io.routes import read_route, read_tum, write_tum

    window = read_route(REPO / "trajectories" / "slalom_control.csv").cropped(30.0, 60.0)
    tum = write_tum(window, tmp_path / "crop.tum", rate_hz=100.0)
    r = CliRunner().invoke(app, ["live", str(tum), "--replay", "1000x", "--json"])
    final = next(e for e in _json_lines(r.stdout) if e["type"] == "final")
    assert final["report"]["score"] == pytest.approx(evaluate(read_tum(tum), load_rig("robotaxi")).score, rel=1e-9)
