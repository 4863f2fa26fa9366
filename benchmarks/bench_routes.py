"""Time loading KITTI 00 (poses + times) and resampling it to 200 Hz.

    python benchmarks/bench_routes.py [--runs 7] [--data ../shared/data]

Prints the machine (CPU model, cores), the median and min of the runs. Expect well under 1 s.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

from excite.routes import read_kitti

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def load_and_resample(data: Path, rate_hz: float = 200.0) -> int:
    traj = read_kitti(data / "kitti_00_poses.txt", data / "kitti_00_times.txt")
    samples = traj.sample(traj.times(rate_hz))
    return samples.t.size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--data", type=Path, default=DATA)
    args = parser.parse_args()
    load_and_resample(args.data)  # warm-up: imports, caches
    times = []
    for _ in range(args.runs):
        t0 = time.perf_counter()
        n = load_and_resample(args.data)
        times.append(time.perf_counter() - t0)
    print(f"machine: {cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}")
    print(f"KITTI 00 (4541 poses, 470.6 s) load + smooth + resample to 200 Hz ({n} samples): "
          f"median {statistics.median(times):.3f} s, min {min(times):.3f} s over {args.runs} runs")


if __name__ == "__main__":
    main()
