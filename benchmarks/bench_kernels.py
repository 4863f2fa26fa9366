"""Time the evaluator's factor kernels, generated from the kinds' statements, and how they are called.

    python benchmarks/bench_kernels.py [--runs 15] [--baseline REV]

On the 10-minute reference drive of the default rig (robotaxi: 6 000 keyframe intervals, IMU at
200 Hz), the thread CPU time of the whitened Jacobians of every factor of each entry:

- as the evaluator computes them: the generated kernel run by the native driver over every
  factor (:func:`excite.factors.kernels.jacobians`);
- the lidar's odometry factor three more ways, to tell the generated code from the way it is
  called: the same statement in CasADi's virtual machine mapped over the factors
  (:func:`excite.factors.symbolic.blocks`); the same generated C compiled to a library and called
  through ``casadi.external(...).map(N)`` on numpy arrays (one ``casadi.Function`` call for the
  batch); and the generated C of one factor called from a C loop over the batch, the loop
  compiled here (``ctypes``: the code alone, no Python in the loop);
- with ``--baseline REV``: each entry's Jacobians as the package at git revision REV computes
  them (its hand-derived numba kernels where it had them), side by side in the same process.

Medians and ranges over ``--runs``; every figure is CPU time of the calling thread (the machine is
shared: wall time says more about the other work than about this one). The load average is
recorded with the figures (benchmarks/results.py).
"""

from __future__ import annotations

import argparse
import ctypes
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_evaluate import baseline_package, generated  # noqa: E402
from results import Session, spread  # noqa: E402

from excite.factors import base as registry  # noqa: E402
from excite.factors import generate, kernels, symbolic  # noqa: E402
from excite.factors.base import Nominal  # noqa: E402
from excite.rig.config import load_rig  # noqa: E402


def cpu_ms(fn, runs: int) -> list[float]:
    fn()  # warm: caches, first-call costs
    out = []
    for _ in range(runs):
        c0 = time.thread_time()
        fn()
        out.append((time.thread_time() - c0) * 1e3)
    return out


def show(name: str, xs: list[float]) -> None:
    print(f"{name:58s} {statistics.median(xs):8.2f} ms  ({min(xs):.2f}–{max(xs):.2f})")


def compiled_copy(fn, tmp: Path) -> Path:
    """``fn``'s generated C compiled to a shared library of its own (and a batch loop over it)."""
    import casadi as ca

    cg = ca.CodeGenerator("one.c", {"with_header": True})
    cg.add(fn)
    cg.generate(str(tmp) + "/")
    n_in, n_out = fn.n_in(), fn.n_out()
    loop = f"""#include "one.h"
int batch(int N, const double** in, const long* stride, double** out, const long* row, double* w) {{
  const double* arg[{n_in}]; double* res[{n_out}]; casadi_int iw[1];
  for (int n = 0; n < N; ++n) {{
    for (int i = 0; i < {n_in}; ++i) arg[i] = in[i] + n * stride[i];
    for (int i = 0; i < {n_out}; ++i) res[i] = out[i] + n * row[i];
    if ({fn.name()}(arg, res, iw, w, 0)) return 1;
  }}
  return 0;
}}
"""
    (tmp / "loop.c").write_text(loop)
    lib = tmp / "one.so"
    subprocess.run(["cc", *generate.FLAGS, str(tmp / "one.c"), str(tmp / "loop.c"), "-o", str(lib), "-lm"],
                   check=True)
    return lib


def odometry_calls(nom: Nominal, rig, runs: int) -> dict[str, list[float]]:
    """The lidar's factor four ways (see the module docstring)."""
    import casadi as ca

    inst = next(i for i in registry.instances(rig) if i.name == "lidar")
    kind, entry = inst.kind, inst.entry
    lay = kernels.layout(kind, rig, entry)
    first = registry.factor_keyframes(kind, rig, entry, nom.n_keyframes, nom)
    N = first.size
    out = {"native": cpu_ms(lambda: kernels.jacobians(kind, nom, rig, entry), runs),
           "casadi_vm": cpu_ms(lambda: symbolic.blocks(kind, nom, rig, entry), runs)}
    fn = generate.functions(kind, lay, "lin")
    c = kernels.constant_inputs(lay, kernels.constant_values(kind, rig, entry))
    x0 = nom.keyframe_table[first]
    x1 = nom.keyframe_table[first + 1]
    q = kernels.quantity_inputs(lay, per_entry=True)
    with tempfile.TemporaryDirectory() as d:
        lib = compiled_copy(fn, Path(d))
        ext = ca.external(fn.name(), str(lib)).map(N, "serial")
        cols = [x0.T, x1.T, np.zeros((0, N)), np.repeat(q[:, None], N, axis=1), np.repeat(c[:, None], N, axis=1)]
        out["casadi_external"] = cpu_ms(lambda: ext(*cols), runs)
        dll = ctypes.CDLL(str(lib))
        P = ctypes.POINTER(ctypes.c_double)
        ins = [np.ascontiguousarray(a) for a in (x0, x1, np.zeros((N, 0)), q, c)]
        strides = (ctypes.c_long * 5)(27, 27, 0, 0, 0)
        outs = [np.empty((N, fn.nnz_out(i))) for i in range(2)]
        in_p = (P * 5)(*[a.ctypes.data_as(P) for a in ins])
        out_p = (P * 2)(*[a.ctypes.data_as(P) for a in outs])
        rows = (ctypes.c_long * 2)(*[fn.nnz_out(i) for i in range(2)])
        w = np.empty(fn.sz_w() + 1)
        w_p = w.ctypes.data_as(P)
        out["c_loop"] = cpu_ms(lambda: dll.batch(N, in_p, strides, out_p, rows, w_p), runs)
    return out


CALLS = {"native": "generated, the native driver over the batch (the evaluator's)",
         "casadi_vm": "the statement in CasADi's virtual machine, mapped",
         "casadi_external": "generated, casadi.external(...).map(N) on numpy",
         "c_loop": "generated, a C loop over the batch (ctypes)"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15)
    parser.add_argument("--baseline", metavar="REV", help="also time the package at this git revision, side by side")
    args = parser.parse_args()
    session = Session()
    rig = load_rig("robotaxi")
    nom = Nominal.of(generated(600.0, rig), rig)
    print(f"10-minute drive, robotaxi: {nom.n_keyframes} keyframes; thread CPU time, median (range) of {args.runs}")
    figures: dict[str, object] = {}
    base = None
    if args.baseline:
        tmp = tempfile.TemporaryDirectory()
        ev, rg, vh = baseline_package(args.baseline, Path(tmp.name))
        import importlib

        ob = importlib.import_module("excite_baseline.factors.base")
        osym = importlib.import_module("excite_baseline.factors.symbolic")
        orig = rg.load_rig("robotaxi")
        onom = ob.Nominal.of(generated(600.0, orig, vh), orig)
        base = {i.name: (lambda i=i: osym.jacobians(i.kind, onom, orig, i.entry)) for i in ob.instances(orig)}
    for inst in registry.instances(rig):
        xs = cpu_ms(lambda: kernels.jacobians(inst.kind, nom, rig, inst.entry), args.runs)
        show(f"{inst.name} ({inst.kind.name}), generated", xs)
        figures[f"{inst.name}_generated_ms"] = spread(xs, 3)
        if base is not None and inst.name in base:
            ys = cpu_ms(base[inst.name], args.runs)
            show(f"{inst.name}, {args.baseline}", ys)
            figures[f"{inst.name}_baseline_ms"] = spread(ys, 3)
    print("the lidar's odometry factor, 6 000 frame pairs:")
    for key, xs in odometry_calls(nom, rig, args.runs).items():
        show("  " + CALLS[key], xs)
        figures[f"lidar_{key}_ms"] = spread(xs, 3)
    if args.baseline:
        figures["baseline"] = args.baseline
    path = session.record("kernels", figures, note="thread CPU time per entry on the 10-minute reference drive "
                          "(robotaxi, 6 000 keyframe intervals); the lidar's factor called four ways")
    print(f"figures: {path}")


if __name__ == "__main__":
    main()
