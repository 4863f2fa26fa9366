"""The kinds' math in CasADi symbols, and what follows from it by automatic differentiation.

Each kind states its measurement, residual and whitening once, for one factor, on a
:class:`FactorInputs` of CasADi SX symbols (:class:`~excite.factors.base.Kind`). From that one
statement:

- :func:`linearised`: the whitened Jacobians of a factor with respect to its keyframes' world
  states ``[δθ, δp, δv]`` (right perturbation of the orientation) and to the coordinates of its
  entry's quantities (right perturbation of a rotation, additive otherwise), at the noise-free
  measurement of its nominal inputs — the Fisher information's factor. The evaluator's kernels
  are generated from it (:mod:`excite.factors.generate`, run by :mod:`excite.factors.kernels`);
  the optimizer's information model (:mod:`excite.plan.model`) is built from it, symbolically.
- :func:`blocks`: the same Jacobians evaluated in CasADi's virtual machine for every factor of an
  entry on a nominal motion, as a :class:`~excite.factors.base.FactorBlock` (what the evaluator
  falls back to for a kind with no kernel and no compiler, and what the calibrator uses).
- :func:`residuals`: whitened residuals of recorded measurements at an estimate (the
  calibrator's cost, :mod:`excite.validate.calibrate`), and :func:`recorded_linearisation` their
  exact derivative (the calibrator's Gauss–Newton step).

The inputs of one factor are laid out as :class:`excite.factors.kernels.Layout` says: per keyframe
``[vec R (9, row-major), p, v, ω, vec R_V_A]``, then the IMU samples of its interval if its kind
reads them (``n + 1`` orientations and ``n`` specific forces; the generated kernels take their
summary instead), then the values of the entry's quantities, then the constants its math reads.
In this module's functions (the virtual machine's, the optimizer's) the constants are numbers of
the entry; in the generated kernels they are inputs, so that one kernel serves every entry of a
kind's variant.
"""

from __future__ import annotations

import contextvars
import json
import math
import threading
from typing import Any

import numpy as np

from ..core.lazy import ca
from . import base
from .base import FactorBlock, FactorInputs, Kind, Nominal, RigView, theta_columns
from .layout import (COMMON, KEYFRAME_INPUTS, Layout, constant_inputs, constant_values, coordinate_names,
                      keyframe_inputs, layout, quantity_inputs, sample_inputs)

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


def mat(v, i: int = 0):
    """A 3×3 SX from 9 row-major entries of ``v`` at ``i``."""
    return ca.reshape(v[i:i + 9], 3, 3).T


# --- the inputs of one factor ------------------------------------------------------------------


def unflatten(v, layout_: tuple[tuple[str, tuple[int, ...]], ...]) -> dict[str, Any]:
    """Named pieces of a flat SX/DM vector: scalars, 3-vectors, 3×3 matrices (row-major)."""
    out, o = {}, 0
    for name, shape in layout_:
        size = math.prod(shape)
        piece = v[o:o + size]
        out[name] = piece[0] if shape == () else (mat(v, o) if shape == (3, 3) else
                                                   piece if len(shape) == 1 else ca.reshape(piece, shape[1], shape[0]).T)
        o += size
    return out


def inputs(kind: Kind, lay: Layout, x, imu, qv, cv, dx=None, dq=None, entry=None, rig=None,
           from_samples: bool = True) -> FactorInputs:
    """:class:`FactorInputs` from flat SX inputs: keyframes ``x``, ``imu`` (the interval's samples
    ``from_samples``, or their summary), quantity values ``qv`` and constants ``cv``; the states
    moved by ``dx`` (9 per keyframe) and every quantity by ``dq`` where given (to first order: all
    that a Jacobian at ``dx = dq = 0`` needs)."""
    R, p, v, w, RVA = [], [], [], [], []
    for a in range(lay.arity):
        o = KEYFRAME_INPUTS * a
        Ra = mat(x, o)
        pa, va = x[o + 9:o + 12], x[o + 12:o + 15]
        if dx is not None:
            d = dx[9 * a:9 * (a + 1)]
            Ra = ca.mtimes(Ra, ca.DM.eye(3) + hat(d[0:3]))
            pa, va = pa + d[3:6], va + d[6:9]
        R.append(Ra)
        p.append(pa)
        v.append(va)
        w.append(x[o + 15:o + 18])
        RVA.append(mat(x, o + 18))
    c = unflatten(cv, lay.constants)
    q, o, e = {}, 0, 0
    for qt in lay.quantities:
        size = qt.nominal_vector().size
        val = qv[o:o + size]
        if qt.rotation:
            val = mat(qv, o)
            if dq is not None:
                val = ca.mtimes(val, ca.DM.eye(3) + hat(dq[e:e + 3]))
        elif dq is not None:
            val = val + dq[e:e + qt.size]
        q[qt.name] = val if size > 1 else val[0]
        o += size
        e += qt.size
    summary = None
    if lay.n_summary:
        summary = fold(kind, lay, imu, c) if from_samples else unflatten(imu, kind.summary_fields)
    common = {k for k, _ in COMMON}
    return FactorInputs(R, p, v, w, RVA, q, {k: val for k, val in c.items() if k not in common}, summary, c["dT"],
                        c["R_V_B"], c["p_V_B"], lay.variant, entry, rig)


def fold(kind: Kind, lay: Layout, samples, c: dict[str, Any]) -> dict[str, Any]:
    """The summary of an interval's IMU samples (SX: the n + 1 orientations, then the n specific
    forces): the kind's fold over them, from the last to the first (:class:`~excite.factors.base.ReadsImu`)."""
    n = lay.n_samples
    R = [mat(samples, 9 * s) for s in range(n + 1)]
    f0 = 9 * (n + 1)
    state = ca.SX(lay.n_state, 1)
    for s in range(n - 1, -1, -1):
        state = kind.summary_step(state, R[0], R[s], samples[f0 + 3 * s:f0 + 3 * s + 3], c)
    return kind.summary_finish(state, R[0], R[n], c)


def symbols(lay: Layout, from_samples: bool = True):
    """Flat SX inputs of one factor: keyframes, the IMU samples (or their summary), quantity
    values, constants."""
    return (ca.SX.sym("x", lay.n_state_inputs), ca.SX.sym("imu", lay.n_sample_inputs if from_samples else lay.n_summary),
            ca.SX.sym("q", lay.n_quantity_inputs), ca.SX.sym("c", lay.n_constants))


def derivatives(kind: Kind, lay: Layout, x, imu, qv, cv, meas=None, whitened: bool = True, entry=None, rig=None,
                from_samples: bool = True):
    """Jacobians ``(Jx, Jt)`` of one factor's residual (SX: rows × 9·arity world states, rows ×
    every coordinate of every quantity): whitened by the statement's :meth:`sqrt_information`, or
    not (``whitened=False``: rows another whitening is applied to); at the noise-free measurement
    of the inputs (the Fisher information's factor), or at a recorded measurement ``meas`` (an SX
    symbol: the exact derivative of the residual the calibrator minimises, whitening included)."""
    args = dict(entry=entry, rig=rig, from_samples=from_samples)
    base = inputs(kind, lay, x, imu, qv, cv, **args)
    dx = ca.SX.sym("dx", 9 * lay.arity)
    dq = ca.SX.sym("dq", lay.n_coordinates)
    moved = inputs(kind, lay, x, imu, qv, cv, dx, dq, **args)
    if meas is None:
        token = _AT_ZERO_RESIDUAL.set(True)
        try:
            res = kind.residual(moved, kind.measurement(base))
            r = whiten(kind.sqrt_information(base), res, res.numel()) if whitened else res
        finally:
            _AT_ZERO_RESIDUAL.reset(token)
    else:
        res = kind.residual(moved, meas)
        r = whiten(kind.sqrt_information(moved), res, res.numel()) if whitened else res
    zero = ca.DM.zeros(dx.numel() + dq.numel())
    Jx = ca.substitute(ca.jacobian(r, dx), ca.vertcat(dx, dq), zero)
    Jt = ca.substitute(ca.jacobian(r, dq), ca.vertcat(dx, dq), zero)
    return Jx, Jt


def linearised(kind: Kind, rig: RigView, entry: Any, x, samples, qv, meas=None):
    """Whitened Jacobians ``(Jx, Jt)`` of one factor of ``entry`` (SX: rows × 9·arity world
    states, rows × its estimated coordinates) with its constants' values, from the symbols ``x``
    (keyframes), ``samples`` (the interval's IMU samples) and ``qv`` (quantity values): see
    :func:`derivatives`."""
    lay = layout(kind, rig, entry)
    cv = ca.DM(constant_inputs(lay, constant_values(kind, rig, entry)))
    Jx, Jt = derivatives(kind, lay, x, samples, qv, cv, meas, entry=entry, rig=rig)
    return Jx, Jt[:, lay.estimated_columns().tolist()]


# --- in CasADi's virtual machine, mapped over the factors of an entry ---------------------------


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
# (a segmentation fault in ca.jacobian). Every use of CasADi here holds this lock.
LOCK = threading.RLock()


def _cached(what: str, kind: Kind, rig: RigView, entry: Any, build):
    key = (what,) + _key(kind, rig, entry)
    with LOCK:
        if key not in _CACHE:
            if len(_CACHE) > 256:
                _CACHE.clear()
            _CACHE[key] = build()
        return _CACHE[key]


def _mapped(what: str, kind: Kind, rig: RigView, entry: Any, function, n: int) -> ca.Function:
    """``function`` (one of this module's per-factor functions) mapped over ``n`` factors, made once
    per entry and count (making a map costs a fifth of evaluating one)."""
    return _cached(f"{what}@{n}", kind, rig, entry, lambda: function(kind, rig, entry).map(n, "serial"))


def _entry_symbols(kind: Kind, rig: RigView, entry: Any):
    lay = layout(kind, rig, entry)
    x, s, q, _ = symbols(lay)
    cv = ca.DM(constant_inputs(lay, constant_values(kind, rig, entry)))
    return lay, x, s, q, cv


def linearisation(kind: Kind, rig: RigView, entry: Any) -> ca.Function:
    """``(x, imu, q) → (Jx, Jt)`` of one factor (:func:`linearised`; ``Jt`` over the estimated
    coordinates), compiled once per entry."""
    def build():
        lay, x, s, q, cv = _entry_symbols(kind, rig, entry)
        Jx, Jt = derivatives(kind, lay, x, s, q, cv, entry=entry, rig=rig)
        return ca.Function(f"lin_{kind.name}", [x, s, q], [Jx, Jt[:, lay.estimated_columns().tolist()]], {"cse": True})

    return _cached("lin", kind, rig, entry, build)


def raw_linearisation(kind: Kind, rig: RigView, entry: Any) -> ca.Function:
    """:func:`linearisation` of the residual's rows not whitened (another whitening is applied
    to them: :meth:`~excite.factors.base.Kind.whitening`)."""
    def build():
        lay, x, s, q, cv = _entry_symbols(kind, rig, entry)
        Jx, Jt = derivatives(kind, lay, x, s, q, cv, whitened=False, entry=entry, rig=rig)
        return ca.Function(f"raw_{kind.name}", [x, s, q], [Jx, Jt[:, lay.estimated_columns().tolist()]], {"cse": True})

    return _cached("raw", kind, rig, entry, build)


def recorded_linearisation(kind: Kind, rig: RigView, entry: Any, whitened: bool = True) -> ca.Function:
    """``(x, imu, q, meas) → (Jx, Jt)`` of one factor at a recorded measurement (:func:`derivatives`),
    compiled once per entry: the derivative of :func:`residual_function` (``whitened=False``: of
    its rows not whitened, :func:`raw_recorded_linearisation`)."""
    def build():
        lay, x, s, q, cv = _entry_symbols(kind, rig, entry)
        f = inputs(kind, lay, x, s, q, cv, entry=entry, rig=rig)
        meas = ca.SX.sym("m", kind.measurement(f).numel())
        Jx, Jt = derivatives(kind, lay, x, s, q, cv, meas, whitened=whitened, entry=entry, rig=rig)
        return ca.Function(f"{'' if whitened else 'raw_'}rlin_{kind.name}", [x, s, q, meas],
                           [Jx, Jt[:, lay.estimated_columns().tolist()]], {"cse": True})

    return _cached("rlin" if whitened else "raw_rlin", kind, rig, entry, build)


def raw_recorded_linearisation(kind: Kind, rig: RigView, entry: Any) -> ca.Function:
    """:func:`recorded_linearisation` of the residual's rows not whitened (another whitening is
    applied to them: :meth:`~excite.factors.base.Kind.whitening`)."""
    return recorded_linearisation(kind, rig, entry, whitened=False)


def residual_function(kind: Kind, rig: RigView, entry: Any, whitened: bool = True) -> ca.Function:
    """``(x, imu, q, meas) → W r`` of one factor, compiled once per entry (``whitened=False``:
    ``r``, :func:`raw_residual_function`)."""
    def build():
        lay, x, s, q, cv = _entry_symbols(kind, rig, entry)
        f = inputs(kind, lay, x, s, q, cv, entry=entry, rig=rig)
        meas = ca.SX.sym("m", kind.measurement(f).numel())
        res = kind.residual(f, meas)
        r = whiten(kind.sqrt_information(f), res, res.numel()) if whitened else res
        return ca.Function(f"{'' if whitened else 'raw_'}res_{kind.name}", [x, s, q, meas], [r], {"cse": True})

    return _cached("res" if whitened else "raw_res", kind, rig, entry, build)


def raw_residual_function(kind: Kind, rig: RigView, entry: Any) -> ca.Function:
    """:func:`residual_function` not whitened (another whitening is applied to its rows)."""
    return residual_function(kind, rig, entry, whitened=False)


def measurement_function(kind: Kind, rig: RigView, entry: Any) -> ca.Function:
    """``(x, imu, q) → measurement`` of one factor (noise-free), compiled once per entry."""
    def build():
        lay, x, s, q, cv = _entry_symbols(kind, rig, entry)
        return ca.Function(f"meas_{kind.name}", [x, s, q],
                           [kind.measurement(inputs(kind, lay, x, s, q, cv, entry=entry, rig=rig))])

    return _cached("meas", kind, rig, entry, build)


def _args(kind: Kind, nom: Nominal, rig: RigView, entry: Any, first: np.ndarray, values: dict[str, Any] | None):
    lay = layout(kind, rig, entry)
    return lay, [keyframe_inputs(nom, first, lay.arity, base.stride(kind, rig, entry)).T, sample_inputs(nom, first, lay).T,
                 np.repeat(quantity_inputs(lay, values)[:, None], first.size, axis=1)]


def blocks(kind: Kind, nom: Nominal, rig: RigView, entry: Any, values: dict[str, Any] | None = None,
           meas: np.ndarray | None = None, whitening: np.ndarray | None = None) -> FactorBlock | None:
    """The whitened Jacobians of every factor of ``entry`` on ``nom``, from the derivative of its
    kind's residual at the noise-free measurement (see the module docstring), or at the recorded
    measurements ``meas`` (N × m, one row per factor) where given, at the quantity ``values`` (by
    name; the nominal ones otherwise); whitened by ``whitening`` (N × rows × the residual's rows)
    in place of the statement's where given."""
    with LOCK:
        first = base.factor_keyframes(kind, rig, entry, nom.n_keyframes, nom)
        if first.size == 0:
            return None
        if meas is None:
            fn = linearisation if whitening is None else raw_linearisation
        else:
            fn = recorded_linearisation if whitening is None else raw_recorded_linearisation
        lay, args = _args(kind, nom, rig, entry, first, values)
        if meas is not None:
            args.append(np.asarray(meas, dtype=float).T)
        lin = fn(kind, rig, entry)
        Jx, Jt = _mapped(fn.__name__, kind, rig, entry, fn, first.size)(*args)
        N, r = first.size, lin.size1_out(0)  # the entry's rows (a kind's entries may differ: a 2-D radar)
        Jx = np.asarray(Jx).reshape(r, N, 9 * lay.arity).transpose(1, 0, 2)
        Jt = np.asarray(Jt).reshape(r, N, lay.n_theta).transpose(1, 0, 2)
        if whitening is not None:
            Jx, Jt = whitening @ Jx, whitening @ Jt
        cols = theta_columns(rig, coordinate_names(lay)) if lay.n_theta else np.zeros(0, dtype=int)
        return FactorBlock(base.block_name(kind, entry), first, base.stride(kind, rig, entry), lay.arity,
                           np.ascontiguousarray(Jx), np.ascontiguousarray(Jt), cols)


def residuals(kind: Kind, nom: Nominal, rig: RigView, entry: Any, first: np.ndarray, meas: np.ndarray,
              values: dict[str, Any] | None = None, whitening: np.ndarray | None = None) -> np.ndarray:
    """Whitened residuals (N × rows) of the measurements ``meas`` (N × m) of the factors starting at
    keyframes ``first``, at the states and samples of ``nom`` and the quantity ``values`` (by name;
    the nominal ones otherwise); whitened by ``whitening`` (N × rows × the residual's rows) in
    place of the statement's where given."""
    with LOCK:
        fn = residual_function if whitening is None else raw_residual_function
        G = fn(kind, rig, entry)
        if first.size == 0:
            return np.zeros((0, G.size1_out(0)))
        _, args = _args(kind, nom, rig, entry, first, values)
        r = np.asarray(_mapped(fn.__name__, kind, rig, entry, fn, first.size)(*args,
                                                                              np.asarray(meas, dtype=float).T)).T
        return r if whitening is None else np.einsum("nij,nj->ni", whitening, r)


def measurements(kind: Kind, nom: Nominal, rig: RigView, entry: Any, first: np.ndarray,
                 values: dict[str, Any] | None = None) -> np.ndarray:
    """The noise-free measurements (N × m) of the factors starting at keyframes ``first``."""
    with LOCK:
        G = measurement_function(kind, rig, entry)
        if first.size == 0:
            return np.zeros((0, G.size1_out(0)))
        _, args = _args(kind, nom, rig, entry, first, values)
        return np.asarray(_mapped("meas", kind, rig, entry, measurement_function, first.size)(*args)).T

