"""Time the evaluator: the score of a drive with every parameter of the default rig estimated.

    python benchmarks/bench_evaluate.py [--runs 7] [--skip-dense]

The default rig (robotaxi) has an IMU at 200 Hz, keyframes at 10 Hz, a lidar and a monocular
camera at 10 Hz, wheel encoders; all 24 calibration coordinates are estimated. Drives are
generated (varying speed and curvature, suspension on). Timed: trajectory → report, i.e.
sampling the motion, linearising every factor, marginalising, eigen-analysis and the report.

Figures: median of ``--runs`` for a 10-minute and a 60-minute drive (alternating) and KITTI 00
(loading the file excluded) with the rig's random-walk biases; the 10-minute drive with random-walk
against constant biases, side by side; and the dense numpy reference against the fast path on a
2-minute drive.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np

from excite import information
from excite.evaluate import evaluate
from excite.factors.base import Nominal
from excite.rig import load_rig
from excite.routes import read_kitti
from excite.vehicle import ControlProfile, drive

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def cpu_model() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown CPU"


def generated(duration_s: float, rig):
    t = np.linspace(0.0, duration_s, int(duration_s / 2) + 1)
    prof = ControlProfile(t, 8 + 3 * np.sin(t / 7), 0.05 * np.sin(t / 5) + 0.02 * np.sin(t / 1.7),
                          grade_rad=0.02 * np.sin(t / 23), name=f"generated {duration_s / 60:.0f} min")
    return drive(prof, rig.suspension)


def median_ms(fn, runs: int) -> tuple[float, float]:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times), min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--skip-dense", action="store_true", help="skip the (slow) dense reference")
    args = parser.parse_args()
    rig = load_rig("robotaxi")
    print(f"machine: {cpu_model()}, {os.cpu_count()} cores; rig robotaxi "
          f"({len(rig.coordinates)} coordinates, IMU {rig.config.imu.update_rate:g} Hz, keyframes "
          f"{rig.keyframe_rate_hz:g} Hz)")

    # the 10- and 60-minute drives alternate, so that drifts of the machine's speed hit both alike
    drives = {minutes: generated(60.0 * minutes, rig) for minutes in (10, 60)}
    times: dict[int, list[float]] = {10: [], 60: []}
    n_kf = {m: Nominal.grid(traj, rig)[1] for m, traj in drives.items()}
    for traj in drives.values():
        evaluate(traj, rig)  # warm up
    for _ in range(args.runs):
        for minutes, traj in drives.items():
            times[minutes].append(median_ms(lambda: evaluate(traj, rig), 1)[0])
    rows = [(f"{m}-minute drive", statistics.median(times[m]), min(times[m])) for m in (10, 60)]
    # the same 10-minute drive with constant biases, alternating with the random-walk model: the
    # price of the drifting biases as a ratio measured side by side
    const = rig.with_constant_biases()
    evaluate(drives[10], const)
    pairs = [(median_ms(lambda: evaluate(drives[10], rig), 1)[0], median_ms(lambda: evaluate(drives[10], const), 1)[0])
             for _ in range(args.runs)]
    print(f"10-minute drive, random-walk / constant biases: median {statistics.median(p[0] for p in pairs):.1f} / "
          f"{statistics.median(p[1] for p in pairs):.1f} ms, ratio per pair median "
          f"{statistics.median(p[0] / p[1] for p in pairs):.2f}x")
    stages = [evaluate(drives[10], rig).timings_ms for _ in range(args.runs)]
    print("10-minute drive, thread time per stage summed over chunks (medians): " + ", ".join(
        f"{k.removesuffix('_thread')} {statistics.median(t[k] for t in stages):.1f} ms"
        for k in stages[0] if k.endswith("_thread")))
    if DATA.is_dir():
        kitti = read_kitti(DATA / "kitti_00_poses.txt", DATA / "kitti_00_times.txt")
        med, best = median_ms(lambda: evaluate(kitti, rig), args.runs)
        rows.append(("KITTI 00 (470 s)", med, best))
    for name, med, best in rows:
        print(f"{name:22s} median {med:8.1f} ms   min {best:8.1f} ms")
    ratios = [b / a for a, b in zip(times[10], times[60])]
    print(f"60 min / 10 min: {rows[1][1] / rows[0][1]:.2f}x (medians); per alternating pair: median "
          f"{statistics.median(ratios):.2f}x, range {min(ratios):.2f}–{max(ratios):.2f}x; per keyframe "
          f"{rows[0][1] / n_kf[10] * 1e3:.2f} vs {rows[1][1] / n_kf[60] * 1e3:.2f} µs")

    if not args.skip_dense:
        traj = generated(120.0, rig)
        nom = Nominal.of(traj, rig)
        t0 = time.perf_counter()
        dense = information.marginal_dense(information.build(nom, rig))
        t_dense = time.perf_counter() - t0
        t_fast, _ = median_ms(lambda: information.drive_information([traj], rig), 5)
        fast = information.drive_information([traj], rig).information
        S = np.array([1.0 if c.nuisance else c.target for c in rig.coordinates])
        rel = np.abs((fast - dense) * np.outer(S, S)).max() / np.abs(fast * np.outer(S, S)).max()
        print(f"2-minute drive: dense reference {t_dense * 1e3:.0f} ms, fast path {t_fast:.1f} ms "
              f"→ {t_dense * 1e3 / t_fast:.0f}x faster; max relative difference {rel:.1e}")


if __name__ == "__main__":
    main()
