"""Do the plans the optimizer sells calibrate better? Monte Carlo in the physical simulator.

Every plan is driven ``--runs`` times in the physical simulator (IMU integrated at 8× its rate,
random-walk biases, wheel slip, tyre slip angle: :class:`excite.validate.SimulationSettings`) and
calibrated (:func:`excite.validate.calibrate`, from :func:`excite.validate.initialise`). Per plan:
the score, the worst empirical σ/target (which parameter) against the worst predicted σ/target,
the convergence rate, the NEES with its 95 % interval, the model check and the systematic error
of the physics alone.

Plans: the optimizer's, one per ``--criterion`` (``E`` = maximise λ_min, what ``excite optimize``
does; ``D``/``A`` when the optimizer offers them, as ``OptimizeSettings.criterion``), or given as
route files with ``--plan NAME=FILE`` (e.g. ``--plan D-optimal=out/d/control.csv``; with
``--no-optimize`` the optimizer is not run); plus the best reference maneuver and the best of
``--n-random`` random candidates of the same duration, by the full evaluator's score.

    python benchmarks/bench_plan_mc.py [--duration 20] [--runs 50] [--imu-rate 100] [--n-random 50]
        [--criterion E ...] [--plan NAME=FILE ...] [--no-optimize] [--time-budget 60] [--out DIR]

Writes ``plans/*.csv``, ``results.json`` and ``table.md`` to ``--out``
(default ``benchmarks/out/plan_mc/``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


from excite.cli.validate import with_imu_rate
from excite.score.evaluate import evaluate
from excite.plan import OptimizeSettings, optimize
from excite.plan import candidates as cand
from excite.rig.config import load_rig
from excite.io.routes import read_route, write_control_csv
from excite.validate import MonteCarloSettings, monte_carlo
from excite.motion.vehicle import drive

OUT = Path(__file__).parent / "out" / "plan_mc"


def optimizer_plans(rig, duration_s: float, criteria: list[str], budget_s: float, out: Path) -> dict[str, Path]:
    """The optimizer's plan per criterion, as control CSV files."""
    plans: dict[str, Path] = {}
    for c in criteria:
        settings = OptimizeSettings(duration_s=duration_s, time_budget_s=budget_s, criterion=c)
        t0 = time.perf_counter()
        res = optimize(rig, settings)
        print(f"{c}-optimal: {res.status}, {res.iterations} iterations, score {res.report.score:.4g} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
        plans[f"{c}-optimal"] = write_control_csv(res.profile, out / f"{c}_optimal_control.csv")
    return plans


def baseline_plans(rig, duration_s: float, n_random: int, seed: int, out: Path) -> dict[str, Path]:
    """The best reference maneuver and the best of ``n_random`` random candidates of this duration
    on the optimizer's default lot and limits, by the full evaluator's score."""
    settings = OptimizeSettings(duration_s=duration_s, seed=seed, n_random=n_random)
    site = settings.lot

    def best(profiles):
        feasible = [p for p in profiles if not cand.check(p, rig, settings, site)[1]]
        return max(feasible, key=lambda p: evaluate(drive(p, rig.suspension), rig).score)

    ref = best([c.profile for c in cand.reference_profiles(rig, settings, site)])
    rand = best(cand.random_profiles(rig, settings, site, 0, n_random, 0))
    return {f"best reference ({ref.name})": write_control_csv(ref, out / "best_reference_control.csv"),
            f"best of {n_random} random ({rand.name})": write_control_csv(rand, out / "best_random_control.csv")}


def row(name: str, res) -> dict:
    rep = res.report
    worst_pred = max(((p.name, p.predicted_sigma / p.target) for p in res.parameters if p.predicted_sigma),
                     key=lambda x: x[1])
    worst = res.worst_ratio()
    mc, (lo, hi) = res.model_check()
    sys_max = None if res.systematic is None else max(res.systematic.items(), key=lambda kv: abs(kv[1]))
    return {"plan": name, "score": rep.score, "runs": len(res.trials), "converged": res.convergence_rate,
            "stop_reasons": res.stop_reasons,
            "worst_empirical": {"name": worst[0], "sigma_over_target": worst[1]},
            "worst_predicted": {"name": worst_pred[0], "sigma_over_target": worst_pred[1]},
            "nees": res.nees_mean, "nees_interval": list(res.nees_interval), "dof": res.dof,
            "model_check": mc, "model_check_interval": [lo, hi],
            "systematic_max": None if sys_max is None else {"name": sys_max[0], "sigma": sys_max[1]},
            "parameters": res.to_dict()["parameters"], "seconds": res.seconds}


def table(rows: list[dict]) -> str:
    out = ["| plan | score | converged | worst empirical σ/target | worst predicted σ/target | NEES [95 % interval] "
           "| model check 2·cost/dof [interval] | largest systematic error |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lo, hi = r["nees_interval"]
        mlo, mhi = r["model_check_interval"]
        s = r["systematic_max"]
        out.append(f"| {r['plan']} | {r['score']:.3g} | {r['converged'] * 100:.0f} % of {r['runs']} | "
                   f"{r['worst_empirical']['sigma_over_target']:.1f} ({r['worst_empirical']['name']}) | "
                   f"{r['worst_predicted']['sigma_over_target']:.1f} ({r['worst_predicted']['name']}) | "
                   f"{r['nees']:.1f} [{lo:.1f}, {hi:.1f}] (dof {r['dof']}) | {r['model_check']:.3f} "
                   f"[{mlo:.3f}, {mhi:.3f}] | "
                   + ("—" if s is None else f"{s['sigma']:+.1f} σ ({s['name']})") + " |")
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--imu-rate", type=float, default=100.0)
    ap.add_argument("--criterion", action="append", default=None, help="optimizer criterion (repeatable)")
    ap.add_argument("--plan", action="append", default=[], help="NAME=FILE, a route file (repeatable)")
    ap.add_argument("--no-optimize", action="store_true", help="no optimizer run: the --plan files")
    ap.add_argument("--time-budget", type=float, default=60.0)
    ap.add_argument("--n-random", type=int, default=50)
    ap.add_argument("--no-baselines", action="store_true", help="only the optimizer's plans and the --plan files")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    out = args.out
    (out / "plans").mkdir(parents=True, exist_ok=True)
    rig = with_imu_rate(load_rig("robotaxi"), args.imu_rate)
    plans: dict[str, Path] = {}
    for spec in args.plan:
        name, sep, path = spec.partition("=")
        if not sep or not Path(path).is_file():
            print(f"--plan needs NAME=FILE with an existing file, got {spec!r}", file=sys.stderr)
            return 2
        plans[name] = Path(path)
    if not args.no_optimize:
        plans.update(optimizer_plans(rig, args.duration, args.criterion or ["E"], args.time_budget, out / "plans"))
    if not args.no_baselines:
        plans.update(baseline_plans(rig, args.duration, args.n_random, args.seed, out / "plans"))
    rows = []
    for name, path in plans.items():
        traj = read_route(path, suspension=rig.suspension)
        t0 = time.perf_counter()
        res = monte_carlo(traj, rig, MonteCarloSettings(runs=args.runs, seed=args.seed))
        rows.append(row(name, res))
        print(f"{name}: {len(res.trials)} trials in {time.perf_counter() - t0:.0f} s", flush=True)
        (out / "results.json").write_text(json.dumps(rows, indent=2))
    text = table(rows)
    (out / "table.md").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
