"""One optimization job in its own process tree:
``python -m api.worker JOB_ID ATTEMPT FUNCTION SERVER_PID MEMORY_MB TIME_LIMIT_S``
(the store's URL in ``EXCITE_JOB_STORE_URL``).

Every process the job starts ends with the job. The server starts this process as the leader
of a session and process group of its own; it stays small (no numpy, no excite) and is the
job's **supervisor**:

- it marks itself a child subreaper, so a process the job starts and abandons is re-parented
  to it, not to PID 1;
- it forks the **runner**, which applies the memory limit (``RLIMIT_AS``, inherited by
  everything the job starts), reads the request, runs ``FUNCTION`` (``module:function``,
  default :func:`api.jobs.run_optimization`) with a progress callback that writes to the store
  and a ``should_stop`` that reads the cancel flag from it, and writes the result;
- when the runner ends, when the server dies (parent-death signal, and a check of the parent
  twice a second), on SIGTERM (the server's cancel past its grace, or its shutdown) and past
  the job's hard wall-clock limit (``TIME_LIMIT_S``: the job's time budget plus the server's
  reserve), it kills every process below it (SIGKILL, repeated until none is left) and exits.
  Past the time limit the job is recorded as failed, naming the limit.

With ``EXCITE_DASK_SCHEDULER`` set (the server passes its setting on) the function runs on that
Dask cluster and the runner relays its progress and cancellation (:func:`api.cluster.run_remote`).
"""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any

log = logging.getLogger("excite.api.worker")

PROGRESS_EVERY_S = 0.5
STOP_CHECK_EVERY_S = 0.2
SUPERVISE_EVERY_S = 0.1
EXIT_ORPHANED = 75
EXIT_TIME_LIMIT = 76
STORE_ENV = "EXCITE_JOB_STORE_URL"
_PR_SET_PDEATHSIG, _PR_SET_CHILD_SUBREAPER = 1, 36


def _prctl(option: int, value: int) -> None:
    try:
        ctypes.CDLL(None, use_errno=True).prctl(option, value, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (from /proc's children lists), deepest last."""
    out: list[int] = []
    frontier = [pid]
    while frontier:
        nxt = []
        for p in frontier:
            try:
                tasks = os.listdir(f"/proc/{p}/task")
            except OSError:
                continue
            for tid in tasks:
                try:
                    text = Path(f"/proc/{p}/task/{tid}/children").read_text()
                except OSError:
                    continue
                nxt += [int(c) for c in text.split()]
        nxt = [c for c in nxt if c not in out]
        out += nxt
        frontier = nxt
    return out


def kill_tree(pid: int, rounds: int = 50) -> None:
    """SIGKILL every process below ``pid`` and reap them, until none is left (a process may
    fork while it is being killed)."""
    for _ in range(rounds):
        below = descendants(pid)
        if not below:
            return
        for p in below:
            try:
                os.kill(p, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        _reap_all()
        time.sleep(0.01)


def _reap_all() -> list[tuple[int, int]]:
    out = []
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return out
        if pid == 0:
            return out
        out.append((pid, status))


# --------------------------------------------------------------------------------------------
# The runner (a forked child of the supervisor)


def run(store_url: str, job_id: str, attempt: int, function: str, parent: int) -> int:
    from excite.errors import ExciteError
    from excite.core.engine import scheduler_address

    from .cluster import load_function, run_remote
    from .store import open_store

    store = open_store(store_url)
    request = store.running_request(job_id, attempt)
    if request is None:
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
            result = load_function(function)(request, progress, should_stop)
        else:
            log.info("job %s attempt %d runs on the Dask cluster at %s", job_id, attempt, address)
            result = run_remote(address, function, request, progress, should_stop)
    except ExciteError as exc:
        store.finish(job_id, attempt, "failed", error={
            "type": "https://excite.dev/problems/validation", "title": "Unprocessable content",
            "status": 422, "detail": str(exc)[:2000], "instance": f"/v1/jobs/{job_id}",
            "errors": [{"field": "request", "message": str(exc)[:2000]}]})
        return 0
    except MemoryError:
        store.finish(job_id, attempt, "failed", error={
            "type": "https://excite.dev/problems/too-large", "title": "Content too large",
            "status": 413, "detail": "the job needs more memory than a job process may use",
            "instance": f"/v1/jobs/{job_id}"})
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


def _runner(store_url: str, job_id: str, attempt: int, function: str, memory_mb: int,
            supervisor: int) -> int:
    import resource

    _prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != supervisor:
        return EXIT_ORPHANED
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if memory_mb:
        limit = memory_mb * 1024 * 1024
        try:
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        except (ValueError, OSError):
            pass
    return run(store_url, job_id, attempt, function, supervisor)


# --------------------------------------------------------------------------------------------
# The supervisor


def _time_limit_error(job_id: str, limit_s: float) -> dict[str, Any]:
    return {"type": "https://excite.dev/problems/time-limit", "title": "Job time limit",
            "status": 422, "detail": f"the job ran past its hard time limit of {limit_s:g} s (its "
                                     "time_budget_s plus EXCITE_JOB_TIME_RESERVE_S) and was stopped; "
                                     "a smaller lot or a larger budget may fit",
            "instance": f"/v1/jobs/{job_id}",
            "errors": [{"field": "time_budget_s", "message": f"the job outran it (hard limit {limit_s:g} s)"}]}


def supervise(store_url: str, job_id: str, attempt: int, function: str, server: int,
              memory_mb: int, time_limit_s: float) -> int:
    me = os.getpid()
    _prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    _prctl(_PR_SET_CHILD_SUBREAPER, 1)
    if os.getppid() != server:  # the server died before the signal was armed
        return EXIT_ORPHANED
    stop = {"why": None}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(why="terminated"))
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the server, which stops us
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            code = _runner(store_url, job_id, attempt, function, memory_mb, me)
        finally:
            logging.shutdown()
            os._exit(code)
    code = None
    while code is None:
        for p, status in _reap_all():
            if p == pid:
                code = os.waitstatus_to_exitcode(status)
        if code is not None:
            break
        if stop["why"] is None and os.getppid() != server:
            stop["why"] = "the server is gone"
        if stop["why"] is None and time.monotonic() - t0 > time_limit_s:
            stop["why"] = "time limit"
        if stop["why"] is not None:
            kill_tree(me)
            if stop["why"] == "time limit":
                log.warning("job %s attempt %d: past its time limit of %g s, stopped", job_id, attempt,
                            time_limit_s)
                try:
                    from .store import open_store

                    open_store(store_url).finish(job_id, attempt, "failed",
                                                 error=_time_limit_error(job_id, time_limit_s))
                except Exception:
                    log.exception("job %s: cannot record its time limit", job_id)
                return EXIT_TIME_LIMIT
            return EXIT_ORPHANED if stop["why"] == "the server is gone" else 143
        time.sleep(SUPERVISE_EVERY_S)
    kill_tree(me)  # whatever the job left running ends with it
    return code


def main(argv: list[str]) -> int:
    job_id, attempt, function, server, memory_mb, time_limit_s = argv
    logging.basicConfig(level=logging.INFO, format="%(asctime)s worker %(levelname)s %(message)s")
    store_url = os.environ.get(STORE_ENV)
    if not store_url:
        log.error("no job store: %s is not set", STORE_ENV)
        return 2
    return supervise(store_url, job_id, int(attempt), function, int(server), int(memory_mb),
                     float(time_limit_s))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
