"""The ``excite`` command, answered by a resident process when one is running.

A cold ``excite score`` spends about 1.4 s before it computes anything: numba's registries and
its cached kernels, scipy's interpolate and spatial packages (the README's "Cold start of the
command line"); scoring the bundled figure-eight then takes 0.05 s. A person working on a route
at a terminal pays that on every command. So the ``excite`` script first asks a *resident
process* of this very installation to run the command. That process has imported excite and
loaded every kernel once; for each command it forks a child, and the child takes on the
caller's working directory, environment, standard streams (their file descriptors are passed
over a Unix socket, so a terminal stays a terminal and a pipe a pipe), umask, niceness, CPU
affinity and resource limits, and runs the command as the caller would have
(:func:`excite.cli.app.main`) in a process group of its own. Its exit code becomes the caller's.

- **Which commands:** :data:`SERVED` — the short ones a person waits on. Commands that run for
  minutes or manage processes of their own (``serve``, ``live``, ``optimize``, ``validate``,
  ``mine``) always run in the calling process: a second saved is nothing to them.
- **Which resident process:** the socket is named by :func:`key`, a hash of the interpreter,
  ``sys.path``, the size and modification time of every file of the excite package, the
  installed numpy/scipy/numba/typer/rich/pydantic/yaml/fsspec, the user, groups, control group
  and namespaces, and the environment variables that change what excite computes or how it
  reads file names (``EXCITE_*``, ``NUMBA_*``, ``PYTHON*``, ``FSSPEC_*``, the locale, thread
  counts). Any change means another key: the next command runs in the caller (and, at a
  terminal, replaces a resident process of the same installation that no longer matches).
- **Lifetime:** ``excite resident start`` starts one; so does the first served command run at a
  terminal (standard input and error both terminals) when none is running, after that command
  has finished, saying so in one line on stderr. It leaves after :data:`IDLE_MINUTES` minutes
  without a command, or at ``excite resident stop``. ``EXCITE_RESIDENT=0`` (or ``false``,
  ``off``, ``no``) makes excite neither use nor start one. Linux only (it passes descriptors
  and checks its peers' credentials the Linux way); elsewhere every command runs in the caller.
- **Privacy:** the socket lives in a directory only its user can enter (``$XDG_RUNTIME_DIR/excite``
  when that runtime directory is the user's, else ``/tmp/excite-UID``, checked before every
  use); the resident process serves only connections of its own user and the caller talks only
  to a resident process of its own user (``SO_PEERCRED`` both ways).
- **Signals:** Ctrl-C, SIGTERM, SIGHUP and SIGQUIT of the caller are forwarded to the command's
  process group (the processes it started included), Ctrl-Z stops it with the caller; a caller
  that disappears takes its command with it; a caller whose command died of a signal dies of
  the same signal.

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

from .commands import command_of

SERVED = frozenset({"score", "route", "rig", "batch"})
IDLE_MINUTES = 30.0
ENV = "EXCITE_RESIDENT"  # "0", "false", "off", "no": neither use nor start a resident process
_MAGIC = b"EXCR"
_HEADER = struct.Struct("!4sI")
_MAX_REQUEST = 1 << 20  # bytes of a request (argv, environment): far above any real one
_ENV_PREFIXES = ("EXCITE_", "NUMBA_", "PYTHON", "FSSPEC_", "LANG", "LC_", "LOCPATH", "OMP_", "OPENBLAS_",
                 "MKL_", "NUMEXPR_")
_LIBRARIES = ("numpy", "scipy", "numba", "llvmlite", "typer", "click", "rich", "pydantic", "yaml", "fsspec")
_FORWARDED = ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT")
_LOST_THE_LOCK = 3  # exit code of a resident process that found another one of its key starting
_RLIMITS = ("RLIMIT_AS", "RLIMIT_CORE", "RLIMIT_CPU", "RLIMIT_DATA", "RLIMIT_FSIZE", "RLIMIT_MEMLOCK",
            "RLIMIT_NOFILE", "RLIMIT_NPROC", "RLIMIT_RSS", "RLIMIT_STACK")


# --- where, and which ---------------------------------------------------------------------


def enabled() -> bool:
    """Whether this process may use or start a resident process (Linux, not turned off)."""
    return sys.platform.startswith("linux") and os.environ.get(ENV, "").lower() not in {"0", "false", "off", "no"}


def _stat(path: str) -> str:
    try:
        st = os.stat(path)
    except OSError:  # a dangling link (an editor's lock file), a file removed meanwhile
        return f"{path}:-\n"
    return f"{path}:{st.st_mtime_ns}:{st.st_size}\n"


def _identity() -> str:
    """Who and where this process is: user, groups, control group, namespaces (a caller in a
    container or a memory-limited scope is not served by a process outside it)."""
    parts = [str((os.getuid(), os.getgid(), sorted(os.getgroups())))]
    for ns in ("mnt", "net", "pid", "user"):
        try:
            parts.append(os.readlink(f"/proc/self/ns/{ns}"))
        except OSError:
            parts.append("-")
    try:
        parts.append(Path("/proc/self/cgroup").read_text())
    except OSError:
        parts.append("-")
    return "\n".join(parts)


def key(env: dict[str, str] | None = None) -> str:
    """What a resident process must share with the caller to answer for it (see the module doc)."""
    import hashlib
    from importlib.util import find_spec

    env = os.environ if env is None else env
    # sys.path[0] is the script's folder (the `excite` script's, "" for `python -c`) unless
    # Python runs with a safe path
    path = sys.path if getattr(sys.flags, "safe_path", False) else sys.path[1:]
    h = hashlib.sha256(repr((os.path.realpath(sys.executable), sys.version, path)).encode())
    h.update(_identity().encode())
    root = Path(__file__).resolve().parent
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d != "__pycache__")
        for name in sorted(filenames):
            if not name.endswith((".pyc", ".nbi", ".nbc")):  # numba's cache is not the code
                h.update(_stat(os.path.join(dirpath, name)).encode())
    for lib in _LIBRARIES:
        spec = find_spec(lib)
        if spec is not None and spec.origin:
            h.update(_stat(spec.origin).encode())
    for name in sorted(env):
        if name.startswith(_ENV_PREFIXES) and name != ENV:
            h.update(f"{name}={env[name]}\n".encode())
    return h.hexdigest()[:20]


def home() -> Path:
    """The directory of the resident processes' sockets, locks and logs: in the user's runtime
    directory when there is one and it is the user's (not under ``sudo -E``), else in /tmp."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    try:
        if runtime and os.stat(runtime).st_uid == os.getuid():
            return Path(runtime) / "excite"
    except OSError:
        pass
    return Path(os.environ.get("TMPDIR") or "/tmp") / f"excite-{os.getuid()}"


def private_home(create: bool) -> Path:
    """:func:`home`, created if asked; raises ``PermissionError`` unless it is a directory of
    this user that nobody else can enter (a socket there must not be someone else's)."""
    import stat

    d = home()
    if create:
        try:
            os.mkdir(d, 0o700)
        except FileExistsError:
            pass
    st = os.lstat(d)
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
        raise PermissionError(f"{d} must be a directory of user {os.getuid()} that only it can enter "
                              f"(mode 700): the resident process's socket cannot be kept there")
    return d


def paths_of(k: str, create: bool = False) -> dict[str, Path]:
    d = private_home(create)
    paths = {part: d / f"{k}.{part}" for part in ("sock", "lock", "log", "failed")}
    if len(str(paths["sock"])) > 100:  # sun_path holds 108 bytes
        raise OSError(f"{paths['sock']}: the path is too long for a Unix socket (set XDG_RUNTIME_DIR "
                      "to a shorter directory)")
    return paths


def _installation() -> dict[str, str]:
    """The interpreter and the excite package of this process (what the resident processes of
    one installation share whatever their key)."""
    return {"python": os.path.realpath(sys.executable), "package": str(Path(__file__).resolve().parent)}


def _peer_uid(s: socket.socket) -> int:
    creds = s.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    return struct.unpack("3i", creds)[1]


# --- the client: the `excite` script ----------------------------------------------------------


def _connect(path: Path, timeout_s: float = 2.0) -> socket.socket | None:
    """A connection to the resident process listening at ``path`` when it is this user's."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(timeout_s)
    try:
        s.connect(str(path))
        if _peer_uid(s) == os.getuid():
            return s
    except OSError:
        pass
    s.close()
    return None


def _send(s: socket.socket, request: dict, fds: list[int] = ()) -> None:
    body = json.dumps(request).encode()
    socket.send_fds(s, [_HEADER.pack(_MAGIC, len(body))], list(fds))
    s.sendall(body)


def _reply(f) -> dict | None:
    line = f.readline()
    answer = json.loads(line) if line else None
    return answer if isinstance(answer, dict) else None


def control(op: str, k: str | None = None, path: Path | None = None) -> dict | None:
    """Ask the resident process of key ``k`` (this installation's by default; or the one at
    socket ``path``) for its ``status`` or to ``stop``; None when none answers."""
    try:
        s = _connect(path or paths_of(k or key())["sock"])
    except OSError:
        return None
    if s is None:
        return None
    with s, s.makefile("rb") as f:
        try:
            _send(s, {"op": op})
            return _reply(f)
        except (OSError, ValueError):
            return None


def _settings() -> dict:
    """The caller's process settings a child must take on: umask, niceness, CPU affinity and
    resource limits."""
    import resource

    mask = os.umask(0o022)
    os.umask(mask)
    return {"umask": mask, "nice": os.getpriority(os.PRIO_PROCESS, 0), "affinity": sorted(os.sched_getaffinity(0)),
            "rlimits": {name: list(resource.getrlimit(getattr(resource, name)))
                        for name in _RLIMITS if hasattr(resource, name)}}


def ask(argv: list[str]) -> int | None:
    """Run ``excite argv`` in the resident process; its exit code, or None when no resident
    process answers or it declines (the caller runs the command itself)."""
    if not enabled() or command_of(argv) not in SERVED:
        return None
    try:
        for fd in (0, 1, 2):
            os.fstat(fd)  # a closed standard stream cannot be passed on
        k = key()
        s = _connect(paths_of(k)["sock"])
        if s is None:
            return None
        streams = (sys.stdin, sys.stdout, sys.stderr)
        request = {"op": "run", "key": k, "argv": argv, "cwd": os.getcwd(), "env": dict(os.environ),
                   "settings": _settings(),
                   "encoding": [getattr(x, "encoding", None) or "utf-8" for x in streams],
                   "errors": [getattr(x, "errors", None) or "strict" for x in streams]}
    except OSError:  # no working directory any more, no runtime directory, …: run it here
        return None
    with s, s.makefile("rb") as f:
        return _served(s, f, k, request)


def _served(s: socket.socket, f, k: str, request: dict) -> int | None:
    import signal

    forwarded: list[int] = []

    def send(signum: int) -> None:
        try:
            s.send(bytes([signum]))
        except OSError:
            pass

    def forward(signum, _frame) -> None:
        forwarded.append(signum)
        send(signum)

    def stop(_signum, _frame) -> None:  # Ctrl-Z: the command stops with the caller, and goes on with it
        send(signal.SIGSTOP)
        os.kill(os.getpid(), signal.SIGSTOP)
        if started and "pid" in started:  # its process group is its pid (a stopped command cannot read a byte)
            try:
                os.killpg(started["pid"], signal.SIGCONT)
            except OSError:
                pass

    started: dict | None = None
    handled = [getattr(signal, name) for name in _FORWARDED] + [signal.SIGTSTP]
    # handlers in place before the command can start, and no signal byte inside the request
    signal.pthread_sigmask(signal.SIG_BLOCK, handled)
    before = {sig: signal.getsignal(sig) for sig in handled}
    for sig in handled:
        signal.signal(sig, stop if sig == signal.SIGTSTP else forward)
    try:
        _send(s, request, [0, 1, 2])
        sent = True
    except OSError:
        sent = False
    signal.pthread_sigmask(signal.SIG_UNBLOCK, handled)
    if sent:
        try:
            s.settimeout(10.0)
            started = _reply(f)
        except (OSError, ValueError):
            pass
    if not started or "pid" not in started:  # declined (another key, settings it cannot take on)
        for sig, handler in before.items():  # or gone: run it here
            signal.signal(sig, handler)
        if forwarded:  # the caller was interrupted meanwhile: as it would have been
            _die(forwarded[-1])
        return None
    s.settimeout(None)
    try:
        done = _reply(f)
    except (OSError, ValueError):
        done = None
    if done is not None and "exit" in done:
        return int(done["exit"])
    if forwarded:
        _die(forwarded[-1])
    if done is not None and "signal" in done:
        _die(done["signal"])
    print(f"excite: error: the resident process's command {started['pid']} ended without an exit code "
          f"(its log: {paths_of(k)['log']}); EXCITE_RESIDENT=0 runs commands in this process",
          file=sys.stderr)
    return 1


def _die(signum: int) -> None:
    """End this process by signal ``signum``, as the command run here would have ended."""
    import signal

    sys.stdout.flush()
    signal.signal(signum, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signum])
    os.kill(os.getpid(), signum)
    time.sleep(1.0)
    os._exit(128 + signum)


def start(idle_minutes: float = IDLE_MINUTES, wait_s: float = 0.0) -> int:
    """Start a resident process for this installation in the background; its pid. With
    ``wait_s`` > 0, wait up to that long until it (or one started meanwhile by another command)
    answers: loading excite takes a few seconds, a minute when numba compiles the kernels first."""
    import subprocess

    if not sys.platform.startswith("linux"):
        raise RuntimeError("the resident process runs on Linux only")
    k = key()
    paths = paths_of(k, create=True)
    paths["failed"].unlink(missing_ok=True)
    with open(paths["log"], "ab") as log:  # the resident process that takes the lock empties it
        proc = subprocess.Popen([sys.executable, "-c", "from excite.cli.resident_process import main; main()",
                                 repr(float(idle_minutes))],
                                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True, close_fds=True)  # the caller's directory: a
        # relative entry of PYTHONPATH resolves in it, as it did for the caller (and the key)
    deadline = time.monotonic() + wait_s
    while wait_s > 0 and (answer := control("status", k)) is None:
        if proc.poll() not in (None, _LOST_THE_LOCK) or time.monotonic() > deadline:
            raise RuntimeError(f"the resident process did not start (its log: {paths['log']})")
        time.sleep(0.1)
    return answer["pid"] if wait_s > 0 else proc.pid


def _retire_others(k: str) -> None:
    """Stop the resident processes of this same installation whose key no longer matches (a
    source file edited, a setting changed): nothing will ask them again."""
    me = _installation()
    for sock in private_home(False).glob("*.sock"):
        if sock.name != f"{k}.sock":
            status = control("status", path=sock)
            if status is not None and {name: status.get(name) for name in me} == me:
                control("stop", path=sock)


def may_start(argv: list[str]) -> None:
    """After a served command ran in this process at a terminal: start a resident process for
    the next ones, unless turned off or one failed to start for this very installation."""
    if not enabled() or command_of(argv) not in SERVED:
        return
    try:
        if not (os.isatty(0) and os.isatty(2)):
            return
        k = key()
        paths = paths_of(k, create=True)
        if paths["failed"].exists() or control("status", k) is not None:
            return
        pid = start()
        _retire_others(k)
    except (OSError, RuntimeError):
        return
    print(f"excite: started a resident process (pid {pid}) that keeps excite loaded so the next "
          f"commands start at once; it leaves after {IDLE_MINUTES:g} minutes unused "
          "(`excite resident stop` ends it, EXCITE_RESIDENT=0 turns it off)", file=sys.stderr)


def run() -> None:
    """The ``excite`` script: the resident process runs the command when it can, this process
    otherwise (:func:`excite.cli.app.main`), then offers to start one."""
    argv = sys.argv[1:]
    rc = ask(argv)
    if rc is not None:
        sys.exit(rc)
    from .app import leave, main

    rc = main(argv)
    may_start(argv)
    leave(rc)


# --- the resident process -------------------------------------------------------------------


class _Resident:
    def __init__(self, k: str, idle_s: float, listener: socket.socket, lock):
        self.key, self.idle_s, self.listener, self.lock = k, idle_s, listener, lock
        self.started = time.time()
        self.last = time.monotonic()
        self.children: dict[int, socket.socket] = {}  # pid → its caller's connection
        self.pending: dict[socket.socket, float] = {}  # accepted, request not read yet → since
        self.served = 0
        self.stop = False

    def status(self) -> dict:
        return {"pid": os.getpid(), "key": self.key, "started": self.started, "served": self.served,
                "running": len(self.children), "commands": sorted(self.children), "idle_s": round(time.monotonic() - self.last, 1),
                "leaves_after_idle_s": self.idle_s, **_installation()}

    def serve(self) -> None:
        import select

        while not self.stop:
            self.reap()
            now = time.monotonic()
            for conn, since in list(self.pending.items()):
                if now - since > 5.0:  # connected and said nothing
                    self.pending.pop(conn).close()
            if not self.children and not self.pending and now - self.last > self.idle_s:
                return
            try:
                ready, _, _ = select.select([self.listener, *self.pending], [], [], 0.5)
            except InterruptedError:
                continue
            for r in ready:
                if r is self.listener:
                    conn, _ = self.listener.accept()
                    self.pending[conn] = time.monotonic()
                else:
                    del self.pending[r]
                    self.handle(r)

    def reap(self) -> None:
        for pid in list(self.children):
            try:
                done, status = os.waitpid(pid, os.WNOHANG)
            except ChildProcessError:
                done, status = pid, 0
            if not done:
                continue
            conn = self.children.pop(pid)
            if os.WIFSIGNALED(status):  # the command could not say so itself
                print(f"command {pid} died of signal {os.WTERMSIG(status)}", flush=True)
                try:
                    conn.settimeout(0.5)
                    conn.sendall(json.dumps({"signal": os.WTERMSIG(status)}).encode() + b"\n")
                except OSError:
                    pass
            conn.close()
            self.last = time.monotonic()

    def handle(self, conn: socket.socket) -> None:
        """Read one request (it was sent at once: its first bytes are here) and answer it."""
        fds: list[int] = []
        keep = False
        try:
            conn.settimeout(1.0)
            if _peer_uid(conn) != os.getuid():
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
            op = request.get("op") if isinstance(request, dict) else None
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
                    code = 1
                    try:
                        # nothing of the resident process's own may outlive it in the command's
                        # processes (its lock, its listening socket, other callers' connections)
                        for other in [self.listener, *self.pending, *self.children.values()]:
                            other.close()
                        self.lock.close()
                        code = _command(conn, fds, request)
                    finally:
                        os._exit(code)
                self.children[pid] = conn
                self.served += 1
                keep = True
        except (OSError, ValueError, TypeError, KeyError):
            pass  # a request that is not one of ours: dropped
        finally:
            for fd in fds:
                os.close(fd)
            if not keep:
                conn.close()
            self.last = time.monotonic()


def _stdio(encoding: list[str], errors: list[str], unbuffered: bool) -> None:
    """Fresh ``sys.std*`` over descriptors 0–2, buffered as Python buffers them for the caller."""
    import io

    sys.stdin = sys.__stdin__ = io.TextIOWrapper(io.BufferedReader(io.FileIO(0, "r", closefd=False)),
                                                 encoding=encoding[0], errors=errors[0])
    for fd, name in ((1, "stdout"), (2, "stderr")):
        stream = io.TextIOWrapper(io.BufferedWriter(io.FileIO(fd, "w", closefd=False)),
                                  encoding=encoding[fd], errors=errors[fd],
                                  line_buffering=fd == 2 or os.isatty(fd), write_through=fd == 2 or unbuffered)
        setattr(sys, name, stream)
        setattr(sys, f"__{name}__", stream)


def _take_on(settings: dict) -> str | None:
    """Take on the caller's process settings; what cannot be taken on (a lower niceness, a
    higher hard limit than this process has), or None."""
    import resource

    os.umask(settings["umask"])
    try:
        os.setpriority(os.PRIO_PROCESS, 0, settings["nice"])
    except OSError:
        return f"niceness {settings['nice']}"
    try:
        os.sched_setaffinity(0, settings["affinity"])
    except OSError:
        return f"CPU affinity {settings['affinity']}"
    for name, (soft, hard) in settings["rlimits"].items():
        try:
            resource.setrlimit(getattr(resource, name), (soft, hard))
        except (OSError, ValueError, AttributeError):
            return f"{name} {soft, hard}"
    return None


def _command(conn: socket.socket, fds: list[int], request: dict) -> int:
    """The forked child: become the caller's command and run it."""
    import signal
    import tempfile
    import threading

    os.setpgid(0, 0)  # the command and the processes it starts: one group, as at a terminal
    forwarded = [getattr(signal, name) for name in _FORWARDED]
    for sig in forwarded:  # as in a fresh process: Ctrl-C raises KeyboardInterrupt, the others end it
        signal.signal(sig, signal.default_int_handler if sig == signal.SIGINT else signal.SIG_DFL)
    conn.settimeout(None)
    declined = _take_on(request["settings"])
    if declined is not None:
        conn.sendall(json.dumps({"refused": f"cannot take on the caller's {declined}"}).encode() + b"\n")
        return 0
    for target, fd in enumerate(fds):
        os.dup2(fd, target)
        os.close(fd)
    fds.clear()
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    time.tzset()
    tempfile.tempdir = None  # chosen again from this environment's TMPDIR
    argv = list(request["argv"])
    sys.argv = ["excite", *argv]
    _stdio(request["encoding"], request["errors"], bool(request["env"].get("PYTHONUNBUFFERED")))
    conn.sendall(json.dumps({"pid": os.getpid()}).encode() + b"\n")

    def watch() -> None:  # the caller's forwarded signals, to the whole group; its end ends it
        signal.pthread_sigmask(signal.SIG_BLOCK, forwarded)
        while True:
            try:
                got = conn.recv(1)
            except OSError:
                got = b""
            os.killpg(0, got[0] if got else signal.SIGTERM)
            if not got:
                return

    threading.Thread(target=watch, daemon=True).start()
    # a process the command forks (batch's workers) must not hold the caller's connection: the
    # caller would wait for it, and could not tell its command has ended
    os.register_at_fork(after_in_child=conn.close)
    from .app import main

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

    from . import app as cli
    from ..core import parallel
    from ..io import routes
    from ..motion.vehicle import ControlProfile, drive

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
    import signal

    idle_s = 60.0 * float(sys.argv[1]) if len(sys.argv) > 1 else 60.0 * IDLE_MINUTES
    k = key()
    if not getattr(sys.flags, "safe_path", False):
        del sys.path[0]  # `python -c`'s "": modules come from where the `excite` script finds them
    os.chdir("/")  # every command runs in its caller's directory
    paths = paths_of(k, create=True)
    lock = open(paths["lock"], "w")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:  # another one of this key is starting or running
        sys.exit(_LOST_THE_LOCK)
    os.truncate(paths["log"], 0)  # this process's log from here (the file is opened for appending)
    try:
        _warm_up()
    except BaseException:
        import traceback

        paths["failed"].write_text(traceback.format_exc())
        raise
    paths["sock"].unlink(missing_ok=True)
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(str(paths["sock"]))
    os.chmod(paths["sock"], 0o600)
    listener.listen(64)
    resident = _Resident(k, idle_s, listener, lock)
    signal.signal(signal.SIGTERM, lambda *_: setattr(resident, "stop", True))
    print(f"resident process {os.getpid()} of key {k} ready; leaves after {idle_s:g} s idle", flush=True)
    try:
        resident.serve()
    finally:
        listener.close()
        paths["sock"].unlink(missing_ok=True)
        print(f"resident process {os.getpid()} leaves after {resident.served} commands", flush=True)
