"""excite.plan.compiled: the compiler ends with its caller. A stand-in compiler (a shell script
that starts a pass of its own, as cc starts cc1, and waits) shows that no compile outlives the
call that started it: past its timeout, on Ctrl-C, on SIGTERM or SIGKILL of the caller; and that a
run on a miss starts no compiler at all."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import casadi as ca
import pytest

from excite.core import native, processes
from excite.plan import compiled

REPO = Path(__file__).resolve().parents[2]



def _gone(pids: list[int], timeout_s: float = 20.0) -> list[int]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and any(processes.alive(p) for p in pids):
        time.sleep(0.05)
    return [p for p in pids if processes.alive(p)]


@pytest.fixture
def stand_in(tmp_path, monkeypatch):
    """``CC`` a script that writes its pid and its pass's, then waits for the pass (10 minutes).
    The native module is built first with the real compiler: in a source checkout whose build is
    not current it is kept in the cache, which the fresh cache dir gets too."""
    mod = Path(native.module().__file__)
    if mod.parent == native.cache_dir() / "native":
        (tmp_path / "cache" / "native").mkdir(parents=True)
        (tmp_path / "cache" / "native" / mod.name).symlink_to(mod)
    pids = tmp_path / "pids"
    cc = tmp_path / "cc"
    cc.write_text(f"#!/bin/sh\nsleep 600 &\necho $$ $! > {pids}.part && mv {pids}.part {pids}\nwait\n")
    cc.chmod(0o755)
    monkeypatch.setenv("CC", str(cc))
    monkeypatch.delenv("EXCITE_COMPILE", raising=False)
    monkeypatch.setenv("EXCITE_CACHE_DIR", str(tmp_path / "cache"))
    return pids


def _toy() -> ca.Function:
    x = ca.MX.sym("x", 3)
    return ca.Function("toy", [x], [ca.sin(x) * ca.sumsqr(x)])


def test_a_run_on_a_miss_starts_no_compiler(stand_in):
    """On a miss the run uses the virtual machine and names the command that compiles; no
    process is started for it."""
    before = set(processes.descendants(os.getpid()))
    loaded = compiled.load("toy", ["toy"], "k1", lambda: [_toy()])
    assert loaded.mode == "virtual machine" and "--compile-only" in loaded.note and "\n" not in loaded.note
    assert set(processes.descendants(os.getpid())) - before == set()
    time.sleep(1.0)
    assert not stand_in.exists()
    assert not (stand_in.parent / "cache" / "casadi" / "toy_k1.lock").exists()


CALLER = """
import sys
from excite.plan import compiled
compiled.COMPILE_TIMEOUT_S = float(sys.argv[1])
sys.path.insert(0, {tests!r})
from test_compiled import _toy
loaded = compiled.load("toy", ["toy"], "k1", lambda: [_toy()], wait=True)
print(loaded.mode, "|", loaded.note, flush=True)
"""


def _caller(timeout_s: float) -> subprocess.Popen:
    code = CALLER.format(tests=str(Path(__file__).parent))
    return subprocess.Popen([sys.executable, "-c", code, str(timeout_s)], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(REPO)})


def _wait_for(pids: Path, caller: subprocess.Popen) -> list[int]:
    deadline = time.monotonic() + 120
    while not pids.exists():
        assert time.monotonic() < deadline and caller.poll() is None, "the stand-in compiler never started"
        time.sleep(0.05)
    return [int(x) for x in pids.read_text().split()]


def test_a_compile_past_its_timeout_ends_with_its_passes_and_leaves_no_files(stand_in):
    caller = _caller(timeout_s=4)
    try:
        started = _wait_for(stand_in, caller)
        out, _ = caller.communicate(timeout=120)
    finally:
        caller.kill()
    assert caller.returncode == 0
    assert out.startswith("virtual machine | cannot compile") and "did not finish within 4 s" in out
    assert _gone(started) == []
    assert sorted(p.name for p in (stand_in.parent / "cache" / "casadi").iterdir()) == []


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL], ids=lambda s: s.name)
def test_a_compile_ends_with_its_caller_interrupted_or_killed(stand_in, sig):
    """Ctrl-C (SIGINT to the caller alone, not to the compiler: a service or a script stops its
    command so), SIGTERM and SIGKILL of the caller: the compiler and its pass end too, and a lock
    left by a caller that died does not hold the next compile back."""
    caller = _caller(timeout_s=600)
    try:
        started = _wait_for(stand_in, caller)
        assert all(processes.alive(p) for p in started)
        caller.send_signal(sig)
        caller.communicate(timeout=60)
    finally:
        caller.kill()
    assert _gone(started) == []
    lock = stand_in.parent / "cache" / "casadi" / "toy_k1.lock"
    assert not lock.exists() or compiled._lock_stale(lock)
