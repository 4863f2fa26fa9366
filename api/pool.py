"""The scoring workers: processes whose work ends with its request, shared fairly between keys,
and admitted by the size of the work.

Each worker is a :class:`excite.core.processes.Worker` forked from a forkserver that preloaded
the evaluator (the server has threads, and forking it would copy held locks), with an
address-space limit (``RLIMIT_AS``: a task that needs more fails with a 413 inside it):

- a task runs until its request's deadline; past it the worker is killed with its tree and a
  fresh one started in the background, so the next request is served;
- after each task the worker returns freed heap to the system (``malloc_trim``) and, if its
  resident memory is still more than ``recycle_mb`` above what it was when it was ready, it
  exits and is replaced;
- **shares**: one key holds at most ``share`` of the workers at once (at least one; the service
  sets it below 1 when it has several keys), and the next worker goes to the waiting key with
  the fewest running tasks, then first come first served: one key's flood of hour-long routes
  holds its share, and another key's request finds a worker free;
- **admission by size**: each task comes with its size (seconds of drive) and the pool learns
  each kind of task's cost per unit of size (:meth:`WorkerPool._learn`: up at once, down
  gradually); work that this key's share of the workers could not finish by its deadline, or that
  would queue past ``max_queued`` tasks, is refused at once (:class:`~api.errors.Overloaded`: 429
  with Retry-After), and so is a waiting task as soon as it could no longer finish in time: a key
  that sends more than its share can do is answered 429, not left to time out.
"""

from __future__ import annotations

import concurrent.futures as cf
import ctypes
import itertools
import logging
import math
import multiprocessing
import multiprocessing.forkserver
import os
import threading
import time
from collections import defaultdict
from dataclasses import dataclass
from typing import Any, Callable

from excite.core.processes import Worker
from excite.errors import WorkerDied, WorkTimeout

from .errors import Overloaded

log = logging.getLogger("excite.api")

_BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
# A task is admitted when its expected finish is within this share of its time left: costs are
# recent averages, and a task that would finish just in time on average times out half the time.
ADMIT_SHARE = 0.7
RATE_FALL = 0.3  # a cost lower than the learned one moves it this share of the way down
WAIT_CHECK_S = 0.25  # a waiting task checks this often whether it can still finish in time
PRELOAD = ("excite.score.evaluate", "excite.io.routes", "excite.score.plots", "excite.score.live", "api.scoring",
           "api.routers.live")  # what a live session runs: loaded before its memory limit


def trim() -> None:
    """Return freed heap to the system."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass


SERVER_ARENAS = 2
_M_ARENA_MAX = -8  # glibc's mallopt parameter


def few_arenas(n: int = SERVER_ARENAS) -> bool:
    """At most ``n`` malloc arenas in this process (glibc; False elsewhere). The server's many
    threads (the request thread pool, the scoring pool's) each take an arena of their own by
    default, and freed memory scattered over them is not given back: the server's resident size
    rose through a soak while its Python heap (tracemalloc) stayed flat. Call before threads start."""
    try:
        return bool(ctypes.CDLL(None).mallopt(_M_ARENA_MAX, n))
    except (OSError, AttributeError):
        return False


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


class _Grown:
    """In a worker: :meth:`warm` it, then after each task trim the heap; True when it grew past
    ``recycle_mb`` since it was warm."""

    def __init__(self, recycle_mb: int, warm: Callable[[], Any] | None):
        self.recycle_mb, self.warm_up, self.baseline = recycle_mb, warm, 0.0

    def warm(self) -> None:
        if self.warm_up is not None:
            self.warm_up()
        trim()
        self.baseline = _rss_mb()

    def __call__(self) -> bool:
        trim()
        return bool(self.recycle_mb) and _rss_mb() - self.baseline > self.recycle_mb


_forkserver_lock = threading.Lock()


def forkserver(preload: tuple[str, ...] = PRELOAD) -> Any:
    """The forkserver context the scoring workers and live sessions are forked from, with one
    BLAS thread per process (the pool has a process per core; threaded BLAS on top halves
    throughput; an explicit setting by the operator wins)."""
    with _forkserver_lock:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(list(preload))
        saved = {k: os.environ.get(k) for k in _BLAS_THREADS}
        try:
            for k in _BLAS_THREADS:
                os.environ.setdefault(k, "1")
            multiprocessing.forkserver.ensure_running()
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
        return ctx


@dataclass(eq=False)
class _Task:
    key: str
    seq: int
    kind: str
    size: float
    deadline: float
    started: float | None = None  # time.monotonic() when a worker took it


class WorkerPool:
    """``workers`` processes; :meth:`submit` runs ``fn(*args)`` in one of them by a deadline, or
    refuses at once the work it cannot finish by then (see the module docstring)."""

    def __init__(self, workers: int, memory_mb: int, recycle_mb: int,
                 warm: Callable[[], Any] | None = None, start_timeout_s: float = 300.0,
                 max_queued: int = 16, share: float = 1.0):
        self.workers, self.memory_mb, self.recycle_mb = workers, memory_mb, recycle_mb
        self.max_queued, self.warm, self.start_timeout_s = max_queued, warm, start_timeout_s
        self.cap = max(1, math.floor(workers * share))  # workers one key holds while others wait
        self._cond = threading.Condition()
        self._idle: list[Worker] = []
        self._all: set[Worker] = set()
        self._waiting: list[_Task] = []
        self._running: dict[str, list[_Task]] = defaultdict(list)
        self._rate: dict[str, float] = {}  # seconds of work per unit of size, per kind of task
        self._seq = itertools.count()
        self._starting = 0
        self._closed = False
        self._started = False
        self._threads = cf.ThreadPoolExecutor(max(8, 4 * workers + max_queued), thread_name_prefix="score")

    @property
    def ready(self) -> bool:
        return self._started and not self._closed and bool(self._all)

    # -- workers ---------------------------------------------------------------------------

    def _spawn(self) -> None:
        if self._closed:
            return
        with self._cond:
            self._starting += 1
        try:
            w = Worker(warm=(grown := _Grown(self.recycle_mb, self.warm)).warm, after=grown,
                       context=forkserver(), memory_mb=self.memory_mb, name="excite-score",
                       start_deadline=time.monotonic() + self.start_timeout_s)
        finally:
            with self._cond:
                self._starting -= 1
        with self._cond:
            if self._closed:
                w.stop()
                return
            self._all.add(w)
            self._idle.append(w)
            self._cond.notify_all()

    def _replace(self, w: Worker, why: str) -> None:
        w.stop()
        with self._cond:
            self._all.discard(w)
        if self._closed:
            return
        log.warning("scoring worker %s replaced: %s", w.pid, why)

        def start() -> None:
            try:
                self._spawn()
            except Exception:  # noqa: BLE001
                if not self._closed:
                    log.exception("cannot start a scoring worker")

        threading.Thread(target=start, daemon=True, name="score-respawn").start()

    def start(self) -> None:
        threads = [threading.Thread(target=self._spawn) for _ in range(self.workers)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        if len(self._all) != self.workers:
            raise RuntimeError("the scoring workers did not start")
        self._started = True

    def close(self) -> None:
        with self._cond:
            self._closed = True
            workers, self._all, self._idle = list(self._all), set(), []
            self._cond.notify_all()
        for w in workers:
            w.stop()
        self._threads.shutdown(wait=False, cancel_futures=True)

    # -- scheduling ------------------------------------------------------------------------

    def _turn(self, task: _Task) -> bool:
        """Whether ``task`` takes the next idle worker (called with the lock held)."""
        if not self._idle:
            return False
        eligible = [t for t in self._waiting if len(self._running[t.key]) < self.cap]
        return bool(eligible) and min(eligible, key=lambda t: (len(self._running[t.key]), t.seq)) is task

    def _run(self, task: _Task, fn: Callable[..., Any], args: tuple, deadline: float, kind: str,
             size: float) -> Any:
        with self._cond:
            while True:
                left = deadline - time.monotonic()
                if left <= 0 or self._closed:
                    self._dequeue(task)
                    raise WorkTimeout("no scoring worker was free in time")
                cost = self._cost(kind, size)
                if cost > ADMIT_SHARE * left:  # what it costs now would not finish in time
                    self._dequeue(task)
                    raise Overloaded(f"this key's work ahead of this request took longer than expected, and its "
                                     f"~{cost:.0f} s would not finish within its time limit",
                                     int(min(60, max(1, math.ceil(cost)))))
                if self._turn(task):
                    break
                self._cond.wait(min(left, WAIT_CHECK_S))
            self._waiting.remove(task)
            w = self._idle.pop()
            task.started = time.monotonic()
            self._running[task.key].append(task)
        t0 = task.started
        try:
            return w.run(fn, *args, deadline=deadline)
        except WorkTimeout:
            self._replace(w, "its task outlived the request's deadline")
            raise
        except WorkerDied:
            self._replace(w, f"it died during a task (exit code {w.proc.exitcode})")
            raise
        finally:
            seconds = time.monotonic() - t0
            with self._cond:
                self._running[task.key].remove(task)
                if not self._running[task.key]:
                    del self._running[task.key]
                if size > 0 and not w.ending and (w.alive or seconds >= deadline - t0):
                    self._learn(kind, seconds / size)  # killed at its deadline: at least that
                if w.alive and not w.ending and w in self._all:
                    self._idle.append(w)
                self._cond.notify_all()
            if w.ending:  # replaced even when it has exited already (else the pool loses it)
                self._replace(w, f"its memory grew by more than {self.recycle_mb} MiB")

    def submit(self, fn: Callable[..., Any], calls: list[tuple], deadline: float, key: str = "",
               sizes: list[float] | None = None) -> list[cf.Future]:
        """``fn(*args)`` for each ``args`` of ``calls`` (of ``sizes``: seconds of drive, 1 when
        unknown), all admitted or none (see the module docstring)."""
        kind = f"{fn.__module__}.{fn.__qualname__}"
        sizes = sizes or [1.0] * len(calls)
        with self._cond:
            costs = [self._cost(kind, s) for s in sizes]
            now = time.monotonic()
            cap = self.cap
            mine_waiting = [t for t in self._waiting if t.key == key]
            mine_running = self._running.get(key, [])
            free = len(self._idle) - len(self._waiting)
            # what this key's share does before this request's tasks, at what each costs now
            ahead = sum(self._cost(t.kind, t.size) for t in mine_waiting + mine_running)
            wait = ahead / cap if len(calls) > max(0, min(free, cap - len(mine_running) - len(mine_waiting))) else 0.0
            finish = wait + sum(costs) / min(cap, len(calls))
            retry = int(min(60, max(1, math.ceil(finish))))
            if len(calls) > max(0, free) and len(self._waiting) + len(calls) > self.max_queued + max(0, free):
                raise Overloaded(f"all {self.workers} scoring workers are busy and {len(self._waiting)} "
                                 f"tasks are waiting (at most {self.max_queued})", retry)
            if finish > ADMIT_SHARE * (deadline - now):
                raise Overloaded(f"this key's share of the scoring workers ({cap} of {self.workers}) "
                                 f"holds ~{wait:.0f} s of its work, and this request's ~{finish - wait:.0f} s "
                                 "would not finish within its time limit", retry)
            tasks = [_Task(key, next(self._seq), kind, s, deadline) for s in sizes]
            self._waiting.extend(tasks)
        futures = [self._threads.submit(self._run, t, fn, args, deadline, kind, s)
                   for t, args, s in zip(tasks, calls, sizes)]
        for t, f in zip(tasks, futures):
            f.add_done_callback(lambda f, t=t: f.cancelled() and self._dequeue(t))
        return futures

    def _dequeue(self, task: _Task) -> None:
        """``task`` waits no more (its future was cancelled, or it was refused)."""
        with self._cond:
            if task in self._waiting:
                self._waiting.remove(task)
                self._cond.notify_all()

    def _learn(self, kind: str, rate: float) -> None:
        """A task of ``kind`` took ``rate`` seconds per unit of size: a higher cost is taken at
        once, a lower one gradually (called with the lock held)."""
        old = self._rate.get(kind)
        self._rate[kind] = rate if old is None or rate >= old else old + RATE_FALL * (rate - old)

    def _cost(self, kind: str, size: float) -> float:
        """The expected seconds of a task of ``kind`` on work of ``size`` now: the learned cost per
        unit, or more when a running task of that kind has already taken longer (0 until one ran;
        called with the lock held)."""
        now = time.monotonic()
        rate = max([self._rate.get(kind, 0.0)] + [(now - t.started) / t.size for ts in self._running.values()
                                                  for t in ts if t.kind == kind and t.size > 0])
        return rate * size
