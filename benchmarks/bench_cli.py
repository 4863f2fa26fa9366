"""Wall time of the command line from a cold process: what a person waits for.

Runs each command ``--runs`` times in a fresh interpreter (the compiled kernels are cached on
disk by then: the first run of all compiles them, ~16 s, and is not counted):

- ``excite --help``
- ``excite score trajectories/figure_eight_control.csv`` (the bundled 90 s figure-eight)

and prints the median, min and max wall time of each.

    python benchmarks/bench_cli.py [--runs 7]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_api import machine  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
COMMANDS = {
    "excite --help": ["--help"],
    "excite score trajectories/figure_eight_control.csv": ["score", "trajectories/figure_eight_control.csv"],
}


def wall(args: list[str]) -> float:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "excite.cli", *args], cwd=REPO, env=env, check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()
    for argv in COMMANDS.values():
        wall(argv)  # kernels compiled and cached, files in the page cache
    print(f"machine: {machine()}; load average {os.getloadavg()[0]:.1f}")
    for name, argv in COMMANDS.items():
        times = [wall(argv) for _ in range(args.runs)]
        print(f"{name}: median {statistics.median(times):.2f} s, min {min(times):.2f} s, "
              f"max {max(times):.2f} s over {args.runs} cold runs")


if __name__ == "__main__":
    main()
