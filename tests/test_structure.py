"""The package's structure, as a newcomer relies on it: imports point one way (no import
cycles), no module uses another module's private names, every exception class lives in its
package's errors module (``excite/errors.py``, ``api/errors.py``, each drawing its tree), and no
module grows past what one can read (900 lines), processes are started by the one supervisor
(``excite.core.processes``) and problem documents built by ``api.errors.Problem`` alone. Read from
the source with ``ast``: nothing is imported or run."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest
from helpers import REPO

ROOT = REPO
PACKAGES = ("excite", "api")
MAX_LINES = 900


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for p in (ROOT / pkg).rglob("*.py"):
            parts = list(p.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = p
    return out


MODULES = _modules()


def _resolve(mod: str, path: Path, node: ast.ImportFrom) -> str | None:
    if node.level == 0:
        return node.module
    base = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(mod: str, path: Path) -> list[tuple[str, list[str], int]]:
    """(target module, names taken from it, line) of every import anywhere in the file."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(mod, path, node)
            if target is None:
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                if sub in MODULES:  # `from . import x` of a module: an edge to that module
                    out.append((sub, [], node.lineno))
                else:
                    out.append((target, [a.name], node.lineno))
    return [(t, n, line) for t, n, line in out if t in MODULES]


def test_no_import_cycles():
    graph = defaultdict(set)
    for mod, path in MODULES.items():
        for target, _, _ in _imports(mod, path):
            if target != mod:
                graph[mod].add(target)
    # Tarjan's strongly connected components
    index, low, on, stack, sccs, counter = {}, {}, set(), [], [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                sccs.append(sorted(comp))

    for v in list(MODULES):
        if v not in index:
            visit(v)
    assert not sccs, f"import cycles: {sccs}"


def test_no_private_name_crosses_a_module_boundary():
    bad = []
    for mod, path in MODULES.items():
        tree = ast.parse(path.read_text())
        aliases = {}  # local name → excite/api module it is bound to
        for target, names, line in _imports(mod, path):
            bad += [f"{path.relative_to(ROOT)}:{line}: imports {target}.{n}" for n in names
                    if n.startswith("_") and not n.startswith("__")]
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for a in node.names:
                    full = (a.name if isinstance(node, ast.Import) else
                            f"{_resolve(mod, path, node)}.{a.name}")
                    if full in MODULES:
                        aliases[a.asname or a.name.split(".")[0]] = full
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases
                    and node.attr.startswith("_") and not node.attr.startswith("__")):
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: uses {aliases[node.value.id]}.{node.attr}")
    assert not bad, "\n".join(bad)


def _is_exception(node: ast.ClassDef, known: set[str]) -> bool:
    names = [b.id if isinstance(b, ast.Name) else b.attr if isinstance(b, ast.Attribute) else "" for b in node.bases]
    return any(n in known or n.endswith(("Error", "Exception")) or n in ("Exception", "BaseException") for n in names)


def test_every_exception_is_in_its_packages_errors_module():
    known: set[str] = set()
    homes = {f"{pkg}.errors" for pkg in PACKAGES}
    for home in sorted(homes):
        tree = ast.parse(MODULES[home].read_text())
        known |= {n.name for n in tree.body if isinstance(n, ast.ClassDef)}
        doc = ast.get_docstring(tree) or ""
        missing = [n.name for n in tree.body if isinstance(n, ast.ClassDef) and n.name not in doc]
        assert not missing, f"{home}'s docstring does not draw {missing}"
    stray = [f"{MODULES[m].relative_to(ROOT)}:{n.lineno}: {n.name}" for m in MODULES if m not in homes
             for n in ast.walk(ast.parse(MODULES[m].read_text()))
             if isinstance(n, ast.ClassDef) and _is_exception(n, known)]
    assert not stray, "exception classes outside the errors modules:\n" + "\n".join(stray)


@pytest.mark.parametrize("mod", sorted(MODULES))
def test_no_module_is_over_900_lines(mod):
    n = len(MODULES[mod].read_text().splitlines())
    assert n <= MAX_LINES, f"{MODULES[mod].relative_to(ROOT)}: {n} lines"


# The layers of excite, bottom to top: a package imports only packages below it (``excite.errors``
# and the package's own ``excite/__init__`` are below every one; ``api`` sits on top of them all).
LAYERS = ("core", "motion", "factors", "rig", "io", "scene", "information", "score", "validate", "plan", "fleet",
          "cli")


def _layer(mod: str) -> int | None:
    """The layer of an excite or api module (None: ``excite.errors``, ``excite`` itself)."""
    parts = mod.split(".")
    if parts[0] == "api":
        return len(LAYERS)
    if len(parts) < 2 or parts[1] not in LAYERS:
        return None
    return LAYERS.index(parts[1])


def test_each_package_imports_only_packages_below_it():
    top = {p.name for p in (ROOT / "excite").iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert top <= set(LAYERS), f"packages missing from the layering: {sorted(top - set(LAYERS))}"
    bad = []
    for mod, path in MODULES.items():
        own = _layer(mod)
        if own is None:
            continue
        for target, _, line in _imports(mod, path):
            other = _layer(target)
            if other is not None and other > own:
                bad.append(f"{path.relative_to(ROOT)}:{line}: {mod} imports {target} (above it)")
    assert not bad, "\n".join(bad)


def _calls(path: Path) -> list[tuple[str, int]]:
    """(called name, line) of every call in the file: ``f(…)`` and ``x.f(…)`` give ``f``."""
    return [(n.func.id if isinstance(n.func, ast.Name) else n.func.attr, n.lineno)
            for n in ast.walk(ast.parse(path.read_text()))
            if isinstance(n, ast.Call) and isinstance(n.func, (ast.Name, ast.Attribute))]


# Starting a process: the one supervisor (its process tree ended with it, its owner's death ending
# it). Besides it, only a C compiler is run to completion, by excite.core.native.run_compiler (for the
# native module and generated kernels).
PROCESS_STARTERS = {"Process", "Popen", "fork", "forkpty", "ProcessPoolExecutor", "Pool", "system", "spawnv",
                    "spawnve", "spawnl", "spawnle", "posix_spawn", "run", "call", "check_call", "check_output"}
SUPERVISOR = "excite.core.processes"
RUNS_A_COMPILER = {"excite.core.native"}


def test_only_the_supervisor_starts_processes():
    bad = []
    for mod, path in MODULES.items():
        if mod == SUPERVISOR:
            continue
        tree = ast.parse(path.read_text())
        for n in ast.walk(tree):
            if not (isinstance(n, ast.Call) and isinstance(n.func, (ast.Name, ast.Attribute))):
                continue
            name = n.func.id if isinstance(n.func, ast.Name) else n.func.attr
            owner = n.func.value.id if isinstance(n.func, ast.Attribute) and isinstance(n.func.value, ast.Name) else ""
            if name not in PROCESS_STARTERS:
                continue
            if name in ("run", "call") and owner != "subprocess":  # run/call of anything else is no process
                continue
            if owner == "subprocess" and name == "run" and mod in RUNS_A_COMPILER:
                continue
            bad.append(f"{path.relative_to(ROOT)}:{n.lineno}: {owner + '.' if owner else ''}{name}(…)")
    assert not bad, ("processes started outside excite.core.processes (use Supervised, Worker or command):\n"
                     + "\n".join(bad))


def test_only_api_errors_builds_problem_documents():
    """A problem document is ``api.errors.Problem.body()``; everything else raises a Problem
    (api.problems maps the library's errors to one), never an HTTPException or a hand-built body."""
    bad = []
    for mod, path in MODULES.items():
        if not mod.startswith("api") or mod == "api.errors":
            continue
        for n in ast.walk(ast.parse(path.read_text())):
            if isinstance(n, ast.Dict):
                keys = {k.value for k in n.keys if isinstance(k, ast.Constant)}
                if {"title", "status"} <= keys or {"type", "detail"} <= keys:
                    bad.append(f"{path.relative_to(ROOT)}:{n.lineno}: a problem body built by hand")
            if isinstance(n, ast.Constant) and n.value == "application/problem+json" and mod != "api.problems":
                bad.append(f"{path.relative_to(ROOT)}:{n.lineno}: the problem media type stated again")
        bad += [f"{path.relative_to(ROOT)}:{line}: HTTPException(…)" for name, line in _calls(path)
                if name == "HTTPException"]
    assert not bad, "\n".join(bad)
