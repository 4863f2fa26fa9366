"""What helps IPOPT on the default problem (robotaxi, 90 s, 80 × 50 m, seed 0)?

    python benchmarks/bench_ipopt.py [--iterations 30]

Each variant runs a fixed number of IPOPT iterations (so that the machine's load changes the
wall time, not the outcome); printed: the model's λ_min (2 Hz model) of the best iterate within
the limits, at iterations 5, 10, 20 and the last, IPOPT's status and the wall time. Variants:
the shipped options from the start the pipeline chooses (the best by the model among the
references and the first 10 random candidates that violate the optimizer's constraints by less
than 1); IPOPT's default adaptive barrier (μ0 = 0.1) from the same start; the shipped options
from the best start that satisfies every constraint.
"""

from __future__ import annotations

import argparse
import time

from excite.plan import OptimizeSettings, candidates as cand, pipeline, solver
from excite.plan.kinematics import z_from_profile
from excite.rig.config import load_rig


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--iterations", type=int, default=30)
    args = ap.parse_args()
    rig = load_rig("robotaxi")
    s = OptimizeSettings()
    site = s.lot
    tr = solver.transcribe(rig, s, site)
    starts = [c.profile for c in cand.reference_profiles(rig, s, site) if c.name != "highway_run"]
    starts += cand.random_profiles(rig, s, site, 0, 5, 0) + cand.random_profiles(rig, s, site, 1, 5, 5)
    zs = [z_from_profile(tr.grid, tr.scales, p) for p in starts]
    rows = [(solver.violation(tr, z), solver.model_value(tr, z), z, p.name) for z, p in zip(zs, starts)]
    feasible = max((r for r in rows if r[0] <= solver.FEASIBLE_TOL), key=lambda r: r[1])
    near = max((r for r in rows if r[0] < pipeline.NEAR_FEASIBLE), key=lambda r: r[1])
    base = dict(solver.IPOPT_OPTIONS)
    n = args.iterations

    def run(name, start, options):
        solver.IPOPT_OPTIONS.clear()
        solver.IPOPT_OPTIONS.update(base, **options)
        t0 = time.perf_counter()
        out = solver.solve(tr, start[2], time.perf_counter() + 3600, max_iterations=n)
        at = {k: max((h[1] for h in out.history if h[0] <= k), default=float("nan")) for k in (5, 10, 20)}
        print(f"{name:<44} start {start[3]} (λ_min {start[1]:.3g}, violation {start[0]:.2g}); "
              f"the run's λ_min at 5/10/20 iterations {at[5]:.3g}/{at[10]:.3g}/{at[20]:.3g}; best within the "
              f"limits {out.score:.4g}  {out.ipopt_status}  {out.iterations} it  {time.perf_counter() - t0:.1f} s",
              flush=True)

    run("shipped (monotone barrier, μ0 1e-3)", near, {})
    run("IPOPT's default adaptive barrier", near, {"ipopt.mu_strategy": "adaptive", "ipopt.mu_init": 0.1})
    run("shipped, from the best feasible start", feasible, {})
    solver.IPOPT_OPTIONS.clear()
    solver.IPOPT_OPTIONS.update(base)


if __name__ == "__main__":
    main()
