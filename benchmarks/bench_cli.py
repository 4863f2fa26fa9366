"""Wall time of the command line from a cold process: what a person waits for, and where it goes.

Runs each command ``--runs`` times in a fresh interpreter (the compiled kernels are cached on
disk by then: the first run of all compiles them, ~16 s, and is not counted):

- ``excite --help``
- ``excite score trajectories/figure_eight_control.csv`` (the bundled 90 s figure-eight)

and prints the median, min and max wall time of each. Then splits a cold ``excite score`` into
its phases, each timed in a fresh interpreter the same number of times: starting Python, the
imports of the command (numpy, scipy, numba, pydantic, typer, excite), reading the route, the
first evaluation (which loads the compiled kernels from numba's cache) and a second one. Last,
it checks that the kernels come from the cache in a fresh process (numba's cache debug output:
"data loaded" lines, no "data saved").

    python benchmarks/bench_cli.py [--runs 7]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_api import machine  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ROUTE = "trajectories/figure_eight_control.csv"
COMMANDS = {
    "excite --help": ["--help"],
    f"excite score {ROUTE}": ["score", ROUTE],
}

# the phases of `excite score ROUTE`, in the order the command meets them
PHASES = f"""
import json, time
t = [time.perf_counter()]
import numpy, scipy.sparse, scipy.interpolate, scipy.spatial.transform
t.append(time.perf_counter())
import numba
t.append(time.perf_counter())
import typer, rich.console, pydantic, yaml
t.append(time.perf_counter())
from excite.cli import score
from excite.evaluate import Options, evaluate
from excite.rig import load_rig
from excite.routes import read_route
t.append(time.perf_counter())
rig = load_rig("robotaxi")
traj = read_route({ROUTE!r}, suspension=rig.suspension)
t.append(time.perf_counter())
evaluate(traj, rig, Options())
t.append(time.perf_counter())
evaluate(traj, rig, Options())
t.append(time.perf_counter())
print(json.dumps([b - a for a, b in zip(t, t[1:])]))
"""
PHASE_NAMES = ["import numpy + scipy (sparse, interpolate, spatial)", "import numba",
               "import typer, rich, pydantic, yaml", "import excite (CLI, evaluate, routes, rig)",
               "load rig + read route", "first evaluation (kernels from cache)", "second evaluation"]


def _env(**extra: str) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
                **extra)


def wall(args: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "excite.cli", *args], cwd=REPO, env=_env(), check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def python_start() -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    return time.perf_counter() - t0


def phases() -> list[float]:
    out = subprocess.run([sys.executable, "-c", PHASES], cwd=REPO, env=_env(), check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def cache_report() -> str:
    err = subprocess.run([sys.executable, "-m", "excite.cli", "score", ROUTE], cwd=REPO,
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
    for name, argv in COMMANDS.items():
        times = [wall(argv) for _ in range(args.runs)]
        print(f"{name}: {summary(times)} over {args.runs} cold runs")
    print(f"phases of a cold `excite score {ROUTE}` ({args.runs} fresh processes each):")
    print(f"  {'start python':<55} {summary([python_start() for _ in range(args.runs)])}")
    runs = [phases() for _ in range(args.runs)]
    for i, name in enumerate(PHASE_NAMES):
        print(f"  {name:<55} {summary([r[i] for r in runs])}")
    print(cache_report())
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
