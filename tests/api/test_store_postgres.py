"""The job store on a real PostgreSQL server: several replicas share it, jobs are
claimed with leases and heartbeats, a replica that dies loses no job, a live replica's job is
never taken over, and an outage of the database longer than the lease ends every job once. The server is Debian's ``postgresql`` package, started here on loopback in a
temporary folder and stopped at the end (``.ci/run`` installs it)."""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import subprocess
import tempfile
import time
from collections import Counter
from pathlib import Path

import httpx
import pytest

from servers import LiveServer, free_port, job_result_file


def _binaries() -> Path | None:
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(p.split("/")[4]))
    if found:
        return Path(found[-1]).parent
    initdb = shutil.which("initdb")
    return Path(initdb).resolve().parent if initdb else None


pytestmark = pytest.mark.postgres


class Server:
    """A PostgreSQL server of its own: ``url``, and ``stop()``/``start()`` for an outage."""

    def __init__(self, run, bindir: Path, data: Path, log: Path, sock: Path, port: int):
        self.run, self.bindir, self.data, self.log, self.sock, self.port = run, bindir, data, log, sock, port
        self.url = f"postgresql://excite@127.0.0.1:{port}/excite_jobs"

    def start(self) -> None:
        self.run(str(self.bindir / "pg_ctl"), "-D", str(self.data), "-l", str(self.log), "-w", "-t", "60", "-o",
                 f"-p {self.port} -k {self.sock} -c listen_addresses=127.0.0.1 -c fsync=off -c max_connections=200",
                 "start")

    def stop(self, mode: str = "fast") -> None:
        self.run(str(self.bindir / "pg_ctl"), "-D", str(self.data), "-m", mode, "-w", "stop")


@pytest.fixture(scope="module")
def postgres_server():
    """A fresh server on 127.0.0.1 (its own cluster in a temp folder)."""
    pytest.importorskip("psycopg", reason="psycopg is not installed (pip install 'psycopg[binary]')")
    bindir = _binaries()
    if bindir is None:
        pytest.skip("PostgreSQL's server binaries are not installed (Debian: apt-get install postgresql)")
    # not under pytest's folders: those are the root user's alone, and the server runs as postgres
    tmp = Path(tempfile.mkdtemp(prefix="excite-pg-"))
    data, sock = tmp / "data", tmp / "sock"
    sock.mkdir()
    user = None
    if os.geteuid() == 0:  # the server refuses to run as root
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root and there is no 'postgres' user to run the server as")
        for p in (tmp, sock):
            os.chown(p, user.pw_uid, user.pw_gid)

    def run(*cmd: str) -> None:
        def demote() -> None:
            if user is not None:
                os.setgid(user.pw_gid)
                os.setuid(user.pw_uid)

        subprocess.run(cmd, check=True, preexec_fn=demote, cwd=tmp, stdout=subprocess.DEVNULL,
                       stderr=subprocess.PIPE, timeout=120)

    port = free_port()
    run(str(bindir / "initdb"), "-D", str(data), "-U", "excite", "--auth=trust", "-E", "UTF8", "--no-sync")
    server = Server(run, bindir, data, tmp / "server.log", sock, port)
    server.start()
    try:
        import psycopg

        with psycopg.connect(f"postgresql://excite@127.0.0.1:{port}/postgres", autocommit=True) as db:
            db.execute("CREATE DATABASE excite_jobs")
        yield server
    finally:
        try:
            server.stop()
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


@pytest.fixture(scope="module")
def postgres(postgres_server):
    """``postgresql://…`` of the module's server."""
    return postgres_server.url


@pytest.fixture
def fresh(postgres):
    """The store emptied for this test."""
    import psycopg

    from api.store import JobStore as PostgresStore

    store = PostgresStore(postgres)
    with psycopg.connect(postgres, autocommit=True) as db:
        db.execute("TRUNCATE jobs, job_runs")
    return store


def test_migrations_leases_and_fairness_on_postgres(postgres, fresh):
    import psycopg

    from api.store import SCHEMA_VERSION, JobStore as PostgresStore

    store = fresh
    versions = "SELECT version FROM excite_schema ORDER BY version"
    with psycopg.connect(postgres) as db:
        before = db.execute(versions).fetchall()
    PostgresStore(postgres)  # opening again migrates nothing
    with psycopg.connect(postgres) as db:
        assert db.execute(versions).fetchall() == before and before[-1][0] == SCHEMA_VERSION
    flood = [store.create("maneuver", {"n": i}, key_id="flood") for i in range(50)]
    first = store.claim("host/boot/1/a", 30)
    assert first == (flood[0], 1)
    late = store.create("maneuver", {"name": "late"}, key_id="late")
    assert store.claim("host/boot/1/a", 30)[0] == late  # the key with nothing running goes first
    assert store.reclaim("host/boot/2/b") == []  # live leases of another replica: untouched
    assert store.heartbeat("host/boot/1/a", 30, {first, (late, 1), ("other", 1)}) == {first, (late, 1)}
    import psycopg

    with psycopg.connect(postgres, autocommit=True) as db:
        db.execute("UPDATE jobs SET lease_expires = 0 WHERE id = %s", (first[0],))
    assert store.reclaim("host/boot/2/b") == [first[0]]
    assert not store.finish(*first, "succeeded", result={})  # the lost run cannot write
    assert store.claim("host/boot/2/b", 30) == (flood[0], 2)
    assert [r["outcome"] for r in store.runs(flood[0])] == ["lost", None]


@pytest.mark.slow
def test_three_replicas_run_thirty_jobs_exactly_once_with_one_killed(tmp_path, postgres, fresh):
    """Replicas A and B take 30 jobs; A is killed with SIGKILL mid-job and C starts afterwards.
    Every job succeeds exactly once: one succeeded run per job in the records, the runs lost
    with A re-run once (attempt 2), and no job of a live replica was ever taken over."""
    result = job_result_file(tmp_path / "result.json")
    log = tmp_path / "completions.log"
    common = {"database_url": postgres, "workers": 2, "job_lease_s": 3, "job_function": "servers:quick_job",
              "test_job_result": result, "test_job_log": log}

    def replica(name: str) -> LiveServer:
        folder = tmp_path / name
        folder.mkdir()
        return LiveServer(folder, **common).start()

    a, b = replica("a"), replica("b")
    c = None
    try:
        ids = []
        for i in range(30):
            srv = (a, b)[i % 2]
            with srv.client() as client:
                r = client.post("/v1/maneuvers", json={"duration_s": 60, "time_budget_s": 2, "name": f"j{i}"})
                assert r.status_code == 202, r.text
                ids.append(r.json()["id"])
        a_tag = f"/{a.proc.pid}/"
        deadline = time.monotonic() + 60
        while not any(a_tag in (fresh.get(i)["lease_owner"] or "") for i in ids):
            assert time.monotonic() < deadline, "replica A never ran a job"
            time.sleep(0.1)
        time.sleep(0.5)  # mid-job
        a.kill9()
        c = replica("c")
        deadline = time.monotonic() + 300
        while fresh.counts().get("succeeded", 0) < 30:
            assert time.monotonic() < deadline, fresh.counts()
            time.sleep(0.5)
        jobs = [fresh.get(i) for i in ids]
        assert all(j["status"] == "succeeded" for j in jobs), fresh.counts()
        rerun = set()
        for i, j in enumerate(jobs):
            runs = fresh.runs(j["id"])
            assert [r["outcome"] for r in runs].count("succeeded") == 1, runs
            assert j["attempt"] == len(runs)
            lost = [r for r in runs if r["outcome"] != "succeeded"]
            assert all(a_tag in r["replica"] and r["outcome"] == "lost" for r in lost), runs
            if lost:
                rerun.add(f"j{i}")
        assert rerun, "the killed replica had a job running"
        # each job's function ran to its end once; twice only for a job A was running when it
        # died — A's run may have ended just before A could record it, and the job ran again
        ended = Counter(log.read_text().split()[0::3])
        assert set(ended) == {f"j{i}" for i in range(30)}, "a job never completed"
        assert all(n == 1 or (n == 2 and name in rerun) for name, n in ended.items()), \
            f"a job completed twice without losing its first run: {ended}"
    finally:
        for srv in (a, b, c):
            if srv is not None:
                srv.stop()


@pytest.mark.slow
def test_a_database_outage_during_running_jobs_ends_every_job_once(tmp_path, postgres_server, fresh):
    """Three replicas (one job worker each, a 3 s lease) run six jobs; PostgreSQL is stopped for
    10 s (longer than the lease) while three of them run. Every job succeeds, once: one run per
    job, succeeded, written by the replica that kept it through the outage — no run lost and
    re-run, none left running, and every replica ready afterwards."""
    result = job_result_file(tmp_path / "result.json")
    log = tmp_path / "completions.log"
    common = {"database_url": postgres_server.url, "workers": 1, "job_lease_s": 3,
              "job_function": "servers:quick_job", "test_job_result": result, "test_job_log": log}
    replicas = []
    try:
        for name in "abc":
            (tmp_path / name).mkdir()
            replicas.append(LiveServer(tmp_path / name, **common).start())
        ids = []
        for i in range(6):
            with replicas[i % 3].client() as client:
                r = client.post("/v1/maneuvers", json={"duration_s": 60, "time_budget_s": 4, "name": f"j{i}"})
                assert r.status_code == 202, r.text
                ids.append(r.json()["id"])
        deadline = time.monotonic() + 60
        while fresh.counts().get("running", 0) < 3:
            assert time.monotonic() < deadline, fresh.counts()
            time.sleep(0.1)
        postgres_server.stop("immediate")  # the outage: the running jobs' ends fall inside it
        try:
            time.sleep(10)
        finally:
            postgres_server.start()
        deadline = time.monotonic() + 120
        while fresh.counts().get("succeeded", 0) < 6:
            assert time.monotonic() < deadline, fresh.counts()
            time.sleep(0.5)
        for job_id in ids:
            runs = fresh.runs(job_id)
            assert [r["outcome"] for r in runs] == ["succeeded"], runs
            assert fresh.get(job_id)["result"]["status"] == "stand-in"
        names = log.read_text().split()[0::3]
        assert sorted(names) == sorted(f"j{i}" for i in range(6)), names  # each ran to its end once
        for srv in replicas:
            assert srv.proc.poll() is None
            assert httpx.get(srv.url + "/readyz", timeout=10).status_code == 200
    finally:
        for srv in replicas:
            srv.stop()


def test_concurrent_submissions_on_two_replicas_never_exceed_the_quota(postgres, fresh):
    """Two replicas (two stores, each with its own connections) take a key's submissions at the
    same moment: with a quota of 2, 10 at once create 2 jobs; with a quota of 20, 80 at once
    create 20 — the count and the insert are one transaction, serialised per key."""
    import concurrent.futures as cf
    import threading

    from api.store import OverQuota, JobStore as PostgresStore

    replicas = [fresh, PostgresStore(postgres)]
    try:
        for key, quota, n in (("two", 2, 10), ("twenty", 20, 80)):
            start = threading.Barrier(n)

            def submit(i: int, key=key, quota=quota, start=start) -> bool:
                start.wait(30)
                try:
                    replicas[i % 2].create("maneuver", {"n": i}, key_id=key, max_active=quota)
                    return True
                except OverQuota:
                    return False

            with cf.ThreadPoolExecutor(n) as pool:
                accepted = sum(pool.map(submit, range(n)))
            assert accepted == quota, (key, accepted)
        assert fresh.counts() == {"queued": 22}
    finally:
        replicas[1].close()
