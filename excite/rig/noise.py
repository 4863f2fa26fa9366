"""An odometry's drift densities from a drive logged with a reference: the numbers a rig's lidar
or camera ``noise`` takes (``rotation_density_deg_per_sqrt_s``,
``translation_density_m_per_sqrt_s``: :mod:`excite.factors.odometry`), measured instead of
guessed.

**The model** is the one the evaluator uses: the odometry's relative pose between consecutive
frames i → i+1 (Δtᵢ apart) is the truth's with an error wᵢ, independent between pairs, N(0, q·Δtᵢ)
per axis (q = density²; rotation errors as ``Log(R_predᵀ R_odom)`` in the odometry's frame at i,
translation errors in the same frame). The reference is not exact either: each of its poses
carries a white error; with the odometry's own per-frame jitter it adds ``nᵢ₊₁ − nᵢ`` (variance c
per pose, per axis) to each pair. So per axis the pair errors eᵢ = wᵢ + nᵢ₊₁ − nᵢ are Gaussian
with a tridiagonal covariance, ``q·Δtᵢ + 2c`` on the diagonal and ``−c`` beside it: q and c are
told apart (the white error's share does not grow with Δt and makes neighbours anti-correlated),
so the reference's own noise does not bias the density up. (q, c) are the maximum-likelihood
estimate over the three axes together (the evaluator takes one density for all three); the
uncertainty is the Cramér–Rao bound of that likelihood (the observed information, by finite
differences of the exact log-likelihood, computed with a banded Cholesky factor). The per-axis
densities are reported beside it.

**Alignment.** The odometry and the reference describe two frames rigidly attached to the
vehicle, on two clocks, in two worlds; a monocular odometry has its own scale. Relative poses do
not depend on the worlds; what is estimated first, as nuisances, is:

- the time offset δ (the reference at ``t + δ`` is the odometry at t), by a search of the
  rotation-only misfit of ~1-s relative rotations (frame- and scale-free), refined by a bounded
  scalar minimisation;
- the rotation X and the lever arm l between the two frames, and the scale s of the odometry's
  translations, by least squares (Huber) over ~1-s relative poses
  (``R_pred = Xᵀ R_ref X``, ``t_pred = Xᵀ (R_ref l + t_ref − l)``, error ``s·t_odom − t_pred``).

The reference is interpolated at the odometry's stamps (slerp, linear), never across one of its
gaps wider than :data:`MAX_GAP_S`; pairs that would are left out.

**Tails.** The density is the pair errors' variance (what a least-squares calibration's σ
follow); where they are heavy-tailed (kurtosis above 6) the report gives the density of their
bulk beside it (a robust variogram: the squared median absolute deviation of errors over four
frames less that over one, over the time added: the white part cancels).

**Assumptions** (the report says how well the drive bears the first out): the odometry's error is
a random walk (no loop closure or map reuse pulling it back, no slow bias); the reference's error
is white (its own drift negligible against the odometry's); one scale per drive; the frames are
rigidly attached. The fit check compares the observed variance of relative poses over ~1 s and
~10 s with what the fitted model predicts: a ratio well below 1 means the odometry's error stays
bounded (loop closures, a map), above 1 a drift the model misses (a slow bias, scale drift).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded
from scipy.optimize import least_squares, minimize, minimize_scalar
from scipy.spatial.transform import Rotation

from ..core import so3
from ..errors import RigError

MAX_GAP_S = 0.5  # the widest gap of the reference the interpolation may bridge
ALIGN_WINDOW_S = 1.0  # relative poses over this long align the frames and the clocks
MIN_PAIRS = 50


@dataclass(frozen=True)
class TimedPoses:
    """Poses of one frame: times [s] (increasing), rotations (n, 3, 3), positions (n, 3) [m]."""

    t_s: np.ndarray
    R: np.ndarray
    p: np.ndarray
    name: str = ""


@dataclass(frozen=True)
class Density:
    """A drift density [unit/√s] with its 1σ uncertainty, per axis, and the white noise per pose."""

    value: float
    sigma: float
    per_axis: tuple[float, float, float]
    white_sigma: float  # per pose and axis (the reference's error and the odometry's jitter)
    over_1s: float  # the density a random walk would need to give the errors observed over ~1 s
    over_10s: float  # … over ~10 s
    unit: str
    kurtosis: float = 3.0  # of the pair errors per √Δt (3 for Gaussian ones)
    bulk: float = math.nan  # the density of their bulk (a variogram of median absolute deviations)


@dataclass(frozen=True)
class DriftEstimate:
    """What :func:`estimate_drift` found (see the module notes)."""

    rotation: Density  # deg/√s
    translation: Density  # m/√s
    time_offset_s: float
    frame_rotation_deg: float  # the angle of X, the odometry's frame in the reference's
    frame_rotation: np.ndarray
    lever_arm_m: np.ndarray
    scale: float
    pairs: int
    duration_s: float
    rate_hz: float
    notes: list[str] = field(default_factory=list)

    def rig_lines(self) -> str:
        """The lines to paste under a lidar's or camera's entry in a rig."""
        return ("    noise:\n"
                f"      rotation_density_deg_per_sqrt_s: {self.rotation.value:.3g}\n"
                f"      translation_density_m_per_sqrt_s: {self.translation.value:.3g}\n")

    def to_dict(self) -> dict[str, Any]:
        def d(x: Density) -> dict[str, Any]:
            return {"value": x.value, "sigma": x.sigma, "per_axis": list(x.per_axis), "white_sigma": x.white_sigma,
                    "over_1s": x.over_1s, "over_10s": x.over_10s, "kurtosis": x.kurtosis, "bulk": x.bulk,
                    "unit": x.unit}

        return {"rotation_density_deg_per_sqrt_s": d(self.rotation),
                "translation_density_m_per_sqrt_s": d(self.translation),
                "time_offset_s": self.time_offset_s, "frame_rotation_deg": self.frame_rotation_deg,
                "lever_arm_m": self.lever_arm_m.tolist(), "scale": self.scale, "pairs": self.pairs,
                "duration_s": self.duration_s, "rate_hz": self.rate_hz, "notes": self.notes}


# --------------------------------------------------------------------------------------------
# Interpolation and relative poses


def max_gap_s(ref: TimedPoses) -> float:
    """The widest gap between reference samples bridged: :data:`MAX_GAP_S`, or 2.5 of its usual
    intervals for a slower reference."""
    return max(MAX_GAP_S, 2.5 * float(np.median(np.diff(ref.t_s))))


def _interpolate(ref: TimedPoses, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reference at times ``t``: (valid, R, p); invalid outside it or across a gap."""
    j = np.searchsorted(ref.t_s, t, side="right") - 1
    valid = (j >= 0) & (j < ref.t_s.size - 1)
    j = np.clip(j, 0, ref.t_s.size - 2)
    t0, t1 = ref.t_s[j], ref.t_s[j + 1]
    valid &= (t1 - t0) <= max_gap_s(ref)
    a = np.clip((t - t0) / np.maximum(t1 - t0, 1e-12), 0.0, 1.0)
    R0, R1 = ref.R[j], ref.R[j + 1]
    d = so3.log(np.swapaxes(R0, 1, 2) @ R1)
    R = R0 @ so3.exp(d * a[:, None])
    p = ref.p[j] + (ref.p[j + 1] - ref.p[j]) * a[:, None]
    return valid, R, p


def _relative(R: np.ndarray, p: np.ndarray, i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    RiT = np.swapaxes(R[i], 1, 2)
    return RiT @ R[j], np.einsum("nab,nb->na", RiT, p[j] - p[i])


def _pairs(valid: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, i+k) with both ends (and everything between) valid."""
    n = valid.size
    if n <= k:
        return np.zeros(0, int), np.zeros(0, int)
    bad = np.concatenate([[0], np.cumsum(~valid)])
    i = np.arange(n - k)
    ok = (bad[i + k + 1] - bad[i]) == 0
    return i[ok], i[ok] + k


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation X minimising Σ|a − X b|²."""
    H = b.T @ a
    u, _, vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    return vt.T @ D @ u.T


def _rotation_misfit(odom: TimedPoses, ref: TimedPoses, delta: float, k: int) -> float:
    """Mean squared rotation misfit of k-frame relative rotations, the frames aligned (Kabsch)."""
    valid, R, _ = _interpolate(ref, odom.t_s + delta)
    i, j = _pairs(valid, k)
    if i.size < MIN_PAIRS:
        return math.inf
    a = so3.log(_relative(R, np.zeros((R.shape[0], 3)), i, j)[0])
    b = so3.log(_relative(odom.R, odom.p, i, j)[0])
    X = _kabsch(a, b)
    return float(np.mean(np.sum((a - b @ X.T) ** 2, axis=1)))


def _time_offset(odom: TimedPoses, ref: TimedPoses, k: int, max_offset_s: float) -> float:
    step = max(0.01, min(0.05, max_offset_s / 50))
    grid = np.arange(-max_offset_s, max_offset_s + step / 2, step)
    cost = np.array([_rotation_misfit(odom, ref, d, k) for d in grid])
    if not np.isfinite(cost).any():
        lo, hi = max(odom.t_s[0], ref.t_s[0] - max_offset_s), min(odom.t_s[-1], ref.t_s[-1] + max_offset_s)
        if hi - lo < ALIGN_WINDOW_S * MIN_PAIRS / k:
            raise RigError(f"the odometry ({odom.t_s[0]:.3f}–{odom.t_s[-1]:.3f} s) and the reference "
                           f"({ref.t_s[0]:.3f}–{ref.t_s[-1]:.3f} s) do not overlap in time (within the time "
                           f"offset searched, ±{max_offset_s:g} s): the same clock, the same drive?")
        raise RigError(f"too few stretches of the reference without a gap over {max_gap_s(ref):.2g} s at the "
                       f"odometry's times: {MIN_PAIRS} relative poses over {ALIGN_WINDOW_S:g} s are needed")
    best = grid[int(np.argmin(cost))]
    res = minimize_scalar(lambda d: _rotation_misfit(odom, ref, d, k), bounds=(best - step, best + step),
                          method="bounded", options={"xatol": 1e-4})
    return float(res.x)


# --------------------------------------------------------------------------------------------
# Alignment of the frames and the scale


def _errors(x: np.ndarray, Rr: np.ndarray, tr: np.ndarray, Ro: np.ndarray, to: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Rotation [rad] and translation [m] errors of the odometry's relative poses against those
    the reference predicts, for alignment ``x`` = (rotvec of X, lever arm l, scale s)."""
    X = so3.exp(x[:3][None])[0]
    l, s = x[3:6], x[6]
    R_pred = X.T @ Rr @ X
    t_pred = np.einsum("ab,nb->na", X.T, np.einsum("nab,b->na", Rr, l) + tr - l)
    r = so3.log(np.swapaxes(R_pred, 1, 2) @ Ro)
    return r, s * to - t_pred


def _align(odom: TimedPoses, ref: TimedPoses, i: np.ndarray, j: np.ndarray, delta0: float, fit_delta: bool
           ) -> tuple[np.ndarray, float]:
    """(x, δ): the alignment ``x`` (rotvec of X, lever arm, scale) and the time offset (refined with
    it when ``fit_delta``), by least squares over the pairs (i, j) (two passes: the σ of the first
    weigh the second)."""
    Ro, to = _relative(odom.R, odom.p, i, j)

    def reference(delta: float) -> tuple[np.ndarray, np.ndarray]:
        _, R, p = _interpolate(ref, odom.t_s + delta)
        return _relative(R, p, i, j)

    Rr, tr = reference(delta0)
    X0 = _kabsch(so3.log(Rr), so3.log(Ro))
    scale0 = float(np.sum(np.linalg.norm(tr, axis=1)) / max(np.sum(np.linalg.norm(to, axis=1)), 1e-12))
    x = np.r_[Rotation.from_matrix(X0).as_rotvec(), np.zeros(3), scale0, delta0][: 8 if fit_delta else 7]
    sr, st = 1e-2, 1e-2
    for _ in range(2):
        def fun(x, sr=sr, st=st):
            r, t = _errors(x[:7], *reference(x[7] if fit_delta else delta0), Ro, to)
            # the lever arm weakly held at zero: a planar drive leaves its vertical part undetermined
            return np.concatenate([(r / sr).ravel(), (t / st).ravel(), x[3:6] / 10.0])

        x = least_squares(fun, x, loss="huber", f_scale=3.0, x_scale="jac", diff_step=1e-6).x
        r, t = _errors(x[:7], *reference(x[7] if fit_delta else delta0), Ro, to)
        sr, st = max(float(np.sqrt(np.mean(r ** 2))), 1e-9), max(float(np.sqrt(np.mean(t ** 2))), 1e-12)
    return x[:7], float(x[7]) if fit_delta else delta0


# --------------------------------------------------------------------------------------------
# The densities


def _segments(i: np.ndarray) -> list[slice]:
    """Runs of consecutive pairs (i, i+1) with i increasing by one."""
    breaks = np.flatnonzero(np.diff(i) != 1) + 1
    edges = np.r_[0, breaks, i.size]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def _neg_loglik(q: float, c: float, e: np.ndarray, dt: np.ndarray, segments: list[slice]) -> float:
    """−log-likelihood of the pair errors ``e`` (n, m axes) under the tridiagonal model."""
    total = 0.0
    for s in segments:
        d, x = dt[s], e[s]
        ab = np.zeros((2, d.size))
        ab[1] = q * d + 2.0 * c
        ab[0, 1:] = -c
        try:
            U = cholesky_banded(ab, lower=False)
        except np.linalg.LinAlgError:
            return math.inf
        z = cho_solve_banded((U, False), x)
        total += 0.5 * float(np.sum(x * z)) + x.shape[1] * float(np.sum(np.log(U[1])))
    return total


def _ml(e: np.ndarray, dt: np.ndarray, segments: list[slice]) -> tuple[float, float, float]:
    """(q, c, σ_q): the maximum-likelihood q and c, and the Cramér–Rao σ of q."""
    v = float(np.mean(e ** 2))
    dtm = float(np.mean(dt))
    # start: half the variance from each part
    x0 = np.log([max(v / 2 / dtm, 1e-30), max(v / 4, 1e-30)])
    f = lambda z: _neg_loglik(math.exp(z[0]), math.exp(z[1]), e, dt, segments)  # noqa: E731
    res = minimize(f, x0, method="Nelder-Mead", options={"xatol": 1e-6, "fatol": 1e-6, "maxiter": 2000})
    q, c = float(np.exp(res.x[0])), float(np.exp(res.x[1]))
    # the observed information in (q, c) by central differences
    h = np.array([q, c]) * 1e-3
    g = lambda a, b: _neg_loglik(a, b, e, dt, segments)  # noqa: E731
    H = np.empty((2, 2))
    f0 = g(q, c)
    H[0, 0] = (g(q + h[0], c) - 2 * f0 + g(q - h[0], c)) / h[0] ** 2
    H[1, 1] = (g(q, c + h[1]) - 2 * f0 + g(q, c - h[1])) / h[1] ** 2
    H[0, 1] = H[1, 0] = (g(q + h[0], c + h[1]) - g(q + h[0], c - h[1]) - g(q - h[0], c + h[1])
                         + g(q - h[0], c - h[1])) / (4 * h[0] * h[1])
    det = H[0, 0] * H[1, 1] - H[0, 1] ** 2
    if det > 0 and H[0, 0] > 0:
        sq = math.sqrt(H[1, 1] / det)
    else:  # c at its bound (no white part to tell): the information on q alone
        sq = 1.0 / math.sqrt(H[0, 0]) if H[0, 0] > 0 else math.inf
    return q, c, sq


def _mad2(e: np.ndarray) -> float:
    """The squared σ of the bulk of ``e`` (per axis, pooled) from its median absolute deviation."""
    return (1.4826 * float(np.median(np.abs(e - np.median(e, axis=0))))) ** 2


def _density(e: np.ndarray, dt: np.ndarray, segments: list[slice], scale: float, unit: str,
             long: list[tuple[float, np.ndarray]], short: tuple[float, np.ndarray]) -> Density:
    q, c, sq = _ml(e, dt, segments)
    per_axis = tuple(math.sqrt(_ml(e[:, [a]], dt, segments)[0]) * scale for a in range(3))
    # the apparent density over longer spans, the white part taken off: a random walk keeps it
    over = [math.sqrt(max(float(np.mean(errs ** 2)) - 2 * c, 0.0) / span) * scale if errs.size else math.nan
            for span, errs in long]
    z = (e / np.sqrt(dt)[:, None]).ravel()
    kurt = float(np.mean(z ** 4) / np.mean(z ** 2) ** 2)
    # the bulk's density: a robust variogram, the spread of errors over a few frames less that of
    # one frame pair (the white part cancels) over the added time
    span, e_k = short
    bulk = math.sqrt(max(_mad2(e_k) - _mad2(e), 0.0) / max(span - float(np.mean(dt)), 1e-9)) * scale
    return Density(math.sqrt(q) * scale, sq / (2 * math.sqrt(q)) * scale, per_axis, math.sqrt(c) * scale,
                   over[0], over[1], unit, kurt, bulk)


def estimate_drift(odometry: TimedPoses, reference: TimedPoses, *, max_time_offset_s: float = 1.0,
                   time_offset_s: float | None = None) -> DriftEstimate:
    """The odometry's drift densities against the reference (see the module notes);
    ``time_offset_s`` fixes the offset instead of searching ±``max_time_offset_s``."""
    for tp, what in ((odometry, "odometry"), (reference, "reference")):
        if tp.t_s.size < MIN_PAIRS or np.any(np.diff(tp.t_s) <= 0):
            raise RigError(f"{what}: needs at least {MIN_PAIRS} poses with increasing times")
    dt_med = float(np.median(np.diff(odometry.t_s)))
    k = max(1, int(round(ALIGN_WINDOW_S / dt_med)))
    delta = (_time_offset(odometry, reference, k, max_time_offset_s) if time_offset_s is None
             else float(time_offset_s))
    valid, _, _ = _interpolate(reference, odometry.t_s + delta)
    if valid.sum() < MIN_PAIRS:
        raise RigError(f"only {int(valid.sum())} odometry poses fall within the reference (need {MIN_PAIRS})")
    i, j = _pairs(valid, k)
    x, delta = _align(odometry, reference, i, j, delta, fit_delta=time_offset_s is None)
    valid, Rref, pref = _interpolate(reference, odometry.t_s + delta)
    notes: list[str] = []
    if time_offset_s is None and abs(abs(delta) - max_time_offset_s) < 0.02:
        notes.append(f"the time offset {delta:+.3f} s is at the edge of the search (±{max_time_offset_s:g} s): "
                     "widen it (--max-time-offset)")

    def pair_errors(kk: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        a, b = _pairs(valid, kk)
        R1, t1 = _relative(Rref, pref, a, b)
        R2, t2 = _relative(odometry.R, odometry.p, a, b)
        r, t = _errors(x, R1, t1, R2, t2)
        return a, odometry.t_s[b] - odometry.t_s[a], r, t

    a, dt, er, et = pair_errors(1)
    if a.size < MIN_PAIRS:
        raise RigError(f"only {a.size} consecutive pairs within the reference (need {MIN_PAIRS})")
    segments = _segments(a)
    longs = []
    for span in (1.0, 10.0):
        kk = max(1, int(round(span / dt_med)))
        _, _, r, t = pair_errors(kk)
        longs.append((kk * dt_med, r, t))
    _, _, r4, t4 = pair_errors(4)
    rot = _density(er, dt, segments, math.degrees(1.0), "deg/√s", [(s, r) for s, r, _ in longs], (4 * dt_med, r4))
    trans = _density(et, dt, segments, 1.0, "m/√s", [(s, t) for s, _, t in longs], (4 * dt_med, t4))
    for d, what in ((rot, "rotation"), (trans, "translation")):
        if d.over_1s > 1.3 * d.value:
            notes.append(f"the {what} error grows faster than a random walk: over 1 s it is that of "
                         f"{d.over_1s:.3g} {d.unit} (over 10 s {d.over_10s:.3g}), against {d.value:.3g} between frames; "
                         "the frame pairs are not independent, and a rig that needs a margin takes the 1-s density")
        if d.kurtosis > 6.0:
            notes.append(f"the {what} pair errors are heavy-tailed (kurtosis {d.kurtosis:.0f}; 3 for Gaussian ones): "
                         f"the density is their variance's ({d.value:.3g} {d.unit}), what a least-squares "
                         f"calibration feels; their bulk is that of {d.bulk:.3g} {d.unit}")
        if d.over_10s < 0.7 * d.value:
            notes.append(f"the {what} error stays bounded over 10 s ({d.over_10s:.3g} {d.unit}): loop closures or a "
                         "map pull the odometry back; between frames it is the density given")
    X = so3.exp(x[:3][None])[0]
    return DriftEstimate(rot, trans, delta, float(np.degrees(np.linalg.norm(x[:3]))), X, x[3:6].copy(),
                         float(x[6]), int(a.size), float(odometry.t_s[valid][-1] - odometry.t_s[valid][0]),
                         1.0 / dt_med, notes)


@dataclass(frozen=True)
class ReportedDensities:
    """What an odometry reports of itself: the drift densities its messages' covariances imply
    (the root of the mean per-second variance over the three axes and the messages), with the
    10th and 90th percentiles over the messages."""

    rotation_deg_per_sqrt_s: tuple[float, float, float]  # (p10, overall, p90)
    translation_m_per_sqrt_s: tuple[float, float, float]
    messages: int

    def rig_lines(self) -> str:
        return ("    noise:\n"
                f"      rotation_density_deg_per_sqrt_s: {self.rotation_deg_per_sqrt_s[1]:.3g}\n"
                f"      translation_density_m_per_sqrt_s: {self.translation_m_per_sqrt_s[1]:.3g}\n")


def reported_densities(per_second: np.ndarray) -> ReportedDensities:
    """The densities an odometry's covariances per second imply (``per_second``: (n, 6, 6) in the
    residual's order, rotation [rad²/s] then translation [m²/s]; NaN where a message reports
    none): what ``noise.use_reported_covariance`` weighs its frame pairs by, in one number each."""
    known = np.all(np.isfinite(per_second), axis=(1, 2))
    if not known.any():
        raise RigError("no message reports a covariance")
    d = np.diagonal(per_second[known], axis1=1, axis2=2)
    rot, trans = d[:, :3].mean(axis=1), d[:, 3:].mean(axis=1)

    def summary(v: np.ndarray, scale: float) -> tuple[float, float, float]:
        return (math.sqrt(np.percentile(v, 10)) * scale, math.sqrt(float(v.mean())) * scale,
                math.sqrt(np.percentile(v, 90)) * scale)

    return ReportedDensities(summary(rot, math.degrees(1.0)), summary(trans, 1.0), int(known.sum()))
