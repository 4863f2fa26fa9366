"""The factor protocol: what one measurement kind declares, the registry of kinds, and what every
factor shares (the nominal states it is linearised at, its Jacobian blocks).

A **kind** (:class:`Kind`) is one module of :mod:`excite.factors`. Every kind declares a few
class attributes and implements a few typed hooks:

- its **rig entry**: the ``kind:`` values of the ``sensors:`` entries it measures
  (:attr:`Kind.sensor_kinds`) or the top-level rig section it reads (:attr:`Kind.section`), the
  pydantic model that validates it (:attr:`Kind.config`), the sane ranges of its numbers
  (:attr:`Kind.ranges`), and the calibration **quantities** it is a function of
  (:meth:`Kind.quantities`: each a rotation, a 3-vector or a scalar, with the coordinates it
  adds to θ);
- its **arity** (one keyframe or a pair, :attr:`Kind.arity`), its residual's rows
  (:attr:`Kind.rows`), and which gauge symmetries its measurements **break**
  (:attr:`Kind.breaks`: an absolute position or an absolute yaw), which decides the
  trajectory's parametrisation and gauge (:mod:`excite.information.closure`);
- its **math, once**: the noise-free measurement at the nominal motion (:meth:`Kind.measurement`),
  the residual (:meth:`Kind.residual`) and its whitening (:meth:`Kind.sqrt_information`), in
  CasADi symbols for one factor (:class:`FactorInputs`), reading the numbers of its entry
  through :meth:`Kind.constants`. Everything else follows from it: the evaluator's kernels are
  generated from it (:mod:`excite.factors.generate`, run by :mod:`excite.factors.kernels`), the
  optimizer's information model and the calibrator differentiate it with CasADi;
- per-factor **whitening from data** where a drive carries it (:meth:`Kind.whitening`: a
  reported covariance, a scene's information; None by default);
- its **simulated measurement** (:meth:`Kind.simulate`: physical, or exactly as the model
  assumes) for :mod:`excite.validate`, and the motion **advice** for its coordinates
  (:attr:`Kind.advice`).

What one or two kinds need is a small protocol of its own, which a kind implements by defining
its methods; callers never ask the kind, they call this module's function of the same name,
which gives the default for a kind without the protocol:

- :class:`ChoosesEntries` (:func:`entries`): entries other than its sensors or section (the
  vehicle's non-holonomic constraint; a lidar's road plane);
- :class:`NamesBlocks` (:func:`block_name`): a block not named after its sensor or itself (the
  road plane's, a GNSS antenna's first fix);
- :class:`HasVariants` (:func:`variant`): a statement whose shape changes with the entry (a 2-D
  radar; a car with or without steering), one kernel per variant;
- :class:`ChoosesFactors` (:func:`factor_keyframes`): factors at only some of the entry's frames
  (:func:`frames`, every :func:`stride`-th keyframe): the fixes a logged drive holds
  (:attr:`Nominal.logs`), the frames that see ground;
- :class:`PreparesRecording` (:func:`prepare_recording`): a recording made into what the
  residual compares (the IMU's samples preintegrated at the estimate; consecutive fixes paired);
- :class:`Resamples` (:func:`at_rate`): an entry at another rate with the same information per
  second by more than its ``rate_hz`` (the optimizer's coarse rig);
- :class:`ReadsImu`: math that reads the interval's IMU samples, folded into a summary (the
  IMU's preintegration);
- :class:`OpensChain` (:func:`openings`): noise that is a Markov chain along the drive, opened
  at a drive's start by a factor of its own (a GNSS antenna's first fix).

Everything else loops over the registry (:func:`kinds`, :func:`instances`, :func:`openings`):
adding a kind is a module that calls :func:`register`, and nothing else changes.

States. The nuisance state of keyframe k is ``x_k = [δθ (3), δp (3), δv (3)]``: a right
perturbation of the body orientation ``R_W_B · Exp(δθ)``, and additive world position and velocity
of B. The calibration vector θ has one column per coordinate of the rig, in its order. Every
factor gives *whitened* Jacobians: one row per residual component divided by its σ (or multiplied
by the inverse Cholesky factor of its covariance).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import TYPE_CHECKING, Any, ClassVar, Generic, Iterator, Protocol, Sequence, TypeVar, Union, runtime_checkable

import numpy as np

from ..core.bounds import Range
from ..core.schema import SensorEntry
from ..motion.trajectory import Trajectory, rigid_body


STATE_DIM = 9
ROT, POS, VEL = slice(0, 3), slice(3, 6), slice(6, 9)
# with random-walk IMU biases every keyframe also carries the bias deviations [δb_g, δb_a]
BIAS_STATE_DIM = 15
BIAS = slice(9, 15)
SYMMETRIES = ("position", "yaw")  # the gauge of a drive whose measurements break none of them


class RigView(Protocol):
    """What a kind reads of the rig it is linearised for (:class:`excite.rig.config.Rig` is one):
    the validated configuration, the parameter coordinates in column order, the keyframe rate."""

    @property
    def config(self) -> ConfigView: ...

    coordinates: tuple
    keyframe_rate_hz: float

    def index(self, name: str) -> int: ...


@dataclass(frozen=True)
class KeyframeLog:
    """What a log recorded of one sensor, on the keyframe grid (:meth:`Nominal.of`): whether
    the sensor has a measurement at each keyframe (a frame of the sensor's that the log holds;
    False between its frames and in outages), and where the sensor reports one, the covariance
    of that measurement (K × d × d, NaN where none)."""

    available: np.ndarray
    covariance: np.ndarray | None = None

    def window(self, k0: int, k1: int) -> "KeyframeLog":
        cov = None if self.covariance is None else self.covariance[k0:k1 + 1]
        return KeyframeLog(self.available[k0:k1 + 1], cov)


@dataclass(frozen=True)
class Nominal:
    """The nominal motion a rig sees on a drive: the IMU's at every IMU sample, the body's at the
    keyframes.

    Keyframe ``k`` is IMU sample ``k · imu_per_keyframe``. At the keyframes: time ``t``, body
    (IMU frame) orientation ``R``, world position ``p`` and velocity ``v``, body rate ``omega``
    and the suspension tilt ``R_V_A``. At the IMU rate: orientation ``imu_R``, body rate
    ``imu_omega`` and specific force ``imu_f``. ``R_V_B, p_V_B`` is the IMU pose in the vehicle frame.
    ``logs``: what a logged drive recorded of some of the rig's sensors, by sensor name
    (:class:`KeyframeLog`; a sensor without one measures at every one of its frames).
    ``scene``: what a scene shows the rig's lidars and cameras at each keyframe, by sensor name
    (K × 6 × 6: the information of a scan's registration or a camera pair's bearings there, in
    world-aligned axes: :class:`~excite.motion.trajectory.SceneView`); a sensor without one is
    scene-blind.
    ``ground``: the same for the road plane fitted to its returns from the ground (K × 4 × 4).
    """

    t: np.ndarray
    R: np.ndarray
    p: np.ndarray
    v: np.ndarray
    omega: np.ndarray
    R_V_A: np.ndarray
    imu_R: np.ndarray
    imu_omega: np.ndarray
    imu_f: np.ndarray
    imu_per_keyframe: int
    R_V_B: np.ndarray
    p_V_B: np.ndarray
    length_m: float = 0.0  # path length of the rear axle (trapezoid over the keyframes)
    logs: dict[str, KeyframeLog] = field(default_factory=dict)
    scene: dict[str, np.ndarray] = field(default_factory=dict)
    ground: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_keyframes(self) -> int:
        return self.t.size

    @cached_property
    def keyframe_table(self) -> np.ndarray:
        """Every keyframe's inputs to a factor, one row each (K × 27): ``[vec R (row-major), p, v, ω,
        vec R_V_A]`` (what the generated kernels read, :mod:`excite.factors.kernels`)."""
        K = self.n_keyframes
        return np.ascontiguousarray(np.hstack([self.R.reshape(K, 9), self.p, self.v, self.omega,
                                               self.R_V_A.reshape(K, 9)]))

    def window(self, k0: int, k1: int) -> "Nominal":
        """Keyframes ``k0..k1`` (inclusive) and the IMU samples between them (views, no copies)."""
        n = self.imu_per_keyframe
        kf = slice(k0, k1 + 1)
        imu = slice(k0 * n, k1 * n + 1)
        return Nominal(t=self.t[kf], R=self.R[kf], p=self.p[kf], v=self.v[kf], omega=self.omega[kf],
                       R_V_A=self.R_V_A[kf], imu_R=self.imu_R[imu], imu_omega=self.imu_omega[imu],
                       imu_f=self.imu_f[imu], imu_per_keyframe=n, R_V_B=self.R_V_B, p_V_B=self.p_V_B,
                       logs={k: v.window(k0, k1) for k, v in self.logs.items()},
                       scene={k: v[kf] for k, v in self.scene.items()},
                       ground={k: v[kf] for k, v in self.ground.items()})

    @staticmethod
    def grid(traj: Trajectory, rig: RigView, t_start: float | None = None,
             t_end: float | None = None) -> tuple[float, int]:
        """Start time and number of keyframes of the whole keyframe intervals of ``traj`` within
        ``[t_start, t_end]``."""
        t0 = traj.t_start if t_start is None else max(t_start, traj.t_start)
        t1 = traj.t_end if t_end is None else min(t_end, traj.t_end)
        return t0, int(np.floor((t1 - t0) * rig.keyframe_rate_hz + 1e-9)) + 1

    @staticmethod
    def keyframe_times(traj: Trajectory, rig: RigView) -> np.ndarray:
        """The times of the keyframes of ``traj`` (those of :meth:`of`, bit for bit)."""
        t0, K = Nominal.grid(traj, rig)
        imu_rate = rig.config.imu.update_rate
        n = int(round(imu_rate / rig.keyframe_rate_hz))
        return np.clip(t0 + np.arange(K) * n / imu_rate, traj.t_start, traj.t_end)

    @classmethod
    def of(cls, traj: Trajectory, rig: RigView, t_start: float | None = None, t_end: float | None = None,
           keyframes: tuple[int, int] | None = None) -> "Nominal":
        """Sample ``traj`` for ``rig`` on the whole keyframe intervals within ``[t_start, t_end]``
        (:meth:`grid`), or on its keyframes ``k0 … k1`` only: the same samples as those of the
        whole, bit for bit."""
        t0, K = cls.grid(traj, rig, t_start, t_end)
        k0, k1 = (0, K - 1) if keyframes is None else keyframes
        imu_rate = rig.config.imu.update_rate
        n = int(round(imu_rate / rig.keyframe_rate_hz))
        t_imu = t0 + np.arange(k0 * n, k1 * n + 1) / imu_rate
        R_V_B, p_V_B = rig.config.vehicle.T_V_B.R, rig.config.vehicle.T_V_B.p
        imu_R, imu_w, imu_f = traj.imu(t_imu, R_V_B, p_V_B)
        # the keyframes: what :meth:`Trajectory.sample` and ``body`` give, less the accelerations
        t = np.clip(t_imu[::n], traj.t_start, traj.t_end)
        R_W_V, omega_V, _ = traj.rotation(t)
        p_V, v_V, R_V_A = traj.translation(t)
        R, p, v, omega = rigid_body(R_W_V, p_V, v_V, omega_V, R_V_B, p_V_B)
        length = float(np.trapezoid(np.linalg.norm(v_V, axis=1), t))
        logs = keyframe_logs(traj, rig, t, k0)
        view = getattr(traj, "scene", None)
        near = {} if view is None else {name: view.nearest(name, t) for name in view.t}
        return cls(t=t, R=R, p=p, v=v, omega=omega, R_V_A=R_V_A, imu_R=imu_R, imu_omega=imu_w, imu_f=imu_f,
                   imu_per_keyframe=n, R_V_B=R_V_B, p_V_B=p_V_B, length_m=length, logs=logs,
                   scene={name: view.H_W[name][j] for name, j in near.items()},
                   ground={name: view.G_W[name][j] for name, j in near.items() if name in view.G_W})


def keyframe_logs(traj: Trajectory, rig: RigView, t: np.ndarray, k0: int) -> dict[str, KeyframeLog]:
    """The logs ``traj`` carries of ``rig``'s sensors (:attr:`Trajectory.logs
    <excite.motion.trajectory.Trajectory.logs>`, by sensor name) on the keyframes ``t``, the first
    of which is keyframe ``k0`` of the drive: a keyframe holds a measurement of a sensor when it
    is one of the sensor's frames (every ``stride``-th keyframe of the drive) and the log has a
    message within half a frame interval of it; its covariance is that message's. Each keyframe
    on its own, so that a window sees what the whole drive sees."""
    out = {}
    logs = getattr(traj, "logs", None) or {}
    for s in rig.config.sensors:
        log = logs.get(s.name)
        kind = kind_of_sensor(s.kind)
        if log is None or kind is None:
            continue
        step = stride(kind, rig, s)
        k = k0 + np.arange(t.size)
        frame = k % step == 0
        ts = np.asarray(log.t, dtype=float)
        if ts.size == 0:
            out[s.name] = KeyframeLog(np.zeros(t.size, dtype=bool))
            continue
        j = np.clip(np.searchsorted(ts, t), 1, ts.size - 1) if ts.size > 1 else np.zeros(t.size, dtype=int)
        if ts.size > 1:
            j = np.where(np.abs(ts[j - 1] - t) <= np.abs(ts[j] - t), j - 1, j)
        near = np.abs(ts[j] - t) < 0.5 * step / rig.keyframe_rate_hz  # (strictly: a message is one frame's)
        avail = frame & near
        cov = None
        if log.covariance is not None:
            cov = np.full((t.size,) + log.covariance.shape[1:], np.nan)
            cov[avail] = log.covariance[j[avail]]
        out[s.name] = KeyframeLog(avail, cov)
    return out


@dataclass(frozen=True)
class FactorBlock:
    """Whitened Jacobians of N factors of one kind.

    Factor ``f`` touches the keyframes ``first[f] + stride · m`` for ``m < n_states`` through
    ``Jx[f]`` (r × 9·n_states), and the calibration columns ``cols`` through ``Jt[f]``
    (r × len(cols)). ``xcols``, where known: the columns of ``Jx`` that may be non-zero (every other
    one is zero for every factor), which :func:`excite.information.kernels.accumulate` can skip.
    """

    name: str
    first: np.ndarray
    stride: int
    n_states: int
    Jx: np.ndarray
    Jt: np.ndarray
    cols: np.ndarray
    xcols: np.ndarray | None = None

    def nonzero_columns(self) -> np.ndarray:
        """``xcols``, or every column of ``Jx`` where they are not known."""
        return np.arange(self.Jx.shape[2]) if self.xcols is None else self.xcols

    @property
    def n_factors(self) -> int:
        return self.first.size

    @property
    def n_rows(self) -> int:
        return self.Jx.shape[1]

    def Jt_full(self, n_params: int) -> np.ndarray:
        """The calibration Jacobian over all ``n_params`` columns (N × r × n_params)."""
        out = np.zeros(self.Jt.shape[:2] + (n_params,))
        out[:, :, self.cols] = self.Jt
        return out

    def select(self, mask: np.ndarray) -> "FactorBlock":
        return replace(self, first=self.first[mask], Jx=self.Jx[mask], Jt=self.Jt[mask])

    def shifted(self, by: int) -> "FactorBlock":
        """The same factors with keyframe indices moved by ``by``."""
        return replace(self, first=self.first + by)

    def within(self, k0: int, k1: int) -> "FactorBlock | None":
        """The factors that lie entirely within keyframes ``k0 … k1``, indexed from ``k0``; None
        if there are none (a window's factors: :meth:`excite.information.problem.Problem.window`)."""
        inside = (self.first >= k0) & (self.first + self.stride * (self.n_states - 1) <= k1)
        return self.select(inside).shifted(-k0) if inside.any() else None


def theta_columns(rig: RigView, names: list[str]) -> np.ndarray:
    """Column indices of the named calibration coordinates."""
    return np.array([rig.index(n) for n in names], dtype=int)


# --- calibration quantities --------------------------------------------------------------------


@dataclass(frozen=True)
class Quantity:
    """One calibration quantity of a rig entry, as its kind's math uses it.

    ``quantity`` names what it is (``rot``, ``trans``, ``time_offset``, ``scale``, …: the stem of
    its coordinates' names). ``size`` 3 is a 3-vector, or with ``quantity == "rot"`` a rotation
    (``nominal`` a 3 × 3 matrix, perturbed on the right: ``R · Exp(δφ)``); ``size`` 1 a scalar.
    ``estimated``: it adds coordinates to θ (``block.quantity_x/y/z`` or ``block.quantity``, or
    ``names``); otherwise the math sees its nominal value. ``nuisance``: estimated but not scored
    (each drive has its own: a monocular camera's scale, tyre slip). ``key``: the name the kind's
    math reads it by (default ``quantity``); ``axis``: the axis a scalar coordinate reports (the
    left wheel 0, the right 1). ``drift``: the density of the quantity's random walk along the
    drive (the IMU biases with the random-walk bias model; 0: constant): each keyframe carries its
    deviation, θ is its value at the drive's end (:mod:`excite.information.closure`).
    ``per_entry``: the nominal value is the entry's (an extrinsic, a radius); False: it is always
    the same (a time offset's 0, a scale's 1, a bias's 0), and the generated kernels take it as a
    constant."""

    block: str
    quantity: str
    size: int
    unit: str
    nominal: Any
    estimated: bool = True
    nuisance: bool = False
    names: tuple[str, ...] | None = None
    key: str | None = None
    axis: int = 0
    drift: float = 0.0
    per_entry: bool = True

    @property
    def rotation(self) -> bool:
        return self.quantity == "rot"

    @property
    def name(self) -> str:
        return self.key or self.quantity

    def coordinate_names(self) -> list[str]:
        if self.names is not None:
            return list(self.names)
        if self.size == 3:
            return [f"{self.block}.{self.quantity}_{a}" for a in "xyz"]
        return [f"{self.block}.{self.quantity}"]

    def nominal_vector(self) -> np.ndarray:
        """The nominal value as a flat vector (a rotation: its 9 entries, row-major)."""
        return np.asarray(self.nominal, dtype=float).reshape(-1)


@dataclass(frozen=True)
class Column:
    """One coordinate of θ as a kind declares it (the rig adds its target and prior)."""

    name: str
    unit: str
    block: str
    quantity: str
    axis: int
    nuisance: bool


# --- the protocol ------------------------------------------------------------------------------

E = TypeVar("E")  # a kind's rig entry (its pydantic model)
if TYPE_CHECKING:
    from casadi import SX as Expr  # a CasADi expression (CasADi is imported lazily: :mod:`excite.core.lazy`)
else:
    Expr = Any
Variant = tuple  # what changes the shape of a kind's statement (its rows, its quantities): small, hashable
# a residual's whitening: a vector (diagonal), a matrix (rows × the residual's rows), or
# ("cholesky", Σ): the inverse Cholesky factor of a covariance Σ
Whitening = Union["Expr", np.ndarray, tuple[str, "Expr"]]


@dataclass
class FactorInputs:
    """One factor's inputs as its kind's math reads them (CasADi SX).

    Per keyframe of the factor (one, or a pair ``dT`` apart): body orientation ``R``, world
    position ``p`` and velocity ``v`` (the states), body rate ``omega`` and suspension tilt
    ``R_V_A`` (nominal inputs, not states). ``q``: the entry's quantities by
    :attr:`~excite.factors.base.Quantity.name` (rotations 3×3, vectors 3×1, scalars). ``c``: the
    constants the kind's math reads (:meth:`~excite.factors.base.Kind.constants`). ``imu``: the
    summary of the interval's IMU samples (:class:`~excite.factors.base.ReadsImu`), for a kind
    that reads them. ``dT``: the factor's interval [s]; ``R_V_B``, ``p_V_B``: the IMU's pose in V.
    ``variant``: the entry's :func:`~excite.factors.base.variant`. ``entry``, ``rig``: the
    entry and its rig, for math that reads them directly (then generated per entry, on demand);
    None where the kernel is generated for every entry of the variant."""

    R: list[Expr]
    p: list[Expr]
    v: list[Expr]
    omega: list[Expr]
    R_V_A: list[Expr]
    q: dict[str, Expr]
    c: dict[str, Expr]
    imu: dict[str, Expr] | None
    dT: Expr
    R_V_B: Expr
    p_V_B: Expr
    variant: Variant
    entry: Any = None
    rig: RigView | None = None



class ConfigView(Protocol):
    """What a kind reads of a rig's validated configuration (:class:`excite.rig.config.RigConfig`)."""

    sensors: Sequence[SensorEntry]
    imu: Any  # :class:`excite.factors.imu.ImuConfig` (a kind's own module)
    vehicle: Any  # :class:`excite.rig.config.VehicleConfig` (of the package above)


class SimulationView(Protocol):
    """What a kind's :meth:`Kind.simulate` reads of a simulated drive
    (:class:`excite.validate.simulate.Simulation`)."""

    traj: Trajectory
    nom: "Nominal"
    rig: RigView
    truth: Any  # the true calibration (:class:`excite.validate.simulate.Calibration`)
    rng: np.random.Generator
    settings: Any  # :class:`excite.validate.simulate.SimulationSettings`
    scan_pairs: dict  # a lidar's frame pairs in a scene, by name (:class:`excite.validate.scans.PairNoise`)

    @property
    def noisy(self) -> bool: ...

    def body_at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def measured(self, kind: "Kind", entry: Any) -> np.ndarray: ...


class Kind(Generic[E]):
    """One measurement kind (see the module docstring): the class attributes and hooks every kind
    declares. Subclasses set the attributes and implement :meth:`quantities`, :meth:`measurement`,
    :meth:`residual`, :meth:`sqrt_information`, :meth:`simulate`, and :meth:`constants` and
    :meth:`whitening` where their math reads numbers of the entry or their drives carry a
    whitening; what one or two kinds need is a protocol of its own (:class:`ChoosesEntries`,
    :class:`NamesBlocks`, :class:`HasVariants`, :class:`ChoosesFactors`, :class:`PreparesRecording`,
    :class:`Resamples`, :class:`ReadsImu`, :class:`OpensChain`), reached through the functions
    of this module (:func:`entries`, :func:`factor_keyframes`, …), never through the kind.
    Instances are stateless and registered once (:func:`register`)."""

    name: ClassVar[str]
    arity: ClassVar[int] = 2  # keyframes per factor: 1, or a pair ``stride`` keyframes apart
    rows: ClassVar[int]  # components of one whitened residual (at most: a 2-D radar's has fewer)
    breaks: ClassVar[frozenset[str]] = frozenset()  # of :data:`SYMMETRIES`
    sensor_kinds: ClassVar[tuple[str, ...]] = ()  # ``sensors:`` entries of these ``kind:`` values
    section: ClassVar[str | None] = None  # or this top-level rig section
    config: ClassVar[type | None] = None  # the pydantic model of an entry (or of the section)
    ranges: ClassVar[dict[str, Range]] = {}  # sane ranges of an entry's numbers (dotted keys within it)
    # motion advice per (coordinate's quantity, vehicle axis or None): (the report's, the driver's)
    advice: ClassVar[dict[tuple[str, int | None], tuple[str, str]]] = {}

    def quantities(self, cfg: ConfigView, entry: E) -> list[Quantity]:
        """The calibration quantities of ``entry`` (``cfg`` is the whole rig configuration): their
        keys, sizes and perturbations (rotation or additive) depend on :func:`variant` only."""
        return []

    # --- the math: stated once, in CasADi symbols for one factor ---

    def constants(self, rig: RigView, entry: E) -> dict[str, float | np.ndarray]:
        """The numbers of ``entry`` (and of the rig) that the math reads, by name (``f.c[name]``):
        σ, correlations, intervals. Through them one generated kernel serves every entry of a
        variant; math that reads ``f.entry`` instead is generated per entry, on demand."""
        return {}

    def measurement(self, f: FactorInputs) -> Expr:
        """The noise-free measurement of the factor at its nominal inputs (a flat SX vector)."""
        raise NotImplementedError

    def residual(self, f: FactorInputs, meas: Expr) -> Expr:
        """The residual (SX) of measurement ``meas``, not whitened; zero at ``meas = measurement(f)``."""
        raise NotImplementedError

    def sqrt_information(self, f: FactorInputs) -> Whitening:
        """``W`` with ``WᵀW = Σ⁻¹`` of the residual (:data:`Whitening`)."""
        raise NotImplementedError

    def whitening(self, nom: Nominal, rig: RigView, entry: E, first: np.ndarray) -> np.ndarray | None:
        """Per-factor whitening from data, where a drive carries it (a reported covariance, a
        scene's information): ``W_n`` (N × rows × the residual's rows, ``W_nᵀW_n = Λ_n``, rows of
        zeros allowed) of the factors at keyframes ``first``, applied to the residual's rows in
        place of :meth:`sqrt_information`; None: the statement's whitening."""
        return None

    # --- simulation ---

    def simulate(self, sim: SimulationView, entry: E) -> Any:
        """What ``entry`` records on the simulated drive ``sim``: a flat measurement per factor, in
        the layout of :meth:`measurement` (rows of an array, one per factor of
        :func:`factor_keyframes`), or what :meth:`PreparesRecording.prepare_recording` makes of it."""
        raise NotImplementedError


# --- what one or two kinds add: protocols of their own -----------------------------------------

E_co = TypeVar("E_co", covariant=True)
E_contra = TypeVar("E_contra", contravariant=True)


@runtime_checkable
class ChoosesEntries(Protocol[E_co]):
    """A kind whose entries are neither its ``sensors:`` entries nor its section (a vehicle's
    constraint; another kind's sensors: a lidar's road plane)."""

    def entries(self, rig: RigView) -> Sequence[E_co]:
        """The rig entries this kind measures."""
        ...


@runtime_checkable
class NamesBlocks(Protocol[E_contra]):
    """A kind whose factor blocks are named otherwise than after its entry (a ``sensors:`` entry's
    name) or after itself (:attr:`Kind.name`): one that measures another kind's entries."""

    def block_name(self, entry: E_contra) -> str:
        """The name of ``entry``'s factor block (unique among the rig's)."""
        ...


@runtime_checkable
class HasVariants(Protocol[E_contra]):
    """A kind whose statement changes shape with its entry (a 2-D radar's rows; a car with or
    without steering): one kernel is generated per variant."""

    def variant(self, entry: E_contra) -> Variant:
        """What of ``entry`` changes the shape of the statement (its rows, its quantities)."""
        ...


@runtime_checkable
class ChoosesFactors(Protocol[E_contra]):
    """A kind whose drives hold factors at only some of its entry's frames (:func:`frames`): the
    fixes a logged drive holds, the frames that see ground."""

    def factor_keyframes(self, rig: RigView, entry: E_contra, n_keyframes: int,
                         nom: Nominal | None = None) -> np.ndarray:
        """First keyframe of every factor of ``entry`` on a drive of ``n_keyframes`` (a subset
        of :func:`frames`); ``nom``, where given, says what the drive holds
        (:attr:`Nominal.logs`, :attr:`Nominal.ground`)."""
        ...


@runtime_checkable
class PreparesRecording(Protocol[E_contra]):
    """A kind whose recordings become something else before the residual compares them with
    the model (the IMU's samples preintegrated at the estimated biases; pairs of consecutive
    GNSS fixes)."""

    def prepare_recording(self, rig: RigView, entry: E_contra, recorded: Any,
                          values: dict[str, Any]) -> tuple[np.ndarray, dict[str, Any]]:
        """What :meth:`Kind.residual` compares with the model (one row per factor of
        :func:`factor_keyframes`), from what ``entry`` recorded (its :meth:`Kind.simulate`
        output), at the estimate ``values`` of its quantities; and the values the residual is
        to be evaluated at."""
        ...


@runtime_checkable
class Resamples(Protocol):
    """A ``sensors:`` kind whose entry at another rate keeps its information per second by more
    than a new ``rate_hz`` (a radar's merged targets; white GNSS fixes' σ)."""

    def at_rate(self, entry: dict[str, Any], rate_hz: float) -> dict[str, Any]:
        """A ``sensors:`` entry (as a dict) at ``rate_hz`` with the same information per second."""
        ...


@runtime_checkable
class ReadsImu(Protocol):
    """A kind whose math reads the IMU samples of its interval (the IMU's preintegration): a fold
    over the samples, from the last to the first, into a summary of the interval that
    :class:`~excite.factors.base.FactorInputs` carries as ``imu``. The fold's state has
    ``summary_state`` numbers and starts at zero; the summary's pieces are ``summary_fields``
    (name, shape), flat in that order."""

    summary_fields: tuple[tuple[str, tuple[int, ...]], ...]
    summary_state: int

    def summary_step(self, state: Expr, R_i: Expr, R_s: Expr, f_s: Expr, c: dict[str, Expr]) -> Expr:
        """The state after sample s (orientation ``R_s`` at its start, specific force ``f_s``;
        ``R_i`` the interval's first orientation)."""
        ...

    def summary_finish(self, state: Expr, R_i: Expr, R_j: Expr, c: dict[str, Expr]) -> dict[str, Expr]:
        """The summary from the final state (``R_j``: the orientation at the interval's end)."""
        ...


@runtime_checkable
class OpensChain(Protocol):
    """A kind whose noise is a Markov chain along the drive (a GNSS error correlated over time,
    whitened by differencing consecutive measurements): ``opening`` is the one-keyframe kind of
    the measurement that opens the chain at a drive's first keyframe (at its stationary noise),
    one per entry of the kind (:func:`openings`). Not registered: a drive's start
    (:meth:`excite.information.closure.Closure.start`) adds it where a drive, or a window closed
    as one, starts. It observes absolute states: such a kind breaks the translation symmetry."""

    opening: Kind


# --- the hooks with their defaults: what every caller asks of a kind --------------------------

_IMPLEMENTS: dict[type, weakref.WeakKeyDictionary] = {}


def implements(kind: Kind, protocol: type) -> bool:
    """``isinstance(kind, protocol)`` for the protocols above, remembered per kind (a kind's hooks
    do not change once it is made): a runtime protocol check looks up every member of the
    protocol each time (~10 µs), and a score of a drive asks ~200 times."""
    seen = _IMPLEMENTS.setdefault(protocol, weakref.WeakKeyDictionary())
    out = seen.get(kind)
    if out is None:
        out = seen[kind] = isinstance(kind, protocol)
    return out

def entries(kind: Kind, rig: RigView) -> list[Any]:
    """The rig entries ``kind`` measures: its own choice (:class:`ChoosesEntries`), its sensors,
    or its section if the rig has one."""
    if implements(kind, ChoosesEntries):
        return list(kind.entries(rig))
    if kind.sensor_kinds:
        return [s for s in rig.config.sensors if s.kind in kind.sensor_kinds]
    if kind.section is not None:
        entry = getattr(rig.config, kind.section, None)
        return [] if entry is None else [entry]
    return [rig.config]


def block_name(kind: Kind, entry: Any) -> str:
    """The name of ``entry``'s factor block: the kind's choice (:class:`NamesBlocks`), a sensor's
    name, the kind's own otherwise."""
    if implements(kind, NamesBlocks):
        return kind.block_name(entry)
    return entry.name if kind.sensor_kinds else kind.name


def variant(kind: Kind, entry: Any) -> Variant:
    """What of ``entry`` changes the shape of ``kind``'s statement (:class:`HasVariants`; ``()``)."""
    return kind.variant(entry) if implements(kind, HasVariants) else ()


def stride(kind: Kind, rig: RigView, entry: Any) -> int:
    """Keyframes between consecutive factors of ``entry``: a sensor (an entry with a ``rate_hz``,
    of a kind that reads no rig section) has one at each of its frames, the keyframe rate over
    its rate; a section's factors (the IMU's, the wheels', a car's CAN means) fall on every
    keyframe interval, whatever its stream's rate."""
    rate = None if kind.section is not None else getattr(entry, "rate_hz", None)
    return 1 if rate is None else int(round(rig.keyframe_rate_hz / rate))


def frames(kind: Kind, rig: RigView, entry: Any, n_keyframes: int) -> np.ndarray:
    """First keyframe of a factor at each frame of ``entry`` on a drive of ``n_keyframes``
    (relative to its start): every :func:`stride`-th keyframe; a pair needs its second."""
    s = stride(kind, rig, entry)
    last = n_keyframes - 1 - (s if kind.arity == 2 else 0)
    return np.arange(0, last + 1, s) if last >= 0 else np.zeros(0, dtype=int)


def factor_keyframes(kind: Kind, rig: RigView, entry: Any, n_keyframes: int,
                     nom: Nominal | None = None) -> np.ndarray:
    """First keyframe of every factor of ``entry`` on a drive of ``n_keyframes``: the kind's
    choice (:class:`ChoosesFactors`, reading ``nom`` where given), every frame otherwise."""
    if implements(kind, ChoosesFactors):
        return kind.factor_keyframes(rig, entry, n_keyframes, nom)
    return frames(kind, rig, entry, n_keyframes)


def prepare_recording(kind: Kind, rig: RigView, entry: Any, recorded: Any,
                      values: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
    """What the residual of ``kind`` compares (:class:`PreparesRecording`; by default what
    ``entry`` recorded as it is) and the quantity values it is evaluated at."""
    if implements(kind, PreparesRecording):
        return kind.prepare_recording(rig, entry, recorded, values)
    return recorded, values


def at_rate(kind: Kind, entry: dict[str, Any], rate_hz: float) -> dict[str, Any]:
    """A ``sensors:`` entry (as a dict) at ``rate_hz`` with the same information per second
    (the optimizer's coarse rig, :func:`excite.plan.model.coarse_rig`): the kind's
    (:class:`Resamples`), or by default only its rate changed (noise given as a density)."""
    return kind.at_rate(entry, rate_hz) if implements(kind, Resamples) else dict(entry, rate_hz=rate_hz)


def summary_size(kind: Kind) -> int:
    """Numbers in the summary of an interval's IMU samples ``kind`` reads (:class:`ReadsImu`; 0)."""
    if not implements(kind, ReadsImu):
        return 0
    return sum(int(np.prod(shape)) for _, shape in kind.summary_fields)


# --- the registry ------------------------------------------------------------------------------

_KINDS: dict[str, Kind] = {}
_GENERATION = [0]  # changes whenever a kind is registered or removed


def generation() -> int:
    """A number that changes whenever the registry does (:func:`register`, :func:`unregister`):
    what is derived from a rig's kinds is kept for as long as it stays the same."""
    return _GENERATION[0]


def register(kind: Kind) -> Kind:
    """Add ``kind`` to the registry (its name, ``sensors:`` kinds and section must be new)."""
    if kind.name in _KINDS:
        raise ValueError(f"a measurement kind named {kind.name!r} is registered already")
    taken = {k for other in _KINDS.values() for k in other.sensor_kinds}
    if set(kind.sensor_kinds) & taken:
        raise ValueError(f"sensor kind(s) {sorted(set(kind.sensor_kinds) & taken)} are measured by another kind")
    if kind.section is not None and any(o.section == kind.section for o in _KINDS.values()):
        raise ValueError(f"rig section {kind.section!r} is read by another kind")
    if implements(kind, OpensChain) and "position" not in kind.breaks:
        raise ValueError(f"{kind.name}: an opening factor sees one keyframe's absolute state: the kind must "
                         f"break the position symmetry")
    unknown = set(kind.breaks) - set(SYMMETRIES)
    if unknown:
        raise ValueError(f"{kind.name}: breaks {sorted(unknown)}, not symmetries ({', '.join(SYMMETRIES)})")
    _KINDS[kind.name] = kind
    _GENERATION[0] += 1
    return kind


def unregister(name: str) -> None:
    """Remove a kind (tests that register a kind of their own remove it again)."""
    if _KINDS.pop(name, None) is not None:
        _GENERATION[0] += 1


def kinds() -> list[Kind]:
    """Every registered kind, in registration order (the built-in ones first)."""
    return list(_KINDS.values())


def kind_of_sensor(kind: str) -> Kind | None:
    """The kind that measures ``sensors:`` entries of ``kind``."""
    return next((k for k in _KINDS.values() if kind in k.sensor_kinds), None)


def kind_of_section(section: str) -> Kind | None:
    """The kind that reads the top-level rig section ``section``."""
    return next((k for k in _KINDS.values() if k.section == section), None)


def sensor_kinds() -> list[str]:
    """Every ``kind:`` a ``sensors:`` entry may have."""
    return [s for k in _KINDS.values() for s in k.sensor_kinds]


@dataclass(frozen=True)
class Instance:
    """One rig entry of one kind: what the loops over a rig's factors iterate."""

    kind: Kind
    entry: Any
    name: str = field(default="")


def instances(rig: RigView) -> Iterator[Instance]:
    """Every (kind, entry) of ``rig``, kind by kind in registration order, entries in rig order."""
    for k in _KINDS.values():
        for e in entries(k, rig):
            yield Instance(k, e, block_name(k, e))


def openings(rig: RigView) -> Iterator[Instance]:
    """The opening (:class:`OpensChain`) of every entry of ``rig`` whose kind opens a chain, in
    the order of :func:`instances`: what a drive's start adds (a GNSS antenna's first fix)."""
    for k in _KINDS.values():
        if implements(k, OpensChain):
            for e in entries(k, rig):
                yield Instance(k.opening, e, block_name(k.opening, e))


def quantities(cfg: Any) -> list[tuple[Kind, Any, Quantity]]:
    """Every calibration quantity of a rig configuration, in the column order of θ: the
    ``sensors:`` entries in their order, then the other kinds in registration order."""
    view = _ConfigOnly(cfg)
    out = []
    for s in cfg.sensors:
        k = kind_of_sensor(s.kind)
        out += [(k, s, q) for q in k.quantities(cfg, s)]
    for k in _KINDS.values():
        if k.sensor_kinds:
            continue
        for e in entries(k, view):
            out += [(k, e, q) for q in k.quantities(cfg, e)]
    # a kind that reads another's quantities (a lidar's road plane, its extrinsic) adds no columns
    seen: set[tuple[str, ...]] = set()
    unique = []
    for k, e, q in out:
        key = tuple(q.coordinate_names())
        if key not in seen:
            seen.add(key)
            unique.append((k, e, q))
    return unique


def columns(cfg: Any) -> list[Column]:
    """The coordinates of θ a rig configuration estimates, in column order."""
    out = []
    for _, _, q in quantities(cfg):
        if not q.estimated:
            continue
        for i, name in enumerate(q.coordinate_names()):
            out.append(Column(name, q.unit, q.block, q.quantity, i if q.size == 3 else q.axis, q.nuisance))
    return out


@dataclass(frozen=True)
class _ConfigOnly:
    """A rig configuration seen as a rig before its coordinates exist (for :func:`entries`)."""

    config: Any
