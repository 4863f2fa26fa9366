"""What drifting IMU biases change: σ of every parameter on KITTI 00 with constant biases (the mean
over the drive) and with random-walk biases (the bias at the end of the drive), and the score of
each reference maneuver under both models (the optimizer's CasADi model keeps constant biases).

    python benchmarks/bench_bias_model.py
"""

from __future__ import annotations

import glob
from pathlib import Path

from excite.score.evaluate import evaluate
from excite.rig.config import load_rig
from excite.io.routes import read_route
from excite.core.units import human

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    rig = load_rig("robotaxi")
    const = rig.with_constant_biases()
    traj = read_route(DATA / "kitti_00_poses.txt", times=DATA / "kitti_00_times.txt", suspension=rig.suspension)
    drift, fixed = evaluate(traj, rig), evaluate(traj, const)
    print(f"KITTI 00: score {fixed.score:.4g} (constant) / {drift.score:.4g} (random walk), "
          f"rank {fixed.rank} / {drift.rank}")
    print("| parameter | σ constant biases | σ random-walk biases | ratio |\n|---|---|---|---|")
    for a, b in zip(fixed.parameters, drift.parameters):
        print(f"| {a.name} | {human(a.sigma, a.unit)} | {human(b.sigma, b.unit)} | {b.sigma / a.sigma:.2f} |")
    print("\nreference maneuvers: score constant / random walk, relative difference")
    for path in sorted(glob.glob(str(ROOT / "trajectories" / "*_control.csv"))):
        t = read_route(path, suspension=rig.suspension)
        a, b = evaluate(t, const).score, evaluate(t, rig).score
        print(f"  {Path(path).name:26s} {a:.6g} / {b:.6g}  {(b / a - 1) if a else float('nan'):+.1e}")


if __name__ == "__main__":
    main()
