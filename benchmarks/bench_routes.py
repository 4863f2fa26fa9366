"""Time loading KITTI 00 (poses + times) and resampling it to 200 Hz; and reading a 10-minute
TUM route against evaluating it (the service's path: reading must not cost more than scoring).

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

from excite.io.routes import read_kitti

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
    read_vs_evaluate(args.runs)


def read_vs_evaluate(runs: int) -> None:
    """A 10-minute figure-eight as TUM text at 10 Hz (what /v1/score receives): read, then score."""
    import sys
    import tempfile

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_api import route_text
    from excite.score.evaluate import evaluate
    from excite.rig.config import load_rig
    from excite.io.routes import read_tum

    rig = load_rig("robotaxi")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "figure_eight_10min.tum"
        path.write_text(route_text(600.0))
        evaluate(read_tum(path), rig)  # warm-up
        read, score = [], []
        for _ in range(runs):
            t0 = time.perf_counter()
            traj = read_tum(path)
            t1 = time.perf_counter()
            evaluate(traj, rig)
            read.append(t1 - t0)
            score.append(time.perf_counter() - t1)
    print(f"10-minute TUM route (6001 poses): read median {1e3 * statistics.median(read):.0f} ms "
          f"(min {1e3 * min(read):.0f}), evaluate median {1e3 * statistics.median(score):.0f} ms "
          f"(min {1e3 * min(score):.0f}) over {runs} runs")


if __name__ == "__main__":
    main()
