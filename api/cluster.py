"""The service's work on a Dask cluster, when ``EXCITE_DASK_SCHEDULER`` names one.

- Batch routes (``POST /v1/batch``): each route is scored on a Dask worker, through
  :class:`ClusterScoring`'s futures, which behave like the local scoring pool's.
- Optimization jobs: the job's process (:func:`api.jobs.job_main`, started per job by the server)
  stays the job's owner and the durable job record its truth; it submits the job function to
  the cluster (:func:`run_remote`) and relays progress (a Dask queue) and cancellation (a Dask
  variable) between the task and the store. A Dask worker lost mid-job: the scheduler re-runs
  the task elsewhere. The server killed: the job's process dies with it, its client
  disconnects, the cluster drops the task, and the next server re-runs the job from the store.
"""

from __future__ import annotations

import concurrent.futures as cf
import importlib
import threading
import time
import uuid
from typing import Any, Callable

from excite.core import engine

from excite.errors import WorkerDied, WorkTimeout

POLL_S = 0.2


class ClusterScoring:
    """Scoring tasks on the Dask cluster at ``address`` (one client, connected on first use)."""

    def __init__(self, address: str):
        self.address = address
        self._client: Any = None
        self._lock = threading.Lock()

    def client(self) -> Any:
        with self._lock:
            if self._client is None:
                self._client = engine.client(self.address)
                engine.check_workers(self._client)
            return self._client

    def submit(self, fn: Callable[..., Any], *args: Any, deadline: float) -> cf.Future:
        """``fn(*args)`` on the cluster as a standard future: its result, :class:`WorkerDied` when
        the cluster gave up on it, :class:`WorkTimeout` past ``deadline`` (time.monotonic)."""
        out: cf.Future = cf.Future()
        remote = self.client().submit(fn, *args, pure=False)

        def done(f: Any) -> None:
            if out.done():
                return
            try:
                out.set_result(f.result())
            except Exception as exc:  # lost with too many workers (KilledWorker), or cancelled
                if not out.done():
                    out.set_exception(WorkerDied(f"{type(exc).__name__}: {exc}"))

        def expire() -> None:
            if not out.done():
                out.set_exception(WorkTimeout())
                remote.cancel()

        timer = threading.Timer(max(0.0, deadline - time.monotonic()), expire)
        timer.daemon = True
        timer.start()
        out.add_done_callback(lambda _: timer.cancel())
        remote.add_done_callback(done)
        return out

    def close(self) -> None:
        with self._lock:
            if self._client is not None:
                self._client.close()
                self._client = None


def load_function(spec: str) -> Any:
    """The job function named ``module:name`` (the local worker and the Dask worker run it)."""
    module, name = spec.split(":", 1)
    return getattr(importlib.import_module(module), name)


def remote_job(function: str, request: dict[str, Any], channel: str) -> dict[str, Any]:
    """Run on a Dask worker: the job function, its progress put on the queue ``channel``, its
    ``should_stop`` read from the variable ``channel`` (both at most every :data:`POLL_S`)."""
    from distributed import Queue, Variable

    queue, stop = Queue(channel), Variable(channel)
    last = {"put": 0.0, "check": 0.0, "stopped": False}

    def progress(p: dict[str, Any]) -> None:
        now = time.monotonic()
        if now - last["put"] >= POLL_S:
            last["put"] = now
            queue.put(p)

    def should_stop() -> bool:
        now = time.monotonic()
        if not last["stopped"] and now - last["check"] >= POLL_S:
            last["check"] = now
            try:
                last["stopped"] = bool(stop.get(timeout=1))
            except TimeoutError:
                pass
        return last["stopped"]

    return load_function(function)(request, progress, should_stop)


def run_remote(address: str, function: str, request: dict[str, Any],
               progress: Callable[[dict[str, Any]], None], should_stop: Callable[[], bool]) -> dict[str, Any]:
    """The job function run on the cluster (see the module docstring); raises what it raised."""
    from distributed import Queue, Variable

    channel = f"excite-job-{uuid.uuid4().hex}"
    with engine.client(address) as c:
        queue, stop = Queue(channel, client=c), Variable(channel, client=c)
        stop.set(False)
        fut = c.submit(remote_job, function, request, channel, pure=False)
        stopped = False
        try:
            while True:
                done = fut.done()
                for p in queue.get(batch=True):
                    progress(p)
                if done:
                    return fut.result()
                if not stopped and should_stop():
                    stopped = True
                    stop.set(True)
                time.sleep(POLL_S)
        finally:
            fut.release()
            stop.delete()
            queue.close()
