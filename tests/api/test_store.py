"""Hardening, round three (issue 31): the newer surfaces. A job's whole process tree ends with it
(cancel, kill -9 of the server, shutdown, its hard time limit); compressed bags are bounded before
they allocate; lots that cannot be planned in are refused at submission; /v1/live runs where a
memory limit applies and refuses malformed frames; error bodies are capped; store faults are
named, not 500s; finished jobs are kept within a retention policy."""

from __future__ import annotations

import bz2
import errno
import json
import os
import socket
import sqlite3
import struct
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from api import Settings, create_app
from excite.core import processes
from api.store import open_store as SqliteStore
from test_api_support import LiveServer, processes_with, wait_job

LOOP = {"waypoints": [[0, 0], [30, 0], [30, 20], [0, 20], [0, 1]]}
TREE = {"job_function": "test_api_support:tree_job", "workers": 1, "cancel_grace_s": 1}


def _gone(text: str, timeout_s: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while processes_with(text):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.1)
    return True


def _running_tree(c, name: str) -> str:
    r = c.post("/v1/maneuvers", json={"duration_s": 60, "time_budget_s": 300, "name": name})
    assert r.status_code == 202, r.text
    wait_job(c, r.headers["location"], lambda j: j["status"] == "running")
    deadline = time.monotonic() + 30
    while len(processes_with(f"excite-tree-job-{name}")) < 2:
        assert time.monotonic() < deadline, "the job's children did not start"
        time.sleep(0.1)
    return r.headers["location"]


# --------------------------------------------------------------------------------------------
# Process trees


def test_no_process_outlives_its_job_after_cancel_kill_9_and_shutdown(tmp_path):
    """The stand-in job starts a child and a grandchild in a session of its own, and ignores
    cancellation. Cancel past the grace, kill -9 of the server and a normal shutdown each leave
    no process of the job behind."""
    srv = LiveServer(tmp_path, **TREE).start()
    try:
        with srv.client() as c:
            loc = _running_tree(c, "cancelled")
            job_id = loc.rsplit("/", 1)[1]
            assert c.delete(loc).status_code == 202
            assert wait_job(c, loc, timeout_s=60)["status"] == "cancelled"
        assert _gone("excite-tree-job-cancelled"), "a process of the cancelled job is still running"
        assert _gone(job_id), "the cancelled job's supervisor is still running"
        with srv.client() as c:
            loc = _running_tree(c, "killed")
    finally:
        srv.kill9()
    assert _gone("excite-tree-job-killed"), "a process of the job outlived the server's kill -9"
    srv = LiveServer(tmp_path, **TREE).start()  # re-runs the killed job: its tree starts again
    try:
        deadline = time.monotonic() + 30
        while len(processes_with("excite-tree-job-killed")) < 2:
            assert time.monotonic() < deadline, "the re-run did not start"
            time.sleep(0.1)
    finally:
        srv.stop()
    assert _gone("excite-tree-job-killed"), "a process of the job outlived the server's shutdown"
    store = SqliteStore(tmp_path / "jobs.sqlite3")
    job = next(j for j in (store.get(i) for i in _ids(tmp_path)) if j["attempt"] == 2)
    assert [r["outcome"] for r in store.runs(job["id"])] == ["lost", "released"]


def _ids(tmp_path: Path) -> list[str]:
    with sqlite3.connect(tmp_path / "jobs.sqlite3") as db:
        return [r[0] for r in db.execute("SELECT id FROM jobs")]


def test_a_job_is_stopped_at_its_hard_time_limit(tmp_path):
    """A job that ignores its budget (0.5 s) is failed at budget + reserve (2 s), its tree with it."""
    srv = LiveServer(tmp_path, **TREE, job_time_reserve_s=2).start()
    try:
        with srv.client() as c:
            r = c.post("/v1/maneuvers", json={"duration_s": 60, "time_budget_s": 0.5, "name": "overdue"})
            job = wait_job(c, r.headers["location"], timeout_s=90)
        assert job["status"] == "failed", job
        assert job["error"]["type"].endswith("/time-limit") and "2.5 s" in job["error"]["detail"]
        assert _gone("excite-tree-job-overdue")
    finally:
        srv.stop()


# --------------------------------------------------------------------------------------------
# Compressed bags


def _ros1_records(data: bytes):
    """(offset, header fields, data offset, data length) of each top-level record of a ROS 1 bag."""
    o = 13
    while o < len(data):
        (hlen,) = struct.unpack_from("<I", data, o)
        fields, p = {}, o + 4
        while p < o + 4 + hlen:
            (flen,) = struct.unpack_from("<I", data, p)
            k, v = data[p + 4:p + 4 + flen].split(b"=", 1)
            fields[k.decode()] = v
            p += 4 + flen
        (dlen,) = struct.unpack_from("<I", data, p)
        yield o, fields, p + 4, dlen
        o = p + 4 + dlen


def _bz2_bomb_bag(tmp_path: Path, expands_to: int = 300 << 20) -> Path:
    """A ROS 1 bag whose bz2 chunk decompresses to ``expands_to`` bytes of zeros (its
    compressed data padded to the chunk's length, so every offset stays right)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    M = ts.types
    path = tmp_path / "bomb.bag"
    rng = np.random.default_rng(0)
    w = Writer(path)
    w.set_compression(Writer.CompressionFormat.BZ2)
    with w:
        conn = w.add_connection("/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        for i in range(400):
            x = rng.normal(size=3)
            msg = M["geometry_msgs/msg/PoseStamped"](
                header=M["std_msgs/msg/Header"](seq=i, stamp=M["builtin_interfaces/msg/Time"](sec=i, nanosec=0),
                                                frame_id="map"),
                pose=M["geometry_msgs/msg/Pose"](position=M["geometry_msgs/msg/Point"](x=x[0], y=x[1], z=x[2]),
                                                 orientation=M["geometry_msgs/msg/Quaternion"](x=0, y=0, z=0, w=1)))
            w.write(conn, i * 10**9, ts.serialize_ros1(msg, "geometry_msgs/msg/PoseStamped"))
    data = bytearray(path.read_bytes())
    comp = bz2.BZ2Compressor(9)
    bomb = b"".join(comp.compress(bytes(16 << 20)) for _ in range(expands_to >> 24)) + comp.flush()
    chunks = [(o, f, d, n) for o, f, d, n in _ros1_records(bytes(data)) if f.get("op") == b"\x05"]
    assert chunks and chunks[0][1]["compression"] == b"bz2"
    _, _, at, n = chunks[0]
    assert len(bomb) <= n, (len(bomb), n)
    data[at:at + n] = bomb + bytes(n - len(bomb))
    path.write_bytes(bytes(data))
    return path


def _mcap(tmp_path: Path, name: str, kind: str, records: bytes, size: int) -> Path:
    """An MCAP file without a summary: header, one chunk (``records`` compressed by the caller
    as ``kind``, declaring ``size``), data end and a footer that points nowhere."""
    def rec(op: int, body: bytes) -> bytes:
        return struct.pack("<BQ", op, len(body)) + body

    def string(s: str) -> bytes:
        return struct.pack("<I", len(s)) + s.encode()

    chunk = struct.pack("<QQQI", 0, 10**9, size, 0) + string(kind) + struct.pack("<Q", len(records)) + records
    body = (b"\x89MCAP0\r\n" + rec(0x01, string("ros2") + string("test")) + rec(0x06, chunk)
            + rec(0x0F, struct.pack("<I", 0)) + rec(0x02, struct.pack("<QQI", 0, 0, 0)) + b"\x89MCAP0\r\n")
    path = tmp_path / name
    path.write_bytes(body)
    return path


def _zstd_zeros(n: int) -> bytes:
    try:
        from compression import zstd
    except ImportError:
        from backports import zstd
    c = zstd.ZstdCompressor()
    out = b"".join(c.compress(bytes(64 << 20)) for _ in range(n >> 26))
    return out + c.flush()


@pytest.fixture(scope="module")
def bag_server(tmp_path_factory):
    srv = LiveServer(tmp_path_factory.mktemp("bombs"), workers=0, score_workers=1,
                     request_timeout_s=60).start()
    yield srv
    srv.stop()


def _upload(srv, path: Path, topic: str = "/pose"):
    with srv.client(headers={"X-Excite-Client": "tests"}) as c:
        return c.post("/v1/score/bag", files={"bag": (path.name, path.read_bytes(), "application/octet-stream")},
                      data={"topic": topic})


def test_compressed_bag_bombs_are_refused_before_they_expand(bag_server, tmp_path):
    """A ROS 1 bag whose bz2 chunk expands to 300 MiB, an MCAP without a summary whose zstd chunk
    declares 900 MiB of zeros, and an LZ4 chunk that is not LZ4: each a 422 naming the bound or
    the damage (never a 500, nor a worker held), and the next request is served."""
    cases = [
        (_bz2_bomb_bag(tmp_path), "/pose", "expands past"),
        (_mcap(tmp_path, "zeros.mcap", "zstd", _zstd_zeros(192 << 20), 192 << 20), "/odom", "past the bounds"),
        (_mcap(tmp_path, "huge.mcap", "zstd", _zstd_zeros(896 << 20), 896 << 20), "/odom", "over the limit"),
        (_mcap(tmp_path, "bad.mcap", "lz4", b"this is not lz4 at all" * 10, 4096), "/odom", "cannot be decompressed"),
    ]
    for path, topic, words in cases:
        assert path.stat().st_size < 300_000
        r = _upload(bag_server, path, topic)
        assert r.status_code == 422, (path.name, r.status_code, r.text[:300])
        body = r.json()
        assert words in body["detail"] and body["errors"][0]["field"] == "bag", body
        assert "/tmp" not in body["detail"]
    with bag_server.client() as c:
        assert c.post("/v1/score", json={"route": LOOP}).status_code == 200


def test_every_decompression_is_bounded():
    from excite.io.bags import MAX_CHUNK_BYTES, Budget, decompress
    from excite.io.bags.mcap import RATIO_FLOOR, bounded_decompressor

    zeros = bz2.compress(bytes(RATIO_FLOOR + 1))
    with pytest.raises(ValueError, match="expands past"):
        bounded_decompressor("bz2", Budget(1 << 40))(zeros)
    assert len(bounded_decompressor("bz2", Budget(1 << 40))(bz2.compress(bytes(1000)))) == 1000
    budget = Budget(5000)  # a read's total
    expand = bounded_decompressor("bz2", budget)
    expand(bz2.compress(bytes(4000)))
    with pytest.raises(ValueError, match="5,000 bytes per read"):
        expand(bz2.compress(bytes(4000)))
    with pytest.raises(ValueError, match="cannot be decompressed"):
        decompress("lz4", b"garbage" * 20, 100)
    with pytest.raises(ValueError, match="over the limit"):
        decompress("zstd", b"", MAX_CHUNK_BYTES + 1)
    with pytest.raises(ValueError, match="unknown chunk compression"):
        decompress("brotli", b"x", 10)


def test_a_bag_upload_is_written_to_disk_once(bag_server, data_dir):
    data = (data_dir / "nav2_turtlebot.mcap").read_bytes()

    def written() -> int:
        return int(next(line.split()[1] for line in Path(f"/proc/{bag_server.proc.pid}/io").read_text().splitlines()
                        if line.startswith("wchar")))

    before = written()
    with bag_server.client(headers={"X-Excite-Client": "tests"}) as c:
        r = c.post("/v1/score/bag", files={"bag": ("nav2.mcap", data, "application/octet-stream")},
                   data={"topic": "/odom"})
    assert r.status_code == 200, r.text[:300]
    assert written() - before < 1.3 * len(data), (written() - before, len(data))


# --------------------------------------------------------------------------------------------
# TF chains and error bodies


def test_tf_chains_resolve_in_linear_time_and_their_errors_are_short(tmp_path):
    from excite.errors import BagError
    from excite.io.bags import Edge, chain_edges
    from excite.io.bags.tf import MAX_HOPS

    n = 50_000
    edges = {f"a{i}": Edge(f"a{i - 1}" if i else "root", f"a{i}") for i in range(n)}
    edges.update({f"b{i}": Edge(f"b{i - 1}" if i else "root", f"b{i}") for i in range(n)})
    hops = chain_edges(tmp_path, "/tf", "a10", "b20", edges)
    assert len(hops) == 32 and hops[0][0].child == "a10" and hops[-1][0].child == "b20"
    with pytest.raises(BagError, match=f"100,000 hops, over the limit of {MAX_HOPS}"):
        chain_edges(tmp_path, "/tf", f"a{n - 1}", f"b{n - 1}", edges)
    with pytest.raises(BagError) as exc:
        chain_edges(tmp_path, "/tf", "nowhere", "a1", edges)
    assert len(str(exc.value)) < 2000 and "and 99,961 more" in str(exc.value)


def test_problem_bodies_are_capped():
    from api.problems import MAX_DETAIL_CHARS, MAX_ERRORS, capped

    body = capped({"detail": "x" * 100_000, "errors": [{"field": "f" * 1000, "message": "m" * 10_000}] * 5000})
    assert len(body["detail"]) <= MAX_DETAIL_CHARS and "characters more" in body["detail"]
    assert len(body["errors"]) == MAX_ERRORS + 1 and "4980 more" in body["errors"][-1]["message"]
    assert len(json.dumps(body)) < 20_000


# --------------------------------------------------------------------------------------------
# Lots


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("surfaces")
    app = create_app(Settings(db_path=tmp / "jobs.sqlite3", workers=0, score_workers=1, max_lot_vertices=500,
                              max_route_duration_s=60, max_live_pose_rate_hz=400))
    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        yield c


def _lot(ring, holes=(), local=True, **props) -> dict:
    feature = {"type": "Feature", "properties": props,
               "geometry": {"type": "Polygon", "coordinates": [ring, *holes]}}
    return {"type": "FeatureCollection", "properties": {"crs": "local"} if local else {}, "features": [feature]}


def _square(x0, y0, side, n=4):
    if n == 4:
        return [[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side], [x0, y0]]
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = [[x0 + side * np.cos(a), y0 + side * np.sin(a)] for a in t]
    return ring + [ring[0]]


def test_impossible_or_malformed_lots_are_refused_at_submission(client):
    ok = _lot(_square(0, 0, 60))
    assert client.post("/v1/maneuvers", json={"lot": ok, "time_budget_s": 1, "duration_s": 30}).status_code == 202
    feature = ok["features"][0]
    cases = {
        "properties a list": {**ok, "features": [{**feature, "properties": [1, 2]}]},
        "properties a string": {**ok, "features": [{**feature, "properties": "lot"}]},
        "geometry a list": {**ok, "features": [{**feature, "geometry": [[0, 0]]}]},
        "a one-number coordinate": _lot([[0, 0], [60], [60, 60], [0, 60], [0, 0]]),
        "a huge integer": _lot([[0, 0], [10**400, 0], [60, 60], [0, 60], [0, 0]]),
        "near the pole": _lot([[10, 89.9], [10.01, 89.9], [10.01, 89.91], [10, 89.91], [10, 89.9]], local=False),
        "a hemisphere": _lot([[-90, 0], [90, 0], [90, 80], [-90, 80], [-90, 0]], local=False),
        "self-intersecting": _lot([[0, 0], [60, 60], [60, 0], [0, 60], [0, 0]]),
        "zero area": _lot([[0, 0], [30, 0], [60, 0], [30, 0], [0, 0]]),
        "sides of 1e7 m": _lot(_square(0, 0, 1e7)),
        "a repeated vertex": _lot([[0, 0], [60, 0], [60, 0], [60, 60], [0, 60], [0, 0]]),
        "a hole across the outline": _lot(_square(0, 0, 60), [_square(50, 10, 20)]),
        "a hole outside": _lot(_square(0, 0, 60), [_square(100, 100, 5)]),
        "too many vertices": _lot(_square(0, 0, 60, n=600)),
        "a 10k x 10k keep-out test": _lot(_square(0, 0, 600, n=10_000), [_square(0, 0, 100, n=10_000)]),
    }
    for what, lot in cases.items():
        t0 = time.monotonic()
        r = client.post("/v1/maneuvers", json={"lot": lot, "time_budget_s": 1, "duration_s": 30})
        assert r.status_code == 422, (what, r.status_code, r.text[:300])
        body = r.json()
        assert body["errors"][0]["field"] == "lot", (what, body)
        assert time.monotonic() - t0 < 30, what  # refused, not computed (a generous bound)
    detail = client.post("/v1/maneuvers", json={"lot": cases["self-intersecting"], "duration_s": 30}).json()["detail"]
    assert "crosses itself" in detail
    detail = client.post("/v1/maneuvers", json={"lot": cases["too many vertices"], "duration_s": 30}).json()["detail"]
    assert "more than 500 vertices" in detail


# --------------------------------------------------------------------------------------------
# /v1/live


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
    from api.routers import live

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
        ws.send_json({"type": "poses", "poses": _poses(np.arange(0, 20, 0.1))})
        p = _frame(ws)
        assert p["status"] in (413, 503) and ("memory" in p["detail"] or "ended" in p["detail"]), p


# --------------------------------------------------------------------------------------------
# The connection after a 500, store faults


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


def test_store_faults_are_named_and_metrics_never_fail(tmp_path, caplog, monkeypatch):
    import logging

    # `excite serve` (run by other tests) stops the service's logger from propagating
    monkeypatch.setattr(logging.getLogger("excite"), "propagate", True)
    db = tmp_path / "jobs.sqlite3"
    app = create_app(Settings(db_path=db, workers=1, score_workers=1))

    @app.get("/full")
    def full():
        raise OSError(errno.ENOSPC, "No space left on device")

    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        job = c.post("/v1/maneuvers", json={"time_budget_s": 1}).json()["id"]
        c.delete(f"/v1/jobs/{job}")
        assert c.get("/readyz").status_code == 200
        with caplog.at_level(logging.ERROR, logger="excite.api"):
            for f in tmp_path.glob("jobs.sqlite3*"):
                f.write_bytes(b"this is no longer a database" * 200)
            time.sleep(3)  # the dispatcher polls five times a second
            m = c.get("/metrics")
            assert m.status_code == 200 and "excite_store_up 0.0" in m.text
            r = c.get("/readyz")
            assert r.status_code == 503 and "job store" in r.json()["detail"]
            r = c.get(f"/v1/jobs/{job}")
            assert r.status_code == 503 and r.json()["type"].endswith("/store-unavailable")
            assert "Traceback" not in r.text
        faults = [rec for rec in caplog.records if rec.getMessage().startswith("job store fault: ")]
        assert len(faults) == 1, [rec.getMessage() for rec in faults]
        assert not any(rec.exc_info for rec in caplog.records if rec.name == "excite.api")
        r = c.get("/full")
        assert r.status_code == 503 and r.json()["type"].endswith("/disk-full")


def test_a_nearly_full_disk_is_not_ready_and_uploads_wait(tmp_path):
    app = create_app(Settings(db_path=tmp_path / "j.sqlite3", workers=0, score_workers=1, min_free_mb=1_000_000))
    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        r = c.get("/readyz")
        assert r.status_code == 503 and "EXCITE_MIN_FREE_MB" in r.json()["detail"]
        r = c.post("/v1/score/bag", files={"bag": ("a.mcap", b"x", "application/octet-stream")},
                   data={"topic": "/odom"}, headers={"X-Excite-Client": "t"})
        assert r.status_code == 503 and r.json()["type"].endswith("/disk-full")


def test_a_read_only_store_says_so(tmp_path, monkeypatch):
    from api.errors import StoreError

    store = SqliteStore(tmp_path / "j.sqlite3")

    def refuse(*a, **k):
        raise sqlite3.OperationalError("attempt to write a readonly database")

    monkeypatch.setattr(sqlite3, "connect", refuse)
    with pytest.raises(StoreError) as exc:
        store.create("maneuver", {})
    assert "read-only" in str(exc.value) and "move it away" not in str(exc.value)


# --------------------------------------------------------------------------------------------
# Retention


def test_finished_jobs_are_purged_by_age_and_size_and_keep_only_what_downloads_need(tmp_path):
    store = SqliteStore(tmp_path / "j.sqlite3")
    big = {"rig": "robotaxi", "name": "m", "origin": None, "lot": {"blob": "x" * 200_000}}
    ids = [store.create("maneuver", big) for _ in range(4)]
    queued = store.create("maneuver", big)
    for i in ids:
        claimed = store.claim("r", 30)
        store.finish(*claimed, "succeeded", result={"score": 1.0})
    assert store.request_of(ids[0]) == {"rig": "robotaxi", "name": "m", "origin": None}
    assert "request" not in store.get(ids[0])  # a GET never reads the request
    assert store.total_bytes() < 250_000  # the queued job's request, and four small ones
    assert store.purge(max_age_s=3600, max_bytes=1 << 30) == 0
    with sqlite3.connect(tmp_path / "j.sqlite3") as db:
        db.execute("UPDATE jobs SET finished_at = finished_at - 7200 WHERE id = ?", (ids[0],))
    assert store.purge(max_age_s=3600, max_bytes=1 << 30) == 1 and store.get(ids[0]) is None
    assert store.purge(max_age_s=3600, max_bytes=1000) == 3  # the oldest finished ones, not the queued
    assert store.get(queued)["status"] == "queued" and store.runs(ids[1]) == []
