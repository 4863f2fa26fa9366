"""The evaluator's whitened Jacobians, from kernels generated from the kinds' statements.

Every kind states its math once (:mod:`excite.factors.symbolic`); :mod:`excite.factors.generate`
turns the derivative of that statement into C, which is compiled with the package into
:mod:`excite.core.native` and run here over every factor of an entry at once
(:func:`jacobians`). No CasADi is imported on this path.

A kernel ``lin_<kind>_<variant>`` takes, per factor, the inputs of each of its keyframes (``x``:
``[vec R (9, row-major), p, v, ω, vec R_V_A]``, rows of a table of every keyframe's,
:meth:`~excite.factors.base.Nominal.keyframe_table`) and, for a kind that reads the IMU samples,
the summary of its interval's samples (``s``: the kind's fold over them, a second generated pair
of kernels, ``step_<kind>`` and ``finish_<kind>``); and, shared by all factors, the nominal values
of the entry's quantities that are the entry's own (``q``: a rotation's 9 entries, a vector's 3, a
scalar; the others, :attr:`~excite.factors.base.Quantity.per_entry` False, are constants of the
kernel) and the constants its math reads (``c``: :meth:`~excite.factors.base.Kind.constants`,
then the rig's common ones, :data:`COMMON`). It returns ``Jx`` (rows × 9 per keyframe, world
states ``[δθ, δp, δv]``) and ``Jt`` (rows × every coordinate of every quantity, estimated or not;
the estimated ones are picked here), both row-major.

A kind that whitens some factors by data (:meth:`~excite.factors.base.Kind.whitening`: a
reported covariance, a scene's information) has a second kernel ``raw_<kind>_<variant>`` whose
rows are not whitened: the factor's ``W_n`` (``W_nᵀW_n = Λ_n``, rows of zeros allowed) is
applied to them here.

A kind whose (kind, variant) has no kernel compiled in — a kind registered from outside excite,
or one added since the package was built — is generated and compiled on demand where a C
compiler is found (:func:`excite.factors.generate.on_demand`: a fraction of a second, cached by
the generated source), and otherwise evaluated in CasADi's virtual machine
(:func:`excite.factors.symbolic.blocks`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.native import module
from . import base
from .base import FactorBlock, Kind, Nominal, RigView, theta_columns
from .layout import (Layout, constant_inputs, constant_values, coordinate_names, input_sizes, layout, output_size,
                     quantity_inputs)

# --- running the kernels ----------------------------------------------------------------------

_COMPILED: dict[str, tuple[tuple[int, ...], tuple[int, ...]]] | None = None


def compiled() -> dict[str, tuple[tuple[int, ...], tuple[int, ...]]]:
    """The kernels compiled into the native module: name → (sizes of the inputs, of the outputs)."""
    global _COMPILED
    if _COMPILED is None:
        _COMPILED = module().generated()
    return _COMPILED


def kernel(lay: Layout, what: str, kind: Kind, rig: RigView, entry: Any) -> tuple[Any, tuple, tuple] | None:
    """The kernel ``what`` of an entry and the sizes of its inputs and outputs: its name where it
    is compiled in, the address pair of one compiled on demand, or None (CasADi's virtual
    machine then)."""
    name = lay.name(what)
    sizes = compiled().get(name)
    if sizes is None:
        from .generate import on_demand  # CasADi and the compiler: only for a kind without a compiled kernel

        return on_demand(kind, rig, entry, what)
    expected = input_sizes(lay, what), output_size(lay, what)
    if sizes[0] != expected[0] or (expected[1] is not None and sizes[1][0] != expected[1]):
        raise RuntimeError(f"the compiled kernel {name} has inputs and outputs of sizes {sizes}, the statement of this "
                           f"entry {expected}: regenerate the kernels (python -m excite.rig.kernels)")
    return name, sizes[0], sizes[1]


def summaries(nom: Nominal, first: np.ndarray, lay: Layout, fold, c: np.ndarray) -> np.ndarray:
    """The summary of the IMU samples of every interval starting at keyframes ``first``
    (N × n_summary): the kind's fold over them (its kernels ``fold = (step, step2, finish)``),
    from the last sample to the first."""
    out = np.empty((first.size, lay.n_summary))
    module().fold(*fold, np.ascontiguousarray(first, dtype=np.int64), nom.imu_per_keyframe, lay.n_samples,
                  lay.n_state, np.ascontiguousarray(nom.imu_R), np.ascontiguousarray(nom.imu_f), c, out)
    return out


def jacobians(kind: Kind, nom: Nominal, rig: RigView, entry: Any) -> FactorBlock | None:
    """The whitened Jacobians (world states) of every factor of ``entry`` on ``nom``, from its
    kind's generated kernel; None if the drive holds no factor of it."""
    first = base.factor_keyframes(kind, rig, entry, nom.n_keyframes, nom)
    if first.size == 0:
        return None
    lay = layout(kind, rig, entry)
    stride = base.stride(kind, rig, entry)
    W = kind.whitening(nom, rig, entry, first)
    what = "lin" if W is None else "raw"
    lin = kernel(lay, what, kind, rig, entry)
    fold = tuple(kernel(lay, w, kind, rig, entry) for w in ("step", "step2", "finish")) if lay.n_summary else None
    if lin is None or (fold is not None and None in fold):
        from . import symbolic  # no compiled kernel and no compiler: CasADi's virtual machine

        return symbolic.blocks(kind, nom, rig, entry, whitening=W)
    c = constant_inputs(lay, constant_values(kind, rig, entry))
    s = summaries(nom, first, lay, tuple(k[0] for k in fold), c) if fold else np.zeros((first.size, 0))
    q = quantity_inputs(lay, per_entry=True)
    N, nx, nt = first.size, 9 * lay.arity, lay.n_coordinates
    rows = lin[2][0] // nx
    Jx, Jt = np.empty((N, rows, nx)), np.empty((N, rows, nt))
    table = nom.keyframe_table
    first = np.ascontiguousarray(first, dtype=np.int64)
    module().run(lin[0], first, (table,) * lay.arity + (s, q, c), tuple(a * stride for a in range(lay.arity)) + (-2, -1, -1),
                 (Jx, Jt))
    if W is not None:
        Jx, Jt = W @ Jx, W @ Jt
    estimated = lay.estimated_columns()
    if estimated.size < Jt.shape[2]:  # (np.take copies once into C order; fancy indexing twice)
        Jt = np.take(Jt, estimated, axis=2)
    cols = theta_columns(rig, coordinate_names(lay)) if lay.n_theta else np.zeros(0, dtype=int)
    return FactorBlock(base.block_name(kind, entry), first, stride, lay.arity, Jx, Jt, cols)
