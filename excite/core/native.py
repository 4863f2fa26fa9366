"""The native module ``excite._native``: the evaluator's inner loops in C (sampling the trajectory,
the factor kernels generated from the kinds' statements, the information and its elimination).

Every ``.c`` file under ``excite/`` is part of it (:func:`sources`). It is compiled when the
package is built or installed (``setup.py``: setuptools and the system C compiler), like the
extension modules of scientific packages, so that no run compiles anything. A source checkout
used in place (``PYTHONPATH``, or an editable install whose sources have changed since it was
built) has no current build: the first use compiles it once with the system compiler (``CC``,
else ``cc``) into the cache (``EXCITE_CACHE_DIR``, default ``~/.cache/excite``), keyed by a hash
of the sources and flags, and says so on stderr; later processes load it from there.

Standard library only, and no relative import: ``setup.py`` loads this file by its path to list
the sources and their hash before anything is installed.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import os
import shutil
import subprocess
import sys
import sysconfig
import time
from pathlib import Path
from types import ModuleType

NAME = "excite._native"
PACKAGE = Path(__file__).resolve().parents[1]  # excite/
FLAGS = ("-O3", "-fPIC", "-fno-math-errno", "-ffp-contract=off", "-std=c99")  # IEEE arithmetic, no fast-math
LOCK_STALE_S = 600.0
COMPILE_TIMEOUT_S = 300.0  # a compiler run still going after this is ended (a few seconds is usual)

_MODULE: ModuleType | None = None


def sources(package: Path = PACKAGE) -> list[Path]:
    """The C files of the native module, in a fixed order."""
    return sorted(package.rglob("*.c"))


def source_hash(package: Path = PACKAGE) -> str:
    """A hash of every C source and header of the package and of the flags: what a build is of."""
    h = hashlib.sha256(repr(FLAGS).encode())
    for p in sorted(list(package.rglob("*.c")) + list(package.rglob("*.h"))):
        h.update(str(p.relative_to(package)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:24]


def define(package: Path = PACKAGE) -> tuple[str, str]:
    """The macro that records in the module which sources it was built from."""
    return "EXCITE_NATIVE_SOURCES", f'"{source_hash(package)}"'


def module() -> ModuleType:
    """The native module: the one built with the package, or, in a source checkout whose
    sources differ from it, the one built from them (compiled now if the cache has none)."""
    global _MODULE
    if _MODULE is None:
        _MODULE = _load()
    return _MODULE


def _load() -> ModuleType:
    built = None
    try:
        built = importlib.import_module(NAME)
    except ImportError:
        pass
    if not sources():  # an installed package: no sources, the module built with it
        if built is None:
            raise ImportError("excite's native module is missing: reinstall excite (it is compiled at install)")
        return built
    digest = source_hash()
    if built is not None and getattr(built, "SOURCES", None) == digest:
        return built
    return _from_cache(digest)


def cache_dir() -> Path:
    base = os.environ.get("EXCITE_CACHE_DIR")
    if base:
        return Path(base)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "excite"


def _suffix() -> str:
    return sysconfig.get_config_var("EXT_SUFFIX") or ".so"


def _from_cache(digest: str) -> ModuleType:
    lib = cache_dir() / "native" / f"_native-{digest}{_suffix()}"
    if not lib.exists():
        build(lib)
    spec = importlib.util.spec_from_file_location(NAME, lib)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {lib}")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def compiler() -> str:
    for cc in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if cc and (path := shutil.which(cc)):
            return path
    raise ImportError("excite's native module is not built for this source checkout and no C compiler was found "
                      "(set CC, or install excite: pip install .)")


def run_compiler(cmd: list[str]) -> subprocess.CompletedProcess:
    """Run a C compiler to completion: past :data:`COMPILE_TIMEOUT_S` it is killed and
    :class:`ImportError` names the compiler and the limit."""
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=COMPILE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise ImportError(f"the C compiler {cmd[0]} did not finish within {COMPILE_TIMEOUT_S:g} s") from None


def build(lib: Path) -> None:
    """Compile the native module of this source tree to ``lib`` (under a lock: one process
    compiles, the others wait for it)."""
    lib.parent.mkdir(parents=True, exist_ok=True)
    lock = lib.with_suffix(".lock")
    t0 = time.monotonic()
    while True:
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            break
        except FileExistsError:
            if lib.exists():
                return
            try:
                if time.time() - lock.stat().st_mtime > LOCK_STALE_S:
                    lock.unlink(missing_ok=True)
            except FileNotFoundError:
                pass
            if time.monotonic() - t0 > LOCK_STALE_S:
                raise ImportError(f"another process has been compiling {lib.name} for {LOCK_STALE_S:.0f} s")
            time.sleep(0.2)
    os.close(fd)
    try:
        if lib.exists():
            return
        print(f"excite: compiling its native module for this source checkout (once) into {lib.parent}",
              file=sys.stderr)
        tmp = lib.with_suffix(f".{os.getpid()}.tmp")
        name, value = define()
        cmd = [compiler(), *FLAGS, "-shared", f"-I{sysconfig.get_paths()['include']}", f"-D{name}={value}",
               *map(str, sources()), "-o", str(tmp), "-lm"]
        try:
            done = run_compiler(cmd)
            if done.returncode != 0:
                raise ImportError("compiling excite's native module failed:\n" + done.stderr[-4000:])
            os.replace(tmp, lib)
        finally:
            tmp.unlink(missing_ok=True)
    finally:
        lock.unlink(missing_ok=True)
