"""Compiled inner loops of the information (numba): ``JᵀJ`` of factor blocks accumulated into
the band of keyframe blocks, its elimination (block Cholesky, slab by slab for the sweeps), the
diagonal of H_θθ, and the world-to-local change of the trajectory states. The math is stated at
the call sites (:mod:`excite.information.problem`, :mod:`excite.information.elimination`); the
tests hold it to the dense numpy marginal."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..core.kernels import tmulv

# a pivot below this fraction of its diagonal entry has lost every digit to cancellation: the
# keyframe's state is undetermined (or nearly so) beyond the gauge
_PIVOT_RTOL = 1e-12


@nb.njit(cache=True, nogil=True)
def accumulate(Jx, Jt, cols, first, stride, n_states, band, Hxt, Htt, f0, f1, origin, sign, xc, comp):
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
    N, r, nx = Jx.shape
    ns = n_states
    xd = nx // ns
    if xd > band.shape[2] or comp.size != band.shape[2]:
        raise ValueError("a factor's states are wider than the information matrix's")
    c = Jt.shape[2]
    nxc = xc.size
    M = nxc + c
    # G's column c + u is column gx[u] of Jx: component gc[u] of G's state gg[u]
    gx = np.empty(nxc, dtype=np.int64)
    gg = np.empty(nxc, dtype=np.int64)
    gc = np.empty(nxc, dtype=np.int64)
    u = 0
    for g in range(ns):
        a = g if sign > 0 else ns - 1 - g
        u0 = u
        for t in range(nxc):
            if xc[t] // xd == a:  # the state's columns, in the order of their stored components
                x, cc = xc[t], comp[xc[t] - xd * a]
                i = u
                while i > u0 and gc[i - 1] > cc:
                    gx[i], gc[i] = gx[i - 1], gc[i - 1]
                    i -= 1
                gx[i], gc[i], gg[u] = x, cc, g
                u += 1
    # runs of consecutive components of one state: its G state, first component, first G column, length
    run_g = np.empty(nxc, dtype=np.int64)
    run_c = np.empty(nxc, dtype=np.int64)
    run_u = np.empty(nxc, dtype=np.int64)
    run_n = np.zeros(nxc, dtype=np.int64)
    n_runs = 0
    for u in range(nxc):
        if u == 0 or gg[u] != gg[u - 1] or gc[u] != gc[u - 1] + 1:
            run_g[n_runs] = gg[u]
            run_c[n_runs] = gc[u]
            run_u[n_runs] = c + u
            n_runs += 1
        run_n[n_runs - 1] += 1
    w = np.empty((3, M))
    G = np.empty((M, M))
    T = np.zeros((c, c))
    pos = np.empty(ns, dtype=np.int64)
    for f in range(f0, f1):
        for u in range(M):
            for v in range(u + 1):
                G[u, v] = 0.0
        for row0 in range(0, r, 3):
            nr = min(3, r - row0)
            w[:] = 0.0
            for k in range(nr):
                Jr = Jx[f, row0 + k]
                for u in range(c):
                    w[k, u] = Jt[f, row0 + k, u]
                for u in range(nxc):
                    w[k, c + u] = Jr[gx[u]]
            w0, w1, w2 = w[0], w[1], w[2]
            for u in range(M):
                a0, a1, a2 = w0[u], w1[u], w2[u]
                if a0 != 0.0 or a1 != 0.0 or a2 != 0.0:
                    for v in range(u + 1):
                        G[u, v] += a0 * w0[v] + a1 * w1[v] + a2 * w2[v]
        for g in range(ns):
            a = g if sign > 0 else ns - 1 - g
            pos[g] = origin + sign * (first[f] + stride * a)
        for A in range(n_runs):
            gA, cA, uA, nA = run_g[A], run_c[A], run_u[A], run_n[A]
            iA = pos[gA]
            for B in range(A + 1):  # a run of the same state or an earlier one (position iA − d)
                gB, cB, uB, nB = run_g[B], run_c[B], run_u[B], run_n[B]
                d = stride * (gA - gB)
                blk = band[d, iA - d]
                for uu in range(nA):
                    Gu = G[uA + uu]
                    bu = blk[cA + uu]
                    top = uu + 1 if B == A else nB
                    for vv in range(top):
                        bu[cB + vv] += Gu[uB + vv]
            for uu in range(nA):
                Gu = G[uA + uu]
                Hu = Hxt[iA, cA + uu]
                for v in range(c):
                    Hu[cols[v]] += Gu[v]
        for u in range(c):
            for v in range(u + 1):
                T[u, v] += G[u, v]
    for u in range(c):
        for v in range(u):
            Htt[cols[u], cols[v]] += T[u, v]
            Htt[cols[v], cols[u]] += T[u, v]
        Htt[cols[u], cols[u]] += T[u, u]


@nb.njit(cache=True, nogil=True)
def eliminate_slabs(blocks, m, slab, forward, band, Hxt, Htt, w2, anchored, comp):
    """The slab loop of :func:`excite.information.elimination.eliminated` (documented there), compiled: the
    factors of ``blocks`` (a tuple of ``(Jx, Jt, cols, first, stride, n_states, xcols)``, keyframe
    indices 0 … m of a chunk: :func:`excite.information.elimination.as_kernel_blocks`) are accumulated and eliminated ``slab`` keyframes at a time in the
    ring buffer ``band, Hxt`` (``slab + D`` positions, D the widest factor's span; position 0
    holds what is carried in), in the sweep's order; with random-walk biases (``w2``: 1/σ² of a
    step's six components; empty without) the walk's information is added on the bias deviations'
    diagonals. A state's component c is stored as component ``comp[c]`` (the ring's order; the bias
    deviations, if any, stored contiguously). Returns −1, or the keyframe (0 … m) whose pivot
    failed (:func:`eliminate`)."""
    D = band.shape[0] - 1
    sd = band.shape[2]
    n_slabs = (m + slab - 1) // slab
    edge = np.empty(n_slabs + 1, dtype=np.int64)
    for i in range(n_slabs):
        edge[i] = i * slab
    edge[n_slabs] = m + 1
    # per block, the factors whose first keyframe in the sweep's order is in each slab: f0 … f1−1
    # (the last slab also takes those at m); blocks list their factors by first keyframe
    bounds = np.empty((len(blocks), n_slabs + 1), dtype=np.int64)
    for bi in range(len(blocks)):
        first, span = blocks[bi][3], blocks[bi][4] * (blocks[bi][5] - 1)
        for i in range(n_slabs + 1):
            bounds[bi, i] = (np.searchsorted(first, edge[i]) if forward else
                             np.searchsorted(first, m - span - edge[i], side="right"))
    o = comp[9] if sd > 9 else 9  # the bias deviations' first stored component (information.BIAS)
    for i in range(n_slabs):
        s = i * slab
        hi = min(s + slab, m)
        for bi in range(len(blocks)):
            Jx, Jt, cols, first, stride, ns, xc = blocks[bi]
            f0, f1 = (bounds[bi, i], bounds[bi, i + 1]) if forward else (bounds[bi, i + 1], bounds[bi, i])
            if f1 > f0:
                accumulate(Jx, Jt, cols, first, stride, ns, band, Hxt, Htt, f0, f1, -s if forward else m - s,
                           1 if forward else -1, xc, comp)
        if w2.size:  # the steps whose first keyframe in the sweep's order is in the slab: positions
            # 0 … n−1 of the ring to 1 … n (either direction), less a step into the drive's end
            n_steps = hi - s if forward else m - s - max(0, m - edge[i + 1])
            cut = anchored and (hi == m if forward else s == 0)
            lo = 1 if cut and not forward else 0
            n_in = n_steps - 1 if cut and forward else n_steps
            a0 = 0 if forward else 1
            for j in range(a0, n_steps + a0):
                for c in range(6):
                    band[0, j, o + c, o + c] += w2[c]
            for j in range(1 - a0 + lo, 1 - a0 + n_in):
                for c in range(6):
                    band[0, j, o + c, o + c] += w2[c]
            for j in range(lo, n_in):
                for c in range(6):
                    band[1, j, o + c, o + c] -= w2[c]
        if D == 1 and sd == 15:  # random-walk biases, consecutive keyframes: sizes known to the compiler
            bad = _eliminate(band, Hxt, Htt, 0, hi - s, 1, 15)
        elif D == 1 and sd == 9:  # constant biases
            bad = _eliminate(band, Hxt, Htt, 0, hi - s, 1, 9)
        else:
            bad = eliminate(band, Hxt, Htt, 0, hi - s)
        if bad >= 0:
            return s + bad if forward else m - s - bad
        if hi < m:  # the keyframes the next slab shares move to the ring's front
            k = hi - s
            band[:, :D] = band[:, k:k + D]
            band[:, D:] = 0.0
            Hxt[:D] = Hxt[k:k + D]
            Hxt[D:] = 0.0
    return -1


@nb.njit(cache=True, nogil=True)
def theta_diagonal(blocks, p):
    """diag H_θθ = Σ Jt² per calibration column of the factors of ``blocks`` (as for
    :func:`eliminate_slabs`)."""
    out = np.zeros(p)
    for bi in range(len(blocks)):
        Jt, cols = blocks[bi][1], blocks[bi][2]
        acc = np.zeros(Jt.shape[2])  # the block's columns (distinct), scattered at the end
        for f in range(Jt.shape[0]):
            for k in range(Jt.shape[1]):
                for u in range(Jt.shape[2]):
                    acc[u] += Jt[f, k, u] * Jt[f, k, u]
        for u in range(Jt.shape[2]):
            out[cols[u]] += acc[u]
    return out


@nb.njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _border_update(ZT, m, Hee):
    """``Hee −= ZT[:, :m] ZT[:, :m]ᵀ`` on the lower triangle: dot products of contiguous rows, which
    the compiler vectorises (reassociating the sums; no other fast-math licence)."""
    q = ZT.shape[0]
    for e in range(q):
        for e2 in range(e + 1):
            s = 0.0
            for k in range(m):
                s += ZT[e, k] * ZT[e2, k]
            Hee[e, e2] -= s


@nb.njit(cache=True, inline="always")
def _subtract_combination(x, c, Z, n, top):
    """``x[:top] −= Σ_{k<n} c[k] Z[k, :top]``, three rows of Z per pass over x (a third of the loads
    and stores of x; the inner loops run along rows), skipping three zero coefficients (with
    random-walk biases, C_1 = H[x_{j+1}, x_j] L⁻ᵀ has a zero block: no factor links the trajectory
    of one keyframe with the bias deviations of the next)."""
    k = 0
    while k + 3 <= n:
        c0, c1, c2 = c[k], c[k + 1], c[k + 2]
        if c0 != 0.0 or c1 != 0.0 or c2 != 0.0:
            for e in range(top):
                x[e] -= c0 * Z[k, e] + c1 * Z[k + 1, e] + c2 * Z[k + 2, e]
        k += 3
    while k < n:
        ck = c[k]
        for e in range(top):
            x[e] -= ck * Z[k, e]
        k += 1


@nb.njit(cache=True, inline="always")
def _solve_lower(L, inv, X):
    """``X ← L⁻¹ X`` for a lower triangular L (``inv``: the reciprocals of its diagonal), row by
    row (the inner loops run along rows of X)."""
    for row in range(X.shape[0]):
        _subtract_combination(X[row], L[row], X, row, X.shape[1])
        for e in range(X.shape[1]):
            X[row, e] *= inv[row]


@nb.njit(cache=True, nogil=True)
def eliminate(band, Hxe, Hee, lo, hi):
    """Eliminate the states ``lo … hi−1`` of a block-banded system with a border, in order (block
    Cholesky).

    ``band[d, j] = H[x_{j+d}, x_j]`` (sd × sd blocks, d ≤ D), the border ``Hxe[j] = H[x_j, e]``
    (sd × q) and ``Hee = H_ee`` are updated in place to the Schur complement on the remaining
    states and e (diagonal blocks are updated on their lower triangle, which is all the Cholesky
    factorisation reads; those of the remaining states are made symmetric at the end). Returns −1,
    or the first state whose pivot block is not positive definite (to rounding: a pivot below
    ``_PIVOT_RTOL`` of its diagonal entry)."""
    return _eliminate(band, Hxe, Hee, lo, hi, band.shape[0] - 1, band.shape[2])


@nb.njit(cache=True, inline="always")
def _eliminate(band, Hxe, Hee, lo, hi, D, sd):
    """:func:`eliminate` with the band's width D and the state dimension sd as arguments: inlined
    where they are constants (the common cases of :func:`eliminate_slabs`), the compiler sizes its
    loops for them."""
    n = band.shape[1]
    q = Hxe.shape[2]
    L = np.zeros((sd, sd))
    inv = np.empty(sd)  # 1 / diag L
    # per state, the right-hand sides of its one triangular solve, side by side: the transposed
    # blocks below it, then its border row (WZ[:, (d−1)·sd …] ← C_dᵀ = L⁻¹ H[x_j, x_{j+d}], WZ[:, D·sd …] ← Z_j)
    WZ = np.zeros((sd, D * sd + q))
    Zj = WZ[:, D * sd:]
    YX = np.zeros((sd, sd + q))  # with D = 1: the next state's [H[x_{j+1}, x_{j+1}] | H[x_{j+1}, e]]
    ZT = np.empty((q, 16 * sd))  # Z_jᵀ of the states eliminated since the last border update
    fill = 0
    for j in range(lo, hi):
        A = band[0, j]
        for col in range(sd):  # L Lᵀ = A
            for row in range(col, sd):
                s = A[row, col]
                for k in range(col):
                    s -= L[row, k] * L[col, k]
                if row == col:
                    if not s > _PIVOT_RTOL * A[col, col]:  # singular, or singular to rounding
                        return j
                    L[col, col] = np.sqrt(s)
                    inv[col] = 1.0 / L[col, col]
                else:
                    L[row, col] = s * inv[col]
        nd = min(D, n - 1 - j)
        for d in range(1, D + 1):
            Wd = WZ[:, (d - 1) * sd:d * sd]
            if d <= nd:
                B = band[d, j]
                for row in range(sd):
                    for k in range(sd):
                        Wd[k, row] = B[row, k]
            else:
                Wd[:] = 0.0
        Zj[:] = Hxe[j]
        _solve_lower(L, inv, WZ)  # C_dᵀ and Z_j = L⁻¹ Hxe[j] in one pass
        for k in range(sd):  # H_ee −= Z_jᵀ Z_j, batched over 16 states (lower triangle; mirrored at the end)
            for e in range(q):
                ZT[e, fill + k] = Zj[k, e]
        fill += sd
        if fill + sd > ZT.shape[1]:
            _border_update(ZT, fill, Hee)
            fill = 0
        if D == 1 and nd == 1:  # the next state's diagonal block and border row side by side, so that
            Y = band[0, j + 1]  # one pass per row updates both: [Y | X] −= C_1 [C_1ᵀ | Z_j]
            X = Hxe[j + 1]
            for row in range(sd):
                for e in range(sd):
                    YX[row, e] = Y[row, e]
                for e in range(q):
                    YX[row, sd + e] = X[row, e]
                _subtract_combination(YX[row], WZ[:, row], WZ, sd, sd + q)
                for e in range(row + 1):  # of Y the lower triangle
                    Y[row, e] = YX[row, e]
                for e in range(q):
                    X[row, e] = YX[row, sd + e]
        else:
            for d in range(1, nd + 1):  # C_d = H[x_{j+d}, x_j] L⁻ᵀ, kept transposed, so that every inner
                X = Hxe[j + d]  # loop below runs along a contiguous row: H[x_{j+d}, e] −= C_d Z_j
                Cd = WZ[:, (d - 1) * sd:d * sd]
                for row in range(sd):
                    _subtract_combination(X[row], Cd[:, row], Zj, sd, q)
                for d2 in range(d, nd + 1):  # H[x_{j+d2}, x_{j+d}] −= C_d2 C_dᵀ (a diagonal block: lower triangle)
                    Y = band[d2 - d, j + d]
                    C2 = WZ[:, (d2 - 1) * sd:d2 * sd]
                    for row in range(sd):
                        _subtract_combination(Y[row], C2[:, row], Cd, sd, row + 1 if d2 == d else sd)
    _border_update(ZT, fill, Hee)
    for e in range(q):
        for e2 in range(e):
            Hee[e2, e] = Hee[e, e2]
    for j in range(hi, min(hi + D, n)):  # the diagonal blocks that remain: mirror their lower triangle
        Y = band[0, j]
        for row in range(sd):
            for col in range(row):
                Y[col, row] = Y[row, col]
    return -1


@nb.njit(cache=True, nogil=True)
def local_maps(R, v, p):
    """The maps ``V, P`` (K × 3 × 6) of :func:`excite.information.problem.to_local` from the keyframes'
    orientation, world velocity and position: ``V_k = [−R_k[v_k]×, R_k]`` with the body velocity
    ``v_k = R_kᵀ v``, ``P_k = [−R_k[d_k]×, R_k]`` with the increment ``d_k = R_kᵀ(p_{k+1} − p_k)``
    (zero for the last keyframe, which has none)."""
    K = R.shape[0]
    V = np.empty((K, 3, 6))
    P = np.zeros((K, 3, 6))
    x, d = np.empty(3), np.empty(3)
    for k in range(K):
        tmulv(R[k], v[k], x)
        _skew_map(R[k], x, V[k])
        if k + 1 < K:
            for c in range(3):
                d[c] = p[k + 1, c] - p[k, c]
            tmulv(R[k], d, x)
            _skew_map(R[k], x, P[k])
    return V, P


@nb.njit(cache=True, inline="always")
def _skew_map(R, x, out):
    """out (3 × 6) = [−R[x]×, R]"""
    for r in range(3):
        out[r, 0] = -(R[r, 1] * x[2] - R[r, 2] * x[1])
        out[r, 1] = -(R[r, 2] * x[0] - R[r, 0] * x[2])
        out[r, 2] = -(R[r, 0] * x[1] - R[r, 1] * x[0])
        for c in range(3):
            out[r, 3 + c] = R[r, c]


@nb.njit(cache=True, nogil=True)
def to_local(Jx, first, stride, V, P, sd):
    """World-state Jacobians ``Jx`` (N × r × 9·n_states) of factors at keyframes ``first + stride·a``
    re-expressed in local states over every keyframe they span (N × r × sd·(span + 1): sd ≥ 9
    columns per state, the 9 trajectory states first, any further ones zero); the maps
    ``V, P`` (K × 3 × 6) and the formula are those of :func:`excite.information.problem.to_local`.
    Also returns which of those columns it wrote a non-zero to (every other column is zero for
    every factor: a factor that sees no velocity, the increments after its last keyframe)."""
    N, r, nx = Jx.shape
    ns = nx // 9
    span = stride * (ns - 1)
    out = np.empty((N, r, sd * (span + 1)))  # zeroed per factor, in cache
    rot_seen = np.zeros(ns, dtype=np.bool_)
    vel_seen = np.zeros(ns, dtype=np.bool_)
    inc_seen = np.zeros(max(span, 1), dtype=np.bool_)
    for f in range(N):
        J = Jx[f]
        O = out[f]
        O[:] = 0.0
        for a in range(ns):
            k = first[f] + a * stride
            col = sd * a * stride
            Vk = V[k]
            v00, v01, v02, v03, v04, v05 = Vk[0, 0], Vk[0, 1], Vk[0, 2], Vk[0, 3], Vk[0, 4], Vk[0, 5]
            v10, v11, v12, v13, v14, v15 = Vk[1, 0], Vk[1, 1], Vk[1, 2], Vk[1, 3], Vk[1, 4], Vk[1, 5]
            v20, v21, v22, v23, v24, v25 = Vk[2, 0], Vk[2, 1], Vk[2, 2], Vk[2, 3], Vk[2, 4], Vk[2, 5]
            for row in range(r):
                Jr, Or = J[row], O[row]
                r0, r1, r2 = Jr[9 * a], Jr[9 * a + 1], Jr[9 * a + 2]
                if r0 != 0.0 or r1 != 0.0 or r2 != 0.0:
                    rot_seen[a] = True
                j0, j1, j2 = Jr[9 * a + 6], Jr[9 * a + 7], Jr[9 * a + 8]
                if j0 != 0.0 or j1 != 0.0 or j2 != 0.0:  # (lidar, camera and wheels see no velocity)
                    vel_seen[a] = True  # velocity: δv_world = V_k [δθ_k; δv_k]
                    Or[col] = r0 + (j0 * v00 + j1 * v10 + j2 * v20)
                    Or[col + 1] = r1 + (j0 * v01 + j1 * v11 + j2 * v21)
                    Or[col + 2] = r2 + (j0 * v02 + j1 * v12 + j2 * v22)
                    Or[col + 3] = j0 * v03 + j1 * v13 + j2 * v23
                    Or[col + 4] = j0 * v04 + j1 * v14 + j2 * v24
                    Or[col + 5] = j0 * v05 + j1 * v15 + j2 * v25
                else:
                    Or[col] = r0
                    Or[col + 1] = r1
                    Or[col + 2] = r2
        for q in range(span):  # increment q moves the position of every later state of the factor
            Pk = P[first[f] + q]
            for row in range(r):
                Jr = J[row]
                j0 = 0.0
                j1 = 0.0
                j2 = 0.0
                for a in range(ns):
                    if a * stride > q:
                        j0 += Jr[9 * a + 3]
                        j1 += Jr[9 * a + 4]
                        j2 += Jr[9 * a + 5]
                if j0 != 0.0 or j1 != 0.0 or j2 != 0.0:
                    inc_seen[q] = True
                    Or = O[row]
                    for c in range(6):
                        Or[sd * q + (c if c < 3 else c + 3)] += j0 * Pk[0, c] + j1 * Pk[1, c] + j2 * Pk[2, c]
    seen = np.zeros(sd * (span + 1), dtype=np.bool_)  # the columns written non-zero
    for a in range(ns):
        col = sd * a * stride
        for c in range(3):
            seen[col + c] = seen[col + c] or rot_seen[a] or vel_seen[a]
            seen[col + 3 + c] = seen[col + 3 + c] or vel_seen[a]
    for q in range(span):
        for c in range(3):
            seen[sd * q + c] = seen[sd * q + c] or inc_seen[q]
            seen[sd * q + 6 + c] = seen[sd * q + 6 + c] or inc_seen[q]
    return out, seen
