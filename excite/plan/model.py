"""The evaluator's information model in CasADi: nominal motion → marginal information Λ_θ.

Every factor's information comes from its kind's one statement of the measurement
(:mod:`excite.factors`): its whitened Jacobians are the automatic derivative of its residual at
the noise-free measurement of the nominal motion (:func:`excite.factors.symbolic.linearised`),
now functions of the decision variables, so that IPOPT gets exact derivatives of everything
downstream. The drive is closed as the evaluator closes it (:mod:`excite.information.closure`:
the same parametrisation of the trajectory, gauge and last keyframe), and the trajectory is
eliminated by sequential block elimination of the block-tridiagonal H_xx (one 9×9 Cholesky per
keyframe, a :meth:`casadi.Function.mapaccum` over the keyframes: cost linear in the drive
length, no dense H_xx), then the nuisance coordinates (a monocular camera's scale, the tyre
slip: what slip costs the calibration is in the objective, so plans that brake and turn hard pay
for it).

The optimizer runs it on a coarse copy of the rig (:func:`coarse_rig`: fewer keyframes, a few IMU
samples per keyframe interval, every sensor at the keyframe rate with the same information per
second); on that rig it reproduces the numpy evaluator to rounding (tests).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..errors import OptimizeError
from ..factors import base as registry
from ..factors import symbolic
from ..information.closure import Closure, marginalise_nuisance_symbolic
from ..rig.config import Rig

D = 9  # the trajectory state of a keyframe (the optimizer's model takes the biases constant)


def coarse_rig(rig: Rig, keyframe_rate_hz: float = 2.0, imu_substeps: int = 4) -> Rig:
    """A copy of ``rig`` at ``keyframe_rate_hz`` with every sensor at that rate
    (:func:`~excite.factors.base.at_rate`: the same information per second) and
    ``imu_substeps`` IMU samples per keyframe interval.

    The IMU biases are constant in the optimizer's model: on maneuvers of a few minutes the random
    walk moves the score by little (README, "What the numbers assume"), and the result is
    re-scored with the rig's own model."""
    c = rig.config.model_dump()
    sensors = [registry.at_rate(registry.kind_of_sensor(s["kind"]), s, keyframe_rate_hz) for s in c["sensors"]]
    changes = dict(keyframe_rate_hz=keyframe_rate_hz, sensors=sensors,
                   imu=dict(c["imu"], update_rate=keyframe_rate_hz * imu_substeps, bias_model="constant"))
    return rig.with_config(**changes)


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


def _row_major(c):
    """Row-major entries of a 3 × 3 matrix given column-major (``ca.vec``)."""
    return ca.vec(ca.reshape(c, 3, 3).T)


def _factor_information(rig: Rig, closure: Closure, arity: int, n: int,
                        instances: list[registry.Instance] | None = None) -> ca.Function | None:
    """``JᵀJ`` in the closure's trajectory states and θ of every factor of ``arity`` that one
    keyframe (arity 1) or keyframe interval (arity 2) holds, summed over the rig's kinds (or over
    ``instances``: the openings of a drive, :func:`~excite.factors.base.openings`).

    Inputs: per keyframe ``[vec R (row-major), p, v, ω, vec R_V_A]`` (27 each), and the interval's
    IMU samples (``n + 1`` orientations, ``n`` specific forces; arity 2). Outputs (vec): arity 1:
    H[x,x], H[x,θ], H[θ,θ]; arity 2: H[x_i,x_i], H[x_j,x_j], H[x_j,x_i], H[x_i,θ], H[x_j,θ], H[θ,θ]."""
    P = len(rig.coordinates)
    x = ca.SX.sym("x", symbolic.KEYFRAME_INPUTS * arity)
    s = ca.SX.sym("imu", 9 * (n + 1) + 3 * n if arity == 2 else 0)
    Jx_all, Jt_all = [], []
    for i in registry.instances(rig) if instances is None else instances:
        kind, entry = i.kind, i.entry
        if kind.arity != arity:
            continue
        if registry.stride(kind, rig, entry) != 1:
            raise OptimizeError(f"{registry.block_name(kind, entry)} runs at every {registry.stride(kind, rig, entry)}th keyframe: the "
                                f"optimizer's model needs every sensor at the keyframe rate "
                                f"{rig.keyframe_rate_hz:g} Hz (use coarse_rig)")
        lay = symbolic.layout(kind, rig, entry)
        Jx, Jt = symbolic.linearised(kind, rig, entry, x, s if lay.n_samples else ca.SX(0, 1),
                                     ca.DM(symbolic.quantity_inputs(lay)))
        full = ca.SX(kind.rows, P)  # the entry's coordinates among all of θ (the rest structurally zero)
        for i, name in enumerate(symbolic.coordinate_names(lay)):
            full[:, rig.index(name)] = Jt[:, i]
        Jx_all.append(Jx)
        Jt_all.append(full)
    if not Jx_all:
        return None
    Jx, Jt = ca.vertcat(*Jx_all), ca.vertcat(*Jt_all)
    L = _to_states(Jx, x, arity, closure.local)
    Lt = [b.T for b in L]
    if arity == 1:
        out = [ca.mtimes(Lt[0], L[0]), ca.mtimes(Lt[0], Jt), ca.mtimes(Jt.T, Jt)]
    else:
        out = [ca.mtimes(Lt[0], L[0]), ca.mtimes(Lt[1], L[1]), ca.mtimes(Lt[1], L[0]),
               ca.mtimes(Lt[0], Jt), ca.mtimes(Lt[1], Jt), ca.mtimes(Jt.T, Jt)]
    return ca.Function(f"information{arity}", [x, s], [ca.vec(o) for o in out], {"cse": True})


def _to_states(Jx, x, arity: int, local: bool) -> list:
    """World-state Jacobians (``[δθ, δp, δv]`` per keyframe) in the closure's states, per keyframe:
    the same map as :func:`excite.information.problem.to_local` (local: ``δv_world = R δv_b −
    R [v_b]× δθ``, and positions through the increment ``d_i = R_iᵀ(p_j − p_i)`` of the pair's first
    keyframe, ``δ(p_j − p_i) = R_i δd_i − R_i [d_i]× δθ_i``)."""
    blocks = [Jx[:, 9 * a:9 * (a + 1)] for a in range(arity)]
    if not local:
        return blocks
    o = symbolic.KEYFRAME_INPUTS
    R = [ca.reshape(x[o * a:o * a + 9], 3, 3).T for a in range(arity)]
    v = [x[o * a + 12:o * a + 15] for a in range(arity)]
    vb = [ca.mtimes(R[a].T, v[a]) for a in range(arity)]
    out = []
    for a in range(arity):
        Jr, Jv = blocks[a][:, 0:3], blocks[a][:, 6:9]
        JvR = ca.mtimes(Jv, R[a])
        out.append([Jr - ca.mtimes(JvR, symbolic.hat(vb[a])), JvR, ca.SX(Jx.size1(), 3)])
    if arity == 2:
        Jp_j = blocks[1][:, 3:6]  # = −Jp_i: positions enter through p_j − p_i only
        p = [x[o * a + 9:o * a + 12] for a in range(2)]
        d = ca.mtimes(R[0].T, p[1] - p[0])
        JpR = ca.mtimes(Jp_j, R[0])
        out[0][0] = out[0][0] - ca.mtimes(JpR, symbolic.hat(d))
        out[0][2] = JpR
    return [ca.horzcat(*o_) for o_ in out]


def build_model(rig: Rig, n_keyframes: int) -> InformationModel:
    """The information model of ``rig`` (every sensor at the keyframe rate) on a drive of
    ``n_keyframes`` keyframes."""
    n = int(round(rig.config.imu.update_rate / rig.keyframe_rate_hz))
    if n_keyframes < 3:
        raise OptimizeError(f"the drive is too short: {n_keyframes} keyframes")
    closure = Closure.of(rig, origin=False)  # plain world states (see closure: no rank test reads this model)
    if closure.state_dim != D:
        raise OptimizeError("the optimizer's model takes the IMU biases constant (use coarse_rig)")
    K = n_keyframes
    P = len(rig.coordinates)
    pair = _factor_information(rig, closure, 2, n)
    single = _factor_information(rig, closure, 1, n)
    openings = list(registry.openings(rig))
    opening = _factor_information(rig, closure, 1, n, openings) if openings else None
    step = _elimination_step(P)

    N = (K - 1) * n + 1
    R = ca.MX.sym("R", 9, N)
    p = ca.MX.sym("p", 3, N)
    v = ca.MX.sym("v", 3, N)
    w = ca.MX.sym("w", 3, N)
    f = ca.MX.sym("f", 3, N)
    RVA = ca.MX.sym("R_V_A", 9, N)
    kf = list(range(0, N, n))
    # per keyframe: its inputs as the factors read them
    X = ca.vertcat(ca.horzcat(*[_row_major(R[:, k]) for k in kf]), p[:, ::n], v[:, ::n], w[:, ::n],
                   ca.horzcat(*[_row_major(RVA[:, k]) for k in kf]))
    zero81, zeroE = ca.MX(81, 1), ca.MX(D * P, 1)
    Dk = ca.MX(81, K)
    Ek = ca.MX(D * P, K)
    Htt = ca.MX(P * P, 1)
    Bji = ca.MX(81, K - 1)
    if pair is not None:
        # per interval: the n+1 orientations and the n specific forces of its samples
        S = ca.vertcat(ca.horzcat(*[ca.vertcat(*[_row_major(R[:, k + s]) for s in range(n + 1)]) for k in kf[:-1]]),
                       ca.horzcat(*[ca.vec(f[:, k:k + n]) for k in kf[:-1]]))
        Dii, Djj, Bji, Ei, Ej, Hp = pair.map(K - 1)(ca.vertcat(X[:, :-1], X[:, 1:]), S)
        Dk = Dk + ca.horzcat(Dii, zero81) + ca.horzcat(zero81, Djj)
        Ek = Ek + ca.horzcat(Ei, zeroE) + ca.horzcat(zeroE, Ej)
        Htt = Htt + ca.sum2(Hp)
    if single is not None:
        Dn, En, Hn = single.map(K)(X, ca.MX(0, K))
        Dk, Ek, Htt = Dk + Dn, Ek + En, Htt + ca.sum2(Hn)
    if opening is not None:  # the chains that open at the drive's first keyframe (a GNSS first fix)
        D0, E0, H0 = opening(X[:, 0], ca.MX(0, 1))
        Dk = ca.horzcat(Dk[:, 0] + D0, Dk[:, 1:])
        Ek = ca.horzcat(Ek[:, 0] + E0, Ek[:, 1:])
        Htt = Htt + H0
    # the drive closed as the evaluator closes it: the gauge (and the openings) at keyframe 0, the last keyframe's end
    G0 = closure.fix_information(ca.reshape(R[:, 0], 3, 3))
    end = np.zeros((D, D))
    held = closure.held()
    end[held, held] = 1.0
    Dk = ca.horzcat(Dk[:, 0] + ca.vec(G0), Dk[:, 1:K - 1], Dk[:, K - 1] + ca.vec(ca.DM(end)))
    # sequential elimination of keyframes 0 .. K−2, then the last one
    carry0 = ca.vertcat(Dk[:, 0], Ek[:, 0], ca.MX(P * P, 1))
    acc = step.mapaccum("eliminate", K - 1)
    carries = acc(carry0, ca.vertcat(Bji, Dk[:, 1:], Ek[:, 1:]))
    last = carries[:, K - 2]
    S_ = ca.reshape(last[0:81], D, D)
    F = ca.reshape(last[81:81 + D * P], D, P)
    Lacc = ca.reshape(last[81 + D * P:], P, P)
    Lam = ca.reshape(Htt, P, P) - Lacc - ca.mtimes(F.T, ca.solve(S_, F))
    Lam = 0.5 * (Lam + Lam.T)
    marginal = ca.Function("marginal", [R, p, v, w, f, RVA], [Lam],
                           ["R", "p", "v", "w", "f", "R_V_A"], ["Lambda"])

    scored = np.array([not c.nuisance for c in rig.coordinates])
    A = marginalise_nuisance_symbolic(Lam, scored)
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
    L = symbolic.chol(S, D)
    Y = symbolic.forward_solve(L, ca.horzcat(B.T, F), D)
    Yb, Yf = Y[:, 0:D], Y[:, D:]
    Lacc = Lacc + ca.mtimes(Yf.T, Yf)
    S1 = Dn - ca.mtimes(Yb.T, Yb)
    F1 = En - ca.mtimes(Yb.T, Yf)
    return ca.Function("step", [carry, inp], [ca.vertcat(ca.vec(S1), ca.vec(F1), ca.vec(Lacc))])
