"""Monte Carlo of a planned car drive (four CAN wheels, steering, a radar) in the physical
simulator, with what the NEES is made of.

The same trials as ``excite validate ROUTE --rig sedan --runs N --imu-rate 100`` (seed 0: trial i
draws from ``default_rng([seed, i])``), then: the NEES of the trials the solver converged on and of
those it stopped at its iteration cap, the largest whitened errors of each stopped trial, the
empirical σ over the converged trials, and the stopped trials solved again with a larger
iteration cap (``--rerun-iterations``) and the NEES with them.

    python benchmarks/bench_car_mc.py [--route examples/sedan_planned_60s_control.csv] [--rig sedan]
        [--runs 100] [--seed 0] [--imu-rate 100] [--rerun-iterations 200] [--json FILE]
        [--set bias_random_walk=false ...]

``--set KEY=VALUE`` changes one field of :class:`excite.validate.simulate.SimulationSettings` (the
physical simulator's), to see which of its effects moves the NEES.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))

from results import Session  # noqa: E402

from excite.cli.validate import with_imu_rate
from excite.io.routes import read_route
from excite.rig.config import load_rig
from excite.validate.calibrate import SolverSettings
from excite.validate.monte_carlo import MonteCarloSettings, monte_carlo, run_trial, statistics
from excite.validate.simulate import SimulationSettings

ROOT = Path(__file__).resolve().parents[1]


def interval(n: int, dof: int, confidence: float = 0.95) -> tuple[float, float]:
    a = 1 - confidence
    return chi2.ppf(a / 2, n * dof) / n, chi2.ppf(1 - a / 2, n * dof) / n


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--route", type=Path, default=ROOT / "examples" / "sedan_planned_60s_control.csv")
    ap.add_argument("--rig", default="sedan")
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--imu-rate", type=float, default=100.0)
    ap.add_argument("--rerun-iterations", type=int, default=200)
    ap.add_argument("--json", type=Path, default=None, help="write the per-trial figures here")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a SimulationSettings field (repeatable), e.g. bias_random_walk=false")
    args = ap.parse_args()
    session = Session()
    sim = SimulationSettings()
    for spec in args.set:
        key, sep, value = spec.partition("=")
        if not sep or not hasattr(sim, key):
            ap.error(f"--set needs KEY=VALUE with a SimulationSettings field, got {spec!r}")
        old = getattr(sim, key)
        new = value.lower() in ("1", "true", "yes") if isinstance(old, bool) else type(old)(value)
        sim = replace(sim, **{key: new})
    print(f"simulation: {sim}", flush=True)
    print(f"load at start {os.getloadavg()[0]:.2f} {time.strftime('%Y-%m-%d %H:%M:%S %Z')}", flush=True)
    rig = with_imu_rate(load_rig(args.rig), args.imu_rate)
    traj = read_route(args.route, suspension=rig.suspension)
    settings = MonteCarloSettings(runs=args.runs, seed=args.seed, simulation=sim)
    t0 = time.perf_counter()
    res = monte_carlo(traj, rig, settings)
    print(f"{len(res.trials)} trials in {time.perf_counter() - t0:.0f} s, load {os.getloadavg()[0]:.2f}", flush=True)
    dof = res.dof
    names = res.names
    sigma = np.array([p.predicted_sigma for p in res.parameters])
    scored = np.array([not c.nuisance for c in rig.coordinates])
    conv = np.array([t.status == "converged" for t in res.trials])
    lo, hi = res.nees_interval
    print(f"NEES all {res.nees_mean:.2f} [{lo:.2f}, {hi:.2f}] (dof {dof}, {len(res.trials)} trials)")
    figures = {"trials": len(res.trials), "converged": int(conv.sum()), "nees": round(res.nees_mean, 2),
               "nees_95_interval": [round(lo, 2), round(hi, 2)], "dof": dof}
    for label, mask in (("converged", conv), ("stopped at the cap", ~conv)):
        if mask.any():
            lo, hi = interval(int(mask.sum()), dof)
            print(f"NEES {label}: {res.nees[mask].mean():.2f} [{lo:.2f}, {hi:.2f}] over {mask.sum()} trials; "
                  f"median {np.median(res.nees[mask]):.2f}")
    E = np.array([t.error[scored] for t in res.trials])
    Z = E / sigma
    print("σ ratio (empirical/predicted), all trials / converged only:")
    for i, n in enumerate(names):
        print(f"  {n:26s} {np.sqrt(np.mean(Z[:, i] ** 2)):.3f} / {np.sqrt(np.mean(Z[conv, i] ** 2)):.3f}")
    stopped = [t for t in res.trials if t.status != "converged"]
    for t in stopped:
        z = Z[t.index]
        top = np.argsort(-np.abs(z))[:3]
        print(f"  stopped trial {t.index}: {t.iterations} iterations, NEES {res.nees[t.index]:.1f}, 2·cost/dof "
              f"{2 * t.cost / t.dof:.4f}; largest " + ", ".join(f"{names[k]} {z[k]:+.2f} σ" for k in top))
    out = {"nees": res.nees.tolist(), "converged": conv.tolist(), "interval": list(res.nees_interval),
           "stop": [f"{t.status}: {t.reason}" for t in res.trials], "iterations": [t.iterations for t in res.trials],
           "systematic": res.systematic}
    if stopped and args.rerun_iterations > 0:
        again = replace(settings, solver=SolverSettings(max_iterations=args.rerun_iterations))
        trials = list(res.trials)
        for t in stopped:
            t1 = run_trial(traj, rig, t.index, again)
            trials[t.index] = t1
            print(f"  trial {t.index} again, cap {args.rerun_iterations}: {t1.status} ({t1.reason}) after "
                  f"{t1.iterations} iterations, 2·cost/dof {2 * t1.cost / t1.dof:.4f}", flush=True)
        res2 = statistics(res.report, rig, trials, settings)
        lo, hi = res2.nees_interval
        print(f"NEES with the stopped trials solved again: {res2.nees_mean:.2f} [{lo:.2f}, {hi:.2f}]; "
              f"{sum(t.status == 'converged' for t in trials)} of {len(trials)} converged; "
              + ", ".join(f"{p.name} {p.ratio:.2f}" for p in res2.parameters if p.ratio and abs(p.ratio - 1) > 0.12))
        for t in stopped:
            print(f"  trial {t.index}: NEES {res.nees[t.index]:.1f} → {res2.nees[t.index]:.1f}")
        out["nees_again"] = res2.nees.tolist()
        figures["nees_stopped_trials_solved_again"] = round(res2.nees_mean, 2)
    ratio = {p.name: round(p.ratio, 2) for p in res.parameters if p.ratio and abs(p.ratio - 1) > 0.12}
    figures["sigma_ratios_off_by_over_12_percent"] = ratio
    session.record("car_mc", figures, note=f"{args.route.name} with the {args.rig} rig (IMU at {args.imu_rate:g} Hz) "
                   f"in the physical simulator{' (' + ', '.join(args.set) + ')' if args.set else ''}, seed {args.seed}; "
                   "the trials stopped at the solver's iteration cap solved again with a cap of "
                   f"{args.rerun_iterations}; σ ratio = empirical / predicted")
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1))
    print(f"done {time.strftime('%H:%M:%S')}, load {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
