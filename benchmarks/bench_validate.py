"""Monte Carlo validation of the predicted σ: the figures of the README.

Writes two routes and a rig variant to ``benchmarks/out/validate/`` and runs ``excite validate``
on them with the model's own data (``--simulator model``; default: 100 trials each, the robotaxi
rig at its 200 Hz IMU):

1. ``hilly_figure_eight_control.csv``: the reference figure-eight (60 s) over undulating ground
   (grade ±8 % with a 4 s period, bank ±3.4° with a 3 s period) with the rig's suspension: full
   rank, every parameter determined, so every empirical σ should match its prediction.
2. ``figure_eight_control.csv`` (60 s, planar) with ``robotaxi_rigid.yaml`` (suspension off): the
   vertical lever arms are exactly unobservable; the rest should still match.

    python benchmarks/bench_validate.py [--runs 100] [--seed 0] [--duration 60]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))

from results import Session  # noqa: E402

from excite.cli.app import main as cli  # noqa: E402
from excite.io.routes import write_control_csv  # noqa: E402
from excite.motion.maneuvers import figure_eight  # noqa: E402
from excite.motion.vehicle import ControlProfile  # noqa: E402
from excite.rig.config import RIGS_DIR  # noqa: E402

OUT = Path(__file__).parent / "out" / "validate"


def hilly(profile: ControlProfile, knot_hz: float = 20.0) -> ControlProfile:
    """``profile`` driven over undulating ground: grade and bank oscillate within a few seconds."""
    t = np.linspace(profile.t_s[0], profile.t_s[-1], int(profile.duration_s * knot_hz) + 1)
    c = profile.at(t)
    return ControlProfile(t, c["speed_mps"], c["curvature_1pm"], grade_rad=0.08 * np.sin(2 * np.pi * t / 4.0),
                          bank_rad=0.06 * np.sin(2 * np.pi * t / 3.0), start=profile.start,
                          name="hilly_figure_eight")


def write_inputs(duration_s: float, out: Path = OUT) -> tuple[Path, Path, Path]:
    out.mkdir(parents=True, exist_ok=True)
    base = figure_eight(duration_s)
    hilly_route = write_control_csv(hilly(base), out / "hilly_figure_eight_control.csv")
    planar_route = write_control_csv(base, out / "figure_eight_control.csv")
    rig = yaml.safe_load((RIGS_DIR / "robotaxi.yaml").read_text())
    rig["name"] = "robotaxi_rigid"
    rig["vehicle"]["suspension"] = {"pitch_deg_per_mps2": 0.0, "roll_deg_per_mps2": 0.0}
    rigid = out / "robotaxi_rigid.yaml"
    rigid.write_text(yaml.safe_dump(rig, sort_keys=False))
    return hilly_route, planar_route, rigid


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=60.0)
    args = ap.parse_args()
    session = Session()
    hilly_route, planar_route, rigid = write_inputs(args.duration)
    # the model's own data: a consistency check of the evaluator and the estimator (the physical
    # simulator's comparison is benchmarks/bench_plan_mc.py)
    common = ["--runs", str(args.runs), "--seed", str(args.seed), "--simulator", "model", "--quiet", "--json"]
    figures = {}
    for case, argv in (("hilly_figure_eight", ["validate", str(hilly_route), *common]),
                       ("planar_figure_eight_rigid", ["validate", str(planar_route), "--rig", str(rigid), *common])):
        print("$ excite " + " ".join(argv), flush=True)
        t0 = time.perf_counter()
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            code = cli(argv)
        print(f"({time.perf_counter() - t0:.0f} s, exit {code})", flush=True)
        if code:
            print(out.getvalue()[-2000:])
            return code
        res = json.loads(out.getvalue())
        ratios = {p["name"]: p["ratio"] for p in res["parameters"] if p["ratio"] is not None}
        worst = max(ratios.items(), key=lambda kv: abs(kv[1] - 1.0))
        figures[case] = {"nees": round(res["nees"]["mean"], 3), "nees_95_interval": [round(x, 3) for x in
                                                                                    res["nees"]["interval"]],
                         "dof": res["nees"]["dof"], "nees_consistent": res["nees"]["consistent"],
                         "sigma_ratio_range": [round(min(ratios.values()), 3), round(max(ratios.values()), 3)],
                         "sigma_ratio_farthest_from_1": {worst[0]: round(worst[1], 3)},
                         "rank": f"{res['rank']}/{res['rank'] + res['nullity']}",
                         "converged": res["convergence_rate"], "seconds": round(res["seconds"])}
        print(json.dumps(figures[case]), "\n", flush=True)
    session.record("validate", figures, note=f"excite validate --simulator model, {args.runs} trials (seed "
                   f"{args.seed}) on a {args.duration:g} s figure-eight: over undulating ground with the robotaxi rig "
                   "(full rank), and planar with its suspension off (the vertical lever arms unobservable); "
                   "σ ratio = empirical / predicted σ of each determined parameter")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
