"""Fairness of the scoring workers: a key flooding hour-long routes within its request rate
holds its share of the workers; another key's latency stays within 3× of its idle value, and the
flood's excess is refused at once with 429 (never a 503 at the time limit)."""

from __future__ import annotations

import os
import statistics
import threading
import time

import httpx
import pytest

from api.errors import Overloaded
from api.pool import WorkerPool
from excite.errors import WorkerDied, WorkTimeout
from servers import LiveServer, write_keys

SHORT = {"route": {"control": {"t_s": [0, 10, 20], "speed_mps": [0, 5, 0], "curvature_1pm": [0, 0.1, 0]}}}
HOUR = {"route": {"control": {"t_s": [0, 1200, 2400, 3600], "speed_mps": [5, 9, 7, 5],
                              "curvature_1pm": [0.02, -0.03, 0.01, 0.02]}}}


def _p50(client: httpx.Client, n: int = 15) -> float:
    times = []
    for _ in range(n):
        t0 = time.monotonic()
        r = client.post("/v1/score", json=SHORT)
        assert r.status_code == 200, r.text[:200]
        times.append(time.monotonic() - t0)
        time.sleep(0.1)
    return statistics.median(times)


@pytest.mark.slow
def test_a_flooding_key_leaves_the_other_keys_latency_within_three_times_idle(tmp_path):
    secrets = write_keys(tmp_path / "keys.yaml", {"quiet": {"scopes": ["score"]},
                                                  "flood": {"scopes": ["score"], "quota": {"rate_per_s": 3, "burst": 3}}})
    srv = LiveServer(tmp_path, workers=0, score_workers=2, api_keys_file=tmp_path / "keys.yaml").start()
    try:
        quiet = httpx.Client(base_url=srv.url, headers={"X-API-Key": secrets["quiet"]}, timeout=120)
        _p50(quiet, 3)  # warm
        idle = _p50(quiet)
        stop = threading.Event()
        statuses: list[int] = []

        def flood() -> None:
            with httpx.Client(base_url=srv.url, headers={"X-API-Key": secrets["flood"]}, timeout=120) as c:
                while not stop.is_set():
                    statuses.append(c.post("/v1/score", json=HOUR).status_code)
                    time.sleep(1.0)  # 3 threads: 3 requests per second, within the key's rate

        threads = [threading.Thread(target=flood) for _ in range(3)]
        for t in threads:
            t.start()
        time.sleep(3)  # the flood holds its share
        try:
            loaded = _p50(quiet)
        finally:
            stop.set()
            for t in threads:
                t.join(180)
        assert statuses and set(statuses) <= {200, 429}, statuses
        assert statuses.count(200) >= 1
        assert loaded <= 3 * idle, (idle, loaded)
    finally:
        srv.stop()


def _outcome(f) -> str:
    exc = f.exception()
    if exc is None:
        return "200"
    return {Overloaded: "429", WorkTimeout: "503", WorkerDied: "503"}.get(type(exc), repr(exc))


def test_a_key_flooding_past_its_share_while_its_costs_triple_is_answered_429_and_the_other_key_is_served():
    """Two workers, one per key. The flooding key sends a task of size 3 every 0.1 s, each with 6 s
    to finish: for 3 s each is 0.2 s of work (what the pool learned: 0.067 s per unit), then 0.6 s
    (as when the machine's load triples). Tasks sleep: their costs do not depend on the machine's
    load. The flood's share does one task at a time, so most of the flood must be refused — with
    429, at admission or once its admitted tasks are seen to cost more, never left to time out
    (503). The quiet key's tasks, one after another throughout, all succeed."""
    pool = WorkerPool(2, memory_mb=0, recycle_mb=0, share=0.5, max_queued=64)
    pool.start()
    try:
        pool.submit(time.sleep, [(0.2,)], time.monotonic() + 10, key="quiet", sizes=[3.0])[0].result()
        flood: list = []  # (phase, future or "429")
        done = threading.Event()

        def flooding() -> None:
            for i in range(60):
                phase = "light" if i < 30 else "tripled"
                try:
                    (f,) = pool.submit(time.sleep, [(0.2 if phase == "light" else 0.6,)], time.monotonic() + 6.0,
                                       key="flood", sizes=[3.0])
                    flood.append((phase, f))
                except Overloaded:
                    flood.append((phase, "429"))
                time.sleep(0.1)
            done.set()

        t = threading.Thread(target=flooding)
        t.start()
        quiet = []
        while not done.is_set():
            (f,) = pool.submit(time.sleep, [(0.05,)], time.monotonic() + 6.0, key="quiet", sizes=[0.5])
            quiet.append(_outcome(f))
        t.join()
        outcomes = [(phase, f if f == "429" else _outcome(f)) for phase, f in flood]
        assert quiet and set(quiet) == {"200"}, quiet
        assert {o for _, o in outcomes} == {"200", "429"}, outcomes
        for phase in ("light", "tripled"):  # both phases were served and refused (none timed out: 503)
            assert {o for p, o in outcomes if p == phase} == {"200", "429"}, outcomes
    finally:
        pool.close()


def test_a_worker_that_has_exited_after_its_last_task_is_replaced(monkeypatch):
    """A worker whose memory grew past recycle_mb answers and exits. Here each run waits until the
    process is gone before the pool looks (as a loaded machine may): the pool must still replace
    it. Checked only while it was alive, the pool kept the dead worker and every later task
    waited for a worker that never came."""
    from excite.core.processes import Worker

    run = Worker.run

    def run_then_exit(self, *args, **kw):
        out = run(self, *args, **kw)
        if self.ending:
            self.proc.join(10)
        return out

    monkeypatch.setattr(Worker, "run", run_then_exit)
    pool = WorkerPool(1, memory_mb=0, recycle_mb=1)
    pool.start()
    try:
        pids = []
        for _ in range(3):  # a task grows its worker past 1 MiB: every such task ends its worker
            (f,) = pool.submit(bytearray, [(8 << 20,)], time.monotonic() + 20)
            assert len(f.result(timeout=30)) == 8 << 20
            pids.append(pool.submit(os.getpid, [()], time.monotonic() + 20)[0].result(timeout=30))
        assert len(set(pids)) == 3  # each served by the worker that replaced the last
    finally:
        pool.close()


ARENAS = """
import ctypes, sys, tempfile, threading
from api.pool import few_arenas
if sys.argv[1] == "few":
    assert few_arenas()
def work():
    for _ in range(100):
        x = [bytearray(1000) for _ in range(2000)]
        del x
threads = [threading.Thread(target=work) for _ in range(12)]
[t.start() for t in threads]
[t.join() for t in threads]
libc = ctypes.CDLL(None)
libc.fopen.restype = ctypes.c_void_p
path = tempfile.mktemp()
fp = libc.fopen(path.encode(), b"w")
libc.malloc_info(0, ctypes.c_void_p(fp))
libc.fclose(ctypes.c_void_p(fp))
print(open(path).read().count("<heap nr="))
"""


def test_the_server_allocates_from_few_arenas_however_many_threads_it_runs():
    """glibc's malloc_info counts the arenas of a process whose 12 threads allocate at once: by
    default several (one per thread up to 8 per core), with few_arenas() at most two."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    env.pop("MALLOC_ARENA_MAX", None)
    counts = {how: int(subprocess.run([sys.executable, "-c", ARENAS, how], env=env, capture_output=True, text=True,
                                      timeout=120, check=True).stdout)
              for how in ("default", "few")}
    assert counts["few"] <= 2 < counts["default"], counts
