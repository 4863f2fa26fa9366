"""Optimization jobs: the dispatcher that runs them in worker processes, and the job itself.

:class:`JobRunner` lives in each server (replica). A thread claims queued jobs from the
:class:`~api.store.JobStore` (fairly across keys, each with a lease) and starts one
``python -m api.worker`` process tree per job, at most ``workers`` at once; it renews the leases
of its jobs (a heartbeat), re-queues the jobs of replicas whose leases expired, reaps its job
processes, stops a cancelled job that outstays ``cancel_grace_s`` and a job past its hard time
limit (the process tree with it), purges finished jobs by the retention policy, and on shutdown
stops its job processes and puts their jobs back in the queue. Progress and results travel
through the store only, so a job is visible from any replica and survives the server.

A fault of the store is logged once when it starts and once when it ends (not at every poll),
and :attr:`JobRunner.fault` names it for ``/readyz``.

:func:`run_optimization` is the default job: :func:`excite.plan.optimize` on the request,
returning plain JSON data (the report, the comparison and the control profile for downloads).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import signal
import subprocess
import sys
import threading
import time
from typing import Any, Callable

import numpy as np

from excite.core.engine import SCHEDULER_ENV

from .errors import StoreError
from .store import JobStore, replica_id
from .worker import STORE_ENV

log = logging.getLogger("excite.api")


def plain(x: Any) -> Any:
    """JSON-ready data: numpy to Python, dataclasses to dicts, non-finite floats to None."""
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        x = {f.name: getattr(x, f.name) for f in dataclasses.fields(x)}
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def profile_data(profile: Any) -> dict[str, Any]:
    """A ControlProfile as JSON data (what the downloads are rebuilt from)."""
    return plain({"t_s": profile.t_s, "speed_mps": profile.speed_mps,
                  "curvature_1pm": profile.curvature_1pm, "grade_rad": profile.grade_rad,
                  "bank_rad": profile.bank_rad, "start": list(profile.start), "name": profile.name})


def run_optimization(request: dict[str, Any], progress: Callable[[dict[str, Any]], None],
                     should_stop: Callable[[], bool]) -> dict[str, Any]:
    """The default job: plan a maneuver for a :class:`~api.schemas.ManeuverRequest` (as data)."""
    from excite.plan import OptimizeSettings, optimize
    from excite.plan.site import read_site
    from excite.motion.vehicle import Limits

    from .errors import Rejected
    from .scoring import resolve_rig

    try:
        rig = resolve_rig(request["rig"])
    except Rejected as exc:
        from excite.errors import RigError

        raise RigError(f"{exc.field}: {exc.message}") from None
    settings = OptimizeSettings(
        duration_s=request["duration_s"], lot_x_m=request["lot_x_m"],
        lot_y_m=request["lot_y_m"], limits=Limits(**request["limits"]),
        seed=request["seed"], time_budget_s=request["time_budget_s"], closed=request["closed"],
        n_random=request["n_random"], criterion=request.get("criterion", "E"),
        site=read_site(request["lot"]) if request.get("lot") else None)
    res = optimize(rig, settings, lambda p: progress(plain(p)), should_stop)
    out = plain(res.to_dict())
    out["report"]["route"] = request.get("name") or out["report"].get("route")
    origin = settings.lot.origin  # a georeferenced lot: GeoJSON downloads need no origin
    return {**out, "profile": profile_data(res.profile),
            "origin": None if origin is None else {"lon_deg": origin[0], "lat_deg": origin[1]}}




class JobRunner:
    """Runs queued jobs in worker process trees (see the module docstring)."""

    def __init__(self, store: JobStore, workers: int, function: str, cancel_grace_s: float,
                 memory_mb: int, poll_s: float = 0.2, scheduler: str | None = None,
                 lease_s: float = 30.0, time_reserve_s: float = 60.0, max_time_budget_s: float = 900.0,
                 retention_s: float = 7 * 86400.0, retention_bytes: int = 1 << 30,
                 purge_every_s: float = 60.0):
        self.store, self.workers, self.function = store, workers, function
        self.scheduler = scheduler  # a Dask scheduler the job processes submit to (api.cluster)
        self.cancel_grace_s, self.memory_mb, self.poll_s = cancel_grace_s, memory_mb, poll_s
        self.lease_s, self.time_reserve_s, self.max_time_budget_s = lease_s, time_reserve_s, max_time_budget_s
        self.retention_s, self.retention_bytes, self.purge_every_s = retention_s, retention_bytes, purge_every_s
        self.replica = replica_id()
        self._procs: dict[tuple[str, int], subprocess.Popen] = {}
        self._limits: dict[tuple[str, int], float] = {}  # monotonic deadline of each run
        self._cancel_seen: dict[tuple[str, int], float] = {}
        self._termed: dict[tuple[str, int], float] = {}  # SIGTERM sent to the supervisor at
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_beat = 0.0
        self._last_purge = 0.0
        self.fault: str | None = None  # the store's current fault, for /readyz
        self.requeued_at_start = 0
        self.purged = 0

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def running(self) -> int:
        return len(self._procs)

    def pids(self) -> list[int]:
        """The supervisors of the jobs running here (each leads its job's process group)."""
        return [p.pid for p in self._procs.values()]

    def start(self) -> None:
        try:
            requeued = self.store.reclaim(self.replica)
        except StoreError as exc:
            self._store_failed(exc)
            requeued = []
        self.requeued_at_start = len(requeued)
        if requeued:
            log.warning("re-queued %d job(s) left running by a previous server: %s",
                        len(requeued), ", ".join(requeued))
        self._thread = threading.Thread(target=self._loop, name="excite-jobs", daemon=True)
        self._thread.start()

    def wake(self) -> None:
        """A job was queued or cancelled: look now rather than at the next poll."""
        self._wake.set()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop dispatching, end every job process tree here and put the jobs back in the queue."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout_s + 5)
        procs = list(self._procs.items())
        for _, proc in procs:
            _signal(proc, signal.SIGTERM)  # the supervisor kills its tree and exits
        deadline = time.monotonic() + timeout_s
        for key, proc in procs:
            try:
                proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                _kill_group(proc)
                proc.wait()
            try:
                self.store.release(*key)
            except StoreError as exc:
                log.error("job %s not released at shutdown (its lease will expire): %s", key[0], exc)
        self._procs.clear()

    def _env(self) -> dict[str, str]:
        env = dict(os.environ)
        paths = [p for p in sys.path if p and os.path.isdir(p)]
        env["PYTHONPATH"] = os.pathsep.join(paths + [env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        env.pop(SCHEDULER_ENV, None)
        if self.scheduler:
            env[SCHEDULER_ENV] = self.scheduler
        env[STORE_ENV] = self.store.url
        # a job uses a compiled model the cache holds (the image's build step compiles one), but
        # does not start the compiler: a background compile is detached and would outlive the job
        env.setdefault("EXCITE_COMPILE", "0")
        return env

    def time_limit_s(self, request: dict[str, Any] | None) -> float:
        """A run's hard wall-clock limit: its time budget plus the reserve."""
        budget = (request or {}).get("time_budget_s", self.max_time_budget_s)
        try:
            budget = min(float(budget), self.max_time_budget_s)
        except (TypeError, ValueError):
            budget = self.max_time_budget_s
        return budget + self.time_reserve_s

    def _launch(self, job_id: str, attempt: int) -> None:
        limit = self.time_limit_s(self.store.running_request(job_id, attempt))
        cmd = [sys.executable, "-m", "api.worker", job_id, str(attempt), self.function,
               str(os.getpid()), str(self.memory_mb), repr(limit)]
        key = (job_id, attempt)
        self._procs[key] = subprocess.Popen(cmd, env=self._env(), stdin=subprocess.DEVNULL,
                                            start_new_session=True)
        self._limits[key] = time.monotonic() + limit
        log.info("job %s attempt %d started (pid %d)", job_id, attempt, self._procs[key].pid)

    def _forget(self, key: tuple[str, int]) -> None:
        self._procs.pop(key, None)
        self._limits.pop(key, None)
        self._termed.pop(key, None)

    def _reap(self) -> None:
        for key, proc in list(self._procs.items()):
            code = proc.poll()
            if code is None:
                continue
            _kill_group(proc)  # anything left in the job's group ends with it
            self._forget(key)
            killed_for_cancel = self._cancel_seen.pop(key, None) is not None
            job = self.store.get(key[0])
            if job is None or job["status"] != "running" or job["attempt"] != key[1]:
                continue
            if killed_for_cancel and code != 0:
                self.store.finish(*key, "cancelled")
            else:  # the worker died without writing its result (crash, memory, signal)
                log.error("job %s attempt %d: worker exited with code %s", key[0], key[1], code)
                self.store.finish(*key, "failed", error={
                    "type": "https://excite.dev/problems/internal", "title": "Internal server error",
                    "status": 500, "detail": f"the worker process ended unexpectedly (exit code {code})",
                    "instance": f"/v1/jobs/{key[0]}"})

    def _enforce(self) -> None:
        """Cancelled jobs past their grace and runs past their hard limit (with a margin: the
        supervisor enforces the limit itself) are stopped, their whole process tree with them."""
        flagged = self.store.cancel_requested_running(self.replica) if self._procs else set()
        now = time.monotonic()
        for key in flagged:
            if key in self._procs:
                first = self._cancel_seen.setdefault(key, now)
                if now - first > self.cancel_grace_s and key not in self._termed:
                    log.warning("job %s did not stop %.0f s after cancel: killing it", key[0],
                                self.cancel_grace_s)
                    self._terminate(key)
        for key, deadline in list(self._limits.items()):
            if now > deadline + 30 and key not in self._termed:
                log.warning("job %s attempt %d outran its time limit: killing it", *key)
                self._terminate(key)
        for key, at in list(self._termed.items()):  # the supervisor did not end: the group goes
            if now - at > 5 and key in self._procs:
                _kill_group(self._procs[key])

    def _terminate(self, key: tuple[str, int]) -> None:
        self._termed[key] = time.monotonic()
        _signal(self._procs[key], signal.SIGTERM)

    def _beat(self) -> None:
        now = time.monotonic()
        if now - self._last_beat < self.lease_s / 3:
            return
        self._last_beat = now
        held = self.store.heartbeat(self.replica, self.lease_s)
        for key in list(self._procs):
            if key not in held and key not in self._termed:
                # the lease was lost (this replica lost the database longer than the lease, or the
                # job finished): another replica may run it now
                job = self.store.get(key[0])
                if job is not None and job["status"] == "running":
                    log.warning("job %s attempt %d: lease lost, stopping its run here", *key)
                    self._terminate(key)
        requeued = self.store.reclaim(self.replica)
        if requeued:
            log.warning("re-queued %d job(s) whose replica's lease expired: %s", len(requeued),
                        ", ".join(requeued))
        if now - self._last_purge >= self.purge_every_s:
            self._last_purge = now
            n = self.store.purge(self.retention_s, self.retention_bytes)
            self.purged += n
            if n:
                log.info("retention: deleted %d finished job(s)", n)

    def _store_failed(self, exc: Exception) -> None:
        text = str(exc)
        if text != self.fault:
            if isinstance(exc, StoreError):
                log.error("job store fault: %s", text)
            else:
                log.exception("job dispatcher")
        self.fault = text

    def _loop(self) -> None:
        delay = self.poll_s
        while not self._stop.is_set():
            try:
                self._reap()
                self._enforce()
                self._beat()
                while len(self._procs) < self.workers and not self._stop.is_set():
                    claimed = self.store.claim(self.replica, self.lease_s)
                    if claimed is None:
                        break
                    self._launch(*claimed)
                if self.fault is not None:
                    log.warning("job store answers again")
                    self.fault = None
                delay = self.poll_s
            except Exception as exc:  # keep dispatching; back off while the store is faulty
                self._store_failed(exc)
                delay = min(5.0, max(delay * 2, 0.5))
            self._wake.wait(delay)
            self._wake.clear()


def _signal(proc: subprocess.Popen, sig: int) -> None:
    if proc.poll() is None:
        try:
            proc.send_signal(sig)
        except ProcessLookupError:
            pass


def _kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL the job's process group (the supervisor leads it)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
