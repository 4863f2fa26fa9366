"""The optimizer's information model, side by side with the package at another revision: what an
IPOPT iteration pays for the model on the default problem (robotaxi, 90 s, 80 × 50 m lot).

    python benchmarks/bench_model.py --baseline REV [--pairs 5] [--iterations 10]

Per package, alternating: the time to state the problem (the CasADi model built and the
transcription), the scaled information ``M(z)`` at the start the pipeline uses and its Jacobian
``∂M/∂z`` (what the objective's value and gradient evaluate every iteration), and a fixed number
of IPOPT iterations from that start (wall per iteration, the model and everything else). The two
models must agree (``max |M − M_baseline|`` relative, printed). Wall and CPU time; the machine is
shared, so compare the per-pair ratios.
"""

from __future__ import annotations

import argparse
import importlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def package(prefix: str):
    """(settings, candidates, solver, kinematics, rig) modules of ``excite`` or a baseline copy."""
    names = (("plan", "plan.candidates", "plan.solver", "plan.kinematics", "rig.config")
             if importlib.util.find_spec(f"{prefix}.plan") else
             ("optimize", "optimize.candidates", "optimize.solver", "optimize.kinematics", "rig"))
    return tuple(importlib.import_module(f"{prefix}.{n}") for n in names)


def baseline(rev: str, into: Path) -> str:
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "excite"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    (into / "excite").rename(into / "excite_baseline")
    sys.path.insert(0, str(into))
    return "excite_baseline"


def timed(fn, reps: int = 3) -> tuple[float, float]:
    """Median wall and CPU seconds of ``fn()`` over ``reps``."""
    w, c = [], []
    for _ in range(reps):
        t0, p0 = time.perf_counter(), time.process_time()
        fn()
        w.append(time.perf_counter() - t0)
        c.append(time.process_time() - p0)
    return statistics.median(w), statistics.median(c)


def measure(prefix: str, iterations: int):
    opt, cand, solver, kin, rigmod = package(prefix)
    rig = rigmod.load_rig("robotaxi")
    s = opt.OptimizeSettings()
    site = s.lot
    t0 = time.perf_counter()
    tr = solver.transcribe(rig, s, site)
    build = time.perf_counter() - t0
    start = next(c.profile for c in cand.reference_profiles(rig, s, site) if c.name == "figure_eight")
    z0 = kin.z_from_profile(tr.grid, tr.scales, start)
    M = np.array(tr.M(z0))
    jac = tr.M.jacobian()
    f_w, f_c = timed(lambda: tr.M(z0), 5)
    j_w, j_c = timed(lambda: jac(z0, tr.M(z0)), 3)
    t0, p0 = time.perf_counter(), time.process_time()
    out = solver.solve(tr, z0, time.perf_counter() + 3600, max_iterations=iterations)
    it_w = (time.perf_counter() - t0) / max(out.iterations, 1)
    it_c = (time.process_time() - p0) / max(out.iterations, 1)
    return dict(build=build, M=M, f=(f_w, f_c), jac=(j_w, j_c), it=(it_w, it_c), n=out.iterations,
                status=out.ipopt_status)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--baseline", required=True, metavar="REV")
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--iterations", type=int, default=10)
    args = ap.parse_args()
    print(f"load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        base = baseline(args.baseline, Path(tmp))
        rows = []
        for _ in range(args.pairs):
            rows.append((measure("excite", args.iterations), measure(base, args.iterations)))
            a, b = rows[-1]
            print(f"pair: state the problem {a['build']:.1f} vs {b['build']:.1f} s; M(z) {a['f'][0] * 1e3:.1f} vs "
                  f"{b['f'][0] * 1e3:.1f} ms; ∂M/∂z {a['jac'][0] * 1e3:.0f} vs {b['jac'][0] * 1e3:.0f} ms; "
                  f"IPOPT iteration {a['it'][0]:.2f} vs {b['it'][0]:.2f} s ({a['n']} / {b['n']} it, "
                  f"{a['status']} / {b['status']}); max |M − M_base| / max |M| "
                  f"{np.abs(a['M'] - b['M']).max() / np.abs(b['M']).max():.1e}", flush=True)
    for key, name in (("build", "state the problem"), ("f", "M(z)"), ("jac", "∂M/∂z"), ("it", "IPOPT iteration")):
        for k, kind in ((0, "wall"), (1, "cpu")) if key != "build" else ((None, "wall"),):
            r = [(a[key][k] if k is not None else a[key]) / (b[key][k] if k is not None else b[key]) for a, b in rows]
            print(f"{name:18s} {kind}: this / {args.baseline} median {statistics.median(r):.2f}x "
                  f"({min(r):.2f}–{max(r):.2f})")
    print(f"load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
