"""The odometry drift densities of ROS_example.bag's ORB-SLAM and S-PTAM estimates against its
ground truth (the rig guide's figures), and the CPU time of each estimate (``excite rig noise``'s
work: the clock search, the alignment, the likelihood fits), over several runs.

    python benchmarks/bench_rig_noise.py [--runs 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from results import Session  # noqa: E402

from excite.io.timed_poses import read_timed_poses  # noqa: E402
from excite.rig.noise import estimate_drift  # noqa: E402

BAG = Path(__file__).resolve().parents[2] / "shared" / "data" / "ROS_example.bag"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    session = Session()
    reference = read_timed_poses(BAG, "groundtruth")
    figures = {}
    for topic in ("ORB-SLAM", "S-PTAM"):
        odom = read_timed_poses(BAG, topic)
        cpu = []
        for _ in range(args.runs):
            t0 = time.process_time()
            est = estimate_drift(odom, reference)
            cpu.append(time.process_time() - t0)
        key = topic.lower().replace("-", "_")
        figures[f"{key}_cpu_s"] = {"median": statistics.median(cpu), "range": [min(cpu), max(cpu)], "runs": args.runs}
        figures[f"{key}_rotation_deg_per_sqrt_s"] = [est.rotation.value, est.rotation.sigma]
        figures[f"{key}_translation_m_per_sqrt_s"] = [est.translation.value, est.translation.sigma]
        figures[f"{key}_over_1s"] = [est.rotation.over_1s, est.translation.over_1s]
        figures[f"{key}_time_offset_s"] = est.time_offset_s
        figures[f"{key}_scale"] = est.scale
        print(topic, figures[f"{key}_rotation_deg_per_sqrt_s"], figures[f"{key}_translation_m_per_sqrt_s"],
              figures[f"{key}_cpu_s"])
    session.record("rig_noise", figures, note="density [value, 1σ]; CPU seconds of one estimate (process time)")


if __name__ == "__main__":
    main()
