"""What makes IPOPT fast on the maneuver NLP? Transcriptions and Hessians side by side, from
one start, each run to convergence.

    python benchmarks/bench_ipopt.py [--start random_0_0 [4:random_4_0 ...]] [--variants shipped single hull ...]
        [--exact-duration 15] [--max-iterations 1500]

The default problem (robotaxi, 90 s, 80 × 50 m, seed 0) from ``--start`` (``random_0_0``:
the start the optimizer chooses for seed 0, whose converged plan scores about 2e-3 by the full
evaluator; ``SEED:NAME`` names another seed's random start; with several starts every
variant runs from each, and a table of iterations and full scores ends the output), IPOPT until
it converges (or ``--max-iterations``). Per variant: IPOPT's
status, iterations, wall time and its split (objective, gradient, constraint Jacobian, IPOPT's
own linear algebra), the model's λ_min and the full evaluator's score of the best iterate that
passes the limit and lot check (rounded as written; best model value first, as the pipeline
checks them), and the first iterations within 10 / 1 / 0.1 % of the best model value. Variants
(by default the first six; every variant is deterministic: the same iterations run to run):

- ``shipped``: what ``excite optimize`` runs (B-spline controls, limits at the model's
  samples, jerk at the knots, multiple shooting every 3 s, SR1 with 20 pairs, compiled model);
- ``bfgs6``: L-BFGS with 6 pairs and MUMPS's own scaling (the untuned baseline); the variants
  after ``vm`` (IPOPT options; ``--print-level 5`` prints IPOPT's iterations) change one or two
  options of ``bfgs6`` each;
- ``single``: the same without multiple shooting (every position depends on every earlier control);
- ``hull``: the limits by the B-spline convex hull (knot intervals split 4×) instead of samples;
- ``history20``: 20 L-BFGS pairs (``bfgs6`` with 20);
- ``vm``: the model and the kinematics in CasADi's virtual machine instead of compiled;
- ``mumps_scaled``: MUMPS with IPOPT's default scaling of the KKT system (77, 7) instead of none;
- ``restored``: shipped, from the start first moved to the nearest point within the optimizer's
  constraints (:func:`excite.plan.solver.restore`; the pipeline starts near-feasible starts as they are).

``--exact-duration``: the exact Hessian of the Lagrangian against L-BFGS on a shorter problem
(the same lot, both to convergence from the best reference), and the time of one exact
Hessian of the objective on the 90 s problem (forward-over-reverse AD through the model).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from results import Session  # noqa: E402

from excite.plan import OptimizeSettings, candidates as cand, solver
from excite.plan.pipeline import CHECK_ITERATES
from excite.plan.kinematics import profile_from_z, z_from_profile
from excite.plan.problem import Problem
from excite.plan.transcription import TranscriptionOptions, transcribe, violation
from excite.rig.config import load_rig
from excite.score.evaluate import evaluate

SHIPPED = TranscriptionOptions()
VARIANTS = {
    "shipped": (SHIPPED, solver.DEFAULT),
    "single": (dataclasses.replace(SHIPPED, shooting_s=None), solver.DEFAULT),
    "hull": (dataclasses.replace(SHIPPED, hull_refine=4), solver.DEFAULT),
    "history20": (SHIPPED, dataclasses.replace(solver.DEFAULT, history=20, update="bfgs")),
    "vm": (dataclasses.replace(SHIPPED, compile="never"), solver.DEFAULT),
    "mumps_scaled": (SHIPPED, dataclasses.replace(solver.DEFAULT, mumps_scaling=True)),
    "restored": (SHIPPED, solver.DEFAULT),  # from the start moved to the constraints first (solver.restore)
}
_D = dataclasses.replace(solver.DEFAULT, history=6, update="bfgs", mumps_scaling=True)  # the untuned baseline


def _x(**extra) -> solver.SolverOptions:
    """``bfgs6`` with further IPOPT options (``SolverOptions.extra``)."""
    return dataclasses.replace(_D, extra=extra)


VARIANTS.update({  # IPOPT's own options, one or two changes each from bfgs6
    "bfgs6": (SHIPPED, _D),
    "history50": (SHIPPED, dataclasses.replace(_D, history=50)),
    "lm_scalar2": (SHIPPED, _x(limited_memory_initialization="scalar2")),
    "lm_const1e-2": (SHIPPED, _x(limited_memory_initialization="constant", limited_memory_init_val=1e-2)),
    "lm_const1": (SHIPPED, _x(limited_memory_initialization="constant", limited_memory_init_val=1.0)),
    "lm_const1e2": (SHIPPED, _x(limited_memory_initialization="constant", limited_memory_init_val=1e2)),
    "sr1": (SHIPPED, _x(limited_memory_update_type="sr1")),
    "adaptive": (SHIPPED, _x(mu_strategy="adaptive")),  # mu_init 1e-3 as shipped
    "adaptive_mu1e-4": (SHIPPED, _x(mu_strategy="adaptive", mu_init=1e-4)),
    "adaptive_mu1e-2": (SHIPPED, _x(mu_strategy="adaptive", mu_init=1e-2)),
    "mono_mu1e-4": (SHIPPED, dataclasses.replace(_D, mu_init=1e-4)),
    "mono_mu1e-2": (SHIPPED, dataclasses.replace(_D, mu_init=1e-2)),
    "scale_none": (SHIPPED, _x(nlp_scaling_method="none")),
    "scale_grad10": (SHIPPED, _x(nlp_scaling_max_gradient=10.0)),
    "scale_grad1": (SHIPPED, _x(nlp_scaling_max_gradient=1.0)),
    "acc_obj1e-4": (SHIPPED, dataclasses.replace(_D, acceptable_obj_change_tol=1e-4)),
    "acc_obj1e-3": (SHIPPED, dataclasses.replace(_D, acceptable_obj_change_tol=1e-3)),
    "acc_iter5": (SHIPPED, dataclasses.replace(_D, acceptable_iter=5)),
    "acc_tol1e-2": (SHIPPED, dataclasses.replace(_D, acceptable_tol=1e-2)),
    "acc_loose": (SHIPPED, dataclasses.replace(_D, acceptable_tol=1e-2, acceptable_iter=5,
                                                acceptable_obj_change_tol=1e-4)),
    "sr1_hist10": (SHIPPED, dataclasses.replace(_D, history=10, extra={"limited_memory_update_type": "sr1"})),
    "sr1_hist50": (SHIPPED, dataclasses.replace(_D, history=50, extra={"limited_memory_update_type": "sr1"})),
    "skip100_hist20": (SHIPPED, dataclasses.replace(_D, history=20, extra={"limited_memory_max_skipping": 100})),
    "sr1_hist20_const1e-2": (SHIPPED, dataclasses.replace(_D, history=20, extra={
        "limited_memory_update_type": "sr1", "limited_memory_initialization": "constant",
        "limited_memory_init_val": 1e-2})),
    "sr1_hist20_skip10": (SHIPPED, dataclasses.replace(_D, history=20, extra={
        "limited_memory_update_type": "sr1", "limited_memory_max_skipping": 10})),
    "sr1_hist20_skip100": (SHIPPED, dataclasses.replace(_D, history=20, extra={
        "limited_memory_update_type": "sr1", "limited_memory_max_skipping": 100})),
    "skip100_hist50": (SHIPPED, dataclasses.replace(_D, history=50, extra={"limited_memory_max_skipping": 100})),
    "recalc_y": (SHIPPED, _x(recalc_y="yes")),
    "alpha_y_full": (SHIPPED, _x(alpha_for_y="full")),
    "alpha_y_minduals": (SHIPPED, _x(alpha_for_y="safer-min-dual-infeas")),
    "obj_scale10": (SHIPPED, _x(obj_scaling_factor=10.0)),
    "lm_skip10": (SHIPPED, _x(limited_memory_max_skipping=10)),
    "lm_skip100": (SHIPPED, _x(limited_memory_max_skipping=100)),
    "sr1_hist20": (SHIPPED, dataclasses.replace(_D, history=20, extra={"limited_memory_update_type": "sr1"})),
    "sr1_hist3": (SHIPPED, dataclasses.replace(_D, history=3, extra={"limited_memory_update_type": "sr1"})),
    "sr1_mu1e-4": (SHIPPED, dataclasses.replace(_D, mu_init=1e-4, extra={"limited_memory_update_type": "sr1"})),
    "sr1_acc_obj1e-4": (SHIPPED, dataclasses.replace(_D, acceptable_obj_change_tol=1e-4,
                                                      extra={"limited_memory_update_type": "sr1"})),
})


def starts(rig, s):
    """The references and the seed's first 10 random candidates (the pipeline's possible starts)."""
    site = s.lot
    out = [c.profile for c in cand.reference_profiles(rig, s, site) if c.name != "highway_run"]
    return out + cand.random_profiles(rig, s, site, 0, 5, 0) + cand.random_profiles(rig, s, site, 1, 5, 5)


def start_of(rig, spec: str):
    """``NAME`` (among seed 0's possible starts) or ``SEED:NAME``: ``(settings, profile)``."""
    seed, _, name = spec.rpartition(":")
    s = OptimizeSettings(seed=int(seed) if seed else 0)
    prof = next((p for p in starts(rig, s) if p.name == name), None)
    if prof is None:
        raise SystemExit(f"--start {spec}: no such start (the references and random_{s.seed}_0 … random_{s.seed}_9)")
    return s, prof


def run(name: str, rig, s: OptimizeSettings, start, tr_opts, sol_opts, max_iterations: int,
        print_level: int = 0, restored: bool = False) -> dict:
    site = s.lot
    t0 = time.perf_counter()
    tr = transcribe(Problem.of(rig, s), tr_opts)
    t_tr = time.perf_counter() - t0
    z0 = z_from_profile(tr.grid, tr.scales, start, terrain=site.terrain)
    if restored:
        t1 = time.perf_counter()
        v0 = violation(tr, z0)
        z0, how = solver.restore(tr, z0, t1 + 120)
        print(f"{name:<10} restored: violation {v0:.3g} → {violation(tr, z0):.3g} ({how}, {time.perf_counter() - t1:.1f} s)",
              flush=True)
    load0 = os.getloadavg()[0]
    if print_level:
        sol_opts = dataclasses.replace(sol_opts, extra={**sol_opts.extra, "print_level": print_level})
    out = solver.solve(tr, z0, time.perf_counter() + 7200, max_iterations=max_iterations, options=sol_opts)
    full = float("nan")
    bad = ["no feasible iterate"]
    rank = 0
    for rank, (_, z) in enumerate(out.feasible[:CHECK_ITERATES], 1):  # as the pipeline: best first, the
        prof = cand.as_written(profile_from_z(tr.grid, tr.scales, z, terrain=site.terrain))  # first to pass
        traj, why = cand.check(prof, rig, s, site)
        if rank == 1:
            bad = why
        if not why:
            full = evaluate(traj, rig).score
            break
    t = out.timings_s
    n = max(out.iterations, 1)
    split = {k: round(1e3 * t.get(k, 0.0) / n, 1) for k in ("nlp_f", "nlp_grad_f", "nlp_jac_g", "nlp_g")}
    own = t["solve"] - sum(t.get(k, 0.0) for k in ("nlp_f", "nlp_grad_f", "nlp_jac_g", "nlp_g", "nlp_hess_l",
                                                     "iteration_callback"))
    print(f"{name:<10} {tr.info.mode:<15} rows {tr.n_g:>5}  {out.ipopt_status:<28} {out.iterations:>5} it  "
          f"{t['solve']:7.1f} s ({1e3 * t['solve'] / n:5.1f} ms/it: f {split['nlp_f']}, ∇f {split['nlp_grad_f']}, "
          f"∂g {split['nlp_jac_g']}, IPOPT {1e3 * own / n:.1f})  transcription {t_tr:.1f} s  model λ_min "
          f"{out.score:.4g}  full {full:.4g} (iterate {rank} of the best, the first to pass)  check of the best "
          f"{'ok' if not bad else bad[0][:60]}  load {load0:.1f}→"
          f"{os.getloadavg()[0]:.1f}", flush=True)
    best = max((h[1] for h in out.history), default=float("nan"))
    marks = {f: next((h[0] for h in out.history if h[1] >= f * best), None) for f in (0.9, 0.99, 0.999)}
    print(f"{name:<10} model λ_min best {best:.5g}; first iteration within 10 % / 1 % / 0.1 % of it: "
          f"{marks[0.9]} / {marks[0.99]} / {marks[0.999]}", flush=True)
    return {"variant": name, "iterations": out.iterations, "status": out.ipopt_status, "seconds": t["solve"],
            "model": out.score, "full": full}


def exact_vs_lbfgs(rig, duration_s: float, max_iterations: int) -> dict:
    s = OptimizeSettings(duration_s=duration_s)
    tr = transcribe(Problem.of(rig, s), TranscriptionOptions(compile="never"))
    best = max(starts(rig, s), key=lambda p: solver.model_value(tr, z_from_profile(tr.grid, tr.scales, p)))
    z0 = z_from_profile(tr.grid, tr.scales, best)
    rows = {}
    for h in ("limited-memory", "exact"):
        t0 = time.perf_counter()
        out = solver.solve(tr, z0, time.perf_counter() + 7200, max_iterations=max_iterations,
                           options=dataclasses.replace(solver.DEFAULT, hessian=h))
        el = time.perf_counter() - t0
        print(f"{duration_s:g} s problem, from {best.name}, Hessian {h:<15}: {out.ipopt_status:<28} "
              f"{out.iterations:>4} it  {el:7.1f} s ({1e3 * el / max(out.iterations, 1):.0f} ms/it)  model λ_min "
              f"{out.score:.4g}  (virtual machine)", flush=True)
        rows[f"{duration_s:g}s_hessian_{h}"] = {"status": out.ipopt_status, "iterations": out.iterations,
                                                "seconds": round(el, 1), "model": float(f"{out.score:.4g}")}
    return rows


def hessian_cost(rig) -> None:
    s = OptimizeSettings()
    tr = transcribe(Problem.of(rig, s), TranscriptionOptions(compile="never"))
    z = z_from_profile(tr.grid, tr.scales, starts(rig, s)[4])
    M = tr.M(z)
    G = np.eye(M.shape[0])
    t0 = time.perf_counter()
    tr.info.second_order(z, G)
    t1 = time.perf_counter()
    tr.info.second_order(z, G)
    t2 = time.perf_counter()
    tr.info.vjp(z, M, G)
    t3 = time.perf_counter()
    print(f"90 s problem, one exact Hessian of the objective (virtual machine): {t2 - t1:.1f} s (building it "
          f"{t1 - t0 - (t2 - t1):.1f} s), one gradient {1e3 * (t3 - t2):.0f} ms; load {os.getloadavg()[0]:.1f}",
          flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--start", nargs="*", default=["random_0_0"],
                    help="NAME (seed 0's) or SEED:NAME; several: each variant from each, and a table")
    ap.add_argument("--variants", nargs="*", default=["shipped", "bfgs6", "single", "hull", "history20", "vm"],
                    choices=list(VARIANTS))
    ap.add_argument("--max-iterations", type=int, default=1500)
    ap.add_argument("--exact-duration", type=float, default=15.0, help="0: skip the exact-Hessian comparison")
    ap.add_argument("--print-level", type=int, default=0, help="IPOPT's print_level (5: a line per iteration)")
    ap.add_argument("--hessian-cost", action="store_true", help="time one exact Hessian on the 90 s problem (minutes)")
    args = ap.parse_args()
    session = Session()
    rig = load_rig("robotaxi")
    chosen = [(spec, *start_of(rig, spec)) for spec in args.start]
    rows = {}
    for name in args.variants:
        tr_opts, sol_opts = VARIANTS[name]
        for spec, s, start in chosen:
            label = name if len(chosen) == 1 else f"{name}:{spec}"
            rows[name, spec] = run(label, rig, s, start, tr_opts, sol_opts, args.max_iterations, args.print_level,
                                   restored=name == "restored")
    if len(chosen) > 1:  # iterations and the full score of every variant from every start
        print(f"\n{'iterations / full score':<24}" + "".join(f"{spec:>20}" for spec, _, _ in chosen) + f"{'largest':>9}")
        for name in args.variants:
            r = [rows[name, spec] for spec, _, _ in chosen]
            print(f"{name:<24}" + "".join(f"{x['iterations']:>9} {x['full']:10.4g}" for x in r)
                  + f"{max(x['iterations'] for x in r):>9}")
    figures = {(name if len(chosen) == 1 else f"{name}:{spec}"): {
        "status": r["status"], "iterations": r["iterations"], "seconds": round(r["seconds"], 1),
        "model": float(f"{r['model']:.4g}"), "full": float(f"{r['full']:.4g}")} for (name, spec), r in rows.items()}
    if args.exact_duration:
        figures.update(exact_vs_lbfgs(rig, args.exact_duration, args.max_iterations))
    if args.hessian_cost:
        hessian_cost(rig)
    session.record("ipopt", figures, note="the default problem (robotaxi, 90 s, 80 × 50 m) from "
                   + ", ".join(args.start) + " to convergence per variant: IPOPT's status, iterations, solve seconds "
                   "(wall), the model's λ_min and the full evaluator's score of the best iterate that passes the check")


if __name__ == "__main__":
    main()
