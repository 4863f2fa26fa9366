"""Problem bodies (application/problem+json) are capped in size, and a connection survives a 500."""

from __future__ import annotations

import json
import socket
import threading
import time
from api import Settings, create_app


def test_problem_bodies_are_capped(tmp_path):
    from fastapi.testclient import TestClient

    from api.errors import MAX_DETAIL_CHARS, MAX_ERRORS, Problem

    huge = Problem(422, "x" * 100_000, errors=[{"field": "f" * 1000, "message": "m" * 10_000}] * 5000)
    body = huge.body("/v1/x")
    assert len(body["detail"]) <= MAX_DETAIL_CHARS and "characters more" in body["detail"]
    assert len(body["errors"]) == MAX_ERRORS + 1 and "4980 more" in body["errors"][-1]["message"]
    assert len(json.dumps(body)) < 20_000

    # and so is the response that carries it
    app = create_app(Settings(db_path=tmp_path / "j.sqlite3", workers=0, score_workers=1))

    @app.get("/huge")
    def raise_huge():
        raise huge

    with TestClient(app, base_url="http://localhost") as c:
        r = c.get("/huge")
    assert r.status_code == 422 and r.headers["content-type"] == "application/problem+json"
    assert len(r.content) < 20_000 and r.json()["errors"][-1]["message"] == "… and 4980 more errors"


def test_the_connection_survives_a_500(tmp_path):
    import uvicorn

    app = create_app(Settings(db_path=tmp_path / "j.sqlite3", workers=0, score_workers=1))

    @app.get("/boom")
    def boom():
        raise RuntimeError("internals")

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="critical"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 60
        while not server.started:
            assert time.monotonic() < deadline
            time.sleep(0.1)
        with socket.create_connection(("127.0.0.1", port), timeout=30) as conn:
            f = conn.makefile("rb")
            for path, status in (("/boom", b"500"), ("/healthz", b"200")):
                conn.sendall(f"GET {path} HTTP/1.1\r\nHost: localhost\r\n\r\n".encode())
                line = f.readline()
                assert status in line, (path, line)
                length = 0
                while (h := f.readline()) not in (b"\r\n", b""):
                    if h.lower().startswith(b"content-length"):
                        length = int(h.split(b":")[1])
                body = f.read(length)
                assert b"internals" not in body
    finally:
        server.should_exit = True
        thread.join(15)
