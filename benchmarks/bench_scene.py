"""The scene's cost and accuracy: the 10-minute reference drive scored scene-aware in a street
canyon beside its scene-blind score, and the quadrature against one eight times finer.

    python benchmarks/bench_scene.py [--runs 5]

Figures (benchmarks/results/scene.json):

- ``ten_minute_canyon_ms``: the generated 10-minute drive of ``bench_evaluate`` (4.8 km),
  ray-cast along (``excite.scene.along.seen``) and scored, warm, in a street canyon built around
  it (buildings 10–25 m tall on a 20 m grid wherever the drive does not pass within 9 m), beside
  ``ten_minute_blind_ms``, the same drive scene-blind, alternating run by run (wall time, and the
  process's CPU time, which the machine's load does not inflate); the process's peak resident
  memory after both;
- ``quadrature_*``: the largest relative difference of a lidar σ between the default quadrature
  and one with 8× the azimuths and all 32 beams, on the 90 s slalom, in a lot with buildings and
  in a lot with one wall and one pole (the hardest case: a thin object between two rays);
- ``slalom_lidar_sigma_over_target``: the 90 s slalom's lidar σ/target blind, in the open lot,
  with buildings on one side and in a street canyon.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_evaluate import generated  # noqa: E402
from results import Session, load_average, spread  # noqa: E402
from scenes import canyon_around, lot_with_buildings, slalom_drive  # noqa: E402
from scenes import lot as lot_ground  # noqa: E402

from excite.rig.config import load_rig  # noqa: E402
from excite.scene import along, lidar, shapes  # noqa: E402
from excite.scene.model import Scene  # noqa: E402
from excite.score.evaluate import evaluate  # noqa: E402


def lidar_sigmas(rep) -> np.ndarray:
    return np.array([p.sigma for p in rep.parameters if p.name.startswith("lidar.")])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    session = Session()
    rig = load_rig("robotaxi")
    figures: dict = {}

    traj = generated(600.0, rig)
    canyon = canyon_around(traj)
    print(f"10-minute drive, {traj.length_m():.0f} m; canyon of {canyon.n_triangles} triangles; "
          f"load {load_average()}")
    evaluate(along.seen(traj, rig, canyon), rig)  # warm: kernels, caches
    evaluate(traj, rig)
    aware, blind, aware_cpu, blind_cpu = [], [], [], []
    for _ in range(args.runs):
        t0, c0 = time.perf_counter(), time.process_time()
        evaluate(along.seen(traj, rig, canyon), rig)
        aware.append((time.perf_counter() - t0) * 1e3)
        aware_cpu.append((time.process_time() - c0) * 1e3)
        t0, c0 = time.perf_counter(), time.process_time()
        evaluate(traj, rig)
        blind.append((time.perf_counter() - t0) * 1e3)
        blind_cpu.append((time.process_time() - c0) * 1e3)
    figures["ten_minute_canyon_ms"] = spread(aware, 1)
    figures["ten_minute_blind_ms"] = spread(blind, 1)
    figures["ten_minute_canyon_cpu_ms"] = spread(aware_cpu, 1)  # both threads' CPU time: what load does not inflate
    figures["ten_minute_blind_cpu_ms"] = spread(blind_cpu, 1)
    figures["peak_rss_mib"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    print(f"scene-aware {figures['ten_minute_canyon_ms']} ms, blind {figures['ten_minute_blind_ms']} ms, "
          f"peak RSS {figures['peak_rss_mib']} MiB")

    sl = slalom_drive(rig)
    lot = lot_ground()
    scenes = {
        "buildings": lot_with_buildings(lot),
        "wall_and_pole": Scene.combine([lot, shapes.wall((-50, 38), (50, 38), 4.0), shapes.cylinder((10, -20), 0.3, 5.0)]),
    }
    default = (lidar.CAST_BEAMS, lidar.AZIMUTHS)
    for name, sc in scenes.items():
        base = lidar_sigmas(evaluate(along.seen(sl, rig, sc), rig))
        lidar.CAST_BEAMS, lidar.AZIMUTHS = 32, 8 * default[1]
        try:
            fine = lidar_sigmas(evaluate(along.seen(sl, rig, sc), rig))
        finally:
            lidar.CAST_BEAMS, lidar.AZIMUTHS = default
        figures[f"quadrature_{name}_max_relative"] = float(f"{np.abs(base / fine - 1).max():.3g}")
        print(f"quadrature, {name}: default against 8x azimuths and 32 beams: "
              f"{figures[f'quadrature_{name}_max_relative']:.3g}")

    table = {}
    canyon_street = Scene.combine([lot, shapes.box(-60, 30, 60, 45, 15), shapes.box(-60, -45, 60, -30, 15)])
    for name, sc in (("blind", None), ("open lot", lot), ("buildings on one side",
                                                            lot_with_buildings(lot, 2)), ("street canyon", canyon_street)):
        rep = evaluate(sl if sc is None else along.seen(sl, rig, sc), rig)
        table[name] = {p.name: round(p.sigma / p.target, 3) for p in rep.parameters if p.name.startswith("lidar.")}
        print(name, table[name])
    figures["slalom_lidar_sigma_over_target"] = table
    session.record("scene", figures, note="robotaxi rig (vlp32c lidar); scene-aware = ray-cast along the drive and "
                                         "scored, warm; ranges over the runs")


if __name__ == "__main__":
    main()
