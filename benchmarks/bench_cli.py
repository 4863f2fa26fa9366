"""Wall and CPU time of the command line from a fresh process: what a person waits for, and where
it goes.

    python benchmarks/bench_cli.py [--runs 9]

Runs each command ``--runs`` times in a fresh interpreter, as the ``excite`` script runs it
(``python -m excite.cli``, with this checkout first on the path; the native module built and
Python's bytecode written by a first run that is not counted):

- ``excite --help``
- ``excite score trajectories/figure_eight_control.csv`` and ``… figure_eight.tum`` (the bundled
  90 s figure-eight as controls and as logged poses)

and prints the median and range of the wall time and of the process's CPU time (user + system,
from ``wait4``): on a shared machine the wall time of a fresh process grows with the other work,
its CPU time much less. Then the largest imports of a fresh ``excite score`` (``python -X
importtime``, cumulative, the median of the runs) and, measured in the same process, the phases
of a score: the imports, reading the route, the evaluation.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results import Session, spread  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ROUTES = ["trajectories/figure_eight_control.csv", "trajectories/figure_eight.tum"]
COMMANDS = {"help": ["--help"], "score_control_csv": ["score", ROUTES[0]], "score_tum": ["score", ROUTES[1]]}

PHASES = f"""
import time
t = [time.perf_counter()]
from excite.cli import app, score  # noqa: F401 (the command line and the score command)
from excite.score.evaluate import Options, evaluate
from excite.rig.config import load_rig
from excite.io.routes import read_route
t.append(time.perf_counter())
rig = load_rig("robotaxi")
traj = read_route({ROUTES[0]!r}, suspension=rig.suspension)
t.append(time.perf_counter())
evaluate(traj, rig, Options())
t.append(time.perf_counter())
evaluate(traj, rig, Options())
t.append(time.perf_counter())
print(" ".join(f"{{b - a:.6f}}" for a, b in zip(t, t[1:])))
"""
PHASE_NAMES = ["import the command line, the evaluator, the routes and the rigs", "load the rig, read the route",
               "first evaluation in the process", "second evaluation"]


def env() -> dict[str, str]:
    """This checkout first on the path, and Python's bytecode written (``PYTHONDONTWRITEBYTECODE``
    dropped): an installed package's is compiled by pip at install, so without it every run would
    compile excite's modules from source (~50–75 ms of CPU) and measure what no user waits for."""
    out = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    out.pop("PYTHONDONTWRITEBYTECODE", None)
    return out


def timed(args: list[str]) -> tuple[float, float]:
    """Wall and CPU time [s] of ``python -m excite.cli ARGS`` (its CPU time from wait4)."""
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "excite.cli", *args], cwd=REPO, env=env(),
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"excite {' '.join(args)} failed: {p.stderr.read().decode()[-500:]}")
    return wall, usage.ru_utime + usage.ru_stime


def imports(args: list[str]) -> dict[str, float]:
    """Cumulative import time [ms] of every top-level import of a fresh ``excite ARGS``."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "excite.cli", *args], cwd=REPO, env=env(),
                          capture_output=True, text=True, check=True)
    out: dict[str, float] = {}
    for line in done.stderr.splitlines():
        m = re.match(r"import time:\s+\d+ \|\s+(\d+) \| (\s*)(\S+)", line)
        if m and len(m.group(2)) <= 2:  # imported by the program, not by another module
            out[m.group(3)] = out.get(m.group(3), 0.0) + int(m.group(1)) / 1e3
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=9)
    args = parser.parse_args()
    session = Session()
    print(f"load average before: {session.load_before}")
    for argv in COMMANDS.values():  # the native module and the bytecode, as a first run writes them
        timed(argv)
    figures: dict[str, object] = {}
    for name, argv in COMMANDS.items():
        runs = [timed(argv) for _ in range(args.runs)]
        w, c = [r[0] for r in runs], [r[1] for r in runs]
        print(f"excite {' '.join(argv):52s} wall {statistics.median(w):.3f} s ({min(w):.3f}–{max(w):.3f}), "
              f"CPU {statistics.median(c):.3f} s ({min(c):.3f}–{max(c):.3f})")
        figures[f"{name}_wall_s"] = spread(w)
        figures[f"{name}_cpu_s"] = spread(c)
    tables = [imports(COMMANDS["score_control_csv"]) for _ in range(args.runs)]
    names = sorted(set().union(*tables), key=lambda n: -statistics.median(t.get(n, 0.0) for t in tables))
    print(f"the largest imports of a fresh `excite score {ROUTES[0]}` (python -X importtime, cumulative, median):")
    top = {}
    for n in names[:12]:
        ms = statistics.median(t.get(n, 0.0) for t in tables)
        top[n] = round(ms, 1)
        print(f"  {n:44s} {ms:7.1f} ms")
    figures["score_imports_ms"] = top
    phases = []
    for _ in range(args.runs):
        done = subprocess.run([sys.executable, "-c", PHASES], cwd=REPO, env=env(), capture_output=True, text=True,
                              check=True)
        phases.append([float(x) for x in done.stdout.split()])
    print(f"the phases of `excite score {ROUTES[0]}` in one process (median, range):")
    for i, n in enumerate(PHASE_NAMES):
        xs = [1e3 * p[i] for p in phases]
        print(f"  {n:64s} {statistics.median(xs):7.1f} ms ({min(xs):.1f}–{max(xs):.1f})")
        figures[f"phase_{i}_ms"] = {"what": n, **spread(xs, 1)}
    path = session.record("cli", figures, note="fresh processes, caches warm (the native module built, bytecode "
                          "written); wall and CPU time per command")
    print(f"load average after: {os.getloadavg()}; figures: {path}")


if __name__ == "__main__":
    main()
