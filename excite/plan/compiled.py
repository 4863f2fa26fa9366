"""CasADi functions compiled to C with the system compiler, cached per problem shape.

The optimizer's information model (:func:`.model.build_model` of the coarse rig, for one number
of keyframes) and its reverse sweep dominate an IPOPT iteration in CasADi's virtual machine;
compiled, they run several times faster with bit-identical results. Code generation
(``casadi.CodeGenerator``) takes a second, the C compiler minutes for the 90 s problem (the model
derived from the kinds' residuals is 6 MB of C: 534 s at load 5–8 on 2 cores), so the shared
library is cached: under :func:`cache_dir`, one file per *key* — a hash
of what the functions are built from (the coarse rig, the keyframe count, the CasADi version and
the source of every module that builds the functions). A cached library is found by its key
alone, without building the functions it was compiled from (that is the start-up it saves): the
key must name every input and every source module, or a stale entry would be trusted.

On a miss, :func:`load` says so in one line and the run uses the virtual machine;
``wait=True`` (``excite optimize --compile-only``, the container image's build) generates the C
source and compiles it before returning. The compiler runs as a command of
:mod:`excite.core.processes`: it and its passes end with the call — past
:data:`COMPILE_TIMEOUT_S`, on Ctrl-C or any exception, and when the calling process dies — so no
compile outlives the command, job or test that started it. Where no C compiler exists, or with
``EXCITE_COMPILE=0``, a library the cache holds is still used.

Environment: ``EXCITE_CACHE_DIR`` (default ``$XDG_CACHE_HOME/excite``, ``~/.cache/excite``),
``CC`` (default ``cc``, else ``gcc``), ``EXCITE_COMPILE`` (``0``: never start the compiler).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import casadi as ca

from ..core import processes
from ..errors import WorkerDied, WorkTimeout

FLAGS = ("-O2", "-shared", "-fPIC")
# the compiler is ended past this (the 90 s problem's model: 534 s at load 5-8 on 2 cores), and
# a lock older than this, or whose process is gone, belongs to a compile that died
COMPILE_TIMEOUT_S = 4 * 3600.0
LOCK_STALE_S = COMPILE_TIMEOUT_S


def cache_dir() -> Path:
    """Where compiled functions (and other per-problem caches) live."""
    base = os.environ.get("EXCITE_CACHE_DIR")
    if base:
        return Path(base)
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "excite"


def compiler() -> str | None:
    """The C compiler to use, or None when there is none (or compiling is disabled)."""
    if os.environ.get("EXCITE_COMPILE", "1").strip().lower() in ("0", "no", "false", "off"):
        return None
    for cc in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if cc and (path := shutil.which(cc)):
            return path
    return None


_PACKAGE = Path(__file__).resolve().parents[1]


def key_of(*parts: object, sources: Sequence[Path] = ()) -> str:
    """A hash of ``parts`` (their ``repr``), the CasADi version, the compiler flags and the
    text of ``sources`` (named relative to the package: an image built elsewhere matches)."""
    h = hashlib.sha256()
    h.update(repr((ca.__version__, FLAGS, parts)).encode())
    for p in sorted(Path(s).resolve() for s in sources):
        try:
            name = str(p.relative_to(_PACKAGE))
        except ValueError:
            name = p.name
        h.update(name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:24]


@dataclass
class Loaded:
    """The functions (by name), how they run (``compiled`` or ``virtual machine``) and, when
    not compiled, the one-line reason."""

    functions: dict[str, ca.Function]
    mode: str
    note: str = ""
    seconds: dict[str, float] = field(default_factory=dict)


def _library(name: str, key: str) -> Path:
    return cache_dir() / "casadi" / f"{name}_{key}.so"


def load(name: str, names: Sequence[str], key: str, build: Callable[[], Sequence[ca.Function]],
         wait: bool = False, what: str = "the optimizer's model") -> Loaded:
    """The functions ``names`` compiled (from the cache, or compiled now with ``wait``), else as
    ``build()`` makes them (called only when needed: the virtual machine, or code generation).
    A cached library that cannot be loaded is deleted and rebuilt.
    """
    t0 = time.perf_counter()
    lib = _library(name, key)
    seconds: dict[str, float] = {}
    note = ""
    if lib.exists():
        try:
            loaded = {n: ca.external(n, str(lib)) for n in names}
            why = ""
        except RuntimeError as exc:
            loaded, why = None, f"cannot load {lib.name}: {str(exc).splitlines()[0][:120]}"
        if loaded is not None:
            seconds["load"] = time.perf_counter() - t0
            return Loaded(loaded, "compiled", "", seconds)
        lib.unlink(missing_ok=True)
        note = f"{why}: " + ("rebuilding it" if wait else "deleted it")
    functions = list(build())
    vm = {f.name(): f for f in functions}
    cc = compiler()
    if cc is None:
        why = ("compiling is disabled (EXCITE_COMPILE=0)" if os.environ.get("EXCITE_COMPILE") is not None
               else "no C compiler found (set CC)")
        return Loaded(vm, "virtual machine", f"{why}: {what} runs in CasADi's virtual machine (several "
                      "times slower)", seconds)
    if not wait:
        return Loaded(vm, "virtual machine", (note + "; " if note else "") + f"{what} is not compiled for this "
                      f"problem shape ({lib.name}): it runs in CasADi's virtual machine (several times slower); "
                      "`excite optimize --compile-only` with this rig and duration compiles it into the cache",
                      seconds)
    fresh = lib.with_suffix(f".{os.getpid()}.{time.time_ns()}.tmp")
    try:
        started = _compile(name, functions, key, cc, seconds, fresh)
    except (OSError, subprocess.CalledProcessError, WorkTimeout, WorkerDied) as exc:
        # a read-only cache, a compiler that failed or did not finish
        return Loaded(vm, "virtual machine", f"cannot compile {what} ({type(exc).__name__}: "
                      f"{str(exc).splitlines()[0][:100] if str(exc) else ''}): it runs in CasADi's virtual machine",
                      seconds)
    if not started:
        return Loaded(vm, "virtual machine", (note + "; " if note else "") + f"another process is compiling {what} "
                      f"for this problem shape ({lib.name}); this run uses CasADi's virtual machine for it", seconds)
    # loaded from the new file (a name never loaded before) before it takes the cache's name: the
    # dynamic loader hands a path it has seen back as the library it loaded then
    try:
        out = Loaded({n: ca.external(n, str(fresh)) for n in names}, "compiled", note, seconds)
        os.replace(fresh, lib)
        return out
    finally:
        fresh.unlink(missing_ok=True)


def _lock_stale(lock: Path) -> bool:
    """Whether ``lock`` belongs to a compile that died: older than :data:`LOCK_STALE_S`, or
    written by a process of this machine that is gone."""
    try:
        if time.time() - lock.stat().st_mtime > LOCK_STALE_S:
            return True
        pid = int(lock.read_text() or "0")
    except FileNotFoundError:
        return True
    except (OSError, ValueError):
        return False
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


def _compile(name: str, functions: list[ca.Function], key: str, cc: str, seconds: dict[str, float],
             tmp: Path) -> bool:
    """Generate the C source and compile it into ``tmp`` (see the module docstring). False when
    another process holds the lock of this key."""
    lib = _library(name, key)
    lib.parent.mkdir(parents=True, exist_ok=True)
    lock = lib.with_suffix(".lock")
    try:
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        if not _lock_stale(lock):
            return False
        lock.unlink(missing_ok=True)
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    os.write(fd, str(os.getpid()).encode())
    os.close(fd)
    src = lib.with_suffix(".c")
    try:
        t0 = time.perf_counter()
        cg = ca.CodeGenerator(src.name, {"with_header": False})
        for f in functions:
            cg.add(f)
        cg.generate(str(src.parent) + os.sep)
        seconds["generate"] = time.perf_counter() - t0
        t1 = time.perf_counter()
        cmd = [cc, *FLAGS, str(src), "-o", str(tmp), "-lm"]
        done = processes.command(cmd, COMPILE_TIMEOUT_S, name="excite-compile")
        if done.returncode != 0:
            raise subprocess.CalledProcessError(done.returncode, cmd, done.stdout, done.stderr)
        seconds["compile"] = time.perf_counter() - t1
        return True
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    finally:
        for p in (src, lock):
            p.unlink(missing_ok=True)
