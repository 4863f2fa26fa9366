"""The drivable plan as people drive it, in the physical simulator: every trial its own driver.

    python benchmarks/bench_drivable_mc.py [--plan plan.json] [--runs 50] [--imu-rate 100] [--jobs 2]

Trial ``i``: the plan driven by the driver model's ``i``-th driver (:mod:`excite.motion.driver`,
drivers ``[1000, i]``), its sensors simulated by the physical simulator (IMU integrated at 8× its
rate, random-walk biases, wheel slip, tyre slip angle), a true calibration drawn 2 targets from
the nominal one, and calibrated (:func:`excite.validate.monte_carlo.monte_carlo_driven`'s trial).
The prediction is made from each trial's own drive (:func:`excite.validate.monte_carlo.statistics_driven`):
the NEES against its interval, and the worst empirical σ/target against the worst predicted σ/target
(RMS of the per-drive σ); the prediction from the nominal drive beside it.

``--plan``: a plan.json (default: the plan in ``benchmarks/results/drivable.json``). Writes
``benchmarks/results/drivable_mc.json``.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import multiprocessing
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from results import RESULTS, Session  # noqa: E402

DRIVERS = 1000


def _setup(plan_doc: dict, imu_rate: float):
    from excite.cli.validate import with_imu_rate
    from excite.motion.vehicle import Limits
    from excite.plan.drivable.plan import build, plan_from_dict
    from excite.rig.config import load_rig

    rig = with_imu_rate(load_rig("robotaxi"), imu_rate)
    return rig, build(plan_from_dict(plan_doc), Limits())


def _drive(built, rig, i: int):
    from excite.motion.driver import DriverModel, drive_course
    from excite.motion.vehicle import Limits, drive

    dc = drive_course(built.course, Limits(), DriverModel(), np.random.default_rng([DRIVERS, i]),
                      duration_s=built.plan.duration_s)
    return drive(dc.profile, rig.suspension)


def _chunk(args):
    plan_doc, imu_rate, indices, runs, seed = args
    from excite.score.evaluate import evaluate
    from excite.validate.monte_carlo import MonteCarloSettings, run_trial

    rig, built = _setup(plan_doc, imu_rate)
    settings = MonteCarloSettings(runs=runs, seed=seed)
    out = []
    for i in indices:
        traj = _drive(built, rig, i)
        rep = evaluate(traj, rig.with_constant_biases())
        out.append((i, rep, run_trial(traj, rig, i, settings)))
        print(f"trial {i}: {out[-1][2].status} in {out[-1][2].seconds:.0f} s", flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plan", type=Path, default=None)
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--imu-rate", type=float, default=100.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    session = Session()
    if args.plan is None:
        plan_doc = json.loads((RESULTS / "drivable.json").read_text())["figures"]["drivable_plan"]
    else:
        plan_doc = json.loads(args.plan.read_text())
    from excite.motion.vehicle import drive
    from excite.score.evaluate import evaluate
    from excite.validate.monte_carlo import MonteCarloSettings, statistics_driven, systematic_error

    rig, built = _setup(plan_doc, args.imu_rate)
    settings = MonteCarloSettings(runs=args.runs, seed=args.seed)
    t0 = time.perf_counter()
    parts = [list(range(args.runs))[k::args.jobs] for k in range(args.jobs)]
    got = []
    with cf.ProcessPoolExecutor(args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        for res in pool.map(_chunk, [(plan_doc, args.imu_rate, p, args.runs, args.seed) for p in parts]):
            got += res
    got.sort(key=lambda r: r[0])
    reports = [r for _, r, _ in got]
    trials = [t for _, _, t in got]
    nominal_traj = drive(built.timed().profile, rig.suspension)
    nominal = evaluate(nominal_traj, rig.with_constant_biases())
    res = statistics_driven(reports, rig, trials, settings, nominal)
    res.systematic = systematic_error(_drive(built, rig, 0), rig, reports[0], settings)
    seconds = time.perf_counter() - t0
    worst_emp = res.worst_ratio()
    pred = max(((p.name, p.predicted_sigma / p.target) for p in res.parameters), key=lambda x: x[1])
    nom = max(((p.name, p.sigma / p.target) for p in nominal.parameters if p.sigma), key=lambda x: x[1])
    emp_of_pred = next(p.empirical_sigma / p.target for p in res.parameters if p.name == pred[0])
    figures = {
        "runs": len(trials), "converged": res.convergence_rate, "imu_rate_hz": args.imu_rate,
        "nees_mean": res.nees_mean, "nees_interval": list(res.nees_interval), "nees_dof": res.dof,
        "nees_inside": res.nees_consistent,
        "worst_empirical_sigma_over_target": {"name": worst_emp[0], "value": worst_emp[1]},
        "worst_predicted_sigma_over_target_driven": {"name": pred[0], "value": pred[1]},
        "worst_predicted_sigma_over_target_nominal": {"name": nom[0], "value": nom[1]},
        "worst_empirical_over_predicted_driven": worst_emp[1] / pred[1],
        "empirical_over_predicted_of_the_worst_predicted": emp_of_pred / pred[1],
        "worst_empirical_over_predicted_nominal": worst_emp[1] / nom[1],
        "model_check": res.model_check()[0], "model_check_interval": list(res.model_check()[1]),
        "systematic_error_in_sigma_max": max(res.systematic.items(), key=lambda kv: abs(kv[1])) if res.systematic
        else None,
        "seconds": round(seconds, 1), "stop_reasons": res.stop_reasons,
    }
    print(json.dumps(figures, indent=1))
    path = session.record("drivable_mc", figures, note=(
        f"the default problem's drivable plan, {len(trials)} drives by the driver model, physical simulator, IMU at "
        f"{args.imu_rate:g} Hz; NEES {res.nees_mean:.2f} in [{res.nees_interval[0]:.2f}, {res.nees_interval[1]:.2f}]; "
        f"worst σ/target {worst_emp[1]:.3g} ({worst_emp[0]}) against {pred[1]:.3g} predicted from the driven drives "
        f"({nom[1]:.3g} from the nominal)"))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
