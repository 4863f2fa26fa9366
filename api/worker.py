"""One optimization job in its own process: ``python -m api.worker DB JOB_ID ATTEMPT FUNCTION``.

The process reads the job's request from the store, runs ``FUNCTION`` (``module:function``,
default :func:`api.jobs.run_optimization`) with a progress callback that writes to the store and
a ``should_stop`` that reads the cancel flag from it, and writes the result. It dies with the
server (parent-death signal, and a parent check in every callback): the job stays ``running``
and the next server re-runs it. With ``EXCITE_DASK_SCHEDULER`` set (the server passes its
setting on) the function runs on that Dask cluster and this process relays its progress and
cancellation (:func:`api.cluster.run_remote`).
"""

from __future__ import annotations

import ctypes
import logging
import os
import resource
import signal
import sys
import time
from typing import Any

from excite.fleet.engine import scheduler_address
from excite.errors import ExciteError

from .cluster import load_function, run_remote
from .store import JobStore

log = logging.getLogger("excite.api.worker")

PROGRESS_EVERY_S = 0.5
STOP_CHECK_EVERY_S = 0.2
EXIT_ORPHANED = 75


def _die_with_parent(parent: int) -> None:
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:  # the parent died before the signal was armed
        os._exit(EXIT_ORPHANED)




def run(db_path: str, job_id: str, attempt: int, function: str, parent: int) -> int:
    store = JobStore(db_path)
    job = store.get(job_id)
    if job is None or job["attempt"] != attempt or job["status"] != "running":
        return 0
    last: dict[str, Any] = {"progress": 0.0, "stop": 0.0, "stopped": False, "latest": None,
                            "written": None}

    def alive() -> None:
        if os.getppid() != parent:
            os._exit(EXIT_ORPHANED)

    def progress(p: dict[str, Any]) -> None:
        alive()
        last["latest"] = p
        now = time.monotonic()
        if now - last["progress"] >= PROGRESS_EVERY_S:
            last["progress"], last["written"] = now, p
            store.progress(job_id, attempt, p)

    def should_stop() -> bool:
        alive()
        now = time.monotonic()
        if not last["stopped"] and now - last["stop"] >= STOP_CHECK_EVERY_S:
            last["stop"] = now
            last["stopped"] = store.should_stop(job_id, attempt)
        return last["stopped"]

    address = scheduler_address()
    try:
        if address is None:
            result = load_function(function)(job["request"], progress, should_stop)
        else:
            log.info("job %s attempt %d runs on the Dask cluster at %s", job_id, attempt, address)
            result = run_remote(address, function, job["request"], progress, should_stop)
    except ExciteError as exc:
        store.finish(job_id, attempt, "failed", error={
            "type": "https://excite.dev/problems/validation", "title": "Unprocessable content",
            "status": 422, "detail": str(exc), "instance": f"/v1/jobs/{job_id}",
            "errors": [{"field": "request", "message": str(exc)}]})
        return 0
    except Exception:
        log.exception("job %s failed", job_id)
        store.finish(job_id, attempt, "failed", error={
            "type": "https://excite.dev/problems/internal", "title": "Internal server error",
            "status": 500, "detail": "The job failed; the error is logged.",
            "instance": f"/v1/jobs/{job_id}"})
        return 1
    if last["latest"] is not None and last["latest"] is not last["written"]:
        store.progress(job_id, attempt, last["latest"])  # the last word, not the last throttled one
    status = "cancelled" if result.get("cancelled") else "succeeded"
    store.finish(job_id, attempt, status, result=result)
    return 0


def main(argv: list[str]) -> int:
    db_path, job_id, attempt, function, parent, memory_mb = argv
    _die_with_parent(int(parent))
    logging.basicConfig(level=logging.INFO, format="%(asctime)s worker %(levelname)s %(message)s")
    if int(memory_mb):
        limit = int(memory_mb) * 1024 * 1024
        try:
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        except (ValueError, OSError):
            pass
    return run(db_path, job_id, int(attempt), function, int(parent))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
