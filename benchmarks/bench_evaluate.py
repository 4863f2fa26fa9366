"""Time the evaluator: the score of a drive with every parameter of the default rig estimated.

    python benchmarks/bench_evaluate.py [--runs 7] [--skip-dense] [--baseline REV] [--when-idle S]

The default rig (robotaxi) has an IMU at 200 Hz, keyframes at 10 Hz, a lidar and a monocular
camera at 10 Hz, wheel encoders; all 23 scored calibration coordinates are estimated, with 4
nuisances (the camera's scale, tyre slip, scrub and slip angle: 27 columns). Drives are
generated (varying speed and curvature, suspension on). Timed: trajectory → report, i.e.
sampling the motion, linearising every factor, marginalising, eigen-analysis and the report.

Figures: median and range over ``--runs`` for a 10-minute and a 60-minute drive (alternating) and
KITTI 00 (loading the file excluded) with the rig's random-walk biases; the 10-minute drive with
random-walk against constant biases, side by side; the 10-minute drive with a GNSS antenna added
to the rig against the rig without it, side by side; with ``--baseline REV``, the same 10-minute
drive scored by the package as committed at git revision REV (its default rig), alternating with
this one; and the dense numpy reference against the fast path on a 1-minute drive (its dense J
is 18612 × 9042, 1.3 GB; a 2-minute drive's, 37212 × 18042, makes numpy's bundled OpenBLAS
crash with a segmentation fault in ``J.T @ J``).

Every figure is given as wall time and as the process's CPU time. This machine is shared: when
other work keeps its cores busy, wall times grow with the load (printed at start and end) while
CPU time stays close to what the evaluator itself spends; on an idle machine with both cores,
wall ≈ CPU / 2 plus the few milliseconds run on one thread. ``--when-idle S`` waits up to S seconds
before each timed run until the machine's cores were ≥ 90 % idle over 0.2 s, and says how many
runs started that way: the wall time the evaluator takes on this machine when nothing else runs.
"""

from __future__ import annotations

import argparse
import importlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from excite.information import dense, elimination, problem
from excite.motion import vehicle as excite_vehicle
from excite.score.evaluate import evaluate
from excite.factors.base import Nominal
from excite.rig.config import load_rig
from excite.io.routes import read_kitti

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results import Session, idle_fraction, spread  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


def cpu_model() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown CPU"


def load() -> str:
    return "load average " + " ".join(f"{x:.1f}" for x in os.getloadavg())


def generated(duration_s: float, rig, vehicle=None):
    v = vehicle or excite_vehicle  # or the baseline revision's own vehicle module
    t = np.linspace(0.0, duration_s, int(duration_s / 2) + 1)
    prof = v.ControlProfile(t, 8 + 3 * np.sin(t / 7), 0.05 * np.sin(t / 5) + 0.02 * np.sin(t / 1.7),
                            grade_rad=0.02 * np.sin(t / 23))
    return v.drive(prof, rig.suspension)


IDLE_WAIT_S = 0.0  # --when-idle
_started_idle = [0, 0]  # timed runs that started on an idle machine, timed runs


def timed(fn) -> tuple[float, float]:
    """Wall and process CPU time of one call [ms] (with ``--when-idle``, started once the machine is idle)."""
    if IDLE_WAIT_S:
        end = time.monotonic() + IDLE_WAIT_S
        idle = False
        while not idle and time.monotonic() < end:
            idle = idle_fraction() >= 0.9
        _started_idle[0] += idle
    _started_idle[1] += 1
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return (time.perf_counter() - t0) * 1e3, (time.process_time() - c0) * 1e3


def summary(xs: list[float]) -> str:
    return f"{statistics.median(xs):7.1f} ({min(xs):.1f}–{max(xs):.1f})"


def row(name: str, times: list[tuple[float, float]]) -> str:
    return f"{name:34s} wall {summary([t[0] for t in times])} ms   cpu {summary([t[1] for t in times])} ms"


def ratios(name: str, a: list[tuple[float, float]], b: list[tuple[float, float]]) -> str:
    out = []
    for i, kind in enumerate(("wall", "cpu")):
        r = [x[i] / y[i] for x, y in zip(a, b)]
        out.append(f"{kind} {statistics.median(r):.2f}x ({min(r):.2f}–{max(r):.2f})")
    return f"{name:34s} per alternating pair: " + ", ".join(out)


def baseline_package(rev: str, into: Path):
    """The ``excite`` package as committed at ``rev``, importable as ``excite_baseline`` (its
    imports within the package are relative)."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "excite"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    (into / "excite").rename(into / "excite_baseline")
    sys.path.insert(0, str(into))
    # the packages by concern (from the factor registry on), or the flat layout before them
    layout = ("score.evaluate", "rig.config", "motion.vehicle") if (into / "excite_baseline" / "score").is_dir() \
        else ("evaluate", "rig", "vehicle")
    return tuple(importlib.import_module(f"excite_baseline.{m}") for m in layout)


def figure(times: list[tuple[float, float]]) -> dict:
    """Wall and CPU time [ms] of timed runs as benchmark figures (median, range, runs)."""
    return {"wall_ms": spread([t[0] for t in times], 1), "cpu_ms": spread([t[1] for t in times], 1)}


def ratio_figure(a: list[tuple[float, float]], b: list[tuple[float, float]]) -> dict:
    return {f"{kind}_ratio": spread([x[i] / y[i] for x, y in zip(a, b)], 3) for i, kind in enumerate(("wall", "cpu"))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--skip-dense", action="store_true", help="skip the (slow) dense reference")
    parser.add_argument("--baseline", metavar="REV", help="also time the package at this git revision, side by side")
    parser.add_argument("--when-idle", type=float, default=0.0, metavar="S",
                        help="wait up to S seconds before each timed run for the machine to be idle")
    args = parser.parse_args()
    session = Session()
    figures: dict = {}
    global IDLE_WAIT_S
    IDLE_WAIT_S = args.when_idle
    rig = load_rig("robotaxi")
    blas = os.environ.get("OPENBLAS_NUM_THREADS")
    print(f"machine: {cpu_model()}, {os.cpu_count()} cores; OPENBLAS_NUM_THREADS={blas or 'unset'}; rig robotaxi "
          f"({len(rig.coordinates)} coordinates, IMU {rig.config.imu.update_rate:g} Hz, keyframes "
          f"{rig.keyframe_rate_hz:g} Hz); {load()}")

    # the 10- and 60-minute drives alternate, so that drifts of the machine's speed hit both alike
    drives = {minutes: generated(60.0 * minutes, rig) for minutes in (10, 60)}
    n_kf = {m: Nominal.grid(traj, rig)[1] for m, traj in drives.items()}
    for traj in drives.values():
        evaluate(traj, rig)  # warm up
    times: dict[int, list] = {10: [], 60: []}
    for _ in range(args.runs):
        for minutes, traj in drives.items():
            times[minutes].append(timed(lambda: evaluate(traj, rig)))
    print(row("10-minute drive, random walk", times[10]))
    print(row("60-minute drive, random walk", times[60]))
    print(ratios("60 min / 10 min", times[60], times[10]))
    figures["ten_minute_drive"] = figure(times[10])
    figures["sixty_minute_drive"] = figure(times[60])
    figures["sixty_over_ten_minutes"] = ratio_figure(times[60], times[10])
    print(f"{'':34s} per keyframe: cpu {statistics.median(t[1] for t in times[10]) / n_kf[10] * 1e3:.1f} vs "
          f"{statistics.median(t[1] for t in times[60]) / n_kf[60] * 1e3:.1f} µs")

    # the same 10-minute drive with constant biases, alternating with the random-walk model: the
    # price of the drifting biases as a ratio measured side by side
    const = rig.with_constant_biases()
    evaluate(drives[10], const)
    pairs = [(timed(lambda: evaluate(drives[10], rig)), timed(lambda: evaluate(drives[10], const)))
             for _ in range(args.runs)]
    print(row("10-minute drive, random walk", [p[0] for p in pairs]))
    print(row("10-minute drive, constant biases", [p[1] for p in pairs]))
    print(ratios("random walk / constant", [p[0] for p in pairs], [p[1] for p in pairs]))
    figures["ten_minute_drive_constant_biases"] = figure([p[1] for p in pairs])
    figures["random_walk_over_constant_biases"] = ratio_figure([p[0] for p in pairs], [p[1] for p in pairs])
    for name, r in (("random walk", rig), ("constant biases", const)):
        stages = [evaluate(drives[10], r).timings_ms for _ in range(args.runs)]
        print(f"10-minute drive, {name}: CPU time per stage summed over threads (medians): " + ", ".join(
            f"{k.removesuffix('_thread')} {statistics.median(t[k] for t in stages):.1f} ms"
            for k in stages[0] if k.endswith("_thread")))

    # the same 10-minute drive with a GNSS antenna (RTK preset, 10 Hz fixes) added to the rig,
    # alternating with the rig without it: the price of the absolute observations (world states
    # with the drive's origin, no gauge) and of the differenced fixes, as a ratio side by side
    data = rig.config.model_dump()
    data["sensors"].append({"name": "gnss", "kind": "gnss", "rate_hz": 10.0,
                            "T_B_S": {"translation_m": [0.2, 0.0, 1.5]}, "noise": "rtk"})
    gnss = rig.with_config(**data)
    evaluate(drives[10], gnss)
    pairs = [(timed(lambda: evaluate(drives[10], gnss)), timed(lambda: evaluate(drives[10], rig)))
             for _ in range(args.runs)]
    print(row("10-minute drive, with GNSS", [p[0] for p in pairs]))
    print(row("10-minute drive, without", [p[1] for p in pairs]))
    print(ratios("with GNSS / without", [p[0] for p in pairs], [p[1] for p in pairs]))
    figures["with_gnss_over_without"] = ratio_figure([p[0] for p in pairs], [p[1] for p in pairs])
    stages = [evaluate(drives[10], gnss).timings_ms for _ in range(args.runs)]
    print("10-minute drive, with GNSS: CPU time per stage summed over threads (medians): " + ", ".join(
        f"{k.removesuffix('_thread')} {statistics.median(t[k] for t in stages):.1f} ms"
        for k in stages[0] if k.endswith("_thread")))

    if args.baseline:
        with tempfile.TemporaryDirectory() as tmp:
            ev, rg, vh = baseline_package(args.baseline, Path(tmp))
            base_rig = rg.load_rig("robotaxi")
            base_traj = generated(600.0, base_rig, vh)
            ev.evaluate(base_traj, base_rig)  # warm up (compiles its kernels: a fresh cache)
            trip = [(timed(lambda: evaluate(drives[10], rig)), timed(lambda: evaluate(drives[10], const)),
                     timed(lambda: ev.evaluate(base_traj, base_rig))) for _ in range(args.runs)]
        print(row(f"10-minute drive, {args.baseline} (its default rig)", [t[2] for t in trip]))
        print(ratios(f"random walk / {args.baseline}", [t[0] for t in trip], [t[2] for t in trip]))
        print(ratios(f"constant biases / {args.baseline}", [t[1] for t in trip], [t[2] for t in trip]))

    if DATA.is_dir():
        kitti = read_kitti(DATA / "kitti_00_poses.txt", DATA / "kitti_00_times.txt")
        evaluate(kitti, rig)
        kitti_times = [timed(lambda: evaluate(kitti, rig)) for _ in range(args.runs)]
        print(row("KITTI 00 (470 s), random walk", kitti_times))
        figures["kitti_00"] = figure(kitti_times)

    if not args.skip_dense:
        traj = generated(60.0, rig)
        nom = Nominal.of(traj, rig)
        t0 = time.perf_counter()
        reference = dense.marginal_dense(problem.build(nom, rig))
        t_dense = time.perf_counter() - t0
        t_fast = statistics.median(timed(lambda: elimination.drive_information([traj], rig))[0] for _ in range(5))
        fast = elimination.drive_information([traj], rig).information
        S = np.array([1.0 if c.nuisance else c.target for c in rig.coordinates])
        rel = np.abs((fast - reference) * np.outer(S, S)).max() / np.abs(fast * np.outer(S, S)).max()
        print(f"1-minute drive: dense reference {t_dense * 1e3:.0f} ms, fast path {t_fast:.1f} ms "
              f"→ {t_dense * 1e3 / t_fast:.0f}x faster; max relative difference {rel:.1e}")
        figures["one_minute_dense_over_fast"] = round(t_dense * 1e3 / t_fast)
        figures["one_minute_max_relative_difference"] = float(f"{rel:.2g}")
    if IDLE_WAIT_S:
        print(f"timed runs started on an idle machine (≥ 90 % idle over 0.2 s): {_started_idle[0]} of {_started_idle[1]}")
    print(load())
    if args.baseline is None:  # a comparison with another revision is not this commit's figure
        figures["timed_runs_started_idle"] = f"{_started_idle[0]} of {_started_idle[1]}" if IDLE_WAIT_S else None
        session.record("evaluate", figures, note=f"robotaxi rig, every coordinate estimated; generated drives; "
                                                 f"{args.runs} runs each; OPENBLAS_NUM_THREADS={blas or 'unset'}")


if __name__ == "__main__":
    main()
