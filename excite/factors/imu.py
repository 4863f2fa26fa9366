"""IMU preintegration between consecutive keyframes (Forster et al. 2017, errors in frame i).

Residuals of the interval ``i → j`` (ΔT long, n IMU samples of dt each, held constant over dt):

    r_R = Log(R_iᵀ R_j · ΔR(b)ᵀ)
    r_v = R_iᵀ (v_j − v_i − g ΔT) − Δv(b)
    r_p = R_iᵀ (p_j − p_i − v_i ΔT − ½ g ΔT²) − Δp(b)

with the preintegrated measurement ``(ΔR, Δv, Δp)`` of the gyro and accelerometer samples
corrected to first order for the biases b (GTSAM's form: ``ΔR(b) = ΔR Exp(−ΔRᵀ G_R b_g)``,
``Δv(b) = Δv + V_g b_g + V_a b_a``, ``Δp(b) = Δp + P_g b_g + P_a b_a``). The measurement
(:func:`preintegrate_all`) applies each sample's specific force in the attitude of the sample's
middle (a sample is the mean over its interval); the bias Jacobians and the covariance take the
attitude at its start, which differs from it by O(ω·dt). The covariance of the preintegrated
measurement is propagated from the Kalibr noise densities at the IMU rate (discrete white noise
σ²/dt per sample); the bias Jacobians are the exact sums of the same discrete scheme
(:func:`preintegration_symbolic`, once in CasADi; compiled for the evaluator, all intervals at
once from running sums over the samples, in :func:`preintegration`).

The biases are calibration parameters: constant over the drive, or random walks with the Kalibr
``*_random_walk`` densities (``bias_model``), whose deviations are keyframe states
(:mod:`excite.information.closure`).
"""

from __future__ import annotations

from typing import Literal

import numba as nb
import numpy as np
from pydantic import ConfigDict

from ..core import kernels, so3
from ..core.bounds import Range
from ..core.kernels import cross_scalars
from ..core.lazy import ca
from ..core.schema import Model, PositiveFloat
from ..motion.trajectory import GRAVITY, Trajectory
from .base import FactorBlock, Kind, Nominal, Quantity, RigView, theta_columns
from .symbolic import hat, residual_log


class ImuConfig(Model):
    """IMU noise in Kalibr's keys and units (continuous-time densities)."""

    model_config = ConfigDict(extra="ignore", frozen=True)  # a Kalibr imu.yaml has rostopic etc.

    accelerometer_noise_density: PositiveFloat  # m/s^2/√Hz
    accelerometer_random_walk: PositiveFloat  # m/s^3/√Hz
    gyroscope_noise_density: PositiveFloat  # rad/s/√Hz
    gyroscope_random_walk: PositiveFloat  # rad/s^2/√Hz
    update_rate: PositiveFloat  # Hz
    estimate_biases: bool = True
    # random_walk: the biases drift with the *_random_walk densities and the report scores the
    # bias at the end of the drive; constant: one bias over the whole drive (shared by drives)
    bias_model: Literal["random_walk", "constant"] = "random_walk"

    @property
    def bias_random_walk(self) -> bool:
        """The biases are estimated and drift as random walks (nuisance states per keyframe)."""
        return self.estimate_biases and self.bias_model == "random_walk"


class Imu(Kind):
    name = "imu"
    arity = 2
    rows = 9
    section = "imu"
    config = ImuConfig
    uses_imu_samples = True
    ranges = {"accelerometer_noise_density": Range(1e-7, 10.0, "m/s^2/√Hz"),
              "accelerometer_random_walk": Range(1e-13, 10.0, "m/s^3/√Hz"),  # tiny: a nearly constant bias
              "gyroscope_noise_density": Range(1e-8, 1.0, "rad/s/√Hz"),
              "gyroscope_random_walk": Range(1e-14, 1.0, "rad/s^2/√Hz"),  # (1e-6 of a MEMS IMU's: tests)
              "update_rate": Range(1.0, 10_000.0, "Hz")}
    advice = {
        ("gyro_bias", None): ("gyroscope bias: add rotation the exteroceptive sensors see too, or drive longer",
                              "needs rotation, or a longer drive"),
        ("accel_bias", 0): ("horizontal accelerometer bias: add heading changes (turns) to separate it "
                            "from roll and pitch", "needs heading changes: turn left and right"),
        ("accel_bias", 1): ("horizontal accelerometer bias: add heading changes (turns) to separate it "
                            "from roll and pitch", "needs heading changes: turn left and right"),
        ("accel_bias", 2): ("vertical accelerometer bias: vary acceleration and attitude",
                            "needs changing speed and attitude: braking, a ramp"),
    }

    def quantities(self, cfg, imu: ImuConfig) -> list[Quantity]:
        on, walk = imu.estimate_biases, imu.bias_random_walk
        return [Quantity("imu", "gyro_bias", 3, "rad/s", np.zeros(3), on,
                         drift=imu.gyroscope_random_walk if walk else 0.0),
                Quantity("imu", "accel_bias", 3, "m/s^2", np.zeros(3), on,
                         drift=imu.accelerometer_random_walk if walk else 0.0)]

    # --- the math ---

    @staticmethod
    def _relative(f):
        """What the states say of the interval: ``R_iᵀR_j`` and the velocity and position
        increments in frame i, gravity removed."""
        Ri, Rj = f.R
        g, dT = ca.DM(GRAVITY), f.dT
        dv = ca.mtimes(Ri.T, f.v[1] - f.v[0] - g * dT)
        dp = ca.mtimes(Ri.T, f.p[1] - f.p[0] - f.v[0] * dT - 0.5 * g * dT ** 2)
        return ca.mtimes(Ri.T, Rj), dv, dp

    def measurement(self, f):
        dR, dv, dp = self._relative(f)
        return ca.vertcat(ca.reshape(dR.T, 9, 1), dv, dp)

    def residual(self, f, meas):
        dR, dv, dp = self._relative(f)
        imu = f.entry
        pre = preintegration_symbolic(f.imu_R, f.imu_f, f.dt_imu, imu.gyroscope_noise_density,
                                      imu.accelerometer_noise_density)
        bg, ba = f.q["gyro_bias"], f.q["accel_bias"]
        dR_m = ca.reshape(meas[0:9], 3, 3).T
        dR_b = ca.mtimes(dR_m, ca.DM.eye(3) - hat(ca.mtimes(dR_m.T, ca.mtimes(pre["G_R"], bg))))
        return ca.vertcat(residual_log(ca.mtimes(dR, dR_b.T)),
                          dv - (meas[9:12] + ca.mtimes(pre["V_g"], bg) + ca.mtimes(pre["V_a"], ba)),
                          dp - (meas[12:15] + ca.mtimes(pre["P_g"], bg) + ca.mtimes(pre["P_a"], ba)))

    def sqrt_information(self, f):
        imu = f.entry
        pre = preintegration_symbolic(f.imu_R, f.imu_f, f.dt_imu, imu.gyroscope_noise_density,
                                      imu.accelerometer_noise_density)
        return ("cholesky", pre["cov"])

    def measured(self, rig: RigView, imu: ImuConfig, recorded: "ImuData", values: dict) -> tuple[np.ndarray, dict]:
        """The preintegrated measurement of every interval, preintegrated at the estimated biases
        (so that the residual's first-order bias correction is zero there)."""
        n = int(round(imu.update_rate / rig.keyframe_rate_hz))
        dR, dv, dp, _ = preintegrate_all(recorded.gyro, recorded.accel, n, 1.0 / imu.update_rate,
                                         values["gyro_bias"], values["accel_bias"])
        zero = {"gyro_bias": np.zeros(3), "accel_bias": np.zeros(3)}
        return np.hstack([dR.reshape(-1, 9), dv, dp]), {**values, **zero}

    # --- the compiled kernel ---

    def blocks(self, nom: Nominal, rig: RigView, imu: ImuConfig) -> FactorBlock:
        """Whitened Jacobians of every keyframe interval's preintegrated IMU factor."""
        pre = preintegration(nom, imu.gyroscope_noise_density, imu.accelerometer_noise_density)
        dT = nom.t[1] - nom.t[0]
        # whiten with the inverse Cholesky factor of the covariance: W = L⁻¹, WᵀW = Σ⁻¹
        W = kernels.inverse_cholesky(pre["cov"])
        Jx, Jt = _jacobians(nom.R, nom.p, nom.v, dT, GRAVITY, pre["dR"], pre["G_R"], pre["V_g"], pre["P_g"],
                            pre["P_a"], W, imu.estimate_biases)
        cols = (theta_columns(rig, [f"imu.{k}_bias_{a}" for k in ("gyro", "accel") for a in "xyz"])
                if imu.estimate_biases else np.zeros(0, dtype=int))
        return FactorBlock("imu", np.arange(Jx.shape[0]), 1, 2, Jx, Jt, cols)

    # --- simulation ---

    def simulate(self, sim, imu: ImuConfig) -> "ImuData":
        """IMU samples at its rate with white noise of discrete σ = density·√rate and the true
        biases, which random-walk per the random-walk densities (physical) or stay constant
        (model). Physical: the IMU integrates the true motion at ``imu_oversampling`` × its rate and
        outputs the mean rate and specific force over each sample (a boxcar, as delta-angle /
        delta-velocity IMUs do, without coning or sculling compensation), which :func:`preintegrate_all`
        applies in the attitude of the sample's middle. Model: sample ``s`` is the
        increment-equivalent rate over ``[τ_s, τ_s + dt)`` (:func:`_imu_increment_equivalent`),
        which :func:`preintegrate_all` turns exactly into the drive's keyframe states."""
        nom, rng, settings = sim.nom, sim.rng, sim.settings
        n, K = nom.imu_per_keyframe, nom.n_keyframes
        rate = imu.update_rate
        dt = 1.0 / rate
        t_imu = nom.t[0] + np.arange((K - 1) * n + 1) * dt
        if settings.imu_oversampling:
            omega, f = _imu_boxcar(sim.traj, t_imu, dt, settings.imu_oversampling, nom.R_V_B, nom.p_V_B)
        else:
            omega, f = _imu_increment_equivalent(sim.traj, nom, t_imu, dt, nom.R_V_B, nom.p_V_B)
        m = omega.shape[0]
        bg = np.broadcast_to(sim.truth.vector("imu", "gyro_bias"), (m, 3)).copy()
        ba = np.broadcast_to(sim.truth.vector("imu", "accel_bias"), (m, 3)).copy()
        if settings.bias_random_walk and sim.noisy:
            bg += np.cumsum(rng.normal(0.0, imu.gyroscope_random_walk * np.sqrt(dt), (m, 3)), axis=0)
            ba += np.cumsum(rng.normal(0.0, imu.accelerometer_random_walk * np.sqrt(dt), (m, 3)), axis=0)
        gyro = omega + bg
        accel = f + ba
        if sim.noisy:
            gyro += rng.normal(0.0, imu.gyroscope_noise_density * np.sqrt(rate), (m, 3))
            accel += rng.normal(0.0, imu.accelerometer_noise_density * np.sqrt(rate), (m, 3))
        return ImuData(t_imu, gyro, accel, bg, ba)


class ImuData:
    """Recorded IMU samples: sample s acts over ``[t[s], t[s] + dt)``; the true bias tracks."""

    def __init__(self, t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, gyro_bias: np.ndarray,
                 accel_bias: np.ndarray):
        self.t, self.gyro, self.accel, self.gyro_bias, self.accel_bias = t, gyro, accel, gyro_bias, accel_bias


# --- the preintegration, once in CasADi and compiled for the evaluator --------------------------


def preintegration_symbolic(imu_R: list, imu_f: list, dt: float, sigma_g: float, sigma_a: float) -> dict:
    """Bias Jacobians ``G_R, V_g, V_a, P_g, P_a`` and the 9×9 covariance (rotation, velocity,
    position) of one interval's preintegrated measurement, from the orientations ``imu_R`` at its
    n + 1 sample times and its n specific forces ``imu_f`` (SX).

    Sample s of an interval (n samples of dt) acts over ``[τ_s, τ_s + dt)`` with ``ΔR_s = R_iᵀR(τ_s)``
    and ``A_s = [ΔR_s f_s]× dt``. A rotation error w entering after sample s (gyro noise, or
    ``−ΔR_s dt δb_g``) reaches the end of the interval as ``[−I; SA_{s+1}; SP_{s+1}] w`` with
    ``SA_m = Σ_{q≥m} A_q`` and ``SP_m = Σ_{q≥m} w_q A_q``, ``w_q = (n − 1 − q + ½) dt``; an
    accelerometer error u as ``[0; −I; −w_s I] u``. Every Jacobian and the covariance are sums
    over s of these terms (:func:`preintegration` computes the same, compiled)."""
    n = len(imu_f)
    Ri = imu_R[0]
    I3 = ca.DM.eye(3)
    dRs = [ca.mtimes(Ri.T, imu_R[s]) for s in range(n)]
    A = [hat(ca.mtimes(dRs[s], imu_f[s])) * dt for s in range(n)]
    G = [ca.SX(3, 3)]
    for s in range(n - 1):
        G.append(G[-1] + dRs[s] * dt)
    G_R = G[n - 1] + dRs[n - 1] * dt
    AG = [ca.mtimes(A[s], G[s]) for s in range(n)]
    Vg = [ca.SX(3, 3)]
    for s in range(n - 1):
        Vg.append(Vg[-1] + AG[s])
    V_g = Vg[n - 1] + AG[n - 1]
    P_g = sum((Vg[s] * dt + 0.5 * dt * AG[s] for s in range(n)), ca.SX(3, 3))
    P_a = sum((-G[s] * dt - 0.5 * dt * dt * dRs[s] for s in range(n)), ca.SX(3, 3))
    wq = [(n - 1 - q + 0.5) * dt for q in range(n)]
    SA1, SP1 = [None] * n, [None] * n
    accA, accP = ca.SX(3, 3), ca.SX(3, 3)
    for s in range(n - 1, -1, -1):
        SA1[s], SP1[s] = accA, accP  # sums over q ≥ s+1
        accA = accA + A[s]
        accP = accP + wq[s] * A[s]
    g2, a2 = sigma_g ** 2 * dt, sigma_a ** 2 * dt
    cRR = g2 * n * I3
    cVR = -g2 * sum(SA1, ca.SX(3, 3))
    cPR = -g2 * sum(SP1, ca.SX(3, 3))
    cVV = g2 * sum((ca.mtimes(x, x.T) for x in SA1), ca.SX(3, 3)) + a2 * n * I3
    cPV = g2 * sum((ca.mtimes(x, y.T) for x, y in zip(SP1, SA1)), ca.SX(3, 3)) + a2 * sum(wq) * I3
    cPP = g2 * sum((ca.mtimes(x, x.T) for x in SP1), ca.SX(3, 3)) + a2 * sum(q * q for q in wq) * I3
    cov = ca.vertcat(ca.horzcat(cRR, cVR.T, cPR.T), ca.horzcat(cVR, cVV, cPV.T), ca.horzcat(cPR, cPV, cPP))
    return dict(G_R=G_R, V_g=V_g, V_a=-G_R, P_g=P_g, P_a=P_a, cov=cov)


def preintegration(nom: Nominal, sigma_g: float, sigma_a: float) -> dict[str, np.ndarray]:
    """Bias Jacobians and covariance of every interval's preintegrated measurement.

    Returns ``dR (N,3,3) = R_iᵀR_j``, ``G_R = ∂r_R/∂b_g``, ``V_g, V_a, P_g, P_a`` (∂Δv, ∂Δp
    w.r.t. gyro and accelerometer bias) and ``cov (N,9,9)`` ordered (rotation, velocity, position).

    The sums of :func:`preintegration_symbolic`, compiled, for all intervals at once from
    running sums over the samples."""
    n = nom.imu_per_keyframe
    N = nom.n_keyframes - 1
    dt = (nom.t[1] - nom.t[0]) / n
    dR, G_R, V_g, P_g, P_a, cov = _preintegration(nom.imu_R, nom.imu_f, n, N, dt, sigma_g, sigma_a)
    return dict(dR=dR, G_R=G_R, V_g=V_g, V_a=-G_R, P_g=P_g, P_a=P_a, cov=cov)


@nb.njit(cache=True, nogil=True)
def _preintegration(imu_R, imu_f, n, n_intervals, dt, sigma_g, sigma_a):
    """Per interval: ΔR = R_iᵀR_j, bias Jacobians G_R, V_g, P_g, P_a and the 9×9 covariance
    (rotation, velocity, position) of the preintegrated measurement; see
    :func:`excite.factors.imu.preintegration` for the formulas."""
    N = n_intervals
    dR = np.empty((N, 3, 3))
    G_R = np.zeros((N, 3, 3))
    V_g = np.zeros((N, 3, 3))
    P_g = np.zeros((N, 3, 3))
    P_a = np.zeros((N, 3, 3))
    cov = np.empty((N, 9, 9))  # zeroed per interval, in cache
    w = np.empty(n)
    for s in range(n):
        w[s] = (n - 1 - s + 0.5) * dt
    sw = w.sum()
    sw2 = (w * w).sum()
    g2 = sigma_g * sigma_g * dt
    a2 = sigma_a * sigma_a * dt
    dRs = np.empty((n, 3, 3))
    av = np.empty((n, 3))
    Mcc = np.empty((3, 3))
    Mce = np.empty((3, 3))
    Mee = np.empty((3, 3))
    for i in range(N):
        i0 = i * n
        for s in range(n):
            for r in range(3):
                for q in range(3):
                    dRs[s, r, q] = (imu_R[i0, 0, r] * imu_R[i0 + s, 0, q] + imu_R[i0, 1, r] * imu_R[i0 + s, 1, q]
                                    + imu_R[i0, 2, r] * imu_R[i0 + s, 2, q])
            for r in range(3):
                av[s, r] = (dRs[s, r, 0] * imu_f[i0 + s, 0] + dRs[s, r, 1] * imu_f[i0 + s, 1]
                            + dRs[s, r, 2] * imu_f[i0 + s, 2]) * dt
        for r in range(3):
            for q in range(3):
                dR[i, r, q] = (imu_R[i0, 0, r] * imu_R[i0 + n, 0, q] + imu_R[i0, 1, r] * imu_R[i0 + n, 1, q]
                               + imu_R[i0, 2, r] * imu_R[i0 + n, 2, q])
        cx = cy = cz = 0.0  # c = Σ_{q>s} a_q
        ex = ey = ez = 0.0  # e = Σ_{q>s} w_q a_q
        sqx = sqy = sqz = 0.0  # Σ_q q a_q
        swx = swy = swz = 0.0  # Σ_q q w_q a_q
        Mcc[:] = 0.0
        Mce[:] = 0.0
        Mee[:] = 0.0
        cov[i] = 0.0
        for s in range(n - 1, -1, -1):
            for q in range(3):
                d0, d1, d2 = dRs[s, 0, q], dRs[s, 1, q], dRs[s, 2, q]
                G_R[i, 0, q] += d0 * dt
                G_R[i, 1, q] += d1 * dt
                G_R[i, 2, q] += d2 * dt
                P_a[i, 0, q] -= d0 * w[s] * dt
                P_a[i, 1, q] -= d1 * w[s] * dt
                P_a[i, 2, q] -= d2 * w[s] * dt
                # [c]× and [e]× times column q of ΔR_s
                x0, x1, x2 = cross_scalars(cx, cy, cz, d0, d1, d2)
                V_g[i, 0, q] += x0 * dt
                V_g[i, 1, q] += x1 * dt
                V_g[i, 2, q] += x2 * dt
                y0, y1, y2 = cross_scalars(ex, ey, ez, d0, d1, d2)
                P_g[i, 0, q] += y0 * dt
                P_g[i, 1, q] += y1 * dt
                P_g[i, 2, q] += y2 * dt
            cv = (cx, cy, cz)
            ev = (ex, ey, ez)
            for r in range(3):
                for q in range(3):
                    Mcc[r, q] += cv[r] * cv[q]
                    Mce[r, q] += cv[r] * ev[q]
                    Mee[r, q] += ev[r] * ev[q]
            ax, ay, az = av[s, 0], av[s, 1], av[s, 2]
            sqx += s * ax
            sqy += s * ay
            sqz += s * az
            swx += s * w[s] * ax
            swy += s * w[s] * ay
            swz += s * w[s] * az
            cx += ax
            cy += ay
            cz += az
            ex += w[s] * ax
            ey += w[s] * ay
            ez += w[s] * az
        C = cov[i]
        tcc = Mcc[0, 0] + Mcc[1, 1] + Mcc[2, 2]
        tce = Mce[0, 0] + Mce[1, 1] + Mce[2, 2]
        tee = Mee[0, 0] + Mee[1, 1] + Mee[2, 2]
        # rotation–velocity and rotation–position: −g2 [Σ q a_q]×, −g2 [Σ q w_q a_q]×
        for (row, vx, vy, vz) in ((3, sqx, sqy, sqz), (6, swx, swy, swz)):
            C[row + 0, 1], C[row + 0, 2] = g2 * vz, -g2 * vy
            C[row + 1, 0], C[row + 1, 2] = -g2 * vz, g2 * vx
            C[row + 2, 0], C[row + 2, 1] = g2 * vy, -g2 * vx
        for r in range(3):
            C[r, r] = g2 * n
            for q in range(3):
                C[3 + r, 3 + q] = -g2 * Mcc[r, q]
                C[6 + r, 3 + q] = -g2 * Mce[r, q]
                C[6 + r, 6 + q] = -g2 * Mee[r, q]
            C[3 + r, 3 + r] += g2 * tcc + a2 * n
            C[6 + r, 3 + r] += g2 * tce + a2 * sw
            C[6 + r, 6 + r] += g2 * tee + a2 * sw2
        for r in range(9):
            for q in range(r + 1, 9):
                C[r, q] = C[q, r]
    return dR, G_R, V_g, P_g, P_a, cov




@nb.njit(cache=True, nogil=True)
def _jacobians(R, p, v, dT, g, dR, G_R, V_g, P_g, P_a, W, estimate):
    """Whitened Jacobians ``W J`` of the residuals (rotation, velocity, position rows) w.r.t. the
    states i, j ``[δθ, δp, δv]`` and the biases (b_g, b_a); with ``Δv' = R_iᵀ(v_j − v_i − g ΔT)``
    and ``Δp' = R_iᵀ(p_j − p_i − v_i ΔT − ½ g ΔT²)``::

        r_R:  ∂θ_i = −I        ∂θ_j = ΔR              ∂b_g = G_R
        r_v:  ∂θ_i = [Δv']×    ∂v_i = −R_iᵀ  ∂v_j = R_iᵀ   ∂b_g = −V_g   ∂b_a = −V_a = G_R
        r_p:  ∂θ_i = [Δp']×    ∂p_i = −R_iᵀ  ∂v_i = −R_iᵀ ΔT   ∂p_j = R_iᵀ   ∂b_g = −P_g   ∂b_a = −P_a
    """
    N = R.shape[0] - 1
    Jx = np.empty((N, 9, 18))  # every entry written below
    Jt = np.empty((N, 9, 6 if estimate else 0))
    A = np.zeros((9, 18))
    B = np.zeros((9, 6))
    X = np.empty((3, 3))
    a, dv, dp = np.empty(3), np.empty(3), np.empty(3)
    for n in range(N):
        i, j = n, n + 1
        Ri = R[i]
        for k in range(3):
            a[k] = v[j, k] - v[i, k] - g[k] * dT
        kernels.tmulv(Ri, a, dv)
        for k in range(3):
            a[k] = p[j, k] - p[i, k] - v[i, k] * dT - 0.5 * g[k] * dT * dT
        kernels.tmulv(Ri, a, dp)
        for r in range(3):
            A[r, r] = -1.0
            for c in range(3):
                A[r, 9 + c] = dR[n, r, c]
                A[3 + r, 6 + c] = -Ri[c, r]
                A[3 + r, 15 + c] = Ri[c, r]
                A[6 + r, 3 + c] = -Ri[c, r]
                A[6 + r, 6 + c] = -Ri[c, r] * dT
                A[6 + r, 12 + c] = Ri[c, r]
                B[r, c] = G_R[n, r, c]
                B[3 + r, c] = -V_g[n, r, c]
                B[6 + r, c] = -P_g[n, r, c]
                B[3 + r, 3 + c] = G_R[n, r, c]
                B[6 + r, 3 + c] = -P_a[n, r, c]
        kernels.hat(dv, X)
        kernels.put(A, 3, 0, X, 1.0)
        kernels.hat(dp, X)
        kernels.put(A, 6, 0, X, 1.0)
        Wn = W[n]
        for r in range(9):  # W is lower triangular; the inner loops run along rows of A and B
            Jr, Tr = Jx[n, r], Jt[n, r]
            w0 = Wn[r, 0]
            for c in range(18):
                Jr[c] = w0 * A[0, c]
            if estimate:
                for c in range(6):
                    Tr[c] = w0 * B[0, c]
            for k in range(1, r + 1):
                wk = Wn[r, k]
                for c in range(18):
                    Jr[c] += wk * A[k, c]
                if estimate:
                    for c in range(6):
                        Tr[c] += wk * B[k, c]
    return Jx, Jt


# --- the measurement, as an IMU records it --------------------------------------------------------


def preintegrate_all(gyro: np.ndarray, accel: np.ndarray, n: int, dt: float, b_g: np.ndarray,
                     b_a: np.ndarray):
    """The preintegrated measurement of every keyframe interval of IMU samples ``gyro, accel`` (``n``
    per interval, held over ``dt``), less the biases ``b_g, b_a``.

    A sample is the mean over its interval (what an IMU outputs): its specific force is applied in
    the attitude of the interval's middle, ``ΔR_s Exp(ω_s dt/2)`` (in the attitude at its start,
    the error ½·ω·dt of attitude on the specific force shows up as an accelerometer bias).

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
        h = so3.exp(0.5 * w[:, s] * dt)  # Exp(ω dt) = Exp(ω dt/2)²
        half = dR @ h  # the mid-sample attitude
        acc = np.einsum("nij,nj->ni", half, a[:, s])
        dp = dp + dv * dt + 0.5 * acc * dt * dt
        dv = dv + acc * dt
        dR = half @ h
    return dR, dv, dp, Rs


# --- simulated samples ---------------------------------------------------------------------------


def _imu_boxcar(traj: Trajectory, t_imu: np.ndarray, dt: float, m: int, R_V_B: np.ndarray, p_V_B: np.ndarray):
    """Mean true body rate and specific force over each IMU sample interval, from ``m`` internal
    samples at the interval's sub-step midpoints."""
    sub = (np.arange(m) + 0.5) * dt / m
    t = (t_imu[:-1, None] + sub[None, :]).ravel()
    _, w, f = traj.imu(t, R_V_B, p_V_B)
    return w.reshape(-1, m, 3).mean(axis=1), f.reshape(-1, m, 3).mean(axis=1)


def _imu_increment_equivalent(traj: Trajectory, nom: Nominal, t_imu: np.ndarray, dt: float, R_V_B: np.ndarray,
                              p_V_B: np.ndarray):
    """Increment-equivalent IMU samples (see the module docstring): the rates over each sample
    interval that the model's held-sample preintegration turns into the drive's keyframe states."""
    n, K = nom.imu_per_keyframe, nom.n_keyframes
    b = traj.sample(t_imu).body(R_V_B, p_V_B)
    R_s, v_s = b.R_W_B, b.v_W
    omega = so3.log(np.swapaxes(R_s[:-1], 1, 2) @ R_s[1:]) / dt
    a_s = (v_s[1:] - v_s[:-1]) / dt  # world acceleration held over each sample
    # Held samples reproduce the keyframe positions only to the trapezoid error dt²·Δa/12, which
    # on a jerky drive reaches several σ of the preintegrated position. A zero-mean ramp across
    # each interval's samples removes it without changing the velocity increment, so the samples
    # are exactly those of a motion through the drive's keyframe states (it departs from the
    # drive between keyframes by less than that error).
    w = (n - 1 - np.arange(n) + 0.5) * dt
    a_int = a_s.reshape(K - 1, n, 3)
    e_p = (nom.p[1:] - nom.p[:-1] - nom.v[:-1] * (n * dt)) - np.einsum("s,nsi->ni", w, a_int) * dt
    wc_ = w - w.mean()
    a_int = a_int + (e_p / (dt * (wc_**2).sum()))[:, None, :] * wc_[None, :, None]
    R_mid = R_s[:-1] @ so3.exp(0.5 * omega * dt)  # the preintegration applies f mid-sample
    f = np.einsum("nji,nj->ni", R_mid, a_int.reshape(-1, 3) - GRAVITY)
    return omega, f


