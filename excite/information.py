"""The joint information problem and the marginal information of the calibration.

:func:`build` linearises every factor of a drive at its nominal motion (IMU preintegration,
exteroceptive odometry, wheel increments, the non-holonomic constraint) and fixes the gauge
minimally. :func:`marginal` eliminates the trajectory from ``H = JᵀJ``:

    Λ_θ = H_θθ − H_θx H_xx⁻¹ H_xθ

exploiting that H_xx is block-banded: it is stored in LAPACK band format, factored with a banded
Cholesky and the border solved by banded triangular substitution. Cost and memory are linear in
the drive length; a dense H_xx is never formed. :func:`marginal_dense` is the plain-numpy dense
reference the tests hold the fast path to.

Two parametrisations of the trajectory, one marginal. The factors' Jacobians are derived for the
*world* state ``[δθ, δp, δv]`` (right rotation perturbation, world position and velocity), whose
gauge is the position (3) and yaw (1) of the whole drive. The fast path uses the *local* state
``[δθ_k, δv_k, δd_k]``: body-frame velocity ``v_k = R_kᵀ v`` and the body-frame increment
``d_k = R_kᵀ (p_{k+1} − p_k)`` to the next keyframe. Every factor sees positions only through
such differences, so no absolute position remains, the only gauge left is yaw, and — unlike in
world coordinates, where a global tilt moves a keyframe 5 km away by 5 km × tilt — every symmetry
of the problem has bounded components. That keeps the Schur complement accurate on hour-long
drives. The marginal on θ does not depend on the parametrisation (the tests compare both).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cholesky_banded
from scipy.linalg.lapack import dtbtrs

from . import kernels, so3
from .parallel import pool
from .errors import EvaluationError
from .factors import imu, nonholonomic, odometry, wheel
from .factors.base import POS, ROT, STATE_DIM, VEL, FactorBlock, Nominal
from .rig import Rig

# The gauge fix: σ of the prior on the first keyframe's position [m] and yaw [rad]. Any value
# gives the same marginal (the gauge is an exact symmetry); one near the data's scale keeps H_xx
# well conditioned.
_GAUGE_SIGMA_POS_M = 1.0
_GAUGE_SIGMA_YAW_RAD = 0.01
_NO_COLS = np.zeros(0, dtype=int)


@dataclass(frozen=True)
class Problem:
    """Whitened Jacobian blocks of every factor of a drive (see :class:`FactorBlock`)."""

    n_keyframes: int
    n_params: int
    blocks: tuple[FactorBlock, ...]
    R_W_B: np.ndarray  # nominal body orientation per keyframe (for gauge fixes of windows)
    local: bool = False  # state parametrisation: local [δθ, δv_body, δd] or world [δθ, δp, δv]
    chain_starts: tuple[int, ...] = (0,)  # first keyframe of each drive (drives share only θ)

    @property
    def n_states(self) -> int:
        return STATE_DIM * self.n_keyframes

    @property
    def bandwidth_blocks(self) -> int:
        return max(b.stride * (b.n_states - 1) for b in self.blocks)

    def window(self, k0: int, k1: int) -> "Problem":
        """The factors that lie entirely within keyframes ``k0..k1``, re-indexed, with new gauges."""
        out = []
        for b in self.blocks:
            if b.name in ("gauge", "placeholder"):
                continue
            last = b.first + b.stride * (b.n_states - 1)
            mask = (b.first >= k0) & (last <= k1)
            if mask.any():
                sel = b.select(mask)
                out.append(sel.shifted(-k0))
        starts = sorted({k0, *(s for s in self.chain_starts if k0 < s <= k1)})
        return _with_gauges(k1 - k0 + 1, self.n_params, out, self.R_W_B[k0:k1 + 1], self.local,
                            tuple(s - k0 for s in starts))

    def without_gauge(self) -> "Problem":
        return Problem(self.n_keyframes, self.n_params, tuple(b for b in self.blocks if b.name != "gauge"),
                       self.R_W_B, self.local, self.chain_starts)


def gauge_block(R_W_B: np.ndarray, keyframe: int, n_params: int) -> FactorBlock:
    """A prior on the position (3) and world yaw (1) of ``keyframe``: the minimal gauge fix."""
    Jx = np.zeros((1, 4, STATE_DIM))
    Jx[0, 0:3, POS] = np.eye(3) / _GAUGE_SIGMA_POS_M
    # world yaw of a right perturbation: e_zᵀ R δθ
    Jx[0, 3, ROT] = R_W_B[2] / _GAUGE_SIGMA_YAW_RAD
    return FactorBlock("gauge", np.array([keyframe]), 1, 1, Jx, np.zeros((1, 4, 0)), _NO_COLS)


def build(nom: Nominal | list[Nominal], rig: Rig, gauge_keyframe: int = 0, local: bool = True) -> Problem:
    """Linearise every factor of ``rig`` on the nominal motion ``nom``.

    A list of nominal motions is several drives calibrated together: they share the calibration θ
    and nothing else (each has its own trajectory and gauge). ``local`` selects the trajectory
    parametrisation (see the module docstring); the gauge of each drive is fixed at its keyframe
    ``gauge_keyframe``.
    """
    noms = nom if isinstance(nom, list) else [nom]
    p = len(rig.coordinates)
    parts: list[FactorBlock] = []
    starts, R_all, offset = [], [], 0
    for n in noms:
        if n.n_keyframes < 3:
            raise EvaluationError(f"the drive is too short: {n.n_keyframes} keyframes at "
                                  f"{rig.keyframe_rate_hz:g} Hz, need at least 3")
        if not -n.n_keyframes <= gauge_keyframe < n.n_keyframes:
            raise EvaluationError(f"gauge keyframe {gauge_keyframe} is outside the drive")
        blocks = _linearise(n, rig, local)
        parts += [b.shifted(offset) for b in blocks]
        starts.append(offset)
        R_all.append(n.R)
        offset += n.n_keyframes
    gauges = tuple(s + (gauge_keyframe % n.n_keyframes) for s, n in zip(starts, noms))
    return _with_gauges(offset, p, parts, np.concatenate(R_all), local, tuple(starts), gauges)


_CHUNK_KEYFRAMES = 3000  # keyframes linearised per task: bounded temporaries, both cores busy


def _linearise(n: Nominal, rig: Rig, local: bool) -> list[FactorBlock]:
    """Every factor of one drive, linearised in chunks of keyframes on the thread pool.

    Chunks start at multiples of every sensor's frame stride, so each factor falls in exactly
    one chunk: the intervals ``k0 → k0+1 … k1−1 → k1`` and the sensor frame pairs inside, the
    non-holonomic constraint at ``k0 … k1−1`` (and at the drive's last keyframe).
    """
    strides = [int(round(rig.keyframe_rate_hz / s.rate_hz)) for s in rig.config.sensors] or [1]
    step = int(np.lcm.reduce(strides))
    size = max(step, (_CHUNK_KEYFRAMES // step) * step)
    K = n.n_keyframes
    edges = list(range(0, K - 1, size)) + [K - 1]

    def chunk(c: int) -> list[FactorBlock | None]:
        k0, k1 = edges[c], edges[c + 1]
        sub = n.window(k0, k1)
        nhc = nonholonomic.blocks(sub, rig)
        blocks = [imu.blocks(sub, rig), nhc if k1 == K - 1 else nhc.select(nhc.first < k1 - k0),
                  wheel.blocks(sub, rig)] + [odometry.blocks(sub, rig, s) for s in rig.config.sensors]
        if local:
            v_b = np.einsum("kji,kj->ki", sub.R, sub.v)
            d = np.einsum("kji,kj->ki", sub.R[:-1], np.diff(sub.p, axis=0))
            V, P = _local_maps(sub.R, v_b, d)
            blocks = [None if b is None else _to_local(b, V, P) for b in blocks]
        return [None if b is None else b.shifted(k0) for b in blocks]

    # kind-major: imu, nonholonomic, wheel, sensors, each in time order (the rows of J follow it)
    per_chunk = list(pool().map(chunk, range(len(edges) - 1)))
    return [b for kind in zip(*per_chunk) for b in kind if b is not None and b.n_factors]


def _with_gauges(K: int, p: int, blocks: list[FactorBlock], R: np.ndarray, local: bool,
                 chain_starts: tuple[int, ...], gauges: tuple[int, ...] | None = None) -> Problem:
    """A problem with the minimal gauge fix of every chain (at its first keyframe by default)."""
    gauges = chain_starts if gauges is None else gauges
    ends = [s - 1 for s in chain_starts[1:]] + [K - 1]
    fix = []
    for g, e in zip(gauges, ends):
        if local:
            fix += [_yaw_gauge(R[g], g, p), _last_increment_prior(e, p)]
        else:
            fix.append(gauge_block(R[g], g, p))
    return Problem(K, p, tuple(blocks) + tuple(fix), R, local, chain_starts)


def _local_maps(R: np.ndarray, v_b: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per keyframe, how world velocity and position perturbations follow from local ones:
    ``δv_world = V_k [δθ_k; δv_k]`` with ``V_k = [−R_k[v_k]×, R_k]`` and
    ``δ(p_{k+1} − p_k) = P_k [δθ_k; δd_k]`` with ``P_k = [−R_k[d_k]×, R_k]`` (each 3 × 6)."""
    V = np.concatenate([-R @ so3.hat(v_b), R], axis=2)
    P = np.zeros_like(V)
    P[:-1] = np.concatenate([-R[:-1] @ so3.hat(d), R[:-1]], axis=2)
    return V, P


def _to_local(b: FactorBlock, V: np.ndarray, P: np.ndarray) -> FactorBlock:
    """Re-express a block's world-state Jacobian in local states (maps from :func:`_local_maps`).

    Positions enter every factor only through differences (its position Jacobians sum to zero),
    so ``Σ_a J_p,a δp_{k_a} = Σ_a J_p,a Σ_{first ≤ q < k_a} δ(p_{q+1} − p_q)`` and the position of
    the factor's first keyframe drops out.
    """
    span = b.stride * (b.n_states - 1)
    n_new = span + 1
    N, r, _ = b.Jx.shape
    out = np.zeros((N, r, STATE_DIM * n_new))
    Jp = [b.Jx[:, :, STATE_DIM * a + 3: STATE_DIM * a + 6] for a in range(b.n_states)]
    for a in range(b.n_states):
        k = b.first + a * b.stride
        Ja = b.Jx[:, :, STATE_DIM * a: STATE_DIM * (a + 1)]
        col = STATE_DIM * a * b.stride
        out[:, :, col + 0: col + 3] += Ja[:, :, ROT]
        vel = Ja[:, :, VEL] @ V[k]  # → [δθ_k, δv_k]
        out[:, :, col + 0: col + 3] += vel[:, :, 0:3]
        out[:, :, col + 3: col + 6] += vel[:, :, 3:6]
    for q in range(span):  # increment q (from keyframe first+q) moves every state after it
        Jp_cum = sum(Jp[a] for a in range(b.n_states) if a * b.stride > q)
        pos = Jp_cum @ P[b.first + q]
        cq = STATE_DIM * q
        out[:, :, cq + 0: cq + 3] += pos[:, :, 0:3]
        out[:, :, cq + 6: cq + 9] += pos[:, :, 3:6]
    return FactorBlock(b.name, b.first, 1, n_new, out, b.Jt, b.cols)


def _yaw_gauge(R_W_B: np.ndarray, keyframe: int, n_params: int) -> FactorBlock:
    """A prior on the world yaw of ``keyframe``: the one gauge of the local parametrisation."""
    Jx = np.zeros((1, 1, STATE_DIM))
    Jx[0, 0, ROT] = R_W_B[2] / _GAUGE_SIGMA_YAW_RAD
    return FactorBlock("gauge", np.array([keyframe]), 1, 1, Jx, np.zeros((1, 1, 0)), _NO_COLS)


def _last_increment_prior(keyframe: int, n_params: int) -> FactorBlock:
    """The last keyframe of a chain has no successor: its increment columns are placeholders held at zero."""
    Jx = np.zeros((1, 3, STATE_DIM))
    Jx[0, :, 6:9] = np.eye(3)
    return FactorBlock("placeholder", np.array([keyframe]), 1, 1, Jx, np.zeros((1, 3, 0)), _NO_COLS)


def _rows(first: np.ndarray, shift: int):
    """Index of ``first + shift``: a slice when ``first`` is an increasing arithmetic progression
    (no copies; plain slicing is ~10x faster than an index array in an in-place add)."""
    f = first + shift
    if f.size == 1:
        return slice(int(f[0]), int(f[0]) + 1)
    step = int(f[1] - f[0])
    if step > 0 and np.all(np.diff(f) == step):
        return slice(int(f[0]), int(f[-1]) + 1, step)
    return f


def _scatter(target: np.ndarray, rows, values: np.ndarray, cols: np.ndarray | None = None) -> None:
    """``target[rows(, :, cols)] += values`` (rows a slice or, possibly repeated, indices)."""
    if cols is not None:
        if isinstance(rows, slice):
            view = target[rows]  # a view: the indexed += below writes through (cols are unique)
            view[:, :, _rows(cols, 0)] += values
        else:
            np.add.at(target, (rows[:, None, None], np.arange(target.shape[1])[None, :, None], cols[None, None, :]),
                      values)
    elif isinstance(rows, slice):
        target[rows] += values
    else:
        np.add.at(target, rows, values)


_CHUNK = 512  # factors per assembly step


def _merged(blocks: list[FactorBlock]) -> list[FactorBlock]:
    """Blocks that touch the same keyframes stacked row-wise: one product and one scatter each."""
    groups: dict[tuple, list[FactorBlock]] = {}
    for b in blocks:
        key = (b.stride, b.n_states, b.first.size, int(b.first[0]), int(b.first[-1]))
        groups.setdefault(key, []).append(b)
    out = []
    for group in groups.values():
        if len(group) == 1 or any(not np.array_equal(g.first, group[0].first) for g in group):
            out += group
            continue
        cols = np.unique(np.concatenate([g.cols for g in group]))
        rows = sum(g.n_rows for g in group)
        N = group[0].n_factors
        Jt = np.zeros((N, rows, cols.size))
        r0 = 0
        for g in group:
            Jt[:, r0:r0 + g.n_rows, np.searchsorted(cols, g.cols)] = g.Jt
            r0 += g.n_rows
        Jx = np.concatenate([g.Jx for g in group], axis=1)
        out.append(FactorBlock("+".join(g.name for g in group), group[0].first, group[0].stride,
                               group[0].n_states, Jx, Jt, cols))
    return out


def assemble(problem: Problem) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """``H`` in blocks: ``B[d][k] = H[x_{k+d}, x_k]`` (K−d, 9, 9), ``H_xθ`` (K, 9, p) and ``H_θθ``.

    The factors are accumulated in chunks, alternately by the pool's threads into private sums
    that are added at the end."""
    pieces = _chunks(problem.blocks)
    n_threads = min(2, len(pieces))
    parts = list(pool().map(lambda i: _accumulate(problem, pieces[i::n_threads]), range(n_threads)))
    B, Hxt, Htt = parts[0]
    for B2, Hxt2, Htt2 in parts[1:]:
        for d in range(len(B)):
            B[d] += B2[d]
        Hxt += Hxt2
        Htt += Htt2
    return B, Hxt, Htt


def _accumulate(problem: Problem, pieces: list[list[FactorBlock]]):
    K, p, D = problem.n_keyframes, problem.n_params, problem.bandwidth_blocks
    B = [np.zeros((K - d, STATE_DIM, STATE_DIM)) for d in range(D + 1)]
    Hxt = np.zeros((K, STATE_DIM, p))
    Htt = np.zeros((p, p))
    for piece in pieces:
        for b in _merged(piece):
            JxT = np.ascontiguousarray(np.swapaxes(b.Jx, 1, 2))  # contiguous: 3x faster batched matmul
            Hxx = JxT @ b.Jx
            k = b.cols.size
            if k:
                Hxt_f = JxT @ b.Jt
                Jt2 = b.Jt.reshape(-1, k)
                c = _rows(b.cols, 0)
                if isinstance(c, slice):
                    Htt[c, c] += Jt2.T @ Jt2
                else:
                    Htt[np.ix_(b.cols, b.cols)] += Jt2.T @ Jt2
            for a in range(b.n_states):
                sa = slice(STATE_DIM * a, STATE_DIM * (a + 1))
                if k:
                    _scatter(Hxt, _rows(b.first, a * b.stride), Hxt_f[:, sa], b.cols)
                for c2 in range(a + 1):
                    sc = slice(STATE_DIM * c2, STATE_DIM * (c2 + 1))
                    _scatter(B[(a - c2) * b.stride], _rows(b.first, c2 * b.stride), Hxx[:, sa, sc])
    return B, Hxt, Htt


def _chunks(blocks: tuple[FactorBlock, ...]) -> list[list[FactorBlock]]:
    """The blocks cut into pieces of at most ``_CHUNK`` factors and grouped by the keyframes they
    start at, so that a group holds the factors of one stretch of the drive (which
    :func:`_merged` stacks) and groups are independent work for the threads."""
    groups: dict[int, list[FactorBlock]] = {}
    for b in blocks:
        for start in range(0, b.n_factors, _CHUNK):
            sl = slice(start, min(start + _CHUNK, b.n_factors))
            key = int(b.first[start]) // _CHUNK
            groups.setdefault(key, []).append(
                FactorBlock(b.name, b.first[sl], b.stride, b.n_states, b.Jx[sl], b.Jt[sl], b.cols))
    return [groups[k] for k in sorted(groups)]


def marginal(problem: Problem) -> np.ndarray:
    """Marginal information ``Λ_θ`` (p × p) of the calibration, trajectory eliminated (fast path)."""
    B, Hxt, Htt = assemble(problem)
    K = problem.n_keyframes
    try:
        L = cholesky_banded(kernels.band_lower(tuple(B), K, STATE_DIM), lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        raise EvaluationError("the trajectory itself is undetermined by this rig's sensors "
                              "(the keyframe information is singular beyond the gauge)") from None
    Z, info = dtbtrs(L, Hxt.reshape(K * STATE_DIM, -1), uplo="L")
    if info != 0:
        raise EvaluationError(f"banded triangular solve failed (LAPACK info {info})")
    Lam = Htt - Z.T @ Z
    return 0.5 * (Lam + Lam.T)


def jacobian(problem: Problem) -> tuple[sp.csr_matrix, list[str]]:
    """The whitened Jacobian ``J`` (sparse, columns: states then θ) and a label per row."""
    rows, cols, vals, labels = [], [], [], []
    r0 = 0
    nx = problem.n_states
    for b in problem.blocks:
        N, r = b.n_factors, b.n_rows
        rid = r0 + np.arange(N * r).reshape(N, r)
        for a in range(b.n_states):
            c = STATE_DIM * (b.first + a * b.stride)[:, None] + np.arange(STATE_DIM)[None, :]
            blk = b.Jx[:, :, STATE_DIM * a: STATE_DIM * (a + 1)]
            rows.append(np.broadcast_to(rid[:, :, None], blk.shape).ravel())
            cols.append(np.broadcast_to(c[:, None, :], blk.shape).ravel())
            vals.append(blk.ravel())
        rows.append(np.broadcast_to(rid[:, :, None], b.Jt.shape).ravel())
        cols.append(np.broadcast_to(nx + b.cols, b.Jt.shape).ravel())
        vals.append(b.Jt.ravel())
        labels += [f"{b.name}[{k}].{i}" for k in b.first for i in range(r)]
        r0 += N * r
    rows, cols, vals = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
    keep = vals != 0
    J = sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(r0, nx + problem.n_params))
    return J, labels


def state_names(n_keyframes: int, local: bool = True) -> list[str]:
    """Names of the state columns of ``J`` and ``H``, in order (see the module docstring)."""
    if local:
        comps = ["rot_x", "rot_y", "rot_z", "vel_body_x", "vel_body_y", "vel_body_z",
                 "incr_body_x", "incr_body_y", "incr_body_z"]
    else:
        comps = ["rot_x", "rot_y", "rot_z", "pos_x", "pos_y", "pos_z", "vel_x", "vel_y", "vel_z"]
    return [f"x{k}.{c}" for k in range(n_keyframes) for c in comps]


def marginal_dense(problem: Problem, gauge: bool = True) -> np.ndarray:
    """Dense reference: form J and H in full and take the Schur complement with numpy.

    With ``gauge=False`` the gauge prior is left out and ``H_xx`` pseudo-inverted instead, which
    shows that the marginal does not depend on how (or whether) the gauge is fixed.
    """
    J, _ = jacobian(problem if gauge else problem.without_gauge())
    J = J.toarray()
    H = J.T @ J
    nx = problem.n_states
    Hxx, Hxt, Htt = H[:nx, :nx], H[:nx, nx:], H[nx:, nx:]
    if gauge:
        X = np.linalg.solve(Hxx, Hxt)
    else:
        X = np.linalg.pinv(Hxx, rcond=1e-12, hermitian=True) @ Hxt
    Lam = Htt - Hxt.T @ X
    return 0.5 * (Lam + Lam.T)
