"""What drifting IMU biases change: σ of every parameter on KITTI 00 with constant biases (the mean
over the drive) and with random-walk biases (the bias at the end of the drive), and the score of
each reference maneuver under both models (the optimizer's CasADi model keeps constant biases).

    python benchmarks/bench_bias_model.py
"""

from __future__ import annotations

import glob
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from results import Session  # noqa: E402

from excite.core.units import human  # noqa: E402
from excite.io.routes import read_route  # noqa: E402
from excite.rig.config import load_rig  # noqa: E402
from excite.score.evaluate import evaluate  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    session = Session()
    rig = load_rig("robotaxi")
    const = rig.with_constant_biases()
    traj = read_route(DATA / "kitti_00_poses.txt", times=DATA / "kitti_00_times.txt", suspension=rig.suspension)
    drift, fixed = evaluate(traj, rig), evaluate(traj, const)
    print(f"KITTI 00: score {fixed.score:.4g} (constant) / {drift.score:.4g} (random walk), "
          f"rank {fixed.rank} / {drift.rank}")
    print("| parameter | σ constant biases | σ random-walk biases | ratio |\n|---|---|---|---|")
    ratios = {}
    for a, b in zip(fixed.parameters, drift.parameters):
        ratios[a.name] = b.sigma / a.sigma
        print(f"| {a.name} | {human(a.sigma, a.unit)} | {human(b.sigma, b.unit)} | {b.sigma / a.sigma:.2f} |")
    print("\nreference maneuvers: score constant / random walk, relative difference")
    maneuvers = {}
    for path in sorted(glob.glob(str(ROOT / "trajectories" / "*_control.csv"))):
        t = read_route(path, suspension=rig.suspension)
        a, b = evaluate(t, const).score, evaluate(t, rig).score
        maneuvers[Path(path).name.removesuffix("_control.csv")] = (b / a - 1) if a else None
        print(f"  {Path(path).name:26s} {a:.6g} / {b:.6g}  {(b / a - 1) if a else float('nan'):+.1e}")
    largest = sorted(ratios.items(), key=lambda kv: -abs(kv[1] - 1))[:4]
    session.record("bias_model", {
        "kitti_00_score_constant_biases": fixed.score, "kitti_00_score_random_walk_biases": drift.score,
        "kitti_00_sigma_ratio_largest": {k: round(v, 3) for k, v in largest},
        "maneuver_score_relative_difference": {k: (None if v is None else float(f"{v:.2e}"))
                                               for k, v in maneuvers.items()},
    }, note="KITTI 00 with the robotaxi rig: σ with random-walk biases / σ with constant biases for the four "
            "parameters it moves most; each reference maneuver's score with random-walk against constant biases "
            "(relative difference)")


if __name__ == "__main__":
    main()
