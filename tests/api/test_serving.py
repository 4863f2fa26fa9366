"""Hostile clients against a live server: work that outlives its request is stopped, slow
bodies time out, absurd numbers and pathological structure are 422s naming field and bound, the
schema states the bounds the server enforces, errors never quote a server path, and the edges
(a directory or a corrupt file as job database) are one-line errors."""

from __future__ import annotations

import json
import os
import signal
import socket
import threading
import time
from pathlib import Path

import httpx
import pytest

from servers import LiveServer

TIMEOUT_S = 20.0  # a replacement worker warms up (imports, loads the kernels) before it takes work: seconds on a busy machine
SETTINGS = {"workers": 0, "score_workers": 1, "request_timeout_s": TIMEOUT_S, "body_timeout_s": 2,
            "header_timeout_s": 2, "max_route_duration_s": 2000, "max_job_time_budget_s": 100,
            "max_samples": 50_000, "worker_recycle_mb": 1, "max_queued_tasks": 1}
LOOP = {"waypoints": [[0, 0], [30, 0], [30, 20], [0, 20], [0, 1]]}


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    server = LiveServer(tmp_path_factory.mktemp("hardening"), **SETTINGS).start()
    yield server
    server.stop()
    log = server.log.read_text()
    assert "leaked semaphore" not in log and "Traceback" not in log, log[-3000:]


class PatientClient(httpx.Client):
    """Waits out back-pressure as a client should: with worker_recycle_mb = 1 every task
    replaces its worker, and a request that arrives while the replacement warms up may be
    answered 429 with Retry-After (tested on its own below)."""

    def request(self, *args, **kwargs) -> httpx.Response:
        for _ in range(30):
            r = super().request(*args, **kwargs)
            if r.status_code != 429:
                return r
            time.sleep(float(r.headers.get("retry-after", "1")))
        return r


@pytest.fixture(scope="module")
def client(srv):
    with PatientClient(base_url=srv.url, timeout=120) as c:
        yield c


def _problem(r, status: int, field: str | None = None) -> dict:
    assert r.status_code == status, (r.status_code, r.text[:500])
    assert r.headers["content-type"].startswith("application/problem+json")
    body = r.json()
    if field is not None:
        assert any(e["field"] == field for e in body.get("errors") or []), body
    return body


def _children(pid: int) -> dict[int, int]:
    """pid → parent pid of every process below ``pid``."""
    parents = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()
            if fields[0] != "Z":
                parents[int(d.name)] = int(fields[1])
    below, frontier = {}, {pid}
    while frontier:
        frontier = {p for p, pp in parents.items() if pp in frontier and p not in below}
        below.update({p: parents[p] for p in frontier})
    return below


def _score_workers(server_pid: int) -> set[int]:
    """The scoring workers: forked by the forkserver, itself a child of the server."""
    tree = _children(server_pid)
    return {p for p, pp in tree.items() if pp != server_pid and tree.get(pp) == server_pid}


@pytest.mark.slow
def test_a_timed_out_request_has_its_worker_killed_and_the_next_is_served(srv, client):
    before = _score_workers(srv.proc.pid)
    assert len(before) == 1
    # within every bound, but 2000 s at 100 keyframes/s and 10 kHz IMU samples, with the
    # information of 100 segments, take ~12 s on the 2-core machine this was written on; the
    # worker is also stopped (SIGSTOP) a second into the work, so that the request outlives the
    # limit however fast the machine (the same request without segments once finished within the
    # limit on a faster CI machine)
    slow_rig = _inline_rig(keyframe_rate_hz=100, update_rate=10_000)
    route = {"control": {"t_s": [0, 1000, 2000], "speed_mps": [0, 5, 0], "curvature_1pm": [0, 0.05, 0]}}
    answers: dict[str, httpx.Response] = {}

    def post(name: str, body: dict) -> None:
        with srv.client() as c:
            answers[name] = c.post("/v1/score", json=body)

    t0 = time.monotonic()
    slow = threading.Thread(target=post, args=("slow", {"route": route, "rig": slow_rig, "segments": 100}))
    slow.start()
    time.sleep(1.0)  # the only worker is busy with it
    (worker,) = before
    os.kill(worker, signal.SIGSTOP)  # SIGKILL, which the server sends past the deadline, still ends it
    queued = threading.Thread(target=post, args=("queued", {"route": LOOP}))
    queued.start()
    time.sleep(1.0)
    # max_queued_tasks = 1 and one request waits already: back-pressure at once, not a 503 later
    t1 = time.monotonic()
    with srv.client() as impatient:
        r = impatient.post("/v1/score", json={"route": LOOP})
    body = _problem(r, 429)
    assert time.monotonic() - t1 < 2.0
    assert body["type"].endswith("/overloaded") and "busy" in body["detail"], body
    assert 1 <= int(r.headers["retry-after"]) <= 60
    slow.join()
    queued.join()
    _problem(answers["slow"], 503)
    assert time.monotonic() - t0 < TIMEOUT_S + 4
    # the queued request waited for a worker: served if the replacement was ready in time
    assert answers["queued"].status_code in (200, 503), answers["queued"].text[:300]
    deadline = time.monotonic() + 10
    while _score_workers(srv.proc.pid) & before and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _score_workers(srv.proc.pid) & before, "the timed-out worker is still running"
    # its replacement warms up (loads the kernels) before it takes work: ready again, then served
    _wait_ready(client)
    r = client.post("/v1/score", json={"route": LOOP})
    assert r.status_code == 200 and r.json()["score"] >= 0, r.text[:300]


def _wait_ready(client: httpx.Client) -> None:
    """Until the scoring workers are warm (a replacement warms up before it takes work)."""
    deadline = time.monotonic() + 60
    while client.get("/readyz").status_code != 200 and time.monotonic() < deadline:
        time.sleep(0.2)


def test_a_worker_that_grew_is_replaced_after_its_task(srv, client):
    # worker_recycle_mb = 1: every task grows a worker by more than that
    _wait_ready(client)
    before = _score_workers(srv.proc.pid)
    assert client.post("/v1/score", json={"route": LOOP}).status_code == 200
    deadline = time.monotonic() + 30
    while (_score_workers(srv.proc.pid) & before or not _score_workers(srv.proc.pid)) \
            and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _score_workers(srv.proc.pid) & before
    _wait_ready(client)
    assert client.post("/v1/score", json={"route": LOOP}).status_code == 200


def test_a_slow_body_is_timed_out_and_the_connection_closed(srv):
    with socket.create_connection(("127.0.0.1", srv.port), timeout=15) as s:
        s.sendall(b"POST /v1/score HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
                  b"Content-Length: 1000\r\n\r\n{\"route\": ")
        t0 = time.monotonic()
        data = b""
        while True:
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
    assert data.startswith(b"HTTP/1.1 408"), data[:200]
    assert b"did not arrive within 2 s" in data
    assert time.monotonic() - t0 < 10


def test_slow_headers_are_timed_out_and_the_connection_closed(srv, client):
    """A client that sends its headers a byte at a time gets 408 and is disconnected once the
    header time limit (2 s) has passed, whatever it keeps sending; one that sends nothing is
    disconnected too; everyone else is served meanwhile."""
    with socket.create_connection(("127.0.0.1", srv.port), timeout=15) as trickle, \
            socket.create_connection(("127.0.0.1", srv.port), timeout=15) as idle:
        t0 = time.monotonic()
        trickle.sendall(b"POST /v1/score HTTP/1.1\r\nHost: localhost\r\n")
        trickle.settimeout(0.25)
        data = b""
        for byte in b"Content-Type: application/json\r\n" * 100:
            assert time.monotonic() - t0 < 15, "still connected after 15 s"
            if byte == ord("C"):  # others are served while it trickles
                assert client.get("/healthz").status_code == 200
            try:
                trickle.sendall(bytes([byte]))
                chunk = trickle.recv(65536)
            except socket.timeout:
                continue
            except OSError:  # reset after the server closed
                break
            if not chunk:
                break
            data += chunk
        cut_after = time.monotonic() - t0
        assert data.startswith(b"HTTP/1.1 408"), data[:200]
        assert b"headers did not arrive within 2 s" in data
        assert 1.5 < cut_after < 8, cut_after
        idle.settimeout(10)
        assert idle.recv(100) == b"", "an idle connection is closed without an answer"
        assert time.monotonic() - t0 < 10


@pytest.mark.slow
def test_a_websocket_outlives_the_header_time_limit(srv):
    """The header deadline ends with the upgrade: a /v1/live session idle for longer than it
    (2 s here) still answers."""
    from websockets.sync.client import connect

    with connect(f"ws://127.0.0.1:{srv.port}/v1/live", open_timeout=30) as ws:
        ws.send(json.dumps({"type": "start", "rig": "robotaxi", "name": "idle"}))
        assert json.loads(ws.recv(timeout=30))["type"] == "started"
        time.sleep(3.0)
        ws.send(json.dumps({"type": "nonsense"}))
        reply = json.loads(ws.recv(timeout=30))
    assert reply["type"] == "error" and "'poses' or 'end'" in reply["problem"]["detail"], reply


@pytest.mark.slow
def test_a_pool_refuses_work_it_cannot_finish_by_the_deadline():
    """Admission by the size of the work: once a task is known to cost ~1.5 s per unit of size,
    a second one while the only worker is busy cannot finish within 1 s and is refused at once
    with a retry time; one with time enough is admitted (and a queue of one is the count bound)."""
    from api.errors import Overloaded
    from api.pool import WorkerPool

    pool = WorkerPool(1, 0, 0, max_queued=1)
    pool.start()
    try:
        soon = lambda s: time.monotonic() + s  # noqa: E731
        (f,) = pool.submit(time.sleep, [(1.5,)], soon(10), sizes=[1.0])
        f.result()  # now a sleep is known to cost ~1.5 s per unit
        (busy,) = pool.submit(time.sleep, [(1.5,)], soon(10), sizes=[1.0])
        time.sleep(0.3)
        t0 = time.monotonic()
        with pytest.raises(Overloaded) as exc:
            pool.submit(time.sleep, [(0.0,)], soon(1.0), sizes=[1.0])
        assert time.monotonic() - t0 < 0.5 and exc.value.retry_after_s >= 1
        assert "time limit" in exc.value.detail
        (waits,) = pool.submit(time.sleep, [(0.0,)], soon(10), sizes=[1.0])  # ~1.5 + 1.5 s < 10 s
        with pytest.raises(Overloaded, match="at most 1"):
            pool.submit(time.sleep, [(0.0,)], soon(60), sizes=[0.001])  # one already waits
        busy.result()
        waits.result()
        assert pool.submit(time.sleep, [(0.0,)], soon(10))[0].result() is None  # drained
    finally:
        pool.close()


def test_a_process_stopped_by_two_threads_at_once_closes_its_pipe_once():
    """A request thread past its deadline and the pool's shutdown can stop the same worker at
    the same moment: the second stop must not close the pipe again, which would close whatever
    file reused its descriptor."""
    from excite.core.processes import Worker

    w = Worker(context="fork")
    closes = []
    real = w.conn.close
    w.conn.close = lambda: (closes.append(1), time.sleep(0.1), real())
    threads = [threading.Thread(target=w.stop) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(closes) == 1


def _inline_rig(**changes: float) -> dict:
    from excite.rig.config import load_rig

    data = json.loads(json.dumps(load_rig("robotaxi").config.model_dump()))
    for k, v in changes.items():
        if k == "update_rate" or k.startswith("gyroscope") or k.startswith("accelerometer"):
            data["imu"][k] = v
        else:
            data[k] = v
    return data


def _score(client: httpx.Client, **kwargs) -> httpx.Response:
    """A score once a scoring worker is warm: this module's server replaces its one worker after
    every task (worker_recycle_mb = 1), and what these tests check is the answer, not the wait
    for a replacement on a busy machine."""
    _wait_ready(client)
    return client.post("/v1/score", **kwargs)


def test_absurd_numbers_are_422_naming_field_and_bound(client):
    cases = [
        ({"route": LOOP, "rig": _inline_rig(gyroscope_noise_density=1e-308)},
         "rig.imu.gyroscope_noise_density", "[1e-08, 1] rad/s/√Hz"),
        ({"route": LOOP, "rig": _inline_rig(update_rate=1e308)}, "rig.imu.update_rate", "[1, 10000] Hz"),
        ({"route": LOOP, "rig": dict(_inline_rig(), targets={"*": 1e308})}, "rig.targets.*", "[1e-09, 3.14159] rad"),
        ({"route": LOOP, "limits": {"speed_max_mps": 1e308}}, "limits.speed_max_mps", "100"),
        ({"route": {"waypoints": [[0, 0], [1e300, 0]]}}, "route.waypoints[1][0]", "100000000"),
        ({"route": {"control": {"t_s": [0, 5, 10], "speed_mps": [0, 5, 0], "curvature_1pm": [0, 1e300, 0]}}},
         "route.control.curvature_1pm[1]", "10"),
        ({"route": {"format": "tum", "text": "".join(f"{i} {1e300 if i == 3 else i} 0 0 0 0 0 1\n"
                                                     for i in range(8))}}, "route.text", "sane range"),
    ]
    for body, field, bound in cases:
        problem = _problem(_score(client, json=body), 422, field)
        assert bound in problem["detail"], (field, problem["detail"])
    problem = _problem(client.post("/v1/maneuvers", json={"duration_s": 1e308}), 422, "duration_s")
    assert "600" in problem["detail"]


def test_pathological_structure_is_422(client):
    deep = '{"route": {"waypoints": [[0, 0], [30, 0], [30, 20]]}, "rig": ' + '{"a": ' * 950 + "1" + "}" * 951
    assert len(deep) < 8000
    r = _score(client, content=deep, headers={"content-type": "application/json"})
    assert "nested more than" in _problem(r, 422, "rig")["detail"]
    rig = _inline_rig()
    rig["sensors"] = [dict(rig["sensors"][0], name=f"s{i}") for i in range(500)]
    _wait_ready(client)
    t0 = time.monotonic()
    r = client.post("/v1/score", json={"route": LOOP, "rig": rig})
    # refused by its size (keys and items) before its sensors are counted
    assert "more than 5000 keys and list items" in _problem(r, 422, "rig")["detail"]
    assert time.monotonic() - t0 < TIMEOUT_S


def test_errors_never_quote_a_server_path(client):
    kitti = "\n".join("1 0 0 %d 0 1 0 0 0 0 1 0" % i for i in range(8))
    bodies = [
        {"format": "kitti", "text": kitti, "times_text": "\n".join(str(i) for i in range(7))},
        {"format": "control_csv", "text": "t_s,speed_mps,curvature_1pm\n0,0,0\n5e5,5,0\n1e6,0,0\n"},
        {"format": "waypoints_csv", "text": "x,y\n0,0\n5000000,0\n"},
        {"format": "tum", "text": "".join(f"{t} 0 0 0 0 0 0 1\n" for t in (0, 1e-6, 2e-6, 3e-6, 4e-6, 5e-6, 9000))},
    ]
    for route in bodies:
        body = _problem(_score(client, json={"route": route}), 422)
        text = json.dumps(body)
        assert "/tmp" not in text and "excite-" not in text, text


def test_schema_states_the_bounds_the_server_enforces(client):
    doc = client.get("/openapi.json").json()
    models = doc["components"]["schemas"]
    man = models["ManeuverRequest"]["properties"]
    assert man["duration_s"]["maximum"] == 600 and man["time_budget_s"]["maximum"] == 100
    assert man["lot_x_m"]["maximum"] == 2000
    for value, status in ((100, 202), (100.5, 422)):
        r = client.post("/v1/maneuvers", json={"time_budget_s": value})
        assert r.status_code == status, r.text[:300]
    wp = next(n for n in models["RouteIn"]["properties"]["waypoints"]["anyOf"] if n.get("type") == "array")
    assert wp["maxItems"] == SETTINGS["max_samples"]
    lim = models["LimitsIn"]["properties"]["speed_max_mps"]
    for value, status in ((lim["maximum"], 200), (lim["maximum"] * 1.01, 422)):
        r = _score(client, json={"route": LOOP, "limits": {"speed_max_mps": value}})
        assert r.status_code == status, r.text[:300]


def test_405_names_the_allowed_methods(client):
    r = client.put("/v1/score", json={})
    assert r.status_code == 405 and "POST" in r.headers["allow"]


def test_unusable_job_databases_are_one_line_errors(tmp_path, monkeypatch, capsys):
    from excite.cli.app import main

    corrupt = tmp_path / "corrupt.sqlite3"
    corrupt.write_bytes(b"this is not a database" * 100)
    for path, words in ((tmp_path, "is a directory"), (corrupt, "cannot be used")):
        monkeypatch.setenv("EXCITE_DB_PATH", str(path))
        capsys.readouterr()
        rc = main(["serve", "--port", "0"])  # refused before the server starts
        lines = capsys.readouterr().err.strip().splitlines()
        assert rc == 1 and len(lines) == 1 and lines[0].startswith("excite: error:"), lines
        assert words in lines[0] and str(path) in lines[0]


def test_default_job_database_is_a_user_data_file(tmp_path, monkeypatch):
    from api.settings import Settings

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("EXCITE_DB_PATH", raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    s = Settings()
    assert s.db_path == tmp_path / "data" / "excite" / "jobs.sqlite3" and s.db_path.parent.is_dir()
    assert "job_function" not in Settings.model_fields  # a test hook is no setting


def test_405_on_a_path_with_several_routes_lists_all_their_methods(client):
    r = client.put("/v1/jobs/0123456789abcdef")
    assert r.status_code == 405 and set(r.headers["allow"].split(", ")) == {"GET", "DELETE"}
    # and a route the API document leaves out (the page) names its own
    r = client.post("/")
    assert r.status_code == 405 and "GET" in r.headers["allow"].split(", ")


def test_numbers_are_not_coerced_from_booleans_or_strings(client):
    for body in ({"route": LOOP, "segments": False}, {"route": LOOP, "segments": "2"},
                 {"route": LOOP, "limits": {"speed_max_mps": True}}):
        _problem(client.post("/v1/score", json=body), 422)
