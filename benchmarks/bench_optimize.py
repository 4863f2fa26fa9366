"""Benchmark: ``excite optimize`` with default settings (robotaxi, 90 s, 80 × 50 m, 60 s budget,
200 random candidates) for several seeds, as a user runs it: the command in a subprocess.

    python benchmarks/bench_optimize.py [--seeds 0 1 2] [--budget 60] [--out benchmarks/out]

Per seed: the command's wall time against the budget (+10 % allowed), IPOPT's status and
iterations, where the result came from, whether the written control CSV passes the limit and lot
check again (read back, driven, checked), its score against the best reference maneuver and
the best random candidate (full evaluator, from comparison.json), and how many of the random
candidates were scored within the budget. Saves a plot of seed 0's maneuver.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402

from excite.score.evaluate import evaluate  # noqa: E402
from excite.plan import OptimizeSettings  # noqa: E402
from excite.plan.candidates import check  # noqa: E402
from excite.rig.config import load_rig  # noqa: E402
from excite.io.routes import read_control_profile  # noqa: E402


def plot(traj, settings: OptimizeSettings, score: float, path: Path) -> None:
    s = traj.sample(traj.times(20.0))
    xy = s.p_W_V[:, :2]
    seg = np.stack([xy[:-1], xy[1:]], axis=1)
    fig, ax = plt.subplots(figsize=(9, 6))
    lc = LineCollection(seg, cmap="viridis", linewidths=2)
    lc.set_array(0.5 * (s.speed[:-1] + s.speed[1:]))
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="speed [m/s]")
    poly = settings.lot.lot.polygon_m
    ax.plot(*np.vstack([poly, poly[:1]]).T, "k-", lw=1.5, label="lot")
    ax.plot(*xy[0], "go", label="start")
    ax.plot(*xy[-1], "rs", label="end")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"optimized {settings.duration_s:g} s maneuver, score λ_min = {score:.3g}")
    ax.legend(loc="upper right")
    ax.autoscale_view()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--budget", type=float, default=60.0)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "out")
    args = ap.parse_args()
    rig = load_rig("robotaxi")
    settings = OptimizeSettings(time_budget_s=args.budget)
    lines = []
    for seed in args.seeds:
        out = args.out / f"seed{seed}"
        cmd = [sys.executable, "-c", "import sys; from excite.cli.app import main; sys.exit(main())",
               "optimize", "-o", str(out), "--seed", str(seed), "--time-budget", f"{args.budget:g}"]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            print(proc.stdout[-3000:], proc.stderr[-3000:])
            raise SystemExit(f"seed {seed}: excite optimize failed ({proc.returncode})")
        opt = json.loads((out / "report.json").read_text())["optimization"]
        rows = json.loads((out / "comparison.json").read_text())
        prof = read_control_profile(out / "control.csv")
        traj, bad = check(prof, rig, settings, settings.lot)
        score = evaluate(traj, rig).score
        best = {k: max((r["score"] or 0.0 for r in rows if r["kind"] == k and r["feasible"]), default=0.0)
                for k in ("reference", "random")}
        rand = next((r for r in rows if r["kind"] == "random"), {})
        ratio = {k: (score / v if v else float("inf")) for k, v in best.items()}
        line = (f"seed {seed}: wall {wall:.1f} s (budget {args.budget:g} s, ≤ +10 %: {wall <= 1.1 * args.budget}); "
                f"status {opt['status']} (IPOPT {opt['ipopt_status']}, {opt['iterations']} iterations); "
                f"result from {opt['source']}; written drive passes the check again: {not bad}; "
                f"score {score:.4g} = {ratio['reference']:.2f}× best reference, {ratio['random']:.2f}× best of "
                f"{rand.get('scored', 0)}/{settings.n_random} random; phases {opt['timings_s']}")
        print(line, flush=True)
        lines.append(line)
        if seed == args.seeds[0]:
            args.out.mkdir(parents=True, exist_ok=True)
            plot(traj, settings, score, args.out / "optimized_maneuver.png")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
