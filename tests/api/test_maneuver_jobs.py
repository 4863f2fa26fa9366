"""Job creation under concurrency and faults: a key's quota holds for concurrent submissions
(one transaction counts and inserts), and a store outage while jobs run loses no job and ends
each once."""

from __future__ import annotations

import concurrent.futures as cf
import time

import httpx
import pytest

from api.store import JobStore
from servers import LiveServer, job_result_file, write_keys

JOB = {"duration_s": 60, "time_budget_s": 5, "n_random": 2}


@pytest.mark.slow
def test_concurrent_submissions_never_exceed_the_quota(tmp_path):
    secrets = write_keys(tmp_path / "keys.yaml", {"two": {"scopes": ["plan"], "quota": {"jobs": 2}},
                                                  "twenty": {"scopes": ["plan"], "quota": {"jobs": 20}}})
    srv = LiveServer(tmp_path, workers=0, api_keys_file=tmp_path / "keys.yaml", quota_rate_per_s=1000,
                     quota_burst=1000).start()
    try:
        def post(key: str) -> int:
            return httpx.post(srv.url + "/v1/maneuvers", json=JOB, headers={"X-API-Key": secrets[key]},
                              timeout=60).status_code

        with cf.ThreadPoolExecutor(40) as pool:
            two = list(pool.map(post, ["two"] * 10))
            twenty = list(pool.map(post, ["twenty"] * 40))
        assert sorted(two) == [202] * 2 + [429] * 8, two
        assert twenty.count(202) == 20 and twenty.count(429) == 20, twenty
        store = JobStore(tmp_path / "jobs.sqlite3")
        assert store.counts() == {"queued": 22}
    finally:
        srv.stop()


@pytest.mark.slow
def test_a_store_outage_during_running_jobs_ends_every_job_once_on_sqlite(tmp_path):
    """The job database's folder disappears for 10 s (longer than the 3 s lease) while two jobs
    run and four wait: every job succeeds, once — one succeeded run each, its result written by
    the dispatcher that kept it through the outage, no run lost or re-run."""
    result = job_result_file(tmp_path / "result.json")
    log = tmp_path / "completions.log"
    folder = tmp_path / "db"
    folder.mkdir()
    srv = LiveServer(tmp_path, db_path=folder / "jobs.sqlite3", workers=2, job_lease_s=3,
                     job_function="servers:quick_job", test_job_result=result, test_job_log=log).start()
    away = tmp_path / "db-away"
    try:
        ids = []
        with srv.client() as c:
            for i in range(6):
                r = c.post("/v1/maneuvers", json={"duration_s": 60, "time_budget_s": 3, "name": f"j{i}"})
                assert r.status_code == 202, r.text
                ids.append(r.json()["id"])
        store = JobStore(folder / "jobs.sqlite3")
        deadline = time.monotonic() + 60
        while store.counts().get("running", 0) < 2:
            assert time.monotonic() < deadline
            time.sleep(0.1)
        store.close()
        folder.rename(away)  # the outage: the jobs' ends fall inside it
        time.sleep(10)
        away.rename(folder)
        store = JobStore(folder / "jobs.sqlite3")
        deadline = time.monotonic() + 120
        while store.counts().get("succeeded", 0) < 6:
            assert time.monotonic() < deadline, store.counts()
            time.sleep(0.5)
        for job_id in ids:
            runs = store.runs(job_id)
            assert [r["outcome"] for r in runs] == ["succeeded"], runs
            assert store.get(job_id)["result"]["status"] == "stand-in"
        names = log.read_text().split()[0::3]
        assert sorted(names) == sorted(f"j{i}" for i in range(6)), names  # each ran to its end once
        assert srv.proc.poll() is None
        assert httpx.get(srv.url + "/readyz").status_code == 200
    finally:
        if away.exists():
            away.rename(folder)
        srv.stop()
