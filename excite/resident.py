"""The ``excite`` command, answered by a resident process when one is running.

A cold ``excite score`` spends about 1.4 s before it computes anything: numba's registries and
its cached kernels, scipy's interpolate and spatial packages (the README's "Cold start of the
command line"); scoring the bundled figure-eight then takes 0.05 s. A person working on a route
at a terminal pays that on every command. So the ``excite`` script first asks a *resident
process* of this very installation to run the command. That process has imported excite and
loaded every kernel once; for each command it forks a child, and the child takes on the
caller's working directory, environment and standard streams (their file descriptors are passed
over a Unix socket, so a terminal stays a terminal and a pipe a pipe) and runs the command as
the caller would have (:func:`excite.cli.main`). Its exit code becomes the caller's.

- **Which commands:** :data:`SERVED` — the short ones a person waits on. Commands that run for
  minutes or manage processes of their own (``serve``, ``live``, ``optimize``, ``validate``,
  ``mine``) always run in the calling process: a second saved is nothing to them.
- **Which resident process:** the socket is named by :func:`key`, a hash of the interpreter,
  ``sys.path``, the size and modification time of every file of the excite package, the
  installed numpy/scipy/numba/typer/rich/pydantic/yaml and the environment variables that change
  what excite computes (``EXCITE_*``, ``NUMBA_*``, ``PYTHON*``, thread counts). Any change means
  another key: an older resident process is never asked again and leaves when idle.
- **Lifetime:** ``excite resident start`` starts one; so does the first served command run at a
  terminal (standard input and error both terminals) when none is running, after that command
  has finished, saying so in one line on stderr. It leaves after :data:`IDLE_MINUTES` minutes
  without a command, or at ``excite resident stop``. ``EXCITE_RESIDENT=0`` makes excite neither
  use nor start one (tests and benchmarks of the cold path set it).
- **Privacy:** the socket lives in a directory only its user can enter (``$XDG_RUNTIME_DIR/excite``
  or ``/tmp/excite-UID``, checked before every use) and the resident process serves only
  connections of its own user (``SO_PEERCRED``).
- **Signals:** Ctrl-C, SIGTERM and SIGHUP of the caller are forwarded to the command's child (Ctrl-C
  interrupts it, exit code 130); a caller that disappears takes its child with it.

This module is what the ``excite`` script imports first, so its client half uses the standard
library only: asking a resident process costs ~0.05 s in all.
"""

from __future__ import annotations

import json
import os
import socket
import struct
import sys
import time
from pathlib import Path

SERVED = frozenset({"score", "route", "rig", "batch"})
IDLE_MINUTES = 30.0
ENV = "EXCITE_RESIDENT"  # "0": neither use nor start a resident process
_MAGIC = b"EXCR"
_HEADER = struct.Struct("!4sI")
_MAX_REQUEST = 1 << 20  # bytes of a request (argv, environment): far above any real one
_ENV_PREFIXES = ("EXCITE_", "NUMBA_", "PYTHON", "OMP_", "OPENBLAS_", "MKL_", "NUMEXPR_")
_LIBRARIES = ("numpy", "scipy", "numba", "llvmlite", "typer", "click", "rich", "pydantic", "yaml", "fsspec")
_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT")


# --- where, and which ---------------------------------------------------------------------


def command_of(argv: list[str]) -> str | None:
    """The command word of ``excite`` arguments (the root takes no option with a value)."""
    words = [a for a in argv if not a.startswith("-")]
    return words[0] if words else None


def key(env: dict[str, str] | None = None) -> str:
    """What a resident process must share with the caller to answer for it (see the module doc)."""
    import hashlib
    from importlib.util import find_spec

    env = os.environ if env is None else env
    # sys.path[0] is the script's folder: the `excite` script's, or "" for `python -c`
    h = hashlib.sha256(repr((os.path.realpath(sys.executable), sys.version, sys.path[1:])).encode())
    root = Path(__file__).resolve().parent
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d != "__pycache__")
        for name in sorted(filenames):
            if not name.endswith((".pyc", ".nbi", ".nbc")):  # numba's cache is not the code
                st = os.stat(os.path.join(dirpath, name))
                h.update(f"{dirpath}/{name}:{st.st_mtime_ns}:{st.st_size}\n".encode())
    for lib in _LIBRARIES:
        spec = find_spec(lib)
        origin = spec.origin if spec is not None else None
        if origin and os.path.exists(origin):
            st = os.stat(origin)
            h.update(f"{origin}:{st.st_mtime_ns}:{st.st_size}\n".encode())
    for name in sorted(env):
        if name.startswith(_ENV_PREFIXES) and name != ENV:
            h.update(f"{name}={env[name]}\n".encode())
    return h.hexdigest()[:20]


def home() -> Path:
    """The directory of the resident processes' sockets, locks and logs."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime:
        return Path(runtime) / "excite"
    return Path(os.environ.get("TMPDIR") or "/tmp") / f"excite-{os.getuid()}"


def private_home(create: bool) -> Path:
    """:func:`home`, created if asked; raises ``PermissionError`` unless it is a directory of
    this user that nobody else can enter (a socket there must not be someone else's)."""
    d = home()
    if create:
        try:
            os.mkdir(d, 0o700)
        except FileExistsError:
            pass
    st = os.lstat(d)
    import stat

    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
        raise PermissionError(f"{d} must be a directory of user {os.getuid()} that only it can enter "
                              f"(mode 700): the resident process's socket cannot be kept there")
    return d


def _paths(k: str, create: bool = False) -> dict[str, Path]:
    d = private_home(create)
    paths = {part: d / f"{k}.{part}" for part in ("sock", "lock", "log", "failed")}
    if len(str(paths["sock"])) > 100:  # sun_path holds 108 bytes
        raise OSError(f"{paths['sock']}: the path is too long for a Unix socket (set XDG_RUNTIME_DIR "
                      "to a shorter directory)")
    return paths


# --- the client: the `excite` script ----------------------------------------------------------


def _connect(k: str, timeout_s: float = 2.0) -> socket.socket | None:
    try:
        path = _paths(k)["sock"]
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    except OSError:
        return None
    s.settimeout(timeout_s)
    try:
        s.connect(str(path))
    except OSError:
        s.close()
        return None
    return s


def _send(s: socket.socket, request: dict, fds: list[int] = ()) -> None:
    body = json.dumps(request).encode()
    socket.send_fds(s, [_HEADER.pack(_MAGIC, len(body))], list(fds))
    s.sendall(body)


def _reply(f) -> dict | None:
    line = f.readline()
    return json.loads(line) if line else None


def control(op: str, k: str | None = None) -> dict | None:
    """Ask the resident process of key ``k`` (this installation's by default) for ``status``
    or to ``stop``; None when none is running."""
    s = _connect(k or key())
    if s is None:
        return None
    with s, s.makefile("rb") as f:
        try:
            _send(s, {"op": op})
            return _reply(f)
        except OSError:
            return None


def ask(argv: list[str]) -> int | None:
    """Run ``excite argv`` in the resident process; its exit code, or None when no resident
    process answers (the caller runs the command itself)."""
    if os.environ.get(ENV) == "0" or command_of(argv) not in SERVED:
        return None
    try:
        for fd in (0, 1, 2):
            os.fstat(fd)
    except OSError:  # a closed standard stream cannot be passed on
        return None
    k = key()
    s = _connect(k)
    if s is None:
        return None
    streams = (sys.stdin, sys.stdout, sys.stderr)
    request = {"op": "run", "key": k, "argv": argv, "cwd": os.getcwd(), "env": dict(os.environ),
               "encoding": [getattr(x, "encoding", None) or "utf-8" for x in streams],
               "errors": [getattr(x, "errors", None) or "strict" for x in streams]}
    with s, s.makefile("rb") as f:
        try:
            _send(s, request, [0, 1, 2])
            s.settimeout(10.0)
            started = _reply(f)
        except (OSError, ValueError):
            return None
        if not started or "pid" not in started:
            return None  # refused (another installation's key) or gone: run it here
        import signal

        forwarded: list[int] = []

        def forward(signum, _frame):
            forwarded.append(signum)
            try:
                s.send(bytes([signum]))
            except OSError:
                pass

        for name in _SIGNALS:
            signal.signal(getattr(signal, name), forward)
        s.settimeout(None)
        try:
            done = _reply(f)
        except (OSError, ValueError):
            done = None
    if done is not None and "exit" in done:
        return int(done["exit"])
    if forwarded:
        return 128 + forwarded[-1]
    print(f"excite: error: the resident process's command {started['pid']} ended without an exit code "
          f"(its log: {_paths(k)['log']}); EXCITE_RESIDENT=0 runs commands in this process",
          file=sys.stderr)
    return 1


def start(idle_minutes: float = IDLE_MINUTES, wait_s: float = 0.0) -> int:
    """Start a resident process for this installation in the background; its pid. With
    ``wait_s`` > 0, wait up to that long until it answers (loading excite takes a few seconds,
    a minute when numba compiles the kernels first)."""
    import subprocess

    paths = _paths(key(), create=True)
    paths["failed"].unlink(missing_ok=True)
    with open(paths["log"], "wb") as log:
        proc = subprocess.Popen([sys.executable, "-c", "from excite.resident import main; main()",
                                 repr(float(idle_minutes))],
                                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True, close_fds=True)  # the caller's directory: a
        # relative entry of PYTHONPATH resolves in it, as it did for the caller (and the key)
    deadline = time.monotonic() + wait_s
    while wait_s > 0 and control("status") is None:
        if proc.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError(f"the resident process did not start (its log: {paths['log']})")
        time.sleep(0.1)
    return proc.pid


def may_start(argv: list[str]) -> None:
    """After a served command ran in this process at a terminal: start a resident process for
    the next ones, unless turned off or one failed to start for this very installation."""
    if os.environ.get(ENV) == "0" or command_of(argv) not in SERVED:
        return
    try:
        if not (os.isatty(0) and os.isatty(2)):
            return
        k = key()
        paths = _paths(k, create=True)
        if paths["failed"].exists() or _connect(k) is not None:
            return
        pid = start()
    except (OSError, RuntimeError):
        return
    print(f"excite: started a resident process (pid {pid}) that keeps excite loaded so the next "
          f"commands start at once; it leaves after {IDLE_MINUTES:g} minutes unused "
          "(`excite resident stop` ends it, EXCITE_RESIDENT=0 turns it off)", file=sys.stderr)


def run() -> None:
    """The ``excite`` script: the resident process runs the command when it can, this process
    otherwise (:func:`excite.cli.run`), then offers to start one."""
    argv = sys.argv[1:]
    rc = ask(argv)
    if rc is not None:
        sys.exit(rc)
    from .cli import main, leave

    rc = main(argv)
    may_start(argv)
    leave(rc)


# --- the resident process -------------------------------------------------------------------


class _Resident:
    def __init__(self, k: str, idle_s: float):
        self.key, self.idle_s = k, idle_s
        self.started = time.time()
        self.last = time.monotonic()
        self.children: set[int] = set()
        self.served = 0
        self.stop = False

    def status(self) -> dict:
        return {"pid": os.getpid(), "key": self.key, "started": self.started, "served": self.served,
                "running": len(self.children), "idle_s": round(time.monotonic() - self.last, 1),
                "leaves_after_idle_s": self.idle_s, "python": sys.executable}

    def reap(self) -> None:
        for pid in list(self.children):
            try:
                done, _ = os.waitpid(pid, os.WNOHANG)
            except ChildProcessError:
                done = pid
            if done:
                self.children.discard(pid)
                self.last = time.monotonic()

    def handle(self, conn: socket.socket, listener: socket.socket) -> None:
        conn.settimeout(5.0)
        fds: list[int] = []
        try:
            creds = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
            if struct.unpack("3i", creds)[1] != os.getuid():
                return
            head, fds, _, _ = socket.recv_fds(conn, _HEADER.size, 3)
            if len(head) != _HEADER.size:
                return
            magic, n = _HEADER.unpack(head)
            if magic != _MAGIC or n > _MAX_REQUEST:
                return
            body = b""
            while len(body) < n:
                part = conn.recv(n - len(body))
                if not part:
                    return
                body += part
            request = json.loads(body)
            op = request.get("op")
            if op == "status":
                conn.sendall(json.dumps(self.status()).encode() + b"\n")
            elif op == "stop":
                self.stop = True
                conn.sendall(json.dumps({"stopping": os.getpid()}).encode() + b"\n")
            elif op == "run" and len(fds) == 3:
                if request.get("key") != self.key:
                    conn.sendall(b'{"refused": "another installation or environment"}\n')
                    return
                pid = os.fork()
                if pid == 0:
                    listener.close()
                    code = 1
                    try:
                        code = _command(conn, fds, request)
                    finally:
                        os._exit(code)
                self.children.add(pid)
                self.served += 1
        except (OSError, ValueError):
            pass
        finally:
            for fd in fds:
                os.close(fd)
            conn.close()
            self.last = time.monotonic()


def _stdio(encoding: list[str], errors: list[str]) -> None:
    """Fresh ``sys.std*`` over descriptors 0–2, buffered as Python buffers them for the caller."""
    import io

    sys.stdin = sys.__stdin__ = io.TextIOWrapper(io.BufferedReader(io.FileIO(0, "r", closefd=False)),
                                                 encoding=encoding[0], errors=errors[0])
    for fd, name in ((1, "stdout"), (2, "stderr")):
        stream = io.TextIOWrapper(io.BufferedWriter(io.FileIO(fd, "w", closefd=False)),
                                  encoding=encoding[fd], errors=errors[fd],
                                  line_buffering=fd == 2 or os.isatty(fd), write_through=fd == 2)
        setattr(sys, name, stream)
        setattr(sys, f"__{name}__", stream)


def _command(conn: socket.socket, fds: list[int], request: dict) -> int:
    """The forked child: become the caller's command and run it."""
    import signal
    import threading

    signal.signal(signal.SIGINT, signal.default_int_handler)
    for name in ("SIGTERM", "SIGHUP", "SIGQUIT"):
        signal.signal(getattr(signal, name), signal.SIG_DFL)
    for target, fd in enumerate(fds):
        os.dup2(fd, target)
        os.close(fd)
    fds.clear()
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    time.tzset()
    argv = list(request["argv"])
    sys.argv = ["excite", *argv]
    _stdio(request["encoding"], request["errors"])
    conn.settimeout(None)
    conn.sendall(json.dumps({"pid": os.getpid()}).encode() + b"\n")

    main_thread = threading.get_ident()

    def watch() -> None:  # the caller's forwarded signals; its end ends the command
        signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT])
        while True:
            try:
                got = conn.recv(1)
            except OSError:
                got = b""
            # to the main thread, so that a system call it waits in is interrupted
            signal.pthread_kill(main_thread, got[0] if got else signal.SIGTERM)
            if not got:
                return

    threading.Thread(target=watch, daemon=True).start()
    from .cli import main

    try:
        rc = main(argv)
    except KeyboardInterrupt:  # as the command line ends at Ctrl-C (click's Abort)
        rc = 130
    except SystemExit as exc:
        rc = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:
        import traceback

        traceback.print_exc()
        rc = 1
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    conn.sendall(json.dumps({"exit": rc}).encode() + b"\n")
    return rc


def _warm_up() -> None:
    """Load what the served commands load: excite's command modules, and every kernel and scipy
    part of scoring (by scoring a short drive in each route format the CLI reads)."""
    import contextlib
    import gc
    import io
    import tempfile

    import numpy as np

    from . import cli, parallel, routes
    from .vehicle import ControlProfile, drive

    for command in sorted(SERVED):
        cli.register([command])
    t = np.linspace(0.0, 30.0, 61)
    traj = drive(ControlProfile(t, 5 + np.sin(t / 5), 0.1 * np.sin(t / 3)))
    with tempfile.TemporaryDirectory() as d:
        files = [routes.write_tum(traj, Path(d) / "warm.tum"), routes.write_control_csv(traj, Path(d) / "warm.csv"),
                 routes.write_waypoints_csv(traj, Path(d) / "warm_waypoints.csv")]
        for f in files:
            with contextlib.redirect_stdout(io.StringIO()):
                rc = cli.main(["score", str(f), "--json"])
            if rc != 0:
                raise RuntimeError(f"scoring {f.name} while warming up failed (exit code {rc})")
    parallel.close()  # no thread may live across a fork
    gc.collect()
    gc.freeze()  # the children's collector leaves the loaded modules alone (no copy-on-write)


def main() -> None:
    """The resident process (started by :func:`start`; argument: idle minutes)."""
    import fcntl
    import select
    import signal

    idle_s = 60.0 * float(sys.argv[1]) if len(sys.argv) > 1 else 60.0 * IDLE_MINUTES
    k = key()
    del sys.path[0]  # `python -c`'s "": modules come from where the `excite` script finds them
    os.chdir("/")  # every command runs in its caller's directory
    paths = _paths(k, create=True)
    lock = open(paths["lock"], "w")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        print(f"a resident process of key {k} is already running", flush=True)
        return
    try:
        _warm_up()
    except BaseException:
        import traceback

        paths["failed"].write_text(traceback.format_exc())
        raise
    resident = _Resident(k, idle_s)
    signal.signal(signal.SIGTERM, lambda *_: setattr(resident, "stop", True))
    paths["sock"].unlink(missing_ok=True)
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(str(paths["sock"]))
    os.chmod(paths["sock"], 0o600)
    listener.listen(16)
    print(f"resident process {os.getpid()} of key {k} ready; leaves after {idle_s:g} s idle", flush=True)
    try:
        while not resident.stop:
            resident.reap()
            if not resident.children and time.monotonic() - resident.last > resident.idle_s:
                break
            try:
                ready, _, _ = select.select([listener], [], [], 0.5)
            except InterruptedError:
                continue
            if ready:
                conn, _ = listener.accept()
                resident.handle(conn, listener)
    finally:
        listener.close()
        paths["sock"].unlink(missing_ok=True)
        print(f"resident process {os.getpid()} leaves after {resident.served} commands", flush=True)
