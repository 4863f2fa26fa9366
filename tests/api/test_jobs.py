"""Jobs are durable and cancellable: cancel a running job; a job survives `kill -9` of the
server and completes after a restart (with a stand-in optimizer and with the real one)."""

from __future__ import annotations

import time

import pytest

from api.store import JobStore as SqliteStore
from servers import LiveServer, processes_with, wait_job

# a generous grace: after the cancel the stand-in still scores its best maneuver so far, which a
# loaded machine may take a while to do (the grace kill would discard it)
SLOW = {"job_function": "servers:slow_job", "workers": 1, "cancel_grace_s": 120}


@pytest.mark.slow
def test_cancel_a_running_job(tmp_path):
    srv = LiveServer(tmp_path, **SLOW).start()
    try:
        with srv.client() as c:
            r = c.post("/v1/maneuvers", json={"duration_s": 60, "time_budget_s": 60})
            loc = r.headers["location"]
            wait_job(c, loc, lambda j: (j["progress"] or {}).get("iteration", -1) >= 2)
            t0 = time.monotonic()
            d = c.delete(loc)
            assert d.status_code == 202 and d.json()["cancel_requested"] is True, d.text
            job = wait_job(c, loc, timeout_s=150)
            assert job["status"] == "cancelled" and time.monotonic() - t0 < 120  # stopped by the cancel
            assert job["result"]["cancelled"] is True  # the best so far is kept
            assert c.get(f"{loc}/maneuver", params={"format": "tum"}).status_code == 200
            assert c.delete(loc).status_code == 200  # cancelling again changes nothing
    finally:
        srv.stop()


@pytest.mark.slow
def test_job_survives_kill_9_and_completes_after_restart(tmp_path):
    srv = LiveServer(tmp_path, **SLOW).start()
    with srv.client() as c:
        running = c.post("/v1/maneuvers", json={"duration_s": 60, "time_budget_s": 3})
        queued = c.post("/v1/maneuvers", json={"duration_s": 60, "time_budget_s": 1})
        assert running.status_code == queued.status_code == 202
        job = wait_job(c, running.headers["location"],
                       lambda j: (j["progress"] or {}).get("iteration", -1) >= 3)
        assert job["status"] == "running"
    srv.kill9()
    # the worker dies with the server; the job is left running in the store
    job_id = running.json()["id"]
    deadline = time.monotonic() + 10
    while processes_with(job_id) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not processes_with(job_id)
    # so do the scoring pool's forkserver and worker (their command lines name the server's directory)
    pool = lambda: set(processes_with(str(tmp_path))) & set(processes_with("multiprocessing.forkserver"))  # noqa: E731
    assert pool(), "the scoring pool should have been running"
    deadline = time.monotonic() + 15
    while pool() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not pool(), "orphaned scoring processes outlived the server"
    stored = SqliteStore(tmp_path / "jobs.sqlite3")
    assert stored.get(job_id)["status"] == "running"
    assert stored.get(queued.json()["id"])["status"] == "queued"

    srv2 = LiveServer(tmp_path, **SLOW).start()
    try:
        with srv2.client() as c:
            first = wait_job(c, running.headers["location"], timeout_s=60)
            second = wait_job(c, queued.headers["location"], timeout_s=60)
        assert first["status"] == "succeeded" and first["attempts"] == 2
        assert second["status"] == "succeeded" and second["attempts"] == 1
        assert first["result"]["report"]["score"] > 0
    finally:
        srv2.stop()
    # the restarted server said which jobs it re-queued
    assert f"re-queued 1 job(s) left running by a previous server: {job_id}" in srv2.log.read_text()


@pytest.mark.slow
def test_real_optimizer_job_survives_kill_9(tmp_path):
    pytest.importorskip("excite.plan")
    srv = LiveServer(tmp_path, workers=1).start()
    with srv.client() as c:
        r = c.post("/v1/maneuvers", json={"duration_s": 60, "time_budget_s": 5, "n_random": 4})
        assert r.status_code == 202
    srv.kill9()  # right after the 202: accepted means persisted
    srv2 = LiveServer(tmp_path, workers=1).start()
    try:
        with srv2.client() as c:
            job = wait_job(c, r.headers["location"], timeout_s=150)
        assert job["status"] == "succeeded", job
        assert job["result"]["report"]["score"] > 0
    finally:
        srv2.stop()
