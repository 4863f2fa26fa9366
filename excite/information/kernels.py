"""The information's inner loops (C: ``information/kernels.c`` of :mod:`excite.core.native`):
``JᵀJ`` of factor blocks accumulated into the band of keyframe blocks, its elimination (block
Cholesky, slab by slab for the sweeps), the diagonal of H_θθ, and the world-to-local change of the
trajectory states. The math is stated here and at the call sites
(:mod:`excite.information.problem`, :mod:`excite.information.elimination`); the tests hold it to
the dense numpy marginal. Every function takes C-contiguous float64 (and int64 index) arrays and
writes into the arrays it is given, the loops running without the GIL."""

from __future__ import annotations

import numpy as np

from ..core.native import module

# loaded with this module, not at the first call: a process that limits its address space after
# its imports (a live session's) has it mapped already
module()


def accumulate(Jx, Jt, cols, first, stride, n_states, band, Hxt, Htt, f0, f1, origin, sign, xc, comp) -> None:
    """Add ``JᵀJ`` of the factors ``f0 … f1−1`` of a stack to a block-banded information matrix.

    Factor ``f`` touches the ``n_states`` keyframes ``first[f] + stride · a`` (xd = nx/n_states
    columns each of ``Jx[f]``: the first xd ≤ sd components of each state, sd the state dimension:
    a factor that does not see the bias states leaves them out) and the calibration columns
    ``cols`` (``Jt[f]``); of ``Jx`` only the columns ``xc`` (increasing) are read, every other one
    being zero (``FactorBlock.xcols``). Keyframe k is stored at position ``origin + sign · k``
    (sign ±1: a window of the keyframes, in either order). Storage: ``band[d, j] = H[x_{j+d}, x_j]``
    (sd × sd, positions; of the diagonal blocks d = 0 the lower triangle only, all that
    :func:`eliminate` reads), ``Hxt[i] = H[x_i, θ]`` (sd × p), ``Htt = H_θθ``; a state's component
    c is stored as component ``comp[c]`` (a permutation of 0 … sd−1: see :func:`eliminate_slabs`).

    Per factor, ``G = [Jt Jxc]ᵀ[Jt Jxc]`` (lower triangle): the calibration columns first, then the
    columns ``xc`` of the factor's states in the order of their positions (state a is state a of G
    for sign > 0, state ns−1−a for sign < 0), so that each block added below is a run of contiguous
    entries in a row of G and in a row of its destination. The sums are those over the full columns
    in the factor's own order, bit for bit (the same rows in the same order, each product commuted;
    a zero column adds exact zeros)."""
    module().accumulate(Jx, Jt, _i(cols), _i(first), int(stride), int(n_states), band, Hxt, Htt, int(f0), int(f1),
                        int(origin), int(sign), _i(xc), _i(comp))


def eliminate_slabs(blocks, m, slab, forward, band, Hxt, Htt, w2, anchored, comp) -> int:
    """The slab loop of :func:`excite.information.elimination.eliminated` (documented there): the
    factors of ``blocks`` (a tuple of ``(Jx, Jt, cols, first, stride, n_states, xcols)``, keyframe
    indices 0 … m of a chunk: :func:`excite.information.elimination.as_kernel_blocks`) are accumulated and eliminated ``slab`` keyframes at a time in the
    ring buffer ``band, Hxt`` (``slab + D`` positions, D the widest factor's span; position 0
    holds what is carried in), in the sweep's order; with random-walk biases (``w2``: 1/σ² of a
    step's six components; empty without) the walk's information is added on the bias deviations'
    diagonals. A state's component c is stored as component ``comp[c]`` (the ring's order; the bias
    deviations, if any, stored contiguously). Returns −1, or the keyframe (0 … m) whose pivot
    failed (:func:`eliminate`)."""
    return module().eliminate_slabs(blocks, int(m), int(slab), bool(forward), band, Hxt, Htt,
                                    np.ascontiguousarray(w2, dtype=float), bool(anchored), _i(comp))


def theta_diagonal(blocks, p: int) -> np.ndarray:
    """diag H_θθ = Σ Jt² per calibration column of the factors of ``blocks`` (as for
    :func:`eliminate_slabs`)."""
    out = np.zeros(p)
    module().theta_diagonal(blocks, out)
    return out


def eliminate(band, Hxe, Hee, lo, hi) -> int:
    """Eliminate the states ``lo … hi−1`` of a block-banded system with a border, in order (block
    Cholesky).

    ``band[d, j] = H[x_{j+d}, x_j]`` (sd × sd blocks, d ≤ D), the border ``Hxe[j] = H[x_j, e]``
    (sd × q) and ``Hee = H_ee`` are updated in place to the Schur complement on the remaining
    states and e (diagonal blocks are updated on their lower triangle, which is all the Cholesky
    factorisation reads; those of the remaining states are made symmetric at the end). Returns −1,
    or the first state whose pivot block is not positive definite (to rounding: a pivot below
    ``_PIVOT_RTOL`` of its diagonal entry)."""
    return module().eliminate(band, Hxe, Hee, int(lo), int(hi))


def local_maps(R, v, p) -> tuple[np.ndarray, np.ndarray]:
    """The maps ``V, P`` (K × 3 × 6) of :func:`excite.information.problem.to_local` from the keyframes'
    orientation, world velocity and position: ``V_k = [−R_k[v_k]×, R_k]`` with the body velocity
    ``v_k = R_kᵀ v``, ``P_k = [−R_k[d_k]×, R_k]`` with the increment ``d_k = R_kᵀ(p_{k+1} − p_k)``
    (zero for the last keyframe, which has none)."""
    K = R.shape[0]
    V, P = np.empty((K, 3, 6)), np.empty((K, 3, 6))
    module().local_maps(_f(R), _f(v), _f(p), V, P)
    return V, P


def to_local(Jx, first, stride, V, P, sd, Jt, copied=((), ())) -> tuple[np.ndarray, np.ndarray]:
    """World-state Jacobians ``Jx`` (N × r × 9·n_states) of factors at keyframes ``first + stride·a``
    re-expressed in local states over every keyframe they span (N × r × sd·(span + 1): sd ≥ 9
    columns per state, the 9 trajectory states first, any further ones zero but for ``copied``);
    the maps ``V, P`` (K × 3 × 6) and the formula are those of
    :func:`excite.information.problem.to_local`. ``copied = (from, to)``: columns ``from`` of the
    factors' ``Jt`` (N × r × c) copied into columns ``to`` (≥ 9) of their first state. Also returns
    which of those columns it wrote a non-zero to, or copied into (every other column is zero for
    every factor: a factor that sees no velocity, the increments after its last keyframe)."""
    N, r, nx = Jx.shape
    span = stride * (nx // 9 - 1)
    out = np.empty((N, r, sd * (span + 1)))
    seen = np.zeros(sd * (span + 1), dtype=np.int64)
    module().to_local(_f(Jx), _i(first), int(stride), _f(V), _f(P), out, seen, _f(Jt), _i(copied[0]), _i(copied[1]))
    return out, seen.astype(bool)


def _f(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float)


def _i(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=np.int64)
