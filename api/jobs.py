"""Optimization jobs: the dispatcher that runs them in supervised processes, and the job itself.

:class:`JobRunner` lives in each server (replica). Its thread claims queued jobs from the
:class:`~api.store.JobStore` (fairly across keys, each with a lease) and runs each in a
:class:`~excite.core.processes.Supervised` process (:func:`job_main`, at most ``workers`` at
once), whose tree ends with it. The job process never touches the store: it sends its progress
and, at the end, its outcome over its pipe, and reads "stop" from it. The dispatcher

- writes progress (best effort) and the **outcome before it forgets the run**: while the store
  fails (an outage of tens of seconds, a full disk) it keeps the outcome and retries the write
  on every pass; a run whose process died without one is recorded failed, one past its hard
  time limit (its time budget plus the reserve) is ended and recorded failed, naming the limit;
- renews the leases of exactly the runs it has (:meth:`~api.store.JobStore.heartbeat`) and ends
  a run whose lease it lost (another replica runs the job now: it ends once, there);
- re-queues the jobs of replicas whose leases expired — but not until the store has answered
  this replica for a whole lease: after an outage every lease has expired, and each live
  replica renews its own within that time (a replica that died meanwhile has its jobs re-queued
  a lease later) — stops a cancelled job (asked over the pipe; ended after ``cancel_grace_s``),
  purges finished jobs by the retention policy, and on shutdown ends its job processes and puts
  their jobs back in the queue. :attr:`JobRunner.fault` names its last store fault for ``/readyz``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from excite.core.processes import Supervised

from .errors import Problem, StoreError
from .settings import Settings
from .store import JobStore, replica_id

log = logging.getLogger("excite.api")


def run_optimization(request: dict[str, Any], progress: Callable[[dict[str, Any]], None],
                     should_stop: Callable[[], bool]) -> dict[str, Any]:
    """The default job: plan a maneuver for a :class:`~api.schemas.ManeuverRequest` (as data),
    free-form (:func:`excite.plan.optimize`) or drivable
    (:func:`excite.plan.drivable.search.optimize_drivable`): the result, and the control profile
    and the lot's origin the downloads are rebuilt from."""
    from excite.plan import optimize
    from excite.plan.site import read_site

    from .scoring import drivable_settings, optimize_settings, plain, resolve_rig

    rig = resolve_rig(request["rig"])
    if request.get("drivable"):
        from excite.plan.drivable.search import optimize_drivable

        if request.get("scene") is not None and request.get("_scene") is None:
            raise Problem.at("scene", f"the scene {request['scene'][:12]}… is no longer kept for this key "
                                      "(deleted, or unused for the retention period): upload it again")
        settings = drivable_settings(request, request.get("_scene"))
        res = optimize_drivable(rig, settings, lambda p: progress(plain(
            {"phase": p.phase, "elapsed_s": p.elapsed_s, "score": p.best or None})), should_stop)
    else:
        settings = optimize_settings(request, read_site(request["lot"]) if request.get("lot") else None)
        res = optimize(rig, settings, lambda p: progress(plain(p)), should_stop)
    out = plain(res.to_dict())
    out["report"]["route"] = request.get("name") or out["report"].get("route")
    origin = settings.lot.origin  # a georeferenced lot: GeoJSON downloads need no origin
    return {**out, "profile": plain(res.profile),
            "origin": None if origin is None else {"lon_deg": origin[0], "lat_deg": origin[1]}}


# --------------------------------------------------------------------------------------------
# The job's process

PROGRESS_EVERY_S = 0.5
POLL_S = 0.2  # the dispatcher looks at the store this often (at once when woken)
PURGE_EVERY_S = 60.0


def job_main(conn: Any, function: str, request: dict[str, Any], instance: str, scheduler: str | None) -> None:
    """A job's process: ``function(request, progress, should_stop)``, its progress and outcome
    sent as ``("progress", p)`` and ``("done", status, result, error)``; ``("stop",)`` received
    makes ``should_stop()`` true."""
    last = {"sent": 0.0, "stopped": False, "latest": None}

    def progress(p: dict[str, Any]) -> None:
        last["latest"] = p
        now = time.monotonic()
        if now - last["sent"] >= PROGRESS_EVERY_S:
            last["sent"] = now
            conn.send(("progress", p))

    def should_stop() -> bool:
        while not last["stopped"] and conn.poll(0):
            last["stopped"] = conn.recv()[0] == "stop"
        return last["stopped"]

    from .cluster import load_function, run_remote
    from .scoring import task

    if scheduler is not None:
        log.info("job %s runs on the Dask cluster at %s", instance, scheduler)
    try:  # every failure a problem (a bug: logged, a bare 500)
        result = (task(load_function(function), request, progress, should_stop, field="request") if scheduler is None
                  else task(run_remote, scheduler, function, request, progress, should_stop, field="request"))
    except Problem as exc:
        conn.send(("done", "failed", None, exc.body(instance), last["latest"]))
        return
    status = "cancelled" if result.get("cancelled") else "succeeded"
    conn.send(("done", status, result, None, last["latest"]))


def _time_limit(job_id: str, limit_s: float) -> dict[str, Any]:
    return Problem(422, f"the job ran past its hard time limit of {limit_s:g} s (its time_budget_s plus "
                        "EXCITE_JOB_TIME_RESERVE_S) and was stopped; a smaller lot or a larger budget may fit",
                   type_="time-limit", title="Job time limit",
                   errors=[{"field": "time_budget_s", "message": f"the job outran it (hard limit {limit_s:g} s)"}]
                   ).body(f"/v1/jobs/{job_id}")


# --------------------------------------------------------------------------------------------
# The dispatcher


@dataclass(eq=False)
class Run:
    """A run of a job in this server: its process, and what it said."""

    job_id: str
    attempt: int
    proc: Supervised
    until: float  # monotonic: the hard time limit
    limit_s: float
    progress: dict[str, Any] | None = None
    progress_written: dict[str, Any] | None = None
    outcome: tuple | None = None  # (status, result, error, progress): written before the run is forgotten
    cancel_at: float | None = None  # when the stop was sent

    @property
    def key(self) -> tuple[str, int]:
        return self.job_id, self.attempt


@dataclass
class JobRunner:
    """Runs queued jobs in supervised processes (see the module docstring)."""

    store: JobStore
    settings: Settings  # workers, cancel_grace_s, worker_memory_mb, dask_scheduler, job_*, retention_days
    function: str  # module:function, the job (create_app's job_function)
    storage_bytes: Callable[[str], int] = lambda key_id: 1 << 30
    replica: str = field(default_factory=replica_id)
    fault: str | None = None  # the store's current fault, for /readyz

    def __post_init__(self) -> None:
        self.runs: dict[tuple[str, int], Run] = {}
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_beat = self._last_purge = 0.0
        self._answering_since = -math.inf  # since when the store has answered every pass

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def running(self) -> int:
        return len(self.runs)

    def start(self) -> None:
        try:
            requeued = self.store.reclaim(self.replica)
        except StoreError as exc:
            self._failed(exc)
            requeued = []
        if requeued:
            log.warning("re-queued %d job(s) left running by a previous server: %s", len(requeued), ", ".join(requeued))
        self._thread = threading.Thread(target=self._loop, name="excite-jobs", daemon=True)
        self._thread.start()

    def wake(self) -> None:
        """A job was queued or cancelled: look now rather than at the next poll."""
        self._wake.set()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop dispatching; write the outcomes already known, end every job process here and
        put the unfinished jobs back in the queue."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout_s + 5)
        for run in list(self.runs.values()):
            self._listen(run)
            run.proc.stop()
            try:
                if run.outcome is not None:
                    self._write(run)
                else:
                    self.store.release(*run.key)
            except StoreError as exc:
                log.error("job %s not recorded at shutdown (its lease will expire): %s", run.job_id, exc)
        self.runs.clear()

    def time_limit_s(self, request: dict[str, Any] | None) -> float:
        """A run's hard wall-clock limit: its time budget plus the reserve."""
        most = self.settings.max_job_time_budget_s
        budget = (request or {}).get("time_budget_s", most)
        try:
            budget = min(float(budget), most)
        except (TypeError, ValueError):
            budget = most
        return budget + self.settings.job_time_reserve_s

    def _launch(self, job_id: str, attempt: int) -> None:
        request = self.store.request_of(job_id, attempt)
        if request is None:
            return
        if request.get("scene") is not None:  # the scene's file goes to the run, not into the stored request
            request = {**request, "_scene": self._scene(job_id, request["scene"])}
        limit = self.time_limit_s(request)
        proc = Supervised(job_main, self.function, request, f"/v1/jobs/{job_id}", self.settings.dask_scheduler,
                          context="spawn", memory_mb=self.settings.worker_memory_mb, name="excite-job")
        self.runs[(job_id, attempt)] = Run(job_id, attempt, proc, time.monotonic() + limit, limit)
        log.info("job %s attempt %d started (pid %d)", job_id, attempt, proc.pid)

    def _scene(self, job_id: str, ref: str) -> tuple | None:
        """The scene a job's request names (:func:`api.scoring.scene_spec`; None when it is no
        longer kept: the run says so)."""
        from .scoring import scene_spec

        job = self.store.get(job_id)
        try:
            return scene_spec(None if job is None else self.store, job and job["key_id"], ref)
        except Problem:
            return None

    def _listen(self, run: Run) -> None:
        """Read what the run's process sent; note its outcome when it ended without one."""
        if run.outcome is not None:
            return
        try:
            while run.proc.conn.poll(0):
                message = run.proc.conn.recv()
                if message[0] == "progress":
                    run.progress = message[1]
                elif message[0] == "done":
                    run.outcome = tuple(message[1:5])
                    return
        except (EOFError, OSError):
            pass
        if not run.proc.proc.is_alive() and not run.proc.conn.poll(0):
            code = run.proc.proc.exitcode
            if run.cancel_at is not None:
                run.outcome = ("cancelled", None, None, run.progress)
            else:
                log.error("job %s attempt %d: its process ended with code %s", run.job_id, run.attempt, code)
                run.outcome = ("failed", None, Problem(500, f"the job's process ended unexpectedly (exit code {code})")
                               .body(f"/v1/jobs/{run.job_id}"), run.progress)

    def _write(self, run: Run) -> None:
        status, result, error, progress = run.outcome
        if not self.store.finish(run.job_id, run.attempt, status, result=result, error=error, progress=progress):
            log.warning("job %s attempt %d: no longer its current run; its outcome is dropped", *run.key)

    def _tend(self, cancelled: set[tuple[str, int]]) -> None:
        """Each run: listen, enforce its limits, write its outcome (forgotten only once written)."""
        now = time.monotonic()
        fault: StoreError | None = None
        for key, run in list(self.runs.items()):
            self._listen(run)
            if run.outcome is None and now > run.until:
                log.warning("job %s attempt %d: past its time limit of %g s, stopped", *key, run.limit_s)
                run.proc.stop()
                run.outcome = ("failed", None, _time_limit(run.job_id, run.limit_s), run.progress)
            if run.outcome is None and key in cancelled:
                if run.cancel_at is None:
                    run.cancel_at = now
                    try:
                        run.proc.send(("stop",))
                    except Exception:  # noqa: BLE001 — it is ending anyway
                        pass
                elif now - run.cancel_at > self.settings.cancel_grace_s:
                    log.warning("job %s did not stop %.0f s after cancel: ending it", run.job_id,
                                self.settings.cancel_grace_s)
                    run.proc.stop()
                    run.outcome = ("cancelled", None, None, run.progress)
            try:
                if run.outcome is not None:
                    run.proc.stop()
                    self._write(run)
                    del self.runs[key]
                elif run.progress is not None and run.progress is not run.progress_written:
                    self.store.progress(run.job_id, run.attempt, run.progress)
                    run.progress_written = run.progress
            except StoreError as exc:  # the outcome is kept and written on a later pass
                fault = fault or exc
        if fault is not None:
            raise fault

    def _beat(self) -> None:
        now, lease_s = time.monotonic(), self.settings.job_lease_s
        if now - self._last_beat < lease_s / 3:
            return
        held = {k for k, r in self.runs.items() if r.outcome is None}
        still = self.store.heartbeat(self.replica, lease_s, held)
        self._last_beat = now
        for key in held - still:  # lost (this replica lost the database longer than the lease)
            run = self.runs.pop(key)
            log.warning("job %s attempt %d: lease lost, its run here is ended (the job runs elsewhere)", *key)
            run.proc.stop()
        if now - self._answering_since >= lease_s:  # not just after a fault (see the module docstring)
            requeued = self.store.reclaim(self.replica)
            if requeued:
                log.warning("re-queued %d job(s) whose replica's lease expired: %s", len(requeued),
                            ", ".join(requeued))
        if now - self._last_purge >= PURGE_EVERY_S:
            self._last_purge = now
            n = self.store.purge(self.settings.retention_days * 86400.0, self.storage_bytes)
            if n:
                log.info("retention: deleted %d finished job(s)", n)

    def _failed(self, exc: Exception) -> None:
        text = str(exc)
        if text != self.fault and not isinstance(exc, StoreError):  # the store logs its own faults
            log.exception("job dispatcher", exc_info=exc)
        self.fault = text

    def _loop(self) -> None:
        delay = POLL_S
        while not self._stop.is_set():
            ok = True
            cancelled: set[tuple[str, int]] = set()
            steps = [("cancels", lambda: cancelled.update(self.store.cancel_requested(self.replica)) if self.runs else None),
                     ("runs", lambda: self._tend(cancelled)), ("leases", self._beat), ("claims", self._claim)]
            for _, step in steps:  # each on its own: a fault in one does not hold the others back
                try:
                    step()
                except Exception as exc:  # noqa: BLE001 — keep dispatching; back off while the store is faulty
                    ok = False
                    self._failed(exc)
            if ok:
                self.fault = None
            if not ok:
                self._answering_since = math.inf
            elif self._answering_since == math.inf:
                self._answering_since = time.monotonic()
            delay = POLL_S if ok else min(2.0, max(delay * 2, 0.5))
            self._wake.wait(delay)
            self._wake.clear()

    def _claim(self) -> None:
        while len(self.runs) < self.settings.workers and not self._stop.is_set():
            claimed = self.store.claim(self.replica, self.settings.job_lease_s)
            if claimed is None:
                return
            self._launch(*claimed)
