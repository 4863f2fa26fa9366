"""excite.core.processes: a supervised process's tree ends with it, it ends with its owner, and
nothing of it keeps its owner's interpreter from exiting — the helper stopped in the middle of
sending a large result included, many times over."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from excite.core import processes
from excite.errors import WorkerDied, WorkTimeout

REPO = Path(__file__).resolve().parents[2]


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")


def _wait_gone(pids: list[int], timeout_s: float = 10.0) -> list[int]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        left = [p for p in pids if _alive(p)]
        if not left:
            return []
        time.sleep(0.05)
    return [p for p in pids if _alive(p)]


def spawn_tree(conn, marker: str) -> None:
    """Start a child and a grandchild in a session of its own, report their pids, then wait."""
    a = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)", marker])
    b = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)", marker], start_new_session=True)
    conn.send([a.pid, b.pid])
    time.sleep(600)


def big(n: int) -> bytes:
    return b"x" * n


def sleep(s: float) -> float:
    time.sleep(s)
    return s


def test_stop_ends_the_whole_tree_even_a_grandchild_in_its_own_session():
    p = processes.Supervised(spawn_tree, "excite-test-tree", context="spawn")
    kids = p.receive(time.monotonic() + 60)
    assert all(_alive(k) for k in kids)
    p.stop()
    assert _wait_gone([p.pid, *kids]) == []
    p.stop()  # idempotent


def test_work_that_returns_leaves_nothing_running():
    """A target that returns with children still running: they end with it."""

    p = processes.Supervised(_return_leaving_children, context="spawn")
    kids = p.receive(time.monotonic() + 60)
    p.proc.join(30)
    assert p.proc.exitcode == 0
    assert _wait_gone(kids) == []
    p.stop()


def _return_leaving_children(conn) -> None:
    a = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
    b = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"], start_new_session=True)
    conn.send([a.pid, b.pid])


def test_a_helper_ends_with_its_owner_killed_by_sigkill(tmp_path):
    """The owner (a process that made a supervised helper, which made a grandchild) is killed
    with SIGKILL: the helper and its tree end by themselves."""
    out = tmp_path / "pids"
    code = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from excite.core import processes
        from test_processes import spawn_tree
        p = processes.Supervised(spawn_tree, "excite-test-owner", context="spawn")
        kids = p.receive(time.monotonic() + 60)
        open({str(out)!r}, "w").write(" ".join(map(str, [p.pid, *kids])))
        time.sleep(600)
    """)
    owner = subprocess.Popen([sys.executable, "-c", code], env={**os.environ, "PYTHONPATH": str(REPO)})
    deadline = time.monotonic() + 60
    while not (out.exists() and out.read_text().strip()):
        assert time.monotonic() < deadline and owner.poll() is None
        time.sleep(0.1)
    pids = [int(x) for x in out.read_text().split()]
    os.kill(owner.pid, signal.SIGKILL)
    owner.wait()
    assert _wait_gone(pids, 15) == []


def test_tasks_return_values_and_exceptions_and_a_deadline_ends_the_worker():
    w = processes.Worker(context="fork", start_deadline=time.monotonic() + 30)
    try:
        assert w.run(big, 10) == b"x" * 10
        with pytest.raises(ZeroDivisionError):
            w.run(divmod, 1, 0)
        assert w.run(sleep, 0.0) == 0.0  # an exception does not end the worker
        with pytest.raises(WorkTimeout):
            w.run(sleep, 30.0, deadline=time.monotonic() + 0.5)
        assert _wait_gone([w.pid]) == []
        with pytest.raises(WorkerDied):
            w.run(sleep, 0.0)
    finally:
        w.stop()


def test_a_large_task_sent_while_the_worker_sends_a_large_answer_does_not_deadlock():
    # the first task's answer and the next tasks' arguments are each larger than the pipe holds:
    # both sides write at once, and the owner reads nothing until it has sent every task
    w = processes.Worker(context="spawn", name="excite-test-pipe", start_deadline=time.monotonic() + 60)
    try:
        n = 8 << 20
        sent = threading.Event()

        def submit_all() -> None:
            w.submit(big, n)
            time.sleep(1.0)  # the worker is writing its answer now
            for _ in range(3):
                w.submit(len, b"y" * n)
            sent.set()

        threading.Thread(target=submit_all, daemon=True).start()
        assert sent.wait(60), "the owner's send waited on the worker's answer"
        deadline = time.monotonic() + 60
        assert len(w.result(deadline)) == n
        assert [w.result(deadline) for _ in range(3)] == [n] * 3
    finally:
        w.stop()


def test_map_ordered_keeps_order_and_survives_a_worker_that_dies():
    out = processes.map_ordered(_square_or_die, list(range(12)), 3, failed=lambda i, e: ("failed", i))
    assert out == [("failed", i) if i == 5 else i * i for i in range(12)]


def test_map_ordered_ended_by_its_poll_stops_every_worker_at_once():
    """Two workers, four items: the first takes 0.1 s, the others an hour. The poll ends the map
    once the first is in; the workers running hour-long items are stopped, not waited for."""
    seen: set[int] = set()

    def poll() -> bool:
        seen.update(w.pid for w in processes.running("excite-worker"))
        return out_so_far[0] is not None

    out_so_far: list = [None]
    t0 = time.monotonic()
    out = processes.map_ordered(sleep, [0.1, 3600, 3600, 3600], 2, failed=lambda i, e: e, poll=poll, poll_s=0.05,
                                on_result=lambda i, r: out_so_far.__setitem__(i, r))
    assert out == [0.1, None, None, None]
    assert time.monotonic() - t0 < 60  # an hour-long item was not waited for
    assert len(seen) == 2 and processes.running() == [] and _wait_gone(sorted(seen)) == []


def _square_or_die(i: int) -> int:
    if i == 5:
        os._exit(3)
    return i * i


STOP_MID_WRITE = """
import sys, time, random
from excite.core import processes
sys.path.insert(0, {here!r})
from test_processes import big
random.seed({seed})
for _ in range({rounds}):
    w = processes.Worker(context="fork", start_deadline=time.monotonic() + 30)
    w.submit(big, 64 * 2**20)      # a result far larger than the pipe holds
    time.sleep(random.uniform(0.0, 0.05))
    w.stop()                        # ... stopped while it writes it
    w2 = processes.Worker(context="fork")
    w2.submit(big, 64 * 2**20)      # and one left running at exit, mid-write
print("done", flush=True)
"""


@pytest.mark.parametrize("seed", range(4))
def test_an_interpreter_with_helpers_stopped_mid_write_exits(seed):
    """The hang of a thread reading a pipe whose writer was killed cannot happen: 4 × 15 helpers
    are stopped while writing 64 MiB, one more is left writing at exit; the process exits."""
    code = STOP_MID_WRITE.format(here=str(Path(__file__).parent), seed=seed, rounds=15)
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-c", code], env={**os.environ, "PYTHONPATH": str(REPO)},
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "done", r.stderr[-2000:]
    assert time.monotonic() - t0 < 120


def test_a_command_past_its_timeout_ends_with_what_it_started(tmp_path):
    """A command that started a process in a session of its own and waits is ended at its
    timeout, the process it started too; its output comes back as subprocess.run's would, and a
    program that does not exist raises its OSError."""
    pids = tmp_path / "pids"
    script = f"setsid sleep 600 & echo $$ $! > {pids}; wait"
    t0 = time.monotonic()
    with pytest.raises(WorkTimeout, match="sh did not finish within 3 s"):
        processes.command(["sh", "-c", script], 3)
    assert time.monotonic() - t0 < 30
    started = [int(x) for x in pids.read_text().split()]
    assert len(started) == 2
    assert _wait_gone(started) == []
    done = processes.command(["sh", "-c", "echo out; echo err >&2; exit 3"], 60)
    assert (done.returncode, done.stdout, done.stderr) == (3, b"out\n", b"err\n")
    with pytest.raises(FileNotFoundError):
        processes.command([str(tmp_path / "no-such-program")], 60)
