"""What the test suite costs: wall and CPU time of the README's `python -m pytest -q -n auto`, with a marker expression.

    python benchmarks/bench_tests.py                 # the everyday loop: -m "not slow"
    python benchmarks/bench_tests.py --all           # everything (what .ci/run runs)
    python benchmarks/bench_tests.py --runs 3        # a range over three runs
    python benchmarks/bench_tests.py --durations 30  # and the 30 slowest tests

The machine is shared, so wall time moves with others' work: the CPU time of pytest and every
process it starts (user + system, from the children's resource usage) is recorded beside it, with
the load average before and after (benchmarks/results.py). Writes benchmarks/results/tests_loop.json
(or tests_all.json) with the counts pytest reported.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results import ROOT, Session, spread  # noqa: E402


def run_once(marker: str | None, durations: int = 0) -> dict:
    args = [sys.executable, "-m", "pytest", "-q", "-n", "auto", "-rf", "-p", "no:cacheprovider"] \
        + (["-m", marker] if marker else []) \
        + ([f"--durations={durations}"] if durations else [])
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(args, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    lines = proc.stdout.strip().splitlines()
    tail = lines[-1] if lines else ""
    for line in lines:
        if line.startswith(("FAILED", "ERROR")) or (durations and " call " in line and line[:1].isdigit()):
            print(line)
    counts = {k: int(v) for v, k in re.findall(r"(\d+) (passed|failed|skipped|deselected|errors?)", tail)}
    return {"wall_s": wall, "cpu_s": cpu, "counts": counts, "returncode": proc.returncode, "summary": tail}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--all", action="store_true", help="run every test (no marker expression)")
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--durations", type=int, default=0, metavar="N", help="also print the N slowest tests")
    a = ap.parse_args()
    marker = None if a.all else "not slow"
    session = Session()
    runs = [run_once(marker, a.durations) for _ in range(a.runs)]
    for r in runs:
        print(f"{r['summary']}  (wall {r['wall_s']:.0f} s, CPU {r['cpu_s']:.0f} s)")
    name = "tests_all" if a.all else "tests_loop"
    session.record(name, {"wall_s": spread([r["wall_s"] for r in runs], 1),
                          "cpu_s": spread([r["cpu_s"] for r in runs], 1),
                          "counts": runs[-1]["counts"], "all_passed": all(r["returncode"] == 0 for r in runs)},
                   note=(f"python -m pytest -n auto -m '{marker}'" if marker else "python -m pytest -n auto (every test)")
                   + f" on {os.cpu_count()} CPUs; CPU = user + system time of pytest, its workers and every "
                   "process they started")
    return 0 if all(r["returncode"] == 0 for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
