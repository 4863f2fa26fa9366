"""Time `excite mine` on a fleet: 10 synthetic logs of 1 h each (default), 120 s windows.

    python benchmarks/bench_mine.py [--logs 10] [--hours 1] [--window 120] [--chunk 10] [--runs 2]
                                    [--scratch-sample 12] [--no-dask]

Logs are control profiles (varying speed, curvature and grade; a different seed each) written as
control CSV files, so each task reads its log like any route file. Timed, wall clock, from the
file paths to the ranked windows (reading the logs, chunk summaries, every window scored, the best
window of each log confirmed by the exact evaluator):

- the local engine (one process per core);
- a two-worker ``distributed.LocalCluster`` started by this script with excite's worker settings
  (:data:`excite.core.engine.WORKER_CONFIG`; ``--dask-default-env``: Dask's) (its start-up not timed; one
  untimed warm-up on a short log, so the workers have imported excite and loaded the compiled
  kernels).

Windows evaluated per second count every window scored. Re-evaluating every window from scratch
means ``evaluate(traj.cropped(a, b))`` per window: timed on ``--scratch-sample`` windows spread
over one log (in this process). Two speed-ups: on one log, the evaluation alone (its windows from
scratch against its chunk summaries and their combination); and the fleet (every log read once,
then its windows from scratch, divided by the core count as the engine's processes would share
it) against the local engine's wall time.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_evaluate import cpu_model  # noqa: E402
from results import Session, spread  # noqa: E402

from excite.fleet import batch as gate
from excite.fleet import mine
from excite.score.evaluate import evaluate  # noqa: E402
from excite.rig.config import load_rig  # noqa: E402
from excite.io.routes import read_route, write_control_csv  # noqa: E402
from excite.motion.vehicle import ControlProfile  # noqa: E402


def fleet_log(seed: int, hours: float) -> ControlProfile:
    """An hour of driving: speed, curvature and grade wandering with random phases and rates."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0 + 1.0, 2.0)
    w = rng.uniform(0.5, 1.5, 4)
    ph = rng.uniform(0, 2 * np.pi, 4)
    speed = 9 + 3 * np.sin(w[0] * t / 7 + ph[0])
    curvature = 0.04 * np.sin(w[1] * t / 5 + ph[1]) * (0.5 + 0.5 * np.sin(w[2] * t / 400 + ph[2])) \
        + 0.015 * np.sin(t / 1.9 + ph[3])
    return ControlProfile(t, speed, curvature, grade_rad=0.02 * np.sin(w[3] * t / 23), name=f"log{seed}")


def run(tasks, **engine) -> tuple[float, list[mine.LogResult]]:
    t0 = time.perf_counter()
    res = mine.mine_logs(tasks, **engine)
    return time.perf_counter() - t0, res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=10)
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--window", type=float, default=120.0)
    ap.add_argument("--chunk", type=float, default=mine.DEFAULT_CHUNK_S)
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--scratch-sample", type=int, default=12)
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument("--dask-default-env", action="store_true",
                    help="workers with Dask's default MALLOC_TRIM_THRESHOLD_ (not excite's WORKER_CONFIG)")
    args = ap.parse_args()
    session = Session()
    figures: dict = {}
    note = (f"excite's mining of {args.logs} synthetic logs × {args.hours:g} h (control CSV), {args.window:g} s windows on "
            f"{args.chunk:g} s chunks, robotaxi rig, from file paths to ranked windows; against every window "
            "evaluated from scratch (timed on a sample of one log's windows)")
    rig = load_rig("robotaxi")
    print(f"machine: {cpu_model()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start")
    with tempfile.TemporaryDirectory() as d:
        paths = [write_control_csv(fleet_log(i, args.hours), Path(d) / f"log{i:02d}_control.csv")
                 for i in range(args.logs)]
        specs = gate.collect([str(p) for p in paths])
        tasks = [mine.Task(s, args.window, None, 1, args.chunk) for s in specs]
        print(f"fleet: {args.logs} logs × {args.hours:g} h, windows of {args.window:g} s on {args.chunk:g} s chunks")

        local = []
        for _ in range(args.runs):
            wall, res = run(tasks)
            local.append(wall)
            assert all(r.error is None for r in res), [r.error for r in res if r.error]
        n_windows = sum(r.windows_evaluated for r in res)
        best = mine.ranked(res)[0][0]
        print(f"local engine ({os.cpu_count()} processes): wall {min(local):.1f}–{max(local):.1f} s over "
              f"{args.runs} runs; {n_windows} windows, {n_windows / statistics.median(local):.0f} windows/s; "
              f"best window {best.log} {best.start_s:.0f}–{best.end_s:.0f} s score {best.score:.3g} "
              f"(exact {best.confirmed_score:.3g})")

        figures["local_engine_wall_s"] = spread(local, 1)
        figures["windows"] = n_windows
        figures["local_windows_per_s"] = round(n_windows / statistics.median(local))

        # one log in this process, stage by stage
        t0_read = time.perf_counter()
        traj = read_route(paths[0], suspension=rig.suspension)
        t1 = time.perf_counter()
        summ = mine.summarise(traj, rig, args.chunk)
        t2 = time.perf_counter()
        L = int(round(args.window / args.chunk))
        sc, _ = mine.scores(rig, summ, L)
        t3 = time.perf_counter()
        print(f"one log in this process: read {t1 - t0_read:.1f} s, chunk summaries {t2 - t1:.1f} s, "
              f"{sc.size} windows combined and scored {t3 - t2:.2f} s ({sc.size / (t3 - t2):.0f} windows/s)")

        # from scratch: the exact evaluator on cropped windows of the same log
        evaluate(traj.cropped(0.0, args.window), rig)  # warm
        starts = np.linspace(0.0, traj.duration - args.window, args.scratch_sample)
        starts = np.floor(starts / args.chunk) * args.chunk
        t0 = time.perf_counter()
        for a in starts:
            evaluate(traj.cropped(float(a), float(a) + args.window), rig)
        per_window = (time.perf_counter() - t0) / len(starts)
        cores = os.cpu_count() or 1
        scratch_total = (args.logs * (t1 - t0_read) + per_window * n_windows) / cores
        mined = (t2 - t1) + (t3 - t2)
        print(f"from scratch: {per_window * 1e3:.0f} ms per {args.window:g} s window (mean of {len(starts)}); "
              f"one log's {sc.size} windows {per_window * sc.size:.1f} s against {mined:.1f} s of summaries + "
              f"combining: ×{per_window * sc.size / mined:.1f} on the evaluation alone; the fleet, reading each "
              f"log once either way, {scratch_total:.0f} s on {cores} cores against the local engine's "
              f"{statistics.median(local):.0f} s: ×{scratch_total / statistics.median(local):.1f}")

        figures["from_scratch_ms_per_window"] = round(per_window * 1e3)
        figures["one_log_speedup_evaluation_alone"] = round(per_window * sc.size / mined, 1)
        figures["fleet_speedup_vs_from_scratch"] = round(scratch_total / statistics.median(local), 1)
        if args.no_dask:
            session.record("mine", figures, note=note)
            return
        import dask
        from distributed import Client, LocalCluster

        from excite.core import engine

        config = {} if args.dask_default_env else engine.WORKER_CONFIG
        with dask.config.set(config):  # the workers' environment is set as they spawn
            cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=None, silence_logs=40)
        with cluster, Client(cluster):
            warm = write_control_csv(fleet_log(99, 0.05), Path(d) / "warm_control.csv")
            warm_task = mine.Task(gate.collect([str(warm)])[0], args.window, None, 1, args.chunk)
            run([warm_task] * 2, scheduler=cluster.scheduler_address)  # imports, compiled kernels
            remote = []
            for _ in range(args.runs):
                wall, res_d = run(tasks, scheduler=cluster.scheduler_address)
                remote.append(wall)
        same = [w.to_dict() for w in mine.ranked(res_d)[0]] == [w.to_dict() for w in mine.ranked(res)[0]]
        print(f"LocalCluster (2 workers × 1 thread): wall {min(remote):.1f}–{max(remote):.1f} s; "
              f"{n_windows / statistics.median(remote):.0f} windows/s; dask/local wall ratio "
              f"{statistics.median(remote) / statistics.median(local):.2f}; same windows as local: {same}")
        figures["dask_localcluster_2_workers_wall_s"] = spread(remote, 1)
        figures["dask_over_local_wall"] = round(statistics.median(remote) / statistics.median(local), 2)
        figures["dask_same_windows_as_local"] = same
        if args.dask_default_env:
            note += "; Dask workers with Dask's default environment"
        session.record("mine", figures, note=note)
    print(f"load average {os.getloadavg()[0]:.1f} at end")


if __name__ == "__main__":
    main()
