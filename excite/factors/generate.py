"""The generator of the evaluator's kernels: each kind's one statement (:mod:`.symbolic`),
differentiated by CasADi and written out as C (``casadi.CodeGenerator``).

``excite/factors/generated.c`` holds the kernels compiled with the package
(:mod:`excite.core.native`), for every registered kind and every variant the example rigs use
(:mod:`excite.rig.kernels`, which writes the file: ``python -m excite.rig.kernels``). It is
committed and never edited by hand; a test regenerates it and compares (the SymForce way). Per
kind and variant (:func:`specs_of`):

- ``lin_<kind>[_<variant>]``: the whitened Jacobians of one factor at its noise-free measurement
  (:func:`.symbolic.derivatives`), inputs ``(x per keyframe, s, q, c)`` and outputs ``(Jx, Jt)``
  as :mod:`.kernels` describes; the constants ``c`` and the entry's own nominal values ``q`` are
  inputs, so one kernel serves every entry of the variant;
- ``raw_<kind>[_<variant>]``, for a kind that whitens some factors by data
  (:meth:`~excite.factors.base.Kind.whitening`): the same rows, not whitened;
- ``step_<kind>``, ``step2_<kind>`` (two samples per call) and ``finish_<kind>``, for a kind
  that reads the IMU samples (:class:`~excite.factors.base.ReadsImu`): its fold over an
  interval's samples.

The kernels run over batches of factors (``lin``, ``raw``, ``step2``) are also written as
``<name>_x4``: the same statements on four factors at once (:func:`batched`), which the drivers
run where a kernel has them.

A kind registered from outside excite, or an entry whose variant is not compiled in, is generated
the same way on demand (:func:`on_demand`): one kernel, compiled with the system C compiler into
the cache (a fraction of a second), keyed by its source.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import re
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca

from . import base as registry
from . import symbolic
from .base import Kind, RigView
from .layout import KEYFRAME_INPUTS, Layout, constant_inputs, constant_values, input_sizes, layout

HERE = Path(__file__).resolve().parent
TARGET = HERE / "generated.c"
FLAGS = ("-O3", "-fPIC", "-shared", "-fno-math-errno")

def instances(rig: RigView) -> list[tuple[Kind, Any]]:
    """Every (kind, entry) of ``rig``, and the opening of every kind that opens a chain."""
    return [(i.kind, i.entry) for i in (*registry.instances(rig), *registry.openings(rig))]


def whitens_by_data(kind: Kind) -> bool:
    """Whether ``kind`` whitens some factors by data (and so has a ``raw`` kernel)."""
    return type(kind).whitening is not Kind.whitening


class _Unread:
    """What a kernel generated for every entry of a variant offers as ``f.entry`` and ``f.rig``:
    nothing (the math reads its numbers through :meth:`~excite.factors.base.Kind.constants`)."""

    def __init__(self, kind: Kind, what: str):
        self._kind, self._what = kind.name, what

    def __getattr__(self, attr: str):
        raise TypeError(f"{self._kind}'s math reads f.{self._what}.{attr}: declare the numbers it reads in "
                        f"{self._kind}.constants() (f.c[...]) so that one kernel serves every entry")


def functions(kind: Kind, lay: Layout, what: str, entry: Any = None, rig: RigView | None = None) -> ca.Function:
    """The CasADi function of the kernel ``what`` of ``kind`` with layout ``lay`` (constants as
    inputs; ``entry`` and ``rig`` for math that reads them directly, generated for that entry
    only)."""
    name = lay.name(what)
    c = ca.SX.sym("c", lay.n_constants)
    cv = c
    if entry is None:
        entry, rig = _Unread(kind, "entry"), _Unread(kind, "rig")
    else:  # generated for this entry: its constants' values in the code (math may treat them as numbers)
        cv = ca.DM(constant_inputs(lay, constant_values(kind, rig, entry)))
    if what == "step":
        state, R_i, R_s, f_s = ca.SX.sym("state", lay.n_state), ca.SX.sym("R_i", 9), ca.SX.sym("R_s", 9), ca.SX.sym("f_s", 3)
        consts = symbolic.unflatten(cv, lay.constants)
        out = kind.summary_step(state, symbolic.mat(R_i), symbolic.mat(R_s), f_s, consts)
        return ca.Function(name, [state, R_i, R_s, f_s, c], [ca.densify(out)], {"cse": True})
    if what == "step2":  # two samples per call (s, then s − 1): half the state written and read
        state, R_i = ca.SX.sym("state", lay.n_state), ca.SX.sym("R_i", 9)
        R_a, f_a, R_b, f_b = ca.SX.sym("R_a", 9), ca.SX.sym("f_a", 3), ca.SX.sym("R_b", 9), ca.SX.sym("f_b", 3)
        consts = symbolic.unflatten(cv, lay.constants)
        mid = kind.summary_step(state, symbolic.mat(R_i), symbolic.mat(R_a), f_a, consts)
        out = kind.summary_step(mid, symbolic.mat(R_i), symbolic.mat(R_b), f_b, consts)
        return ca.Function(name, [state, R_i, R_a, f_a, R_b, f_b, c], [ca.densify(out)], {"cse": True})
    if what == "finish":
        state, R_i, R_j = ca.SX.sym("state", lay.n_state), ca.SX.sym("R_i", 9), ca.SX.sym("R_j", 9)
        consts = symbolic.unflatten(cv, lay.constants)
        summary = kind.summary_finish(state, symbolic.mat(R_i), symbolic.mat(R_j), consts)
        flat = ca.vertcat(*(ca.vec(summary[k].T) for k, _ in kind.summary_fields))
        return ca.Function(name, [state, R_i, R_j, c], [ca.densify(flat)], {"cse": True})
    xs = [ca.SX.sym(f"x{a}", KEYFRAME_INPUTS) for a in range(lay.arity)]
    s = ca.SX.sym("s", lay.n_summary)
    q = ca.SX.sym("q", lay.n_entry_quantities)
    Jx, Jt = symbolic.derivatives(kind, lay, ca.vertcat(*xs), s, quantity_values(lay, q), cv, whitened=what == "lin",
                                  entry=entry, rig=rig, from_samples=False)
    return ca.Function(name, [*xs, s, q, c], [ca.densify(Jx.T), ca.densify(Jt.T)], {"cse": True})


def quantity_values(lay: Layout, q) -> Any:
    """Every quantity's value for the statement: the entry's own from the input ``q``, the others
    their nominal value (a constant of the kernel)."""
    parts, o = [], 0
    for qt in lay.quantities:
        size = qt.nominal_vector().size
        if qt.per_entry:
            parts.append(q[o:o + size])
            o += size
        else:
            parts.append(ca.DM(qt.nominal_vector()))
    return ca.vertcat(*parts) if parts else ca.DM(0, 1)


def kernels_of(kind: Kind, lay: Layout) -> list[str]:
    """The kernels an entry of ``kind`` with layout ``lay`` needs."""
    return (["lin"] + (["raw"] if whitens_by_data(kind) else []) +
            (["step", "step2", "finish"] if lay.n_summary else []))


@dataclass(frozen=True)
class Spec:
    """One kernel to generate: ``what`` of ``kind`` with layout ``lay``, and an entry of an example
    rig it serves (the tests evaluate it there)."""

    kind: Kind
    lay: Layout
    what: str
    rig: RigView
    entry: Any


def specs_of(rigs) -> dict[str, Spec]:
    """name → :class:`Spec` of every kernel the entries of ``rigs`` call for, in a fixed order."""
    out: dict[str, Spec] = {}
    for rig in rigs:
        for kind, entry in instances(rig):
            lay = layout(kind, rig, entry)
            for what in kernels_of(kind, lay):
                name = lay.name(what)
                other = out.get(name)
                if other is not None and input_sizes(other.lay, what) != input_sizes(lay, what):
                    raise ValueError(f"{name}: two entries of one variant have statements of different sizes: "
                                     f"make what changes them part of {kind.name}'s variant")
                out.setdefault(name, Spec(kind, lay, what, rig, entry))
    return dict(sorted(out.items()))


HEADER = """/* Generated by excite.factors.generate from the measurement kinds' statements
 * (excite/factors/*.py, differentiated by CasADi) for the rigs of excite/rig/kernels.py; compiled
 * with the package into excite._native. Do not edit: change a kind's statement and run
 * `python -m excite.rig.kernels` (tests/factors/test_generate.py regenerates this file and compares). */
"""


def source(kernels: dict[str, Spec], prefix: str = "generated") -> str:
    """The C source of ``kernels`` (:func:`specs_of`), with their table, and those that run over
    batches of factors (the Jacobians; the fold's ``step2``) also four factors at a time
    (:func:`batched`)."""
    fns = [functions(k.kind, k.lay, k.what) for k in kernels.values()]
    code = _codegen(fns, prefix)
    return HEADER + code + _table(fns) + batched(code, {f.name(): kernels[f.name()].what == "step2" for f in fns
                                                        if kernels[f.name()].what in ("lin", "raw", "step2")})


LANES = 4  # factors a batched kernel runs at once (the vector macros of BATCHED_PRELUDE are written for four)

# the statements of a CasADi-generated function of scalar arithmetic, each as its batched form
# (``\g<…>`` the statement's parts), every input gathered from the lanes' own, every output
# scattered to them; a fold's step has its input 0 and output 0 (the state) lane-interleaved
_STATE = [
    (r"  (?P<a>a\d+)=arg\[0\]\? arg\[0\]\[(?P<k>\d+)\] : 0;", r"  \g<a>=LOAD_V4(arg[0] + 4 * \g<k>);"),
    (r"  if \(res\[0\]!=0\) res\[0\]\[(?P<k>\d+)\]=(?P<a>a\d+);", r"  STORE_V4(res[0] + 4 * \g<k>, \g<a>);"),
]
_STATEMENTS = [
    (r"  casadi_real (?P<names>a\d+(, a\d+)*);", r"  v4 \g<names>;"),
    (r"  (?P<a>a\d+)=arg\[(?P<j>\d+)\]\? arg\[(?P=j)\]\[(?P<k>\d+)\] : 0;", r"  \g<a>=GATHER_V4(\g<j>, \g<k>);"),
    (r"  if \(res\[(?P<j>\d+)\]!=0\) res\[(?P=j)\]\[(?P<k>\d+)\]=(?P<a>a\d+);", r"  SCATTER_V4(\g<j>, \g<k>, \g<a>);"),
    (r"  (?P<a>a\d+)=\((?P<x>a\d+)(?P<op>[-+*/])(?P<y>a\d+)\);", r"  \g<a>=(\g<x>\g<op>\g<y>);"),
    (r"  (?P<a>a\d+)=\((?P<v>[0-9.]+(e[-+]\d+)?)(?P<op>[-+*/])(?P<y>a\d+)\);", r"  \g<a>=(BROADCAST_V4(\g<v>)\g<op>\g<y>);"),
    (r"  (?P<a>a\d+)=\((?P<x>a\d+)(?P<op>[-+*/])(?P<v>[0-9.]+(e[-+]\d+)?)\);", r"  \g<a>=(\g<x>\g<op>BROADCAST_V4(\g<v>));"),
    (r"  (?P<a>a\d+)=\(-(?P<x>a\d+)\);", r"  \g<a>=(-\g<x>);"),
    (r"  (?P<a>a\d+)=casadi_sq\((?P<x>a\d+)\);", r"  \g<a>=(\g<x>*\g<x>);"),
    (r"  (?P<a>a\d+)=sqrt\((?P<x>a\d+)\);", r"  \g<a>=SQRT_V4(\g<x>);"),
    (r"  (?P<a>a\d+)=(?P<v>-?[0-9.]+(e[-+]\d+)?);", r"  \g<a>=BROADCAST_V4(\g<v>);"),
    (r"  return 0;", r"  return 0;"),
]

BATCHED_PRELUDE = """
/* Kernels run on 4 factors at once: the same statements on vectors of one number per factor (the
 * same arithmetic on each, rounded alike: the numbers of the kernel run on each factor alone).
 * arg[4·j + l] is input j of factor l, res[4·j + l] its output j; but a fold's step (state 1 in
 * excite_batched) has input 0 and output 0, the state, as one array each of the 4 factors' states
 * interleaved (entry k of factor l at 4·k + l). */
typedef double v4 __attribute__((vector_size(32)));
#define LOAD_V4(p) ({ v4 v_; memcpy(&v_, (p), sizeof v_); v_; })
#define STORE_V4(p, v) do { v4 v_ = (v); memcpy((p), &v_, sizeof v_); } while (0)
#define GATHER_V4(j, k) ((v4){arg[4 * (j)][k], arg[4 * (j) + 1][k], arg[4 * (j) + 2][k], arg[4 * (j) + 3][k]})
#define SCATTER_V4(j, k, v) \\
    do { v4 v_ = (v); res[4 * (j)][k] = v_[0], res[4 * (j) + 1][k] = v_[1], res[4 * (j) + 2][k] = v_[2], res[4 * (j) + 3][k] = v_[3]; } while (0)
#define SQRT_V4(x) ({ v4 x_ = (x); (v4){sqrt(x_[0]), sqrt(x_[1]), sqrt(x_[2]), sqrt(x_[3])}; })
#define BROADCAST_V4(x) ((v4){x, x, x, x})
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__GLIBC__)
#define BATCHED __attribute__((target_clones("avx2", "default")))
#else
#define BATCHED
#endif
"""


def batched(code: str, kernels: dict[str, bool]) -> str:
    """C of the ``kernels`` of the CasADi-generated ``code`` (name → whether it is a fold's step,
    whose state is interleaved) run on :data:`LANES` factors at once (``<name>_x4``, see
    :data:`BATCHED_PRELUDE`), and their table (``excite_batched``). A kernel with a statement
    :data:`_STATEMENTS` does not know is left out (its factors run one at a time)."""
    out = []
    for name, state in kernels.items():
        inner = re.search(rf"int {name}\(const casadi_real\*\* arg.*?return (casadi_f\d+)\(", code, re.S).group(1)
        body = re.search(rf"static int {inner}\(.*?\) {{\n(.*?)\n}}\n", code, re.S).group(1)
        statements = (_STATE if state else []) + _STATEMENTS
        lines = []
        for line in body.split("\n"):
            for pattern, repl in statements:
                m = re.fullmatch(pattern, line)
                if m:
                    lines.append(m.expand(repl))
                    break
            else:
                break
        else:
            out.append((name, state, f"BATCHED static int {name}_x{LANES}(const double **arg, double **res) {{\n" +
                        "\n".join(lines) + "\n}\n"))
    table = [f'    {{"{n}", (void *){n}_x{LANES}, {int(state)}}},' for n, state, _ in out] or ["    {0},"]
    return ("\n#include <string.h>\n" + BATCHED_PRELUDE + "\n" + "\n".join(c for _, _, c in out) +
            f"\nconst excite_batched_kernel excite_batched[{max(len(out), 1)}] = {{\n" + "\n".join(table) +
            f"\n}};\nconst int excite_n_batched = {len(out)};\n")


def _codegen(fns: list[ca.Function], prefix: str) -> str:
    cg = ca.CodeGenerator(f"{prefix}.c", {"with_header": False, "with_mem": False})
    for f in fns:
        cg.add(f)
    return cg.dump()


def _table(fns: list[ca.Function]) -> str:
    lines = ['\n#include "generated.h"\n']
    for f in fns:
        n = f.name()
        lines.append(f"static const long long {n}_nnz_in[] = {{{', '.join(str(f.nnz_in(i)) for i in range(f.n_in()))}}};")
        lines.append(f"static const long long {n}_nnz_out[] = {{{', '.join(str(f.nnz_out(i)) for i in range(f.n_out()))}}};")
    lines.append(f"\nconst excite_kernel excite_kernels[{max(len(fns), 1)}] = {{")
    for f in fns:
        n = f.name()
        lines.append(f'    {{"{n}", (void *){n}, (void *){n}_work, {f.n_in()}, {f.n_out()}, {n}_nnz_in, {n}_nnz_out}},')
    if not fns:
        lines.append("    {0},")
    lines.append("};")
    lines.append(f"const int excite_n_kernels = {len(fns)};\n")
    return "\n".join(lines)


# --- on demand ----------------------------------------------------------------------------------

_LOADED: dict[tuple, Any] = {}
_LOCK = threading.Lock()


def on_demand(kind: Kind, rig: RigView, entry: Any, what: str) -> tuple[tuple[int, int], tuple, tuple] | None:
    """The kernel ``what`` of ``entry`` generated now and compiled into the cache (loaded from it
    when it is there): ``((address of f, address of f_work), input sizes, output sizes)``; None
    where no C compiler is found or compiling is disabled (``EXCITE_COMPILE=0``)."""
    from ..core.native import cache_dir

    lay = layout(kind, rig, entry)
    with symbolic.LOCK:
        fn = functions(kind, lay, what, entry, rig)
        code = "/* generated on demand by excite.factors.generate */\n" + _codegen([fn], "on_demand")
    lib = cache_dir() / "kernels" / f"{fn.name()}_{hashlib.sha256((code + repr(FLAGS)).encode()).hexdigest()[:24]}.so"
    key = str(lib)
    with _LOCK:
        if key in _LOADED:
            return _LOADED[key]
        if not lib.exists():
            cc = _compiler()
            if cc is None:
                return None
            compile_source(code, lib, cc)
        dll = ctypes.CDLL(str(lib))
        address = (ctypes.cast(getattr(dll, fn.name()), ctypes.c_void_p).value,
                   ctypes.cast(getattr(dll, f"{fn.name()}_work"), ctypes.c_void_p).value)
        sizes = (tuple(fn.nnz_in(i) for i in range(fn.n_in())), tuple(fn.nnz_out(i) for i in range(fn.n_out())))
        _LOADED[key] = (address, *sizes)
        _LOADED[(key, "dll")] = dll  # kept loaded with the addresses
        return _LOADED[key]


def _compiler() -> str | None:
    if os.environ.get("EXCITE_COMPILE", "1").strip().lower() in ("0", "no", "false", "off"):
        return None
    from ..core.native import compiler

    try:
        return compiler()
    except ImportError:
        return None


def compile_source(code: str, lib: Path, cc: str) -> None:
    """Compile C ``code`` into the shared library ``lib`` (written whole, then moved into place)."""
    from ..core.native import run_compiler

    lib.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=lib.parent) as tmp:
        src = Path(tmp) / "kernel.c"
        src.write_text(code)
        out = Path(tmp) / lib.name
        try:
            done = run_compiler([cc, *FLAGS, str(src), "-o", str(out), "-lm"])
        except ImportError as exc:
            raise RuntimeError(f"compiling a generated kernel failed: {exc}") from None
        if done.returncode != 0:
            raise RuntimeError(f"compiling a generated kernel failed:\n{done.stderr[-2000:]}")
        os.replace(out, lib)
