"""The /v1/live WebSocket: malformed frames are refused with a problem, sessions are bounded and run
in a process of their own, and a session over its memory limit is refused."""

from __future__ import annotations

import os
import time
from pathlib import Path
import numpy as np
import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect
from api import Settings, create_app
from excite.core import processes


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("surfaces")
    app = create_app(Settings(db_path=tmp / "jobs.sqlite3", workers=0, score_workers=1, max_lot_vertices=500,
                              max_route_duration_s=60, max_live_pose_rate_hz=400))
    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        yield c


def _poses(t):
    return [[float(x), 5.0 * float(x), 0.0, 0.0, 0.0, 0.0, 0.0, 1.0] for x in t]


def _frame(ws):
    msg = ws.receive_json()
    assert msg["type"] == "error", msg
    return msg["problem"]


def test_malformed_websocket_frames_are_refused_with_a_problem(client):
    with client.websocket_connect("ws://localhost/v1/live") as ws:
        ws.send_bytes(b"\x00\x01binary")
        p = _frame(ws)
        assert p["status"] == 422 and "binary frames" in p["detail"]
        with pytest.raises(WebSocketDisconnect) as exc:
            ws.receive_json()
        assert exc.value.code == 1003
    with client.websocket_connect("ws://localhost/v1/live") as ws:
        ws.send_text('{"type": "start", "x": ' + "[" * 5000 + "]" * 5000 + "}")
        assert "nested more than" in _frame(ws)["detail"]
    with client.websocket_connect("ws://localhost/v1/live") as ws:
        ws.send_json({"type": "start"})
        assert ws.receive_json()["type"] == "started"
        ws.send_text('{"type": "poses", "poses": [[0, 1' + "0" * 400 + ', 0, 0, 0, 0, 0, 1]]}')
        p = _frame(ws)
        assert p["errors"][0]["field"] == "poses[0]", p


def test_live_sessions_are_bounded_and_run_in_a_process_of_their_own(client):

    with client.websocket_connect("ws://localhost/v1/live") as ws:  # the route-duration bound (60 s here)
        ws.send_json({"type": "start"})
        ws.receive_json()
        ws.send_json({"type": "poses", "poses": _poses(np.arange(0, 30, 0.1))})
        ws.send_json({"type": "poses", "poses": _poses(np.arange(30, 61, 0.1))})
        p = None
        while p is None:
            msg = ws.receive_json()
            p = msg["problem"] if msg["type"] == "error" else None
        assert "over the limit of 60 s" in p["detail"]
    with client.websocket_connect("ws://localhost/v1/live") as ws:  # the pose rate (400 Hz here)
        ws.send_json({"type": "start"})
        ws.receive_json()
        ws.send_json({"type": "poses", "poses": _poses(np.arange(0, 2, 0.001))})
        assert "denser than the limit of 400 Hz" in _frame(ws)["detail"]
    with client.websocket_connect("ws://localhost/v1/live") as ws:
        ws.send_json({"type": "start"})
        ws.receive_json()
        (proc,) = processes.running("excite-live")
        pid = proc.proc.pid
        assert pid != os.getpid() and proc.proc.is_alive()
        ws.send_json({"type": "poses", "poses": _poses(np.arange(0, 20, 0.1))})
        ws.send_json({"type": "end"})
        while ws.receive_json()["type"] != "final":
            pass
    deadline = time.monotonic() + 10
    while processes.running("excite-live") and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not processes.running("excite-live") and not os.path.exists(f"/proc/{pid}/status") or \
        "zombie" in Path(f"/proc/{pid}/status").read_text()


def test_a_live_session_over_its_memory_limit_is_refused(tmp_path):
    app = create_app(Settings(db_path=tmp_path / "j.sqlite3", workers=0, score_workers=1, live_memory_mb=64))
    with TestClient(app, base_url="http://localhost") as c, c.websocket_connect("ws://localhost/v1/live") as ws:
        ws.send_json({"type": "start"})
        ws.receive_json()
        # minutes of poses, message after message: the session's samples and blocks grow past
        # what it may map
        for k in range(10):
            ws.send_json({"type": "poses", "poses": _poses(np.arange(400 * k, 400 * (k + 1), 0.1))})
            msg = ws.receive_json()
            if msg["type"] == "error":
                break
        p = msg["problem"]
        assert p["status"] in (413, 503) and ("memory" in p["detail"] or "ended" in p["detail"]), p
