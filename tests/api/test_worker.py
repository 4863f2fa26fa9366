"""A job's whole process tree ends with it: on cancel, on kill -9 of the server, on shutdown and at
its hard time limit."""

from __future__ import annotations

import pytest
import sqlite3
import time
from pathlib import Path
from api.store import JobStore as SqliteStore
from servers import LiveServer, processes_with, wait_job


TREE = {"job_function": "servers:tree_job", "workers": 1, "cancel_grace_s": 1}


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


@pytest.mark.slow
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


@pytest.mark.slow
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
