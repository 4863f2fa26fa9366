"""Wall time of the command line from a cold process: what a person waits for, and where it goes;
the kernels built ahead of time (what ``excite score`` loads) against numba's JIT cache, side by side.

Runs each command ``--runs`` times in a fresh interpreter, the variants alternating so that the
machine's load hits them alike (the first run of all builds the ahead-of-time kernels and fills
numba's cache if needed, and is not counted):

- ``excite --help``
- ``excite score`` of the bundled 90 s figure-eight, as logged poses (``.tum``) and as controls
  (``_control.csv``), each **ahead of time** (``python -m excite.cli``, as the ``excite``
  script runs it) and with **numba's JIT** (the same process, :func:`excite.cli.main` without the
  ahead-of-time choice, then the same exit);
- the ahead-of-time ``score`` of the TUM file once more with Python's bytecode cached in a
  scratch ``PYTHONPYCACHEPREFIX`` (this machine sets ``PYTHONDONTWRITEBYTECODE``: excite's own
  modules are otherwise compiled from source in every process).

Then splits a cold ahead-of-time ``excite score`` of the TUM file into its phases (fresh
interpreters): starting Python, the imports (numpy, the scipy parts excite uses, typer/rich/
pydantic/yaml, excite's modules), loading the ahead-of-time module (its key: hashing the kernel
sources; the module and its manifest), rig and route, the first and a second evaluation, the exit.

Last, the evaluation of a generated 10-minute drive in a warm process of each kind (median of
``--runs`` evaluations after one warm-up): what the ahead-of-time kernels cost when the work is
large, both with the evaluator's two threads; whether a kernel releases the GIL (the pace of a
Python loop while a kernel runs in another thread); and the cost of the argument checks of
:class:`excite.compiled.Kernel` per call.

    python benchmarks/bench_cli.py [--runs 5]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_api import machine  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ROUTES = ["trajectories/figure_eight.tum", "trajectories/figure_eight_control.csv"]
AOT = ["-m", "excite.cli"]
# excite.cli.run() without its ahead-of-time choice: the command on numba's JIT cache
JIT = ["-c", "import gc, sys; from excite.cli import main; rc = main(); gc.freeze(); sys.exit(rc)"]
COMMANDS = {"excite --help": (AOT, ["--help"], {})}
for _r in ROUTES:
    COMMANDS[f"excite score {_r}, ahead of time"] = (AOT, ["score", _r], {})
    COMMANDS[f"excite score {_r}, numba JIT"] = (JIT, ["score", _r], {})

# the phases of an ahead-of-time `excite score ROUTES[0]`, in the order the command meets them; the
# child prints its phase durations and the wall-clock time at its start and end (the parent adds
# the exit)
PHASES = f"""
import time
t_wall = time.time()
t = [time.perf_counter()]
import numpy
t.append(time.perf_counter())
import scipy.sparse, scipy.interpolate, scipy.spatial.transform
t.append(time.perf_counter())
import typer, rich.console, pydantic, yaml
t.append(time.perf_counter())
from excite import compiled
compiled.ahead_of_time()
from excite import kernels
assert compiled.mode() == "aot"
t.append(time.perf_counter())
from excite.cli import score
from excite.evaluate import Options, evaluate
from excite.rig import load_rig
from excite.routes import read_route
t.append(time.perf_counter())
rig = load_rig("robotaxi")
traj = read_route({ROUTES[0]!r}, suspension=rig.suspension)
t.append(time.perf_counter())
evaluate(traj, rig, Options())
t.append(time.perf_counter())
evaluate(traj, rig, Options())
t.append(time.perf_counter())
import gc, json, sys
assert "numba" not in sys.modules
gc.freeze()  # as the excite command does before it exits
print(json.dumps([t_wall, [b - a for a, b in zip(t, t[1:])], time.time()]), flush=True)
"""
PHASE_NAMES = ["import numpy", "import scipy.sparse, .interpolate, .spatial (excite's)",
               "import typer, rich, pydantic, yaml", "load the ahead-of-time kernels (key, module, manifest)",
               "import excite (CLI, evaluate, routes, rig)", "load rig + read route",
               "first evaluation", "second evaluation"]

# a warm process of each kind evaluates a generated 10-minute drive
LONG = """
import json, statistics, sys, time
sys.path.insert(0, "benchmarks")
from excite import compiled
if sys.argv[1] == "aot":
    compiled.ahead_of_time()
import numpy as np
from bench_evaluate import generated
from excite.evaluate import evaluate
from excite.rig import load_rig
from excite import kernels
assert compiled.mode() == sys.argv[1]
rig = load_rig("robotaxi")
traj = generated(600.0, rig)
evaluate(traj, rig)
wall, cpu = [], []
for _ in range(int(sys.argv[2])):
    t0, c0 = time.perf_counter(), time.process_time()
    evaluate(traj, rig)
    wall.append(time.perf_counter() - t0)
    cpu.append(time.process_time() - c0)
out = {"wall": wall, "cpu": cpu}
if sys.argv[1] == "aot":  # the argument checks: a call of the wrapper against the export itself
    seg = kernels.segments
    fn = seg._variants[0][0]
    b, t = np.array([0.0, 1.0]), np.array([0.5])
    n = 20000
    t0 = time.perf_counter()
    for _ in range(n):
        fn(b, t)
    t1 = time.perf_counter()
    for _ in range(n):
        seg(b, t)
    t2 = time.perf_counter()
    out["check_us"] = ((t2 - t1) - (t1 - t0)) / n * 1e6
    calls = [0]
    call = compiled.Kernel.__call__
    def counted(self, *args):
        calls[0] += 1
        return call(self, *args)
    compiled.Kernel.__call__ = counted
    evaluate(traj, rig)
    out["calls"] = calls[0]
    compiled.Kernel.__call__ = call
# the GIL: a Python loop's pace in this thread while a kernel runs in another, over its pace alone
import threading
a = np.random.default_rng(0).normal(size=(100000, 9, 9))
cov = np.einsum("nij,nkj->nik", a, a) + 9.0 * np.eye(9)
def pace(busy):
    n, t0 = 0, time.perf_counter()
    while (busy.is_alive() if busy else time.perf_counter() - t0 < 0.3):
        n += 1
    return n / (time.perf_counter() - t0)
def beside(kernel):
    alone = pace(None)
    kernel(cov[:10])
    busy = threading.Thread(target=lambda: [kernel(cov) for _ in range(5)])
    busy.start()
    return pace(busy) / alone
out["gil"] = beside(kernels.inverse_cholesky)
if sys.argv[1] == "jit":  # for comparison: the same kernel compiled without nogil
    import numba
    out["gil_held"] = beside(numba.njit(kernels.inverse_cholesky.py_func))
print(json.dumps(out))
"""


def _env(**extra: str) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
                **extra)


def wall(how: list[str], args: list[str], env: dict[str, str]) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, *how, *args], cwd=REPO, env=_env(**env), check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def phases() -> dict[str, float]:
    t0 = time.time()
    out = subprocess.run([sys.executable, "-c", PHASES], cwd=REPO, env=_env(), check=True,
                         capture_output=True, text=True).stdout
    t1 = time.time()
    t_start, steps, t_end = json.loads(out.strip().splitlines()[-1])
    return {"start python": t_start - t0, **dict(zip(PHASE_NAMES, steps)), "exit": t1 - t_end}


def long_drive(kind: str, runs: int) -> dict:
    out = subprocess.run([sys.executable, "-c", LONG, kind, str(runs)], cwd=REPO, env=_env(), check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def summary(times: list[float], unit: str = "s", scale: float = 1.0, digits: int = 2) -> str:
    xs = [x * scale for x in times]
    return (f"median {statistics.median(xs):.{digits}f} {unit} "
            f"({min(xs):.{digits}f}–{max(xs):.{digits}f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    pycache = tempfile.mkdtemp(prefix="excite-pycache-")
    env_bytecode = {"PYTHONPYCACHEPREFIX": pycache, "PYTHONDONTWRITEBYTECODE": ""}
    commands = dict(COMMANDS)
    commands[f"excite score {ROUTES[0]}, ahead of time, bytecode cached"] = (AOT, ["score", ROUTES[0]], env_bytecode)
    for how, argv, env in commands.values():
        wall(how, argv, env)  # kernels built and cached, bytecode written, files in the page cache
    print(f"machine: {machine()}; load average {os.getloadavg()[0]:.1f} at the start")
    print("bytecode of excite's modules: " + ("not cached (PYTHONDONTWRITEBYTECODE is set), except where said"
                                              if os.environ.get("PYTHONDONTWRITEBYTECODE") else "cached"))
    times: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(args.runs):
        for name, (how, argv, env) in commands.items():
            times[name].append(wall(how, argv, env))
    for name, ts in times.items():
        print(f"{name}: {summary(ts)} over {args.runs} cold runs")
    print(f"phases of a cold ahead-of-time `excite score {ROUTES[0]}` ({args.runs} fresh processes):")
    runs = [phases() for _ in range(args.runs)]
    for name in ["start python", *PHASE_NAMES, "exit"]:
        print(f"  {name:<58} {summary([r[name] for r in runs])}")
    print(f"load average {os.getloadavg()[0]:.1f}")
    print(f"a generated 10-minute drive, evaluated {args.runs} times in a warm process (after one warm-up):")
    aot, jit = long_drive("aot", args.runs), long_drive("jit", args.runs)
    for name, r in (("ahead of time", aot), ("numba JIT", jit)):
        print(f"  {name:<14} wall {summary(r['wall'], 'ms', 1e3, 0)}, CPU {summary(r['cpu'], 'ms', 1e3, 0)}")
    print(f"  argument checks of the ahead-of-time wrapper: {aot['check_us']:.1f} µs per call, "
          f"{aot['calls']} kernel calls per evaluation of the 10-minute drive")
    print(f"  a Python loop beside a running kernel, pace against alone (~0 if the kernel held the GIL): "
          f"ahead of time {aot['gil']:.2f}, numba JIT {jit['gil']:.2f}, the JIT without nogil {jit['gil_held']:.2f}")
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
