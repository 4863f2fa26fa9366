"""/v1/scenes: a scene file uploaded once, kept for its key under the digest of the scene it holds,
named by that digest (or a bundled scene by its name) in the score, plot, batch and live requests;
bad files are problems naming the field, sizes and storage bounded, another key's scenes unseen."""

from __future__ import annotations

import json
import time

import pytest
from fastapi.testclient import TestClient

from api import Settings, create_app
from excite.io.routes import read_route
from excite.rig.config import load_rig
from excite.scene.along import seen
from excite.scene.files import load_scene
from excite.score.evaluate import evaluate
from helpers import REPO
from servers import write_keys

LOOP = {"waypoints": [[0, 0], [30, 0], [30, 20], [0, 20], [0, 1]]}
KEYS = {"scorer": {"scopes": ["score"]}, "other": {"scopes": ["score"]}, "planner": {"scopes": ["plan"]},
        "small": {"scopes": ["score"], "quota": {"storage_mb": 1}}, "both": {"scopes": ["score", "plan"]}}
CONTROL = (REPO / "trajectories" / "figure_eight_control.csv").read_text()


def scene_file(walls: list[tuple[float, float, float, float]], pad: int = 0) -> bytes:
    """A GeoJSON scene (local metres): level ground and walls 4 m high; ``pad`` bytes of white space."""
    features = [{"type": "Feature", "properties": {"kind": "ground"}, "geometry": {"type": "Polygon", "coordinates": [
        [[-150, -150], [150, -150], [150, 150], [-150, 150], [-150, -150]]]}}]
    features += [{"type": "Feature", "properties": {"kind": "wall", "height": 4.0, "name": f"wall {i}"},
                  "geometry": {"type": "LineString", "coordinates": [[x0, y0], [x1, y1]]}}
                 for i, (x0, y0, x1, y1) in enumerate(walls)]
    text = json.dumps({"type": "FeatureCollection", "properties": {"crs": "local"}, "features": features})
    return (text + " " * pad).encode()


@pytest.fixture(scope="module")
def keyed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("scenes")
    secrets = write_keys(tmp / "keys.yaml", KEYS)
    app = create_app(Settings(db_path=tmp / "jobs.sqlite3", workers=0, score_workers=1,
                              api_keys_file=tmp / "keys.yaml", max_scene_bytes=2_000_000))
    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        yield c, secrets


def _h(secrets, key_id: str) -> dict[str, str]:
    return {"X-API-Key": secrets[key_id]}


def _problem(r, status: int, field: str | None = None) -> dict:
    assert r.status_code == status, (r.status_code, r.text[:400])
    assert r.headers["content-type"].startswith("application/problem+json")
    body = r.json()
    if field is not None:
        assert body["errors"][0]["field"] == field, body
    return body


def _upload(c, secrets, key, name, data):
    return c.post("/v1/scenes", files={"file": (name, data, "application/geo+json")}, headers=_h(secrets, key))


def test_a_scene_is_kept_for_its_key_under_its_digest(keyed):
    c, s = keyed
    data = scene_file([(-100, 40, 100, 40)])
    r = _upload(c, s, "scorer", "depot.geojson", data)
    assert r.status_code == 201, r.text
    got = r.json()
    digest = load_scene("depot.geojson", data=data).digest
    assert got["digest"] == digest and got["name"] == "depot.geojson" and got["size_bytes"] == len(data)
    assert got["surfaces_by_kind"] == {"ground": 1, "wall": 1}
    assert got["area_m2_by_kind"] == pytest.approx({"ground": 300.0 * 300.0, "wall": 200.0 * 4.0})
    assert r.headers["location"] == f"/v1/scenes/{digest}"
    again = _upload(c, s, "scorer", "depot-copy.geojson", data)
    assert again.status_code == 200 and again.json()["digest"] == digest
    listed = c.get("/v1/scenes", headers=_h(s, "scorer")).json()
    assert "street_canyon" in listed["bundled"] and [x["digest"] for x in listed["uploaded"]] == [digest]
    view = c.get(f"/v1/scenes/{digest}", headers=_h(s, "scorer")).json()
    wall = [x for x in view["outline"]["surfaces"] if x["kind"] == "wall"]
    assert wall[0]["segments"] == [[-100.0, 40.0, 100.0, 40.0]]
    # another key neither sees nor uses it
    _problem(c.get(f"/v1/scenes/{digest}", headers=_h(s, "other")), 404)
    assert c.get("/v1/scenes", headers=_h(s, "other")).json()["uploaded"] == []
    body = _problem(c.post("/v1/score", json={"route": LOOP, "scene": digest}, headers=_h(s, "other")), 422, "scene")
    assert "no scene" in body["detail"]
    _problem(c.delete(f"/v1/scenes/{digest}", headers=_h(s, "other")), 404)
    # a key without the score scope, or none at all
    _problem(_upload(c, s, "planner", "depot.geojson", data), 403)
    _problem(c.post("/v1/scenes", files={"file": ("depot.geojson", data)}, headers={"X-Excite-Client": "t"}), 401)


def test_bad_scene_files_are_problems_naming_the_field(keyed):
    c, s = keyed
    bad = json.dumps({"type": "FeatureCollection", "properties": {"crs": "local"}, "features": [
        {"type": "Feature", "properties": {"kind": "building", "height": -3.0},
         "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [10, 0], [10, 10], [0, 0]]]}}]}).encode()
    body = _problem(_upload(c, s, "scorer", "yard.geojson", bad), 422, "file")
    assert "yard.geojson" in body["detail"] and "height" in body["detail"] and "/tmp" not in body["detail"]
    body = _problem(_upload(c, s, "scorer", "yard.txt", bad), 422, "file")
    assert ".geojson" in body["detail"]
    _problem(_upload(c, s, "scorer", "empty.geojson", b""), 422, "file")
    body = _problem(_upload(c, s, "scorer", "huge.geojson", scene_file([], pad=2_000_001)), 413, "file")
    assert "2000000 bytes" in body["detail"]
    body = _problem(c.post("/v1/score", json={"route": LOOP, "scene": "atlantis"}, headers=_h(s, "scorer")),
                    422, "scene")
    assert "street_canyon" in body["detail"]
    _problem(c.post("/v1/score", json={"route": LOOP, "scene": "../etc/passwd"}, headers=_h(s, "scorer")),
             422, "scene")


def test_scores_in_a_scene_are_the_library_s_and_name_it(keyed):
    c, s = keyed
    data = scene_file([(-100, 60, 100, 60), (-100, -60, 100, -60)])
    digest = _upload(c, s, "scorer", "street.geojson", data).json()["digest"]
    route = {"format": "control_csv", "text": CONTROL, "name": "figure_eight"}
    r = c.post("/v1/score", json={"route": route, "scene": digest, "track_points": 50}, headers=_h(s, "scorer"))
    assert r.status_code == 200, r.text[:500]
    got = r.json()
    assert got["scene"] == {"name": "street.geojson", "digest": digest}
    rig = load_rig("robotaxi")
    traj = read_route(REPO / "trajectories" / "figure_eight_control.csv", suspension=rig.suspension)
    expected = evaluate(seen(traj, rig, load_scene("street.geojson", data=data)), rig)
    assert got["score"] == pytest.approx(expected.score, rel=1e-9)
    for p, e in zip(got["parameters"], expected.parameters):
        assert p["sigma"] == pytest.approx(e.sigma, rel=1e-9), p["name"]
    # along the route: two parallel walls along x leave each scan's x translation, and only that
    assert got["scene_track"] and all(x["unobservable"] == ["x translation"] for x in got["scene_track"])
    # a bundled scene by its name: the open lot leaves x, y and yaw
    r = c.post("/v1/score", json={"route": LOOP, "scene": "open_lot", "track_points": 20}, headers=_h(s, "scorer"))
    got = r.json()
    assert got["scene"]["name"] == "open_lot" and got["scene"]["digest"] == load_scene("open_lot").digest
    assert all(set(x["unobservable"]) == {"x translation", "y translation", "yaw"} for x in got["scene_track"])
    blind = c.post("/v1/score", json={"route": LOOP}, headers=_h(s, "scorer")).json()
    assert blind["scene"] is None and "scene_track" not in blind or blind["scene_track"] is None
    # the batch: every route in the scene
    b = c.post("/v1/batch", json={"routes": [LOOP, route], "scene": "open_lot"}, headers=_h(s, "scorer")).json()
    assert [x["report"]["scene"]["name"] for x in b["results"]] == ["open_lot", "open_lot"]
    png = c.post("/v1/score/plot", json={"route": LOOP, "scene": digest}, headers=_h(s, "scorer"))
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"


def test_scenes_count_against_the_key_s_storage(keyed):
    """The key "small" may store 1 MiB: a second scene of 0.6 MB pushes out the first (least
    recently used), and one of 1.5 MB is refused."""
    c, s = keyed
    first = _upload(c, s, "small", "a.geojson", scene_file([(-50, 10, 50, 10)], pad=600_000))
    assert first.status_code == 201, first.text[:300]
    second = _upload(c, s, "small", "b.geojson", scene_file([(-50, 20, 50, 20)], pad=600_000))
    assert second.status_code == 201
    kept = [x["digest"] for x in c.get("/v1/scenes", headers=_h(s, "small")).json()["uploaded"]]
    assert kept == [second.json()["digest"]]
    body = _problem(_upload(c, s, "small", "c.geojson", scene_file([(-50, 30, 50, 30)], pad=1_500_000)), 429)
    assert "storage quota" in body["detail"]
    assert c.delete(f"/v1/scenes/{kept[0]}", headers=_h(s, "small")).status_code == 204
    assert c.get("/v1/scenes", headers=_h(s, "small")).json()["uploaded"] == []


def test_a_live_session_sees_its_scene(keyed):
    c, s = keyed
    rows = [line.split() for line in (REPO / "trajectories" / "figure_eight.tum").read_text().splitlines()
            if line.strip() and not line.startswith("#")]
    poses = [[float(x) for x in r] for r in rows if float(r[0]) <= 30.0]
    with c.websocket_connect("ws://localhost/v1/live", headers=_h(s, "scorer")) as ws:
        ws.send_json({"type": "start", "scene": "open_lot"})
        started = ws.receive_json()
        assert started["type"] == "started" and started["scene"]["name"] == "open_lot"
        ws.send_json({"type": "poses", "poses": poses})
        ws.send_json({"type": "end"})
        while (msg := ws.receive_json())["type"] != "final":
            assert msg["type"] in ("update", "done") and msg.get("scene", started["scene"]) == started["scene"]
    assert msg["report"]["scene"] == started["scene"]
    with c.websocket_connect("ws://localhost/v1/live", headers=_h(s, "scorer")) as ws:
        ws.send_json({"type": "start", "scene": "f" * 64})
        msg = ws.receive_json()
        assert msg["type"] == "error" and msg["problem"]["errors"][0]["field"] == "scene"


def test_a_drivable_plan_may_be_planned_in_a_scene(keyed):
    """A maneuver request names a scene for a drivable plan only; a scene that does not reach over
    the lot, or another key's, is refused naming the field; an accepted job keeps the scene's name
    or digest in its request (the run is given the file)."""
    c, s = keyed
    body = _problem(c.post("/v1/maneuvers", json={"scene": "open_lot"}, headers=_h(s, "both")), 422, "scene")
    assert "drivable" in body["detail"]
    far = b'{"type": "FeatureCollection", "properties": {"crs": "local"}, "features": [{"type": "Feature", ' \
          b'"properties": {"kind": "ground"}, "geometry": {"type": "Polygon", "coordinates": ' \
          b'[[[1000, 1000], [1200, 1000], [1200, 1200], [1000, 1200], [1000, 1000]]]}}]}'
    digest = _upload(c, s, "both", "far.geojson", far).json()["digest"]
    body = _problem(c.post("/v1/maneuvers", json={"drivable": True, "scene": digest}, headers=_h(s, "both")),
                    422, "scene")
    assert "do not overlap" in body["detail"]
    _problem(c.post("/v1/maneuvers", json={"drivable": True, "scene": digest}, headers=_h(s, "planner")),
             422, "scene")  # the planner's key did not upload it
    r = c.post("/v1/maneuvers", json={"drivable": True, "scene": "open_lot"}, headers=_h(s, "both"))
    assert r.status_code == 202, r.text[:300]
    store = c.app.state.ctx.store
    assert store.request_of(r.json()["id"])["scene"] == "open_lot"
    runner = c.app.state.ctx.runner
    assert runner._scene(r.json()["id"], "open_lot") == ("bundled", "open_lot")
    assert runner._scene(r.json()["id"], digest) == ("upload", digest, "far.geojson", far)
    theirs = c.post("/v1/maneuvers", json={"drivable": True}, headers=_h(s, "planner")).json()["id"]
    assert runner._scene(theirs, digest) is None  # a job of another key is not given it


@pytest.mark.slow
def test_a_drivable_job_in_a_scene_reports_it(tmp_path):
    app = create_app(Settings(db_path=tmp_path / "j.sqlite3", workers=1, score_workers=1))
    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        r = c.post("/v1/maneuvers", json={"drivable": True, "duration_s": 60, "time_budget_s": 20, "draws": 5,
                                          "scene": "lot_buildings_one_side"})
        assert r.status_code == 202, r.text
        deadline = time.monotonic() + 300
        while (job := c.get(r.headers["location"]).json())["status"] in ("queued", "running"):
            assert time.monotonic() < deadline, job
            time.sleep(1.0)
    assert job["status"] == "succeeded", job
    scene = load_scene("lot_buildings_one_side")
    assert job["result"]["report"]["scene"] == {"name": "lot_buildings_one_side", "digest": scene.digest}
