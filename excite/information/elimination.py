"""The marginal information of the calibration: the trajectory eliminated from ``H = JᵀJ``,

    Λ_θ = H_θθ − H_θx H_xx⁻¹ H_xθ

exploiting that H_xx is block-banded (a keyframe's state meets only its neighbours'): the drive
is cut into chunks of keyframes that no factor reaches across, and the keyframes are eliminated
with a compiled block Cholesky (:mod:`.kernels`). :func:`marginal` does it for a linearised
:class:`~.problem.Problem`: every chunk eliminates its inner keyframes (:func:`piece`), in
parallel with the others, and the chain of chunk ends is eliminated last. :func:`drive_information`
streams it from the trajectories (the evaluator's path): each drive is swept from both ends at
once, chunk after chunk, each chunk sampled and linearised where it is eliminated, towards a
keyframe in its middle. :func:`window_information` does the same for windows of a drive, each
closed as a drive of its own. Cost is linear in the drive length and memory bounded by a chunk;
a dense H_xx is never formed (:func:`excite.information.dense.marginal_dense` is the
plain-numpy reference the tests hold both to). Every drive is closed by its rig's
:class:`~.closure.Closure`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..core.parallel import pool
from ..errors import EvaluationError
from ..factors.base import STATE_DIM, FactorBlock, Nominal, RigView
from ..motion.trajectory import Trajectory
from . import kernels
from .closure import Closure
from .problem import (
    CHUNK_KEYFRAMES,
    Problem,
    check_length,
    check_trimmed,
    chunk_edges,
    columns,
    drive_column_map,
    frame_step,
    linearise,
    on_drive_columns,
    trimmed,
)

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


def piece(blocks: Sequence[FactorBlock], a: int, b: int, n_params: int, sd: int) -> Piece:
    """Accumulate ``JᵀJ`` of the blocks of chunk ``a … b`` (keyframe indices relative to a; states
    of dimension ``sd``) and eliminate its inner keyframes (compiled:
    :func:`excite.information.kernels.accumulate`, :func:`~excite.information.kernels.eliminate`)."""
    m, p = b - a, n_params
    band, Hxt, Htt = accumulated(blocks, m, p, sd)
    D = band.shape[0] - 1
    # the first keyframe joins θ in the border e = [x_a, θ]
    q = sd + p
    Hxe = np.zeros((m + 1, sd, q))
    Hxe[:, :, sd:] = Hxt
    for d in range(1, min(D, m) + 1):
        Hxe[d, :, :sd] = band[d, 0]
    H_ee = np.block([[band[0, 0], Hxt[0]], [Hxt[0].T, Htt]])
    check_pivot(kernels.eliminate(band, Hxe, H_ee, 1, m), a)
    return Piece(a, b, H_ee, Hxe[m].copy(), band[0, m].copy(), np.diag(Htt).copy())


def accumulated(blocks: Sequence[FactorBlock], m: int, p: int, sd: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``JᵀJ`` of the blocks of a chunk of ``m + 1`` keyframes in the storage of
    :func:`excite.information.kernels.accumulate`: the band of keyframe blocks, H_xθ and H_θθ."""
    D = max([1] + [blk.stride * (blk.n_states - 1) for blk in blocks])
    band = np.zeros((D + 1, m + 1, sd, sd))
    Hxt = np.zeros((m + 1, sd, p))
    Htt = np.zeros((p, p))
    for blk in blocks:
        kernels.accumulate(blk.Jx, blk.Jt, blk.cols, blk.first, blk.stride, blk.n_states, band, Hxt, Htt,
                           0, blk.n_factors, 0, 1, blk.nonzero_columns(), np.arange(sd))
    return band, Hxt, Htt


def check_pivot(bad: int, offset: int) -> None:
    if bad >= 0:
        raise EvaluationError(f"the trajectory itself is undetermined by this rig's sensors (the "
                              f"information of keyframe {bad + offset} is singular beyond the gauge)")


def reduce(pieces: Sequence[Piece], n_params: int) -> np.ndarray:
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
    check_pivot(-1 if bad < 0 else nodes[bad], 0)
    return 0.5 * (Htt + Htt.T)


def marginal(problem: Problem) -> np.ndarray:
    """Marginal information ``Λ_θ`` (p × p) of the calibration, trajectory eliminated (fast path)."""
    edges = separators(problem)
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
    pieces = list(pool().map(lambda c: piece(per_chunk[c], edges[c], edges[c + 1], problem.n_params,
                                              problem.state_dim), range(C)))
    return reduce(pieces, problem.n_params)


def separators(problem: Problem) -> np.ndarray:
    """Chunk ends for :func:`marginal`: keyframes no factor reaches across, about
    ``CHUNK_KEYFRAMES`` apart (the first and last keyframe always)."""
    K = problem.n_keyframes
    inside = np.zeros(K + 1, dtype=np.int64)  # factors reaching strictly across each keyframe
    for blk in problem.blocks:
        span = blk.stride * (blk.n_states - 1)
        if span > 1:
            inside += np.bincount(blk.first + 1, minlength=K + 1) - np.bincount(blk.first + span, minlength=K + 1)
    free = np.flatnonzero(np.cumsum(inside)[:K] == 0)
    edges = [0]
    while edges[-1] < K - 1:
        i = np.searchsorted(free, edges[-1] + CHUNK_KEYFRAMES, side="right") - 1
        edges.append(int(free[i]) if free[i] > edges[-1] else int(free[np.searchsorted(free, edges[-1], side="right")]))
    return np.array(edges)


SLAB = 64  # keyframes accumulated and eliminated together by a sweep (their storage stays in the cache)


def eliminated(blocks: Sequence[FactorBlock], m: int, carry: tuple, forward: bool, k0: int,
                walk: tuple[np.ndarray, bool] | None = None) -> tuple:
    """One step of a sweep (:func:`sweep`): the information of chunk ``0 … m`` (``blocks``, keyframe
    indices relative to its start ``k0``) plus ``carry`` on its first keyframe in the sweep's
    order (0 forward, m backward) and θ, with every keyframe but the last one in that order
    eliminated: ``(H_xx, H_xθ, H_θθ)`` on that keyframe and θ.

    Slab by slab of ``SLAB`` keyframes, in a ring buffer: the factors whose first keyframe (in
    the sweep's order) is in the slab are accumulated, then the slab's keyframes are eliminated
    (every factor that touches them is in by then), and the few keyframes the next slab shares
    move to the ring's front.

    ``walk = (w², anchored)``: the bias random walk of every interval ``k → k+1`` of the chunk
    (:meth:`Closure.walk <excite.information.closure.Closure.walk>`, whitened by ``w``), added as its information ``w²`` on the bias
    deviations of both keyframes and ``−w²`` between them (the same numbers as the accumulated
    ``JᵀJ``, without forming J); ``anchored``: the last step ends at the drive's end (only its
    first keyframe, see :meth:`~excite.information.closure.Closure.anchored`).

    The backward sweep stores a state's bias deviations before its trajectory components
    (:func:`ring_order`); the carry in and out is in the usual order."""
    sd, p = carry[0].shape[0], carry[2].shape[0]
    D = max([1] + [blk.stride * (blk.n_states - 1) for blk in blocks])
    n = SLAB + D
    comp = ring_order(sd, forward)
    band = np.zeros((D + 1, n, sd, sd))
    Hxt = np.zeros((n, sd, p))
    band[0, 0][np.ix_(comp, comp)] = carry[0]
    Hxt[0][comp] = carry[1]
    Htt = carry[2].copy()
    w2, anchored = walk if walk is not None else (np.zeros(0), False)
    bad = kernels.eliminate_slabs(as_kernel_blocks(blocks), m, SLAB, forward, band, Hxt, Htt, w2, anchored, comp)
    if bad >= 0:
        check_pivot(bad, k0)
    slabs = np.arange(0, m, SLAB)
    last = m - slabs[-1] if slabs.size else 0
    return band[0, last][np.ix_(comp, comp)], Hxt[last][comp], Htt


def ring_order(sd: int, forward: bool) -> np.ndarray:
    """Where a sweep stores each component of a keyframe's state (``comp[c]``, see
    :func:`excite.information.kernels.eliminate_slabs`). Eliminating x_j updates the next state by
    ``H[x_{j+1}, x_j] L_j⁻ᵀ``, which keeps a leading zero block of ``H[x_{j+1}, x_j]`` (in x_j's
    columns) zero, and the elimination skips zero coefficients three at a time. With random-walk
    biases, forward: the next keyframe's biases see the trajectory of x_j through no factor, its
    increment sees nothing of x_j; the usual order (trajectory first) leads with those zeros.
    Backward, x_j is the later keyframe: the earlier trajectory sees neither its biases nor its
    increment (the IMU factor between them ends at x_j), so those go first: biases, increment,
    rotation, velocity. The bias deviations stay contiguous."""
    if forward or sd == STATE_DIM:
        return np.arange(sd)
    comp = np.empty(sd, dtype=np.int64)
    comp[np.r_[STATE_DIM:sd, 6:9, 0:6]] = np.arange(sd)  # stored order: biases, increment, rotation, velocity
    return comp


def as_kernel_blocks(blocks: Sequence[FactorBlock]) -> tuple:
    """``blocks`` for the compiled sweep (:func:`excite.information.kernels.eliminate_slabs`): a tuple of
    ``(Jx, Jt, cols, first, stride, n_states, xcols)``."""
    return tuple((np.ascontiguousarray(b.Jx), np.ascontiguousarray(b.Jt), np.ascontiguousarray(b.cols, dtype=np.int64),
                  np.ascontiguousarray(b.first, dtype=np.int64), int(b.stride), int(b.n_states),
                  np.ascontiguousarray(b.nonzero_columns(), dtype=np.int64)) for b in blocks)


def diagonal(blocks: Sequence[FactorBlock], p: int) -> np.ndarray:
    """diag H_θθ of ``blocks``: each calibration coordinate's information before the trajectory
    is eliminated (:func:`excite.information.kernels.theta_diagonal`)."""
    return kernels.theta_diagonal(as_kernel_blocks(blocks), p)


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


def drive_information(trajs: Sequence[Trajectory], rig: RigView,
                      meanwhile: Callable[[], object] | None = None) -> DriveInformation:
    """Λ_θ of drives calibrated together, streamed: each drive is swept from both ends towards
    the chunk edge in its middle, the two sweeps in parallel on the thread pool. A sweep samples,
    linearises and eliminates one chunk after another, carrying the information of the keyframe
    it has reached and of θ into the next chunk (:func:`sweep`), so no whole-drive array is ever
    formed; the middle keyframe is eliminated last; ``meanwhile()``, where given, runs in the
    calling thread while the sweeps do. :func:`marginal` of :func:`build` gives the
    same Λ_θ from the whole linearised problem.

    Why not :class:`Piece` s: a chunk with both ends kept carries its first keyframe's state in the
    border of every elimination step (q = sd + p columns); a sweep from a drive's end has nothing
    before it to keep (q = p), which saves about 40 % of the elimination's arithmetic with random-walk
    biases (15-wide states, p = 24)."""
    _, nuisance = columns(rig, len(trajs))
    p = nuisance.size
    closure = Closure.of(rig)
    sd = closure.state_dim
    tasks, meets = [], []
    offset = 0
    for d, traj in enumerate(trajs):
        K = check_length(Nominal.grid(traj, rig)[1], rig)
        pair, meet = sweeps(traj, 0, K - 1, offset, drive_column_map(rig, d, len(trajs)), rig)
        tasks += pair
        meets.append(meet)
        offset += K

    futures = [pool().submit(sweep, *task, rig, p, closure) for task in tasks]
    if meanwhile is not None:  # the caller's own work, in this thread while the sweeps run
        meanwhile()
    results = [f.result() for f in futures]
    Lam = sum(met(results[2 * i][0], results[2 * i + 1][0], meet) for i, meet in enumerate(meets))
    spent = np.sum([r[3] for r in results], axis=0) * 1e3
    return DriveInformation(
        information=0.5 * (Lam + Lam.T), diag_tt=np.sum([r[1] for r in results], axis=0), nuisance=nuisance,
        n_keyframes=offset,
        duration_s=(offset - len(trajs)) / rig.keyframe_rate_hz,
        length_m=float(sum(r[2] for r in results)),
        thread_ms={"sample": float(spent[0]), "linearise": float(spent[1]), "eliminate": float(spent[2])})


def window_information(trajs: Sequence[Trajectory], rig: RigView,
                       windows: Sequence[tuple[int, int]]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Λ_θ (over :func:`columns`) and diag H_θθ of each window ``(k0, k1)`` of the keyframes of
    ``trajs`` (numbered on from one drive to the next, as in :func:`build`) on its own: the
    factors that lie within it, each piece of a drive in it closed as a drive of its own. The
    same as :func:`marginal` of :meth:`Problem.window` of the whole :func:`build`, streamed
    (no whole-drive array; the work on the thread pool): a piece longer than a chunk is swept
    from both ends as :func:`drive_information` sweeps a drive; shorter ones are sampled and
    linearised together, about a chunk at a time, and each is eliminated on its own
    (:func:`short_pieces`).

    A window's ends are keyframes at multiples of :func:`frame_step` from their drive's start, or
    a drive's last keyframe (:func:`windows`), and it cuts no piece of fewer than 3 keyframes off
    a drive (:func:`trimmed`)."""
    _, nuisance = columns(rig, len(trajs))
    p = nuisance.size
    closure = Closure.of(rig)
    sd = closure.state_dim
    Ks = [check_length(Nominal.grid(t, rig)[1], rig) for t in trajs]
    starts = np.cumsum([0] + Ks[:-1]).tolist()
    step = frame_step(rig)
    long, short = [], [[] for _ in trajs]  # (window, drive, a, b) with a, b within the drive
    for w, (k0, k1) in enumerate(windows):
        if not 0 <= k0 < k1 <= sum(Ks) - 1:
            raise EvaluationError(f"window {k0}..{k1} is not within the drives' keyframes 0..{sum(Ks) - 1}")
        check_trimmed(starts, k0, k1)
        for d, (s, K) in enumerate(zip(starts, Ks)):
            a, b = max(k0, s) - s, min(k1, s + K - 1) - s
            if a >= b:
                continue
            if a % step or (b % step and b != K - 1):
                raise EvaluationError(f"window {k0}..{k1} cuts a sensor's frame pair: its ends must be "
                                      f"multiples of {step} keyframes from its drive's start")
            (long if b - a > CHUNK_KEYFRAMES else short[d]).append((w, d, a, b))
    tasks, meets = [], []
    for w, d, a, b in long:
        pair, meet = sweeps(trajs[d], a, b, starts[d], drive_column_map(rig, d, len(trajs)), rig)
        tasks += [lambda task=task: sweep(*task, rig, p, closure) for task in pair]
        meets.append((w, meet))
    groups = []
    for d, pieces in enumerate(short):  # consecutive pieces of a drive, spanning a chunk at most
        for pc in sorted(pieces, key=lambda pc: pc[2]):
            if groups and groups[-1][0][1] == d and pc[3] - groups[-1][0][2] <= CHUNK_KEYFRAMES:
                groups[-1].append(pc)
            else:
                groups.append([pc])
    tasks += [lambda g=g: short_pieces(trajs[g[0][1]], [pc[2:] for pc in g], starts[g[0][1]],
                                        drive_column_map(rig, g[0][1], len(trajs)), rig, p, closure) for g in groups]
    results = list(pool().map(lambda task: task(), tasks))
    out = [(np.zeros((p, p)), np.zeros(p)) for _ in windows]
    for i, (w, meet) in enumerate(meets):
        (fwd, fdiag, *_), (bwd, bdiag, *_) = results[2 * i], results[2 * i + 1]
        out[w][0][...] += met(fwd, bwd, meet)
        out[w][1][...] += fdiag + bdiag
    for g, res in zip(groups, results[2 * len(meets):]):
        for (w, *_), (Lam, diag) in zip(g, res):
            out[w][0][...] += Lam
            out[w][1][...] += diag
    return [(0.5 * (Lam + Lam.T), diag) for Lam, diag in out]


def short_pieces(traj: Trajectory, pieces: Sequence[tuple[int, int]], offset: int, col_map: np.ndarray,
                  rig: RigView, p: int, closure: Closure) -> list[tuple[np.ndarray, np.ndarray]]:
    """Λ_θ and diag H_θθ of each piece ``(a, b)`` of a drive (keyframes of it, numbered from
    ``offset`` in messages), each closed as a drive of its own: their span sampled and linearised
    once, then each piece's factors (those within it) swept backward and its first keyframe
    eliminated last."""
    sd = closure.state_dim
    a0, b1 = min(a for a, _ in pieces), max(b for _, b in pieces)
    sub = Nominal.of(traj, rig, keyframes=(a0, b1))
    blocks = [b for b in on_drive_columns(linearise(sub, rig, closure, True, walk=False), col_map)
              if b is not None and b.n_factors]
    walk = (closure.walk_weights(float(sub.t[1] - sub.t[0])) ** 2, True) if sd > STATE_DIM else None
    zero = (np.zeros((sd, sd)), np.zeros((sd, p)), np.zeros((p, p)))
    out = []
    for a, b in pieces:
        own = [sel for blk in blocks if (sel := blk.within(a - a0, b - a0)) is not None]
        own += on_drive_columns(closure.start(sub.window(a - a0, b - a0), rig), col_map) + closure.end(b - a)
        carry = eliminated(own, b - a, zero, False, offset + a, walk)
        out.append((met(zero, carry, offset + a), diagonal(own, p)))
    return out


def windows(Ks: Sequence[int], rig: RigView, n: int) -> list[tuple[int, int]]:
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


def sweeps(traj: Trajectory, first: int, last: int, offset: int, col_map: np.ndarray, rig: RigView) -> tuple[list, int]:
    """The two sweeps (:func:`sweep`'s arguments) over keyframes ``first … last`` of a drive,
    closed as a drive of its own, from both ends towards a chunk edge in the middle; and that
    keyframe (``offset`` on), where they meet (:func:`met`)."""
    edges = [first + e for e in chunk_edges(last - first + 1, rig)]
    chunks = list(zip(edges[:-1], edges[1:]))
    h = len(chunks) // 2
    return ([(traj, first, last, offset, chunks[:h], True, col_map),
             (traj, first, last, offset, chunks[h:][::-1], False, col_map)], offset + edges[h])


def met(forward: tuple, backward: tuple, meet: int) -> np.ndarray:
    """Λ_θ from what two sweeps carried into the keyframe ``meet`` where they met: that keyframe
    eliminated last."""
    (fxx, fxt, ftt), (bxx, bxt, btt) = forward, backward
    Htt = ftt + btt
    check_pivot(kernels.eliminate((fxx + bxx)[None, None], (fxt + bxt)[None], Htt, 0, 1), meet)
    return Htt


def sweep(traj: Trajectory, first: int, last: int, offset: int, chunks: Sequence[tuple[int, int]],
           forward: bool, col_map: np.ndarray, rig: RigView, p: int, closure: Closure):
    """Eliminate the keyframes of ``chunks`` of the drive ``first … last`` of ``traj`` (keyframes
    ``k0 … k1`` each, in the order given: consecutive, running forward or backward) but the last
    one reached, carrying what is eliminated into it and θ: returns that information
    ``(H_xx, H_xθ, H_θθ)``, diag H_θθ of the chunks before elimination, their path length and
    the thread's CPU time [s] per stage."""
    sd = closure.state_dim
    carry = (np.zeros((sd, sd)), np.zeros((sd, p)), np.zeros((p, p)))
    diag, length, spent = np.zeros(p), 0.0, np.zeros(3)
    for k0, k1 in chunks:
        c0 = time.thread_time()
        sub = Nominal.of(traj, rig, keyframes=(k0, k1))
        c1 = time.thread_time()
        blocks = [b for b in on_drive_columns(linearise(sub, rig, closure, k1 == last, walk=False), col_map)
                  if b is not None and b.n_factors]
        if k0 == first:
            blocks += on_drive_columns(closure.start(sub, rig), col_map)
        if k1 == last:
            blocks += closure.end(k1 - k0)
        walk = (closure.walk_weights(float(sub.t[1] - sub.t[0])) ** 2, k1 == last) if sd > STATE_DIM else None
        c2 = time.thread_time()
        carry = eliminated(blocks, k1 - k0, carry, forward, offset + k0, walk)
        diag += diagonal(blocks, p)
        c3 = time.thread_time()
        length += sub.length_m
        spent += (c1 - c0, c2 - c1, c3 - c2)
    return carry, diag, length, spent


def theta_diagonal(problem: Problem) -> np.ndarray:
    """diag H_θθ of a linearised problem: each calibration coordinate's information before the
    trajectory is eliminated (the normalisation of the rank test, :mod:`excite.score.spectrum`)."""
    return diagonal(problem.blocks, problem.n_params)


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
