"""Wall time of the command line from a cold process: what a person waits for, and where it goes.

Runs each command ``--runs`` times in a fresh interpreter (the compiled kernels are cached on
disk by then: the first run of all compiles them, ~16 s, and is not counted):

- ``excite --help``
- ``excite score trajectories/figure_eight.tum`` and ``... figure_eight_control.csv`` (the bundled
  90 s figure-eight as logged poses and as controls)

and prints the median, min and max wall time of each. Then splits a cold ``excite score`` of the
TUM file into its phases, each timed in a fresh interpreter the same number of times: starting
Python, the imports (numpy, numba, the scipy.linalg that numba's first cached kernel imports
for its BLAS check, the scipy parts excite uses itself, typer/rich/pydantic/yaml, excite's
modules), reading the route, numba's first kernel load (its registries of implementations), the
first evaluation (the remaining kernels from numba's cache), a second one, and the exit. The
*floor* is what any process scoring with these numba kernels pays: Python, numpy, numba,
scipy.linalg, numba's registries, loading the kernels and the exit. Last, it checks that the
kernels come from the cache in a fresh process (numba's cache debug output: "data loaded"
lines, no "data saved").

Python's bytecode cache matters: with ``PYTHONDONTWRITEBYTECODE`` set (as on the machine these
figures were first taken on) excite's own modules are compiled from source in every process;
the benchmark says which.

Last, the same ``excite score`` commands answered by a resident process (``excite resident``,
:mod:`excite.cli.resident_process`): one is started in a temporary runtime directory, and each command runs
``--runs`` times through the ``excite`` script's client, alternating with a cold run in the
calling process (``EXCITE_RESIDENT=0``), so the ratio is measured side by side. The resident
process's own count of commands served is checked against the runs.

    python benchmarks/bench_cli.py [--runs 7]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_api import machine  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ROUTES = ["trajectories/figure_eight.tum", "trajectories/figure_eight_control.csv"]
COMMANDS = {"excite --help": ["--help"], **{f"excite score {r}": ["score", r] for r in ROUTES}}

# the phases of `excite score ROUTES[0]`, in the order the command meets them; the child prints
# its phase durations and the wall-clock time at its start and end (the parent adds the exit)
PHASES = f"""
import time
t_wall = time.time()
t = [time.perf_counter()]
import numpy
t.append(time.perf_counter())
import numba
t.append(time.perf_counter())
import scipy.linalg
t.append(time.perf_counter())
import scipy.sparse, scipy.interpolate, scipy.spatial.transform
t.append(time.perf_counter())
import typer, rich.console, pydantic, yaml
t.append(time.perf_counter())
from excite.cli import score  # noqa: F401 (registers the command)
from excite.score.evaluate import Options, evaluate
from excite.rig.config import load_rig
from excite.io.routes import read_route
from excite.core import kernels
t.append(time.perf_counter())
rig = load_rig("robotaxi")
traj = read_route({ROUTES[0]!r}, suspension=rig.suspension)
t.append(time.perf_counter())
kernels.segments(numpy.array([0.0, 1.0]), numpy.array([0.5]))
t.append(time.perf_counter())
evaluate(traj, rig, Options())
t.append(time.perf_counter())
evaluate(traj, rig, Options())
t.append(time.perf_counter())
import gc, json
gc.freeze()  # as the excite command does before it exits
print(json.dumps([t_wall, [b - a for a, b in zip(t, t[1:])], time.time()]), flush=True)
"""
PHASE_NAMES = ["import numpy", "import numba", "import scipy.linalg (numba's BLAS check needs it)",
               "import scipy.sparse, .interpolate, .spatial (excite's)",
               "import typer, rich, pydantic, yaml", "import excite (CLI, evaluate, routes, rig)",
               "load rig + read route", "numba's first kernel load (its registries)",
               "first evaluation (the other kernels from cache)", "second evaluation"]
FLOOR = ["start python", "import numpy", "import numba", PHASE_NAMES[2], PHASE_NAMES[7],
         "kernel loads (first − second evaluation)", "exit"]


CLIENT = [sys.executable, "-c", "from excite.cli.resident_process import run; run()"]  # what the `excite` script runs


def _env(**extra: str) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
                EXCITE_RESIDENT="0", **extra)


def wall(args: list[str], command: list[str] | None = None, env: dict | None = None) -> float:
    t0 = time.perf_counter()
    subprocess.run([*(command or [sys.executable, "-m", "excite.cli"]), *args], cwd=REPO, env=env or _env(),
                   check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def served(runs: int) -> None:
    """The score commands through the client of a resident process, alternating with cold runs."""
    home = tempfile.mkdtemp(prefix="rt", dir="/tmp")
    env = _env(XDG_RUNTIME_DIR=home)
    del env["EXCITE_RESIDENT"]
    t0 = time.perf_counter()
    subprocess.run([*CLIENT, "resident", "start", "--idle-minutes", "10"], cwd=REPO, env=env, check=True,
                   stdout=subprocess.DEVNULL)
    print(f"resident process started and warmed up in {time.perf_counter() - t0:.1f} s")
    try:
        n = 0
        for name, argv in COMMANDS.items():
            if argv[0] != "score":
                continue
            pairs = [(wall(argv, CLIENT, env), wall(argv)) for _ in range(runs)]
            n += runs
            hot, cold = [p[0] for p in pairs], [p[1] for p in pairs]
            print(f"{name} served by the resident process: {summary(hot)}; alternating cold runs "
                  f"{summary(cold)}; cold/served per pair: median {statistics.median(c / h for h, c in pairs):.1f}x")
        status = subprocess.run([*CLIENT, "resident", "status", "--json"], cwd=REPO, env=env, check=True,
                                capture_output=True, text=True).stdout
        assert json.loads(status)["served"] == n, status  # every timed run was served
    finally:
        subprocess.run([*CLIENT, "resident", "stop"], cwd=REPO, env=env, stdout=subprocess.DEVNULL)
        shutil.rmtree(home, ignore_errors=True)


def phases() -> dict[str, float]:
    t0 = time.time()
    out = subprocess.run([sys.executable, "-c", PHASES], cwd=REPO, env=_env(), check=True,
                         capture_output=True, text=True).stdout
    t1 = time.time()
    t_start, steps, t_end = json.loads(out.strip().splitlines()[-1])
    d = {"start python": t_start - t0, **dict(zip(PHASE_NAMES, steps)), "exit": t1 - t_end}
    d["kernel loads (first − second evaluation)"] = d[PHASE_NAMES[8]] - d[PHASE_NAMES[9]]
    d["floor"] = sum(d[k] for k in FLOOR)
    return d


def cache_report() -> str:
    err = subprocess.run([sys.executable, "-m", "excite.cli", "score", ROUTES[0]], cwd=REPO,
                         env=_env(NUMBA_DEBUG_CACHE="1"), check=True, capture_output=True,
                         text=True).stdout
    loaded, saved = err.count("data loaded from"), err.count("data saved to")
    return f"numba cache in a fresh process: {loaded} kernels loaded, {saved} compiled and saved"


def summary(times: list[float]) -> str:
    return (f"median {statistics.median(times):.2f} s, min {min(times):.2f} s, "
            f"max {max(times):.2f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()
    for argv in COMMANDS.values():
        wall(argv)  # kernels compiled and cached, files in the page cache
    print(f"machine: {machine()}; load average {os.getloadavg()[0]:.1f} at the start")
    print("bytecode of excite's modules: " + ("not cached (PYTHONDONTWRITEBYTECODE is set)"
                                              if os.environ.get("PYTHONDONTWRITEBYTECODE") else "cached"))
    for name, argv in COMMANDS.items():
        times = [wall(argv) for _ in range(args.runs)]
        print(f"{name}: {summary(times)} over {args.runs} cold runs")
    print(f"phases of a cold `excite score {ROUTES[0]}` ({args.runs} fresh processes):")
    runs = [phases() for _ in range(args.runs)]
    for name in ["start python", *PHASE_NAMES, "exit", "kernel loads (first − second evaluation)"]:
        print(f"  {name:<58} {summary([r[name] for r in runs])}")
    print(f"floor with numba ({' + '.join(FLOOR)}): {summary([r['floor'] for r in runs])}")
    print(cache_report())
    served(args.runs)
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
