"""Time the route segments' information (``Options(segments=N)``, what the page's map and the
plots colour the route with) against the score alone, and the peak memory of a long drive's.

    python benchmarks/bench_segments.py [--runs 7] [--segments 12] [--baseline REV] [--skip-memory]

Timed, alternating (so that drifts of the machine's speed hit all alike): the 10-minute drive of
``bench_evaluate.py`` (robotaxi rig) scored without and with ``--segments`` segments; with
``--baseline REV``, the same with segments by the package as committed at REV. Memory: the peak
resident set of a fresh process that scores a 30-minute drive at 100 keyframes/s with a 10 kHz IMU
(the largest the service accepts by default is 200 000 keyframes) with 12 segments, and of one that
scores it without.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path


from bench_evaluate import baseline_package, generated, load, ratios, row, timed
from results import Session, spread

from excite.score.evaluate import Options, evaluate
from excite.rig.config import build_rig, load_rig

ROOT = Path(__file__).resolve().parents[1]

_PEAK = """
import importlib, json, resource, sys
sys.path[:0] = [{bench!r}, {where!r}]
from bench_evaluate import generated
ev, rg, vh = (importlib.import_module({pkg!r} + m) for m in (".score.evaluate", ".rig.config", ".motion.vehicle"))
rig = rg.build_rig(json.loads({rig!r}))
ev.evaluate(generated(1800.0, rig, vh), rig, ev.Options(segments={segments}))
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def peak_rss_mb(rig_data: dict, segments: int, baseline: Path | None = None) -> float:
    """Peak resident set [MB] of a fresh process scoring the 30-minute drive (with the package
    ``excite_baseline`` in the folder ``baseline``, if given)."""
    code = _PEAK.format(bench=str(ROOT / "benchmarks"), where=str(baseline or ROOT), rig=json.dumps(rig_data),
                        pkg="excite_baseline" if baseline else "excite", segments=segments)
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    return int(out.split()[-1]) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--segments", type=int, default=12)
    parser.add_argument("--baseline", metavar="REV", help="also time the package at this git revision")
    parser.add_argument("--skip-memory", action="store_true", help="skip the 30-minute peak-memory runs")
    args = parser.parse_args()
    if args.runs < 1 or args.segments < 1:
        parser.error("--runs and --segments must be at least 1")
    session = Session()
    figures: dict = {}
    rig = load_rig("robotaxi")
    print(load())
    traj = generated(600.0, rig)
    with_segments = Options(segments=args.segments)
    evaluate(traj, rig, with_segments)  # warm up
    fns = [lambda: evaluate(traj, rig), lambda: evaluate(traj, rig, with_segments)]
    with tempfile.TemporaryDirectory() as tmp:
        base_dir = Path(tmp) if args.baseline else None
        if args.baseline:
            ev, rg, vh = baseline_package(args.baseline, Path(tmp))
            base_rig = rg.load_rig("robotaxi")
            base_traj = generated(600.0, base_rig, vh)
            base_options = ev.Options(segments=args.segments)
            ev.evaluate(base_traj, base_rig, base_options)  # warm up (compiles its kernels: a fresh cache)
            fns.append(lambda: ev.evaluate(base_traj, base_rig, base_options))
        runs = [[timed(fn) for fn in fns] for _ in range(args.runs)]
        alone, seg = [r[0] for r in runs], [r[1] for r in runs]
        print(row("10-minute drive, score alone", alone))
        print(row(f"10-minute drive, {args.segments} segments", seg))
        print(ratios("segments / score alone", seg, alone))
        figures["score_alone_cpu_ms"] = spread([t[1] for t in alone], 1)
        figures[f"with_{args.segments}_segments_cpu_ms"] = spread([t[1] for t in seg], 1)
        figures["segments_over_alone_cpu"] = spread([x[1] / y[1] for x, y in zip(seg, alone)], 3)
        figures["segments_over_alone_wall"] = spread([x[0] / y[0] for x, y in zip(seg, alone)], 3)
        if args.baseline:
            base = [r[2] for r in runs]
            print(row(f"{args.baseline}, {args.segments} segments", base))
            print(ratios(f"segments / {args.baseline}'s", seg, base))

        if not args.skip_memory:
            data = json.loads(json.dumps(rig.config.model_dump()))
            data["keyframe_rate_hz"] = 100.0
            data["imu"]["update_rate"] = 10_000.0
            build_rig(data)  # a bad edit fails here, not in the child
            for n in (0, 12):
                mb = peak_rss_mb(data, n)
                figures[f"peak_rss_30min_100hz_{n}_segments_mib"] = round(mb)
                print(f"30-minute drive, 100 keyframes/s, 10 kHz IMU, {n:2d} segments: peak RSS {mb:.0f} MB"
                      + (f"; {args.baseline} {peak_rss_mb(data, n, base_dir):.0f} MB" if base_dir else ""))
    print(load())
    if not args.baseline:
        session.record("segments", figures, note="the 10-minute generated drive (robotaxi rig) scored without and "
                       "with segments, alternating (CPU ms of one evaluation; ratio per pair); peak resident set of a "
                       "fresh process scoring a 30-minute drive at 100 keyframes/s with a 10 kHz IMU")


if __name__ == "__main__":
    main()
