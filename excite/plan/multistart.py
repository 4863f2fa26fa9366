"""Several IPOPT starts on the engine (:mod:`excite.core.engine`: local processes or Dask).

Each start is a task (:class:`StartTask`, plain picklable data) that :func:`run_start` runs
anywhere excite is installed: it builds (or, in a process forked from the caller, finds) the
transcription, runs IPOPT from its start until it converges, its deadline passes or it is told to
stop, and sends back the best few iterates within the limits (:meth:`.solver.Outcome.best`).
:func:`run` submits them and, meanwhile, relays progress and cancellation through two small
files in a scratch folder (the task writes its latest iteration, the caller creates ``stop``):
so the caller's thread that reports progress is the one that asked for it, and a task on a
local process or on a Dask worker that shares the folder stops within one iteration. (A remote
Dask worker that cannot see the folder runs to its deadline.)
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..core import engine
from .problem import Problem
from .solver import Outcome, SolverOptions, solve
from .transcription import TranscriptionOptions, cached

KEEP = 15  # iterates a start sends back (the pipeline checks them best first)
POLL_S = 0.1


@dataclass(frozen=True)
class StartTask:
    """One IPOPT start: the problem, how it is transcribed and solved, the start ``z0`` (named
    ``name``), the wall-clock ``deadline`` (seconds since the epoch) and the scratch folder
    ``channel`` for progress and cancellation (None: neither)."""

    problem: Problem
    name: str
    z0: np.ndarray
    deadline: float
    transcription: TranscriptionOptions = TranscriptionOptions()
    solver: SolverOptions = SolverOptions()
    max_iterations: int | None = None
    channel: str | None = None
    index: int = 0


@dataclass
class StartResult:
    """What a start sends back: its name, IPOPT's outcome (the best iterates only), the seconds
    it ran, the compiled model's mode, and the error that ended it, if one did."""

    name: str
    outcome: Outcome | None
    seconds: float
    mode: str = ""
    error: str = ""
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def converged(self) -> bool:
        return self.outcome is not None and self.outcome.status == "converged"


def run_start(task: StartTask) -> StartResult:
    """Run one start (module level: the engine imports it by name)."""
    t0 = time.perf_counter()
    deadline = t0 + (task.deadline - time.time())
    stop_file = progress_file = None
    if task.channel is not None:
        stop_file = os.path.join(task.channel, "stop")
        progress_file = os.path.join(task.channel, f"progress_{task.index}")

    def should_stop() -> bool:
        return stop_file is not None and os.path.exists(stop_file)

    def progress(it: int, s: float, v: float, el: float, best: float) -> None:
        if progress_file is not None:
            tmp = progress_file + ".tmp"
            with open(tmp, "w") as f:
                f.write(f"{it} {s!r} {v!r}")
            os.replace(tmp, progress_file)

    try:
        tr = cached(task.problem, task.transcription)
        t1 = time.perf_counter()
        out = solve(tr, task.z0, deadline, task.problem.criterion, task.max_iterations, should_stop=should_stop,
                    progress=progress, options=task.solver)
    except Exception as exc:  # noqa: BLE001 — a start that fails is reported, the others stand
        return StartResult(task.name, None, time.perf_counter() - t0, error=f"{type(exc).__name__}: {exc}"[:300])
    return StartResult(task.name, out.best(KEEP), time.perf_counter() - t0, tr.info.mode,
                       timings_s={"transcription": t1 - t0, "solve": time.perf_counter() - t1})


def _failed(task: StartTask, exc: BaseException) -> StartResult:
    return StartResult(task.name, None, 0.0, error=f"the start's process died: {exc}"[:300])


def run(tasks: list[StartTask], jobs: int, scheduler: str | None = None,
        progress: Callable[[int, float, float], None] | None = None,
        should_stop: Callable[[], bool] | None = None) -> list[StartResult]:
    """Every task on the engine (``jobs`` local processes, or the Dask cluster at
    ``scheduler``), results in order. ``progress(iteration, best model value, violation)`` and
    ``should_stop()`` are called from this thread while the tasks run."""
    channel = tempfile.mkdtemp(prefix="excite-starts-")
    tasks = [StartTask(**{**t.__dict__, "channel": channel, "index": i}) for i, t in enumerate(tasks)]
    box: dict[str, Any] = {}

    def work() -> None:
        try:
            box["results"] = engine.run(run_start, tasks, failed=_failed, jobs=jobs, scheduler=scheduler)
        except BaseException as exc:  # noqa: BLE001 — re-raised in the caller's thread
            box["error"] = exc

    thread = threading.Thread(target=work, name="excite-starts", daemon=True)
    thread.start()
    stopped = False
    try:
        while thread.is_alive():
            thread.join(POLL_S)
            if not stopped and should_stop is not None and should_stop():
                Path(channel, "stop").touch()
                stopped = True
            if progress is not None:
                latest = _latest(channel, len(tasks))
                if latest is not None:
                    progress(*latest)
    finally:
        if thread.is_alive():  # interrupted: tell the starts, do not wait for them
            Path(channel, "stop").touch()
        else:
            shutil.rmtree(channel, ignore_errors=True)
    if "error" in box:
        raise box["error"]
    return box["results"]


def _latest(channel: str, n: int) -> tuple[int, float, float] | None:
    """The most advanced start's iteration and the best model value any start has reached."""
    best: tuple[int, float, float] | None = None
    for i in range(n):
        try:
            it, s, v = Path(channel, f"progress_{i}").read_text().split()
        except (OSError, ValueError):
            continue
        row = (int(it), float(s), float(v))
        if best is None:
            best = row
        else:
            best = (max(best[0], row[0]), max(best[1], row[1]), min(best[2], row[2]))
    return best
