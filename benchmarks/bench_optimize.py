"""Benchmark: optimize the default rig's 90 s maneuver in an 80 × 50 m lot.

    python benchmarks/bench_optimize.py [--budget 60] [--n-random 200] [--out benchmarks/out]

Prints the score, IPOPT iterations, wall times and the comparison table (every reference
maneuver, the best of N random candidates, COBYLA, the start), and saves a plot of the maneuver
(path coloured by speed, lot outline) as ``optimized_maneuver.png``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402

from excite.optimize import OptimizeSettings, optimize  # noqa: E402
from excite.optimize.pipeline import feasibility, lot_of  # noqa: E402
from excite.rig import load_rig  # noqa: E402


def plot(result, settings: OptimizeSettings, path: Path) -> None:
    s = result.trajectory.sample(result.trajectory.times(20.0))
    xy = s.p_W_V[:, :2]
    seg = np.stack([xy[:-1], xy[1:]], axis=1)
    fig, ax = plt.subplots(figsize=(9, 6))
    lc = LineCollection(seg, cmap="viridis", linewidths=2)
    lc.set_array(0.5 * (s.speed[:-1] + s.speed[1:]))
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="speed [m/s]")
    poly = lot_of(settings).polygon_m
    ax.plot(*np.vstack([poly, poly[:1]]).T, "k-", lw=1.5, label="lot")
    ax.plot(*xy[0], "go", label="start")
    ax.plot(*xy[-1], "rs", label="end")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"optimized {settings.duration_s:g} s maneuver, score λ_min = {result.report.score:.3g}")
    ax.legend(loc="upper right")
    ax.autoscale_view()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--budget", type=float, default=60.0)
    ap.add_argument("--n-random", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "out")
    args = ap.parse_args()
    settings = OptimizeSettings(duration_s=90.0, lot_x_m=80.0, lot_y_m=50.0,
                                time_budget_s=args.budget, n_random=args.n_random, seed=args.seed)
    rig = load_rig("robotaxi")
    t0 = time.perf_counter()
    result = optimize(rig, settings)
    wall = time.perf_counter() - t0
    opt_wall = result.timings_s["start"] + result.timings_s["optimize"] + result.timings_s["result"]
    print(f"status {result.status}; IPOPT iterations {result.iterations}")
    print(f"optimization wall time {opt_wall:.1f} s (budget {args.budget:g} s); "
          f"with the comparison {wall:.1f} s; phases {result.timings_s}")
    print(f"score (full evaluator) {result.report.score:.4g}; coarse model {result.model_score:.4g}")
    print(f"independent feasibility check: {feasibility(result.trajectory, settings) or 'all limits and the lot hold'}")
    print(f"{'candidate':<22} {'kind':<10} {'score':>10} {'optimized ÷':>12}  feasible")
    for r in result.comparison:
        ratio = "—" if r["ratio"] is None else f"{r['ratio']:.2f}×"
        print(f"{r['name']:<22} {r['kind']:<10} {r['score']:>10.4g} {ratio:>12}  {r['feasible']}")
    args.out.mkdir(parents=True, exist_ok=True)
    png = args.out / "optimized_maneuver.png"
    plot(result, settings, png)
    print(f"plot: {png}")
    print(f"under 60 s: {opt_wall < 60.0}")


if __name__ == "__main__":
    main()
