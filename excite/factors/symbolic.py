"""The kinds' math in CasADi symbols, and what follows from it by automatic differentiation.

Each kind states its measurement, residual and whitening once, for one factor, on a
:class:`FactorInputs` of CasADi SX symbols (:class:`~excite.factors.base.Kind`). From that one
statement:

- :func:`linearisation`: the whitened Jacobians of a factor with respect to its keyframes' world
  states ``[δθ, δp, δv]`` (right perturbation of the orientation) and to the coordinates of its
  entry's estimated quantities (right perturbation of a rotation, additive otherwise), at the
  noise-free measurement of its nominal inputs — the Fisher information's factor. The
  optimizer's information model (:mod:`excite.plan.model`) is built from it, symbolically.
- :func:`blocks`: the same Jacobians evaluated for every factor of an entry on a nominal motion,
  as a :class:`~excite.factors.base.FactorBlock`: what the evaluator uses for a kind without a
  compiled kernel, and what the contract test holds every compiled kernel equal to.
- :func:`residuals`: whitened residuals of recorded measurements at an estimate (the
  calibrator's cost, :mod:`excite.validate.calibrate`), and :func:`recorded_linearisation` their
  exact derivative (the calibrator's Gauss–Newton step).

Everything is compiled once per entry and rig shape (an SX function, mapped over the factors).
The inputs of one factor, flattened: per keyframe ``[vec R (9, row-major), p, v, ω, vec R_V_A]``
(27 numbers), then the IMU samples of its interval if its kind reads them (``n + 1``
orientations and ``n`` specific forces), then the values of the entry's quantities (a rotation's
9 entries, a vector's 3, a scalar), then for :func:`residuals` the measurement.
"""

from __future__ import annotations

import contextvars
import json
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.lazy import ca
from .base import FactorBlock, Kind, Nominal, Quantity, RigView, theta_columns

KEYFRAME_INPUTS = 27  # vec R (9), p (3), v (3), ω (3), vec R_V_A (9)


# --- SX helpers ---------------------------------------------------------------------------------

def hat(v):
    """``[v]×`` of an SX 3-vector."""
    return ca.vertcat(ca.horzcat(0, -v[2], v[1]), ca.horzcat(v[2], 0, -v[0]), ca.horzcat(-v[1], v[0], 0))


def exp(w):
    """``Exp(w)`` (Rodrigues), smooth through zero (series below 1e-4 rad)."""
    t2 = ca.dot(w, w)
    small = t2 < 1e-8
    t = ca.sqrt(ca.if_else(small, 1.0, t2))
    A = ca.if_else(small, 1.0 - t2 / 6.0, ca.sin(t) / t)
    B = ca.if_else(small, 0.5 - t2 / 24.0, (1.0 - ca.cos(t)) / (t * t))
    K = hat(w)
    return ca.DM.eye(3) + A * K + B * ca.mtimes(K, K)


def log(R):
    """Rotation vector of R (angle < π), smooth through the identity."""
    w = 0.5 * ca.vertcat(R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1])
    s2 = ca.dot(w, w)
    c = 0.5 * (ca.trace(R) - 1)
    small = s2 < 1e-12
    s_safe = ca.sqrt(ca.if_else(small, 1.0, s2))
    k = ca.if_else(small, 1.0 + s2 / 6.0, ca.atan2(s_safe, c) / s_safe)
    return k * w


_AT_ZERO_RESIDUAL = contextvars.ContextVar("at_zero_residual", default=False)


def residual_log(R):
    """``Log(R)`` of a rotation residual, one that is the identity at the noise-free measurement
    (``Log(R_measᵀ R_rel)``): exact, but where only its derivative at the identity is built
    (:func:`linearised`), its first-order part — the skew part of R, whose derivative there is
    Log's — without the series and arctangent branches that would be evaluated (and
    differentiated) on every call."""
    if _AT_ZERO_RESIDUAL.get():
        return 0.5 * ca.vertcat(R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1])
    return log(R)


def chol(A, n: int):
    """Lower Cholesky factor of a symmetric positive definite n×n SX matrix (list of rows)."""
    L = [[None] * n for _ in range(n)]
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s = s - L[j][k] * L[j][k]
        d = ca.sqrt(s)
        L[j][j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s = s - L[i][k] * L[j][k]
            L[i][j] = s / d
    return L


def forward_solve(L, B, n: int):
    """``L⁻¹ B`` for a lower-triangular factor from :func:`chol` (B an SX with n rows)."""
    rows = []
    for i in range(n):
        r = B[i, :]
        for k in range(i):
            r = r - L[i][k] * rows[k]
        rows.append(r / L[i][i])
    return ca.vertcat(*rows)


def whiten(W, r, n: int):
    """``W r`` for a whitening from :meth:`Kind.sqrt_information`: a vector (diagonal), an SX
    matrix, or ``("cholesky", Σ)`` — the inverse Cholesky factor of a covariance Σ."""
    if isinstance(W, tuple) and W[0] == "cholesky":
        return forward_solve(chol(W[1], n), r, n)
    W = ca.SX(W) if not isinstance(W, ca.SX) else W
    if W.size2() == 1:
        return W * r
    return ca.mtimes(W, r)


def _mat(v, i: int = 0):
    """A 3×3 SX from 9 row-major entries of ``v`` at ``i``."""
    return ca.reshape(v[i:i + 9], 3, 3).T


# --- the inputs of one factor ------------------------------------------------------------------


@dataclass
class FactorInputs:
    """One factor's inputs as its kind's math reads them (CasADi SX).

    Per keyframe of the factor (one, or a pair ``dT`` apart): body orientation ``R``, world
    position ``p`` and velocity ``v`` (the states), body rate ``omega`` and suspension tilt
    ``R_V_A`` (nominal inputs, not states). ``q``: the entry's quantities by
    :attr:`~excite.factors.base.Quantity.name` (rotations 3×3, vectors 3×1, scalars). ``imu_R``
    / ``imu_f``: the IMU samples of the interval (orientations at the n + 1 sample times, the n
    specific forces), for kinds that read them. ``R_V_B``, ``p_V_B``: the IMU pose in V."""

    R: list
    p: list
    v: list
    omega: list
    R_V_A: list
    q: dict[str, Any]
    imu_R: list | None
    imu_f: list | None
    dT: float
    dt_imu: float
    entry: Any
    rig: RigView
    R_V_B: np.ndarray
    p_V_B: np.ndarray


@dataclass(frozen=True)
class Layout:
    """How one factor's inputs are flattened (see the module docstring)."""

    arity: int
    n_samples: int  # IMU samples of the interval (0: the kind reads none)
    quantities: tuple[Quantity, ...]

    @property
    def n_state_inputs(self) -> int:
        return KEYFRAME_INPUTS * self.arity

    @property
    def n_sample_inputs(self) -> int:
        return 9 * (self.n_samples + 1) + 3 * self.n_samples if self.n_samples else 0

    @property
    def n_quantity_inputs(self) -> int:
        return sum(q.nominal_vector().size for q in self.quantities)

    @property
    def estimated(self) -> list[Quantity]:
        return [q for q in self.quantities if q.estimated]

    @property
    def n_theta(self) -> int:
        return sum(q.size for q in self.estimated)


def layout(kind: Kind, rig: RigView, entry: Any) -> Layout:
    n = int(round(rig.config.imu.update_rate / rig.keyframe_rate_hz)) * kind.stride(rig, entry)
    return Layout(kind.arity, n if kind.uses_imu_samples else 0, tuple(kind.quantities(rig.config, entry)))


def _inputs(kind: Kind, rig: RigView, entry: Any, lay: Layout, x, samples, qv, dx=None, dq=None) -> FactorInputs:
    """:class:`FactorInputs` from flat SX inputs, the states moved by ``dx`` (9 per keyframe) and the
    estimated quantities by ``dq`` where given."""
    R, p, v, w, RVA = [], [], [], [], []
    for a in range(lay.arity):
        o = KEYFRAME_INPUTS * a
        Ra = _mat(x, o)
        pa, va = x[o + 9:o + 12], x[o + 12:o + 15]
        if dx is not None:
            d = dx[9 * a:9 * (a + 1)]
            Ra = ca.mtimes(Ra, ca.DM.eye(3) + hat(d[0:3]))  # first order: all that the Jacobian needs
            pa, va = pa + d[3:6], va + d[6:9]
        R.append(Ra)
        p.append(pa)
        v.append(va)
        w.append(x[o + 15:o + 18])
        RVA.append(_mat(x, o + 18))
    imu_R = imu_f = None
    if lay.n_samples:
        n = lay.n_samples
        imu_R = [_mat(samples, 9 * s) for s in range(n + 1)]
        f0 = 9 * (n + 1)
        imu_f = [samples[f0 + 3 * s:f0 + 3 * s + 3] for s in range(n)]
    q, o, e = {}, 0, 0
    for qt in lay.quantities:
        size = qt.nominal_vector().size
        val = qv[o:o + size]
        if qt.rotation:
            val = _mat(qv, o)
            if dq is not None and qt.estimated:
                val = ca.mtimes(val, ca.DM.eye(3) + hat(dq[e:e + 3]))
        elif dq is not None and qt.estimated:
            val = val + dq[e:e + qt.size]
        q[qt.name] = val if size > 1 else val[0]
        o += size
        e += qt.size if qt.estimated else 0
    stride = kind.stride(rig, entry)
    pose = rig.config.vehicle.T_V_B
    return FactorInputs(R, p, v, w, RVA, q, imu_R, imu_f, stride / rig.keyframe_rate_hz,
                        1.0 / rig.config.imu.update_rate, entry, rig, pose.R, pose.p)


def symbols(lay: Layout):
    """Flat SX inputs of one factor: states and nominal inputs, IMU samples, quantity values."""
    return (ca.SX.sym("x", lay.n_state_inputs), ca.SX.sym("imu", lay.n_sample_inputs),
            ca.SX.sym("q", lay.n_quantity_inputs))


def linearised(kind: Kind, rig: RigView, entry: Any, lay: Layout, x, samples, qv, meas=None):
    """Whitened Jacobians ``(Jx, Jt)`` of one factor (SX: rows × 9·arity world states, rows ×
    estimated coordinates): at the noise-free measurement of the inputs ``x, samples, qv`` (the
    Fisher information's factor), or at a recorded measurement ``meas`` (an SX symbol: the exact
    derivative of the residual the calibrator minimises, whitening included)."""
    base = _inputs(kind, rig, entry, lay, x, samples, qv)
    dx = ca.SX.sym("dx", 9 * lay.arity)
    dq = ca.SX.sym("dq", lay.n_theta)
    moved = _inputs(kind, rig, entry, lay, x, samples, qv, dx, dq)
    if meas is None:
        token = _AT_ZERO_RESIDUAL.set(True)
        try:
            res = kind.residual(moved, kind.measurement(base))
            r = whiten(kind.sqrt_information(base), res, res.numel())
        finally:
            _AT_ZERO_RESIDUAL.reset(token)
    else:
        res = kind.residual(moved, meas)
        r = whiten(kind.sqrt_information(moved), res, res.numel())
    Jx = ca.substitute(ca.jacobian(r, dx), ca.vertcat(dx, dq), ca.DM.zeros(dx.numel() + dq.numel()))
    Jt = ca.substitute(ca.jacobian(r, dq), ca.vertcat(dx, dq), ca.DM.zeros(dx.numel() + dq.numel()))
    return Jx, Jt


# --- compiled, mapped over the factors of an entry ---------------------------------------------


def _key(kind: Kind, rig: RigView, entry: Any) -> tuple:
    """What the compiled functions of an entry depend on."""
    cfg = rig.config
    dump = entry.model_dump(mode="json") if hasattr(entry, "model_dump") else repr(entry)
    return (kind.name, json.dumps(dump, sort_keys=True, default=str), float(rig.keyframe_rate_hz),
            float(cfg.imu.update_rate), json.dumps(cfg.vehicle.model_dump(mode="json"), sort_keys=True),
            json.dumps(cfg.imu.model_dump(mode="json"), sort_keys=True))


_CACHE: dict[tuple, Any] = {}

# CasADi's symbolics are not thread-safe, and neither is a call of a Function on numpy arrays (it
# makes DM matrices and their sparsity patterns): the evaluator linearises a drive's pieces in a
# thread pool, and two threads building their entry's functions at once crashed the process
# (a segmentation fault in ca.jacobian). Every use of CasADi here holds this lock; the compiled
# kernels of the other kinds run in parallel still.
_LOCK = threading.RLock()


def _cached(what: str, kind: Kind, rig: RigView, entry: Any, build):
    key = (what,) + _key(kind, rig, entry)
    with _LOCK:
        if key not in _CACHE:
            if len(_CACHE) > 256:
                _CACHE.clear()
            _CACHE[key] = build()
        return _CACHE[key]


def _mapped(what: str, kind: Kind, rig: RigView, entry: Any, function, n: int) -> ca.Function:
    """``function`` (one of this module's per-factor functions) mapped over ``n`` factors, made once
    per entry and count (making a map costs a fifth of evaluating one)."""
    return _cached(f"{what}@{n}", kind, rig, entry, lambda: function(kind, rig, entry).map(n, "serial"))


def linearisation(kind: Kind, rig: RigView, entry: Any) -> ca.Function:
    """``(x, imu, q) → (Jx, Jt)`` of one factor (:func:`linearised`), compiled once per entry."""
    def build():
        lay = layout(kind, rig, entry)
        x, s, q = symbols(lay)
        Jx, Jt = linearised(kind, rig, entry, lay, x, s, q)
        return ca.Function(f"lin_{kind.name}", [x, s, q], [Jx, Jt], {"cse": True})

    return _cached("lin", kind, rig, entry, build)


def recorded_linearisation(kind: Kind, rig: RigView, entry: Any) -> ca.Function:
    """``(x, imu, q, meas) → (Jx, Jt)`` of one factor at a recorded measurement (:func:`linearised`),
    compiled once per entry: the derivative of :func:`residual_function`."""
    def build():
        lay = layout(kind, rig, entry)
        x, s, q = symbols(lay)
        meas = ca.SX.sym("m", kind.measurement(_inputs(kind, rig, entry, lay, x, s, q)).numel())
        Jx, Jt = linearised(kind, rig, entry, lay, x, s, q, meas)
        return ca.Function(f"rlin_{kind.name}", [x, s, q, meas], [Jx, Jt], {"cse": True})

    return _cached("rlin", kind, rig, entry, build)


def residual_function(kind: Kind, rig: RigView, entry: Any) -> ca.Function:
    """``(x, imu, q, meas) → W r`` of one factor, compiled once per entry."""
    def build():
        lay = layout(kind, rig, entry)
        x, s, q = symbols(lay)
        f = _inputs(kind, rig, entry, lay, x, s, q)
        meas = ca.SX.sym("m", kind.measurement(f).numel())
        res = kind.residual(f, meas)
        r = whiten(kind.sqrt_information(f), res, res.numel())
        return ca.Function(f"res_{kind.name}", [x, s, q, meas], [r], {"cse": True})

    return _cached("res", kind, rig, entry, build)


def measurement_function(kind: Kind, rig: RigView, entry: Any) -> ca.Function:
    """``(x, imu, q) → measurement`` of one factor (noise-free), compiled once per entry."""
    def build():
        lay = layout(kind, rig, entry)
        x, s, q = symbols(lay)
        return ca.Function(f"meas_{kind.name}", [x, s, q], [kind.measurement(_inputs(kind, rig, entry, lay, x, s, q))])

    return _cached("meas", kind, rig, entry, build)


def keyframe_inputs(nom: Nominal, first: np.ndarray, arity: int, stride: int) -> np.ndarray:
    """The per-keyframe inputs of factors starting at keyframes ``first`` (27 · arity × N)."""
    cols = []
    for a in range(arity):
        k = first + a * stride
        cols += [nom.R[k].reshape(-1, 9), nom.p[k], nom.v[k], nom.omega[k], nom.R_V_A[k].reshape(-1, 9)]
    return np.hstack(cols).T


def sample_inputs(nom: Nominal, first: np.ndarray, lay: Layout) -> np.ndarray:
    """The IMU samples of the intervals starting at keyframes ``first`` (columns, one per factor)."""
    if not lay.n_samples:
        return np.zeros((0, first.size))
    n = lay.n_samples
    base = first * nom.imu_per_keyframe
    idx = base[:, None] + np.arange(n + 1)[None, :]
    R = nom.imu_R[idx].reshape(first.size, -1)
    f = nom.imu_f[idx[:, :n]].reshape(first.size, -1)
    return np.hstack([R, f]).T


def quantity_inputs(lay: Layout, values: dict[str, Any] | None = None) -> np.ndarray:
    """The quantities' values, flat: their nominal values, or ``values`` by name where given."""
    parts = []
    for q in lay.quantities:
        v = q.nominal if values is None or q.name not in values else values[q.name]
        parts.append(np.asarray(v, dtype=float).reshape(-1))
    return np.concatenate(parts) if parts else np.zeros(0)


def coordinate_names(lay: Layout) -> list[str]:
    return [n for q in lay.estimated for n in q.coordinate_names()]


def blocks(kind: Kind, nom: Nominal, rig: RigView, entry: Any, values: dict[str, Any] | None = None,
           meas: np.ndarray | None = None) -> FactorBlock | None:
    """The whitened Jacobians of every factor of ``entry`` on ``nom``, from the derivative of its
    kind's residual at the noise-free measurement (see the module docstring), or at the recorded
    measurements ``meas`` (N × m, one row per factor) where given, at the quantity ``values`` (by
    name; the nominal ones otherwise)."""
    with _LOCK:
        first = kind.factor_keyframes(rig, entry, nom.n_keyframes, nom)
        if first.size == 0:
            return None
        lay = layout(kind, rig, entry)
        fn = linearisation if meas is None else recorded_linearisation
        lin = fn(kind, rig, entry)
        args = [keyframe_inputs(nom, first, lay.arity, kind.stride(rig, entry)), sample_inputs(nom, first, lay),
                np.repeat(quantity_inputs(lay, values)[:, None], first.size, axis=1)]
        if meas is not None:
            args.append(np.asarray(meas, dtype=float).T)
        Jx, Jt = _mapped(fn.__name__, kind, rig, entry, fn, first.size)(*args)
        N, r = first.size, lin.size1_out(0)  # the entry's rows (a kind's entries may differ: a 2-D radar)
        Jx = np.asarray(Jx).reshape(r, N, 9 * lay.arity).transpose(1, 0, 2)
        Jt = np.asarray(Jt).reshape(r, N, lay.n_theta).transpose(1, 0, 2)
        cols = theta_columns(rig, coordinate_names(lay))
        return FactorBlock(kind.block_name(entry), first, kind.stride(rig, entry), lay.arity,
                           np.ascontiguousarray(Jx), np.ascontiguousarray(Jt), cols)


def jacobians(kind: Kind, nom: Nominal, rig: RigView, entry: Any) -> FactorBlock | None:
    """The evaluator's whitened Jacobians of ``entry`` on ``nom``: its kind's compiled kernel
    (:meth:`~excite.factors.base.Kind.blocks`, held equal to the derivative by the contract
    tests), or the derivative of its residual (:func:`blocks`)."""
    return kind.blocks(nom, rig, entry) if kind.compiled else blocks(kind, nom, rig, entry)


def residuals(kind: Kind, nom: Nominal, rig: RigView, entry: Any, first: np.ndarray, meas: np.ndarray,
              values: dict[str, Any] | None = None) -> np.ndarray:
    """Whitened residuals (N × rows) of the measurements ``meas`` (N × m) of the factors starting at
    keyframes ``first``, at the states and samples of ``nom`` and the quantity ``values`` (by name;
    the nominal ones otherwise)."""
    with _LOCK:
        G = residual_function(kind, rig, entry)
        if first.size == 0:
            return np.zeros((0, G.size1_out(0)))
        lay = layout(kind, rig, entry)
        F = _mapped("res", kind, rig, entry, residual_function, first.size)
        r = F(keyframe_inputs(nom, first, lay.arity, kind.stride(rig, entry)), sample_inputs(nom, first, lay),
              np.repeat(quantity_inputs(lay, values)[:, None], first.size, axis=1), np.asarray(meas, dtype=float).T)
        return np.asarray(r).T


def measurements(kind: Kind, nom: Nominal, rig: RigView, entry: Any, first: np.ndarray,
                 values: dict[str, Any] | None = None) -> np.ndarray:
    """The noise-free measurements (N × m) of the factors starting at keyframes ``first``."""
    with _LOCK:
        lay = layout(kind, rig, entry)
        G = measurement_function(kind, rig, entry)
        if first.size == 0:
            return np.zeros((0, G.size1_out(0)))
        m = _mapped("meas", kind, rig, entry, measurement_function, first.size)(keyframe_inputs(nom, first, lay.arity, kind.stride(rig, entry)), sample_inputs(nom, first, lay),
              np.repeat(quantity_inputs(lay, values)[:, None], first.size, axis=1))
        return np.asarray(m).T

