"""The job store's faults and retention: store faults are named, never 500s, and metrics never
fail; a nearly full disk is not ready and uploads wait; a read-only store says so; finished jobs
are purged by age and size, keeping only what downloads need."""

from __future__ import annotations

import errno
import sqlite3
import time
import pytest
from fastapi.testclient import TestClient
from api import Settings, create_app
from api.store import JobStore as SqliteStore


@pytest.mark.slow
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


def test_a_read_only_store_says_so(tmp_path):
    import sqlalchemy as sa

    from api.errors import StoreError

    store = SqliteStore(tmp_path / "j.sqlite3")
    job = store.create("maneuver", {})
    # SQLite refuses every write from here on, as it does on a read-only file (root writes any
    # file whatever its mode, so the test cannot make one that way)
    sa.event.listen(store.engine, "connect", lambda dbapi, _: dbapi.execute("PRAGMA query_only=ON"))
    with pytest.raises(StoreError) as exc:
        store.create("maneuver", {})
    assert "read-only" in str(exc.value) and "move it away" not in str(exc.value)
    assert str(tmp_path / "j.sqlite3") in str(exc.value)
    with pytest.raises(StoreError, match="read-only"):
        store.cancel(job)


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
    with sqlite3.connect(tmp_path / "j.sqlite3") as db:  # the queued job's request, and four small ones
        assert db.execute("SELECT sum(size_bytes) FROM jobs").fetchone()[0] < 250_000
    assert store.purge(max_age_s=3600, max_bytes=lambda key_id: 1 << 30) == 0
    with sqlite3.connect(tmp_path / "j.sqlite3") as db:
        db.execute("UPDATE jobs SET finished_at = finished_at - 7200 WHERE id = ?", (ids[0],))
    assert store.purge(max_age_s=3600, max_bytes=lambda key_id: 1 << 30) == 1 and store.get(ids[0]) is None
    # the oldest finished ones, not the queued
    assert store.purge(max_age_s=3600, max_bytes=lambda key_id: 1000) == 3
    assert store.get(queued)["status"] == "queued" and store.runs(ids[1]) == []


def test_retention_by_size_trims_only_the_key_over_its_quota(tmp_path):
    store = SqliteStore(tmp_path / "j.sqlite3")
    quiet = store.create("maneuver", {"rig": "robotaxi"}, key_id="quiet")
    store.finish(*store.claim("r", 30), "succeeded", result={"score": 1.0})
    loud = [store.create("maneuver", {"rig": "robotaxi"}, key_id="loud") for _ in range(3)]
    for _ in loud:
        store.finish(*store.claim("r", 30), "cancelled", result={"blob": "x" * 50_000})
    # the quiet key's result is the oldest of all, and stays: each key is held to its own quota
    assert store.purge(max_age_s=3600, max_bytes=lambda key_id: 60_000) == 2
    assert store.get(quiet)["status"] == "succeeded"
    assert [store.get(i) is None for i in loud] == [True, True, False]
