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

Per plan also the *systematic NEES*: the NEES contribution ``eᵀ Λ_θ e`` of the error ``e`` that
the physics alone causes (noise-free data, calibrated from the truth) — the mean NEES is the dof
plus about this, so it names what pushes a plan's NEES out of its interval without the noise of the
trials. ``--decompose``: the same with each physical effect of the simulator alone (IMU
discretisation, bias random walk, longitudinal slip, the loaded tyres' rolling radius, the slip
angle), seconds per plan.

Writes ``plans/*.csv``, ``results.json`` and ``table.md`` to ``--out``
(default ``benchmarks/out/plan_mc/``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from results import Session  # noqa: E402

from excite.cli.validate import with_imu_rate
from excite.score.evaluate import evaluate
from excite.plan import OptimizeSettings, optimize
from excite.plan import candidates as cand
from excite.rig.config import load_rig
from excite.io.routes import read_route, write_control_csv
from excite.validate import MonteCarloSettings, monte_carlo
from excite.validate.calibrate import States, calibrate
from excite.validate.simulate import Calibration, SimulationSettings, simulate
from excite.motion.vehicle import drive

EFFECTS = {  # each physical effect of the simulator alone (the rest as the model assumes)
    "IMU discretisation": dict(imu_oversampling=8),
    "bias random walk": dict(bias_random_walk=True),
    "longitudinal slip": dict(wheel_slip_per_g=0.01),
    "loaded rolling radius": dict(wheel_scrub_per_g2=0.01),
    "slip angle": dict(slip_angle_deg_per_mps2=0.15),
}

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


def systematic_nees(traj, rig, sim: SimulationSettings, seed: int = 0) -> tuple[float, list[tuple[str, float]]]:
    """The NEES contribution ``eᵀ Λ_θ e`` of the error the physics of ``sim`` alone causes
    (noise-free data of the nominal calibration, calibrated from the truth), and the largest
    errors in predicted σ."""
    from dataclasses import replace

    report = evaluate(traj, rig.with_constant_biases())
    truth = Calibration.nominal(rig)
    data = simulate(traj, rig, truth, __import__("numpy").random.default_rng([seed, 0, 1]), replace(sim, noise=False))
    tr = data.truth
    res = calibrate(data, rig, truth, States(tr.R, tr.p, tr.v), MonteCarloSettings().solver)
    truth = truth.with_values("imu", gyro_bias=tr.gyro_bias.mean(axis=0), accel_bias=tr.accel_bias.mean(axis=0))
    e = res.calibration.minus(truth, rig)[[not c.nuisance for c in rig.coordinates]]
    sig = sorted(((p.name, float(x / p.sigma)) for p, x in zip(report.parameters, e) if p.sigma),
                 key=lambda kv: -abs(kv[1]))
    return float(e @ report.information @ e), sig[:3]


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
           "| systematic NEES | model check 2·cost/dof [interval] | largest systematic error |",
           "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lo, hi = r["nees_interval"]
        mlo, mhi = r["model_check_interval"]
        s = r["systematic_max"]
        out.append(f"| {r['plan']} | {r['score']:.3g} | {r['converged'] * 100:.0f} % of {r['runs']} | "
                   f"{r['worst_empirical']['sigma_over_target']:.1f} ({r['worst_empirical']['name']}) | "
                   f"{r['worst_predicted']['sigma_over_target']:.1f} ({r['worst_predicted']['name']}) | "
                   f"{r['nees']:.1f} [{lo:.1f}, {hi:.1f}] (dof {r['dof']}) | {r.get('systematic_nees', float('nan')):.2f} | "
                   f"{r['model_check']:.3f} "
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
    ap.add_argument("--decompose", action="store_true", help="the systematic NEES of each physical effect alone")
    ap.add_argument("--systematic-only", action="store_true", help="no trials: the systematic NEES only (seconds)")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    session = Session()
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
        nees_sys, top = systematic_nees(traj, rig, SimulationSettings(), args.seed)
        print(f"{name}: systematic NEES {nees_sys:.2f} (largest: "
              + ", ".join(f"{k} {v:+.2f} σ" for k, v in top) + ")", flush=True)
        if args.decompose:
            for effect, change in EFFECTS.items():
                n, t = systematic_nees(traj, rig, SimulationSettings.model(**change), args.seed)
                print(f"  {effect:<22} alone: systematic NEES {n:.2f} (largest: "
                      + ", ".join(f"{k} {v:+.2f} σ" for k, v in t) + ")", flush=True)
        if args.systematic_only:
            continue
        res = monte_carlo(traj, rig, MonteCarloSettings(runs=args.runs, seed=args.seed))
        rows.append({**row(name, res), "systematic_nees": nees_sys})
        print(f"{name}: {len(res.trials)} trials in {time.perf_counter() - t0:.0f} s", flush=True)
        (out / "results.json").write_text(json.dumps(rows, indent=2))
    if args.systematic_only:
        return 0
    text = table(rows)
    (out / "table.md").write_text(text + "\n")
    print(text)
    session.record("plan_mc", {r["plan"]: {
        "score": float(f"{r['score']:.4g}"), "converged": r["converged"],
        "nees": round(r["nees"], 2), "nees_95_interval": [round(x, 2) for x in r["nees_interval"]], "dof": r["dof"],
        "systematic_nees": round(r["systematic_nees"], 2),
        "worst_empirical_sigma_over_target": {r["worst_empirical"]["name"]:
                                              round(r["worst_empirical"]["sigma_over_target"], 2)},
        "worst_predicted_sigma_over_target": {r["worst_predicted"]["name"]:
                                              round(r["worst_predicted"]["sigma_over_target"], 2)},
    } for r in rows}, note=f"robotaxi rig (IMU at {args.imu_rate:g} Hz), {args.duration:g} s plans, each driven "
                           f"{args.runs} times in the physical simulator (seed {args.seed}) and calibrated")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
