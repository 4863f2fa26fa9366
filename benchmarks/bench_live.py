"""Time live guidance: per-update latency and memory while a 60-minute drive streams in.

    python benchmarks/bench_live.py [--minutes 60] [--runs 1]

Writes ``benchmarks/results/live.json``.

The default rig (robotaxi: IMU at 200 Hz, keyframes at 10 Hz, lidar and monocular camera at
10 Hz, wheels, random-walk biases, 24 scored coordinates). A generated drive (varying speed and
curvature, suspension on: the same generator as bench_evaluate.py) is streamed as the vehicle
would stream it: its poses at 10 Hz, one second of them per call of
:meth:`excite.score.live.PoseStream.add`. Every call commits one chunk (10 keyframes: the fit of the
poses around it, 200 IMU samples of preintegration, linearisation, elimination into the running
state) and returns one update (the report of the drive so far, progress, ETAs, advice).

Figures: per-update latency p50 / p99 per 10 minutes of drive (does the cost grow with elapsed
time?), the resident memory at each 10-minute mark, the same latency for the elimination alone
(:class:`excite.score.live.Incremental` fed the batch evaluator's keyframes: no pose fitting, no
report), and the final batch evaluation that ends the drive (:meth:`PoseStream.finish`).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from bench_evaluate import cpu_model, generated
from results import Session

from excite.score import live
from excite.rig.config import load_rig


def rss_mb() -> float:
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def stream(traj, rig, minutes: int) -> dict:
    t = traj.times(10.0)
    s = traj.sample(t)
    ps = live.PoseStream(rig, name=traj.name)
    lat = [[] for _ in range(minutes // 10 or 1)]
    rss = []
    for i in range(0, t.size, 10):
        c0 = time.perf_counter()
        ups = ps.add(t[i:i + 10], s.p_W_V[i:i + 10], s.R_W_V[i:i + 10])
        dt = (time.perf_counter() - c0) * 1e3
        if ups:
            lat[min(int(t[i] // 600), len(lat) - 1)].append(dt)
        if i % 6000 == 0:
            rss.append(rss_mb())
    rss.append(rss_mb())
    c0 = time.perf_counter()
    ps.finish()
    return {"latency": lat, "rss": rss, "finish_s": time.perf_counter() - c0, "poses_mb": ps.n_poses * 13 * 8 / 2**20}


def eliminate_only(traj, rig, minutes: int) -> list[list[float]]:
    inc = live.Incremental(rig)
    lat = [[] for _ in range(minutes // 10 or 1)]
    for nom in live.chunks(traj, rig):
        c0 = time.perf_counter()
        inc.append(nom)
        inc.information()
        lat[min(int(nom.t[0] // 600), len(lat) - 1)].append((time.perf_counter() - c0) * 1e3)
    return lat


def pct(x: list[float], q: float) -> float:
    return float(np.percentile(x, q)) if x else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=int, default=60)
    parser.add_argument("--runs", type=int, default=1)
    args = parser.parse_args()
    session = Session()
    rig = load_rig("robotaxi")
    traj = generated(args.minutes * 60.0, rig)
    print(f"{cpu_model()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}; "
          f"{args.minutes}-minute drive, poses at 10 Hz, IMU at {rig.config.imu.update_rate:g} Hz")
    for run in range(args.runs):
        r = stream(traj, rig, args.minutes)
        e = eliminate_only(traj, rig, args.minutes)
        print(f"run {run + 1}:")
        print("  minutes   update p50 / p99 [ms]   elimination alone p50 / p99 [ms]   RSS at start of span [MB]")
        for k, (a, b) in enumerate(zip(r["latency"], e)):
            rss = r["rss"][k] if k < len(r["rss"]) else float("nan")
            print(f"  {10 * k:3d}-{10 * k + 10:<3d}   {pct(a, 50):8.1f} / {pct(a, 99):6.1f}"
                  f"            {pct(b, 50):8.2f} / {pct(b, 99):6.2f}                  {rss:8.0f}")
        print(f"  RSS at the end of the stream {r['rss'][-1]:.0f} MB (the kept poses: {r['poses_mb']:.1f} MB); "
              f"final batch evaluation (finish) {r['finish_s']:.2f} s")
    spans = [f"{10 * k}-{10 * k + 10}" for k in range(len(r["latency"]))]
    session.record("live", {
        "update_p50_p99_ms_by_minute": {m: [round(pct(a, 50), 1), round(pct(a, 99), 1)]
                                        for m, a in zip(spans, r["latency"])},
        "elimination_alone_p50_p99_ms_by_minute": {m: [round(pct(b, 50), 2), round(pct(b, 99), 2)]
                                                   for m, b in zip(spans, e)},
        "rss_mib_at_10_minute_marks": [round(x) for x in r["rss"]],
        "finish_s": round(r["finish_s"], 2),
    }, note=f"a {args.minutes}-minute generated drive streamed to PoseStream.add one second (10 poses) per call, "
            "robotaxi rig; latency of one update (wall, last run) per 10 minutes of drive, and of the elimination "
            "alone; resident memory; the final batch evaluation")


if __name__ == "__main__":
    main()
