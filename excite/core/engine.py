"""Where many independent tasks run: a Dask cluster when one is configured, local processes
otherwise.

:func:`run` applies a module-level function to every item and returns the results in order,
calling ``on_result`` as each one finishes (progress bars). With a scheduler address
(``--scheduler tcp://host:8786`` or :data:`SCHEDULER_ENV`) the tasks are submitted to that
Dask cluster: its workers need excite installed and must reach the inputs the items name (file
paths on shared storage, or the bytes themselves for small inputs); results come back pickled.
Workers should be started with Dask's ``MALLOC_TRIM_THRESHOLD_`` unset
(:data:`WORKER_CONFIG`): Dask's nanny sets it to 64 KiB by default, which fixes glibc's
thresholds, so every large array is mapped and unmapped afresh; the evaluation then runs 1.7–2.6×
slower than in a local process (``benchmarks/bench_mine.py``). :func:`run` logs a warning when the
workers it gets have it set. A task whose worker dies is re-run by the scheduler on another worker (Dask's
``allowed-failures``, 3 by default); one that keeps killing workers comes back as
``failed(item, error)``, like a task whose process died in the local pool. Without a scheduler
the tasks run on a process pool forked from this one (one per core by default; ``jobs=1`` runs
them in this process).
"""

from __future__ import annotations

import math
import multiprocessing
import os
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence, TypeVar

from . import processes
from ..errors import EngineError

SCHEDULER_ENV = "EXCITE_DASK_SCHEDULER"
CONNECT_TIMEOUT_S = 10.0
WORKER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
"""The Dask configuration excite's workers want (``dask.config.set(WORKER_CONFIG)`` around a
``LocalCluster``; for ``dask worker``, the same key in a Dask YAML config file: README)."""
_TRIM = "MALLOC_TRIM_THRESHOLD_"

I = TypeVar("I")
R = TypeVar("R")


def scheduler_address(explicit: str | None = None) -> str | None:
    """The Dask scheduler to use: ``explicit``, else :data:`SCHEDULER_ENV`, else None (local)."""
    address = explicit if explicit is not None else os.environ.get(SCHEDULER_ENV) or None
    if address is not None and "://" not in address and ":" not in address:
        raise EngineError(f"--scheduler: expected an address such as tcp://host:8786, got {address!r}")
    return address


@dataclass(frozen=True)
class Progress:
    """Tasks done of ``total``, with the time spent and a linear estimate of the time left."""

    done: int
    total: int
    elapsed_s: float

    @property
    def eta_s(self) -> float | None:
        if self.done == 0:
            return None
        return self.elapsed_s / self.done * (self.total - self.done)

    def to_dict(self) -> dict[str, Any]:
        eta = self.eta_s
        return {"done": self.done, "total": self.total, "elapsed_s": round(self.elapsed_s, 3),
                "eta_s": None if eta is None or not math.isfinite(eta) else round(eta, 3)}


def run(fn: Callable[[I], R], items: Sequence[I], *, failed: Callable[[I, BaseException], R],
        jobs: int | None = None, scheduler: str | None = None,
        on_result: Callable[[int, R, Progress], None] | None = None) -> list[R]:
    """``fn(item)`` for every item, results in order (see the module docstring). ``fn`` must be
    importable by name (a module-level function) and should report its own errors in its result;
    ``failed`` builds the result of a task that could not run (its worker or process died)."""
    address = scheduler_address(scheduler)
    if jobs is not None and jobs < 1:
        raise EngineError(f"--jobs must be ≥ 1, got {jobs}")
    results: list[Any] = [None] * len(items)
    t0 = time.perf_counter()
    done = 0

    def finish(i: int, r: R) -> None:
        nonlocal done
        results[i] = r
        done += 1
        if on_result:
            on_result(i, r, Progress(done, len(items), time.perf_counter() - t0))

    if not items:
        return []
    if address is not None:
        _run_dask(fn, items, failed, address, finish)
        return results
    jobs = min(jobs or os.cpu_count() or 1, len(items))
    if jobs <= 1:
        for i, item in enumerate(items):
            finish(i, fn(item))
        return results
    # fork on Linux: workers start in milliseconds with excite already imported; elsewhere the
    # platform default. Each is a supervised process (excite.core.processes): interrupted, or
    # when this process exits, the workers and what they started end with it.
    processes.map_ordered(fn, items, jobs, failed=failed, on_result=finish,
                          context="fork" if sys.platform == "linux" else multiprocessing.get_context())
    return results


def client(address: str) -> Any:
    """A Dask client connected to ``address`` (:class:`EngineError` when it cannot be reached)."""
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover - a runtime dependency
        raise EngineError("the Dask scheduler needs the package 'distributed' (pip install "
                          "'dask[distributed]')") from None
    try:
        return Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise EngineError(f"cannot reach the Dask scheduler at {address}: {exc}") from None


def _trim_threshold() -> str | None:
    """(On a worker) glibc's trim threshold as the environment fixes it, if it does."""
    return os.environ.get(_TRIM)


def slow_workers(settings: dict[str, str | None]) -> str | None:
    """The warning for workers (address → their ``MALLOC_TRIM_THRESHOLD_``) that run with the
    threshold fixed, or None."""
    slow = sorted(w for w, v in settings.items() if v is not None)
    if not slow:
        return None
    value = settings[slow[0]]
    return (f"excite: warning: {len(slow)} of {len(settings)} Dask workers run with {_TRIM}={value}"
            f"{' (Dask’s default)' if value == '65536' else ''}, which makes excite's evaluation about 2x "
            f"slower: start them with distributed.nanny.pre-spawn-environ.{_TRIM} set to null (README: "
            f"On a Dask cluster)")


def check_workers(c: Any) -> None:
    """Log :func:`slow_workers`' warning for the workers of client ``c`` (one line on stderr
    from a command; the service's log)."""
    import logging

    try:
        message = slow_workers(c.run(_trim_threshold))
    except Exception:  # a worker that cannot answer is not a reason to fail the work
        return
    if message:
        logging.getLogger("excite.core.engine").warning(message)


def _run_dask(fn: Callable[[I], R], items: Sequence[I], failed: Callable[[I, BaseException], R],
              address: str, finish: Callable[[int, R], None]) -> None:
    from distributed import as_completed as dask_completed

    with client(address) as c, c.as_current():
        check_workers(c)
        futures = c.map(fn, list(items), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in dask_completed(futures):
            i = index[fut.key]
            try:
                r = fut.result()
            except Exception as exc:  # lost with more workers than allowed (KilledWorker)
                r = failed(items[i], exc)
            finish(i, r)
            fut.release()
