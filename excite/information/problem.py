"""The joint information problem of a drive: every factor of a rig linearised at the drive's
nominal motion, as whitened Jacobian blocks (:class:`Problem`).

:func:`linearise` linearises the factors of one chunk of keyframes, looping over the rig's
measurement kinds (:mod:`excite.factors`), in the trajectory parametrisation of the rig's
closure (:mod:`.closure`): world states ``[δθ, δp, δv]``, or local ones ``[δθ_k, δv_k, δd_k]``
(body velocity, body-frame increment to the next keyframe) when no kind observes absolute
position. :func:`build` linearises whole drives (several drives share the calibration θ and
nothing else: :func:`columns`); :mod:`.elimination` eliminates the trajectory from ``H = JᵀJ``.

A chunk ``k0 … k1`` owns the factors of pairs ``k0 → … → k1`` and the one-keyframe factors at
``k0 … k1 − 1`` (and at ``k1`` if it ends the drive): chunks cut at multiples of every kind's
stride (:func:`frame_step`) hold every factor exactly once.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.parallel import n_threads, pool
from ..errors import EvaluationError
from ..factors import base as registry
from ..factors import kernels as factor_kernels
from ..factors.base import STATE_DIM, FactorBlock, Nominal, RigView
from . import kernels
from .closure import ORIGIN, Closure


@dataclass(frozen=True)
class Problem:
    """Whitened Jacobian blocks of every factor of a drive (see
    :class:`~excite.factors.base.FactorBlock`), closed by ``closure``."""

    n_keyframes: int
    n_params: int
    blocks: tuple[FactorBlock, ...]
    R_W_B: np.ndarray  # nominal body orientation per keyframe (for gauge fixes of windows)
    closure: Closure
    chain_starts: tuple[int, ...] = (0,)  # first keyframe of each drive (drives share only θ)
    # what a drive that would start at a keyframe adds there (:meth:`Closure.start`: the gauge fix,
    # the openings of its kinds' chains), for :meth:`window`
    start_at: Callable[[int], list[FactorBlock]] | None = field(default=None, compare=False)

    @property
    def local(self) -> bool:
        return self.closure.local

    @property
    def state_dim(self) -> int:
        return self.closure.state_dim

    @property
    def n_states(self) -> int:
        return self.state_dim * self.n_keyframes

    @property
    def bandwidth_blocks(self) -> int:
        return max(b.stride * (b.n_states - 1) for b in self.blocks)

    def window(self, k0: int, k1: int) -> "Problem":
        """The factors that lie entirely within keyframes ``k0..k1``, re-indexed, each piece of a
        drive in it closed as a drive of its own (every piece needs 3 keyframes: see :func:`trimmed`)."""
        check_trimmed(self.chain_starts, k0, k1)
        out = []
        starts = [s - k0 for s in sorted({k0, *(s for s in self.chain_starts if k0 < s <= k1)})]
        ends = [s - 1 for s in starts[1:]] + [k1 - k0]
        for b in self.blocks:
            if b.name in ("gauge", "placeholder") or self.closure.is_opening(b):
                continue
            sel = b.within(k0, k1)
            if sel is not None:
                if b.name == "bias_walk":  # the bias columns of θ are the bias at each piece's end
                    sel = self.closure.anchored(sel, np.asarray(ends))
                out.append(sel)
        R = self.R_W_B[k0:k1 + 1]
        for s, e in zip(starts, ends):
            start = (self.closure.fix(R[s], 0) if self.start_at is None else self.start_at(k0 + s))
            out += [b.shifted(s) for b in start] + self.closure.end(e)
        return Problem(k1 - k0 + 1, self.n_params, tuple(out), R, self.closure, tuple(starts))

    def without_gauge(self) -> "Problem":
        return Problem(self.n_keyframes, self.n_params, tuple(b for b in self.blocks if b.name != "gauge"),
                       self.R_W_B, self.closure, self.chain_starts, self.start_at)


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


def check_trimmed(starts: Sequence[int], k0: int, k1: int) -> None:
    if trimmed(starts, k0, k1) != (k0, k1):
        raise EvaluationError(f"keyframes {k0}..{k1} cut a piece of fewer than 3 keyframes off a drive")


def own_columns(rig: RigView) -> np.ndarray:
    """Indices of the coordinates every drive has of its own: its nuisances (a monocular camera's
    scale, tyre slip) and the drifting ones (each recording's bias process is its own)."""
    drift = set(Closure.of(rig).walk_columns.tolist())
    return np.flatnonzero([c.nuisance or i in drift for i, c in enumerate(rig.coordinates)])


def columns(rig: RigView, n_drives: int) -> tuple[list[str], np.ndarray]:
    """Names and nuisance mask of the parameter columns of ``n_drives`` drives calibrated
    together: the rig's coordinates, which the *last* drive's own coordinates (:func:`own_columns`)
    use, then each earlier drive's own coordinates as nuisances (``cam_front.scale@0``): drives
    share the calibration and nothing else. With random-walk biases the scored bias is therefore
    the bias at the end of the last drive. A rig that observes absolute position then has each
    drive's origin (``drive.origin_x@0`` …: :attr:`.closure.Closure.origin`), nuisances too."""
    own = [rig.coordinates[i].name for i in own_columns(rig)]
    names = [c.name for c in rig.coordinates] + [f"{n}@{d}" for d in range(n_drives - 1) for n in own]
    if Closure.of(rig).origin:
        names += [f"{n}@{d}" for d in range(n_drives) for n in ORIGIN]
    mask = np.array([c.nuisance for c in rig.coordinates] + [True] * (len(names) - len(rig.coordinates)))
    return names, mask


def drive_column_map(rig: RigView, drive: int, n_drives: int) -> np.ndarray:
    """Column of each rig coordinate in drive ``drive``'s factors (see :func:`columns`), then of
    the drive's origin where the rig has one (the slots after the rig's coordinates)."""
    p = len(rig.coordinates)
    out = np.arange(p)
    own = own_columns(rig)
    if drive < n_drives - 1 and own.size:
        out[own] = p + drive * own.size + np.arange(own.size)
    if Closure.of(rig).origin:
        out = np.r_[out, p + (n_drives - 1) * own.size + 3 * drive + np.arange(3)]
    return out


def on_drive_columns(blocks: list, col_map: np.ndarray) -> list:
    """``blocks`` with their θ columns moved to a drive's own (:func:`drive_column_map`)."""
    return [b if b is None or not b.cols.size else replace(b, cols=col_map[b.cols]) for b in blocks]


def build(nom: Nominal | list[Nominal], rig: RigView, gauge_keyframe: int = 0, local: bool | None = None) -> Problem:
    """Linearise every factor of ``rig`` on the nominal motion ``nom``.

    A list of nominal motions is several drives calibrated together: they share the calibration θ
    and nothing else (each has its own trajectory, gauge and nuisance columns: :func:`columns`).
    ``local`` forces the trajectory parametrisation (default: the rig's closure's); the gauge of
    each drive is fixed at its keyframe ``gauge_keyframe``.
    """
    noms = nom if isinstance(nom, list) else [nom]
    closure = Closure.of(rig, local)
    p = len(columns(rig, len(noms))[0])
    parts: list[FactorBlock] = []
    fixes: list[FactorBlock] = []
    starts, R_all, offset = [], [], 0
    for d, n in enumerate(noms):
        col_map = drive_column_map(rig, d, len(noms))
        K = check_length(n.n_keyframes, rig)
        if not -K <= gauge_keyframe < K:
            raise EvaluationError(f"gauge keyframe {gauge_keyframe} is outside the drive")
        edges = chunk_edges(K, rig)
        per_chunk = pool().map(lambda c: [None if b is None else b.shifted(edges[c]) for b in on_drive_columns(
                                          linearise(n.window(edges[c], edges[c + 1]), rig, closure,
                                                    edges[c + 1] == K - 1), col_map)],
                               range(len(edges) - 1))
        # kind-major, each kind in time order (the rows of J follow it)
        parts += [b.shifted(offset) for kind in zip(*per_chunk) for b in kind if b is not None and b.n_factors]
        g = gauge_keyframe % K
        fixes += [b.shifted(offset) for b in on_drive_columns(closure.start(n, rig, g), col_map) + closure.end(K - 1)]
        starts.append(offset)
        R_all.append(n.R)
        offset += K
    ends = np.cumsum([n.n_keyframes for n in noms])

    def start_at(k: int) -> list[FactorBlock]:
        d = int(np.searchsorted(ends, k, side="right"))
        local = k - (ends[d] - noms[d].n_keyframes)
        return on_drive_columns(closure.start(noms[d].window(local, local), rig), drive_column_map(rig, d, len(noms)))
    return Problem(offset, p, tuple(parts + fixes), np.concatenate(R_all), closure, tuple(starts), start_at)


def check_length(K: int, rig: RigView) -> int:
    if K < 3:
        raise EvaluationError(f"the drive is too short: {K} keyframes at {rig.keyframe_rate_hz:g} Hz, "
                              f"need at least 3")
    return K


CHUNK_KEYFRAMES = 3000  # keyframes per task at most: bounded memory, little interpreter time per keyframe


def chunk_edges(K: int, rig: RigView) -> list[int]:
    """Keyframes that cut a drive into chunks of at most about :data:`CHUNK_KEYFRAMES`, as many as a
    multiple of the thread count (every thread gets an equal share), at multiples of every
    kind's stride (so each factor falls in exactly one chunk: see :func:`linearise`)."""
    step = frame_step(rig)
    n = -(-(K - 1) // CHUNK_KEYFRAMES)
    n = -(-n // n_threads()) * n_threads()
    size = max(step, -(-(K - 1) // (n * step)) * step)
    return list(range(0, K - 1, size)) + [K - 1]


def frame_step(rig: RigView) -> int:
    """The fewest keyframes that hold a whole number of frames of every sensor (the least common
    multiple of every kind's stride): a chunk or window that starts and ends at multiples of it,
    counted from its drive's start, cuts no sensor's frame pair."""
    strides = [registry.stride(i.kind, rig, i.entry) for i in registry.instances(rig)] or [1]
    return int(np.lcm.reduce(strides))


def linearise(sub: Nominal, rig: RigView, closure: Closure, last: bool, walk: bool = True) -> list[FactorBlock | None]:
    """Every factor of one chunk ``k0 … k1`` of a drive (indices relative to ``k0``), kind by kind
    (:func:`excite.factors.base.instances`), in the closure's parametrisation.

    The chunk owns the factors of pairs within it and the one-keyframe factors at ``k0 … k1−1``
    (and at ``k1`` if it ends the drive). With drifting coordinates (random-walk biases) only the
    blocks that see them are widened to the deviation states (the others stay 9 wide:
    :func:`excite.information.kernels.accumulate` places them in the first 9 components); a block
    sees the value at its first keyframe (the θ column plus the deviation there), and the walk
    links consecutive deviations; the deviation at the drive's last keyframe is zero (θ is the
    value there), so the walk's last step does not reach it. ``walk=False`` leaves the walk out
    (a sweep adds its constant information directly: :func:`excite.information.elimination.eliminated`).
    """
    m = sub.n_keyframes - 1
    blocks: list[FactorBlock | None] = []
    for inst in registry.instances(rig):
        b = factor_kernels.jacobians(inst.kind, sub, rig, inst.entry)
        if b is not None and inst.kind.arity == 1 and not last:
            b = b.select(b.first < m)
        if b is not None and "position" in inst.kind.breaks:
            b = closure.absolute(b, rig)
        blocks.append(b)
    if closure.local:
        V, P = kernels.local_maps(sub.R, sub.v, sub.p)
        blocks = [None if b is None else to_local(b, V, P, closure if closure.sees_drift(b) else None) for b in blocks]
    else:
        blocks = [b if b is None or not closure.sees_drift(b) else closure.widened(b) for b in blocks]
    if closure.state_dim > STATE_DIM and walk:
        steps = closure.walk(m, float(sub.t[1] - sub.t[0]))
        blocks.append(closure.anchored(steps, np.array([m])) if last else steps)
    return blocks


def to_local(b: FactorBlock, V: np.ndarray, P: np.ndarray, drift: Closure | None = None) -> FactorBlock:
    """Re-express a block's world-state Jacobian in local states, with the maps of
    :func:`excite.information.kernels.local_maps`: ``δv_world = V_k [δθ_k; δv_k]`` with
    ``V_k = [−R_k[v_k]×, R_k]`` (body velocity ``v_k = R_kᵀ v``) and
    ``δ(p_{k+1} − p_k) = P_k [δθ_k; δd_k]`` with ``P_k = [−R_k[d_k]×, R_k]`` (increment
    ``d_k = R_kᵀ(p_{k+1} − p_k)``).

    Positions enter the factor only through differences (its position Jacobians sum to zero:
    every kind that does not break the translation symmetry, which the contract tests check), so
    ``Σ_a J_p,a δp_{k_a} = Σ_a J_p,a Σ_{first ≤ q < k_a} δ(p_{q+1} − p_q)`` and the position of
    the factor's first keyframe drops out. The 9 trajectory states per keyframe; with ``drift``, a
    closure with drifting coordinates that ``b`` sees, its states (the deviations after them), with
    the block's drifting θ columns on the deviations at its first keyframe
    (:meth:`Closure.with_deviations <excite.information.closure.Closure.with_deviations>`, here while
    each row is written).
    """
    sd = STATE_DIM if drift is None else drift.state_dim
    copied = ((), ()) if drift is None else drift.deviation_slots(b)
    out, seen = kernels.to_local(np.ascontiguousarray(b.Jx), b.first, b.stride, V, P, sd, b.Jt, copied)
    return FactorBlock(b.name, b.first, 1, out.shape[2] // sd, out, b.Jt, b.cols, np.flatnonzero(seen))
