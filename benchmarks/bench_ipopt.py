"""What helps IPOPT on the default problem (robotaxi, 90 s, 80 × 50 m, seed 0's start)?

    python benchmarks/bench_ipopt.py [--iterations 30]

Each variant starts from the same start the pipeline chooses and runs a fixed number of IPOPT
iterations (so that the machine's load changes the wall time, not the outcome); printed: the
model's λ_min (2 Hz model) of the best feasible iterate, IPOPT's status, iterations, wall time.
Variants: the shipped options; no NLP scaling; a short L-BFGS memory (6); a coarser model first
(1 Hz keyframes for the first half of the iterations, then the 2 Hz model from there).
"""

from __future__ import annotations

import argparse
import time

from excite.optimize import OptimizeSettings, candidates as cand, solver
from excite.optimize.kinematics import z_from_profile
from excite.rig import load_rig


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--iterations", type=int, default=30)
    args = ap.parse_args()
    rig = load_rig("robotaxi")
    s = OptimizeSettings()
    site = s.lot
    tr = solver.transcribe(rig, s, site)
    starts = [c.profile for c in cand.reference_profiles(rig, s, site) if c.name != "highway_run"]
    starts += cand.random_profiles(rig, s, site, 0, 5, 0)
    ranked = sorted(((solver.violation(tr, z) < 1.0, solver.model_value(tr, z), z)
                     for z in (z_from_profile(tr.grid, tr.scales, p) for p in starts)),
                    key=lambda r: (r[0], r[1]), reverse=True)
    z0 = ranked[0][2]
    print(f"start: model λ_min {solver.model_value(tr, z0):.4g}, violation {solver.violation(tr, z0):.3g}")
    base = dict(solver.IPOPT_OPTIONS)
    n = args.iterations

    def run(name, options, coarse_first=False):
        solver.IPOPT_OPTIONS.clear()
        solver.IPOPT_OPTIONS.update(base, **options)
        t0 = time.perf_counter()
        z, its = z0, 0
        if coarse_first:
            trc = solver.transcribe(rig, s, site, keyframe_rate_hz=1.0)
            oc = solver.solve(trc, z, time.perf_counter() + 3600, max_iterations=n // 2)
            its += oc.iterations
            if oc.z is not None:
                z = oc.z
        out = solver.solve(tr, z, time.perf_counter() + 3600, max_iterations=n - its if coarse_first else n)
        best = max((solver.model_value(tr, zz) for _, zz in out.feasible[:5]), default=float("nan"))
        print(f"{name:<32} λ_min {best:.4g}  {out.ipopt_status:<28} {its + out.iterations:>4} it  "
              f"{time.perf_counter() - t0:6.1f} s", flush=True)

    run("shipped", {})
    run("no NLP scaling", {"ipopt.nlp_scaling_method": "none"})
    run("L-BFGS memory 6", {"ipopt.limited_memory_max_history": 6})
    run("coarser model (1 Hz) first", {}, coarse_first=True)
    solver.IPOPT_OPTIONS.clear()
    solver.IPOPT_OPTIONS.update(base)


if __name__ == "__main__":
    main()
