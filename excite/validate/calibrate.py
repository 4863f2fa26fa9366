"""Nonlinear batch calibration: Levenberg–Marquardt over the joint sparse problem.

:func:`calibrate` estimates the body trajectory (orientation, position, velocity at every
keyframe) and the calibration from :class:`~excite.validate.simulate.SensorData`, with the factors
the evaluator scores: every entry of the rig that recorded data, through its measurement kind's
one statement of the residual (:mod:`excite.factors`), evaluated at the current estimate on a
:class:`~excite.factors.base.Nominal` made of the estimated states and the bias-corrected IMU
samples. The step is exact Gauss–Newton: the residual's derivative at the *recorded* measurements
(:func:`excite.factors.symbolic.recorded_linearisation`), so that the solver's fixed point is the
cost's minimum also where a derivative depends on the reading (the steering's kinematic form, a
speed-dependent weight); with the derivative at the noise-free measurement (the evaluator's
linearisation) it was not (a car trial stalled 19 units of cost above its optimum). Which
directions of the calibration the step may move, and the information reported, come from the
evaluator's linearisation: at the recorded measurements the noise adds terms of O(residual) that
give an exactly unobservable direction spurious information of its own (a vertical lever arm on a
flat lot wandered 76 targets). The drive is closed as the evaluator closes it (:mod:`excite.information.closure`:
the same parametrisation, a prior on the first keyframe's gauge, the last keyframe's held
components) and the sparse Jacobian assembled by :func:`excite.information.dense.jacobian`.

The body rate at a keyframe (lever-arm velocity, time-offset prediction) is the bias-corrected
gyro averaged over the two samples around it; the suspension tilt is a known input. Both are
taken as known by the information model too. :func:`initialise` builds a start as real
calibrators do, from the kinds it knows (rotations from the odometry sensors' rotations and the
gyro; the trajectory from the IMU, the metric sensors, the wheels and the non-holonomic
constraint); a kind it does not know starts at its nominal values.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.linalg.lapack import dpbtrf, dtbtrs

from ..core import so3
from ..errors import FactorisationError, ValidateError
from ..factors import base as registry
from ..factors import symbolic
from ..factors.base import Nominal
from ..factors.imu import preintegrate_all
from ..factors.nonholonomic import sigma_mps
from ..factors.odometry import (Odometry, drift_whitening, pair_sigmas, reported_whitening,
                                residual_information, sqrt_psd)
from ..factors.wheel import increment_sigma_rad
from ..information import dense
from ..information import kernels as info_kernels
from ..information.closure import GAUGE_SIGMA_POS_M, GAUGE_SIGMA_YAW_RAD, Closure
from ..information.problem import Problem, to_local
from ..motion.trajectory import GRAVITY
from ..rig.config import Rig
from .simulate import Calibration, SensorData


@dataclass(frozen=True)
class SolverSettings:
    """Trust-region (Levenberg–Marquardt) settings of :func:`calibrate`.

    The step is solved in scaled coordinates (states: columns of J at unit norm; calibration: in
    units of its targets). Convergence: the Gauss–Newton decrement ``√(gᵀH⁻¹g)`` — the distance
    from the estimate to the minimum of the local model, in the metric of the whitened cost, i.e.
    in standard deviations of the joint estimate — is below ``decrement_tolerance``. It is the
    undamped step's length in that metric, so a step made short by the damping (or by the scale of
    a parameter's target) is never taken for convergence. ``max_iterations``: linearisations at
    most. ``lambda_initial/min/max``: Marquardt damping (× diag H), updated from the gain ratio
    (Nielsen). ``rank_rtol``: directions of the calibration whose information (in targets,
    trajectory eliminated) is below ``rank_rtol`` × the largest single parameter's are not moved
    (a truncated solve, as observability-aware calibration does; see :meth:`_Normal.rank`). At a
    noisy estimate, exact null directions pick up spurious information of about 1e-10 of that
    scale from the estimated trajectory's noise (measured on a planar drive, against ~2e-8 for a
    vertical lever arm seen through suspension pitch), so the default sits at 1e-9. With a smaller
    value an unobservable direction is "estimated" from that noise and wanders (metres for a
    vertical lever arm on a planar drive). Away from the optimum that spurious information grows
    with the estimate's error, as the excess cost does: the threshold is multiplied by the
    normalised cost ``2·cost/dof`` where it exceeds 1 (a start 10× off in cost moved a vertical
    lever arm 680 targets in one step). ``scale_sigma``: the scale unit of a monocular camera's
    scale (it has no target).
    """

    max_iterations: int = 50
    # 0.05 standard deviations of the joint estimate: far below what a calibration's σ or its
    # NEES can see (a trial's NEES moves by ~0.05² on average), and above the floor a drive that
    # starts and ends at a standstill leaves (the steering's weight moves with the crawl off a
    # standstill: decrements of 0.01–0.03 at a cost converged to 1e-6; 24 trials of a 25 s car
    # drive: 8–34 iterations).
    decrement_tolerance: float = 5e-2
    lambda_initial: float = 1e-12
    lambda_min: float = 1e-15
    lambda_max: float = 1e10
    rank_rtol: float = 1e-9
    scale_sigma: float = 0.01

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise ValidateError(f"max_iterations must be ≥ 1, got {self.max_iterations}")
        for name in ("decrement_tolerance", "lambda_initial", "lambda_min", "lambda_max", "rank_rtol", "scale_sigma"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValidateError(f"{name} must be positive and finite, got {v!r}")


@dataclass(frozen=True)
class States:
    """Body orientation, world position and velocity at every keyframe."""

    R: np.ndarray
    p: np.ndarray
    v: np.ndarray

    def plus(self, d: np.ndarray) -> "States":
        """Moved by a world-frame step ``[δθ, δp, δv]`` per keyframe."""
        d = d.reshape(-1, 9)
        return States(self.R @ so3.exp(d[:, 0:3]), self.p + d[:, 3:6], self.v + d[:, 6:9])

    def plus_local(self, d: np.ndarray) -> "States":
        """Moved by a step in the evaluator's local states ``[δθ, δv_body, δd_body]`` per keyframe
        (:mod:`excite.information`): ``R ← R·Exp(δθ)``, body velocity ``Rᵀv += δv``, body increment
        ``R_kᵀ(p_{k+1} − p_k) += δd``; the first position stays (positions enter only as
        differences). To first order this is the world step the local Jacobian describes."""
        d = d.reshape(-1, 9)
        R = self.R @ so3.exp(d[:, 0:3])
        v = np.einsum("kij,kj->ki", R, np.einsum("kji,kj->ki", self.R, self.v) + d[:, 3:6])
        inc = np.einsum("kji,kj->ki", self.R[:-1], np.diff(self.p, axis=0)) + d[:-1, 6:9]
        p = self.p[0] + np.vstack([np.zeros((1, 3)), np.cumsum(np.einsum("kij,kj->ki", R[:-1], inc), axis=0)])
        return States(R, p, v)


@dataclass(frozen=True)
class CalibrationResult:
    """What :func:`calibrate` returns. ``status``: "converged", "max_iterations" or "failed"
    (``reason`` says why); ``cost`` = ½‖r‖² of the whitened residuals (its expectation at the
    optimum is about half the number of residuals minus unknowns)."""

    status: str
    reason: str
    iterations: int
    initial_cost: float
    cost: float
    n_residuals: int  # that carry information (a row whitened by zero measures nothing)
    n_unknowns: int
    calibration: Calibration
    states: States
    information: np.ndarray | None = None  # Λ over rig.coordinates at the estimate (trajectory eliminated)
    residual_rms: dict[str, float] | None = None  # whitened RMS per factor kind at the estimate (≈ 1)

    @property
    def converged(self) -> bool:
        return self.status == "converged"


def keyframe_rates(data: SensorData, b_g: np.ndarray) -> np.ndarray:
    """Bias-corrected body rate at every keyframe: the mean of the samples just before and after
    it (each sample is the mean rate over its interval, so this is centred on the keyframe)."""
    n = data.imu_per_keyframe
    g = data.imu.gyro - b_g
    after = np.vstack([g[::n], g[-1:]])
    before = np.vstack([g[:1], g[n - 1::n]])
    return 0.5 * (after + before)


# ------------------------------------------------------------------------------------------------
# The problem at a linearisation point


@dataclass(frozen=True)
class Linearisation:
    """The whitened Jacobians at an estimate. ``recorded``: the residual's exact derivative at the
    recorded measurements (the cost's gradient and Gauss–Newton matrix: the step).
    ``predicted``: the derivative at the noise-free measurement of the estimate (the evaluator's
    Fisher information: the directions the data determines, and the information reported)."""

    recorded: sp.csr_matrix
    predicted: sp.csr_matrix


class _Problem:
    """Residuals and Jacobian of the joint problem for fixed data, rig and gauge reference: every
    entry of the rig that recorded data, through its kind's one statement of the residual
    (:mod:`excite.factors.symbolic`), closed as the evaluator closes a drive."""

    def __init__(self, data: SensorData, rig: Rig, gauge_R: np.ndarray, gauge_p: np.ndarray | None = None):
        # the estimator takes the biases constant (the simulator may let them drift): the factors
        # are linearised for that model, 9-wide states
        self.data, self.rig = data, rig.with_constant_biases() if rig.bias_random_walk else rig
        self.closure = Closure.of(self.rig, origin=False)  # plain world states: LM needs no origin
        self.K = data.n_keyframes
        self.n_params = len(rig.coordinates)
        self.n_x = 9 * self.K
        self.gauge_R = gauge_R
        self.gauge_p = np.zeros(3) if gauge_p is None else gauge_p
        self.empty_rows: dict[str, int] = {}  # per kind: rows its whitening from data sets to zero
        self.whitenings: dict[str, np.ndarray | None] = {}  # per kind: its whitening from data, held
        # (kind, entry, what it recorded, its label): every entry that recorded data, and the
        # factors that open its chains at the drive's start (a GNSS antenna's first fix)
        self.instances = [(i.kind, i.entry, i.name, i.name) for i in registry.instances(self.rig)
                          if i.name in data.recorded]
        self.instances += [(i.kind, i.entry, i.entry.name, i.name) for i in registry.openings(self.rig)
                           if i.entry.name in data.recorded]
        # the IMU biases reach every factor through the bias-corrected samples the nominal motion
        # is built from (keyframe rates, sample attitudes, the preintegration at the estimate),
        # which a factor's inputs hold fixed: their columns of the step's Jacobian are forward
        # differences of the whole residual vector (steps of 1e-3 target: the residuals are linear
        # in a bias to far better than that over such a step)
        self.bias_columns = [(i, 1e-3 * c.target) for i, c in enumerate(rig.coordinates)
                             if c.block == "imu" and c.quantity in ("gyro_bias", "accel_bias")]

    @property
    def n_empty(self) -> int:
        """Residual rows whitened by zero at the last evaluation (they carry no information)."""
        return sum(self.empty_rows.values())

    def nominal(self, X: States, cal: Calibration) -> Nominal:
        """The motion the factors are evaluated on: the estimated states, the IMU samples
        corrected for the estimated biases, their attitudes integrated from the states, and the
        bias-corrected body rate at the keyframes (lever-arm velocity, time-offset prediction)."""
        d = self.data
        n = d.imu_per_keyframe
        b_g, b_a = cal.vector("imu", "gyro_bias"), cal.vector("imu", "accel_bias")
        Rs = preintegrate_all(d.imu.gyro, d.imu.accel, n, d.dt_imu, b_g, b_a)[3]
        imu_R = np.empty(((self.K - 1) * n + 1, 3, 3))
        imu_R[:-1] = (X.R[:-1, None] @ Rs).reshape(-1, 3, 3)
        imu_R[-1] = X.R[-1]
        return Nominal(t=d.t, R=X.R, p=X.p, v=X.v, omega=keyframe_rates(d, b_g), R_V_A=d.R_V_A, imu_R=imu_R,
                       imu_omega=d.imu.gyro - b_g, imu_f=d.imu.accel - b_a, imu_per_keyframe=n,
                       R_V_B=d.R_V_B, p_V_B=d.p_V_B, logs=d.logs, scene=d.scene, ground=d.ground)

    def evaluate(self, X: States, cal: Calibration, jacobian: bool):
        """Whitened residual vector at ``(X, cal)``, and with ``jacobian`` its :class:`Linearisation`
        (sparse whitened Jacobians in the closure's states)."""
        nom = self.nominal(X, cal)
        parts, kinds, recorded, predicted = [], [], [], []
        self.empty_rows = {}
        for kind, entry, record, label in self.instances:
            first = registry.factor_keyframes(kind, self.rig, entry, self.K, nom)
            meas, values = registry.prepare_recording(kind, self.rig, entry, self.data.recorded[record],
                                         cal.for_entry(kind, self.rig, entry))
            # the factors' whitening from data (a scene's information, a reported covariance; a
            # lidar pair's ray-cast scans by what their registration reports): at the first
            # estimate, then held (a weight that moved with the estimate would move the cost under
            # the solver's steps)
            if label not in self.whitenings:
                W = None
                if first.size:
                    W = _lidar_whitening(self.data, self.rig, entry, nom, first) if isinstance(kind, Odometry) else None
                    W = kind.whitening(nom, self.rig, entry, first) if W is None else W
                self.whitenings[label] = W
            W = self.whitenings[label]
            if W is not None:
                self.empty_rows[label] = int((~np.any(W != 0, axis=2)).sum())
            parts.append(symbolic.residuals(kind, nom, self.rig, entry, first, meas, values, whitening=W).ravel())
            if jacobian:
                # the residual's own derivative, and the evaluator's (at the estimate's values)
                for out, v, m in ((recorded, values, meas), (predicted, cal.for_entry(kind, self.rig, entry), None)):
                    b = symbolic.blocks(kind, nom, self.rig, entry, v, meas=m, whitening=W)
                    if b is not None:
                        out.append(b)
            kinds.append(label)
        # the gauge, as the evaluator's: priors on the first keyframe's position and world yaw as far
        # as they are symmetries (held at the reference), and the last keyframe's held components
        fix = self.closure.fix(X.R[0], 0)
        gauge = []
        if "position" in self.closure.gauge:
            gauge += list((X.p[0] - self.gauge_p) / GAUGE_SIGMA_POS_M)
        if "yaw" in self.closure.gauge:
            gauge.append((self.gauge_R @ so3.log(self.gauge_R.T @ X.R[0]))[2] / GAUGE_SIGMA_YAW_RAD)
        end = self.closure.end(self.K - 1)
        parts.append(np.r_[gauge, np.zeros(len(self.closure.held()))])
        kinds.append("gauge")
        edges = np.cumsum([0] + [x.size for x in parts])
        self.kinds = {k: slice(a, b) for k, a, b in zip(kinds, edges[:-1], edges[1:])}
        r = np.concatenate(parts)
        if not jacobian:
            return r, None
        maps = info_kernels.local_maps(X.R, X.v, X.p) if self.closure.local else None

        def assemble(blocks):
            if maps is not None:
                blocks = [to_local(b, *maps) for b in blocks]
            J, _ = dense.jacobian(Problem(self.K, self.n_params, tuple(blocks + fix + end), X.R, self.closure))
            if J.shape[0] != r.size:
                raise ValidateError(f"internal: {J.shape[0]} Jacobian rows for {r.size} residuals")
            return J

        return r, Linearisation(self._with_bias_differences(assemble(recorded), r, X, cal), assemble(predicted))

    def _with_bias_differences(self, J: sp.csr_matrix, r: np.ndarray, X: States, cal: Calibration) -> sp.csr_matrix:
        """``J`` with the IMU biases' columns replaced by forward differences from the residual
        ``r`` at ``(X, cal)`` (see ``__init__``)."""
        if not self.bias_columns:
            return J
        cols = np.array([self.n_x + i for i, _ in self.bias_columns])
        D = np.empty((J.shape[0], cols.size))
        for n, (i, h) in enumerate(self.bias_columns):
            d = np.zeros(self.n_params)
            d[i] = h
            D[:, n] = (self.evaluate(X, cal.plus(self.rig, d), False)[0] - r) / h
        keep = np.ones(J.shape[1])
        keep[cols] = 0.0
        rows = np.repeat(np.arange(J.shape[0]), cols.size)
        diff = sp.csr_matrix((D.ravel(), (rows, np.tile(cols, J.shape[0]))), shape=J.shape)
        return (J @ sp.diags(keep) + diff).tocsr()


# ------------------------------------------------------------------------------------------------
# The trust-region solver


class _Normal:
    """The scaled normal equations at one estimate.

    Unknowns are scaled first: states to unit column norm of J (unit diag H_xx), the calibration
    into units of its targets (as the evaluator scales). ``factor(λ)`` solves the Marquardt-damped
    system ``(H + λ·diag H) y = −g`` by eliminating the trajectory: Cholesky of the banded state
    block in LAPACK band storage (``dpbtrf``), then the calibration's small dense Schur
    complement. The step is restricted to a basis of calibration directions (:meth:`rank`).
    """

    def __init__(self, J: sp.csr_matrix, r: np.ndarray, n_x: int, theta_scale: np.ndarray):
        col = np.sqrt(np.asarray(J[:, :n_x].multiply(J[:, :n_x]).sum(axis=0)).ravel())
        col[col == 0] = 1.0
        self.n_x = n_x
        self.D = np.r_[col, 1.0 / theta_scale]
        self.Js = (J @ sp.diags(1.0 / self.D)).tocsc()
        Jx, Jt = self.Js[:, :n_x], self.Js[:, n_x:].toarray()
        Hxx = (Jx.T @ Jx).tocoo()
        self.Hxt = np.asarray(Jx.T @ Jt)
        self.Htt = Jt.T @ Jt
        self.g = np.asarray(self.Js.T @ r).ravel()
        low = Hxx.row >= Hxx.col
        rows, cols = Hxx.row[low], Hxx.col[low]
        self.band = np.zeros((int((rows - cols).max()) + 1, n_x))
        self.band[rows - cols, cols] = Hxx.data[low]
        self.diag = np.r_[self.band[0], np.diag(self.Htt)]
        self.diag_raw = self.diag * self.D**2  # diag of the unscaled H

    def factor(self, lam: float):
        """``(L, Z, zg, A)``: Cholesky of the damped H_xx, ``Z = L⁻¹H_xθ``, ``zg = L⁻¹g_x`` and the
        damped Schur complement ``A`` of the calibration."""
        ab = self.band.copy()
        ab[0] *= 1.0 + lam
        L, info = dpbtrf(ab, lower=1)
        if info != 0:
            raise FactorisationError(info - 1)
        Z, i1 = dtbtrs(L, self.Hxt, uplo="L")
        zg, i2 = dtbtrs(L, self.g[:self.n_x, None], uplo="L")
        if i1 or i2:
            raise FactorisationError(max(i1, i2) - 1)
        A = self.Htt - Z.T @ Z
        A = 0.5 * (A + A.T) + lam * np.diag(np.diag(self.Htt))
        return L, Z, zg[:, 0], A

    def rank(self, A0: np.ndarray, rank_rtol: float):
        """The calibration directions the data determines: eigenvectors of the undamped Schur
        complement ``A0`` (in target units) above ``rank_rtol · max diag(H_θθ)``. Not the evaluator's
        normalised test (:mod:`excite.score.spectrum`, each coordinate against its own information): at a
        noisy estimate an exactly unobservable coordinate (a vertical lever arm on a flat lot) has
        spurious information of its own from the estimate's noise, and normalised by that it
        survives marginalisation as if it were real (measured: no normalised eigenvalue below 1e-3
        where the evaluator finds two exact zeros). Returns the basis, the threshold and the
        condition over the kept directions."""
        w, V = np.linalg.eigh(A0)
        tol = rank_rtol * max(np.diag(self.Htt).max(), 1e-300)
        kept = w > tol
        cond = float(w[kept].max() / w[kept].min()) if kept.any() else float("inf")
        return V[:, kept], float(tol), cond

    def step(self, fac, basis: np.ndarray) -> np.ndarray:
        """The scaled step of the factored damped system, calibration within ``basis``."""
        L, Z, zg, A = fac
        b = self.g[self.n_x:] - Z.T @ zg
        yt = -basis @ np.linalg.solve(basis.T @ A @ basis, basis.T @ b) if basis.shape[1] else np.zeros(b.size)
        yx, info = dtbtrs(L, (zg + Z @ yt)[:, None], uplo="L", trans="T")
        if info:
            raise FactorisationError(info - 1)
        return np.r_[-yx[:, 0], yt]

    def hessian_times(self, y: np.ndarray) -> np.ndarray:
        return np.asarray(self.Js.T @ (self.Js @ y)).ravel()


def _unknown_names(rig: Rig, n_keyframes: int, local: bool) -> list[str]:
    return dense.state_names(n_keyframes, local=local) + [c.name for c in rig.coordinates]


def calibrate(data: SensorData, rig: Rig, initial: Calibration, initial_states: States,
              settings: SolverSettings = SolverSettings(),
              log: Callable[[dict], None] | None = None) -> CalibrationResult:
    """Estimate the trajectory and the calibration from ``data`` (see the module docstring).

    Levenberg–Marquardt as a trust-region method (Moré's scaling, Nielsen's damping update from
    the gain ratio of actual to predicted decrease), starting from ``initial`` and
    ``initial_states`` (:func:`initialise`); the gauge (position and yaw of the first
    keyframe) is held at the initial states' values. Coordinates the rig does not estimate stay at
    ``initial``'s values, and so do directions of the calibration the data leaves undetermined
    (:meth:`_Normal.rank`). ``log`` receives one record per trial step (see the README's solver
    log) and a last one with the stop reason.

    Why not ``scipy.optimize.least_squares``: its 'trf'/'lm' methods take additive vectors (the
    orientations live on SO(3)) and either solve the step densely (thousands of trajectory
    unknowns) or iteratively with LSMR, which neither exploits the banded trajectory nor gives a
    rank-aware step on the calibration.
    """
    if initial_states.R.shape[0] != data.n_keyframes:
        raise ValidateError(f"{initial_states.R.shape[0]} initial states for {data.n_keyframes} keyframes")
    prob = _Problem(data, rig, initial_states.R[0].copy(), initial_states.p[0].copy())
    scale = np.array([settings.scale_sigma if c.nuisance else c.target for c in rig.coordinates])
    names = _unknown_names(rig, data.n_keyframes, prob.closure.local)
    X, cal = initial_states, initial
    r, lin = prob.evaluate(X, cal, jacobian=True)
    cost0 = cost = 0.5 * float(r @ r)
    lam, nu = settings.lambda_initial, 2.0
    status, reason = "max_iterations", f"no convergence in {settings.max_iterations} iterations"
    it = trials = 0
    info = None
    solver = "banded Cholesky of the states (LAPACK dpbtrf, half-bandwidth {}) + dense Schur complement"
    while it < settings.max_iterations:
        it += 1
        try:
            nrm = _Normal(lin.recorded, r, prob.n_x, scale)
            fac0 = nrm.factor(0.0)
            fisher = _Normal(lin.predicted, r, prob.n_x, scale)
            info0 = fisher.factor(0.0)[3]
            # spurious information of an estimate's error grows with it, as its excess cost does
            excess = max(1.0, 2.0 * cost / max(r.size - prob.n_empty - lin.recorded.shape[1], 1))
            basis, tol, cond_t = fisher.rank(info0, settings.rank_rtol * excess)
            y0 = nrm.step(fac0, basis)  # the undamped Gauss–Newton step
        except FactorisationError as e:
            status, reason = "failed", f"the normal equations are singular at {names[e.column]}"
            _emit(log, dict(event="step", iteration=it, failure=reason, failed_variable=names[e.column]))
            break
        info = info0 / np.outer(scale, scale)
        decrement = float(np.sqrt(max(-float(nrm.g @ y0), 0.0)))
        d = np.abs(fac0[0][0])
        base = dict(event="step", iteration=it, variables=len(names), residuals=int(r.size),
                    linear_solver=solver.format(nrm.band.shape[0] - 1), rank=prob.n_x + basis.shape[1],
                    rank_threshold=tol, diag_H_min=float(nrm.diag_raw.min()),
                    diag_H_min_variable=names[int(np.argmin(nrm.diag_raw))], diag_H_max=float(nrm.diag_raw.max()),
                    condition_states_lower_bound=float((d.max() / d.min()) ** 2), condition_calibration=cond_t,
                    decrement=decrement)
        if decrement < settings.decrement_tolerance:
            status, reason = "converged", "Gauss–Newton decrement below tolerance"
            break
        accepted = False
        while True:
            trials += 1
            try:
                fac = nrm.factor(lam)
                y = nrm.step(fac, basis)
            except FactorisationError as e:
                status, reason = "failed", f"the damped system is singular at {names[e.column]}"
                _emit(log, dict(base, **{"lambda": lam}, failure=reason, failed_variable=names[e.column]))
                break
            Hy = nrm.hessian_times(y)
            lin_res = float(np.linalg.norm(Hy + lam * nrm.diag * y + nrm.g) / max(np.linalg.norm(nrm.g), 1e-300))
            predicted = -float(nrm.g @ y + 0.5 * y @ Hy)
            step = y / nrm.D
            X_new = X.plus_local(step[:prob.n_x]) if prob.closure.local else X.plus(step[:prob.n_x])
            cal_new = cal.plus(rig, step[prob.n_x:])
            r_new, _ = prob.evaluate(X_new, cal_new, jacobian=False)
            cost_new = 0.5 * float(r_new @ r_new)
            rho = (cost - cost_new) / predicted if predicted > 0 and np.isfinite(cost_new) else -np.inf
            accepted = rho > 1e-4
            _emit(log, dict(base, **{"lambda": lam}, linear_residual=lin_res, cost_before=cost,
                            cost_after=cost_new if np.isfinite(cost_new) else None, predicted_decrease=predicted,
                            gain_ratio=rho if np.isfinite(rho) else None, accepted=accepted,
                            step_max=float(np.abs(y).max())))
            if accepted:
                lam = max(lam * max(1 / 3, 1 - (2 * rho - 1) ** 3), settings.lambda_min)
                nu = 2.0
                break
            if predicted <= _ROUNDING * max(cost, 1.0):
                break  # the local model promises less than the cost's rounding
            lam *= nu
            nu *= 2
            if lam > settings.lambda_max:
                break
        if status != "max_iterations":
            break
        if not accepted:
            status, reason = "failed", f"no step reduces the cost (Gauss–Newton decrement {decrement:.3g})"
            break
        X, cal, cost = X_new, cal_new, cost_new
        r, lin = prob.evaluate(X, cal, jacobian=True)
    if status != "failed":
        try:
            info = _Normal(lin.predicted, r, prob.n_x, scale).factor(0.0)[3] / np.outer(scale, scale)
        except FactorisationError:
            pass
    _emit(log, dict(event="stop", status=status, reason=reason, iterations=it, step_trials=trials,
                    initial_cost=cost0, cost=cost))
    rms = {k: float(np.sqrt(np.sum(r[sl] ** 2) / max(sl.stop - sl.start - prob.empty_rows.get(k, 0), 1)))
           for k, sl in prob.kinds.items() if k != "gauge"}
    return CalibrationResult(status, reason, it, cost0, cost, int(r.size) - prob.n_empty, int(lin.recorded.shape[1]),
                             cal, X, info, rms)


_ROUNDING = 1e-13  # relative rounding of the cost, a sum of ~10⁴ squares


def _emit(log: Callable[[dict], None] | None, record: dict) -> None:
    """One solver log record (non-finite numbers as None, so that every line is valid JSON)."""
    if log is not None:
        log({k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in record.items()})


# ------------------------------------------------------------------------------------------------
# Initial values

# How far from the nominal (CAD) values the initialisation may move, as weak priors that keep its
# small linear solves well posed on drives that do not determine everything: the joint solve
# starts from what they give and no longer sees them.
_INIT_PRIOR_ROT_RAD = np.deg2rad(2.0)
_INIT_PRIOR_TIME_S = 0.05
_INIT_PRIOR_GYRO_BIAS = np.deg2rad(1.0)
_INIT_ATTITUDE_RAD = 1e-3  # attitude error of the gyro-integrated rotations, in the velocity solve


@dataclass(frozen=True)
class Initialisation:
    """What :func:`initialise` estimated before the joint solve: the calibration and trajectory
    it starts from, and the RMS whitened residual of the rotation alignment of each sensor."""

    calibration: Calibration
    states: States
    rotation_rms: dict[str, float]


class _GyroAttitude:
    """Orientation relative to the first IMU sample, integrated from the bias-corrected gyro
    (samples held over their interval), at any time; extrapolated at the end rates."""

    def __init__(self, data: SensorData, b_g: np.ndarray):
        self.t0, self.dt = float(data.imu.t[0]), data.dt_imu
        self.w = data.imu.gyro - b_g
        inc = so3.exp(self.w * self.dt)
        self.R = np.empty((inc.shape[0] + 1, 3, 3))
        self.R[0] = np.eye(3)
        for s in range(inc.shape[0]):
            self.R[s + 1] = self.R[s] @ inc[s]

    def _sample(self, t: np.ndarray) -> np.ndarray:
        return np.clip(np.floor((t - self.t0) / self.dt).astype(int), 0, self.w.shape[0] - 1)

    def at(self, t: np.ndarray) -> np.ndarray:
        s = self._sample(t)
        return self.R[s] @ so3.exp(self.w[s] * (t - self.t0 - s * self.dt)[:, None])

    def rate(self, t: np.ndarray) -> np.ndarray:
        return self.w[self._sample(t)]


def initialise(data: SensorData, rig: Rig, nominal: Calibration, R0: np.ndarray, p0: np.ndarray,
               iterations: int = 3) -> Initialisation:
    """A start for :func:`calibrate`, as real calibrators build one: rotation first, from the
    angular rates, then the trajectory; translations are left to the joint solve.

    1. **Rotation, gyro bias and time offsets** from the rotation increments alone (hand–eye on
       rotations, which need no translation): every sensor's relative rotation between its frames,
       turned into the body frame by its extrinsic rotation, must equal the gyro's integral over
       the same interval shifted by the sensor's time offset. Linearised about the current values
       (``Log ΔR_B(τ, b_g) ≈ c − ΔT·δb_g + δτ·(ω_end − ω_start)``, ``R_B_S Log ΔR_S`` with a right
       perturbation), one small least-squares solve per iteration, weak priors at the nominal values.
    2. **Trajectory**: orientations from the bias-corrected gyro from ``R0`` (the first keyframe's
       orientation, e.g. gravity-aligned at rest); positions and velocities, given those, are
       linear in the IMU's velocity and position increments, the metric sensors' relative
       translations (nominal lever arms), the wheels' travel and the non-holonomic constraint:
       one sparse linear least-squares solve, the first position held at ``p0``.

    Translations, accelerometer biases, wheel values and scales start at ``nominal``: the joint
    solve estimates them, and leaves the directions the drive does not determine where they are.
    """
    names = {c.name for c in rig.coordinates}
    sensors = _odometry_sensors(data, rig)
    R_BS = {s.name: nominal.rotation(s.name).copy() for s in sensors}
    tau = {s.name: nominal.scalar(s.name, "time_offset") for s in sensors}
    b_g = nominal.vector("imu", "gyro_bias").copy()
    est_b = "imu.gyro_bias_x" in names
    # unknown layout: per sensor [φ (3) if its rotation is estimated, δτ (1) if its offset is], then δb_g
    layout, n = {}, 0
    for s in sensors:
        rot = f"{s.name}.rot_x" in names
        td = f"{s.name}.time_offset" in names
        layout[s.name] = (n if rot else None, n + 3 * rot if td else None)
        n += 3 * rot + td
    nb = n
    n += 3 * est_b
    rms: dict[str, float] = {}
    for _ in range(iterations):
        gyro = _GyroAttitude(data, b_g)
        rows, rhs = [], []
        for s in sensors:
            frames, R_rel, _ = _relative_poses(data, rig, s)
            sig = pair_sigmas(s)[0]
            t = data.t[frames] + tau[s.name]
            Ra = gyro.at(t)
            c = so3.log(np.swapaxes(Ra[:-1], 1, 2) @ Ra[1:])
            a = so3.log(R_rel)
            Ra_ = np.einsum("ij,nj->ni", R_BS[s.name], a)
            e = c - Ra_  # residual at the current values
            F = e.shape[0]
            A = np.zeros((F, 3, n))
            i_rot, i_td = layout[s.name]
            if i_rot is not None:
                A[:, :, i_rot:i_rot + 3] = R_BS[s.name] @ so3.hat(a)
            if i_td is not None:
                A[:, :, i_td] = gyro.rate(t[1:]) - gyro.rate(t[:-1])
            if est_b:
                A[:, :, nb:nb + 3] = -np.diff(t)[:, None, None] * np.eye(3)
            weights = _start_weights(data, rig, s, frames, R0 @ gyro.at(data.t))
            if weights is None:
                W = np.broadcast_to(np.eye(3) / sig, (F, 3, 3))
            else:  # the pair's rotation information, its residual turned from S into B
                W = weights[0] @ R_BS[s.name].T
            A, e = W @ A, np.einsum("nij,nj->ni", W, e)
            rows.append(A.reshape(-1, n))
            rhs.append(-e.ravel())
            rms[s.name] = float(np.sqrt(np.mean(e ** 2)))
        prior = np.zeros(n)
        for s in sensors:
            i_rot, i_td = layout[s.name]
            if i_rot is not None:
                prior[i_rot:i_rot + 3] = _INIT_PRIOR_ROT_RAD
            if i_td is not None:
                prior[i_td] = _INIT_PRIOR_TIME_S
        prior[nb:] = _INIT_PRIOR_GYRO_BIAS
        # priors hold the total offset from nominal: residual (current − nominal) + δ
        cur = np.zeros(n)
        for s in sensors:
            i_rot, i_td = layout[s.name]
            if i_rot is not None:
                cur[i_rot:i_rot + 3] = so3.log(nominal.rotation(s.name).T @ R_BS[s.name])
            if i_td is not None:
                cur[i_td] = tau[s.name] - nominal.scalar(s.name, "time_offset")
        cur[nb:] = b_g - nominal.vector("imu", "gyro_bias")
        A = np.vstack(rows + [np.diag(1.0 / prior)])
        b = np.concatenate(rhs + [-cur / prior])
        delta = np.linalg.lstsq(A, b, rcond=None)[0]
        for s in sensors:
            i_rot, i_td = layout[s.name]
            if i_rot is not None:
                R_BS[s.name] = R_BS[s.name] @ so3.exp(delta[None, i_rot:i_rot + 3])[0]
            if i_td is not None:
                tau[s.name] += delta[i_td]
        if est_b:
            b_g = b_g + delta[nb:]
    cal = nominal.with_values("imu", gyro_bias=b_g)
    for s in sensors:
        cal = cal.with_values(s.name, rot=R_BS[s.name], time_offset=tau[s.name])
    gyro = _GyroAttitude(data, b_g)
    R = R0 @ gyro.R[::data.imu_per_keyframe][:data.n_keyframes]
    p, v = _positions_and_velocities(data, rig, cal, R, p0)
    return Initialisation(cal, States(R, p, v), rms)


def _positions_and_velocities(data: SensorData, rig: Rig, cal: Calibration, R: np.ndarray, p0: np.ndarray):
    """Keyframe positions and velocities given the orientations ``R`` (step 2 of :func:`initialise`):
    sparse weighted linear least squares."""
    cfg = rig.config
    K = data.n_keyframes
    nx = 6 * K  # [p_k (3), v_k (3)]
    dT = float(data.t[1] - data.t[0])
    blocks: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []  # (rows, cols, vals, rhs)
    row0 = 0

    def add(coef: list[tuple[np.ndarray, np.ndarray]], rhs: np.ndarray, sigma: float | np.ndarray,
            weight: np.ndarray | None = None):
        """Rows ``Σ M_k x_{idx_k} = rhs`` (M: (F, m, 3) blocks on unknown triples at column idx (F,)),
        whitened by ``1/sigma`` or by the matrices ``weight`` (F, m, m)."""
        nonlocal row0
        F, m = rhs.shape
        if weight is not None:
            coef = [(weight @ M, idx) for M, idx in coef]
            rhs, sigma = np.einsum("nij,nj->ni", weight, rhs), 1.0
        w = 1.0 / np.broadcast_to(np.asarray(sigma, dtype=float), (m,))
        rid = row0 + np.arange(F * m).reshape(F, m)
        for M, idx in coef:
            r_ = np.broadcast_to(rid[:, :, None], M.shape)
            c_ = np.broadcast_to(idx[:, None, None] + np.arange(3)[None, None, :], M.shape)
            blocks.append((r_.ravel(), c_.ravel(), (M * w[None, :, None]).ravel(), None))
        blocks.append((None, None, None, (rhs * w[None, :]).ravel()))
        row0 += F * m

    P = lambda k: 6 * k  # noqa: E731
    V = lambda k: 6 * k + 3  # noqa: E731
    i, j = np.arange(K - 1), np.arange(1, K)
    RiT = np.swapaxes(R[:-1], 1, 2)
    pre = preintegrate_all(data.imu.gyro, data.imu.accel, data.imu_per_keyframe, data.dt_imu,
                           cal.vector("imu", "gyro_bias"), cal.vector("imu", "accel_bias"))
    ic = cfg.imu
    g = np.linalg.norm(GRAVITY)
    s_v = ic.accelerometer_noise_density * np.sqrt(dT) + _INIT_ATTITUDE_RAD * g * dT
    s_p = s_v * dT / np.sqrt(3.0)
    add([(RiT, V(j)), (-RiT, V(i))], pre[1] + np.einsum("nji,j->ni", R[:-1], GRAVITY * dT), s_v)
    add([(RiT, P(j)), (-RiT, P(i)), (-RiT * dT, V(i))],
        pre[2] + np.einsum("nji,j->ni", R[:-1], 0.5 * GRAVITY * dT**2), s_p)
    # metric sensors: R_S,iᵀ (p_j + v_j τ + R_j p_BS − p_i − v_i τ − R_i p_BS) = t_meas
    omega = keyframe_rates(data, cal.vector("imu", "gyro_bias"))
    for s in _odometry_sensors(data, rig):
        if s.monocular:
            continue
        frames, _, t_rel = _relative_poses(data, rig, s)
        R_BS, p_BS = cal.rotation(s.name), cal.vector(s.name, "trans")
        td = cal.scalar(s.name, "time_offset")
        fi, fj = frames[:-1], frames[1:]
        Rb = R[frames] @ so3.exp(omega[frames] * td)
        RSiT = np.swapaxes(Rb[:-1] @ R_BS, 1, 2)
        lever = np.einsum("nij,j->ni", Rb, p_BS)
        rhs = t_rel - np.einsum("nij,nj->ni", RSiT, lever[1:] - lever[:-1])
        weights = _start_weights(data, rig, s, frames, R)
        add([(RSiT, P(fj)), (-RSiT, P(fi)), (RSiT * td, V(fj)), (-RSiT * td, V(fi))], rhs, pair_sigmas(s)[1],
            None if weights is None else weights[1])
    # non-holonomic: lateral and vertical velocity of the axle ≈ 0
    R_BV = data.R_V_B.T
    p_BV = -R_BV @ data.p_V_B
    RA = R @ (R_BV @ data.R_V_A)
    RAT = np.swapaxes(RA, 1, 2)
    lever_v = np.einsum("kij,kj->ki", R, np.cross(omega, p_BV))
    add([(RAT[:, 1:3], V(np.arange(K)))], data.recorded["nonholonomic"] - np.einsum("kij,kj->ki", RAT[:, 1:3], lever_v),
        np.array(sigma_mps(cfg.vehicle.nonholonomic, rig.keyframe_rate_hz)))
    # wheels: the axle's travel along the mean heading of each interval (chord ≈ arc: a start value)
    wc = cfg.wheels
    if wc is not None and "wheel" in data.recorded:
        rl, rr = cal.scalar("wheel", "radius_left"), cal.scalar("wheel", "radius_right")
        inc = data.recorded["wheel"]
        ds = 0.5 * (rl * inc[:, 0] + rr * inc[:, 1])
        dpsi = so3.log(RAT[:-1] @ RA[1:])[:, 2]
        m = np.stack([np.cos(dpsi / 2), np.sin(dpsi / 2), np.zeros_like(dpsi)], axis=1)
        M = np.einsum("ni,nji->nj", m, RA[:-1])[:, None, :]  # mᵀ R_A,iᵀ
        arm = np.einsum("kij,j->ki", R, p_BV)
        rhs = ds - np.einsum("nij,nj->ni", M, arm[1:] - arm[:-1])[:, 0]
        add([(M, P(j)), (-M, P(i))], rhs[:, None], 0.5 * np.hypot(rl, rr) * increment_sigma_rad(wc, rig.keyframe_rate_hz))
    add([(np.eye(3)[None], np.array([P(0)]))], np.asarray(p0, dtype=float)[None], 1e-3)
    rows = np.concatenate([b[0] for b in blocks if b[0] is not None])
    cols = np.concatenate([b[1] for b in blocks if b[0] is not None])
    vals = np.concatenate([b[2] for b in blocks if b[0] is not None])
    rhs = np.concatenate([b[3] for b in blocks if b[0] is None])
    A = sp.csr_matrix((vals, (rows, cols)), shape=(row0, nx))
    x = spla.spsolve((A.T @ A).tocsc(), A.T @ rhs)
    x = x.reshape(K, 6)
    return x[:, 0:3], x[:, 3:6]


def _lidar_whitening(data: SensorData, rig: Rig, s, nom, first: np.ndarray) -> np.ndarray | None:
    """``W_n`` of the frame pairs of lidar ``s`` starting at keyframes ``first`` whose scans the
    simulator ray-cast in a scene: the information each pair's registration reports
    (``data.registration``: in the sensor's own frame, nothing along what its scans do not see)
    with the drift, as the evaluator combines the scene's
    (:func:`~excite.factors.odometry.drift_whitening`), at the orientations of ``nom`` (anything with
    the keyframes' ``R``); None for any other entry. (The evaluator's own whitening of such a pair,
    whose null directions the extrinsic's error turns away from the true ones, would let the motion
    the scans do not see — metres — leak into what they do.)"""
    A = data.registration.get(getattr(s, "name", None))
    if A is None or getattr(s, "kind", None) != "lidar":
        return None
    if A.shape[0] != first.size:
        raise ValidateError(f"internal: {s.name}'s registrations are of {A.shape[0]} pairs, not {first.size}")
    stride = registry.stride(registry.kind_of_sensor(s.kind), rig, s)
    reported = reported_whitening(nom, s, first, stride) if getattr(nom, "logs", None) is not None else None
    return drift_whitening(s, residual_information(nom, s, first, stride, A), reported)


def _start_weights(data: SensorData, rig: Rig, s, frames: np.ndarray, R: np.ndarray):
    """Square roots of a ray-cast lidar pair's rotation and translation information (F × 3 × 3
    each, the blocks of :func:`_lidar_whitening` at the body orientations ``R`` of the keyframes,
    the other held known, as each step of :func:`initialise` holds it); None for other sensors."""
    from types import SimpleNamespace

    W = _lidar_whitening(data, rig, s, SimpleNamespace(R=R), frames[:-1])
    if W is None:
        return None
    Lam = np.swapaxes(W, 1, 2) @ W
    return sqrt_psd(Lam[:, :3, :3]), sqrt_psd(Lam[:, 3:, 3:])


def _odometry_sensors(data: SensorData, rig: Rig) -> list:
    """The rig's lidar and camera odometry sensors that recorded data."""
    return [s for s in rig.config.sensors
            if isinstance(registry.kind_of_sensor(s.kind), Odometry) and s.name in data.recorded]


def _relative_poses(data: SensorData, rig: Rig, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames (keyframe indices), relative rotations and translations an odometry sensor recorded."""
    kind = registry.kind_of_sensor(s.kind)
    first = registry.factor_keyframes(kind, rig, s, data.n_keyframes)
    rows = data.recorded[s.name]
    return np.r_[first, first[-1] + registry.stride(kind, rig, s)], rows[:, :9].reshape(-1, 3, 3), rows[:, 9:12]


def perturbed_states(states: States, rng: np.random.Generator, sigma_rot_rad: float = 0.01,
                     sigma_pos_m: float = 0.3, sigma_vel_mps: float = 0.1) -> States:
    """``states`` with independent white noise on every keyframe (a crude initial trajectory)."""
    K = states.R.shape[0]
    return States(states.R @ so3.exp(rng.normal(0, sigma_rot_rad, (K, 3))),
                  states.p + rng.normal(0, sigma_pos_m, (K, 3)), states.v + rng.normal(0, sigma_vel_mps, (K, 3)))
