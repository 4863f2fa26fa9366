"""Batch and mine on a real Dask cluster (a LocalCluster of two worker processes started here):
the same results as the local run, and a worker killed mid-run loses no route."""

from __future__ import annotations

import json
import os
import shutil
import signal
from pathlib import Path

import pytest

distributed = pytest.importorskip("distributed")
import dask  # noqa: E402

from excite.fleet import batch as gate
from excite.core import engine
from excite.fleet import mine
from excite.cli.app import main
from helpers import REPO


ROOT = REPO


@pytest.fixture(scope="module")
def cluster():
    # the workers also import the tests' stand-in job (tests/servers.py)
    path = os.pathsep.join([str(ROOT / "tests"), str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    with dask.config.set(engine.WORKER_CONFIG):  # the workers' environment is set as they spawn
        c = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                     dashboard_address=None, silence_logs=40, env={"PYTHONPATH": path})
    with c, distributed.Client(c, set_as_default=False) as client:
        yield c.scheduler_address, client


def test_the_recommended_worker_config_reaches_the_workers(cluster):
    """Dask's nanny fixes glibc's trim threshold (MALLOC_TRIM_THRESHOLD_=65536) unless told not
    to: excite's setting reaches the spawned workers, and the engine would warn otherwise."""
    _, client = cluster
    settings = client.run(engine._trim_threshold)
    assert len(settings) == 2 and engine.slow_workers(settings) is None
    message = engine.slow_workers({**settings, "tcp://10.0.0.9:4001": "65536"})
    assert message.startswith("excite: warning: 1 of 3 Dask workers run with MALLOC_TRIM_THRESHOLD_=65536 "
                              "(Dask’s default)") and "\n" not in message


@pytest.fixture(scope="module")
def routes(tmp_path_factory) -> list[Path]:
    """Five short routes with distinct names (the reference drives, some twice) and one that
    does not exist."""
    d = tmp_path_factory.mktemp("routes")
    files = sorted((ROOT / "trajectories").glob("*.tum"))
    out = []
    for i in range(5):
        src = files[i % len(files)]
        out.append(Path(shutil.copy(src, d / f"{i}_{src.name}")))
    return out + [d / "missing.tum"]


@pytest.fixture(scope="module")
def local(routes) -> list[gate.RouteResult]:
    """The routes evaluated in this process: what the cluster must reproduce."""
    return gate.run(gate.collect([str(p) for p in routes], min_score=1e-4), jobs=1, keep_reports=True)


def _untimed(doc: dict) -> list[dict]:
    for r in doc["routes"]:
        del r["seconds"]
        if r["report"]:
            del r["report"]["timings_ms"]
    return doc["routes"]


def _same(a: list[gate.RouteResult], b: list[gate.RouteResult]) -> None:
    assert [(r.name, r.status, r.score, r.failures, r.error) for r in a] == \
           [(r.name, r.status, r.score, r.failures, r.error) for r in b]


def test_batch_on_the_cluster_equals_the_local_run(cluster, routes, local, tmp_path, monkeypatch, capsys):
    address, _ = cluster
    out = tmp_path / "dask.json"
    monkeypatch.setenv(engine.SCHEDULER_ENV, address)  # the environment selects the cluster
    assert main(["batch", *map(str, routes), "--min-score", "1e-4", "--json", str(out)]) == 1
    capsys.readouterr()
    expected = _untimed(json.loads(gate.dumps(local)))
    assert _untimed(json.loads(out.read_text())) == expected
    assert {r["status"] for r in expected} == {"passed", "failed", "error"}


def test_an_unreachable_scheduler_is_a_one_line_error(routes, monkeypatch, capsys):
    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 1.0)
    assert main(["batch", str(routes[0]), "--scheduler", "tcp://127.0.0.1:9"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("excite: error: cannot reach the Dask scheduler at tcp://127.0.0.1:9") and err.count("\n") == 1


def test_mine_on_the_cluster_equals_the_local_run(cluster, routes):
    address, _ = cluster
    specs = gate.collect([str(p) for p in routes[:3]])
    tasks = [mine.Task(s, 30.0, mine.Goal(min_score=1e-4), per_log=2) for s in specs]
    local = mine.mine_logs(tasks, jobs=1)
    seen = []
    remote = mine.mine_logs(tasks, scheduler=address, on_result=lambda r, p: seen.append((r.log, p.done, p.total)))
    assert [x[1:] for x in seen] == [(1, 3), (2, 3), (3, 3)]  # progress: done / total
    drop = {"seconds"}
    doc = lambda rs: [{k: v for k, v in e.items() if k not in drop} for e in mine.results_json(rs, 30.0, None)["logs"]]
    assert doc(local) == doc(remote)
    assert mine.results_json(local, 30.0, None)["best"] == mine.results_json(remote, 30.0, None)["best"]
    assert all(r.error is None and r.best for r in remote)


def test_a_worker_killed_mid_run_loses_no_route(cluster, routes, local):
    address, client = cluster
    specs = gate.collect([str(p) for p in routes], min_score=1e-4)
    killed = []

    def kill_one(_: gate.RouteResult) -> None:
        if killed:
            return
        busy = {w: keys for w, keys in client.processing().items() if keys}
        assert busy, "the kill must land while routes are being evaluated"
        worker = next(iter(busy))
        pid = client.run(os.getpid, workers=[worker])[worker]
        os.kill(pid, signal.SIGKILL)
        killed.append((worker, len(busy[worker])))

    remote = gate.run(specs, scheduler=address, on_result=kill_one)
    assert killed and killed[0][1] >= 1
    assert sorted(r.name for r in remote) == sorted(s.name for s in specs)  # each route once
    _same(local, remote)


@pytest.mark.slow
def test_the_service_runs_batches_and_jobs_on_the_cluster(cluster, tmp_path):
    """With EXCITE_DASK_SCHEDULER the service's batch routes and optimization jobs run on the
    cluster (seen in its task stream); a Dask worker killed mid-job loses nothing: the job
    completes from the durable record's process; a job cancelled while on the cluster stops."""
    from servers import LiveServer, wait_job

    from excite.score.evaluate import evaluate
    from excite.rig.config import load_rig
    from excite.io.routes import read_route

    address, client = cluster
    files = [ROOT / "trajectories" / "figure_eight.tum", ROOT / "trajectories" / "slalom.tum"]
    srv = LiveServer(tmp_path, job_function="servers:slow_job", workers=1, dask_scheduler=address).start(timeout_s=180)
    try:
        with srv.client() as c, distributed.get_task_stream(client=client) as stream:
            r = c.post("/v1/batch", json={"routes": [{"name": f.stem, "format": "tum", "text": f.read_text()}
                                                      for f in files]})
            assert r.status_code == 200, r.text
            rig = load_rig("robotaxi")
            for item, f in zip(r.json()["results"], files):
                assert item["report"]["score"] == pytest.approx(evaluate(read_route(f), rig).score, rel=1e-12)
            job = c.post("/v1/maneuvers", json={"duration_s": 30, "time_budget_s": 5})
            loc = job.headers["location"]
            wait_job(c, loc, lambda j: (j["progress"] or {}).get("iteration", -1) >= 1)
            busy = [w for w, keys in client.processing().items() if any("remote_job" in str(k) for k in keys)]
            assert busy, f"the job runs on a Dask worker: {client.processing()}\n{srv.log.read_text()[-3000:]}"
            os.kill(client.run(os.getpid, workers=busy)[busy[0]], signal.SIGKILL)
            done = wait_job(c, loc, timeout_s=90)
            # a job cancelled while it runs on the cluster: the task itself stops (60 s of
            # iterations were asked for) and the record says cancelled, keeping the best so far
            job = c.post("/v1/maneuvers", json={"duration_s": 30, "time_budget_s": 60})
            loc2 = job.headers["location"]
            wait_job(c, loc2, lambda j: (j["progress"] or {}).get("iteration", -1) >= 1, timeout_s=90)
            assert c.delete(loc2).status_code == 202
            cancelled = wait_job(c, loc2, timeout_s=45)
        assert done["status"] == "succeeded" and done["result"]["score"] > 0, done
        assert cancelled["status"] == "cancelled" and cancelled["result"]["cancelled"] is True, cancelled
        assert cancelled["result"]["iterations"] < 590  # stopped well before its 60 s of iterations
        ran = {str(t["key"]).split("-")[0] for t in stream.data}
        assert {"batch_item_task", "remote_job"} <= ran, ran  # /v1/batch's items, the job
    finally:
        srv.stop()
