"""The service with car rig (four CAN wheel speeds, the steering angle, a radar): /v1/rigs lists it, /v1/score scores it
(bundled or given inline, its errors named), /v1/live guides a drive with it — σ as the evaluator's."""

from __future__ import annotations

import json
import numpy as np
import pytest
from excite.motion.vehicle import ControlProfile, drive
from excite.rig.config import load_rig
from excite.score.evaluate import evaluate


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


NEW = ("wheel.scale_fl", "wheel.track_rear", "wheel.wheelbase", "steering.ratio", "steering.offset",
       "wheel.time_offset", "radar_front.rot_z", "radar_front.trans_x", "radar_front.time_offset")


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
