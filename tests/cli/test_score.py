"""A car rig (four CAN wheel speeds, the steering angle, a radar) on every surface: live guidance,
mining, the optimizer's CasADi model, the service (score, rigs, live) and the command line —
with no change to any of them for the new kinds, and with the evaluator's σ everywhere."""

from __future__ import annotations

import json

import numpy as np
import pytest

from excite.motion.vehicle import ControlProfile, drive
from excite.rig.config import load_rig
from excite.score.evaluate import evaluate
from test_optimize import model_samples


@pytest.fixture(scope="module")
def rig():
    return load_rig("sedan")


@pytest.fixture(scope="module")
def traj(rig):
    t = np.linspace(0.0, 40.0, 81)
    prof = ControlProfile(t, 6 + 3 * np.sin(t / 4), 0.08 * np.sin(t / 3), grade_rad=0.03 * np.sin(t / 5))
    return drive(prof, rig.suspension)


@pytest.fixture(scope="module")
def report(rig, traj):
    return evaluate(traj, rig)


def _sigma(Lam, rig, name):
    from excite.information.closure import marginalise_nuisance

    scored = np.array([not c.nuisance for c in rig.coordinates] + [True] * (Lam.shape[0] - len(rig.coordinates)))
    L = marginalise_nuisance(Lam, scored)
    i = [c.name for c in rig.scored].index(name)
    return float(np.sqrt(np.linalg.inv(L)[i, i]))


NEW = ("wheel.scale_fl", "wheel.track_rear", "wheel.wheelbase", "steering.ratio", "steering.offset",
       "wheel.time_offset", "radar_front.rot_z", "radar_front.trans_x", "radar_front.time_offset")


def test_live_guidance(rig, traj, report):
    from excite.score.live import Incremental, chunks

    inc = Incremental(rig)
    for c in chunks(traj, rig):
        inc.append(c)
    Lam = inc.information().information
    sig = {p.name: p.sigma for p in report.parameters}
    for n in NEW:
        assert _sigma(Lam, rig, n) == pytest.approx(sig[n], rel=1e-7), n


def test_mining(rig, traj):
    from excite.fleet import mine

    s = mine.summarise(traj, rig, chunk_s=10.0)
    Lam, _ = mine.window_information(s, 2, first=1)  # chunks 1 and 2
    crop = mine.crop(traj, s.time(int(s.edges[1])), s.time(int(s.edges[3])))
    sig = {p.name: p.sigma for p in evaluate(crop, rig).parameters}
    for n in NEW:
        assert _sigma(Lam[0], rig, n) == pytest.approx(sig[n], rel=1e-6), n


def test_the_optimizers_model(rig, traj):
    from excite.factors.base import Nominal
    from excite.information import elimination, problem
    from excite.plan.model import build_model, coarse_rig

    coarse = coarse_rig(rig, 2.0, 4)
    nom = Nominal.of(traj, coarse)
    _, args = model_samples(traj, coarse)
    Lam = np.array(build_model(coarse, nom.n_keyframes).marginal(*args))
    ref = elimination.marginal(problem.build(nom, coarse))
    assert np.abs(Lam - ref).max() <= 1e-6 * np.abs(ref).max()
    for n_ in NEW:
        assert ref[coarse.index(n_), coarse.index(n_)] > 0


def test_the_command_line_scores_and_shows_the_rig(tmp_path, capsys):
    from excite.cli.app import main
    from excite.io.routes import write_tum

    t = np.linspace(0.0, 30.0, 61)
    route = write_tum(drive(ControlProfile(t, 5 + 2 * np.sin(t / 3), 0.1 * np.sin(t / 4))), tmp_path / "drive.tum")
    assert main(["score", str(route), "--rig", "sedan", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    names = {p["name"] for p in out["parameters"]}
    assert {"wheel.wheelbase", "steering.ratio", "radar_front.rot_z"} <= names
    assert main(["rig", "show", "sedan"]) == 0 and "ackermann:" in capsys.readouterr().out


# --- the service ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    from fastapi.testclient import TestClient

    from api import Settings, create_app

    app = create_app(Settings(db_path=tmp_path_factory.mktemp("car") / "j.sqlite3", workers=0, score_workers=1))
    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        yield c


def test_the_service_lists_and_scores_the_car(client, report):
    rigs = {r["name"]: r for r in client.get("/v1/rigs").json()["rigs"]}
    assert "sedan" in rigs and "steering.ratio" in {p["name"] for p in rigs["sedan"]["parameters"]}
    route = {"control": {"t_s": list(np.linspace(0.0, 40.0, 81)),
                         "speed_mps": list(6 + 3 * np.sin(np.linspace(0.0, 40.0, 81) / 4)),
                         "curvature_1pm": list(0.08 * np.sin(np.linspace(0.0, 40.0, 81) / 3)),
                         "grade_rad": list(0.03 * np.sin(np.linspace(0.0, 40.0, 81) / 5))}}
    r = client.post("/v1/score", json={"route": route, "rig": "sedan"})
    assert r.status_code == 200, r.text
    got = {p["name"]: p["sigma"] for p in r.json()["parameters"]}
    want = {p.name: p.sigma for p in report.parameters}
    for n in NEW:
        assert got[n] == pytest.approx(want[n], rel=1e-6), n


def test_the_service_takes_a_car_rig_inline_and_names_its_errors(client):
    import yaml

    from excite.rig.config import RIGS_DIR

    data = yaml.safe_load((RIGS_DIR / "sedan.yaml").read_text())
    route = {"control": {"t_s": [0.0, 10.0, 20.0], "speed_mps": [0.0, 5.0, 0.0], "curvature_1pm": [0.0, 0.1, 0.0]}}
    assert client.post("/v1/score", json={"route": route, "rig": data}).status_code == 200
    data["ackermann"]["speeds"] = "radps"
    r = client.post("/v1/score", json={"route": route, "rig": data})
    assert r.status_code == 422 and "radius_m" in r.text and "Traceback" not in r.text


def test_live_guidance_over_the_service(client):
    from scipy.spatial.transform import Rotation

    t = np.arange(0.0, 30.0, 0.1)
    traj = drive(ControlProfile(np.linspace(0, 30, 31), 5 + 2 * np.sin(np.linspace(0, 30, 31) / 3),
                                0.1 * np.sin(np.linspace(0, 30, 31) / 4)))
    s = traj.sample(t)
    rows = np.column_stack([t, s.p_W_V, Rotation.from_matrix(s.R_W_V).as_quat()]).tolist()
    with client.websocket_connect("ws://localhost/v1/live") as ws:
        ws.send_text(json.dumps({"type": "start", "rig": "sedan", "name": "car"}))
        assert ws.receive_json()["type"] == "started"
        for i in range(0, len(rows), 100):
            ws.send_text(json.dumps({"type": "poses", "poses": rows[i:i + 100]}))
        ws.send_text(json.dumps({"type": "end"}))
        while True:
            e = ws.receive_json()
            if e["type"] in ("final", "error"):
                break
    assert e["type"] == "final", e
    assert {"wheel.wheelbase", "steering.offset", "radar_front.rot_z"} <= {p["name"] for p in e["parameters"]}
