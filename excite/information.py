"""The joint information problem and the marginal information of the calibration.

:func:`build` linearises every factor of a drive at its nominal motion (IMU preintegration,
exteroceptive odometry, wheel increments, the non-holonomic constraint) and fixes the gauge
minimally. :func:`marginal` eliminates the trajectory from ``H = JᵀJ``:

    Λ_θ = H_θθ − H_θx H_xx⁻¹ H_xθ

exploiting that H_xx is block-banded (a keyframe's state meets only its neighbours'): the drive
is cut into chunks of keyframes that no factor reaches across, and the keyframes are eliminated
with a compiled block Cholesky. :func:`marginal` does it for a linearised :class:`Problem`:
every chunk eliminates its inner keyframes, in parallel with the others, and the chain of chunk
ends is eliminated last. :func:`drive_information` streams it from the trajectories (the
evaluator's path): each drive is swept from both ends at once, chunk after chunk, each chunk
sampled and linearised where it is eliminated, towards a keyframe in its middle. Cost is linear
in the drive length and memory bounded by a chunk; a dense H_xx is never formed.
:func:`marginal_dense` is the plain-numpy dense reference the tests hold both to.

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

from dataclasses import dataclass, replace

import time
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from .core import kernels
from .errors import EvaluationError
from .factors import imu, nonholonomic, odometry, wheel
from .factors.base import BIAS, BIAS_STATE_DIM, POS, ROT, STATE_DIM, FactorBlock, Nominal
from .core.parallel import n_threads, pool
from .rig.config import Rig
from .motion.trajectory import Trajectory

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
    state_dim: int = STATE_DIM  # 15 with random-walk IMU biases (the bias deviations δb_g, δb_a)

    @property
    def n_states(self) -> int:
        return self.state_dim * self.n_keyframes

    @property
    def bandwidth_blocks(self) -> int:
        return max(b.stride * (b.n_states - 1) for b in self.blocks)

    def window(self, k0: int, k1: int) -> "Problem":
        """The factors that lie entirely within keyframes ``k0..k1``, re-indexed, with new gauges
        (every piece of a drive in it needs 3 keyframes: see :func:`trimmed`)."""
        _check_trimmed(self.chain_starts, k0, k1)
        out = []
        starts = [s - k0 for s in sorted({k0, *(s for s in self.chain_starts if k0 < s <= k1)})]
        ends = [s - 1 for s in starts[1:]] + [k1 - k0]
        for b in self.blocks:
            if b.name in ("gauge", "placeholder"):
                continue
            sel = b.within(k0, k1)
            if sel is not None:
                if b.name == "bias_walk":  # the bias columns of θ are the bias at each piece's end
                    sel = _bias_anchored(sel, np.asarray(ends))
                out.append(sel)
        R = self.R_W_B[k0:k1 + 1]
        for s, e in zip(starts, ends):
            out += _gauge(R[s], s, self.local) + _chain_end(e, self.local, self.state_dim)
        return Problem(k1 - k0 + 1, self.n_params, tuple(out), R, self.local, tuple(starts), self.state_dim)

    def without_gauge(self) -> "Problem":
        return Problem(self.n_keyframes, self.n_params, tuple(b for b in self.blocks if b.name != "gauge"),
                       self.R_W_B, self.local, self.chain_starts, self.state_dim)


def trimmed(starts: Sequence[int], k0: int, k1: int) -> tuple[int, int] | None:
    """Keyframes ``k0..k1`` (numbered on from one drive to the next; drives start at ``starts``)
    less a piece of fewer than 3 keyframes that a boundary between two drives cuts off at either
    end (it carries no determinable trajectory of its own); None if less than 3 keyframes remain.
    Drives themselves have at least 3 (:func:`build`)."""
    inner = [s for s in starts if k0 < s <= k1]
    if inner and inner[0] - k0 < 3:
        k0 = inner[0]
    if inner and k1 - inner[-1] + 1 < 3:
        k1 = inner[-1] - 1
    return (k0, k1) if k1 - k0 >= 2 else None


def _check_trimmed(starts: Sequence[int], k0: int, k1: int) -> None:
    if trimmed(starts, k0, k1) != (k0, k1):
        raise EvaluationError(f"keyframes {k0}..{k1} cut a piece of fewer than 3 keyframes off a drive")


def gauge_block(R_W_B: np.ndarray, keyframe: int) -> FactorBlock:
    """A prior on the position (3) and world yaw (1) of ``keyframe``: the minimal gauge fix."""
    Jx = np.zeros((1, 4, STATE_DIM))
    Jx[0, 0:3, POS] = np.eye(3) / _GAUGE_SIGMA_POS_M
    # world yaw of a right perturbation: e_zᵀ R δθ
    Jx[0, 3, ROT] = R_W_B[2] / _GAUGE_SIGMA_YAW_RAD
    return FactorBlock("gauge", np.array([keyframe]), 1, 1, Jx, np.zeros((1, 4, 0)), _NO_COLS)


def _own(rig: Rig) -> np.ndarray:
    """Indices of the coordinates every drive has of its own: a monocular camera's scale, and the
    IMU biases when they drift (each recording's bias process is its own)."""
    return np.flatnonzero([c.nuisance or (rig.bias_random_walk and c.block == "imu") for c in rig.coordinates])


def columns(rig: Rig, n_drives: int) -> tuple[list[str], np.ndarray]:
    """Names and nuisance mask of the parameter columns of ``n_drives`` drives calibrated
    together: the rig's coordinates, which the *last* drive's own coordinates (:func:`_own`) use,
    then each earlier drive's own coordinates as nuisances (``cam_front.scale@0``): drives share
    the calibration and nothing else. With random-walk biases the scored bias is therefore the
    bias at the end of the last drive."""
    own = [rig.coordinates[i].name for i in _own(rig)]
    names = [c.name for c in rig.coordinates] + [f"{n}@{d}" for d in range(n_drives - 1) for n in own]
    mask = np.array([c.nuisance for c in rig.coordinates] + [True] * (len(names) - len(rig.coordinates)))
    return names, mask


def _drive_column_map(rig: Rig, drive: int, n_drives: int) -> np.ndarray:
    """Column of each rig coordinate in drive ``drive``'s factors (see :func:`columns`)."""
    p = len(rig.coordinates)
    out = np.arange(p)
    own = _own(rig)
    if drive < n_drives - 1 and own.size:
        out[own] = p + drive * own.size + np.arange(own.size)
    return out


def _on_drive_columns(blocks: list, col_map: np.ndarray) -> list:
    return [b if b is None or not b.cols.size else
            replace(b, cols=col_map[b.cols]) for b in blocks]


def build(nom: Nominal | list[Nominal], rig: Rig, gauge_keyframe: int = 0, local: bool = True) -> Problem:
    """Linearise every factor of ``rig`` on the nominal motion ``nom``.

    A list of nominal motions is several drives calibrated together: they share the calibration θ
    and nothing else (each has its own trajectory, gauge and nuisance columns: :func:`columns`).
    ``local`` selects the trajectory parametrisation (see the module docstring); the gauge of each
    drive is fixed at its keyframe ``gauge_keyframe``.
    """
    noms = nom if isinstance(nom, list) else [nom]
    p = len(columns(rig, len(noms))[0])
    sd = state_dim(rig)
    parts: list[FactorBlock] = []
    fixes: list[FactorBlock] = []
    starts, R_all, offset = [], [], 0
    for d, n in enumerate(noms):
        col_map = _drive_column_map(rig, d, len(noms))
        K = _check_length(n.n_keyframes, rig)
        if not -K <= gauge_keyframe < K:
            raise EvaluationError(f"gauge keyframe {gauge_keyframe} is outside the drive")
        edges = _chunk_edges(K, rig)
        per_chunk = pool().map(lambda c: [None if b is None else b.shifted(edges[c]) for b in _on_drive_columns(
                                          _linearise(n.window(edges[c], edges[c + 1]), rig, local, edges[c + 1] == K - 1),
                                          col_map)],
                               range(len(edges) - 1))
        # kind-major: imu, nonholonomic, wheel, sensors, each in time order (the rows of J follow it)
        parts += [b.shifted(offset) for kind in zip(*per_chunk) for b in kind if b is not None and b.n_factors]
        g = gauge_keyframe % K
        fixes += [b.shifted(offset) for b in _gauge(n.R[g], g, local) + _chain_end(K - 1, local, sd)]
        starts.append(offset)
        R_all.append(n.R)
        offset += K
    return Problem(offset, p, tuple(parts + fixes), np.concatenate(R_all), local, tuple(starts), sd)


def _check_length(K: int, rig: Rig) -> int:
    if K < 3:
        raise EvaluationError(f"the drive is too short: {K} keyframes at {rig.keyframe_rate_hz:g} Hz, "
                              f"need at least 3")
    return K


_CHUNK_KEYFRAMES = 3000  # keyframes per task at most: bounded memory, little interpreter time per keyframe


def _chunk_edges(K: int, rig: Rig) -> list[int]:
    """Keyframes that cut a drive into chunks of at most about ``_CHUNK_KEYFRAMES``, as many as a
    multiple of the thread count (every thread gets an equal share), at multiples of every
    sensor's frame stride (so each factor falls in exactly one chunk: see :func:`_linearise`)."""
    step = frame_step(rig)
    n = -(-(K - 1) // _CHUNK_KEYFRAMES)
    n = -(-n // n_threads()) * n_threads()
    size = max(step, -(-(K - 1) // (n * step)) * step)
    return list(range(0, K - 1, size)) + [K - 1]


def frame_step(rig: Rig) -> int:
    """The fewest keyframes that hold a whole number of frames of every sensor (the least common
    multiple of their strides): a chunk or window that starts and ends at multiples of it, counted
    from its drive's start, cuts no sensor's frame pair."""
    strides = [int(round(rig.keyframe_rate_hz / s.rate_hz)) for s in rig.config.sensors] or [1]
    return int(np.lcm.reduce(strides))


def state_dim(rig: Rig) -> int:
    """Dimension of a keyframe's nuisance state for ``rig`` (see :data:`BIAS_STATE_DIM`)."""
    return BIAS_STATE_DIM if rig.bias_random_walk else STATE_DIM


def _linearise(sub: Nominal, rig: Rig, local: bool, last: bool, walk: bool = True) -> list[FactorBlock | None]:
    """Every factor of one chunk ``k0 … k1`` of a drive (indices relative to ``k0``), per kind.

    The chunk owns the intervals ``k0 → k0+1 … k1−1 → k1`` and the sensor frame pairs inside,
    and the non-holonomic constraint at ``k0 … k1−1`` (and at ``k1`` if it ends the drive).
    With random-walk biases only the IMU factor is widened to the bias states (the other blocks
    stay 9 wide: :func:`excite.core.kernels.accumulate` places them in the first 9 components); it
    sees the bias of its interval's start (the θ column plus the state's deviation), and the random
    walk links consecutive deviations; the deviation at the drive's last keyframe is zero (θ is the
    bias there), so the walk's last step does not reach it. ``walk=False`` leaves the walk out
    (the sweep adds its constant information directly: :func:`_eliminated`).
    """
    m = sub.n_keyframes - 1
    nhc = nonholonomic.blocks(sub, rig)
    blocks = [imu.blocks(sub, rig), nhc if last else nhc.select(nhc.first < m),
              wheel.blocks(sub, rig)] + [odometry.blocks(sub, rig, s) for s in rig.config.sensors]
    if local:
        V, P = _local_maps(sub.R, sub.v, sub.p)
        sd = state_dim(rig)  # the IMU block is written widened to the bias states
        blocks = [None if b is None else _to_local(b, V, P, sd if i == 0 else STATE_DIM) for i, b in enumerate(blocks)]
    if rig.bias_random_walk:
        imu_blk = blocks[0] = blocks[0] if local else _widen(blocks[0])
        imu_blk.Jx[:, :, BIAS] = imu_blk.Jt  # b_k = θ_b + δb_k
        if imu_blk.xcols is not None:
            blocks[0] = replace(imu_blk, xcols=np.union1d(imu_blk.xcols, np.arange(BIAS.start, BIAS.stop)))
        if walk:
            steps = _bias_walk(rig, m, float(sub.t[1] - sub.t[0]))
            blocks.append(_bias_anchored(steps, np.array([m])) if last else steps)
    return blocks


def _widen(b: FactorBlock) -> FactorBlock:
    """A block's Jacobian over trajectory states, widened with zero columns for the bias states."""
    N, r, _ = b.Jx.shape
    Jx = np.zeros((N, r, b.n_states, BIAS_STATE_DIM))
    Jx[..., :STATE_DIM] = b.Jx.reshape(N, r, b.n_states, STATE_DIM)
    return FactorBlock(b.name, b.first, b.stride, b.n_states, Jx.reshape(N, r, -1), b.Jt, b.cols)


def _bias_walk(rig: Rig, n_intervals: int, dT: float) -> FactorBlock:
    """The random walk of the IMU biases over each keyframe interval: ``δb_j − δb_i`` with
    σ = random-walk density · √ΔT (Kalibr's ``*_random_walk`` units)."""
    w = _walk_weights(rig, dT)
    Jx = np.zeros((n_intervals, 6, 2 * BIAS_STATE_DIM))
    Jx[:, :, BIAS] = -np.diag(w)
    Jx[:, :, BIAS_STATE_DIM + 9:] = np.diag(w)
    return FactorBlock("bias_walk", np.arange(n_intervals), 1, 2, Jx, np.zeros((n_intervals, 6, 0)), _NO_COLS)


def _walk_weights(rig: Rig, dT: float) -> np.ndarray:
    """1/σ of a random-walk step of the biases (gyro xyz, accel xyz) over ``dT``."""
    imu = rig.config.imu
    return 1.0 / (np.repeat([imu.gyroscope_random_walk, imu.accelerometer_random_walk], 3) * np.sqrt(dT))


def _bias_anchored(walk: FactorBlock, ends: np.ndarray) -> FactorBlock:
    """The walk with its steps into the keyframes ``ends`` cut off at their end: there the bias is
    θ's own column, its deviation zero (held by the chain-end placeholder)."""
    into = np.isin(walk.first + 1, ends)
    if not into.any():
        return walk
    Jx = walk.Jx.copy()
    Jx[into, :, BIAS_STATE_DIM + 9:] = 0.0
    return FactorBlock(walk.name, walk.first, walk.stride, walk.n_states, Jx, walk.Jt, walk.cols)


def _gauge(R_W_B: np.ndarray, keyframe: int, local: bool) -> list[FactorBlock]:
    """The minimal gauge fix of a drive at ``keyframe``: its yaw (local states) or its position
    and yaw (world states). It sees trajectory states only (never the bias states)."""
    return [_yaw_gauge(R_W_B, keyframe) if local else gauge_block(R_W_B, keyframe)]


def _end_held(sd: int, local: bool = True) -> list[int]:
    """Columns of a drive's last keyframe held at zero (see :func:`_chain_end`)."""
    return (list(range(6, 9)) if local else []) + (list(range(9, 15)) if sd == BIAS_STATE_DIM else [])


def end_free(sd: int) -> np.ndarray:
    """Columns of a drive's last keyframe (local states) that stay free when a drive is closed
    there: its rotation and body velocity. :mod:`excite.score.live` and :mod:`excite.fleet.mine` close a
    drive "so far" or a window with them, as :func:`_chain_end` closes a whole drive."""
    return np.setdiff1d(np.arange(sd), _end_held(sd))


def _chain_end(keyframe: int, local: bool, sd: int = STATE_DIM) -> list[FactorBlock]:
    """Columns of the last keyframe of a drive that no factor reaches, held at zero: in local
    states its increment (it has no successor), with random-walk biases its bias deviation
    (θ holds the bias there)."""
    rows = _end_held(sd, local)
    if not rows:
        return []
    Jx = np.zeros((1, len(rows), sd))
    Jx[0, np.arange(len(rows)), rows] = 1.0
    return [FactorBlock("placeholder", np.array([keyframe]), 1, 1, Jx, np.zeros((1, len(rows), 0)), _NO_COLS)]


def _local_maps(R: np.ndarray, v: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per keyframe (orientation ``R``, world velocity ``v`` and position ``p``), how world velocity
    and position perturbations follow from local ones: ``δv_world = V_k [δθ_k; δv_k]`` with
    ``V_k = [−R_k[v_k]×, R_k]`` (body velocity ``v_k = R_kᵀ v``) and ``δ(p_{k+1} − p_k) = P_k [δθ_k; δd_k]``
    with ``P_k = [−R_k[d_k]×, R_k]`` (increment ``d_k = R_kᵀ(p_{k+1} − p_k)``), each 3 × 6
    (compiled: :func:`excite.core.kernels.local_maps`)."""
    return kernels.local_maps(R, v, p)


def _to_local(b: FactorBlock, V: np.ndarray, P: np.ndarray, sd: int = STATE_DIM) -> FactorBlock:
    """Re-express a block's world-state Jacobian in local states (maps from :func:`_local_maps`).

    Positions enter every factor only through differences (its position Jacobians sum to zero),
    so ``Σ_a J_p,a δp_{k_a} = Σ_a J_p,a Σ_{first ≤ q < k_a} δ(p_{q+1} − p_q)`` and the position of
    the factor's first keyframe drops out. ``sd`` columns per state (the 9 trajectory states
    first; with ``sd`` = 15 the bias columns are left zero).
    """
    out, seen = kernels.to_local(np.ascontiguousarray(b.Jx), b.first, b.stride, V, P, sd)
    return FactorBlock(b.name, b.first, 1, out.shape[2] // sd, out, b.Jt, b.cols, np.flatnonzero(seen))


def _yaw_gauge(R_W_B: np.ndarray, keyframe: int) -> FactorBlock:
    """A prior on the world yaw of ``keyframe``: the one gauge of the local parametrisation."""
    Jx = np.zeros((1, 1, STATE_DIM))
    Jx[0, 0, ROT] = R_W_B[2] / _GAUGE_SIGMA_YAW_RAD
    return FactorBlock("gauge", np.array([keyframe]), 1, 1, Jx, np.zeros((1, 1, 0)), _NO_COLS)


# --- marginalisation ---------------------------------------------------------------------------
#
# The keyframes are eliminated chunk by chunk (a nested dissection of the chain): a chunk
# ``a … b`` of the drive holds every factor that touches its inner keyframes, so those can be
# eliminated from the chunk's own information alone, in parallel with every other chunk. What
# remains of a chunk (a :class:`Piece`) is the Schur complement on its end keyframes a, b and θ;
# the pieces form a chain over the chunk ends, which is eliminated last.


@dataclass(frozen=True)
class Piece:
    """The information of one chunk ``a … b`` with its inner keyframes eliminated.

    ``H_ee`` over ``e = [x_a, θ]``, ``H_be = H[x_b, e]`` and ``H_bb``; ``diag_tt`` is diag H_θθ
    of the chunk before any elimination (the scale of the data's information)."""

    a: int
    b: int
    H_ee: np.ndarray
    H_be: np.ndarray
    H_bb: np.ndarray
    diag_tt: np.ndarray

    @property
    def state_dim(self) -> int:
        return self.H_bb.shape[0]


def _piece(blocks: Sequence[FactorBlock], a: int, b: int, n_params: int, sd: int) -> Piece:
    """Accumulate ``JᵀJ`` of the blocks of chunk ``a … b`` (keyframe indices relative to a; states
    of dimension ``sd``) and eliminate its inner keyframes (compiled:
    :func:`excite.core.kernels.accumulate`, :func:`~excite.core.kernels.eliminate`)."""
    m, p = b - a, n_params
    band, Hxt, Htt = _accumulated(blocks, m, p, sd)
    D = band.shape[0] - 1
    # the first keyframe joins θ in the border e = [x_a, θ]
    q = sd + p
    Hxe = np.zeros((m + 1, sd, q))
    Hxe[:, :, sd:] = Hxt
    for d in range(1, min(D, m) + 1):
        Hxe[d, :, :sd] = band[d, 0]
    H_ee = np.block([[band[0, 0], Hxt[0]], [Hxt[0].T, Htt]])
    _check_pivot(kernels.eliminate(band, Hxe, H_ee, 1, m), a)
    return Piece(a, b, H_ee, Hxe[m].copy(), band[0, m].copy(), np.diag(Htt).copy())


def _accumulated(blocks: Sequence[FactorBlock], m: int, p: int, sd: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``JᵀJ`` of the blocks of a chunk of ``m + 1`` keyframes in the storage of
    :func:`excite.core.kernels.accumulate`: the band of keyframe blocks, H_xθ and H_θθ."""
    D = max([1] + [blk.stride * (blk.n_states - 1) for blk in blocks])
    band = np.zeros((D + 1, m + 1, sd, sd))
    Hxt = np.zeros((m + 1, sd, p))
    Htt = np.zeros((p, p))
    for blk in blocks:
        kernels.accumulate(blk.Jx, blk.Jt, blk.cols, blk.first, blk.stride, blk.n_states, band, Hxt, Htt,
                           0, blk.n_factors, 0, 1, blk.nonzero_columns(), np.arange(sd))
    return band, Hxt, Htt


def _check_pivot(bad: int, offset: int) -> None:
    if bad >= 0:
        raise EvaluationError(f"the trajectory itself is undetermined by this rig's sensors (the "
                              f"information of keyframe {bad + offset} is singular beyond the gauge)")


def _reduce(pieces: Sequence[Piece], n_params: int) -> np.ndarray:
    """Λ_θ from the pieces: their chain over the chunk ends, eliminated in order."""
    p = n_params
    sd = pieces[0].state_dim
    nodes = sorted({pc.a for pc in pieces} | {pc.b for pc in pieces})
    at = {k: i for i, k in enumerate(nodes)}
    n = len(nodes)
    band = np.zeros((2, n, sd, sd))
    Hxt = np.zeros((n, sd, p))
    Htt = np.zeros((p, p))
    for pc in pieces:
        i, j = at[pc.a], at[pc.b]
        assert j == i + 1, "pieces overlap"
        band[0, i] += pc.H_ee[:sd, :sd]
        band[0, j] += pc.H_bb
        band[1, i] += pc.H_be[:, :sd]
        Hxt[i] += pc.H_ee[:sd, sd:]
        Hxt[j] += pc.H_be[:, sd:]
        Htt += pc.H_ee[sd:, sd:]
    bad = kernels.eliminate(band, Hxt, Htt, 0, n)
    _check_pivot(-1 if bad < 0 else nodes[bad], 0)
    return 0.5 * (Htt + Htt.T)


def marginal(problem: Problem) -> np.ndarray:
    """Marginal information ``Λ_θ`` (p × p) of the calibration, trajectory eliminated (fast path)."""
    edges = _separators(problem)
    C = len(edges) - 1
    per_chunk: list[list[FactorBlock]] = [[] for _ in range(C)]
    for blk in problem.blocks:
        c = np.clip(np.searchsorted(edges, blk.first, side="right") - 1, 0, C - 1)
        order = np.argsort(c, kind="stable")
        bounds = np.searchsorted(c[order], np.arange(C + 1))
        for k in np.flatnonzero(np.diff(bounds)):
            idx = order[bounds[k]:bounds[k + 1]]
            sel = slice(idx[0], idx[-1] + 1) if idx[-1] - idx[0] + 1 == idx.size else idx  # idx increases
            per_chunk[k].append(replace(blk, first=blk.first[sel] - edges[k], Jx=blk.Jx[sel], Jt=blk.Jt[sel]))
    pieces = list(pool().map(lambda c: _piece(per_chunk[c], edges[c], edges[c + 1], problem.n_params,
                                              problem.state_dim), range(C)))
    return _reduce(pieces, problem.n_params)


def _separators(problem: Problem) -> np.ndarray:
    """Chunk ends for :func:`marginal`: keyframes no factor reaches across, about
    ``_CHUNK_KEYFRAMES`` apart (the first and last keyframe always)."""
    K = problem.n_keyframes
    inside = np.zeros(K + 1, dtype=np.int64)  # factors reaching strictly across each keyframe
    for blk in problem.blocks:
        span = blk.stride * (blk.n_states - 1)
        if span > 1:
            inside += np.bincount(blk.first + 1, minlength=K + 1) - np.bincount(blk.first + span, minlength=K + 1)
    free = np.flatnonzero(np.cumsum(inside)[:K] == 0)
    edges = [0]
    while edges[-1] < K - 1:
        i = np.searchsorted(free, edges[-1] + _CHUNK_KEYFRAMES, side="right") - 1
        edges.append(int(free[i]) if free[i] > edges[-1] else int(free[np.searchsorted(free, edges[-1], side="right")]))
    return np.array(edges)


_SLAB = 64  # keyframes accumulated and eliminated together by a sweep (their storage stays in the cache)


def _eliminated(blocks: Sequence[FactorBlock], m: int, carry: tuple, forward: bool, k0: int,
                walk: tuple[np.ndarray, bool] | None = None) -> tuple:
    """One step of a sweep (:func:`_sweep`): the information of chunk ``0 … m`` (``blocks``, keyframe
    indices relative to its start ``k0``) plus ``carry`` on its first keyframe in the sweep's
    order (0 forward, m backward) and θ, with every keyframe but the last one in that order
    eliminated: ``(H_xx, H_xθ, H_θθ)`` on that keyframe and θ.

    Slab by slab of ``_SLAB`` keyframes, in a ring buffer: the factors whose first keyframe (in
    the sweep's order) is in the slab are accumulated, then the slab's keyframes are eliminated
    (every factor that touches them is in by then), and the few keyframes the next slab shares
    move to the ring's front.

    ``walk = (w², anchored)``: the bias random walk of every interval ``k → k+1`` of the chunk
    (:func:`_bias_walk`, whitened by ``w``), added as its information ``w²`` on the bias
    deviations of both keyframes and ``−w²`` between them (the same numbers as the accumulated
    ``JᵀJ``, without forming J); ``anchored``: the last step ends at the drive's end (only its
    first keyframe, see :func:`_bias_anchored`).

    The backward sweep stores a state's bias deviations before its trajectory components
    (:func:`_ring_order`); the carry in and out is in the usual order."""
    sd, p = carry[0].shape[0], carry[2].shape[0]
    D = max([1] + [blk.stride * (blk.n_states - 1) for blk in blocks])
    n = _SLAB + D
    comp = _ring_order(sd, forward)
    band = np.zeros((D + 1, n, sd, sd))
    Hxt = np.zeros((n, sd, p))
    band[0, 0][np.ix_(comp, comp)] = carry[0]
    Hxt[0][comp] = carry[1]
    Htt = carry[2].copy()
    w2, anchored = walk if walk is not None else (np.zeros(0), False)
    bad = kernels.eliminate_slabs(_as_tuple(blocks), m, _SLAB, forward, band, Hxt, Htt, w2, anchored, comp)
    if bad >= 0:
        _check_pivot(bad, k0)
    slabs = np.arange(0, m, _SLAB)
    last = m - slabs[-1] if slabs.size else 0
    return band[0, last][np.ix_(comp, comp)], Hxt[last][comp], Htt


def _ring_order(sd: int, forward: bool) -> np.ndarray:
    """Where a sweep stores each component of a keyframe's state (``comp[c]``, see
    :func:`excite.core.kernels.eliminate_slabs`). Eliminating x_j updates the next state by
    ``H[x_{j+1}, x_j] L_j⁻ᵀ``, which keeps a leading zero block of ``H[x_{j+1}, x_j]`` (in x_j's
    columns) zero, and the elimination skips zero coefficients three at a time. With random-walk
    biases, forward: the next keyframe's biases see the trajectory of x_j through no factor, its
    increment sees nothing of x_j; the usual order (trajectory first) leads with those zeros.
    Backward, x_j is the later keyframe: the earlier trajectory sees neither its biases nor its
    increment (the IMU factor between them ends at x_j), so those go first: biases, increment,
    rotation, velocity. The bias deviations stay contiguous."""
    if forward or sd != BIAS_STATE_DIM:
        return np.arange(sd)
    comp = np.empty(sd, dtype=np.int64)
    comp[np.r_[9:15, 6:9, 0:6]] = np.arange(sd)  # stored order: biases, increment, rotation, velocity
    return comp


_NO_BLOCK = (np.zeros((0, 1, STATE_DIM)), np.zeros((0, 1, 0)), _NO_COLS, np.zeros(0, dtype=np.int64), 1, 1,
             np.zeros(0, dtype=np.int64))


def _as_tuple(blocks: Sequence[FactorBlock]) -> tuple:
    """``blocks`` for the compiled sweep (:func:`excite.core.kernels.eliminate_slabs`): a tuple of
    ``(Jx, Jt, cols, first, stride, n_states, xcols)``, padded with empty blocks to a multiple of 8, so
    that its type, and with it the compiled code, is the same for every rig (up to 8 blocks)."""
    out = [(np.ascontiguousarray(b.Jx), np.ascontiguousarray(b.Jt), np.ascontiguousarray(b.cols, dtype=np.int64),
            np.ascontiguousarray(b.first, dtype=np.int64), int(b.stride), int(b.n_states),
            np.ascontiguousarray(b.nonzero_columns(), dtype=np.int64)) for b in blocks]
    return tuple(out + [_NO_BLOCK] * (-len(out) % 8))


def _theta_diagonal(blocks: Sequence[FactorBlock], p: int) -> np.ndarray:
    """diag H_θθ of ``blocks``: each calibration coordinate's information before the trajectory
    is eliminated (compiled: :func:`excite.core.kernels.theta_diagonal`, 8 blocks at a time)."""
    out = np.zeros(p)
    for i in range(0, len(blocks), 8):
        out += kernels.theta_diagonal(_as_tuple(blocks[i:i + 8]), p)
    return out


@dataclass(frozen=True)
class DriveInformation:
    """What :func:`drive_information` returns: Λ_θ over all rig coordinates and what the report
    needs of the drives (their keyframe count, duration and length, diag H_θθ), with the CPU time
    the threads spent per stage [ms], summed over chunks (wall time on a loaded machine says more
    about the other work than about this one)."""

    information: np.ndarray  # over :func:`columns` (each drive's nuisances apart)
    diag_tt: np.ndarray
    nuisance: np.ndarray  # mask of the nuisance columns
    n_keyframes: int
    duration_s: float
    length_m: float
    thread_ms: dict[str, float]


def drive_information(trajs: Sequence[Trajectory], rig: Rig) -> DriveInformation:
    """Λ_θ of drives calibrated together, streamed: each drive is swept from both ends towards
    the chunk edge in its middle, the two sweeps in parallel on the thread pool. A sweep samples,
    linearises and eliminates one chunk after another, carrying the information of the keyframe
    it has reached and of θ into the next chunk (:func:`_sweep`), so no whole-drive array is ever
    formed; the middle keyframe is eliminated last. :func:`marginal` of :func:`build` gives the
    same Λ_θ from the whole linearised problem.

    Why not :class:`Piece` s: a chunk with both ends kept carries its first keyframe's state in the
    border of every elimination step (q = sd + p columns); a sweep from a drive's end has nothing
    before it to keep (q = p), which saves about 40 % of the elimination's arithmetic with random-walk
    biases (15-wide states, p = 24)."""
    _, nuisance = columns(rig, len(trajs))
    p = nuisance.size
    sd = state_dim(rig)
    tasks, meets = [], []
    offset = 0
    for d, traj in enumerate(trajs):
        K = _check_length(Nominal.grid(traj, rig)[1], rig)
        pair, meet = _sweeps(traj, 0, K - 1, offset, _drive_column_map(rig, d, len(trajs)), rig)
        tasks += pair
        meets.append(meet)
        offset += K

    results = list(pool().map(lambda task: _sweep(*task, rig, p, sd), tasks))
    Lam = sum(_met(results[2 * i][0], results[2 * i + 1][0], meet) for i, meet in enumerate(meets))
    spent = np.sum([r[3] for r in results], axis=0) * 1e3
    return DriveInformation(
        information=0.5 * (Lam + Lam.T), diag_tt=np.sum([r[1] for r in results], axis=0), nuisance=nuisance,
        n_keyframes=offset,
        duration_s=(offset - len(trajs)) / rig.keyframe_rate_hz,
        length_m=float(sum(r[2] for r in results)),
        thread_ms={"sample": float(spent[0]), "linearise": float(spent[1]), "eliminate": float(spent[2])})


def window_information(trajs: Sequence[Trajectory], rig: Rig,
                       windows: Sequence[tuple[int, int]]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Λ_θ (over :func:`columns`) and diag H_θθ of each window ``(k0, k1)`` of the keyframes of
    ``trajs`` (numbered on from one drive to the next, as in :func:`build`) on its own: the
    factors that lie within it, each piece of a drive in it closed as a drive of its own. The
    same as :func:`marginal` of :meth:`Problem.window` of the whole :func:`build`, streamed
    (no whole-drive array; the work on the thread pool): a piece longer than a chunk is swept
    from both ends as :func:`drive_information` sweeps a drive; shorter ones are sampled and
    linearised together, about a chunk at a time, and each is eliminated on its own
    (:func:`_short_pieces`).

    A window's ends are keyframes at multiples of :func:`frame_step` from their drive's start, or
    a drive's last keyframe (:func:`windows`), and it cuts no piece of fewer than 3 keyframes off
    a drive (:func:`trimmed`)."""
    _, nuisance = columns(rig, len(trajs))
    p = nuisance.size
    sd = state_dim(rig)
    Ks = [_check_length(Nominal.grid(t, rig)[1], rig) for t in trajs]
    starts = np.cumsum([0] + Ks[:-1]).tolist()
    step = frame_step(rig)
    long, short = [], [[] for _ in trajs]  # (window, drive, a, b) with a, b within the drive
    for w, (k0, k1) in enumerate(windows):
        if not 0 <= k0 < k1 <= sum(Ks) - 1:
            raise EvaluationError(f"window {k0}..{k1} is not within the drives' keyframes 0..{sum(Ks) - 1}")
        _check_trimmed(starts, k0, k1)
        for d, (s, K) in enumerate(zip(starts, Ks)):
            a, b = max(k0, s) - s, min(k1, s + K - 1) - s
            if a >= b:
                continue
            if a % step or (b % step and b != K - 1):
                raise EvaluationError(f"window {k0}..{k1} cuts a sensor's frame pair: its ends must be "
                                      f"multiples of {step} keyframes from its drive's start")
            (long if b - a > _CHUNK_KEYFRAMES else short[d]).append((w, d, a, b))
    tasks, meets = [], []
    for w, d, a, b in long:
        pair, meet = _sweeps(trajs[d], a, b, starts[d], _drive_column_map(rig, d, len(trajs)), rig)
        tasks += [lambda task=task: _sweep(*task, rig, p, sd) for task in pair]
        meets.append((w, meet))
    groups = []
    for d, pieces in enumerate(short):  # consecutive pieces of a drive, spanning a chunk at most
        for pc in sorted(pieces, key=lambda pc: pc[2]):
            if groups and groups[-1][0][1] == d and pc[3] - groups[-1][0][2] <= _CHUNK_KEYFRAMES:
                groups[-1].append(pc)
            else:
                groups.append([pc])
    tasks += [lambda g=g: _short_pieces(trajs[g[0][1]], [pc[2:] for pc in g], starts[g[0][1]],
                                        _drive_column_map(rig, g[0][1], len(trajs)), rig, p, sd) for g in groups]
    results = list(pool().map(lambda task: task(), tasks))
    out = [(np.zeros((p, p)), np.zeros(p)) for _ in windows]
    for i, (w, meet) in enumerate(meets):
        (fwd, fdiag, *_), (bwd, bdiag, *_) = results[2 * i], results[2 * i + 1]
        out[w][0][...] += _met(fwd, bwd, meet)
        out[w][1][...] += fdiag + bdiag
    for g, res in zip(groups, results[2 * len(meets):]):
        for (w, *_), (Lam, diag) in zip(g, res):
            out[w][0][...] += Lam
            out[w][1][...] += diag
    return [(0.5 * (Lam + Lam.T), diag) for Lam, diag in out]


def _short_pieces(traj: Trajectory, pieces: Sequence[tuple[int, int]], offset: int, col_map: np.ndarray,
                  rig: Rig, p: int, sd: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Λ_θ and diag H_θθ of each piece ``(a, b)`` of a drive (keyframes of it, numbered from
    ``offset`` in messages), each closed as a drive of its own: their span sampled and linearised
    once, then each piece's factors (those within it) swept backward and its first keyframe
    eliminated last."""
    a0, b1 = min(a for a, _ in pieces), max(b for _, b in pieces)
    sub = Nominal.of(traj, rig, keyframes=(a0, b1))
    blocks = [b for b in _on_drive_columns(_linearise(sub, rig, True, True, walk=False), col_map)
              if b is not None and b.n_factors]
    walk = (_walk_weights(rig, float(sub.t[1] - sub.t[0])) ** 2, True) if rig.bias_random_walk else None
    zero = (np.zeros((sd, sd)), np.zeros((sd, p)), np.zeros((p, p)))
    out = []
    for a, b in pieces:
        own = [sel for blk in blocks if (sel := blk.within(a - a0, b - a0)) is not None]
        own += _gauge(sub.R[a - a0], 0, True) + _chain_end(b - a, True, sd)
        carry = _eliminated(own, b - a, zero, False, offset + a, walk)
        out.append((_met(zero, carry, offset + a), _theta_diagonal(own, p)))
    return out


def windows(Ks: Sequence[int], rig: Rig, n: int) -> list[tuple[int, int]]:
    """``n`` windows of about equal length over drives of ``Ks`` keyframes (numbered on, as in
    :func:`build`), for :func:`window_information`: consecutive windows share their edge keyframe,
    edges fall on multiples of :func:`frame_step` from their drive's start (a drive's end stays
    an edge), a piece of fewer than 3 keyframes at a drive boundary is left out (:func:`trimmed`),
    and windows left with fewer than 3 keyframes are dropped."""
    starts = np.cumsum([0] + list(Ks[:-1]))
    step = frame_step(rig)
    edges = []
    for e in np.linspace(0, sum(Ks) - 1, n + 1):
        d = int(np.searchsorted(starts, round(e), side="right")) - 1
        s, K = int(starts[d]), int(Ks[d])
        local = min(max(round((e - s) / step), 0) * step, K - 1)
        if (local > 0 and K - 1 - local < step) or e >= s + K - 1:  # no sliver left before the drive's end
            local = K - 1
        edges.append(s + local)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        span = trimmed(starts.tolist(), a, b)
        if span is not None:
            out.append(span)
    return out


def _sweeps(traj: Trajectory, first: int, last: int, offset: int, col_map: np.ndarray, rig: Rig) -> tuple[list, int]:
    """The two sweeps (:func:`_sweep`'s arguments) over keyframes ``first … last`` of a drive,
    closed as a drive of its own, from both ends towards a chunk edge in the middle; and that
    keyframe (``offset`` on), where they meet (:func:`_met`)."""
    edges = [first + e for e in _chunk_edges(last - first + 1, rig)]
    chunks = list(zip(edges[:-1], edges[1:]))
    h = len(chunks) // 2
    return ([(traj, first, last, offset, chunks[:h], True, col_map),
             (traj, first, last, offset, chunks[h:][::-1], False, col_map)], offset + edges[h])


def _met(forward: tuple, backward: tuple, meet: int) -> np.ndarray:
    """Λ_θ from what two sweeps carried into the keyframe ``meet`` where they met: that keyframe
    eliminated last."""
    (fxx, fxt, ftt), (bxx, bxt, btt) = forward, backward
    Htt = ftt + btt
    _check_pivot(kernels.eliminate((fxx + bxx)[None, None], (fxt + bxt)[None], Htt, 0, 1), meet)
    return Htt


def _sweep(traj: Trajectory, first: int, last: int, offset: int, chunks: Sequence[tuple[int, int]],
           forward: bool, col_map: np.ndarray, rig: Rig, p: int, sd: int):
    """Eliminate the keyframes of ``chunks`` of the drive ``first … last`` of ``traj`` (keyframes
    ``k0 … k1`` each, in the order given: consecutive, running forward or backward) but the last
    one reached, carrying what is eliminated into it and θ: returns that information
    ``(H_xx, H_xθ, H_θθ)``, diag H_θθ of the chunks before elimination, their path length and
    the thread's CPU time [s] per stage."""
    carry = (np.zeros((sd, sd)), np.zeros((sd, p)), np.zeros((p, p)))
    diag, length, spent = np.zeros(p), 0.0, np.zeros(3)
    for k0, k1 in chunks:
        c0 = time.thread_time()
        sub = Nominal.of(traj, rig, keyframes=(k0, k1))
        c1 = time.thread_time()
        blocks = [b for b in _on_drive_columns(_linearise(sub, rig, True, k1 == last, walk=False), col_map)
                  if b is not None and b.n_factors]
        if k0 == first:
            blocks += _gauge(sub.R[0], 0, True)
        if k1 == last:
            blocks += _chain_end(k1 - k0, True, sd)
        walk = (_walk_weights(rig, float(sub.t[1] - sub.t[0])) ** 2, k1 == last) if rig.bias_random_walk else None
        c2 = time.thread_time()
        carry = _eliminated(blocks, k1 - k0, carry, forward, offset + k0, walk)
        diag += _theta_diagonal(blocks, p)
        c3 = time.thread_time()
        length += sub.length_m
        spent += (c1 - c0, c2 - c1, c3 - c2)
    return carry, diag, length, spent


def theta_diagonal(problem: Problem) -> np.ndarray:
    """diag H_θθ of a linearised problem: each calibration coordinate's information before the
    trajectory is eliminated (the normalisation of the rank test, :mod:`excite.score.spectrum`)."""
    return _theta_diagonal(problem.blocks, problem.n_params)


def jacobian(problem: Problem) -> tuple[sp.csr_matrix, list[str]]:
    """The whitened Jacobian ``J`` (sparse, columns: states then θ) and a label per row."""
    rows, cols, vals, labels = [], [], [], []
    r0 = 0
    nx = problem.n_states
    for b in problem.blocks:
        N, r = b.n_factors, b.n_rows
        rid = r0 + np.arange(N * r).reshape(N, r)
        sd, xd = problem.state_dim, b.Jx.shape[2] // b.n_states
        for a in range(b.n_states):
            c = sd * (b.first + a * b.stride)[:, None] + np.arange(xd)[None, :]
            blk = b.Jx[:, :, xd * a: xd * (a + 1)]
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


def state_names(n_keyframes: int, local: bool = True, state_dim: int = STATE_DIM) -> list[str]:
    """Names of the state columns of ``J`` and ``H``, in order (see the module docstring)."""
    if local:
        comps = ["rot_x", "rot_y", "rot_z", "vel_body_x", "vel_body_y", "vel_body_z",
                 "incr_body_x", "incr_body_y", "incr_body_z"]
    else:
        comps = ["rot_x", "rot_y", "rot_z", "pos_x", "pos_y", "pos_z", "vel_x", "vel_y", "vel_z"]
    if state_dim == BIAS_STATE_DIM:
        comps += [f"{k}_bias_dev_{a}" for k in ("gyro", "accel") for a in "xyz"]
    return [f"x{k}.{c}" for k in range(n_keyframes) for c in comps]


def at_keyframe(blocks: list, sd: int, p: int) -> np.ndarray:
    """``JᵀJ`` over ``[x, θ]`` ((sd + p) square) of factors that see one keyframe's state only
    (the gauge; the non-holonomic constraint, whose slip angle is a θ column)."""
    band = np.zeros((1, 1, sd, sd))
    Hxt, Htt = np.zeros((1, sd, p)), np.zeros((p, p))
    for b in blocks:
        kernels.accumulate(b.Jx, b.Jt, b.cols, b.first, b.stride, b.n_states, band, Hxt, Htt, 0, b.n_factors, 0, 1,
                           b.nonzero_columns(), np.arange(sd))
    H = np.zeros((sd + p, sd + p))
    H[:sd, :sd] = np.tril(band[0, 0]) + np.tril(band[0, 0], -1).T
    H[:sd, sd:] = Hxt[0]
    H[sd:, :sd] = Hxt[0].T
    H[sd:, sd:] = Htt
    return H


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
