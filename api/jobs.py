"""Optimization jobs: the dispatcher that runs them in worker processes, and the job itself.

:class:`JobRunner` lives in the server. A thread claims queued jobs from the :class:`JobStore`
and starts one ``python -m api.worker`` process per job, at most ``workers`` at once; it reaps
them, kills a cancelled job that outstays ``cancel_grace_s``, and on shutdown stops its
workers and puts their jobs back in the queue. Progress and results travel through the store
only, so a job is visible from any request thread and survives the server.

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

from excite.fleet.engine import SCHEDULER_ENV

from .store import JobStore

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
    """Runs queued jobs in worker processes (see the module docstring)."""

    def __init__(self, store: JobStore, workers: int, function: str, cancel_grace_s: float,
                 memory_mb: int, poll_s: float = 0.2, scheduler: str | None = None):
        self.store, self.workers, self.function = store, workers, function
        self.scheduler = scheduler  # a Dask scheduler the job processes submit to (api.cluster)
        self.cancel_grace_s, self.memory_mb, self.poll_s = cancel_grace_s, memory_mb, poll_s
        self._procs: dict[tuple[str, int], subprocess.Popen] = {}
        self._cancel_seen: dict[tuple[str, int], float] = {}
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self.requeued_at_start = 0

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def running(self) -> int:
        return len(self._procs)

    def start(self) -> None:
        requeued = self.store.recover()
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
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout_s + 5)
        for (job_id, attempt), proc in list(self._procs.items()):
            _terminate(proc, timeout_s)
            self.store.requeue(job_id, attempt)
        self._procs.clear()

    def _env(self) -> dict[str, str]:
        env = dict(os.environ)
        paths = [p for p in sys.path if p and os.path.isdir(p)]
        env["PYTHONPATH"] = os.pathsep.join(paths + [env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        env.pop(SCHEDULER_ENV, None)
        if self.scheduler:
            env[SCHEDULER_ENV] = self.scheduler
        return env

    def _launch(self, job_id: str, attempt: int) -> None:
        cmd = [sys.executable, "-m", "api.worker", str(self.store.path), job_id, str(attempt),
               self.function, str(os.getpid()), str(self.memory_mb)]
        self._procs[(job_id, attempt)] = subprocess.Popen(cmd, env=self._env(), stdin=subprocess.DEVNULL)
        log.info("job %s attempt %d started (pid %d)", job_id, attempt, self._procs[(job_id, attempt)].pid)

    def _reap(self) -> None:
        for key, proc in list(self._procs.items()):
            code = proc.poll()
            if code is None:
                continue
            del self._procs[key]
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

    def _enforce_cancel(self) -> None:
        flagged = self.store.cancel_requested_running() if self._procs else set()
        now = time.monotonic()
        for key in flagged:
            proc = self._procs.get(key)
            if proc is None:
                continue
            first = self._cancel_seen.setdefault(key, now)
            if now - first > self.cancel_grace_s and proc.poll() is None:
                log.warning("job %s did not stop %.0f s after cancel: killing it", key[0], self.cancel_grace_s)
                proc.kill()

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                self._reap()
                self._enforce_cancel()
                while len(self._procs) < self.workers and not self._stop.is_set():
                    claimed = self.store.claim()
                    if claimed is None:
                        break
                    self._launch(*claimed)
            except Exception:  # keep dispatching; the store may be briefly locked
                log.exception("job dispatcher")
            self._wake.wait(self.poll_s)
            self._wake.clear()


def _terminate(proc: subprocess.Popen, timeout_s: float) -> None:
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
