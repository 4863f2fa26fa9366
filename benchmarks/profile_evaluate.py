"""Where the evaluator's CPU time goes, down to the native module's loops: a sampling profile with ``perf``.

    python benchmarks/profile_evaluate.py [--seconds 600] [--runs 40] [--top 30] [--annotate eliminate]

Runs both sweeps of a generated drive (the default rig, every coordinate estimated: what
:func:`excite.information.elimination.drive_information` runs on two threads) one after the
other in one thread, ``--runs`` times, while ``perf record -e cpu-clock`` samples this process;
then prints the CPU time per evaluation, each stage's share (the sweeps' own thread CPU time:
sampling the motion, linearising the factors, eliminating the keyframes) and ``perf report`` by
shared object and symbol. The native module (:mod:`excite.core.native`) is compiled C with its
symbols: its loops appear by name (``accumulate``, ``eliminate``, ``border_update`` and, for
each generated kernel, ``lin_<kind>``, ``step2_imu``, …; a function compiled in two versions
shows as ``NAME.avx2`` or ``NAME.default``). ``--annotate NAME`` also prints ``perf annotate``
of that symbol: its hottest instructions.

Needs ``perf`` (Debian: linux-perf) and ``kernel.perf_event_paranoid`` ≤ 2. CPU time, not wall
time, is what this measures: the machine may be shared.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def positive(kind):
    def parse(text: str):
        value = kind(text)
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be positive, got {text}")
        return value
    return parse


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=positive(float), default=600.0, help="length of the generated drive")
    parser.add_argument("--runs", type=positive(int), default=40, help="evaluations (both sweeps) recorded")
    parser.add_argument("--top", type=positive(int), default=30, help="symbols listed")
    parser.add_argument("--annotate", metavar="NAME", help="also print perf annotate of this symbol")
    args = parser.parse_args()
    if shutil.which("perf") is None:
        sys.exit("profile_evaluate: needs perf on PATH (Debian: linux-perf)")

    from bench_evaluate import generated
    from excite.factors.base import Nominal
    from excite.information import elimination, problem
    from excite.information.closure import Closure
    from excite.rig.config import load_rig

    rig = load_rig("robotaxi")
    traj = generated(args.seconds, rig)
    _, nuisance = problem.columns(rig, 1)
    p, closure = nuisance.size, Closure.of(rig)
    K = problem.check_length(Nominal.grid(traj, rig)[1], rig)
    col_map = problem.drive_column_map(rig, 0, 1)
    (forward, backward), _ = elimination.sweeps(traj, 0, K - 1, 0, col_map, rig)

    def both() -> np.ndarray:
        """Both sweeps, one after the other: their thread CPU time per stage [s]."""
        return sum(elimination.sweep(*task, rig, p, closure)[3] for task in (forward, backward))

    both()  # the native module loaded, every buffer's first use behind us
    work = Path(tempfile.mkdtemp(prefix="excite-profile-"))
    data = work / "perf.data"
    try:
        recorder = subprocess.Popen(["perf", "record", "-q", "-e", "cpu-clock", "-F", "2000", "-o", str(data),
                                     "-p", str(os.getpid())], stderr=subprocess.DEVNULL)
        time.sleep(1.0)  # perf attached
        c0 = time.process_time()
        stages = sum(both() for _ in range(args.runs))
        cpu = time.process_time() - c0
        recorder.send_signal(signal.SIGINT)
        recorder.wait()
        if recorder.returncode not in (0, -signal.SIGINT) or not data.exists():
            sys.exit("profile_evaluate: perf record failed (is kernel.perf_event_paranoid ≤ 2?)")
        report = subprocess.run(["perf", "report", "-i", str(data), "--sort", "dso,sym", "--stdio"],
                                capture_output=True, text=True).stdout
        annotation = "" if not args.annotate else subprocess.run(
            ["perf", "annotate", "-i", str(data), "--stdio", "-s", args.annotate],
            capture_output=True, text=True).stdout
    finally:
        shutil.rmtree(work, ignore_errors=True)

    print(f"{args.runs} evaluations of a {args.seconds:g} s drive ({K} keyframes; both sweeps, one thread): "
          f"{cpu / args.runs * 1e3:.1f} ms CPU each; load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    per_run = stages / args.runs * 1e3
    print("per stage (the sweeps' thread CPU time): " + ", ".join(
        f"{name} {ms:.1f} ms" for name, ms in zip(("sample", "linearise", "eliminate"), per_run)))
    rows = [line for line in report.splitlines() if line.strip() and not line.startswith("#")]
    print("\n".join(" ".join(line.split()[:4])[:110] for line in rows[:args.top]))  # share, object, [.], symbol
    if args.annotate:
        lines = [line for line in annotation.splitlines() if line.strip()]
        hot = sorted((line for line in lines if _share(line) is not None), key=_share, reverse=True)
        print(f"\n{args.annotate}: hottest instructions (perf annotate)" if hot else
              f"\nprofile_evaluate: no samples in a symbol named {args.annotate}")
        print("\n".join(line.rstrip()[:120] for line in hot[:25]))


def _share(line: str) -> float | None:
    """The percentage at the start of a ``perf annotate`` line, where it has one."""
    head = line.split(":", 1)[0].strip()
    try:
        return float(head)
    except ValueError:
        return None


if __name__ == "__main__":
    main()
