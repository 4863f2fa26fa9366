"""Who may do what: API keys with scopes and owners, jobs that belong to their key,
per-key quotas, a fair job queue, browser safety, and a server that will not serve the network
without keys. In-process (TestClient) unless a real socket or process is the point."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from api import Settings, create_app
from api.store import JobStore as SqliteStore
from servers import LiveServer, job_result_file, write_keys

LOOP = {"waypoints": [[0, 0], [30, 0], [30, 20], [0, 20], [0, 1]]}
JOB = {"duration_s": 60, "time_budget_s": 5, "n_random": 2}
KEYS = {"scorer": {"scopes": ["score"]}, "planner": {"scopes": ["plan"], "quota": {"jobs": 3}},
        "other": {"scopes": ["plan", "score"]}, "root": {"scopes": ["admin"]},
        "slow": {"scopes": ["score"], "quota": {"rate_per_s": 0.5, "burst": 2, "live_sessions": 1}}}


@pytest.fixture(scope="module")
def keyed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("auth")
    secrets = write_keys(tmp / "keys.yaml", KEYS)
    app = create_app(Settings(db_path=tmp / "jobs.sqlite3", workers=0, score_workers=1,
                              api_keys_file=tmp / "keys.yaml"))
    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        yield c, secrets


def _h(secrets, key_id: str) -> dict[str, str]:
    return {"X-API-Key": secrets[key_id]}


def _problem(r, status: int) -> dict:
    assert r.status_code == status, (r.status_code, r.text[:400])
    assert r.headers["content-type"].startswith("application/problem+json")
    return r.json()


def test_no_key_or_an_unknown_key_is_401(keyed):
    c, _ = keyed
    body = _problem(c.post("/v1/score", json={"route": LOOP}), 401)
    assert "API key" in body["detail"] and c.post("/v1/score", json={"route": LOOP}).headers["www-authenticate"]
    _problem(c.post("/v1/score", json={"route": LOOP}, headers={"X-API-Key": "exk_guess"}), 401)
    _problem(c.get("/v1/rigs"), 401)


def test_a_key_without_the_scope_is_403_and_with_it_served(keyed):
    c, s = keyed
    body = _problem(c.post("/v1/maneuvers", json=JOB, headers=_h(s, "scorer")), 403)
    assert "lacks the scope 'plan'" in body["detail"]
    _problem(c.post("/v1/score", json={"route": LOOP}, headers=_h(s, "planner")), 403)
    r = c.post("/v1/score", json={"route": LOOP}, headers=_h(s, "scorer"))
    assert r.status_code == 200 and r.json()["score"] >= 0, r.text[:300]
    # the same key as a bearer token
    r = c.post("/v1/score", json={"route": LOOP}, headers={"Authorization": f"Bearer {s['scorer']}"})
    assert r.status_code == 200
    assert c.get("/v1/rigs", headers=_h(s, "planner")).status_code == 200  # any key lists rigs


def test_another_keys_job_is_404_and_admin_sees_it(keyed):
    c, s = keyed
    r = c.post("/v1/maneuvers", json=JOB, headers=_h(s, "other"))
    assert r.status_code == 202, r.text
    loc = r.headers["location"]
    assert c.get(loc, headers=_h(s, "other")).status_code == 200
    _problem(c.get(loc, headers=_h(s, "planner")), 404)
    _problem(c.delete(loc, headers=_h(s, "planner")), 404)
    _problem(c.get(loc + "/maneuver", headers=_h(s, "planner")), 404)
    assert c.get(loc, headers=_h(s, "root")).json()["status"] == "queued"
    assert c.delete(loc, headers=_h(s, "root")).json()["status"] == "cancelled"
    job = SqliteStore(Path(c.app.state.ctx.settings.db_path)).get(r.json()["id"])
    assert (job["key_id"], job["owner"]) == ("other", "other")


def test_job_quota_is_429_with_retry_after(keyed):
    c, s = keyed
    for _ in range(3):  # planner's quota: 3 queued or running
        assert c.post("/v1/maneuvers", json=JOB, headers=_h(s, "planner")).status_code == 202
    r = c.post("/v1/maneuvers", json=JOB, headers=_h(s, "planner"))
    body = _problem(r, 429)
    assert "quota" in body["detail"] and int(r.headers["retry-after"]) >= 1
    assert c.post("/v1/maneuvers", json=JOB, headers=_h(s, "other")).status_code == 202  # others unaffected


def test_request_rate_is_429_with_retry_after(keyed):
    c, s = keyed
    answers = [c.get("/v1/rigs", headers=_h(s, "slow")) for _ in range(3)]  # burst 2, then 0.5/s
    assert [a.status_code for a in answers[:2]] == [200, 200]
    body = _problem(answers[2], 429)
    assert "0.5 requests per second" in body["detail"] and 1 <= int(answers[2].headers["retry-after"]) <= 2
    assert c.get("/v1/rigs", headers=_h(s, "scorer")).status_code == 200  # a key's rate is its own


def test_live_sessions_are_per_key_and_need_a_key(keyed):
    c, s = keyed
    with c.websocket_connect("ws://localhost/v1/live") as ws:  # no key: refused in a problem frame
        frame = ws.receive_json()
        assert frame["type"] == "error" and frame["problem"]["status"] == 401
    with c.websocket_connect("ws://localhost/v1/live", headers=_h(s, "slow")) as first:
        first.send_json({"type": "start", "rig": "robotaxi"})
        assert first.receive_json()["type"] == "started"
        with c.websocket_connect("ws://localhost/v1/live", headers=_h(s, "slow")) as second:  # quota: 1 session
            frame = second.receive_json()
            assert frame["problem"]["status"] == 429 and "quota" in frame["problem"]["detail"]
    # a browser's ticket (its WebSocket cannot send a header), offered as a subprotocol: it
    # opens one session, once
    ticket = c.post("/v1/live/tickets", headers=_h(s, "scorer")).json()["ticket"]
    offer = ["excite-live", f"excite-ticket.{ticket}"]
    with c.websocket_connect("ws://localhost/v1/live", subprotocols=offer) as ws:
        assert ws.accepted_subprotocol == "excite-live"
        ws.send_json({"type": "start", "rig": "robotaxi"})
        assert ws.receive_json()["type"] == "started"
    with c.websocket_connect("ws://localhost/v1/live", subprotocols=offer) as ws:  # used already
        assert ws.receive_json()["problem"]["status"] == 401
    with c.websocket_connect("ws://localhost/v1/live", subprotocols=["excite-live", "excite-ticket.scorer.1.x.forged"]) as ws:
        assert ws.receive_json()["problem"]["status"] == 401


def test_tickets_are_random_secret_signed_short_lived_and_not_in_any_url(keyed, tmp_path):
    """The ticket secret is random and kept in the job store (shared by replicas), not derived
    from the keys file; a validly signed ticket that would outlive the TTL is refused; the
    OpenAPI document offers the ticket as no HTTP route's credential."""
    from api import auth

    c, s = keyed
    secret = c.app.state.ticket_secret
    keys_file = Path(c.app.state.ctx.settings.api_keys_file).read_bytes()
    assert len(secret) == 32 and secret not in keys_file
    import hashlib

    assert secret != hashlib.sha256(b"excite-live-ticket\0" + keys_file).digest()
    assert auth.ticket_claims(secret, auth.ticket(secret, "root")) is not None
    ten_years = auth.ticket(secret, "root", ttl_s=10 * 365 * 86400)
    assert auth.ticket_claims(secret, ten_years) is None
    with c.websocket_connect("ws://localhost/v1/live", subprotocols=["excite-live", f"excite-ticket.{ten_years}"]) as ws:
        assert ws.receive_json()["problem"]["status"] == 401
    doc = c.get("/openapi.json", headers=_h(s, "scorer")).json()
    assert "LiveTicket" not in doc["components"]["securitySchemes"]
    assert all("LiveTicket" not in str(op.get("security")) for item in doc["paths"].values() for op in item.values())
    # another replica on the same store signs with the same secret
    app2 = create_app(Settings(db_path=c.app.state.ctx.settings.db_path, workers=0, score_workers=1,
                               api_keys_file=c.app.state.ctx.settings.api_keys_file))
    assert app2.state.ticket_secret == secret


def test_metrics_and_docs_follow_their_settings(keyed, tmp_path):
    c, s = keyed
    _problem(c.get("/metrics", headers=_h(s, "scorer")), 403)
    assert "excite_store_up 1.0" in c.get("/metrics", headers=_h(s, "root")).text
    _problem(c.get("/openapi.json"), 401)
    doc = c.get("/openapi.json", headers=_h(s, "scorer")).json()
    assert {"APIKey", "Bearer"} <= set(doc["components"]["securitySchemes"])
    assert c.get("/readyz").status_code == 200 and c.get("/readyz").json()["detail"] == {}
    assert c.get("/healthz").status_code == 200
    secrets = write_keys(tmp_path / "keys.yaml", {"a": {"scopes": ["admin"]}})
    app = create_app(Settings(db_path=tmp_path / "j.sqlite3", workers=0, score_workers=1,
                              api_keys_file=tmp_path / "keys.yaml", docs="off", metrics="public"))
    with TestClient(app, base_url="http://localhost") as c2:
        assert c2.get("/openapi.json", headers={"X-API-Key": secrets["a"]}).status_code == 404
        assert c2.get("/docs", headers={"X-API-Key": secrets["a"]}).status_code == 404
        assert c2.get("/metrics").status_code == 200


def test_a_non_loopback_server_without_keys_refuses_to_start(tmp_path, monkeypatch, capsys):
    from api.auth import check_exposure, is_loopback
    from excite.cli.app import main

    monkeypatch.setenv("EXCITE_DB_PATH", str(tmp_path / "j.sqlite3"))
    monkeypatch.delenv("EXCITE_OPEN", raising=False)
    monkeypatch.delenv("EXCITE_API_KEYS_FILE", raising=False)
    for host in ("0.0.0.0", "::"):
        capsys.readouterr()
        assert main(["serve", "--host", host, "--port", "0"]) == 1
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("excite: error: refusing to serve"), lines
        assert "EXCITE_API_KEYS_FILE" in lines[0] and "EXCITE_OPEN" in lines[0]
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.0.2.1")
    check_exposure("0.0.0.0", has_keys=False, open_access=True)  # told it is open: served
    check_exposure("0.0.0.0", has_keys=True, open_access=False)
    check_exposure("127.0.0.1", has_keys=False, open_access=False)


def test_a_bad_keys_file_is_a_one_line_error(tmp_path, monkeypatch, capsys):
    from excite.cli.app import main

    keys = tmp_path / "keys.yaml"
    keys.write_text("keys:\n  - id: x\n    owner: me\n    scopes: [fly]\n    sha256: '" + "0" * 64 + "'\n")
    monkeypatch.setenv("EXCITE_DB_PATH", str(tmp_path / "j.sqlite3"))
    monkeypatch.setenv("EXCITE_API_KEYS_FILE", str(keys))
    assert main(["serve", "--port", "0"]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "unknown scope 'fly'" in lines[0], lines


def test_an_empty_keys_file_setting_is_no_keys_file(tmp_path, monkeypatch):
    """EXCITE_API_KEYS_FILE set to nothing (as a compose file's ${VAR:-} leaves it) is unset: an
    open server, still refused off loopback unless EXCITE_OPEN; it was read as the path "."."""
    monkeypatch.setenv("EXCITE_API_KEYS_FILE", "")
    assert Settings(db_path=tmp_path / "j.sqlite3").api_keys_file is None
    monkeypatch.setenv("EXCITE_API_KEYS_FILE", str(tmp_path))
    with pytest.raises(ValueError, match="is not a file"):
        Settings(db_path=tmp_path / "j.sqlite3")


def test_keys_tool_makes_a_key_whose_hash_is_its_entry(capsys):
    from api.auth import hash_key
    from api.keys import main

    assert main(["new", "--id", "ci", "--owner", "team", "--scopes", "score,plan"]) == 0
    out = capsys.readouterr()
    key = out.out.strip()
    entry = json.loads(out.err.split("- ", 1)[1])
    assert key.startswith("exk_") and entry["sha256"] == hash_key(key) and entry["scopes"] == ["score", "plan"]


# --------------------------------------------------------------------------------------------
# Fairness


def test_the_queue_serves_the_key_with_fewest_running_first(tmp_path):
    """One key's 300 queued jobs delay another key's job by at most one job slot: the claim
    order, deterministically, with one worker."""
    store = SqliteStore(tmp_path / "j.sqlite3")
    flood = [store.create("maneuver", {"n": i}, key_id="flood") for i in range(300)]
    first = store.claim("r", 30)
    assert first == (flood[0], 1)
    late = store.create("maneuver", {"n": -1}, key_id="late")
    store.finish(*first, "succeeded", result={})
    assert store.claim("r", 30)[0] == late  # next slot: the other key, not flood's 2nd job
    # with two slots busy by flood, a third key still goes first at the next free slot
    second = store.claim("r", 30)
    assert second[0] == flood[1]
    third = store.create("maneuver", {}, key_id="third")
    store.finish(*second, "succeeded", result={})
    assert store.claim("r", 30)[0] == third


@pytest.mark.slow
def test_a_flood_of_jobs_does_not_starve_another_key_over_http(tmp_path):
    """300 jobs from one key, then one from another, on a live server with one job worker: the
    other key's job starts at the first free slot (after at most one of the flood's)."""
    secrets = write_keys(tmp_path / "keys.yaml", {"flood": {"scopes": ["plan"], "quota": {"jobs": 300,
                                                                                       "rate_per_s": 1000, "burst": 1000}},
                                                  "late": {"scopes": ["plan"]}})
    srv = LiveServer(tmp_path, workers=1, api_keys_file=tmp_path / "keys.yaml", job_function="servers:quick_job",
                     test_job_result=job_result_file(tmp_path / "result.json")).start()
    try:
        with srv.client(headers={"X-API-Key": secrets["flood"]}) as c:
            ids = []
            for i in range(300):
                r = c.post("/v1/maneuvers", json={**JOB, "time_budget_s": 0.5, "name": f"f{i}"})
                assert r.status_code == 202, r.text[:300]
                ids.append(r.json()["id"])
        with srv.client(headers={"X-API-Key": secrets["late"]}) as c:
            r = c.post("/v1/maneuvers", json={**JOB, "time_budget_s": 0.5, "name": "late"})
            assert r.status_code == 202
            late = r.json()["id"]
            t0 = time.monotonic()
            while c.get(f"/v1/jobs/{late}").json()["status"] != "succeeded":
                assert time.monotonic() - t0 < 120, "the late key's job did not run"
                time.sleep(0.2)
        store = SqliteStore(tmp_path / "jobs.sqlite3")
        started = store.get(late)["started_at"]
        before = [i for i in ids if (store.get(i)["started_at"] or 1e18) < started]
        running_when_queued = [i for i in ids if (store.get(i)["started_at"] or 1e18) <= store.get(late)["created_at"]]
        assert len(before) <= len(running_when_queued) + 1, (len(before), len(running_when_queued))
    finally:
        srv.stop()


# --------------------------------------------------------------------------------------------
# Browser safety


@pytest.fixture(scope="module")
def open_client(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("open")
    app = create_app(Settings(db_path=tmp / "jobs.sqlite3", workers=0, score_workers=1))
    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        yield c


def test_a_cross_site_multipart_post_is_refused(open_client, data_dir):
    c = open_client
    bag = (data_dir / "nav2_turtlebot.mcap").read_bytes()
    files = {"bag": ("nav2_turtlebot.mcap", bag, "application/octet-stream")}
    # what a foreign page's form would send: its origin, or (old browsers) no origin and no custom header
    body = _problem(c.post("/v1/score/bag", files=files, data={"topic": "/odom"},
                           headers={"Origin": "https://evil.example"}), 403)
    assert "evil.example" in body["detail"]
    _problem(c.post("/v1/score/bag", files=files, data={"topic": "/odom"}), 403)
    _problem(c.post("/v1/score/bag", files=files, data={"topic": "/odom"}, headers={"Sec-Fetch-Site": "cross-site"}), 403)
    _problem(c.post("/v1/score", content=b'{"route": {}}', headers={"Content-Type": "text/plain"}), 403)
    # this server's own page, or a client that says it is one (a header a form cannot send)
    r = c.post("/v1/score/bag", files=files, data={"topic": "/odom"}, headers={"Origin": "http://localhost"})
    assert r.status_code == 200, r.text[:300]
    assert c.post("/v1/score/bag", files=files, data={"topic": "/odom"},
                  headers={"X-Excite-Client": "curl"}).status_code == 200
    # JSON needs a preflight a foreign page does not pass: allowed without the header, not from a foreign origin
    assert c.post("/v1/score", json={"route": LOOP}).status_code == 200
    _problem(c.post("/v1/score", json={"route": LOOP}, headers={"Origin": "https://evil.example"}), 403)
    _problem(c.delete("/v1/jobs/abc", headers={"Origin": "https://evil.example"}), 403)


def test_a_foreign_origin_websocket_is_refused(open_client, tmp_path):
    c = open_client
    with pytest.raises(WebSocketDisconnect) as exc:
        with c.websocket_connect("ws://localhost/v1/live", headers={"Origin": "https://evil.example"}) as ws:
            ws.receive_json()
    assert exc.value.code == 1008
    with c.websocket_connect("ws://localhost/v1/live", headers={"Origin": "http://localhost"}) as ws:
        ws.send_json({"type": "start"})
        assert ws.receive_json()["type"] == "started"
    app = create_app(Settings(db_path=tmp_path / "j.sqlite3", workers=0, score_workers=1,
                              allowed_origins="https://planner.example:8443"))
    with TestClient(app, base_url="http://localhost") as c2:
        with c2.websocket_connect("ws://localhost/v1/live", headers={"Origin": "https://planner.example:8443"}) as ws:
            ws.send_json({"type": "start"})
            assert ws.receive_json()["type"] == "started"


def test_security_headers_and_head(open_client):
    c = open_client
    for path in ("/", "/static/app.js", "/v1/rigs", "/healthz", "/v1/nothing"):
        r = c.get(path)
        assert "frame-ancestors 'none'" in r.headers["content-security-policy"], path
        assert r.headers["x-frame-options"] == "DENY" and r.headers["x-content-type-options"] == "nosniff"
    assert "script-src 'self'" in c.get("/").headers["content-security-policy"]
    for path in ("/", "/v1/rigs", "/healthz", "/openapi.json", "/static/style.css"):
        get, head = c.get(path), c.head(path)
        assert head.status_code == get.status_code == 200, path
        assert head.content == b"" and head.headers["content-type"] == get.headers["content-type"]
        assert head.headers["content-length"] == get.headers["content-length"], path
    assert c.head("/v1/jobs/0123").status_code == 404


def test_an_open_servers_schema_declares_no_credentials(open_client):
    doc = open_client.get("/openapi.json").json()
    assert "securitySchemes" not in doc.get("components", {})
    assert all("security" not in op for item in doc["paths"].values() for op in item.values())
