"""excite's one way to run work in a process of its own: :class:`Supervised`.

Every helper process excite starts (the optimizer's comparison worker, the local engine's
workers, the service's jobs, scoring workers and live sessions) is one of these, and each keeps
the same promises:

- **its process tree ends with it.** The process leads a session of its own and is a child
  subreaper (what it starts and abandons is re-parented to it, not to PID 1); whatever it
  leaves running when its work returns is killed, and :meth:`Supervised.stop` kills its
  descendants, then it, then what remains of its process group;
- **it ends with its owner.** The kernel signals it when its parent dies (``PR_SET_PDEATHSIG``),
  and a watchdog thread in it notices when the owner process (the one that created the
  :class:`Supervised`, which for a forkserver child is not its parent) is gone: either way it
  kills its descendants and exits;
- **nothing of it keeps its owner alive.** The owner talks to it over a pipe whose child end it
  closes at once (so a dead child reads as end-of-file, never as a pipe that waits forever), no
  owner thread ever blocks on that pipe without a deadline, and a process still running when the
  owner's interpreter exits is stopped first (before :mod:`multiprocessing` would join it);
- **its results come back as data** (:func:`serve`: each task's value or its exception), and a
  task that outlives its deadline ends the process (:class:`~excite.errors.WorkTimeout`), one
  that dies raises :class:`~excite.errors.WorkerDied`.

Pools (:func:`map_ordered`, the service's scoring pool) are built from these, and so is
:func:`command`, a program (the C compiler) run to its end or ended with everything it started.
"""

from __future__ import annotations

import ctypes
import logging
import multiprocessing
import multiprocessing.connection
import multiprocessing.util
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from ..errors import WorkerDied, WorkTimeout

log = logging.getLogger("excite.processes")

_PR_SET_PDEATHSIG, _PR_SET_CHILD_SUBREAPER = 1, 36
OWNER_CHECK_S = 0.5
_live: "set[Supervised]" = set()  # every process not yet stopped (never forgotten while alive)
_live_lock = threading.Lock()


def _prctl(option: int, value: int) -> None:
    try:
        ctypes.CDLL(None, use_errno=True).prctl(option, value, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _state(pid: int) -> str | None:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return None


def descendants(pid: int) -> list[int]:
    """Every live (not zombie) process below ``pid``, from /proc's children lists."""
    out: list[int] = []
    frontier = [pid]
    while frontier:
        found = []
        for p in frontier:
            try:
                tasks = os.listdir(f"/proc/{p}/task")
            except OSError:
                continue
            for tid in tasks:
                try:
                    found += [int(c) for c in Path(f"/proc/{p}/task/{tid}/children").read_text().split()]
                except OSError:
                    continue
        frontier = [c for c in dict.fromkeys(found) if c not in out]
        out += frontier
    return [p for p in out if _state(p) not in (None, "Z", "X")]


def kill_descendants(pid: int, rounds: int = 50) -> None:
    """SIGKILL every process below ``pid`` until none is left (one may fork while it is killed)."""
    for _ in range(rounds):
        below = descendants(pid)
        if not below:
            return
        for p in below:
            try:
                os.kill(p, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        if pid == os.getpid():
            _reap()
        time.sleep(0.005)


def _reap() -> None:
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return


def alive(pid: int) -> bool:
    """Whether the process ``pid`` runs (a zombie does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return _state(pid) not in (None, "Z", "X")


def _watch_owner(owner: int) -> None:
    while True:
        time.sleep(OWNER_CHECK_S)
        if not alive(owner):
            _end()


def _end(*_: Any) -> None:
    kill_descendants(os.getpid())
    os._exit(70)


def _main(conn: Any, owner: int, memory_mb: int, target: Callable[..., Any], args: tuple) -> None:
    """The process's entry: its promises (module docstring), then ``target(conn, *args)``."""
    # the parent's death (or SIGTERM) ends the process and its descendants first
    signal.signal(signal.SIGTERM, _end)
    _prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    try:
        os.setsid()
    except OSError:
        pass
    _prctl(_PR_SET_CHILD_SUBREAPER, 1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the owner decides when a helper ends
    if not alive(owner):
        os._exit(70)
    threading.Thread(target=_watch_owner, args=(owner,), daemon=True, name="owner-watch").start()
    if memory_mb:
        import resource

        limit = memory_mb * 2**20
        try:
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        except (ValueError, OSError):
            log.warning("cannot limit the process's memory to %d MiB", memory_mb)
    code = 0
    try:
        target(conn, *args)
    except BaseException:  # noqa: BLE001 — a bug in the target: logged, the process ends
        log.exception("supervised process failed")
        code = 1
    finally:
        kill_descendants(os.getpid())
        try:
            conn.close()
        except OSError:
            pass
        logging.shutdown()
        os._exit(code)


class Supervised:
    """``target(conn, *args)`` in a process of its own (see the module docstring); ``conn`` is
    its end of a duplex pipe to this object. ``context``: ``"spawn"`` (a fresh interpreter),
    ``"forkserver"`` (forked from a server that preloaded modules: :func:`forkserver`) or
    ``"fork"``; ``memory_mb`` limits its address space (0: none)."""

    def __init__(self, target: Callable[..., Any], *args: Any, context: Any = "spawn", memory_mb: int = 0,
                 name: str = "excite-helper"):
        ctx = multiprocessing.get_context(context) if isinstance(context, str) else context
        self.conn, child = ctx.Pipe(duplex=True)
        self.proc = ctx.Process(target=_main, name=name, args=(child, os.getpid(), memory_mb, target, args))
        self._lock = threading.Lock()
        self._stopped = False
        with _hidden_main():
            self.proc.start()
        child.close()
        self.pid: int = self.proc.pid  # type: ignore[assignment]
        with _live_lock:
            _live.add(self)

    @property
    def alive(self) -> bool:
        return not self._stopped and self.proc.is_alive()

    def send(self, obj: Any) -> None:
        """Send ``obj`` (:class:`WorkerDied` when the process is gone)."""
        try:
            self.conn.send(obj)
        except (OSError, ValueError) as exc:  # a closed or broken pipe
            raise WorkerDied(f"the process {self.pid} ended ({exc})") from None

    def receive(self, deadline: float | None = None) -> Any:
        """The next object it sent, waiting at most until ``deadline`` (time.monotonic()):
        :class:`WorkTimeout` then (the process keeps running), :class:`WorkerDied` when it ended."""
        try:
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            if not self.conn.poll(wait):
                raise WorkTimeout(f"the process {self.pid} did not answer in time")
            return self.conn.recv()
        except (EOFError, OSError, ValueError):
            code = self.proc.exitcode
            raise WorkerDied(f"the process {self.pid} ended (exit code {code})") from None

    def stop(self) -> None:
        """End the process and everything below it, now (idempotent, from any thread)."""
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
        with _live_lock:
            _live.discard(self)
        try:
            if self.proc.is_alive():
                kill_descendants(self.pid)
                self.proc.kill()
            self.proc.join(10)
        except (OSError, ValueError, AssertionError):
            pass
        try:
            os.killpg(self.pid, signal.SIGKILL)  # what is left of its group
        except (ProcessLookupError, PermissionError, OSError):
            pass
        try:
            self.conn.close()
        except OSError:
            pass

    def __enter__(self) -> "Supervised":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()


def running(name: str | None = None) -> list[Supervised]:
    """The supervised processes of this process not yet stopped (named ``name``, when given)."""
    with _live_lock:
        return [p for p in _live if name is None or p.proc.name == name]


def stop_all() -> None:
    """Stop every supervised process of this process (at interpreter exit, before
    :mod:`multiprocessing` joins its children; also at a server's shutdown)."""
    with _live_lock:
        procs = list(_live)
    for p in procs:
        p.stop()


# before multiprocessing's own exit function joins the children it started (exitpriority ≥ 0
# finalizers run first): a helper still running when the interpreter exits is stopped, not waited for
multiprocessing.util.Finalize(None, stop_all, exitpriority=100)


class _hidden_main:
    """A spawned child re-imports the parent's ``__main__`` script unless it is hidden: a script
    without an ``if __name__ == "__main__"`` guard would run again in it. Nothing a helper runs
    lives in ``__main__``."""

    def __enter__(self) -> None:
        main = sys.modules["__main__"]
        self.saved = {k: main.__dict__[k] for k in ("__file__", "__spec__") if k in main.__dict__}
        main.__dict__.pop("__file__", None)
        main.__spec__ = None

    def __exit__(self, *exc: Any) -> None:
        main = sys.modules["__main__"]
        main.__dict__.pop("__spec__", None)
        main.__dict__.update(self.saved)


# --------------------------------------------------------------------------------------------
# Tasks: a process that runs what it is sent


def serve(conn: Any, warm: Callable[[], Any] | None = None, after: Callable[[], bool] | None = None) -> None:
    """The target of a task worker: for each ``(fn, args)`` received, sends ``("ok", fn(*args),
    ending)`` or ``("error", exception, ending)``; ``warm()`` runs first (then ``("ready", None,
    False)`` is sent); ``after()`` after each task: True ends the worker (it grew too large), and
    the answer says so (``ending``)."""
    if warm is not None:
        warm()
    conn.send(("ready", None, False))
    # Tasks are read as they come, by a thread of their own: an owner that sends a large task
    # while this process sends a large answer would otherwise wait on a full pipe each way.
    tasks: queue.SimpleQueue[Any] = queue.SimpleQueue()

    def read() -> None:
        while True:
            try:
                tasks.put(conn.recv())
            except BaseException:  # noqa: BLE001 — closed, broken or unreadable: the worker ends
                tasks.put(None)
                return

    threading.Thread(target=read, name="excite-tasks", daemon=True).start()
    while True:
        task = tasks.get()
        if task is None:
            return
        fn, args = task
        try:
            kind, value = "ok", fn(*args)
        except BaseException as exc:  # noqa: BLE001 — returned to the owner as data
            kind, value = "error", exc
        ending = bool(after is not None and after())
        try:
            conn.send((kind, value, ending))
        except Exception:  # noqa: BLE001 — the value or exception does not pickle
            conn.send(("error", RuntimeError(f"{type(value).__name__}: {str(value)[:500]}"), ending))
        if ending:
            return


class Worker(Supervised):
    """A :func:`serve` process: :meth:`submit` tasks, :meth:`result` their values in order."""

    def __init__(self, *, warm: Callable[[], Any] | None = None, after: Callable[[], bool] | None = None,
                 context: Any = "spawn", memory_mb: int = 0, name: str = "excite-worker",
                 start_deadline: float | None = None):
        super().__init__(serve, warm, after, context=context, memory_mb=memory_mb, name=name)
        self.submitted = self.received = 0
        self._ready = False
        self.ending = False  # its last answer said it ends after it (replace it)
        if start_deadline is not None:
            self.wait_ready(start_deadline)

    def wait_ready(self, deadline: float | None = None) -> None:
        if not self._ready:
            kind, _, _ = self.receive(deadline)
            self._ready = kind == "ready"

    def submit(self, fn: Callable[..., Any], *args: Any) -> int:
        """Queue ``fn(*args)``; returns its index. Arguments that cannot be pickled raise here
        (pickling is done before a byte is written)."""
        self.send((fn, args))
        self.submitted += 1
        return self.submitted - 1

    def result(self, deadline: float | None = None) -> Any:
        """The value of the oldest task not yet read (its exception re-raised): a worker runs its
        tasks in order. Past ``deadline`` the worker is stopped: :class:`WorkTimeout`."""
        self.wait_ready(deadline)
        try:
            kind, value, self.ending = self.receive(deadline)
        except WorkTimeout:
            self.stop()
            raise
        except WorkerDied:
            self.stop()
            raise
        self.received += 1
        if kind == "error":
            raise value
        return value

    def run(self, fn: Callable[..., Any], *args: Any, deadline: float | None = None) -> Any:
        """``fn(*args)`` in this worker, by ``deadline``."""
        self.submit(fn, *args)
        return self.result(deadline)


def map_ordered(fn: Callable[[Any], Any], items: Sequence[Any], jobs: int, *,
                failed: Callable[[Any, BaseException], Any], context: Any = "fork",
                on_result: Callable[[int, Any], None] | None = None,
                poll: Callable[[], bool] | None = None, poll_s: float = 0.5) -> list[Any]:
    """``fn(item)`` for every item on ``jobs`` workers, results in order; an item whose worker
    died gets ``failed(item, exception)`` (and a fresh worker takes the next). ``poll()`` runs
    every ``poll_s`` seconds while results are awaited and after each result: True ends the map
    early (the items not done are None). Ended early, interrupted (Ctrl-C) or when an exception
    leaves ``failed``, ``on_result`` or ``poll``, every worker is stopped before it returns."""
    results: list[Any] = [None] * len(items)
    todo = list(range(len(items)))[::-1]  # the next item last
    starting: dict[Any, Worker] = {}  # its first task is sent when it is ready: the owner never
    busy: dict[Any, tuple[Worker, int]] = {}  # waits on a pipe that a starting worker does not read yet
    workers: list[Worker] = []

    def start() -> None:
        w = Worker(context=context)
        workers.append(w)
        starting[w.conn] = w

    def give(w: Worker) -> bool:
        if not todo:
            return False
        i = todo.pop()
        w.submit(fn, items[i])
        busy[w.conn] = (w, i)
        return True

    try:
        for _ in range(min(jobs, len(items))):
            start()
        while busy or starting:
            ready = multiprocessing.connection.wait([*starting, *busy], timeout=None if poll is None else poll_s)
            for conn in ready:
                if conn in starting:
                    w = starting.pop(conn)
                    w.wait_ready()  # WorkerDied when it ended before it was ready
                    if not give(w):
                        w.stop()
                    continue
                w, i = busy.pop(conn)
                try:
                    r = w.result()
                except Exception as exc:  # noqa: BLE001 — its process died, or fn raised
                    r = failed(items[i], exc)
                    if not w.alive:
                        w = None  # type: ignore[assignment]
                        if todo:
                            start()
                results[i] = r
                if on_result is not None:
                    on_result(i, r)
                if w is not None and not give(w):
                    w.stop()
            if poll is not None and poll():
                break
    finally:
        for w in workers:
            w.stop()
    return results


# --------------------------------------------------------------------------------------------
# Commands: a program run to its end, or ended with everything it started

_OUTPUT_TAIL = 1 << 16  # bytes of a command's output and errors sent back


def _run_command(cmd: list[str]) -> tuple[int, bytes, bytes]:
    done = subprocess.run(cmd, stdin=subprocess.DEVNULL, capture_output=True)
    return done.returncode, done.stdout[-_OUTPUT_TAIL:], done.stderr[-_OUTPUT_TAIL:]


def command(cmd: Sequence[str], timeout_s: float, name: str = "excite-command") -> subprocess.CompletedProcess:
    """Run ``cmd`` in a supervised process and return it as :func:`subprocess.run` would (the
    last 64 KiB of its output and of its errors, as bytes). The command and every process it
    starts (a compiler's passes) end when it does not finish within ``timeout_s``
    (:class:`WorkTimeout`), when an exception reaches this call (Ctrl-C), and when this process
    dies: nothing of it outlives its caller. A program that cannot be started raises its
    :class:`OSError` here."""
    with Worker(name=name) as w:
        try:
            code, out, err = w.run(_run_command, list(cmd), deadline=time.monotonic() + timeout_s)
        except WorkTimeout:
            raise WorkTimeout(f"{Path(cmd[0]).name} did not finish within {timeout_s:g} s") from None
    return subprocess.CompletedProcess(list(cmd), code, out, err)
