"""How this process gets excite's compiled kernels: numba's JIT, or the same kernels built ahead of time.

The kernels are the ``nb.njit`` functions of :data:`MODULES`, each written once in Python. A
long-running process (the service's workers, ``excite live``, batch and mine, a library user)
compiles them with numba's JIT, loaded from numba's on-disk cache: about a second for importing
numba and loading the cache, paid once. A one-shot command cannot afford that second: the
command line calls :func:`ahead_of_time` before anything imports a kernel, and the process then
loads an extension module that ``numba.pycc`` built from the same Python functions, with the
flags the JIT compiles them with (``nogil``: the GIL is released inside, so the evaluator's two
threads still run in parallel; ``fastmath`` where a kernel asks for it). numba is not imported.

The kernel modules import ``numba`` from here (``from .compiled import numba as nb``): in a JIT
process that is numba itself; in an ahead-of-time process, a stand-in whose ``njit`` binds each
kernel to its compiled exports (inlined helpers stay plain Python: only other kernels call them).

**Which signatures.** The exports are the signatures the JIT compiles in a representative run
(:func:`_exercise`: an evaluation of a generated figure-eight), read from each dispatcher, so a
kernel whose body changes needs no edit here. A kernel that only other kernels call is compiled
into them (it has no export of its own: called from Python, it raises ``TypeError``).
pycc does not check argument types (a wrong dtype reads memory as something else), so every call
goes through :class:`Kernel`, which checks dtype, ndim, contiguity, alignment and writability of
each array and the kind of each number, and raises ``TypeError`` on a mismatch.

**Where and when it is built.** On first use, into ``$XDG_CACHE_HOME/excite/kernels`` (default
``~/.cache/excite/kernels``), as numba caches its JIT code on first use: by a child process
(``python -m excite.compiled DIR``) that runs the representative evaluation with the JIT and
compiles (about a minute), under a lock, written atomically. The module's name carries a hash
of the kernel sources (the kernel modules and the excite modules they import, numba's, numpy's and
Python's versions, the CPU): after a ``git pull`` that changes a kernel the old module is simply
not found, and the next one-shot command builds the new one. If the build fails (no C
compiler, a read-only cache), the process says so once on stderr and uses the JIT; the failure
is remembered next to the modules (delete the ``.failed`` file to retry).
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import json
import os
import re
import sys
from pathlib import Path
from typing import Any, Callable

MODULES = ("excite.kernels", "excite.factors.imu", "excite.factors.odometry", "excite.factors.wheel")
_PACKAGE = Path(__file__).resolve().parent
_PREFIX = "excite_kernels_"
_KEEP = 4  # builds kept in the cache directory (other checkouts, other versions)

_want_ahead_of_time = False
_numba: Any = None  # what the kernel modules get as ``nb``, decided at the first kernel import


def ahead_of_time() -> bool:
    """Make this process use the ahead-of-time kernels (building them if needed); returns False
    if a kernel module was already imported (the process keeps the JIT then)."""
    global _want_ahead_of_time
    if _numba is not None:
        return False
    _want_ahead_of_time = True
    return True


def mode() -> str:
    """``"aot"``, ``"jit"``, or ``"undecided"`` (no kernel module imported yet)."""
    if _numba is None:
        return "undecided"
    return "aot" if isinstance(_numba, _AheadOfTime) else "jit"


def __getattr__(name: str) -> Any:
    if name != "numba":
        raise AttributeError(name)
    global _numba
    if _numba is None:
        loaded = _load_or_build(cache_dir()) if _want_ahead_of_time else None
        if loaded is None:
            import numba

            _numba = numba
        else:
            _numba = _AheadOfTime(*loaded)
    return _numba


def cache_dir() -> Path:
    """Where the ahead-of-time modules are kept."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "excite" / "kernels"


# --- which sources a build depends on ---------------------------------------------------------

_FROM = re.compile(r"^from (\.+)([\w.]*) import \(?([\w\s,]+)\)?", re.M)


def sources(package: Path = _PACKAGE) -> list[Path]:
    """The files a build depends on: the kernel modules, the excite modules they import (their
    constants, e.g. gravity, are compiled into the kernels) and this module."""
    files = {package / "compiled.py"}
    for name in MODULES:
        path = package.joinpath(*name.split(".")[1:]).with_suffix(".py")
        files.add(path)
        for dots, module, names in _FROM.findall(path.read_text()):
            base = path.parent
            for _ in range(len(dots) - 1):
                base = base.parent
            if module:
                files.add(_module_file(base.joinpath(*module.split("."))))
            else:
                for n in names.replace("\n", " ").split(","):
                    if (base / f"{n.strip()}.py").is_file():
                        files.add(base / f"{n.strip()}.py")
    return sorted(files)


def _module_file(stem: Path) -> Path:
    return stem.with_suffix(".py") if stem.with_suffix(".py").is_file() else stem / "__init__.py"


def _numba_version() -> bytes:
    """numba's version file (read, not imported: importing numba is what this module avoids;
    importlib.metadata alone costs ~50 ms)."""
    spec = importlib.util.find_spec("numba")
    if spec is None or not spec.submodule_search_locations:
        return b"no numba"
    package = Path(spec.submodule_search_locations[0])
    version = package / "_version.py"
    return (version if version.is_file() else package / "__init__.py").read_bytes()


def _cpu() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            text = f.read(200_000)
    except OSError:
        import platform

        return platform.machine() + platform.processor()
    fields = dict(re.findall(r"^(model name|flags)\s*:\s*(.*)$", text, re.M)[:2])
    return repr(sorted(fields.items()))


def key(package: Path = _PACKAGE) -> str:
    """The hash a build is named by (see the module docstring)."""
    import numpy

    h = hashlib.sha256()
    for part in (sys.version.encode(), numpy.__version__.encode(), _numba_version(), _cpu().encode()):
        h.update(part + b"\0")
    for path in sources(package):
        h.update(path.relative_to(package).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()[:24]


# --- loading ----------------------------------------------------------------------------------

def _paths(directory: Path, k: str) -> tuple[Path, Path, Path]:
    name = _PREFIX + k
    return (directory / (name + importlib.machinery.EXTENSION_SUFFIXES[0]), directory / (name + ".json"),
            directory / (name + ".failed"))


def load(directory: Path, k: str) -> tuple[Any, dict] | None:
    """The module built for key ``k`` in ``directory`` and its manifest, or None."""
    so, manifest, _ = _paths(directory, k)
    if not (so.is_file() and manifest.is_file()):
        return None
    table = json.loads(manifest.read_text())
    if table["key"] != k:
        return None
    spec = importlib.util.spec_from_file_location(_PREFIX + k, so)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module, table


def _say(message: str) -> None:
    print(f"excite: {message}", file=sys.stderr, flush=True)


def _load_or_build(directory: Path) -> tuple[Any, dict] | None:
    """The ahead-of-time module of the current sources, built first if missing; None (after one
    line on stderr) if it cannot be had: the process uses the JIT."""
    k = key()
    try:
        found = load(directory, k)
        if found is not None:
            return found
        so, _, failed = _paths(directory, k)
        if failed.is_file():
            _say(f"using numba's JIT: building the kernels ahead of time failed before (see {failed}; "
                 "delete it to retry)")
            return None
        directory.mkdir(parents=True, exist_ok=True)
        _say(f"compiling the kernels ahead of time for the command line into {directory} "
             "(once per change of the kernels; about a minute)")
        import subprocess

        r = subprocess.run([sys.executable, "-m", "excite.compiled", str(directory)], capture_output=True,
                           text=True, env=dict(os.environ, PYTHONPATH=os.pathsep.join(
                               p for p in (str(_PACKAGE.parent), os.environ.get("PYTHONPATH")) if p)))
        found = load(directory, k)
        if found is None:
            failed.write_text(f"exit code {r.returncode}\n--- stdout\n{r.stdout}\n--- stderr\n{r.stderr}")
            _say(f"using numba's JIT: building the kernels ahead of time failed (see {failed})")
        return found
    except OSError as exc:
        _say(f"using numba's JIT: the ahead-of-time kernels cannot be stored in {directory} ({exc.strerror or exc})")
    except (ImportError, ValueError) as exc:  # a damaged module or manifest
        _say(f"using numba's JIT: the ahead-of-time kernels in {directory} cannot be loaded ({exc})")
    return None


# --- the ahead-of-time process's kernels ------------------------------------------------------

def _checker(spec: list) -> Callable[[Any], bool]:
    """A test that an argument has the type of one position of an exported signature."""
    import numpy as np

    kind = spec[0]
    if kind == "array":
        dtype, ndim, layout, writable = np.dtype(spec[1]), spec[2], spec[3], spec[4]

        def check(a: Any) -> bool:
            if not isinstance(a, np.ndarray) or a.dtype != dtype or a.ndim != ndim:
                return False
            f = a.flags
            return (f.aligned and (f.writeable or not writable)
                    and (layout == "A" or (f.c_contiguous if layout == "C" else f.f_contiguous)))
        return check
    if kind == "bool":
        return lambda x: isinstance(x, (bool, np.bool_))
    if kind == "int":
        return lambda x: isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))
    if kind == "float":
        return lambda x: isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))
    raise ValueError(f"unknown argument kind {kind!r}")


def _describe(a: Any) -> str:
    import numpy as np

    if isinstance(a, np.ndarray):
        f = a.flags
        layout = "C" if f.c_contiguous else "F" if f.f_contiguous else "A"
        return f"array({a.dtype}, {a.ndim}d, {layout}{'' if f.writeable else ', read-only'})"
    return type(a).__name__


class Kernel:
    """A kernel of the ahead-of-time module: calls the export whose signature the arguments
    match (checked: the exports themselves would read any memory as their types) or raises
    ``TypeError``."""

    def __init__(self, func: Callable, exports: list[tuple[Callable, list]]):
        self.py_func = func
        self.__name__, self.__qualname__, self.__module__ = func.__name__, func.__qualname__, func.__module__
        self.__doc__ = func.__doc__
        self._variants = [(fn, tuple(_checker(s) for s in specs), specs) for fn, specs in exports]

    def __call__(self, *args: Any) -> Any:
        for fn, checks, _ in self._variants:
            if len(args) == len(checks) and all(c(a) for c, a in zip(checks, args)):
                return fn(*args)
        compiled = "; ".join("(" + ", ".join(":".join(map(str, s)) for s in specs) + ")"
                             for _, _, specs in self._variants) or "none (only other kernels call it)"
        raise TypeError(f"{self.__module__}.{self.__qualname__}: no compiled signature takes "
                        f"({', '.join(map(_describe, args))}); compiled: {compiled}")

    def __repr__(self) -> str:
        return f"<ahead-of-time kernel {self.__module__}.{self.__qualname__}>"


class _AheadOfTime:
    """The stand-in for numba in an ahead-of-time process: ``njit(...)`` binds a kernel to its
    exports, and leaves an inlined helper a plain function."""

    def __init__(self, module: Any, table: dict):
        self.module, self.table = module, table

    def njit(self, *args: Any, **options: Any) -> Any:
        def bind(func: Callable) -> Any:
            if options.get("inline") == "always":
                return func
            exports = self.table["kernels"].get(f"{func.__module__}.{func.__qualname__}", [])
            return Kernel(func, [(getattr(self.module, sym), specs) for sym, specs in exports])
        return bind(args[0]) if args else bind  # @nb.njit or @nb.njit(**options)


# --- the build --------------------------------------------------------------------------------

def _exercise() -> None:
    """The representative run: what ``excite score`` computes, on a generated 30 s figure-eight
    with the bundled rig, with route segments (every kernel is called from it)."""
    from .evaluate import Options, evaluate
    from .maneuvers import figure_eight
    from .rig import load_rig
    from .vehicle import drive

    rig = load_rig("robotaxi")
    evaluate(drive(figure_eight(30.0), rig.suspension), rig, Options(segments=2))


def _spec(t: Any) -> list:
    from numba.core import types

    t = types.unliteral(t)
    if isinstance(t, types.Array):
        return ["array", str(t.dtype), t.ndim, t.layout, t.mutable]
    if isinstance(t, types.Boolean):
        return ["bool"]
    if isinstance(t, types.Integer) and t.bitwidth == 64 and t.signed:
        return ["int"]
    if t == types.float64:
        return ["float"]
    raise TypeError(f"no ahead-of-time export for an argument of type {t}")


def kernels() -> dict[str, Any]:
    """Every kernel (the numba dispatchers of :data:`MODULES` that are not inlined), by name."""
    import importlib

    from numba.core.registry import CPUDispatcher

    found = {}
    for module_name in MODULES:
        module = importlib.import_module(module_name)
        for obj in vars(module).values():
            if (isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == module_name
                    and obj.targetoptions.get("inline", "never") != "always"):
                found[f"{module_name}.{obj.py_func.__qualname__}"] = obj
    return found


def build(directory: Path) -> Path:
    """Build the ahead-of-time module of the current sources into ``directory`` (under a lock;
    nothing to do if another process has built it meanwhile); returns its path."""
    import fcntl

    if mode() == "aot":
        raise RuntimeError("the build needs numba's JIT kernels: run it in a process of its own")
    directory.mkdir(parents=True, exist_ok=True)
    k = key()
    so, manifest, failed = _paths(directory, k)
    with open(directory / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if so.is_file() and manifest.is_file():
            return so
        _compile(directory, k, so, manifest)
        failed.unlink(missing_ok=True)
        old = sorted(directory.glob(_PREFIX + "*" + importlib.machinery.EXTENSION_SUFFIXES[0]),
                     key=lambda p: p.stat().st_mtime)[:-_KEEP]
        for path in old:
            for p in _paths(directory, path.name[len(_PREFIX):].split(".")[0]):
                p.unlink(missing_ok=True)
    return so


def _compile(directory: Path, k: str, so: Path, manifest: Path) -> None:
    import tempfile
    import warnings

    from numba.core import compiler, types
    from numba.core.errors import NumbaPendingDeprecationWarning
    from numba.core.typing import signature

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NumbaPendingDeprecationWarning)
        import numba.pycc.compiler as pycc_compiler
        from numba.pycc import CC

    _exercise()
    table: dict[str, list] = {}
    dispatcher_of: dict[Any, Any] = {}
    cc = CC(_PREFIX + k, source_module=__name__)
    cc.target_cpu = "host"  # as the JIT compiles
    for i, (name, d) in enumerate(sorted(kernels().items())):
        seen = {}
        for args in d.signatures:
            specs = [_spec(a) for a in args]
            seen.setdefault(json.dumps(specs), (args, specs))
        if not seen:  # only other kernels call it (compiled into them; from numba's cache, unseen)
            continue
        table[name] = []
        for j, (args, specs) in enumerate(seen.values()):
            symbol = f"k{i}_{j}"
            ret = d.overloads[args].signature.return_type
            cc.export(symbol, signature(ret, *(types.unliteral(a) for a in args)))(d.py_func)
            table[name].append([symbol, specs])
        dispatcher_of[d.py_func] = d

    plain = pycc_compiler.compile_extra

    def with_jit_flags(typingctx, targetctx, func, args, return_type, flags, locals, library):
        """pycc compiles every export with default flags; use the dispatcher's (nogil, fastmath…)."""
        d = dispatcher_of[func]
        own = compiler.Flags()
        d.targetdescr.options.parse_as_flags(own, d.targetoptions)
        own.no_compile, own.nrt = flags.no_compile, flags.nrt
        own.no_cpython_wrapper, own.no_cfunc_wrapper = flags.no_cpython_wrapper, flags.no_cfunc_wrapper
        return plain(typingctx, targetctx, func, args, return_type, own, locals=locals, library=library)

    with tempfile.TemporaryDirectory(dir=directory) as tmp:
        cc.output_dir = tmp
        pycc_compiler.compile_extra = with_jit_flags
        try:
            cc.compile()
        finally:
            pycc_compiler.compile_extra = plain
        Path(tmp, manifest.name).write_text(json.dumps({"key": k, "kernels": table}, indent=1))
        os.replace(Path(tmp, manifest.name), manifest)
        os.replace(Path(tmp, cc.output_file), so)  # last: a module on disk is complete


if __name__ == "__main__":  # the build's child process (the kernels import excite.compiled, not __main__)
    from excite import compiled

    print(compiled.build(Path(sys.argv[1]) if len(sys.argv) > 1 else compiled.cache_dir()))
