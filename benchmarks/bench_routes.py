"""Time loading KITTI 00 (poses + times) and resampling it to 200 Hz; and reading a 10-minute
TUM route against evaluating it (the service's path: reading must not cost more than scoring).

    python benchmarks/bench_routes.py [--runs 7] [--data ../shared/data]

Prints the median and min of the runs; writes them to ``benchmarks/results/routes.json``.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from results import Session, cpu_model, spread  # noqa: E402

from excite.io.routes import read_kitti  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def load_and_resample(data: Path, rate_hz: float = 200.0) -> int:
    traj = read_kitti(data / "kitti_00_poses.txt", data / "kitti_00_times.txt")
    samples = traj.sample(traj.times(rate_hz))
    return samples.t.size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--data", type=Path, default=DATA)
    args = parser.parse_args()
    session = Session()
    load_and_resample(args.data)  # warm-up: imports, caches
    times = []
    for _ in range(args.runs):
        t0 = time.perf_counter()
        n = load_and_resample(args.data)
        times.append(time.perf_counter() - t0)
    print(f"machine: {cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}")
    print(f"KITTI 00 (4541 poses, 470.6 s) load + smooth + resample to 200 Hz ({n} samples): "
          f"median {statistics.median(times):.3f} s, min {min(times):.3f} s over {args.runs} runs")
    read, score = read_vs_evaluate(args.runs)
    session.record("routes", {"kitti_00_load_resample_200hz_s": spread(times),
                              "tum_10min_read_ms": spread([1e3 * x for x in read], 2),
                              "tum_10min_evaluate_ms": spread([1e3 * x for x in score], 2)},
                   note=f"KITTI 00 (4541 poses, 470.6 s) read, smoothed and resampled to 200 Hz ({n} samples); a "
                        "10-minute figure-eight as TUM text at 10 Hz (6001 poses) read, then scored with the robotaxi "
                        "rig (wall times)")


def read_vs_evaluate(runs: int) -> tuple[list[float], list[float]]:
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
    return read, score


if __name__ == "__main__":
    main()
