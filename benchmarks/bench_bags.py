"""Time a 1-hour bag to a scored report: a synthetic ROS 2 MCAP (100 Hz nav_msgs/Odometry +
200 Hz sensor_msgs/Imu, written once by excite's writer and cached), read with the measured IMU
and scored with the robotaxi rig. Reports wall time of each stage and peak memory.

    python benchmarks/bench_bags.py [--runs 3] [--minutes 60] [--cache /tmp/excite-bench-bag]

Each run is a fresh process (so peak RSS is that run's): the poses and IMU out of the bag
(stream + decode), the route (that + the smoothing fit), the evaluation, and the whole.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parent))
from results import Session, cpu_model, spread  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def make_bag(path: Path, minutes: float) -> None:
    from excite.io.bags import write_bag
    from excite.rig.config import load_rig
    from excite.motion.vehicle import ControlProfile, drive

    duration = minutes * 60.0
    t = np.linspace(0.0, duration, int(duration * 10) + 1)
    profile = ControlProfile(t_s=t, speed_mps=8.0 + 3.0 * np.sin(2 * np.pi * t / 40.0),
                             curvature_1pm=0.03 * np.sin(2 * np.pi * t / 25.0),
                             grade_rad=0.02 * np.sin(2 * np.pi * t / 60.0), name="hour")
    pose = load_rig("robotaxi").config.vehicle.T_V_B
    write_bag(drive(profile), path, topic="/odom", rate_hz=100.0, imu_topic="/imu",
              imu_rate_hz=200.0, T_V_B=(pose.R, pose.p))


def one_run(path: Path) -> dict:
    t0 = time.perf_counter()
    from excite.io import bags
    from excite.io.bags import reader
    from excite.score.evaluate import evaluate
    from excite.rig.config import load_rig

    rig = load_rig("robotaxi")
    t1 = time.perf_counter()
    reader._read_drive(path, "/odom", "/imu", None, None)  # stream + decode only
    t2 = time.perf_counter()
    traj = bags.read_bag_route(path, "/odom", imu_topic="/imu")  # again, with the fit
    t3 = time.perf_counter()
    rep = evaluate(traj, rig)
    t4 = time.perf_counter()
    return {"import_s": t1 - t0, "decode_s": t2 - t1, "route_s": t3 - t2, "score_s": t4 - t3,
            "total_s": (t3 - t2) + (t4 - t3), "score": rep.score, "duration_s": traj.duration,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--cache", type=Path, default=Path("/tmp/excite-bench-bag"))
    parser.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        print(json.dumps(one_run(args.child)))
        return
    session = Session()
    path = args.cache / f"drive_{args.minutes:g}min"
    if not path.exists():
        args.cache.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        make_bag(path, args.minutes)
        print(f"wrote {path} in {time.perf_counter() - t0:.0f} s")
    size_mb = sum(f.stat().st_size for f in path.iterdir()) / 1e6
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    cmd = [sys.executable, __file__, "--child", str(path)]
    subprocess.run(cmd, env=env, check=True, capture_output=True)  # warm-up: the compiled kernels loaded, the bag in the page cache
    runs = [json.loads(subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout)
            for _ in range(args.runs)]
    print(f"machine: {cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}")
    print(f"bag: {size_mb:.0f} MB MCAP, {args.minutes:g} min, /odom 100 Hz + /imu 200 Hz "
          f"({int(args.minutes * 60 * 300)} messages)")
    for key, label in (("decode_s", "poses + IMU out of the bag (stream, decode, checks)"),
                       ("route_s", "bag → route (the above + the smoothing fit shared with TUM)"),
                       ("score_s", "score (first evaluation in the process: loads compiled kernels)"),
                       ("total_s", "bag → scored report"), ("peak_rss_mb", "peak RSS [MB]")):
        vals = [r[key] for r in runs]
        print(f"  {label}: median {statistics.median(vals):.2f}, range {min(vals):.2f}–{max(vals):.2f}")
    print(f"  score {runs[0]['score']:.4g} over {runs[0]['duration_s']:.0f} s; {args.runs} runs")
    session.record("bags", {"bag_mb": round(size_mb), **{key: spread([r[key] for r in runs], 2) for key in (
        "decode_s", "route_s", "score_s", "total_s", "peak_rss_mb")}},
        note=f"a synthetic {args.minutes:g}-minute ROS 2 MCAP (/odom 100 Hz + /imu 200 Hz), each run a fresh process: "
             "poses and IMU out of the bag (decode), the route (decode + smoothing fit), the robotaxi rig's score "
             "(the first evaluation in the process), bag to scored report (total), peak resident set")


if __name__ == "__main__":
    main()
