"""Could ``excite optimize`` stop a start that cannot win? Every start run to convergence with its
history, then early-stop rules replayed on the histories.

    python benchmarks/bench_multistart.py [--seeds 0 1 2 3 4] [--top 4] [--out benchmarks/out/multistart.json]

The command waits for every IPOPT start (:mod:`excite.plan.multistart`), so its wall time is the
slowest start's. A rule that stops a start once another has converged would end it sooner, if it
never stopped the start that would have won. The rules replayed: start B is stopped at
iteration ``k·N_A`` — ``N_A`` the iterations start A needed to converge to model value ``S_A`` —
when B's best value within the limits so far is below ``(1 − m)·S_A``; *wrong* when B, left to
run, ends above ``S_A`` (the plan would have been worse by ``B/S_A − 1``). IPOPT's iterations are
deterministic, so the replay is what the rule would have done (up to when a start past ``k·N_A``
sees the other's end).

Problems (robotaxi): the default (90 s, 80 × 50 m, the model compiled) from each seed's ``--top``
best starts by the model, as the pipeline ranks them; and 12 s in 40 × 30 m and 30 s in 60 × 40 m
from every reference maneuver and 8 random candidates (seed 0). Every ordered pair of starts of
one problem is a case. Then, per problem, what ``--starts k`` would have found: the best model
value of the k best-ranked starts (ranked as the pipeline ranks them) against the best of all,
and the slowest of those k starts.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from results import Session  # noqa: E402

from excite.plan import OptimizeSettings, candidates as cand
from excite.plan.pipeline import TRANSCRIPTION, rank, rank_starts
from excite.plan.problem import Problem
from excite.plan.solver import solve
from excite.plan.transcription import cached
from excite.rig.config import load_rig

SHORT = {"12 s": dict(duration_s=12.0, lot_x_m=40.0, lot_y_m=30.0), "30 s": dict(duration_s=30.0, lot_x_m=60.0, lot_y_m=40.0)}
RULES = [(k, m) for k in (1.0, 1.25, 1.5, 2.0) for m in (0.0, 0.1, 0.2, 0.3)]


def _z0s(problem: str, seed: int, top: int):
    rig = load_rig("robotaxi")
    if problem == "90 s":
        s = OptimizeSettings(seed=seed).for_rig(rig)
        tr = cached(Problem.of(rig, s, s.lot), TRANSCRIPTION)
        ranked, _ = rank_starts(tr, s, s.lot, s.criterion, lambda *a: None, cand.reference_profiles(rig, s, s.lot))
        return tr, [(r[4].name, r[3]) for r in ranked if r[0]][:top]
    s = OptimizeSettings(**SHORT[problem]).for_rig(rig)
    tr = cached(Problem.of(rig, s, s.lot), TRANSCRIPTION)
    profs = [c.profile for c in cand.reference_profiles(rig, s, s.lot) if c.name != "highway_run"]
    profs += cand.random_profiles(rig, s, s.lot, 0, 5, 0) + cand.random_profiles(rig, s, s.lot, 1, 3, 5)
    return tr, [(r[4].name, r[3]) for r in rank(tr, s.lot, s.criterion, profs)]  # as the pipeline ranks them


def one(job: tuple[str, int, int, int]) -> dict:
    problem, seed, top, k = job
    tr, z0s = _z0s(problem, seed, top)
    name, z0 = z0s[k]
    rows: list[tuple[int, float]] = []
    t0 = time.perf_counter()
    out = solve(tr, z0, time.perf_counter() + 900, progress=lambda it, s, v, el, best: rows.append((it, best)))
    return {"problem": problem, "seed": seed, "start": name, "rank": k + 1, "status": out.status,
            "iterations": out.iterations,
            "value": out.score, "seconds": time.perf_counter() - t0, "best_by_iteration": rows}


def by_problem(runs: list[dict]) -> dict[tuple, list[dict]]:
    """The runs grouped by (problem, seed)."""
    groups: dict[tuple, list[dict]] = {}
    for r in runs:
        groups.setdefault((r["problem"], r["seed"]), []).append(r)
    return groups


def replay(runs: list[dict]) -> dict:
    groups = by_problem(runs)
    print(f"\n{'k':>5} {'m':>4}  {'cases':>5} {'stopped':>7} {'wrong':>5}  {'largest loss':>12}  iterations saved  wrong on")
    table = {}
    for k, m in RULES:
        cases = stopped = wrong = saved = 0
        losses, where = [], []
        for (problem, seed), rs in groups.items():
            for a, b in itertools.permutations(rs, 2):
                if a["status"] != "converged":
                    continue
                n = int(k * a["iterations"])
                if b["iterations"] <= n:  # B ends by itself first: nothing to decide
                    continue
                cases += 1
                best = max((v for it, v in b["best_by_iteration"] if it <= n), default=float("-inf"))
                if best < (1 - m) * a["value"]:
                    stopped += 1
                    saved += b["iterations"] - n
                    if b["value"] > a["value"]:
                        wrong += 1
                        losses.append(b["value"] / a["value"] - 1)
                        where.append(f"{problem}{'' if problem != '90 s' else f' seed {seed}'}: {b['start']} for {a['start']}")
        print(f"{k:5.2f} {m:4.1f}  {cases:5d} {stopped:7d} {wrong:5d}  {max(losses, default=0.0):12.1%}  {saved:16d}  "
              + "; ".join(where[:3]) + (" …" if len(where) > 3 else ""))
        table[f"k={k:g} m={m:g}"] = {"cases": cases, "stopped": stopped, "wrong": wrong,
                                     "largest_loss": round(max(losses, default=0.0), 4), "iterations_saved": saved}
    return table


def top_k(runs: list[dict]) -> dict:
    """What the command's ``--starts k`` would have found: the best of the k best-ranked starts
    against the best of all, per problem (and seed), and where the best start ranked."""
    groups = by_problem(runs)
    ks = (1, 2, 4)
    print(f"\n{'problem':<12} {'starts':>6}  {'winner (rank)':<22}" + "".join(f"{f'top {k}':>9}" for k in ks)
          + "   slowest of the top 1 / 2 / 4 [iterations]")
    found = {}
    for (problem, seed), rs in groups.items():
        rs = sorted(rs, key=lambda r: r["rank"])
        best = max(rs, key=lambda r: r["value"])
        label = problem if problem != "90 s" else f"90 s seed {seed}"
        winner = f"{best['start']} ({best['rank']})"
        print(f"{label:<12} {len(rs):>6}  {winner:<22}"
              + "".join(f"{max(r['value'] for r in rs[:k]) / best['value']:9.1%}" for k in ks)
              + "   " + " / ".join(str(max(r["iterations"] for r in rs[:k])) for k in ks))
        found[label] = {f"top_{k}_of_best": round(max(r["value"] for r in rs[:k]) / best["value"], 4) for k in ks}
        found[label]["winner_rank"] = best["rank"]
    return found


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--top", type=int, default=4)
    ap.add_argument("--short", nargs="*", default=list(SHORT), choices=list(SHORT),
                    help="the short problems to run every start of (none: only the 90 s problem)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "out" / "multistart.json")
    args = ap.parse_args()
    session = Session()
    jobs = [("90 s", seed, args.top, k) for seed in args.seeds for k in range(args.top)]
    for problem in args.short:
        jobs += [(problem, 0, 0, k) for k in range(len(_z0s(problem, 0, 0)[1]))]
    runs = []
    with ProcessPoolExecutor(2) as ex:
        for r in ex.map(one, jobs):
            print(f"{r['problem']:<5} seed {r['seed']} {r['start']:<12} {r['status']:<10} {r['iterations']:4d} iterations "
                  f"{r['seconds']:5.1f} s  model {r['value']:.4g}", flush=True)
            runs.append(r)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(runs))
    rules = replay(runs)
    found = top_k(runs)
    session.record("multistart", {"early_stop_rules": rules, "best_of_top_k_starts": found},
                   note=f"every IPOPT start run to convergence: the 90 s problem (seeds {args.seeds}, the {args.top} "
                        "best-ranked starts each)" + (f" and every start of the {' and '.join(args.short)} problems"
                                                      if args.short else "")
                        + "; each rule (stop start B at k·N_A iterations when its best is below (1 − m)·S_A) replayed "
                          "on every ordered pair: cases, stopped, wrong (B would have won), largest loss")


if __name__ == "__main__":
    main()
