"""The resident process (excite.cli.resident_process): a served command is the command the caller would
have run — same output, files, exit code and messages, in the caller's directory, environment
and terminal —; only the same installation and user are served; it starts by itself only at a
terminal; Ctrl-C and a vanished caller reach the command; it leaves when idle or told to."""

from __future__ import annotations

import fcntl
import importlib.metadata
import json
import os
import pty
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import termios
import time
from pathlib import Path

import numpy as np
import pytest

from excite.cli import resident_process as resident
from helpers import REPO

ROUTE = REPO / "trajectories" / "figure_eight_control.csv"
# exactly what the `excite` script runs (its sys.path[0] differs, which the key leaves out)
CLIENT = [sys.executable, "-c", "from excite.cli.resident_process import run; run()"]


def _env(home: Path, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != resident.ENV}
    env.update(XDG_RUNTIME_DIR=str(home), **extra)
    return env


def _excite(args: list[str], env: dict, cwd: Path, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([*CLIENT, *args], env=env, cwd=cwd, capture_output=True, text=True, timeout=300, **kw)


def _key(env: dict) -> str:
    r = subprocess.run([sys.executable, "-c", "from excite.cli.resident_process import key; print(key())"], env=env,
                       capture_output=True, text=True, timeout=60, check=True)
    return r.stdout.strip()


def _status(env: dict) -> dict | None:
    """The resident process's status, asked from this process (as the client asks)."""
    old = os.environ.get("XDG_RUNTIME_DIR")
    os.environ["XDG_RUNTIME_DIR"] = env["XDG_RUNTIME_DIR"]
    try:
        return resident.control("status", env["_KEY"])
    finally:
        if old is None:
            del os.environ["XDG_RUNTIME_DIR"]
        else:
            os.environ["XDG_RUNTIME_DIR"] = old


def _wait(predicate, timeout_s: float = 60.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return False


def _gone(pid: int) -> bool:
    stat = Path(f"/proc/{pid}/stat")
    return not stat.exists() or stat.read_text().split()[2] == "Z"


def _stop(env: dict) -> None:
    st = _status(env)
    if st is not None:
        r = _excite(["resident", "stop"], env, REPO)
        assert r.returncode == 0 and f"resident process {st['pid']} stops" in r.stdout, r.stdout + r.stderr
        if not _wait(lambda: _gone(st["pid"]), 20):
            os.kill(st["pid"], signal.SIGKILL)


def _home():
    # a short path: a Unix socket's path holds at most 108 bytes
    d = Path(tempfile.mkdtemp(prefix="rt", dir="/tmp"))
    env = _env(d)
    env["_KEY"] = _key(env)  # an underscore name: not part of the key
    return d, env


@pytest.fixture(scope="module")
def home():
    d, env = _home()
    r = _excite(["resident", "start", "--idle-minutes", "10"], env, REPO)
    assert r.returncode == 0 and "ready" in r.stdout, r.stderr
    yield d, env
    try:
        _stop(env)
    finally:
        shutil.rmtree(d, ignore_errors=True)


@pytest.fixture
def started(home):
    return home[1]


def _served(env: dict) -> int:
    return _status(env)["served"]


def _in_pty(args: list[str], env: dict, cwd: Path, cols: int = 120) -> tuple[int, str]:
    """Run the client with a terminal (``cols`` wide) as its stdin, stdout and stderr."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 50, cols, 0, 0))
    proc = subprocess.Popen([*CLIENT, *args], env=env, cwd=cwd, stdin=slave, stdout=slave, stderr=slave,
                            start_new_session=True)
    os.close(slave)
    out = b""
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:  # EIO: every end of the terminal is closed
            break
        if not chunk:
            break
        out += chunk
    os.close(master)
    return proc.wait(timeout=120), out.decode().replace("\r\n", "\n")


def test_the_excite_script_is_the_resident_client():
    (script,) = importlib.metadata.entry_points(group="console_scripts", name="excite")
    assert script.value == "excite.cli.resident_process:run"


@pytest.mark.slow
def test_a_served_command_is_the_command_run_here(started, tmp_path):
    """Relative paths resolve in the caller's directory, files land there, and output, messages
    and exit codes are those of the same command run in the calling process."""
    env, here = started, dict(started, EXCITE_RESIDENT="0")
    n = _served(env)
    shutil.copy(ROUTE, tmp_path / "route.csv")
    served = _excite(["score", "route.csv", "--json", "--export", "served.npz"], env, tmp_path)
    local = _excite(["score", "route.csv", "--json", "--export", "local.npz"], here, tmp_path)
    assert served.returncode == local.returncode == 0, served.stderr + local.stderr
    a, b = json.loads(served.stdout), json.loads(local.stdout)
    a.pop("timings_ms"), b.pop("timings_ms")
    assert a == b
    with np.load(tmp_path / "served.npz") as x, np.load(tmp_path / "local.npz") as y:
        assert sorted(x.files) == sorted(y.files)
        for name in x.files:
            assert np.array_equal(x[name], y[name]), name
    assert _served(env) == n + 1

    for args in (["score", "missing.csv"], ["score", "route.csv", "--rig", "no_such_rig"],
                 ["score", "route.csv", "--no-such-option"]):
        s, h = _excite(args, env, tmp_path), _excite(args, here, tmp_path)
        assert (s.returncode, s.stdout, s.stderr) == (h.returncode, h.stdout, h.stderr), args
        assert s.returncode != 0
    assert _served(env) == n + 4


def test_a_served_command_writes_to_the_callers_terminal(started):
    """The terminal itself is passed on: the report is the rich table at the terminal's width,
    as the command run in the calling process draws it."""
    n = _served(started)
    served = _in_pty(["score", str(ROUTE)], started, REPO, cols=100)
    local = _in_pty(["score", str(ROUTE)], dict(started, EXCITE_RESIDENT="0"), REPO, cols=100)
    assert served[0] == local[0] == 0
    # colorama (imported by a dependency) resets the terminal's style at the exit of the calling
    # process: its exit handler belongs to the resident process, whose output is its log
    assert served[1] == local[1].removesuffix("\x1b[0m")
    text = re.sub(r"\x1b\[[0-9;]*m", "", served[1])  # the terminal's styles
    assert "σ/target" in text and max(len(line) for line in text.splitlines()) == 100
    assert _served(started) == n + 1


def test_only_this_installation_and_environment_are_served(started, monkeypatch, tmp_path):
    """A setting that changes what excite computes (any EXCITE_* variable) is another key: the
    resident process is not asked, the command runs in the caller."""
    n = _served(started)
    r = _excite(["score", str(ROUTE), "--json"], dict(started, EXCITE_ANYTHING="1"), REPO)
    assert r.returncode == 0 and json.loads(r.stdout)["rank"] > 0
    assert _served(started) == n

    # the key follows every file of the package (not numba's cache)
    pkg = tmp_path / "excite"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "resident.py").write_text("x = 1\n")
    (pkg / "sub" / "m.py").write_text("y = 1\n")
    monkeypatch.setattr(resident, "__file__", str(pkg / "resident.py"))
    k0 = resident.key()
    (pkg / "sub" / "__pycache__").mkdir()
    (pkg / "sub" / "__pycache__" / "m.k.nbi").write_bytes(b"cache")
    assert resident.key() == k0
    (pkg / "sub" / "m.py").write_text("y = 2\n")
    assert resident.key() != k0


def test_a_directory_others_can_enter_is_not_used(started, home):
    home, n = home[0], _served(started)
    (home / "excite").chmod(0o755)
    try:
        r = _excite(["score", str(ROUTE), "--json"], started, REPO)
        assert r.returncode == 0 and json.loads(r.stdout)["rank"] > 0  # run here instead
        s = _excite(["resident", "start"], started, REPO)
        assert s.returncode == 1 and s.stderr.count("\n") == 1
        assert s.stderr.startswith("excite: error: ") and str(home / "excite") in s.stderr and "700" in s.stderr
    finally:
        (home / "excite").chmod(0o700)
    assert _served(started) == n


def _group(pgid: int) -> list[int]:
    """Live processes of process group ``pgid``."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            out.append(int(stat.parent.name))
    return out


def test_signals_and_a_vanished_caller_reach_the_command_and_its_workers(started, tmp_path):
    """A served `batch --jobs 2` whose two routes are named pipes nobody writes: the command and
    its two worker processes block. Ctrl-C of the caller interrupts them all (exit code 130, as
    in the caller), SIGTERM ends them and the caller dies of SIGTERM as it would have, and a
    caller killed outright takes them with it."""
    for name in ("a.tum", "b.tum"):
        os.mkfifo(tmp_path / name)
    for how in ("interrupt", "terminate", "kill"):
        proc = subprocess.Popen([*CLIENT, "batch", "a.tum", "b.tum", "--jobs", "2"], env=started, cwd=tmp_path,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert _wait(lambda: len((_status(started) or {}).get("commands", [])) == 1, 30)
        (command,) = _status(started)["commands"]
        assert _wait(lambda: len(_group(command)) == 3, 30), _group(command)  # the command and its workers
        getattr(proc, {"interrupt": "send_signal", "terminate": "terminate", "kill": "kill"}[how])(
            *([signal.SIGINT] if how == "interrupt" else []))
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == {"interrupt": 130, "terminate": -signal.SIGTERM, "kill": -signal.SIGKILL}[how], err
        assert "Traceback" not in err, err
        assert _wait(lambda: not _group(command), 30), (how, _group(command))
        assert _wait(lambda: _status(started)["running"] == 0, 30), how


@pytest.mark.slow
def test_a_running_command_does_not_keep_a_new_resident_process_from_starting(tmp_path):
    """Neither a served command nor the processes it starts hold the resident process's lock:
    stopped while a command runs, it can be started again at once; two starts at once give one
    resident process."""
    home, env = _home()
    try:
        starts = [subprocess.Popen([*CLIENT, "resident", "start"], env=env, cwd=REPO, stdout=subprocess.PIPE,
                                   stderr=subprocess.PIPE, text=True) for _ in range(2)]
        outs = [p.communicate(timeout=300) for p in starts]
        assert [p.returncode for p in starts] == [0, 0], outs
        first = _status(env)["pid"]
        assert all(str(first) in out for out, _ in outs), outs
        os.mkfifo(tmp_path / "a.tum")
        blocked = subprocess.Popen([*CLIENT, "batch", "a.tum", "a.tum", "--jobs", "2"], env=env, cwd=tmp_path,
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        assert _wait(lambda: len((_status(env) or {}).get("commands", [])) == 1, 30)
        (command,) = _status(env)["commands"]
        assert _wait(lambda: len(_group(command)) == 3, 30)
        _stop(env)
        again = _excite(["resident", "start"], env, REPO)
        assert again.returncode == 0, again.stdout + again.stderr
        assert _status(env)["pid"] != first
        blocked.kill()
        blocked.wait(timeout=30)
        assert _wait(lambda: not _group(command), 30)
    finally:
        _stop(env)
        shutil.rmtree(home, ignore_errors=True)


def test_silent_or_foreign_requests_do_not_stop_it(started):
    """Connections that send nothing, or a request that is not one, neither delay nor end it."""
    path = home_socket = Path(started["XDG_RUNTIME_DIR"]) / "excite" / f"{started['_KEY']}.sock"
    silent = []
    for _ in range(3):
        c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        c.connect(str(path))
        silent.append(c)
    t0 = time.monotonic()
    assert _status(started) is not None
    assert time.monotonic() - t0 < 2.0  # the silent ones are dropped after 5 s each, not waited for in turn
    for body in (b"[1, 2]", b"not json", b'{"op": "run"}'):
        c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        c.connect(str(home_socket))
        c.sendall(struct.pack("!4sI", b"EXCR", len(body)) + body)
        c.close()
    for c in silent:
        c.close()
    assert _status(started) is not None


def test_the_callers_umask_and_locale_are_its_own(started, tmp_path):
    """A file the command writes has the caller's umask; another locale is another key (file
    names are decoded by it)."""
    shutil.copy(ROUTE, tmp_path / "route.csv")
    n = _served(started)
    for env, out in ((started, "served.npz"), (dict(started, EXCITE_RESIDENT="0"), "local.npz")):
        r = subprocess.run([*CLIENT, "score", "route.csv", "--export", out], env=env, cwd=tmp_path,
                           capture_output=True, text=True, timeout=300, preexec_fn=lambda: os.umask(0o077))
        assert r.returncode == 0, r.stderr
    assert _served(started) == n + 1
    assert (tmp_path / "served.npz").stat().st_mode & 0o777 == (tmp_path / "local.npz").stat().st_mode & 0o777 == 0o600
    base = {k: v for k, v in started.items() if not k.startswith(("LANG", "LC_"))}
    assert resident.key(base) != resident.key(dict(base, LC_ALL="C"))
    assert resident.key(base) != resident.key(dict(base, LANG="de_DE.ISO-8859-1"))
    assert resident.key(base) == resident.key(dict(base, EXCITE_RESIDENT="1", HOME="/elsewhere"))


@pytest.mark.slow
def test_it_starts_itself_only_at_a_terminal_and_leaves_when_idle():
    home, env = _home()
    try:
        _starts_itself(home, env)
    finally:
        _stop(env)
        shutil.rmtree(home, ignore_errors=True)


def _starts_itself(home: Path, env: dict) -> None:
    piped = _excite(["score", str(ROUTE)], env, REPO)
    assert piped.returncode == 0 and _status(env) is None  # scripts and CI: never
    off = _in_pty(["score", str(ROUTE)], dict(env, EXCITE_RESIDENT="0"), REPO)
    assert off[0] == 0 and _status(env) is None

    rc, out = _in_pty(["score", str(ROUTE)], env, REPO)
    assert rc == 0 and "excite: started a resident process" in out
    assert _wait(lambda: _status(env) is not None, 120)
    rc, again = _in_pty(["score", str(ROUTE)], env, REPO)
    assert rc == 0 and "started a resident process" not in again
    assert _served(env) == 1

    # another setting is another key: that command runs here, and the resident process it
    # starts replaces the one of the same installation that no longer matches
    first = _status(env)["pid"]
    other = dict(env, EXCITE_ANYTHING="1")
    other["_KEY"] = _key(other)
    try:
        rc, out = _in_pty(["score", str(ROUTE)], other, REPO)
        assert rc == 0 and "excite: started a resident process" in out  # so it ran here
        assert _wait(lambda: _gone(first), 30)
        assert _wait(lambda: _status(other) is not None, 120)
    finally:
        _stop(other)
    assert _status(env) is None

    r = _excite(["resident", "start", "--idle-minutes", "0.02"], env, REPO)  # 1.2 s
    assert r.returncode == 0, r.stderr
    pid = _status(env)["pid"]
    assert _wait(lambda: _gone(pid), 30)
    assert _status(env) is None and not list((home / "excite").glob("*.sock"))
