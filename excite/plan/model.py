"""The evaluator's information model in CasADi: nominal motion → marginal information Λ_θ.

The same factors as :mod:`excite.factors` (IMU preintegration with bias Jacobians and propagated
covariance, exteroceptive relative poses with extrinsic / time-offset / monocular-scale columns,
wheel increments with the tyres' slip column, the non-holonomic constraint with the slip-angle
column), the same local trajectory parametrisation and
gauge as :func:`excite.information.build`, written as CasADi SX so that IPOPT gets exact
derivatives of everything downstream. The trajectory is eliminated by sequential block
elimination of the block-tridiagonal H_xx (one 9×9 Cholesky per keyframe, a
:meth:`casadi.Function.mapaccum` over the keyframes: cost linear in the drive length, no dense
H_xx), then the nuisance coordinates (a monocular camera's scale, the tyre slip: what slip costs
the calibration is in the objective, so plans that brake and turn hard pay for it).

The optimizer runs it on a coarse copy of the rig (:func:`coarse_rig`: fewer keyframes, a few IMU
samples per keyframe interval, per-measurement noise scaled so that the information per second
stays about the same); on that rig it reproduces the numpy evaluator to rounding (tests).
Every sensor must run at the keyframe rate (stride 1), which :func:`coarse_rig` ensures.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..information import _GAUGE_SIGMA_YAW_RAD
from ..rig.config import Rig
from ..factors.wheel import G_MPS2
from ..motion.trajectory import GRAVITY
from ..errors import OptimizeError

D = 9  # local state: [δθ, δv_body, δd]


def coarse_rig(rig: Rig, keyframe_rate_hz: float = 2.0, imu_substeps: int = 4) -> Rig:
    """A copy of ``rig`` at ``keyframe_rate_hz`` with every sensor at that rate and
    ``imu_substeps`` IMU samples per keyframe interval.

    Relative-pose σ grow with √(old rate / new rate): chaining the fine measurements over one
    coarse interval has about that noise. The IMU, wheel and slip noise are densities: they are
    kept (each factor converts its density to the coarse interval). The IMU biases are constant
    in the optimizer's model: on maneuvers of a few minutes the random walk moves the score by
    little (README, "What the numbers assume"), and the result is re-scored with the rig's own model.
    """
    c = rig.config.model_dump()
    sensors = []
    for s in c["sensors"]:
        f = float(np.sqrt(s["rate_hz"] / keyframe_rate_hz))
        sensors.append(dict(s, rate_hz=keyframe_rate_hz, noise={
            "rotation_sigma_deg": s["noise"]["rotation_sigma_deg"] * f,
            "translation_sigma_m": s["noise"]["translation_sigma_m"] * f}))
    changes = dict(keyframe_rate_hz=keyframe_rate_hz, sensors=sensors,
                   imu=dict(c["imu"], update_rate=keyframe_rate_hz * imu_substeps, bias_model="constant"))
    return rig.with_config(**changes)


# --- small SX helpers -----------------------------------------------------------------------

def _hat(v):
    return ca.vertcat(ca.horzcat(0, -v[2], v[1]), ca.horzcat(v[2], 0, -v[0]), ca.horzcat(-v[1], v[0], 0))


def _log(R):
    """Rotation vector of R (angle < π), smooth through the identity."""
    w = 0.5 * ca.vertcat(R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1])
    s2 = ca.dot(w, w)
    c = 0.5 * (ca.trace(R) - 1)
    small = s2 < 1e-12
    s_safe = ca.sqrt(ca.if_else(small, 1.0, s2))
    k = ca.if_else(small, 1.0 + s2 / 6.0, ca.atan2(s_safe, c) / s_safe)
    return k * w


def _right_jacobian_inv(phi):
    """``J_r⁻¹(φ)``, as :func:`excite.core.kernels.right_jacobian_inv` (series near zero)."""
    t2 = ca.dot(phi, phi)
    small = t2 < 1e-8
    t = ca.sqrt(ca.if_else(small, 1.0, t2))
    exact = 1.0 / (t * t) - (1.0 + ca.cos(t)) / (2.0 * t * ca.sin(t))
    coef = ca.if_else(small, 1.0 / 12.0 + t2 / 720.0, exact)
    K = _hat(phi)
    return ca.DM.eye(3) + 0.5 * K + coef * ca.mtimes(K, K)


def _chol(A, n: int):
    """Lower Cholesky factor of a symmetric positive definite n×n SX matrix."""
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


def _fsolve(L, B, n: int):
    """L⁻¹ B for a lower-triangular factor from :func:`_chol` (rows of B, as a list)."""
    rows = []
    for i in range(n):
        r = B[i, :]
        for k in range(i):
            r = r - L[i][k] * rows[k]
        rows.append(r / L[i][i])
    return ca.vertcat(*rows)


# --- the model --------------------------------------------------------------------------------

@dataclass(frozen=True)
class InformationModel:
    """CasADi functions of the information model of a (coarse) rig for ``n_keyframes``.

    ``marginal(R, p, v, w, f, R_V_A)`` → Λ over all coordinates (p × p); the inputs are the body
    samples as returned by :func:`excite.plan.kinematics.body_samples` (matrices
    column-major, one column per IMU sample; ``R_V_A`` per sample too, keyframes are taken).
    ``scaled(...)`` → S Λ S over the scored coordinates, nuisance marginalised.
    """

    rig: Rig
    n_keyframes: int
    substeps: int
    marginal: ca.Function
    scaled: ca.Function

    @property
    def n_params(self) -> int:
        return len(self.rig.coordinates)


def build_model(rig: Rig, n_keyframes: int) -> InformationModel:
    """The information model of ``rig`` (every sensor at the keyframe rate) on a drive of
    ``n_keyframes`` keyframes."""
    n = int(round(rig.config.imu.update_rate / rig.keyframe_rate_hz))
    for s in rig.config.sensors:
        if abs(s.rate_hz - rig.keyframe_rate_hz) > 1e-9:
            raise OptimizeError(f"sensor {s.name} runs at {s.rate_hz:g} Hz: the optimizer's model needs "
                                f"every sensor at the keyframe rate {rig.keyframe_rate_hz:g} Hz "
                                "(use coarse_rig)")
    if n_keyframes < 3:
        raise OptimizeError(f"the drive is too short: {n_keyframes} keyframes")
    K = n_keyframes
    P = len(rig.coordinates)
    dT = 1.0 / rig.keyframe_rate_hz
    interval = _interval_function(rig, n, dT)
    nhc = _nhc_function(rig)
    step = _elimination_step(P)

    N = (K - 1) * n + 1
    R = ca.MX.sym("R", 9, N)
    p = ca.MX.sym("p", 3, N)
    v = ca.MX.sym("v", 3, N)
    w = ca.MX.sym("w", 3, N)
    f = ca.MX.sym("f", 3, N)
    RVA = ca.MX.sym("R_V_A", 9, N)
    kf = list(range(0, N, n))
    # per interval: the n+1 orientations and the n specific forces of its samples
    R_int = ca.horzcat(*[ca.vec(R[:, k:k + n + 1]) for k in kf[:-1]])
    f_int = ca.horzcat(*[ca.vec(f[:, k:k + n]) for k in kf[:-1]])
    sl_i, sl_j = slice(0, N - 1, n), slice(n, N, n)
    Dii, Djj, Bji, Ei, Ej, Htt = interval.map(K - 1)(
        R_int, f_int, p[:, sl_i], p[:, sl_j], v[:, sl_i], v[:, sl_j], w[:, sl_i], w[:, sl_j],
        RVA[:, sl_i], RVA[:, sl_j])
    Dn, En, Hn = nhc.map(K)(R[:, ::n], v[:, ::n], w[:, ::n], RVA[:, ::n])
    zero81 = ca.MX(81, 1)
    zeroE = ca.MX(D * P, 1)
    Dk = Dn + ca.horzcat(Dii, zero81) + ca.horzcat(zero81, Djj)
    Ek = En + ca.horzcat(Ei, zeroE) + ca.horzcat(zeroE, Ej)
    # gauge: yaw of keyframe 0; the last keyframe's increment is a placeholder held at zero
    g = np.zeros((D, D))
    g[6:9, 6:9] = np.eye(3)
    r0 = R[:, 0]
    e = ca.vertcat(r0[2], r0[5], r0[8]) / _GAUGE_SIGMA_YAW_RAD  # third row of R_W_B
    G0 = ca.MX(D, D)
    G0[0:3, 0:3] = ca.mtimes(e, e.T)
    Dk = ca.horzcat(Dk[:, 0] + ca.vec(G0), Dk[:, 1:K - 1], Dk[:, K - 1] + ca.vec(ca.DM(g)))
    # sequential elimination of keyframes 0 .. K−2, then the last one
    carry0 = ca.vertcat(Dk[:, 0], Ek[:, 0], ca.MX(P * P, 1))
    acc = step.mapaccum("eliminate", K - 1)
    carries = acc(carry0, ca.vertcat(Bji, Dk[:, 1:], Ek[:, 1:]))
    last = carries[:, K - 2]
    S = ca.reshape(last[0:81], D, D)
    F = ca.reshape(last[81:81 + D * P], D, P)
    Lacc = ca.reshape(last[81 + D * P:], P, P)
    Htt_sum = ca.reshape(ca.sum2(Htt) + ca.sum2(Hn), P, P)
    Lam = Htt_sum - Lacc - ca.mtimes(F.T, ca.solve(S, F))
    Lam = 0.5 * (Lam + Lam.T)
    marginal = ca.Function("marginal", [R, p, v, w, f, RVA], [Lam],
                           ["R", "p", "v", "w", "f", "R_V_A"], ["Lambda"])

    scored = np.array([not c.nuisance for c in rig.coordinates])
    iS = np.flatnonzero(scored)
    iN = np.flatnonzero(~scored)
    A = Lam[iS.tolist(), iS.tolist()]
    if iN.size:  # as excite.score.evaluate._marginalise_nuisance: an undetermined nuisance removes nothing
        Bm = Lam[iS.tolist(), iN.tolist()]
        C = Lam[iN.tolist(), iN.tolist()]
        d = ca.sqrt(ca.fmax(ca.diag(C), 1e-300))
        Bd = Bm / ca.repmat(d.T, iS.size, 1)
        Cn = C / ca.mtimes(d, d.T) + 1e-12 * ca.DM.eye(iN.size)
        A = A - ca.mtimes(Bd, ca.solve(Cn, Bd.T))
    Svec = np.array([c.target for c in rig.scored])
    M = A * ca.DM(np.outer(Svec, Svec))
    M = 0.5 * (M + M.T)
    scaled = ca.Function("scaled", [R, p, v, w, f, RVA], [M], ["R", "p", "v", "w", "f", "R_V_A"], ["M"])
    return InformationModel(rig, K, n, marginal, scaled)


def _elimination_step(P: int) -> ca.Function:
    """One step of block-tridiagonal elimination: eliminate keyframe k given its Schur-updated
    diagonal block S_k and coupling F_k to θ, return those of keyframe k+1 and the θ update.

    carry = [vec S_k (81), vec F_k (9P), vec Λacc (P²)]; input = [vec B_k (81) = H[x_{k+1}, x_k],
    vec D_{k+1} (81), vec E_{k+1} (9P)].
    """
    carry = ca.SX.sym("c", 81 + D * P + P * P)
    inp = ca.SX.sym("i", 81 + 81 + D * P)
    S = ca.reshape(carry[0:81], D, D)
    F = ca.reshape(carry[81:81 + D * P], D, P)
    Lacc = ca.reshape(carry[81 + D * P:], P, P)
    B = ca.reshape(inp[0:81], D, D)
    Dn = ca.reshape(inp[81:162], D, D)
    En = ca.reshape(inp[162:], D, P)
    L = _chol(S, D)
    Y = _fsolve(L, ca.horzcat(B.T, F), D)
    Yb, Yf = Y[:, 0:D], Y[:, D:]
    Lacc = Lacc + ca.mtimes(Yf.T, Yf)
    S1 = Dn - ca.mtimes(Yb.T, Yb)
    F1 = En - ca.mtimes(Yb.T, Yf)
    return ca.Function("step", [carry, inp], [ca.vertcat(ca.vec(S1), ca.vec(F1), ca.vec(Lacc))])


def _geometry(rig: Rig):
    pose = rig.config.vehicle.T_V_B
    R_BV = pose.R.T
    p_BV = -R_BV @ pose.p
    return R_BV, p_BV


def _nhc_function(rig: Rig) -> ca.Function:
    """H_xx, H_xθ and H_θθ contributions (vec, local state) of the non-holonomic constraint at a
    keyframe (θ: the slip angle's column, excite.factors.nonholonomic)."""
    R_BV, p_BV = _geometry(rig)
    P = len(rig.coordinates)
    Rv = ca.SX.sym("R", 9)
    v = ca.SX.sym("v", 3)
    w = ca.SX.sym("w", 3)
    RVAv = ca.SX.sym("RVA", 9)
    R = ca.reshape(Rv, 3, 3)
    R_BA = ca.mtimes(ca.DM(R_BV), ca.reshape(RVAv, 3, 3))
    R_AB = R_BA.T
    vb = ca.mtimes(R.T, v)
    Jr = ca.mtimes(R_AB, _hat(vb))
    Jv = ca.mtimes(R_AB, R.T)
    # local: δv_world = R δv_b − R [v_b]× δθ
    Jl = ca.horzcat(Jr - ca.mtimes(ca.mtimes(Jv, R), _hat(vb)), ca.mtimes(Jv, R), ca.SX(3, 3))
    sig = ca.DM(list(rig.nonholonomic_sigma_mps))
    Jl = Jl[1:3, :] / sig
    Jt = ca.SX(2, P)
    if rig.config.vehicle.slip.estimate:  # excite.factors.nonholonomic.lateral_slip_regressor
        u = ca.dot(ca.mtimes(R, R_BA)[:, 0], v + ca.mtimes(R, ca.cross(w, ca.DM(p_BV))))
        Jt[0, rig.index("vehicle.slip_angle")] = u * u * ca.dot(R_BA[:, 2], w) / G_MPS2 / sig[0]
    return ca.Function("nhc", [Rv, v, w, RVAv], [ca.vec(ca.mtimes(Jl.T, Jl)), ca.vec(ca.mtimes(Jl.T, Jt)),
                                                 ca.vec(ca.mtimes(Jt.T, Jt))])


def _interval_function(rig: Rig, n: int, dT: float) -> ca.Function:
    """Information contributions of every factor of one keyframe interval i → j = i+1.

    Outputs (vec, local states): H[x_i,x_i], H[x_j,x_j], H[x_j,x_i], H[x_i,θ], H[x_j,θ], H[θ,θ].
    """
    P = len(rig.coordinates)
    Rs = ca.SX.sym("R", 9 * (n + 1))
    fs = ca.SX.sym("f", 3 * n)
    pi, pj = ca.SX.sym("pi", 3), ca.SX.sym("pj", 3)
    vi, vj = ca.SX.sym("vi", 3), ca.SX.sym("vj", 3)
    wi, wj = ca.SX.sym("wi", 3), ca.SX.sym("wj", 3)
    RVAi, RVAj = ca.SX.sym("RVAi", 9), ca.SX.sym("RVAj", 9)
    Rl = [ca.reshape(Rs[9 * s:9 * (s + 1)], 3, 3) for s in range(n + 1)]
    f = [fs[3 * s:3 * (s + 1)] for s in range(n)]
    Ri, Rj = Rl[0], Rl[n]
    world = []  # (Jx 18 columns [rot_i pos_i vel_i rot_j pos_j vel_j], Jt), whitened

    # IMU preintegration (same discrete scheme as excite.factors.imu.preintegration)
    imu = rig.config.imu
    sg, sa = imu.gyroscope_noise_density, imu.accelerometer_noise_density
    dt = dT / n
    I3 = ca.DM.eye(3)
    dRs = [ca.mtimes(Ri.T, Rl[s]) for s in range(n)]
    A = [_hat(ca.mtimes(dRs[s], f[s])) * dt for s in range(n)]
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
    V_a = -G_R
    P_a = sum((-G[s] * dt - 0.5 * dt * dt * dRs[s] for s in range(n)), ca.SX(3, 3))
    wq = [(n - 1 - q + 0.5) * dt for q in range(n)]
    SA1 = [None] * n
    SP1 = [None] * n
    accA, accP = ca.SX(3, 3), ca.SX(3, 3)
    for s in range(n - 1, -1, -1):
        SA1[s], SP1[s] = accA, accP  # sums over q ≥ s+1
        accA = accA + A[s]
        accP = accP + wq[s] * A[s]
    g2, a2 = sg**2 * dt, sa**2 * dt
    cRR = g2 * n * I3
    cVR = -g2 * sum(SA1, ca.SX(3, 3))
    cPR = -g2 * sum(SP1, ca.SX(3, 3))
    cVV = g2 * sum((ca.mtimes(x, x.T) for x in SA1), ca.SX(3, 3)) + a2 * n * I3
    cPV = g2 * sum((ca.mtimes(x, y.T) for x, y in zip(SP1, SA1)), ca.SX(3, 3)) + a2 * sum(wq) * I3
    cPP = g2 * sum((ca.mtimes(x, x.T) for x in SP1), ca.SX(3, 3)) + a2 * sum(q * q for q in wq) * I3
    cov = ca.vertcat(ca.horzcat(cRR, cVR.T, cPR.T), ca.horzcat(cVR, cVV, cPV.T), ca.horzcat(cPR, cPV, cPP))
    grav = ca.DM(GRAVITY)
    dv = ca.mtimes(Ri.T, vj - vi - grav * dT)
    dp = ca.mtimes(Ri.T, pj - pi - vi * dT - 0.5 * grav * dT**2)
    Z = ca.SX(3, 3)
    RiT = Ri.T
    Jx = ca.vertcat(
        ca.horzcat(-I3, Z, Z, ca.mtimes(Ri.T, Rj), Z, Z),
        ca.horzcat(_hat(dv), Z, -RiT, Z, Z, RiT),
        ca.horzcat(_hat(dp), -RiT, -RiT * dT, Z, RiT, Z))
    Jt = ca.SX(9, P)
    if imu.estimate_biases:
        gcol = rig.index("imu.gyro_bias_x")
        acol = rig.index("imu.accel_bias_x")
        Jt[0:3, gcol:gcol + 3] = G_R
        Jt[3:6, gcol:gcol + 3] = -V_g
        Jt[6:9, gcol:gcol + 3] = -P_g
        Jt[3:6, acol:acol + 3] = -V_a
        Jt[6:9, acol:acol + 3] = -P_a
    Lc = _chol(cov, 9)
    world.append((_fsolve(Lc, Jx, 9), _fsolve(Lc, Jt, 9)))

    # wheel increments (excite.factors.wheel)
    R_BV, p_BV = _geometry(rig)
    R_BA_i = ca.mtimes(ca.DM(R_BV), ca.reshape(RVAi, 3, 3))
    R_BA_j = ca.mtimes(ca.DM(R_BV), ca.reshape(RVAj, 3, 3))
    wc = rig.config.wheels
    if wc is not None:
        pBV = ca.DM(p_BV)
        RAi, RAj = ca.mtimes(Ri, R_BA_i), ca.mtimes(Rj, R_BA_j)
        phi = _log(ca.mtimes(RAi.T, RAj))
        dpsi = phi[2]
        pVi = pi + ca.mtimes(Ri, pBV)
        pVj = pj + ca.mtimes(Rj, pBV)
        c = ca.mtimes(RAi.T, pVj - pVi)
        m = ca.vertcat(ca.cos(dpsi / 2), ca.sin(dpsi / 2), 0)
        dm = 0.5 * ca.vertcat(-ca.sin(dpsi / 2), ca.cos(dpsi / 2), 0)
        small = ca.fabs(dpsi) < 2e-3
        h = ca.if_else(small, 1.0, 0.5 * dpsi)
        arc = ca.if_else(small, 1.0 + dpsi**2 / 24.0 + 7.0 * dpsi**4 / 5760.0, h / ca.sin(h))
        darc = ca.if_else(small, dpsi / 12.0 + 7.0 * dpsi**3 / 1440.0,
                          0.5 * (ca.sin(h) - h * ca.cos(h)) / ca.sin(h)**2)
        chord = ca.dot(m, c)
        ds = arc * chord
        Jl_inv = _right_jacobian_inv(-phi)
        Jr_inv = _right_jacobian_inv(phi)
        Jphi = ca.horzcat(-ca.mtimes(Jl_inv, R_BA_i.T), Z, Z, ca.mtimes(Jr_inv, R_BA_j.T), Z, Z)
        q = ca.mtimes(Ri.T, pj + ca.mtimes(Rj, pBV) - pi)
        Jc = ca.horzcat(ca.mtimes(R_BA_i.T, _hat(q)), -RAi.T, Z,
                        -ca.mtimes(ca.mtimes(RAi.T, Rj), _hat(pBV)), RAi.T, Z)
        Jpsi = Jphi[2, :]
        Js = arc * (ca.mtimes(m.T, Jc) + ca.dot(dm, c) * Jpsi) + darc * chord * Jpsi
        rl, rr, b = wc.radius_left_m, wc.radius_right_m, wc.track_m
        Jx = ca.vertcat((Js - 0.5 * b * Jpsi) / rl, (Js + 0.5 * b * Jpsi) / rr) / rig.wheel_increment_sigma_rad
        Jt = ca.SX(2, P)
        if wc.estimate:
            il, ir, it = (rig.index(f"wheel.{k}") for k in ("radius_left", "radius_right", "track"))
            Jt[0, il] = -(ds - 0.5 * b * dpsi) / rl**2
            Jt[1, ir] = -(ds + 0.5 * b * dpsi) / rr**2
            Jt[0, it] = -0.5 * dpsi / rl
            Jt[1, it] = 0.5 * dpsi / rr
        if rig.config.vehicle.slip.estimate:
            # excite.factors.wheel.longitudinal_accel_g: the axle's, along the interval's mean heading
            dvV = vj + ca.mtimes(Rj, ca.cross(wj, pBV)) - vi - ca.mtimes(Ri, ca.cross(wi, pBV))
            along = ca.dot(m, ca.mtimes(RAi.T, dvV)) / (dT * G_MPS2)
            isl = rig.index("wheel.slip")
            Jt[0, isl] = (ds - 0.5 * b * dpsi) / rl * along
            Jt[1, isl] = (ds + 0.5 * b * dpsi) / rr * along
        world.append((Jx, Jt / rig.wheel_increment_sigma_rad))

    # exteroceptive relative poses (excite.factors.odometry), stride 1
    for sensor in rig.config.sensors:
        R_BS, p_BS = ca.DM(sensor.T_B_S.R), ca.DM(sensor.T_B_S.p)
        R_SB = R_BS.T
        Rij = ca.mtimes(Ri.T, Rj)
        e = ca.mtimes(Ri.T, pj - pi) + ca.mtimes(Rij, p_BS)
        d = e - p_BS
        t_rel = ca.mtimes(R_SB, d)
        R_rel = ca.mtimes(ca.mtimes(R_SB, Rij), R_BS)
        Jx = ca.vertcat(
            ca.horzcat(-ca.mtimes(R_SB, Rij.T), Z, Z, R_SB, Z, Z),
            ca.horzcat(ca.mtimes(R_SB, _hat(e)), -ca.mtimes(R_SB, Ri.T), Z,
                       -ca.mtimes(ca.mtimes(R_SB, Rij), _hat(p_BS)), ca.mtimes(R_SB, Ri.T), Z))
        Jt = ca.SX(6, P)
        name = sensor.name
        if sensor.estimate.extrinsic:
            r0 = rig.index(f"{name}.rot_x")
            t0 = rig.index(f"{name}.trans_x")
            Jt[0:3, r0:r0 + 3] = I3 - R_rel.T
            Jt[3:6, r0:r0 + 3] = _hat(t_rel)
            Jt[3:6, t0:t0 + 3] = ca.mtimes(R_SB, Rij - I3)
        if sensor.estimate.time_offset:
            k = rig.index(f"{name}.time_offset")
            Jt[0:3, k] = ca.mtimes(R_SB, wj - ca.mtimes(Rij.T, wi))
            dt_t = ca.cross(e, wi) + ca.mtimes(Ri.T, vj - vi) + ca.mtimes(Rij, ca.cross(wj, p_BS))
            Jt[3:6, k] = ca.mtimes(R_SB, dt_t)
        if sensor.monocular:
            Jt[3:6, rig.index(f"{name}.scale")] = t_rel
        W = ca.DM([1.0 / np.deg2rad(sensor.noise.rotation_sigma_deg)] * 3
                  + [1.0 / sensor.noise.translation_sigma_m] * 3)
        world.append((Jx * W, Jt * W))

    # world → local states (excite.information._to_local, stride 1)
    vbi, vbj = ca.mtimes(Ri.T, vi), ca.mtimes(Rj.T, vj)
    di = ca.mtimes(Ri.T, pj - pi)
    Jx_all = ca.vertcat(*[x for x, _ in world])
    Jt_all = ca.vertcat(*[t for _, t in world])
    Jr_i, Jv_i = Jx_all[:, 0:3], Jx_all[:, 6:9]
    Jr_j, Jp_j, Jv_j = Jx_all[:, 9:12], Jx_all[:, 12:15], Jx_all[:, 15:18]
    JvRi, JvRj, JpRi = ca.mtimes(Jv_i, Ri), ca.mtimes(Jv_j, Rj), ca.mtimes(Jp_j, Ri)
    Li = ca.horzcat(Jr_i - ca.mtimes(JvRi, _hat(vbi)) - ca.mtimes(JpRi, _hat(di)), JvRi, JpRi)
    Lj = ca.horzcat(Jr_j - ca.mtimes(JvRj, _hat(vbj)), JvRj, ca.SX(Jx_all.size1(), 3))
    out = [ca.mtimes(Li.T, Li), ca.mtimes(Lj.T, Lj), ca.mtimes(Lj.T, Li),
           ca.mtimes(Li.T, Jt_all), ca.mtimes(Lj.T, Jt_all), ca.mtimes(Jt_all.T, Jt_all)]
    return ca.Function("interval", [Rs, fs, pi, pj, vi, vj, wi, wj, RVAi, RVAj], [ca.vec(o) for o in out])
