"""Scoring processes whose work ends with its request: a worker that outlives its deadline is
killed and replaced, and a worker that grew is replaced after its task.

A process pool from the standard library cannot stop one task: a timed-out request would leave
its worker computing (minutes, gigabytes) while later requests queue behind it. Here each worker
is a process with a pipe of its own, lent to one task at a time:

- the task runs until the request's deadline; past it the worker is killed (SIGKILL) and a
  fresh one is started in the background, so the next request is served;
- each worker has an address-space limit (``RLIMIT_AS``): a task that needs more fails with a
  413 inside the worker instead of taking the machine's memory;
- after each task the worker returns freed heap to the system (``malloc_trim``) and, if its
  resident memory is still more than ``recycle_mb`` above what it was when it was ready, it
  exits and is replaced: the memory of one large route is not kept;
- when every worker is busy, work that would queue past ``max_queued`` tasks or could not
  finish by its deadline (by the recent cost of the work ahead) is refused at once
  (:class:`Overloaded`: the service answers 429 with Retry-After) rather than timed out later.

Workers are forked from a forkserver that preloaded the evaluator (the server has threads, and
forking it would copy held locks); pipes hold no named semaphores, so nothing leaks at shutdown.
"""

from __future__ import annotations

import concurrent.futures as cf
import ctypes
import logging
import math
import multiprocessing
import multiprocessing.forkserver
import os
import queue
import resource
import threading
import time
from multiprocessing.connection import Connection
from typing import Any, Callable
from .errors import Overloaded, Unsendable, WorkTimeout, WorkerDied

log = logging.getLogger("excite.api")

_BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
# A task is admitted when its expected finish is within this share of its time left: costs are
# recent averages, and a task that would finish just in time on average times out half the time.
ADMIT_SHARE = 0.7


# --------------------------------------------------------------------------------------------
# Inside a worker


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


def limit_memory(memory_mb: int) -> None:
    """This process's address space at most ``memory_mb`` MiB (0: no limit)."""
    if memory_mb:
        limit = memory_mb * 2**20
        try:
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        except (ValueError, OSError):
            log.warning("cannot limit worker memory to %d MiB", memory_mb)


def trim() -> None:
    """Return freed heap to the system."""
    _trim()


def _trim() -> None:
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass


def exit_with_server(server_pid: int, period_s: float = 1.0) -> None:
    """End this worker once the server process is gone (e.g. killed with SIGKILL): an orphan
    would otherwise wait for work forever, and keep the forkserver alive with it."""
    while True:
        time.sleep(period_s)
        try:
            os.kill(server_pid, 0)
        except (ProcessLookupError, PermissionError):  # gone, or the pid is another user's now
            os._exit(0)


def _worker_main(conn: Connection, memory_mb: int, recycle_mb: int, server_pid: int,
                 warm: Callable[[], Any] | None) -> None:
    threading.Thread(target=exit_with_server, args=(server_pid,), daemon=True,
                     name="server-watch").start()
    limit_memory(memory_mb)
    if warm is not None:
        warm()
    _trim()
    baseline = _rss_mb()
    conn.send(("ready", baseline))
    while True:
        try:
            fn, args = conn.recv()
        except (EOFError, OSError):
            return
        try:
            out: Any = ("ok", fn(*args))
        except MemoryError:
            out = ("memory", None)
        except Exception as exc:  # tasks return problems as data; anything else is a bug
            log.exception("task failed")
            out = ("error", repr(exc))
        _trim()
        grown = recycle_mb and _rss_mb() - baseline > recycle_mb
        conn.send((out, bool(grown)))
        if grown:
            return


# --------------------------------------------------------------------------------------------
# In the server


class _Worker:
    def __init__(self, proc: multiprocessing.process.BaseProcess, conn: Connection):
        self.proc, self.conn = proc, conn
        self._killed = threading.Lock()

    def kill(self) -> None:
        """Idempotent and safe from several threads at once: a request thread past its deadline
        and the pool's shutdown may both kill the same worker, and closing its pipe twice would
        close whatever file now has that descriptor."""
        if not self._killed.acquire(blocking=False):
            return
        try:
            self.proc.kill()
            self.proc.join(5)
        except (OSError, ValueError, AssertionError):
            pass
        self.conn.close()


class WorkerPool:
    """``workers`` processes; :meth:`submit_all` runs ``fn(*args)`` in one of them by a deadline,
    or refuses at once the work it cannot finish by then."""

    def __init__(self, workers: int, memory_mb: int, recycle_mb: int,
                 warm: Callable[[], Any] | None = None, start_timeout_s: float = 300.0,
                 max_queued: int = 16,
                 preload: tuple[str, ...] = ("excite.score.evaluate", "excite.io.routes", "excite.score.plots", "api.scoring")):
        self.workers, self.memory_mb, self.recycle_mb = workers, memory_mb, recycle_mb
        self.max_queued, self.preload = max_queued, list(preload)
        # admission: tasks waiting for a worker, and the seconds of work queued and running
        # by the recent cost of each task function (see :meth:`submit_all`)
        self._waiting = 0
        self._queued_s = 0.0
        self._running_s = 0.0
        self._cost_s: dict[str, float] = {}
        self._starting: dict[object, float] = {}  # workers warming up → when they started
        self._start_s = 0.0  # how long the last one took to start
        self.shed = 0  # tasks refused as overloaded (for tests and metrics)
        self.warm, self.start_timeout_s = warm, start_timeout_s
        self._idle: queue.Queue[_Worker] = queue.Queue()
        self._all: set[_Worker] = set()
        self._lock = threading.Lock()
        self._closed = False
        self._started = False
        self._ctx: Any = None
        self._threads = cf.ThreadPoolExecutor(max(8, 4 * workers), thread_name_prefix="score")
        self.killed = 0  # workers killed past a deadline (for tests and metrics)
        self.recycled = 0  # workers replaced after growing

    @property
    def ready(self) -> bool:
        return self._started and not self._closed and bool(self._all)

    def context(self) -> Any:
        """The forkserver context the workers (and live sessions) are started from."""
        return self._context()

    def _context(self) -> Any:
        if self._ctx is None:
            ctx = multiprocessing.get_context("forkserver")
            ctx.set_forkserver_preload(self.preload)
            # One BLAS thread per worker: the pool already has a process per core, and threaded
            # BLAS on top halves throughput. The forkserver reads the environment once, when it
            # starts; an explicit setting by the operator wins.
            saved = {k: os.environ.get(k) for k in _BLAS_THREADS}
            try:
                for k in _BLAS_THREADS:
                    os.environ.setdefault(k, "1")
                multiprocessing.forkserver.ensure_running()
            finally:
                for k, v in saved.items():
                    if v is None:
                        os.environ.pop(k, None)
            self._ctx = ctx
        return self._ctx

    def _spawn(self) -> None:
        """Start one worker, wait until it is warm, and lend it out."""
        if self._closed:
            return
        t0 = time.monotonic()
        token = object()
        with self._lock:
            self._starting[token] = t0
        try:
            self._start_one()
        finally:
            with self._lock:
                del self._starting[token]
        self._start_s = time.monotonic() - t0

    def _start_one(self) -> None:
        ctx = self._context()
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=_worker_main, daemon=True, name="excite-score",
                           args=(child, self.memory_mb, self.recycle_mb, os.getpid(), self.warm))
        proc.start()
        child.close()
        w = _Worker(proc, parent)
        if not parent.poll(self.start_timeout_s):
            w.kill()
            raise RuntimeError("a scoring worker did not start")
        try:
            parent.recv()
        except (EOFError, OSError):
            w.kill()
            raise RuntimeError("a scoring worker died while starting") from None
        with self._lock:
            if self._closed:
                w.kill()
                return
            self._all.add(w)
        self._idle.put(w)

    def _replace(self, w: _Worker, why: str) -> None:
        with self._lock:
            self._all.discard(w)
        w.kill()
        if self._closed:
            return
        log.warning("scoring worker %s replaced: %s", w.proc.pid, why)

        def start() -> None:
            try:
                self._spawn()
            except Exception:
                if not self._closed:  # at shutdown the forkserver may be gone first
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

    def _run(self, fn: Callable[..., Any], args: tuple, deadline: float, cost: float) -> Any:
        """``fn(*args)`` in a worker by ``deadline`` (monotonic); :meth:`submit_all` counted the
        task as waiting, with ``cost`` seconds of work."""
        try:
            w = self._idle.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            raise WorkTimeout from None
        finally:
            self._unqueue(cost)
        with self._lock:
            self._running_s += cost
        t0 = time.monotonic()
        try:
            value = self._run_on(w, fn, args, deadline)
        finally:
            with self._lock:
                self._running_s -= cost
        seconds = time.monotonic() - t0
        with self._lock:  # the recent cost of this kind of task (exponential average)
            key = fn.__qualname__
            old = self._cost_s.get(key)
            self._cost_s[key] = seconds if old is None else 0.7 * old + 0.3 * seconds
        return value

    def _cost(self, fn: Callable[..., Any]) -> float:
        return self._cost_s.get(fn.__qualname__, 0.0)

    def _unqueue(self, cost: float) -> None:
        with self._lock:
            self._waiting -= 1
            self._queued_s -= cost

    def _run_on(self, w: _Worker, fn: Callable[..., Any], args: tuple, deadline: float) -> Any:
        while True:
            if w is None:
                try:
                    w = self._idle.get(timeout=max(0.0, deadline - time.monotonic()))
                except queue.Empty:
                    raise WorkTimeout from None
            try:
                w.conn.send((fn, args))
            except (RecursionError, TypeError, ValueError) as exc:  # pickling: nothing was written
                self._idle.put(w)
                raise Unsendable(str(exc)) from None
            except OSError:  # the worker died while idle: take another
                self._replace(w, "found dead")
                w = None
                continue
            break
        if not w.conn.poll(max(0.0, deadline - time.monotonic())):
            self.killed += 1
            self._replace(w, "its task outlived the request's deadline")
            raise WorkTimeout
        try:
            (kind, value), grown = w.conn.recv()
        except (EOFError, OSError):
            self._replace(w, f"it died during a task (exit code {w.proc.exitcode})")
            raise WorkerDied from None
        if grown:
            self.recycled += 1
            self._replace(w, f"its memory grew by more than {self.recycle_mb} MiB")
        else:
            self._idle.put(w)
        if kind == "memory":
            raise MemoryError
        if kind == "error":
            raise RuntimeError(value)
        return value

    def submit_all(self, fn: Callable[..., Any], calls: list[tuple], deadline: float) -> list[cf.Future]:
        """``fn(*args)`` for each ``args`` of ``calls``, all admitted or none.

        Refused with :class:`Overloaded` when the tasks cannot all start at once and either the
        queue would exceed ``max_queued`` tasks or the work already queued and running (by the
        recent cost of each kind of task) would keep them from finishing by ``deadline``: a
        client then hears at once when to retry, instead of a timeout after the whole wait.
        """
        n = len(calls)
        with self._lock:
            cost = self._cost(fn)
            free = max(0, self._idle.qsize() - self._waiting)
            if n > free:
                # seconds until a worker is free for each of ours: the queued and the running
                # work (as if it had just begun: on a loaded machine tasks take longer than
                # their average) and the warm-up of replacements, shared by the workers
                now = time.monotonic()
                warming = sum(max(0.0, self._start_s - (now - t)) for t in self._starting.values())
                wait = (self._queued_s + self._running_s + warming) / self.workers
                finish = wait + cost * math.ceil(n / self.workers)
                retry = int(min(60, max(1, math.ceil(wait))))
                if self._waiting and self._waiting + n > self.max_queued:
                    self.shed += 1
                    raise Overloaded(f"all {self.workers} scoring workers are busy and "
                                     f"{self._waiting} tasks are waiting (at most {self.max_queued})",
                                     retry)
                if finish > ADMIT_SHARE * (deadline - now):
                    self.shed += 1
                    raise Overloaded(f"all {self.workers} scoring workers are busy: the work queued "
                                     f"ahead would take ~{wait:.0f} s, past this request's time limit",
                                     retry)
            self._waiting += n
            self._queued_s += n * cost
        futures = [self._threads.submit(self._run, fn, args, deadline, cost) for args in calls]
        for f in futures:  # cancelled before it ran (its request ended): no longer waiting
            f.add_done_callback(lambda f: f.cancelled() and self._unqueue(cost))
        return futures

    def pids(self) -> list[int]:
        with self._lock:
            return [w.proc.pid for w in self._all if w.proc.pid is not None]

    def close(self) -> None:
        with self._lock:
            self._closed = True
            workers, self._all = list(self._all), set()
        for w in workers:
            w.kill()
        self._threads.shutdown(wait=False, cancel_futures=True)
