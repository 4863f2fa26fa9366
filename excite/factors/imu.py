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
σ²/dt per sample); the bias Jacobians are the exact sums of the same discrete scheme. Both are
stated once, as a fold over the interval's samples from the last to the first
(:meth:`Imu.summary_step`, :meth:`Imu.summary_finish`): the kind's math reads the interval's
summary (``f.imu``), and the evaluator's kernel for the fold is generated from the same statement.

The biases are calibration parameters: constant over the drive, or random walks with the Kalibr
``*_random_walk`` densities (``bias_model``), whose deviations are keyframe states
(:mod:`excite.information.closure`).
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import ConfigDict

from ..core import so3
from ..core.bounds import Range
from ..core.lazy import ca
from ..core.schema import Model, PositiveFloat
from ..motion.trajectory import GRAVITY, Trajectory
from .base import ConfigView, Expr, FactorInputs, Kind, Nominal, Quantity, RigView, SimulationView, Whitening
from .symbolic import hat, mat, residual_log

STATE = 76  # numbers of the preintegration's fold (:meth:`Imu.summary_step`)


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


class Imu(Kind[ImuConfig]):
    name = "imu"
    arity = 2
    rows = 9
    section = "imu"
    config = ImuConfig
    summary_fields = (("G_R", (3, 3)), ("V_g", (3, 3)), ("P_g", (3, 3)), ("P_a", (3, 3)), ("cov", (9, 9)))
    summary_state = STATE
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

    def quantities(self, cfg: ConfigView, imu: ImuConfig) -> list[Quantity]:
        on, walk = imu.estimate_biases, imu.bias_random_walk
        return [Quantity("imu", "gyro_bias", 3, "rad/s", np.zeros(3), on,
                         drift=imu.gyroscope_random_walk if walk else 0.0, per_entry=False),
                Quantity("imu", "accel_bias", 3, "m/s^2", np.zeros(3), on,
                         drift=imu.accelerometer_random_walk if walk else 0.0, per_entry=False)]

    # --- the math ---

    @staticmethod
    def _relative(f: FactorInputs) -> tuple[Expr, Expr, Expr]:
        """What the states say of the interval: ``R_iᵀR_j`` and the velocity and position
        increments in frame i, gravity removed."""
        Ri, Rj = f.R
        g, dT = ca.DM(GRAVITY), f.dT
        dv = ca.mtimes(Ri.T, f.v[1] - f.v[0] - g * dT)
        dp = ca.mtimes(Ri.T, f.p[1] - f.p[0] - f.v[0] * dT - 0.5 * g * dT ** 2)
        return ca.mtimes(Ri.T, Rj), dv, dp

    def measurement(self, f: FactorInputs) -> Expr:
        dR, dv, dp = self._relative(f)
        return ca.vertcat(ca.reshape(dR.T, 9, 1), dv, dp)

    def constants(self, rig: RigView, imu: ImuConfig) -> dict[str, float]:
        return {"sigma_g": imu.gyroscope_noise_density, "sigma_a": imu.accelerometer_noise_density}

    def residual(self, f: FactorInputs, meas: Expr) -> Expr:
        pre = f.imu
        bg, ba = f.q["gyro_bias"], f.q["accel_bias"]
        dR_m = ca.reshape(meas[0:9], 3, 3).T
        dR_b = ca.mtimes(dR_m, ca.DM.eye(3) - hat(ca.mtimes(dR_m.T, ca.mtimes(pre["G_R"], bg))))
        dR, dv, dp = self._relative(f)
        return ca.vertcat(residual_log(ca.mtimes(dR, dR_b.T)),
                          dv - (meas[9:12] + ca.mtimes(pre["V_g"], bg) - ca.mtimes(pre["G_R"], ba)),
                          dp - (meas[12:15] + ca.mtimes(pre["P_g"], bg) + ca.mtimes(pre["P_a"], ba)))

    def sqrt_information(self, f: FactorInputs) -> Whitening:
        return ("cholesky", f.imu["cov"])

    # --- the preintegration: a fold over the interval's samples, from the last to the first ---

    def summary_step(self, state: Expr, R_i: Expr, R_s: Expr, f_s: Expr, c: dict[str, Expr]) -> Expr:
        """Sample s (from n − 1 down to 0) of an interval of n, held over ``[τ_s, τ_s + dt)``, with
        ``ΔR_s = R_iᵀR(τ_s)`` and ``a_s = ΔR_s f_s dt``. A rotation error w entering after sample
        s (gyro noise, or ``−ΔR_s dt δb_g``) reaches the end of the interval as
        ``[−I; [c_s]×; [e_s]×] w`` with ``c_s = Σ_{q>s} a_q`` and ``e_s = Σ_{q>s} w_q a_q``,
        ``w_q = (n − 1 − q + ½) dt``; an accelerometer error u as ``[0; −I; −w_s I] u``. The state
        accumulates, over the samples after s, ``G_R = Σ ΔR_q dt``, ``P_a = −Σ w_q ΔR_q dt``,
        ``V_g = Σ [c_q]× ΔR_q dt``, ``P_g = Σ [e_q]× ΔR_q dt``, the sums c and e, the second
        moments ``Σ c cᵀ, Σ c eᵀ, Σ e eᵀ`` and ``Σ q a_q, Σ q w_q a_q`` that the covariance is made
        of (:meth:`summary_finish`), and the count k of samples taken (``w_s = (k + ½) dt``)."""
        G_R, P_a, V_g, P_g = (mat(state, 9 * i) for i in range(4))
        cv, ev = state[36:39], state[39:42]
        Mcc, Mce, Mee = mat(state, 42), mat(state, 51), mat(state, 60)
        sq, sw, k = state[69:72], state[72:75], state[75]
        dt = c["dt_imu"]
        w = (k + 0.5) * dt
        s = c["n_imu"] - 1.0 - k
        dRs = ca.mtimes(R_i.T, R_s)
        G_R = G_R + dRs * dt
        P_a = P_a - dRs * (w * dt)
        V_g = V_g + ca.mtimes(hat(cv), dRs) * dt
        P_g = P_g + ca.mtimes(hat(ev), dRs) * dt
        Mcc = Mcc + ca.mtimes(cv, cv.T)
        Mce = Mce + ca.mtimes(cv, ev.T)
        Mee = Mee + ca.mtimes(ev, ev.T)
        a = ca.mtimes(dRs, f_s) * dt
        return ca.vertcat(*(ca.vec(M.T) for M in (G_R, P_a, V_g, P_g)), cv + a, ev + w * a,
                          *(ca.vec(M.T) for M in (Mcc, Mce, Mee)), sq + s * a, sw + (s * w) * a, k + 1.0)

    def summary_finish(self, state: Expr, R_i: Expr, R_j: Expr, c: dict[str, Expr]) -> dict[str, Expr]:
        """The bias Jacobians and the 9×9 covariance (rotation, velocity, position) of the
        interval's preintegrated measurement: with ``g² = σ_g² dt``, ``a² = σ_a² dt``,
        ``[x]×[x]×ᵀ = |x|² I − x xᵀ``, the rotation block ``g² n I``; velocity–rotation
        ``−g² [Σ q a_q]×``, position–rotation ``−g² [Σ q w_q a_q]×``; velocity
        ``g² (tr M_cc I − M_cc) + a² n I``, position–velocity ``g² (tr M_ce I − M_ce) + a² Σ w_q I``,
        position ``g² (tr M_ee I − M_ee) + a² Σ w_q² I``."""
        G_R, P_a, V_g, P_g = (mat(state, 9 * i) for i in range(4))
        Mcc, Mce, Mee = mat(state, 42), mat(state, 51), mat(state, 60)
        sq, sw = state[69:72], state[72:75]
        n, dt = c["n_imu"], c["dt_imu"]
        g2, a2 = c["sigma_g"] ** 2 * dt, c["sigma_a"] ** 2 * dt
        sum_w = 0.5 * n * n * dt  # Σ_{k<n} (k + ½) dt
        sum_w2 = n * (4.0 * n * n - 1.0) / 12.0 * dt * dt  # Σ_{k<n} ((k + ½) dt)²
        I3 = ca.DM.eye(3)

        def squared(M):
            return ca.trace(M) * I3 - M

        cRR = g2 * n * I3
        cVR = -g2 * hat(sq)
        cPR = -g2 * hat(sw)
        cVV = g2 * squared(Mcc) + a2 * n * I3
        cPV = g2 * squared(Mce) + a2 * sum_w * I3
        cPP = g2 * squared(Mee) + a2 * sum_w2 * I3
        cov = ca.vertcat(ca.horzcat(cRR, cVR.T, cPR.T), ca.horzcat(cVR, cVV, cPV.T), ca.horzcat(cPR, cPV, cPP))
        return {"G_R": G_R, "V_g": V_g, "P_g": P_g, "P_a": P_a, "cov": cov}

    def prepare_recording(self, rig: RigView, imu: ImuConfig, recorded: "ImuData",
                          values: dict[str, Any]) -> tuple[np.ndarray, dict[str, Any]]:
        """The preintegrated measurement of every interval, preintegrated at the estimated biases
        (so that the residual's first-order bias correction is zero there)."""
        n = int(round(imu.update_rate / rig.keyframe_rate_hz))
        dR, dv, dp, _ = preintegrate_all(recorded.gyro, recorded.accel, n, 1.0 / imu.update_rate,
                                         values["gyro_bias"], values["accel_bias"])
        zero = {"gyro_bias": np.zeros(3), "accel_bias": np.zeros(3)}
        return np.hstack([dR.reshape(-1, 9), dv, dp]), {**values, **zero}

    # --- simulation ---

    def simulate(self, sim: SimulationView, imu: ImuConfig) -> "ImuData":
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


