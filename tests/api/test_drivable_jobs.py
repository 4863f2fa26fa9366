"""Drivable plans through the service: a maneuver job with ``drivable`` gives the plan, its
instructions, cones and robust score and offers the sheet (PDF, PNG), the cone layout and the
plan; bad problems are refused with a 422 naming the limit; /v1/live follows a plan."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient

from api import Settings, create_app


def _client(tmp_path, workers: int = 0) -> TestClient:
    app = create_app(Settings(db_path=tmp_path / "j.sqlite3", workers=workers, score_workers=1))
    return TestClient(app, base_url="http://localhost", raise_server_exceptions=False)


def test_a_drivable_request_is_refused_naming_the_limit(tmp_path):
    with _client(tmp_path) as c:
        r = c.post("/v1/maneuvers", json={"drivable": True, "lot_x_m": 16, "lot_y_m": 16})
        assert r.status_code == 422, r.text
        assert "too small for any element" in r.json()["detail"] and "turning radius" in r.json()["detail"]
        assert r.json()["errors"][0]["field"] == "lot"
        r = c.post("/v1/maneuvers", json={"drivable": True, "lot_x_m": 40, "lot_y_m": 30, "speed_max_mps": 14})
        assert r.status_code == 422, r.text
        assert "above the lot's safe speed" in r.json()["detail"]
        assert r.json()["errors"][0]["field"] == "speed_max_mps"
        r = c.post("/v1/maneuvers", json={"drivable": True, "draws": 2})
        assert r.status_code == 422
        assert c.post("/v1/maneuvers", json={"drivable": True}).status_code == 202


@pytest.mark.slow
def test_a_drivable_job_gives_the_plan_and_its_sheet_cones_and_plan_downloads(tmp_path):
    with _client(tmp_path, workers=1) as c:
        r = c.post("/v1/maneuvers", json={"drivable": True, "duration_s": 60, "time_budget_s": 20, "draws": 8,
                                          "name": "lot_A"})
        assert r.status_code == 202, r.text
        loc = r.headers["location"]
        deadline = time.monotonic() + 240
        while True:
            job = c.get(loc).json()
            if job["status"] not in ("queued", "running"):
                break
            assert time.monotonic() < deadline, job
            time.sleep(1.0)
        assert job["status"] == "succeeded", job
        d = job["result"]["drivable"]
        assert d["plan"]["elements"] and len(d["instructions"]) == len(d["plan"]["elements"])
        assert d["robust"]["draws"] == 8 and d["robust"]["score_quantile"] > 0
        assert job["result"]["score"] == pytest.approx(d["robust"]["nominal"])
        cones = [f for f in d["cones"]["features"] if f["properties"]["role"] == "cone"]
        assert cones and d["cones"]["properties"]["crs"] == "local"
        for fmt, magic in (("sheet_pdf", b"%PDF"), ("sheet_png", b"\x89PNG")):
            f = c.get(job["links"][fmt])
            assert f.status_code == 200 and f.content.startswith(magic), f.text[:200]
            assert f.headers["content-disposition"].endswith(f'lot_A.{fmt.replace("_", ".")}"')
        plan = c.get(job["links"]["plan"]).json()
        assert plan["elements"] == d["plan"]["elements"]
        layout = c.get(job["links"]["cones"]).json()
        assert len([f for f in layout["features"] if f["properties"]["role"] == "cone"]) == len(cones)
        assert c.get(f"{loc}/maneuver", params={"format": "tum"}).status_code == 200

        # /v1/live with the plan: the element being driven is named
        from excite.motion.vehicle import Limits, drive
        from excite.plan.drivable.plan import build, plan_from_dict
        from excite.rig.config import load_rig

        built = build(plan_from_dict(plan), Limits())
        traj = drive(built.timed().profile, load_rig("robotaxi").suspension)
        t = np.arange(0.0, 20.0, 0.1)
        s = traj.sample(t)
        from scipy.spatial.transform import Rotation

        q = Rotation.from_matrix(s.R_W_V).as_quat()
        poses = [[float(a), *map(float, p), *map(float, qq)] for a, p, qq in zip(t, s.p_W_V, q)]
        with c.websocket_connect("ws://localhost/v1/live") as ws:
            ws.send_text(json.dumps({"type": "start", "name": "drive", "plan": plan}))
            assert ws.receive_json()["type"] == "started"
            got = []
            for k in range(0, len(poses), 20):
                ws.send_text(json.dumps({"type": "poses", "poses": poses[k:k + 20]}))
            ws.send_text(json.dumps({"type": "end"}))
            while True:
                m = ws.receive_json()
                got.append(m)
                if m["type"] in ("final", "error"):
                    break
        elements = [m for m in got if m["type"] == "element"]
        assert elements and elements[0]["element"] == 1, [m["type"] for m in got]
        assert got[-1]["type"] == "final"


def test_a_live_start_with_a_malformed_plan_is_refused_naming_it(tmp_path):
    with _client(tmp_path) as c:
        with c.websocket_connect("ws://localhost/v1/live") as ws:
            ws.send_text(json.dumps({"type": "start", "plan": {"elements": [{"kind": "donut"}]}}))
            m = ws.receive_json()
            assert m["type"] == "error" and "plan" in m["problem"]["detail"], m
