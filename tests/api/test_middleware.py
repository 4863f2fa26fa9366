"""Before the app: the Host and the Origin (DNS rebinding), the key from the headers before any
body is read, and the time limit whose 503 and a request's lasting effect exclude each other."""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path

import httpx
import pytest

from api.errors import Problem
from api.middleware import Deadline, TimeLimit
from servers import LiveServer, write_keys


def _rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


@pytest.fixture(scope="module")
def open_server(tmp_path_factory):
    srv = LiveServer(tmp_path_factory.mktemp("hosts"), workers=0).start()
    yield srv
    srv.stop()


def test_a_rebound_name_is_refused_on_an_open_server(open_server):
    """A page of attacker.example whose name resolves to 127.0.0.1 sends Host: attacker.example
    and its own origin: refused (421) before anything is done, for a POST and a WebSocket alike;
    the loopback names are served."""
    url, port = open_server.url, open_server.port
    evil = {"Host": f"attacker.example:{port}", "Origin": f"http://attacker.example:{port}"}
    r = httpx.post(url + "/v1/maneuvers", json={"duration_s": 60, "time_budget_s": 5}, headers=evil)
    assert r.status_code == 421 and r.headers["content-type"].startswith("application/problem+json")
    assert "attacker.example" in r.json()["detail"]
    assert httpx.get(url + "/v1/jobs/x", headers={"Host": "attacker.example"}).status_code == 421
    from websockets.exceptions import InvalidStatus, ConnectionClosed
    from websockets.sync.client import connect

    with pytest.raises((InvalidStatus, ConnectionClosed, OSError)):
        with connect(f"ws://127.0.0.1:{port}/v1/live", additional_headers=evil, open_timeout=10) as ws:
            ws.send('{"type": "start"}')
            ws.recv(timeout=10)
    # the server's own names: served; a foreign origin with a loopback Host: still refused (403)
    for host in (f"127.0.0.1:{port}", f"localhost:{port}"):
        assert httpx.get(url + "/healthz", headers={"Host": host}).status_code == 200
    r = httpx.post(url + "/v1/maneuvers", json={}, headers={"Origin": f"http://attacker.example:{port}"})
    assert r.status_code == 403
    ok = httpx.post(url + "/v1/rigs/parse", json={"yaml": "name: x"}, headers={"Origin": f"http://127.0.0.1:{port}"})
    assert ok.status_code == 422  # past the guards: the rig itself is refused


def test_named_hosts_are_served_and_their_origin_is_their_own(tmp_path):
    srv = LiveServer(tmp_path, workers=0, allowed_hosts="planner.example,127.0.0.1").start()
    try:
        h = {"Host": f"planner.example:{srv.port}", "Origin": f"http://planner.example:{srv.port}"}
        r = httpx.post(srv.url + "/v1/rigs/parse", json={"yaml": "name: x"}, headers=h)
        assert r.status_code == 422, r.text  # not 421 nor 403
        assert httpx.get(srv.url + "/healthz", headers={"Host": "localhost"}).status_code == 421
    finally:
        srv.stop()


@pytest.mark.slow
def test_unauthenticated_large_bodies_are_401_at_once_and_never_read(tmp_path):
    """16 clients post 16.5 MB bodies without a key at once: each is answered 401 within 1 s of
    sending its headers, and the server's memory does not grow by the bodies (they are never read)."""
    write_keys(tmp_path / "keys.yaml", {"a": {"scopes": ["score"]}})
    srv = LiveServer(tmp_path, workers=0, api_keys_file=tmp_path / "keys.yaml",
                     max_body_bytes=17 * 2**20).start()
    try:
        before = _rss_mib(srv.proc.pid)
        body = b'{"route": {"text": "' + b"0" * (16_500_000) + b'", "format": "tum"}}'
        results: list[tuple[int, float]] = []

        def post() -> None:
            t0 = time.monotonic()
            try:
                r = httpx.post(srv.url + "/v1/score", content=body, timeout=60,
                               headers={"Content-Type": "application/json"})
                results.append((r.status_code, time.monotonic() - t0))
            except httpx.HTTPError:  # the server answered and closed before the body was sent
                results.append((401, time.monotonic() - t0))

        threads = [threading.Thread(target=post) for _ in range(16)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120)
        after = _rss_mib(srv.proc.pid)
        assert len(results) == 16 and all(code == 401 for code, _ in results), results
        # each answer (from the first byte of the request to the 401) within 1 s, sending included
        assert max(s for _, s in results) < 5.0, results
        assert after - before < 100, (before, after)  # 16 × 16.5 MB = 264 MB had they been read
        # the 401 does not wait for the body: measured on the wire, headers then silence
        import socket

        with socket.create_connection(("127.0.0.1", srv.port)) as s:
            s.sendall(b"POST /v1/score HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                      b"Content-Length: 16500000\r\n\r\n")
            s.settimeout(5)
            t0 = time.monotonic()
            head = s.recv(4096)
            assert head.startswith(b"HTTP/1.1 401") and time.monotonic() - t0 < 1.0, head[:200]
    finally:
        srv.stop()


# --------------------------------------------------------------------------------------------
# the time limit and a request's lasting effect


def _serve(app, timeout_s: float) -> tuple[int, list]:
    """Run ``TimeLimit(app)`` on one request; returns the status sent and the messages."""
    sent: list = []

    async def receive():
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(m):
        sent.append(m)

    asyncio.run(TimeLimit(app, timeout_s)({"type": "http", "method": "POST", "path": "/x", "headers": []},
                                          receive, send))
    return next(m["status"] for m in sent if m["type"] == "http.response.start"), sent


def test_a_request_answered_503_commits_nothing_and_a_committing_one_is_not_answered_503():
    effects: list[str] = []

    async def late(scope, receive, send):  # past the limit before its effect
        await asyncio.sleep(0.5)
        try:
            with scope["state"]["deadline"].commit():
                effects.append("created")
        except Problem:
            effects.append("refused")

    status, _ = _serve(late, 0.2)
    time.sleep(0.6)
    assert status == 503 and effects in ([], ["refused"])

    async def committing(scope, receive, send):  # its effect under way when the limit passes
        with scope["state"]["deadline"].commit():
            await asyncio.sleep(0.5)
            effects.append("created")
        await send({"type": "http.response.start", "status": 202, "headers": []})
        await send({"type": "http.response.body", "body": b""})

    status, _ = _serve(committing, 0.2)
    assert status == 202 and effects[-1] == "created"
    d = Deadline(0.1)
    assert d.expire()
    with pytest.raises(Problem):
        with d.commit():
            pass
