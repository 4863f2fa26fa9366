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

On a miss, :func:`load` generates the C source and starts the compiler in the background (a
detached process, one per key); this run uses the virtual machine and says so in one line, the
next run of the same shape finds the library. ``wait=True`` (``excite optimize --compile-only``)
compiles before returning. Where no C compiler exists, or with ``EXCITE_COMPILE=0``, a library
the cache holds is still used, and on a miss the virtual machine, with a one-line note; the
service's jobs run so (a detached compile would outlive its job), and so do the tests.

Environment: ``EXCITE_CACHE_DIR`` (default ``$XDG_CACHE_HOME/excite``, ``~/.cache/excite``),
``CC`` (default ``cc``, else ``gcc``), ``EXCITE_COMPILE`` (``0``: never start the compiler).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import casadi as ca

FLAGS = ("-O2", "-shared", "-fPIC")
LOCK_STALE_S = 1800.0  # a lock older than this belongs to a compile that died


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
        note = f"{why}: rebuilding it"
    functions = list(build())
    vm = {f.name(): f for f in functions}
    cc = compiler()
    if cc is None:
        why = ("compiling is disabled (EXCITE_COMPILE=0)" if os.environ.get("EXCITE_COMPILE") is not None
               else "no C compiler found (set CC)")
        return Loaded(vm, "virtual machine", f"{why}: {what} runs in CasADi's virtual machine (several "
                      "times slower)", seconds)
    fresh = lib.with_suffix(f".{os.getpid()}.{time.time_ns()}.tmp")
    try:
        started = _compile(name, functions, key, cc, wait, seconds, fresh)
    except (OSError, subprocess.CalledProcessError) as exc:  # a read-only cache, a compiler that failed
        return Loaded(vm, "virtual machine", f"cannot compile {what} ({type(exc).__name__}: "
                      f"{str(exc).splitlines()[0][:100] if str(exc) else ''}): it runs in CasADi's virtual machine",
                      seconds)
    if wait and started:
        # loaded from the new file (a name never loaded before) before it takes the cache's
        # name: the dynamic loader hands a path it has seen back as the library it loaded then
        try:
            out = Loaded({n: ca.external(n, str(fresh)) for n in names}, "compiled", note, seconds)
            os.replace(fresh, lib)
            return out
        finally:
            fresh.unlink(missing_ok=True)
    how = "started compiling" if started else "another process is compiling"
    return Loaded(vm, "virtual machine", (note + "; " if note else "") + f"{how} {what} for this problem shape "
                  f"in the background ({lib.name}); this run uses CasADi's virtual machine for it", seconds)


def _compile(name: str, functions: list[ca.Function], key: str, cc: str, wait: bool,
             seconds: dict[str, float], tmp: Path) -> bool:
    """Generate the C source and compile it (in the background unless ``wait``). False when
    another process holds the lock of this key."""
    lib = _library(name, key)
    lib.parent.mkdir(parents=True, exist_ok=True)
    lock = lib.with_suffix(".lock")
    try:
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        try:
            stale = time.time() - lock.stat().st_mtime > LOCK_STALE_S
        except FileNotFoundError:
            stale = True
        if not stale:
            return False
        lock.unlink(missing_ok=True)
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    os.write(fd, str(os.getpid()).encode())
    os.close(fd)
    t0 = time.perf_counter()
    src = lib.with_suffix(".c")
    try:
        cg = ca.CodeGenerator(src.name, {"with_header": False})
        for f in functions:
            cg.add(f)
        cg.generate(str(src.parent) + os.sep)
    except Exception:
        lock.unlink(missing_ok=True)
        raise
    seconds["generate"] = time.perf_counter() - t0
    cmd = [cc, *FLAGS, str(src), "-o", str(tmp), "-lm"]
    if wait:  # the caller loads ``tmp`` and moves it into place
        t1 = time.perf_counter()
        try:
            subprocess.run(cmd, check=True, capture_output=True)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        finally:
            for p in (src, lock):
                p.unlink(missing_ok=True)
        seconds["compile"] = time.perf_counter() - t1
        return True
    # detached: it outlives this process, and a Ctrl-C here does not reach it
    script = ("import os, subprocess, sys\n"
              "os.nice(10)\n"
              "cmd, src, tmp, lib, lock = sys.argv[1:-4], *sys.argv[-4:]\n"
              "try:\n"
              "    if subprocess.run(cmd, capture_output=True).returncode == 0:\n"
              "        os.replace(tmp, lib)\n"
              "finally:\n"
              "    for p in (src, tmp, lock):\n"
              "        try:\n"
              "            os.unlink(p)\n"
              "        except OSError:\n"
              "            pass\n")
    subprocess.Popen([sys.executable, "-c", script, *cmd, str(src), str(tmp), str(lib), str(lock)],
                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                     start_new_session=True, close_fds=True)
    return True
