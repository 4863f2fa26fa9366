"""How a drive is closed: its trajectory's parametrisation, its gauge, its last keyframe, the
drift of its biases, and the nuisance coordinates of θ. Every part of excite that turns factors
into the marginal information of the calibration — the evaluator (:mod:`.problem`,
:mod:`.elimination`), live guidance, mining, the optimizer's model and the calibrator — closes a
drive through this one module.

**Parametrisation and gauge.** The factors' Jacobians are derived for the *world* state
``[δθ, δp, δv]`` of every keyframe. The measurements of most kinds are invariant to a rigid
motion of the whole drive that keeps gravity: a translation (3) and a rotation about the vertical
(yaw, 1). Those symmetries are the gauge; a kind declares which of them its measurements break
(:attr:`excite.factors.base.Kind.breaks`: an absolute position fix, an absolute heading). What
no kind of the rig breaks is fixed minimally, by a prior on the first keyframe
(:meth:`Closure.fix`); the marginal on θ does not depend on how (the tests check it). When no
kind breaks translation the trajectory is parametrised *locally* (``[δθ_k, δv_k, δd_k]``: body
velocity and the body-frame increment to the next keyframe; :func:`.problem.linearise`): every
factor then sees positions only through differences, no absolute position remains, the only
gauge is yaw, and every symmetry has bounded components, which keeps the elimination accurate
on hour-long drives. A rig with a kind that observes absolute position keeps the world states
(a GNSS fix sees one keyframe's position: the band stays a band), each drive's positions split
into an **origin** and positions relative to it: ``p_k = c + q_k``, the origin c three nuisance
columns of the drive beside θ (:data:`ORIGIN`, in the border the elimination carries), the
translation of the q's the gauge again, fixed on the first keyframe (:attr:`Closure.origin`). The
factors that see positions through differences do not see c; those that see absolute positions
see it through their position Jacobians (:meth:`Closure.absolute`). Why: in plain world states
the absolute position is the weakest direction of the trajectory's information by far (a few
centimetres of GNSS against the IMU's micrometres between keyframes), and a calibration
coordinate that is confounded with it (a lever arm at constant heading) kept 1e-7 of its
information as rounding noise, enough for the rank test to call it determined; with the origin
in the border it is exactly zero. (The optimizer's model and the calibrator work on plain world
states, ``origin=False``: no rank test reads them.)

**A drive's start.** A kind whose noise is a Markov chain along the drive (a GNSS error correlated
over time, whitened by differencing consecutive fixes) declares the factor that opens the chain
at the stationary noise (:class:`excite.factors.base.OpensChain`): it is added where a drive, or a
window closed as one, starts, beside the gauge fix: :meth:`Closure.start` gives both.

**The last keyframe.** In local states, the increment of a drive's last keyframe has no
successor: it is held at zero (:meth:`Closure.end`). With drifting biases (the random-walk bias
model) every keyframe carries the deviation of the bias from θ's, and θ is the bias at the end of
the drive: the last keyframe's deviation is held at zero too, and the walk's last step does not
reach it (:meth:`Closure.anchored`).

**The bias walk** links the deviations of consecutive keyframes with σ = density · √ΔT
(Kalibr's ``*_random_walk`` units) (:meth:`Closure.walk`).

**Nuisance coordinates** (a monocular camera's scale, tyre slip: estimated, not scored) are
eliminated from Λ_θ last (:func:`marginalise_nuisance`).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..core.lazy import ca
from ..errors import EvaluationError
from ..factors import base as registry
from ..factors import kernels as factor_kernels
from ..factors.base import STATE_DIM, FactorBlock, Kind, Nominal, RigView

# The gauge fix: σ of the prior on the first keyframe's position [m] and yaw [rad]. Any value
# gives the same marginal (the gauge is an exact symmetry); one near the data's scale keeps H_xx
# well conditioned.
GAUGE_SIGMA_POS_M = 1.0
GAUGE_SIGMA_YAW_RAD = 0.01
_NO_COLS = np.zeros(0, dtype=int)
_MADE: dict[tuple, tuple[weakref.ref, int, "Closure"]] = {}  # (id(rig), local, origin) → (rig, generation, closure)
ORIGIN = ("drive.origin_x", "drive.origin_y", "drive.origin_z")  # a drive's origin columns [m] (world axes)


def broken(rig: RigView) -> frozenset[str]:
    """The gauge symmetries the measurements of ``rig`` break (any of its kinds)."""
    return frozenset().union(*(i.kind.breaks for i in registry.instances(rig)))


def drifting(rig: RigView) -> list[tuple[int, float]]:
    """``(column of θ, random-walk density)`` of every drifting coordinate of ``rig`` (the IMU
    biases with the random-walk model), in column order: each keyframe carries its deviation."""
    out = []
    for _, _, q in registry.quantities(rig.config):
        if q.estimated and q.drift:
            out += [(rig.index(n), float(q.drift)) for n in q.coordinate_names()]
    return out


def state_dim(rig: RigView) -> int:
    """Dimension of a keyframe's nuisance state: the trajectory's 9, plus the deviation of every
    drifting coordinate."""
    return STATE_DIM + len(drifting(rig))


@dataclass(frozen=True)
class Closure:
    """How every drive of one rig is closed (see the module docstring)."""

    local: bool  # the trajectory in local states (no absolute position)
    gauge: tuple[str, ...]  # the symmetries fixed by a prior on the first keyframe
    state_dim: int
    walk_density: np.ndarray  # random-walk density of each drifting coordinate (state slots 9 …)
    walk_columns: np.ndarray  # their columns of θ
    openers: tuple[registry.Instance, ...] = ()  # the opening of every chain that opens a drive (:func:`~excite.factors.base.openings`)
    origin: bool = False  # world positions split into the drive's origin (nuisance columns) and q's

    @classmethod
    def of(cls, rig: RigView, local: bool | None = None, origin: bool = True) -> "Closure":
        """The closure of ``rig``'s drives; ``local`` forces a parametrisation (the world states
        always work; local ones only when no kind observes absolute position); ``origin=False``
        keeps plain world states for a rig that observes absolute position (no origin columns:
        the optimizer's model, the calibrator). Made once per rig object and registry
        (:func:`~excite.factors.base.generation`): an evaluation asks for it several times, and a
        rig does not change once built."""
        key = (id(rig), local, origin)
        made = _MADE.get(key)
        if made is not None and made[0]() is rig and made[1] == registry.generation():
            return made[2]
        out = cls._made(rig, local, origin)
        try:
            ref = weakref.ref(rig, lambda _, key=key: _MADE.pop(key, None))
        except TypeError:  # a rig view that takes no weak reference: made each time
            return out
        _MADE[key] = (ref, registry.generation(), out)
        return out

    @classmethod
    def _made(cls, rig: RigView, local: bool | None, origin: bool) -> "Closure":
        """:meth:`of`, made afresh."""
        br = broken(rig)
        can_local = "position" not in br
        if local is None:
            local = can_local
        elif local and not can_local:
            raise EvaluationError("local trajectory states need every factor to see positions through "
                                  "differences only, and this rig observes absolute position")
        origin = origin and not can_local
        gauge = tuple(s for s in registry.SYMMETRIES
                      if (s not in br or (origin and s == "position")) and not (local and s == "position"))
        drift = drifting(rig)
        openers = tuple(registry.openings(rig))
        density, columns = np.array([d for _, d in drift]), np.array([c for c, _ in drift], dtype=int)
        density.flags.writeable = columns.flags.writeable = False  # shared by every caller of :meth:`of`
        return cls(local, gauge, STATE_DIM + len(drift), density, columns, openers, origin)

    # --- the origin ---

    def absolute(self, b: FactorBlock, rig: RigView) -> FactorBlock:
        """A block of a kind that sees absolute positions, with the drive's origin: its position
        Jacobians (on ``q_k``) summed over its keyframes onto the origin columns, which follow
        the rig's coordinates (``len(rig.coordinates) + 0, 1, 2``; :func:`.problem.on_drive_columns`
        moves them to the drive's own). Unchanged without an origin."""
        if not self.origin:
            return b
        N, r, nx = b.Jx.shape
        xd = nx // b.n_states
        J = b.Jx.reshape(N, r, b.n_states, xd)
        Jc = J[:, :, :, 3:6].sum(axis=2)
        P = len(rig.coordinates)
        return FactorBlock(b.name, b.first, b.stride, b.n_states, b.Jx, np.concatenate([b.Jt, Jc], axis=2),
                           np.r_[b.cols, P + np.arange(3)], b.xcols)

    # --- the gauge ---

    def fix(self, R_W_B: np.ndarray, keyframe: int) -> list[FactorBlock]:
        """The minimal gauge fix of a drive at ``keyframe`` (orientation ``R_W_B`` there): priors on
        its position and world yaw, as far as they are symmetries. Trajectory states only."""
        rows = []
        if "position" in self.gauge:
            rows += [np.r_[np.zeros(3), e, np.zeros(3)] / GAUGE_SIGMA_POS_M for e in np.eye(3)]
        if "yaw" in self.gauge:  # world yaw of a right perturbation: e_zᵀ R δθ
            rows.append(np.r_[R_W_B[2], np.zeros(6)] / GAUGE_SIGMA_YAW_RAD)
        if not rows:
            return []
        Jx = np.array(rows)[None]
        return [FactorBlock("gauge", np.array([keyframe]), 1, 1, Jx, np.zeros((1, len(rows), 0)), _NO_COLS)]

    def fix_information(self, R_W_B) -> "ca.SX | ca.MX":
        """The information (9 × 9, trajectory states) of :meth:`fix` at a keyframe of CasADi
        orientation ``R_W_B`` (3 × 3): the optimizer's model closes its drives with it."""
        rows = []
        if "position" in self.gauge:
            rows += [ca.DM(np.r_[np.zeros(3), e, np.zeros(3)] / GAUGE_SIGMA_POS_M).T for e in np.eye(3)]
        if "yaw" in self.gauge:
            rows.append(ca.horzcat(R_W_B[2, :], ca.DM.zeros(1, 6)) / GAUGE_SIGMA_YAW_RAD)
        if not rows:
            return ca.DM.zeros(STATE_DIM, STATE_DIM)
        J = ca.vertcat(*rows)
        return ca.mtimes(J.T, J)

    # --- a drive's start ---

    def start(self, nom: Nominal, rig: RigView, gauge_keyframe: int = 0) -> list[FactorBlock]:
        """What a drive (or a window closed as one) whose first keyframe is ``nom``'s adds there:
        the gauge fix (:meth:`fix`, at its keyframe ``gauge_keyframe``) and the factors that open
        its kinds' chains (:class:`~excite.factors.base.OpensChain`: their measurement at the
        first keyframe, none where the log has none there)."""
        return self.fix(nom.R[gauge_keyframe], gauge_keyframe) + self.openings(nom, rig)

    def openings(self, nom: Nominal, rig: RigView) -> list[FactorBlock]:
        """The factors that open the chains at ``nom``'s first keyframe (see :meth:`start`). World
        trajectory states (an opening sees absolute states, so its rig has no local ones)."""
        if not self.openers:
            return []
        first = nom.window(0, 0)
        out = []
        for i in self.openers:
            b = factor_kernels.jacobians(i.kind, first, rig, i.entry)
            if b is not None and b.n_factors:
                b = self.absolute(b, rig)
                out.append(self.widened(b) if self.sees_drift(b) else b)
        return out

    def is_opening(self, b: FactorBlock) -> bool:
        """Whether ``b`` is an opening's block (:meth:`openings`; a window re-opens its own)."""
        return any(b.name == i.name for i in self.openers)

    # --- the last keyframe ---

    def held(self) -> list[int]:
        """Components of a drive's last keyframe held at zero: in local states its increment (it
        has no successor), and the deviations of the drifting coordinates (θ holds their value there)."""
        return (list(range(6, 9)) if self.local else []) + list(range(STATE_DIM, self.state_dim))

    def free(self) -> np.ndarray:
        """Components of a drive's last keyframe that stay free when a drive is closed there (live
        guidance closes the drive so far, mining a window, with them)."""
        return np.setdiff1d(np.arange(self.state_dim), self.held())

    def end(self, keyframe: int) -> list[FactorBlock]:
        """The components :meth:`held` of ``keyframe``, the last of a drive, held at zero."""
        rows = self.held()
        if not rows:
            return []
        Jx = np.zeros((1, len(rows), self.state_dim))
        Jx[0, np.arange(len(rows)), rows] = 1.0
        return [FactorBlock("placeholder", np.array([keyframe]), 1, 1, Jx, np.zeros((1, len(rows), 0)), _NO_COLS)]

    # --- the bias walk ---

    def walk_weights(self, dT: float) -> np.ndarray:
        """1/σ of one random-walk step over ``dT`` of every drifting coordinate."""
        return 1.0 / (self.walk_density * np.sqrt(dT))

    def walk(self, n_intervals: int, dT: float) -> FactorBlock:
        """The random walk of the drifting coordinates over each of ``n_intervals`` keyframe
        intervals: ``δb_j − δb_i`` whitened by :meth:`walk_weights`."""
        sd, d = self.state_dim, self.state_dim - STATE_DIM
        w = self.walk_weights(dT)
        Jx = np.zeros((n_intervals, d, 2 * sd))
        Jx[:, :, STATE_DIM:sd] = -np.diag(w)
        Jx[:, :, sd + STATE_DIM:] = np.diag(w)
        return FactorBlock("bias_walk", np.arange(n_intervals), 1, 2, Jx, np.zeros((n_intervals, d, 0)), _NO_COLS)

    def anchored(self, walk: FactorBlock, ends: np.ndarray) -> FactorBlock:
        """The walk with its steps into the keyframes ``ends`` (the last of each drive) cut off at
        their end: there the value is θ's own column, the deviation zero (held by :meth:`end`)."""
        into = np.isin(walk.first + 1, ends)
        if not into.any():
            return walk
        Jx = walk.Jx.copy()
        Jx[into, :, self.state_dim + STATE_DIM:] = 0.0
        return FactorBlock(walk.name, walk.first, walk.stride, walk.n_states, Jx, walk.Jt, walk.cols)

    def widened(self, b: FactorBlock) -> FactorBlock:
        """A block over world trajectory states widened to the closure's states: zero columns for
        the deviations, and where the block sees a drifting coordinate of θ, the same column on the
        deviation at its first keyframe too (the value there is θ's plus the deviation)."""
        if self.state_dim == STATE_DIM:
            return b
        N, r, _ = b.Jx.shape
        Jx = np.zeros((N, r, b.n_states, self.state_dim))
        Jx[..., :STATE_DIM] = b.Jx.reshape(N, r, b.n_states, STATE_DIM)
        out = FactorBlock(b.name, b.first, b.stride, b.n_states, Jx.reshape(N, r, -1), b.Jt, b.cols)
        return self.with_deviations(out)

    def with_deviations(self, b: FactorBlock) -> FactorBlock:
        """A block already over the closure's states (its deviation columns zero) with its
        drifting θ columns copied onto the deviations at its first keyframe."""
        ks, ss = self.deviation_slots(b)
        if not ks.size:
            return b
        b.Jx[:, :, ss] = b.Jt[:, :, ks]
        xcols = None if b.xcols is None else np.union1d(b.xcols, ss)
        return FactorBlock(b.name, b.first, b.stride, b.n_states, b.Jx, b.Jt, b.cols, xcols)

    def deviation_slots(self, b: FactorBlock) -> tuple[np.ndarray, np.ndarray]:
        """Where :meth:`with_deviations` copies ``b``'s drifting θ columns: their columns of ``b.Jt``
        and the deviation columns of its first keyframe."""
        slots = [(k, STATE_DIM + i) for i, c in enumerate(self.walk_columns) for k in np.flatnonzero(b.cols == c)]
        return np.array([k for k, _ in slots], dtype=np.int64), np.array([s for _, s in slots], dtype=np.int64)

    def sees_drift(self, b: FactorBlock) -> bool:
        """Whether ``b`` sees a drifting coordinate of θ (and so needs the deviation states)."""
        return not self.drifting_columns.isdisjoint(b.cols.tolist())

    @cached_property
    def drifting_columns(self) -> frozenset[int]:
        """:attr:`walk_columns` as a set (:meth:`sees_drift` asks for every block of every chunk)."""
        return frozenset(self.walk_columns.tolist())


def marginalise_nuisance_symbolic(Lam, scored: np.ndarray):
    """:func:`marginalise_nuisance` of a CasADi Λ, smooth for IPOPT: the nuisance block is
    scaled to unit diagonal and regularised by 1e-12 (instead of pseudo-inverted), so that an
    undetermined nuisance removes nothing, as there."""
    iS, iN = np.flatnonzero(scored), np.flatnonzero(~scored)
    A = Lam[iS.tolist(), iS.tolist()]
    if not iN.size:
        return A
    B = Lam[iS.tolist(), iN.tolist()]
    C = Lam[iN.tolist(), iN.tolist()]
    d = ca.sqrt(ca.fmax(ca.diag(C), 1e-300))
    Bd = B / ca.repmat(d.T, iS.size, 1)
    Cn = C / ca.mtimes(d, d.T) + 1e-12 * ca.DM.eye(iN.size)
    return A - ca.mtimes(Bd, ca.solve(Cn, Bd.T))


def marginalise_nuisance(Lam: np.ndarray, scored: np.ndarray) -> np.ndarray:
    """Schur complement of the nuisance coordinates (``~scored``) of Λ (pseudo-inverse: an
    unobservable nuisance carries no information to remove)."""
    nu = ~scored
    if not nu.any():
        return Lam
    A = Lam[np.ix_(scored, scored)]
    B = Lam[np.ix_(scored, nu)]
    C = Lam[np.ix_(nu, nu)]
    d = np.sqrt(np.maximum(np.diag(C), 1e-300))
    Cn = C / np.outer(d, d)
    X = np.linalg.pinv(Cn, rcond=1e-12, hermitian=True)
    out = A - (B / d) @ X @ (B / d).T
    return 0.5 * (out + out.T)
