"""The service over a real HTTP connection: `excite serve` on a loopback port, real optimizer."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest

from excite.io import routes
from servers import LiveServer, wait_job

PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = LiveServer(tmp_path_factory.mktemp("http"), workers=1, score_workers=2,
                     max_body_bytes=4 * 1024 * 1024, max_samples=20_000,
                     max_route_duration_s=1200, max_job_time_budget_s=30).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def client(server):
    with server.client() as c:
        yield c


def _problem(r, status: int, field: str | None = None) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM)
    body = r.json()
    assert {"type", "title", "status", "detail", "instance"} <= body.keys()
    assert body["status"] == status
    assert "Traceback" not in r.text
    if field is not None:
        assert any(e["field"] == field for e in body["errors"]), body
    return body


@pytest.mark.slow
def test_score_kitti_00_uploaded_inline(client, data_dir):
    body = {"route": {"name": "kitti_00", "format": "kitti",
                      "text": (data_dir / "kitti_00_poses.txt").read_text(),
                      "times_text": (data_dir / "kitti_00_times.txt").read_text()},
            "rig": "robotaxi", "segments": 4}
    r = client.post("/v1/score", json=body)
    assert r.status_code == 200, r.text
    rep = r.json()
    assert rep["route"] == "kitti_00" and rep["rig"] == "robotaxi"
    assert 400 < rep["duration_s"] < 500 and rep["length_m"] > 3000
    assert rep["score"] >= 0 and len(rep["spectrum_scaled"]) == len(rep["column_map"])
    names = {c["name"] for c in rep["column_map"]}
    assert "lidar.trans_z" in names and "wheel.track" in names
    assert len(rep["segments"]) == 4
    # the same numbers as the library on the same files
    from excite.score.evaluate import Options, evaluate
    from excite.rig.config import load_rig

    rig = load_rig("robotaxi")
    lib = evaluate(routes.read_kitti(data_dir / "kitti_00_poses.txt", data_dir / "kitti_00_times.txt"),
                   rig, Options(segments=4))
    assert rep["score"] == pytest.approx(lib.score, rel=1e-9)


def test_score_plot_returns_the_report_figure(client):
    route = {"control": {"t_s": [0, 10, 20, 30], "speed_mps": [0, 6, 6, 0], "curvature_1pm": [0, 0.1, -0.1, 0]}}
    r = client.post("/v1/score/plot", json={"route": route, "parameter": "wheel.track"})
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "image/png" and r.content[:8] == b"\x89PNG\r\n\x1a\n"
    _problem(client.post("/v1/score/plot", json={"route": route, "parameter": "wheel.trak"}), 422, "parameter")


def test_score_json_waypoints_poses_and_control(client):
    wp = {"route": {"waypoints": [[0, 0], [30, 0], [30, 20], [0, 20], [0, 1]]}}
    r = client.post("/v1/score", json=wp)
    assert r.status_code == 200, r.text
    t = np.arange(0, 30, 0.1)
    poses = [{"t": float(ti), "position": [5 * float(ti), 0.0, 0.0], "quaternion_xyzw": [0, 0, 0, 1]}
             for ti in t]
    r = client.post("/v1/score", json={"route": {"poses": poses, "name": "straight"}})
    assert r.status_code == 200, r.text
    assert r.json()["route"] == "straight" and r.json()["nullity"] > 0  # straight: unobservable
    ctrl = {"t_s": [0, 5, 10, 20, 30], "speed_mps": [0, 5, 6, 5, 0],
            "curvature_1pm": [0, 0.05, -0.05, 0.05, 0], "start": {"x_m": 1, "y_m": 2, "heading_rad": 0.5}}
    r = client.post("/v1/score", json={"route": {"control": ctrl}})
    assert r.status_code == 200, r.text
    assert r.json()["duration_s"] == pytest.approx(30, abs=0.2)


def test_errors_are_problems_naming_the_field(client, data_dir):
    # NaN literal in the JSON body
    r = client.post("/v1/score", content=b'{"route": {"waypoints": [[0, 0], [NaN, 1]]}}',
                    headers={"content-type": "application/json"})
    _problem(r, 422, "route.waypoints[1][0]")
    r = client.post("/v1/score", content=b'{"route": {"waypoints": [[0, 0], [1, 1]]}, "segments": Infinity}',
                    headers={"content-type": "application/json"})
    _problem(r, 422, "segments")
    # a NaN inside an inline rig (the schema takes a rig object as it is): refused as the rig's
    r = client.post("/v1/score", content=b'{"route": {"waypoints": [[0, 0], [30, 0], [30, 20]]}, '
                                         b'"rig": {"name": "r", "imu": {"update_rate": NaN}}}',
                    headers={"content-type": "application/json"})
    assert "NaN or infinity" in _problem(r, 422, "rig")["detail"]
    # more segments than a short route holds (6 s at 10 Hz: 61 keyframes, at most 30): the most it
    # holds, and a warning that says so
    short = {"control": {"t_s": [0, 3, 6], "speed_mps": [0, 4, 0], "curvature_1pm": [0, 0.05, 0]}}
    rep = client.post("/v1/score", json={"route": short, "segments": 31}).json()
    assert len(rep["segments"]) == 30 and rep["segments"][29]["t_end_s"] > 5.9
    assert rep["warnings"] == ["segments: 31 asked, 30 reported: the drive holds at most 30 of 3 keyframes or "
                               "more and a whole number of every sensor's frames (61 keyframes at 10 Hz)"]
    # a malformed line of an uploaded file: the field and the line
    lines = (data_dir / "kitti_00_poses.txt").read_text().splitlines()[:50]
    lines[9] = lines[9].replace(" ", " x", 1)
    r = client.post("/v1/score", json={"route": {"format": "kitti", "text": "\n".join(lines),
                                                 "times_text": "\n".join(str(0.1 * i) for i in range(50))}})
    body = _problem(r, 422, "route.text")
    assert "line 10" in body["detail"] and "/tmp" not in body["detail"]
    # a repeated waypoint: its index
    r = client.post("/v1/score", json={"route": {"waypoints": [[0, 0], [10, 0], [10, 0], [20, 5]]}})
    _problem(r, 422, "route.waypoints[2]")
    # no route at all, two routes, unknown keys
    _problem(client.post("/v1/score", json={"route": {}}), 422)
    _problem(client.post("/v1/score", json={"route": {"waypoints": [[0, 0], [1, 1]]}, "bogus": 1}), 422, "bogus")
    # rigs: unknown name, a path the server would read, an invalid inline rig
    _problem(client.post("/v1/score", json={"route": {"waypoints": [[0, 0], [9, 9]]}, "rig": "nope"}), 422, "rig")
    _problem(client.post("/v1/score", json={"route": {"waypoints": [[0, 0], [9, 9]]},
                                            "rig": {"imu": "/etc/passwd"}}), 422, "rig.imu")
    body = _problem(client.post("/v1/score", json={"route": {"waypoints": [[0, 0], [9, 9]]},
                                                   "rig": {"imu": {"update_rate": 200}}}), 422)
    assert body["errors"][0]["field"].startswith("rig")
    # bounds: samples (413), duration (422), body size (413): each quotes its bound
    body = _problem(client.post("/v1/score", json={"route": {"format": "tum", "text": "0 0 0 0 0 0 0 1\n" * 20_001}}), 413)
    assert "20000" in body["detail"]
    poses = [{"t": 200.0 * i, "position": [i, 0, 0], "quaternion_xyzw": [0, 0, 0, 1]} for i in range(8)]
    body = _problem(client.post("/v1/score", json={"route": {"poses": poses}}), 422, "route.poses")
    assert "1200" in body["detail"]
    big = b'{"route": {"format": "tum", "text": "' + b"0" * (5 * 1024 * 1024) + b'"}}'
    body = _problem(client.post("/v1/score", content=big, headers={"content-type": "application/json"}), 413)
    assert str(4 * 1024 * 1024) in body["detail"]
    # unknown job, unknown path, malformed JSON
    _problem(client.get("/v1/jobs/0123456789abcdef"), 404)
    _problem(client.get("/v1/nothing"), 404)
    _problem(client.post("/v1/score", content=b"{", headers={"content-type": "application/json"}), 422)


def test_streamed_body_is_bounded_without_content_length(server):
    import httpx

    def chunks():
        yield b'{"route": {"format": "tum", "text": "'
        for _ in range(80):
            yield b"0" * 65536
        yield b'"}}'

    with httpx.Client(base_url=server.url, timeout=60) as c:
        r = c.post("/v1/score", content=chunks(), headers={"content-type": "application/json"})
    _problem(r, 413)


def test_batch_reports_each_route_and_a_summary(client):
    body = {"routes": [{"name": "loop", "waypoints": [[0, 0], [30, 0], [30, 20], [0, 20], [0, 1]]},
                       {"name": "bad", "waypoints": [[0, 0], [0, 0], [3, 3]]},
                       {"name": "ctrl", "control": {"t_s": [0, 10, 20], "speed_mps": [0, 5, 0],
                                                    "curvature_1pm": [0, 0.1, 0]}}]}
    r = client.post("/v1/batch", json=body)
    assert r.status_code == 200, r.text
    out = r.json()
    s = out["summary"]
    assert s["count"] == 3 and s["errors"] == 1 and s["passed"] + s["failed"] == 2
    assert s["min_score"] == min(x["report"]["score"] for x in out["results"] if x["report"])
    bad = out["results"][1]
    assert bad["report"] is None and bad["error"]["errors"][0]["field"] == "routes[1].waypoints[1]"


def test_rigs_probes_metrics_docs(client):
    rigs = client.get("/v1/rigs").json()["rigs"]
    assert any(r["name"] == "robotaxi" and r["parameters"] for r in rigs)
    assert client.get("/healthz").json()["status"] == "ok"
    assert client.get("/readyz").status_code == 200
    m = client.get("/metrics")
    assert m.status_code == 200 and "excite_http_requests_total" in m.text
    assert 'route="/v1/score"' in m.text and "excite_jobs" in m.text
    assert client.get("/docs").status_code == 200
    spec = client.get("/openapi.json").json()
    assert {"/v1/score", "/v1/batch", "/v1/maneuvers", "/v1/jobs/{job_id}", "/v1/rigs"} <= spec["paths"].keys()


@pytest.mark.slow
def test_optimization_job_runs_to_completion_and_downloads(client):
    req = {"duration_s": 60, "time_budget_s": 5, "n_random": 4, "seed": 1, "name": "lot_a",
           "origin": {"lon_deg": 11.57, "lat_deg": 48.14}}
    r = client.post("/v1/maneuvers", json=req)
    assert r.status_code == 202, r.text
    loc = r.headers["location"]
    assert loc == f"/v1/jobs/{r.json()['id']}" and r.json()["status"] in ("queued", "running")
    job = wait_job(client, loc, timeout_s=150)
    assert job["status"] == "succeeded", job
    assert job["progress"]["score"] is not None and job["progress"]["iteration"] is not None
    res = job["result"]
    assert res["report"]["route"] == "lot_a" and res["report"]["score"] > 0
    assert res["comparison"] and all("score" in row for row in res["comparison"])
    # how the optimizer ran, as the CLI's report.json says it: its starts and whether it was compiled
    assert 1 <= res["starts"] and 0 <= res["starts_converged"] <= res["starts"]
    assert res["compiled"] in (True, False) and (res["compiled"] or "virtual machine" in res["message"])
    with tempfile.TemporaryDirectory() as tmp:
        for fmt, suffix in (("tum", ".tum"), ("csv", ".csv"), ("control", ".csv"), ("geojson", ".geojson")):
            d = client.get(f"{loc}/maneuver", params={"format": fmt})
            assert d.status_code == 200, d.text
            path = Path(tmp) / f"m_{fmt}{suffix}"
            path.write_text(d.text)
            traj = routes.read_route(path)  # every download reads back
            assert traj.duration > 10
    # a finished job cannot be cancelled
    _problem(client.delete(loc), 409)


@pytest.mark.slow
def test_cancel_a_queued_job(client):
    # one job worker: the second job waits in the queue and is cancelled at once
    a = client.post("/v1/maneuvers", json={"duration_s": 60, "time_budget_s": 5, "n_random": 2})
    b = client.post("/v1/maneuvers", json={"duration_s": 60, "time_budget_s": 5, "n_random": 2})
    assert a.status_code == b.status_code == 202
    r = client.delete(b.headers["location"])
    assert r.status_code in (200, 202), r.text
    job = wait_job(client, b.headers["location"])
    assert job["status"] in ("cancelled", "succeeded")  # succeeded only if it had already finished
    assert job["cancel_requested"] is True
    wait_job(client, a.headers["location"], timeout_s=150)
