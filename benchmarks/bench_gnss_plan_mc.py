"""Is a rig with GNSS consistent on a drive the optimizer planned? Monte Carlo.

The rig is ``benchmarks/robotaxi_gnss.yaml`` (the bundled robotaxi with an RTK antenna, 2/4 cm,
τ 30 s, 10 Hz). The plan is the optimizer's (``excite optimize``'s, E-optimal) for ``--duration``
seconds, or a route file given with ``--plan``. It is driven ``--runs`` times in each simulator
(``physical``: the IMU integrated at 8× its rate, random-walk biases, wheel slip and tyre slip
angle, fixes of the exact pose; ``model``: data exactly as the information model assumes) and
calibrated. Per simulator: the NEES over every scored parameter with its 95 % interval, the NEES
of the antenna alone (its 4 coordinates, against their marginal covariance from the same report:
χ²(4) per trial), each antenna coordinate's empirical/predicted σ, and the physics' systematic
error (a noise-free trial).

    python benchmarks/bench_gnss_plan_mc.py [--plan FILE] [--duration 20] [--runs 50] [--seed 0]
        [--imu-rate 100] [--time-budget 90] [--simulator physical --simulator model] [--out DIR]

The same as ``excite optimize --rig benchmarks/robotaxi_gnss.yaml --duration 20 --seed 0
--time-budget 90 -o OUT`` then ``excite validate OUT/control.csv --rig benchmarks/robotaxi_gnss.yaml
--runs 50 --imu-rate 100 [--simulator model]``, plus the antenna's own NEES.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))

from results import Session  # noqa: E402

from excite.cli.validate import with_imu_rate
from excite.io.routes import read_route, write_control_csv
from excite.plan import OptimizeSettings, optimize
from excite.rig.config import load_rig
from excite.validate import MonteCarloSettings, monte_carlo
from excite.validate.simulate import SimulationSettings

RIG = Path(__file__).parent / "robotaxi_gnss.yaml"
OUT = Path(__file__).parent / "out" / "gnss_plan_mc"


def antenna_nees(res, rig) -> tuple[float, tuple[float, float], int]:
    """Mean NEES of the antenna's coordinates over the trials, its 95 % interval and its dof."""
    rep = res.report
    names = [c.name for c in rig.scored]
    S = np.array([c.target for c in rig.scored])
    w, V = np.asarray(rep.spectrum_scaled), rep.eigenvectors_scaled
    if rep.nullity:
        raise SystemExit(f"the plan leaves {rep.nullity} directions undetermined: no antenna NEES")
    C = (S[:, None] * (V / w) @ V.T) * S[None, :]  # covariance of the scored parameters
    g = [i for i, n in enumerate(names) if n.startswith("gnss.")]
    scored = np.array([not c.nuisance for c in rig.coordinates])
    E = np.array([t.error[scored] for t in res.trials])[:, g]
    info = np.linalg.inv(C[np.ix_(g, g)])
    nees = np.einsum("ni,ij,nj->n", E, info, E)
    N, d = E.shape
    return float(nees.mean()), (chi2.ppf(0.025, N * d) / N, chi2.ppf(0.975, N * d) / N), d


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plan", type=Path, default=None, help="a route file (else the optimizer plans one)")
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--imu-rate", type=float, default=100.0)
    ap.add_argument("--time-budget", type=float, default=90.0)
    ap.add_argument("--simulator", action="append", default=None, choices=["physical", "model"])
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    session = Session()
    args.out.mkdir(parents=True, exist_ok=True)
    rig = load_rig(RIG)
    plan = args.plan
    if plan is None:
        t0 = time.perf_counter()
        res = optimize(rig, OptimizeSettings(duration_s=args.duration, seed=args.seed, time_budget_s=args.time_budget))
        print(f"optimizer: {res.status}, score {res.report.score:.4g} ({time.perf_counter() - t0:.0f} s)", flush=True)
        plan = write_control_csv(res.profile, args.out / "control.csv")
    coarse = with_imu_rate(rig, args.imu_rate)
    traj = read_route(plan, suspension=coarse.suspension)
    rows = []
    for sim in args.simulator or ["physical", "model"]:
        settings = SimulationSettings.model() if sim == "model" else SimulationSettings()
        t0 = time.perf_counter()
        res = monte_carlo(traj, coarse, MonteCarloSettings(runs=args.runs, seed=args.seed, simulation=settings))
        g_mean, g_int, g_dof = antenna_nees(res, coarse)
        ratios = {p.name: p.ratio for p in res.parameters if p.name.startswith("gnss.")}
        sys_err = {} if res.systematic is None else dict(sorted(res.systematic.items(), key=lambda kv: -abs(kv[1]))[:3])
        row = {"simulator": sim, "runs": len(res.trials), "converged": res.convergence_rate,
               "nees": res.nees_mean, "nees_interval": list(res.nees_interval), "dof": res.dof,
               "antenna_nees": g_mean, "antenna_nees_interval": list(g_int), "antenna_dof": g_dof,
               "antenna_ratios": ratios, "systematic_top": sys_err, "seconds": time.perf_counter() - t0}
        rows.append(row)
        lo, hi = res.nees_interval
        print(f"{sim}: {len(res.trials)} trials, {res.convergence_rate * 100:.0f} % converged; NEES {res.nees_mean:.2f} "
              f"[{lo:.2f}, {hi:.2f}] dof {res.dof}; antenna NEES {g_mean:.2f} [{g_int[0]:.2f}, {g_int[1]:.2f}] "
              f"dof {g_dof}; σ ratios " + ", ".join(f"{k} {v:.2f}" for k, v in ratios.items())
              + ("; systematic " + ", ".join(f"{k} {v:+.2f} σ" for k, v in sys_err.items()) if sys_err else "")
              + f" ({row['seconds']:.0f} s)", flush=True)
        (args.out / "results.json").write_text(json.dumps(rows, indent=2))
    session.record("gnss_plan_mc", {r["simulator"]: {
        "converged": r["converged"], "nees": round(r["nees"], 2),
        "nees_95_interval": [round(x, 2) for x in r["nees_interval"]], "dof": r["dof"],
        "antenna_nees": round(r["antenna_nees"], 2),
        "antenna_nees_95_interval": [round(x, 2) for x in r["antenna_nees_interval"]],
        "antenna_sigma_ratios": {k: round(v, 2) for k, v in r["antenna_ratios"].items() if v is not None},
    } for r in rows}, note=f"benchmarks/robotaxi_gnss.yaml (IMU at {args.imu_rate:g} Hz) on "
                           + (f"the plan {plan.name}" if args.plan else f"the optimizer's {args.duration:g} s plan")
                           + f", {args.runs} trials per simulator (seed {args.seed}); antenna NEES over its "
                           "4 coordinates; σ ratio = empirical / predicted")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
