"""A client's rig is resolved off the event loop and bounded before it costs: /v1/live's start
message in the session's process, and the same rigs over HTTP refused or resolved in a worker —
a rig built to cost seconds (50,000 glob targets in a 1 MB message, or 4,900 globs of many
wildcards each, under the size bound) never holds the event loop nor a request to its time limit."""

from __future__ import annotations

import contextlib
import json
import threading
import time

import httpx
import pytest

from servers import LiveServer

REQUEST_TIMEOUT_S = 60
IMU = {"accelerometer_noise_density": 2e-3, "accelerometer_random_walk": 3e-3,
       "gyroscope_noise_density": 1.7e-4, "gyroscope_random_walk": 2e-5, "update_rate": 200.0}


@contextlib.contextmanager
def healthz_probed(url: str):
    """``/healthz`` asked every 50 ms while the block runs; yields a one-item list that holds the
    slowest answer's seconds when the block ends."""
    worst = [0.0]
    done = threading.Event()

    def probe() -> None:
        while not done.is_set():
            t0 = time.monotonic()
            assert httpx.get(url + "/healthz", timeout=30).status_code == 200
            worst[0] = max(worst[0], time.monotonic() - t0)
            time.sleep(0.05)

    t = threading.Thread(target=probe)
    t.start()
    try:
        yield worst
    finally:
        done.set()
        t.join(60)


@pytest.mark.slow
def test_a_50000_glob_rig_start_keeps_healthz_under_a_second(tmp_path):
    from websockets.sync.client import connect

    srv = LiveServer(tmp_path, workers=0).start()
    try:
        targets = {f"*.r{i}*": "1 deg" for i in range(50_000)}
        start = json.dumps({"type": "start", "name": "bomb", "rig": {"name": "bomb", "imu": IMU, "targets": targets}},
                           separators=(",", ":"))
        assert len(start) < 1 << 20  # within the frame bound (MAX_MESSAGE_BYTES): the server reads it
        t0 = time.monotonic()
        with healthz_probed(srv.url) as worst:
            with connect(f"ws://127.0.0.1:{srv.port}/v1/live", open_timeout=10, max_size=None) as ws:
                ws.send(start)
                frame = json.loads(ws.recv(timeout=60))
        assert frame["type"] == "error" and frame["problem"]["status"] == 422, frame
        assert frame["problem"]["errors"][0]["field"].startswith("rig")
        assert time.monotonic() - t0 < 10
        assert worst[0] < 1.0, worst
    finally:
        srv.stop()


@pytest.mark.slow
def test_glob_rigs_over_http_are_422_at_once_and_keep_healthz_under_a_second(tmp_path):
    srv = LiveServer(tmp_path, workers=0, request_timeout_s=REQUEST_TIMEOUT_S).start()
    loop = {"waypoints": [[0, 0], [30, 0], [30, 20], [0, 20], [0, 1]]}
    try:
        for targets in ({f"*.r{i}*": "1 deg" for i in range(50_000)},  # over the size bound
                        {f"*{i}*a*b*c*d*e*f*g*h*": "1 deg" for i in range(4_900)}):  # under it, each glob costly
            t0 = time.monotonic()
            with healthz_probed(srv.url) as worst:
                r = httpx.post(srv.url + "/v1/score", json={"route": loop, "rig": {"name": "bomb", "imu": IMU,
                                                                                    "targets": targets}}, timeout=120)
            took = time.monotonic() - t0
            assert r.status_code == 422, r.text[:300]
            assert r.json()["errors"][0]["field"].startswith("rig"), r.text[:300]
            assert took < REQUEST_TIMEOUT_S / 3, took  # refused, not held to the time limit
            assert worst[0] < 1.0, worst
    finally:
        srv.stop()
