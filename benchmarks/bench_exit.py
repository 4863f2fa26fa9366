"""Every command exits: ``excite optimize`` run many times with short budgets, each under a
timeout. A run that does not exit within its budget plus ``--grace-s`` counts as a hang (and is
killed); the figures are the count of runs, of hangs and of non-zero exits, and the spread of
the time from start to exit beyond the budget.

    python benchmarks/bench_exit.py [--runs 200] [--budgets 2 3 5 8] [--grace-s 60]

Budgets cycle through ``--budgets`` and seeds through the runs, so that the comparison worker
is ended in every phase (starting, scoring references, screening, COBYLA, sending a result).
The command runs as ``python -m excite.cli`` (the library's own entry point).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results import Session, spread  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--budgets", type=float, nargs="+", default=[2.0, 3.0, 5.0, 8.0])
    ap.add_argument("--grace-s", type=float, default=60.0)
    args = ap.parse_args()
    session = Session()
    env = {**os.environ, "PYTHONPATH": str(ROOT), "EXCITE_COMPILE": os.environ.get("EXCITE_COMPILE", "0")}
    hangs, failures, over = 0, 0, []
    t_all = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="excite-exit-") as tmp:
        for i in range(args.runs):
            budget = args.budgets[i % len(args.budgets)]
            out = Path(tmp) / f"run{i}"
            cmd = [sys.executable, "-m", "excite.cli", "optimize", "-o", str(out), "--time-budget", str(budget),
                   "--duration", "30", "--lot", "60x40", "--n-random", "20", "--seed", str(i)]
            t0 = time.monotonic()
            try:
                r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=budget + args.grace_s)
                took = time.monotonic() - t0
                over.append(took - budget)
                if r.returncode != 0:
                    failures += 1
                    print(f"run {i}: exit {r.returncode}: {r.stderr.strip()[-300:]}", flush=True)
            except subprocess.TimeoutExpired:
                hangs += 1
                print(f"run {i}: did not exit within {budget + args.grace_s:g} s (killed)", flush=True)
            if (i + 1) % 10 == 0 or i + 1 == args.runs:  # recorded as it goes: a stopped run keeps its count
                figures = {"runs": i + 1, "asked": args.runs, "hangs": hangs, "nonzero_exits": failures,
                           "exit_after_budget_s": spread(over, 3), "total_s": round(time.monotonic() - t_all, 1),
                           "budgets_s": args.budgets}
                path = session.record("exit", figures, note="excite optimize with short budgets, each under a "
                                      "timeout of its budget plus the grace: a run that does not exit is a hang")
                print(figures, "→", path, flush=True)
    return 1 if hangs or failures else 0


if __name__ == "__main__":
    sys.exit(main())
