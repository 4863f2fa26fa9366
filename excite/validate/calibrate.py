"""Nonlinear batch calibration: Levenberg–Marquardt over the joint sparse problem.

:func:`calibrate` estimates the body trajectory (orientation, position, velocity at every
keyframe) and the calibration from :class:`~excite.validate.simulate.SensorData`, with the factors
the evaluator scores:

- residuals from the factors' nonlinear models (:func:`excite.factors.imu.residual` on the
  measurements preintegrated with the current bias estimate, :func:`~excite.factors.odometry.residual`,
  :func:`~excite.factors.wheel.increments`, :func:`~excite.factors.nonholonomic.residual`),
  vectorised here and held equal to those functions by the tests;
- Jacobians from the factors' own ``blocks``, evaluated at the current estimate: a
  :class:`~excite.factors.base.Nominal` built from the estimated states and the bias-corrected IMU
  samples, and a rig carrying the estimated extrinsics and wheel values, assembled by
  :func:`excite.information.build` in the world parametrisation with the evaluator's gauge (a prior
  on the first keyframe's position and yaw, an exact symmetry) and exported by
  :func:`excite.information.jacobian`.

The body rate at a keyframe (lever-arm velocity, time-offset prediction) is the bias-corrected
gyro averaged over the two samples around it; the suspension tilt is a known input. Both are
taken as known by the information model too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cholesky_banded
from scipy.linalg.lapack import dtbtrs

from .. import information, so3
from ..factors import imu as imu_factor
from ..factors import wheel
from ..factors.base import Nominal
from ..rig import Rig
from ..trajectory import GRAVITY
from .simulate import Calibration, SensorData, ValidateError

_GAUGE_SIGMA_POS_M = 1.0  # as the evaluator's gauge prior (excite.information)
_GAUGE_SIGMA_YAW_RAD = 0.01


@dataclass(frozen=True)
class SolverSettings:
    """Levenberg–Marquardt settings.

    ``max_iterations``: accepted steps at most. The step is solved in scaled coordinates (states:
    columns of J at unit norm; calibration: in units of its targets), so ``step_tolerance`` is in
    units of each state's conditional σ and of each target: the solver stops once no unknown moves
    by more than that, or the cost decreases by less than ``cost_tolerance`` (relative).
    ``lambda_initial/min/max``: Marquardt damping (× diag H). ``rank_rtol``: directions of the
    calibration whose information (in targets, trajectory eliminated) is below ``rank_rtol`` × the
    largest single parameter's are not moved (a truncated solve, as observability-aware
    calibration does). The evaluator counts information below 1e-10 of that scale as zero at the
    *nominal* motion; at a noisy estimate, exact null directions pick up spurious information of
    about that size from the estimated trajectory's noise (measured ~1e-10 on a planar drive,
    against ~2e-8 for a vertical lever arm seen through suspension pitch), so the solver's default
    sits at 1e-9. With a smaller value an unobservable direction is "estimated" from that noise
    and wanders (metres for a vertical lever arm on a planar drive). ``scale_sigma``: the scale unit of a
    monocular camera's scale (it has no target).
    """

    max_iterations: int = 30
    step_tolerance: float = 1e-3
    cost_tolerance: float = 1e-10
    lambda_initial: float = 1e-12
    lambda_min: float = 1e-15
    lambda_max: float = 1e8
    rank_rtol: float = 1e-9
    scale_sigma: float = 0.01

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise ValidateError(f"max_iterations must be ≥ 1, got {self.max_iterations}")
        for name in ("step_tolerance", "cost_tolerance", "lambda_initial", "lambda_min", "lambda_max"):
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
        d = d.reshape(-1, 9)
        return States(self.R @ so3.exp(d[:, 0:3]), self.p + d[:, 3:6], self.v + d[:, 6:9])


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
    n_residuals: int
    n_unknowns: int
    calibration: Calibration
    states: States
    information: np.ndarray | None = None  # Λ over rig.coordinates at the estimate (trajectory eliminated)

    @property
    def converged(self) -> bool:
        return self.status == "converged"


# ------------------------------------------------------------------------------------------------
# The measurement models, vectorised


def preintegrate_all(gyro: np.ndarray, accel: np.ndarray, n: int, dt: float, b_g: np.ndarray,
                     b_a: np.ndarray):
    """:func:`excite.factors.imu.preintegrate` for every keyframe interval at once.

    Returns ``ΔR, Δv, Δp`` (N, …) and ``R_s`` (N, n, 3, 3): the rotation at the start of each sample
    relative to the interval's start.
    """
    N = gyro.shape[0] // n
    w = (gyro - b_g).reshape(N, n, 3)
    a = (accel - b_a).reshape(N, n, 3)
    dR = np.broadcast_to(np.eye(3), (N, 3, 3)).copy()
    dv = np.zeros((N, 3))
    dp = np.zeros((N, 3))
    Rs = np.empty((N, n, 3, 3))
    for s in range(n):
        Rs[:, s] = dR
        acc = np.einsum("nij,nj->ni", dR, a[:, s])
        dp = dp + dv * dt + 0.5 * acc * dt * dt
        dv = dv + acc * dt
        dR = dR @ so3.exp(w[:, s] * dt)
    return dR, dv, dp, Rs


def imu_residuals(X: States, pre, dT: float) -> np.ndarray:
    """Unwhitened (rotation, velocity, position) residuals of every interval (N, 9)."""
    dR, dv, dp = pre[:3]
    RiT = np.swapaxes(X.R[:-1], 1, 2)
    rR = so3.log(RiT @ X.R[1:] @ np.swapaxes(dR, 1, 2))
    rv = np.einsum("nij,nj->ni", RiT, X.v[1:] - X.v[:-1] - GRAVITY * dT) - dv
    rp = np.einsum("nij,nj->ni", RiT, X.p[1:] - X.p[:-1] - X.v[:-1] * dT - 0.5 * GRAVITY * dT**2) - dp
    return np.hstack([rR, rv, rp])


def odometry_residuals(X: States, omega: np.ndarray, frames: np.ndarray, R_BS: np.ndarray, p_BS: np.ndarray,
                       t_d: float, scale: float, R_meas: np.ndarray, t_meas: np.ndarray) -> np.ndarray:
    """:func:`excite.factors.odometry.residual` of every frame pair (F−1, 6)."""
    R, p, v, w = X.R[frames], X.p[frames], X.v[frames], omega[frames]
    Rb = R @ so3.exp(w * t_d)
    R_S = Rb @ R_BS
    p_S = p + v * t_d + Rb @ p_BS
    R_iT = np.swapaxes(R_S[:-1], 1, 2)
    R_rel = R_iT @ R_S[1:]
    t_rel = np.einsum("nij,nj->ni", R_iT, p_S[1:] - p_S[:-1])
    return np.hstack([so3.log(np.swapaxes(R_meas, 1, 2) @ R_rel), scale * t_rel - t_meas])


def wheel_increments(X: States, R_BA: np.ndarray, p_BV: np.ndarray, radius_left: float, radius_right: float,
                     track: float) -> np.ndarray:
    """:func:`excite.factors.wheel.increments` of every keyframe interval (N, 2)."""
    return wheel.increments(X.R[:-1], X.p[:-1], X.R[1:], X.p[1:], R_BA[:-1], R_BA[1:], p_BV,
                            radius_left, radius_right, track)


def nonholonomic_residuals(X: States, omega: np.ndarray, R_BA: np.ndarray, p_BV: np.ndarray) -> np.ndarray:
    """:func:`excite.factors.nonholonomic.residual` at every keyframe (K, 2)."""
    v_V = X.v + np.einsum("kij,kj->ki", X.R, np.cross(omega, p_BV))
    return np.einsum("kji,kj->ki", X.R @ R_BA, v_V)[:, 1:3]


def keyframe_rates(data: SensorData, b_g: np.ndarray) -> np.ndarray:
    """Bias-corrected body rate at every keyframe: the mean of the samples just before and after
    it (each sample is the mean rate over its interval, so this is centred on the keyframe)."""
    n = data.imu_per_keyframe
    g = data.gyro - b_g
    after = np.vstack([g[::n], g[-1:]])
    before = np.vstack([g[:1], g[n - 1::n]])
    return 0.5 * (after + before)


# ------------------------------------------------------------------------------------------------
# The problem at a linearisation point


class _Problem:
    """Residuals and Jacobian of the joint problem for fixed data, rig and gauge reference."""

    def __init__(self, data: SensorData, rig: Rig, gauge_R: np.ndarray, gauge_p: np.ndarray):
        rig = rig.with_constant_biases()  # one bias per drive, as the simulator draws it
        self.data, self.rig = data, rig
        self.coords = rig.coordinates
        self.K = data.n_keyframes
        self.n_params = len(self.coords)
        self.n_x = 9 * self.K
        self.gauge_R, self.gauge_p = gauge_R, gauge_p
        self.dT = float(data.t[1] - data.t[0])
        R_BV = data.R_V_B.T
        self.p_BV = -R_BV @ data.p_V_B
        self.R_BA = R_BV @ data.R_V_A
        self.inc = data.wheel_increments
        cfg = rig.config
        self.sensors = [s for s in cfg.sensors if s.name in data.odometry]
        self.bias_cols = None
        if cfg.imu.estimate_biases:
            self.bias_cols = np.array([rig.index(f"imu.{k}_bias_{a}") for k in ("gyro", "accel") for a in "xyz"])

    def evaluate(self, X: States, cal: Calibration, jacobian: bool):
        """Whitened residual vector (and the sparse whitened Jacobian) at ``(X, cal)``."""
        d, cfg = self.data, self.rig.config
        n = d.imu_per_keyframe
        pre = preintegrate_all(d.gyro, d.accel, n, d.dt_imu, cal.gyro_bias, cal.accel_bias)
        omega = keyframe_rates(d, cal.gyro_bias)
        N = self.K - 1
        imu_R = np.empty((N * n + 1, 3, 3))
        imu_R[:-1] = (X.R[:-1, None] @ pre[3]).reshape(-1, 3, 3)
        imu_R[-1] = X.R[-1]
        nom = Nominal(t=d.t, R=X.R, p=X.p, v=X.v, omega=omega, R_V_A=d.R_V_A, imu_R=imu_R,
                      imu_omega=d.gyro - cal.gyro_bias, imu_f=d.accel - cal.accel_bias, imu_per_keyframe=n,
                      R_V_B=d.R_V_B, p_V_B=d.p_V_B)
        ic = cfg.imu
        cov = imu_factor.preintegration(nom, ic.gyroscope_noise_density, ic.accelerometer_noise_density)["cov"]
        L = np.linalg.cholesky(cov)
        r_imu = np.linalg.solve(L, imu_residuals(X, pre, self.dT)[:, :, None])[..., 0]
        r_nh = (nonholonomic_residuals(X, omega, self.R_BA, self.p_BV) - d.slip) / np.array(
            self.rig.nonholonomic_sigma_mps)
        parts = [r_imu.ravel(), r_nh.ravel()]
        if cfg.wheels is not None:
            parts.append(((wheel_increments(X, self.R_BA, self.p_BV, *cal.wheel) - self.inc)
                          / self.rig.wheel_increment_sigma_rad).ravel())
        for s in self.sensors:
            od = d.odometry[s.name]
            R_BS, p_BS = cal.extrinsics[s.name]
            r = odometry_residuals(X, omega, od.frames, R_BS, p_BS, cal.time_offsets[s.name], cal.scales[s.name],
                                   od.R_rel, od.t_rel)
            r[:, 0:3] /= np.deg2rad(s.noise.rotation_sigma_deg)
            r[:, 3:6] /= s.noise.translation_sigma_m
            parts.append(r.ravel())
        yaw = (self.gauge_R @ so3.log(self.gauge_R.T @ X.R[0]))[2]  # world yaw of the first keyframe
        parts.append(np.r_[(X.p[0] - self.gauge_p) / _GAUGE_SIGMA_POS_M, yaw / _GAUGE_SIGMA_YAW_RAD])
        r = np.concatenate(parts)
        if not jacobian:
            return r, None
        prob = information.build(nom, cal.rig(self.rig), local=False)
        J, _ = information.jacobian(prob)
        if J.shape[0] != r.size:
            raise ValidateError(f"internal: {J.shape[0]} Jacobian rows for {r.size} residuals")
        return r, self._monocular_scale(J, prob, cal)

    def _monocular_scale(self, J: sp.csr_matrix, prob: information.Problem, cal: Calibration) -> sp.csr_matrix:
        """The factor linearises a monocular camera at unit scale; its translation rows scale with ŝ
        (all but the scale column, whose entry t_rel is already right)."""
        mono = [s for s in self.sensors if s.monocular and cal.scales[s.name] != 1.0]
        if not mono:
            return J
        rows = np.ones(J.shape[0])
        r0 = 0
        for b in prob.blocks:
            for s in mono:
                if b.name == s.name:
                    idx = r0 + np.arange(b.n_factors)[:, None] * b.n_rows + np.arange(3, 6)[None, :]
                    rows[idx.ravel()] = cal.scales[s.name]
            r0 += b.n_factors * b.n_rows
        J = (sp.diags(rows) @ J).tocsc()
        for s in mono:
            c = self.n_x + self.rig.index(f"{s.name}.scale")
            sl = slice(J.indptr[c], J.indptr[c + 1])
            J.data[sl] /= rows[J.indices[sl]]
        return J.tocsr()


# ------------------------------------------------------------------------------------------------


def _step(J: sp.csr_matrix, r: np.ndarray, n_x: int, theta_scale: np.ndarray, lam: float, rank_rtol: float):
    """The damped Gauss–Newton step, trajectory eliminated through the banded structure.

    Unknowns are scaled first: states to unit column norm of J, θ by ``theta_scale`` (the targets,
    as the evaluator scales). ``(H + λ·diag H) y = −Jᵀr`` is solved by banded Cholesky of the
    state block and an eigendecomposition of the θ Schur complement, whose eigenvalues below
    ``rank_rtol · max diag(H_θθ)`` count as zero: along directions the data does not determine,
    the step is zero, so the estimate stays where it started.
    Returns the step (unscaled), the scaled step, and the undamped scaled Schur complement.
    """
    col = np.sqrt(np.asarray(J[:, :n_x].multiply(J[:, :n_x]).sum(axis=0)).ravel())
    col[col == 0] = 1.0
    D = np.r_[col, 1.0 / theta_scale]
    Js = (J @ sp.diags(1.0 / D)).tocsc()
    Jx, Jt = Js[:, :n_x], Js[:, n_x:].toarray()
    Hxx = (Jx.T @ Jx).tocoo()
    Hxt = np.asarray(Jx.T @ Jt)
    Htt = Jt.T @ Jt
    gx, gt = Jx.T @ r, Jt.T @ r
    low = Hxx.row >= Hxx.col
    rows, cols, vals = Hxx.row[low], Hxx.col[low], Hxx.data[low]
    ab = np.zeros((int((rows - cols).max()) + 1, n_x))
    ab[rows - cols, cols] = vals
    ab[0] *= 1.0 + lam
    try:
        L = cholesky_banded(ab, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return None
    Z, info1 = dtbtrs(L, Hxt, uplo="L")
    zg, info2 = dtbtrs(L, gx[:, None], uplo="L")
    if info1 or info2:
        return None
    schur = Htt - Z.T @ Z
    A = schur + lam * np.diag(np.diag(Htt))
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    keep = w > rank_rtol * max(np.diag(Htt).max(), 1e-300)
    b = gt - Z.T @ zg[:, 0]
    yt = -V[:, keep] @ ((V[:, keep].T @ b) / w[keep])
    yx, info3 = dtbtrs(L, zg[:, 0] + Z @ yt, uplo="L", trans="T")
    if info3:
        return None
    y = np.r_[-yx, yt]
    return y / D, y, 0.5 * (schur + schur.T)


def calibrate(data: SensorData, rig: Rig, initial: Calibration, initial_states: States,
              settings: SolverSettings = SolverSettings()) -> CalibrationResult:
    """Estimate the trajectory and the calibration from ``data`` (see the module docstring).

    Starts from ``initial`` and ``initial_states``; the gauge (position and yaw of the first
    keyframe) is held at the initial states' values. Coordinates the rig does not estimate stay at
    ``initial``'s values, and so do directions of the calibration the data leaves undetermined
    (see :func:`_step`).
    """
    if initial_states.R.shape[0] != data.n_keyframes:
        raise ValidateError(f"{initial_states.R.shape[0]} initial states for {data.n_keyframes} keyframes")
    prob = _Problem(data, rig, initial_states.R[0].copy(), initial_states.p[0].copy())
    scale = np.array([settings.scale_sigma if c.nuisance else c.target for c in rig.coordinates])
    X, cal = initial_states, initial
    r, J = prob.evaluate(X, cal, jacobian=True)
    cost0 = cost = 0.5 * float(r @ r)
    lam = settings.lambda_initial
    status, reason = "max_iterations", f"no convergence in {settings.max_iterations} iterations"
    it = 0
    while it < settings.max_iterations:
        it += 1
        accepted = False
        while True:
            out = _step(J, r, prob.n_x, scale, lam, settings.rank_rtol)
            if out is not None:
                step, y, _ = out
                X_new = X.plus(step[:prob.n_x])
                cal_new = cal.plus(rig, step[prob.n_x:])
                r_new, _ = prob.evaluate(X_new, cal_new, jacobian=False)
                cost_new = 0.5 * float(r_new @ r_new)
                if np.isfinite(cost_new) and cost_new <= cost:
                    accepted = True
                    break
                if np.isfinite(cost_new) and cost_new - cost <= settings.cost_tolerance * max(cost, 1.0):
                    break  # the cost is flat to rounding here: nothing left to gain
            lam = max(lam * 10, 1e-9)
            if lam > settings.lambda_max:
                break
        if not accepted:
            if lam <= settings.lambda_max:
                status, reason = "converged", "cost flat to rounding"
            else:
                status, reason = "failed", "no step reduces the cost (damping at its maximum)"
            break
        decrease = cost - cost_new
        X, cal, cost = X_new, cal_new, cost_new
        lam = max(lam / 10, settings.lambda_min)
        r, J = prob.evaluate(X, cal, jacobian=True)
        small = np.abs(y).max() < settings.step_tolerance
        if small or decrease <= settings.cost_tolerance * max(cost, 1.0):
            status, reason = "converged", ("step below tolerance" if small else "cost decrease below tolerance")
            break
    out = _step(J, r, prob.n_x, scale, 0.0, settings.rank_rtol)
    info = None if out is None else out[2] / np.outer(scale, scale)
    return CalibrationResult(status, reason, it, cost0, cost, int(r.size), int(J.shape[1]), cal, X, info)


# ------------------------------------------------------------------------------------------------
# Initial values


def dead_reckoning(data: SensorData, R0: np.ndarray, p0: np.ndarray, v0: np.ndarray,
                   calibration: Calibration) -> States:
    """Keyframe states integrated from the IMU alone (biases from ``calibration``), starting at
    ``R0, p0, v0`` (e.g. gravity-aligned at rest). Drifts quadratically: a starting point only."""
    n = data.imu_per_keyframe
    dR, dv, dp, _ = preintegrate_all(data.gyro, data.accel, n, data.dt_imu, calibration.gyro_bias,
                                     calibration.accel_bias)
    dT = float(data.t[1] - data.t[0])
    K = data.n_keyframes
    R = np.empty((K, 3, 3))
    p = np.empty((K, 3))
    v = np.empty((K, 3))
    R[0], p[0], v[0] = R0, p0, v0
    for k in range(K - 1):
        R[k + 1] = R[k] @ dR[k]
        v[k + 1] = v[k] + GRAVITY * dT + R[k] @ dv[k]
        p[k + 1] = p[k] + v[k] * dT + 0.5 * GRAVITY * dT**2 + R[k] @ dp[k]
    return States(R, p, v)


def perturbed_states(states: States, rng: np.random.Generator, sigma_rot_rad: float = 0.01,
                     sigma_pos_m: float = 0.3, sigma_vel_mps: float = 0.1) -> States:
    """``states`` with independent white noise on every keyframe (a crude initial trajectory)."""
    K = states.R.shape[0]
    return States(states.R @ so3.exp(rng.normal(0, sigma_rot_rad, (K, 3))),
                  states.p + rng.normal(0, sigma_pos_m, (K, 3)), states.v + rng.normal(0, sigma_vel_mps, (K, 3)))
