"""The drivable plan against the free-form plan on the default problem, both driven by the driver
model; the drivable search's wall time, memory and the sheet's drawing time.

    python benchmarks/bench_drivable.py [--budget 60] [--draws 200] [--seed 0]

1. the free-form plan (``excite optimize``: IPOPT, ``--budget``) and its score;
2. the drivable plan (``excite optimize --drivable``, the same budget): wall time, the peak memory
   of the process and its workers, its score;
3. both driven ``--draws`` times by the driver model (:mod:`excite.motion.driver`; drivers
   ``[seed + 1000, i]``, not those the drivable search chose by): the 10th percentile of each
   plan's scores, and its ratio to the plan's own score (the free-form plan's course is its path
   with its speeds, :func:`excite.motion.driver.course_of`); the 10th percentile of ``--draws``
   drives has a spread of its own (about ±0.05 of the score for 30 drives, ±0.02 for 200);
4. what costs the drivable plan most: its 10th percentile over the same drivers with one of the
   driver model's errors taken out at a time (the speed held per element, its fluctuation, the
   spread of the effort in acceleration and braking, the lateral offset, the reaction time);
5. the sheet of the drivable plan drawn as PNG and PDF (CPU seconds).

Writes ``benchmarks/results/drivable.json`` (:mod:`results`) with the table in its note.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from results import Session  # noqa: E402

from excite.motion.driver import course_of  # noqa: E402
from excite.plan import OptimizeSettings, optimize  # noqa: E402
from excite.plan.drivable.robust import robust_scores  # noqa: E402
from excite.plan.drivable.search import DrivableSettings, optimize_drivable  # noqa: E402
from excite.plan.drivable.sheet import sheet  # noqa: E402
from excite.rig.config import load_rig  # noqa: E402


def peak_mib() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return round(max(own, kids) / 1024, 1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=float, default=60.0)
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    session = Session()
    rig = load_rig("robotaxi")

    t0 = time.perf_counter()
    free = optimize(rig, OptimizeSettings(time_budget_s=args.budget, seed=args.seed))
    free_s = time.perf_counter() - t0
    print(f"free-form: score {free.report.score:.4g} in {free_s:.1f} s ({free.status})", flush=True)

    t0 = time.perf_counter()
    cpu0 = time.process_time()
    settings = DrivableSettings(time_budget_s=args.budget, seed=args.seed)
    res = optimize_drivable(rig, settings, progress=lambda p: print(f"  {p.elapsed_s:5.1f} s {p.phase} {p.detail}",
                                                                    flush=True) if p.phase != "refine" else None)
    drivable_s = time.perf_counter() - t0
    mem = peak_mib()
    print(f"drivable: score {res.report.score:.4g} in {drivable_s:.1f} s, peak {mem} MiB; 10th percentile over the "
          f"search's own {res.robust.scores.size} drivers {res.robust.low:.4g}", flush=True)

    seed = args.seed + 1000
    rd = robust_scores(res.built.course, rig, settings.limits, args.draws, res.report.score, seed,
                       duration_s=settings.duration_s)
    rf = robust_scores(course_of(free.profile, name="free-form"), rig, settings.limits, args.draws, free.report.score,
                       seed, duration_s=settings.duration_s, margin=1.0)
    print(f"drivable 10th percentile {rd.low:.4g} ({100 * rd.ratio:.0f} %); free-form {rf.low:.4g} "
          f"({100 * rf.ratio:.0f} %)", flush=True)

    # what costs most: the same drivers, one error of the driver model taken out at a time
    base = settings.driver
    without = {"speed held per element": {"speed_bias_sigma": 0.0}, "speed fluctuation": {"speed_noise_sigma": 0.0},
               "effort spread": {"effort_sigma": 0.0}, "lateral offset": {"lateral_sigma_m": 0.0},
               "reaction time": {"reaction_s": 0.0}}
    parts = {}
    for what, change in without.items():
        r = robust_scores(res.built.course, rig, settings.limits, args.draws, res.report.score, seed,
                          model=replace(base, **change), duration_s=settings.duration_s)
        parts[what] = r.ratio
        print(f"  without the {what}: 10th percentile {100 * r.ratio:.0f} % of the score", flush=True)

    times = {}
    site = settings.lot
    sheet(res.built, site, "png")
    for fmt in ("png", "pdf"):
        c0 = time.process_time()
        sheet(res.built, site, fmt)
        times[fmt] = round(time.process_time() - c0, 3)

    elements = " + ".join(f"{e.kind}×{int(e.params['laps'])}" for e in res.plan.elements)
    table = ["| plan | score | 10th percentile (driver model, {n} drives) | 10th percentile / score |".format(
        n=args.draws), "|---|---|---|---|",
        f"| free-form (IPOPT) | {free.report.score:.3g} | {rf.low:.3g} | {100 * rf.ratio:.0f} % |",
        f"| drivable ({elements}) | "
        f"{res.report.score:.3g} | {rd.low:.3g} | {100 * rd.ratio:.0f} % |"]
    costs = ["| the drivable plan driven without | 10th percentile / score |", "|---|---|",
             f"| (the driver model as it is) | {100 * rd.ratio:.0f} % |",
             *[f"| the {what} | {100 * v:.0f} % |" for what, v in parts.items()]]
    print("\n".join(costs))
    print("\n".join(table))
    figures = {
        "free_form_score": free.report.score, "free_form_p10": rf.low, "free_form_p10_over_score": rf.ratio,
        "drivable_score": res.report.score, "drivable_p10": rd.low, "drivable_p10_over_score": rd.ratio,
        "drivable_p10_search_drivers": res.robust.low,
        "drivable_over_free_form": res.report.score / free.report.score,
        "drivable_wall_s": round(drivable_s, 1), "drivable_cpu_s_main": round(time.process_time() - cpu0, 1),
        "drivable_peak_mib": mem, "free_form_wall_s": round(free_s, 1), "draws": args.draws,
        "sheet_cpu_s": times, "drivable_plan": res.plan.to_dict(), "instructions": res.built.instructions,
        "timings_s": res.timings_s, "table": table,
        "drivable_p10_over_score_without": parts, "costs_table": costs,
    }
    path = session.record("drivable", figures, note="default problem: robotaxi, 90 s, 80 × 50 m lot; both plans "
                          "driven by the default driver model; " + " ".join(table) + " " + " ".join(costs))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
