"""Which elements, and how much of each: an E-optimal design over a library of elements.

The information of a drive made of elements is, to a good approximation, the sum of what each
element gives when driven alone (from rest to rest, each with its own trajectory and nuisances:
the joint drive only adds what ties them together, so the sum is the pessimistic side). That
turns the choice of elements into a classical optimal-design problem:

    maximise  λ_min( M₀ + Σₑ nₑ Mₑ )   over  nₑ ≥ 0,   Σₑ nₑ dₑ ≤ T,

``Mₑ`` the target-scaled information of one repetition of library element ``e`` (the full
evaluator's S Λ_θ S), ``dₑ`` its duration, ``T`` the time there is and ``M₀`` what is known
already (zero for a new plan; the drive so far for live guidance's re-plan). λ_min is concave in
n; with time fractions ``ξₑ = nₑdₑ/T`` on the simplex it is maximised by Frank–Wolfe on a smooth
lower bound of λ_min (the log-sum-exp of −β·eigenvalues, β tied to the current λ_min), each step
moving time to the element whose information lies most along the weak directions
(:func:`e_design`; with away steps, which take time off the least useful element in use, so that
it converges where plain Frank–Wolfe zigzags). The result is sparse — a few elements — and is rounded to whole repetitions
(:func:`repetitions`).

:func:`library` builds the candidate elements (a grid over each kind's parameters within the
limits and the lot, at the speeds the limits allow) and scores each alone (:class:`Candidate`);
with a scene, an element's information depends on where it is driven and at what heading, and
the library holds each at several placements (:func:`library` ``placements``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ...errors import OptimizeError
from ...motion.course import Course, Leg, trace
from ...motion.vehicle import Limits, drive
from ...rig.config import Rig
from .elements import KINDS, MARGIN, MIN_OFFSET_M, Geometry, Slalom, footprint, kind, turning_radius_m

SCREEN_RATE_HZ = 25.0  # the drive's grid when screening (the score within 0.05 % of 100 Hz's)


@dataclass
class Candidate:
    """One repetition of an element, scored alone: ``info`` (S Λ_θ S), ``duration_s``, the
    ``pose`` it was scored at (its centre and heading in the lot) and its footprint's half extent
    along its own axes (``half_extent_m``)."""

    kind: str
    params: dict[str, float]
    info: np.ndarray
    duration_s: float
    pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    half_extent_m: tuple[float, float] = (0.0, 0.0)
    score: float = 0.0

    @property
    def rate(self) -> np.ndarray:
        """Information per second of driving it."""
        return self.info / self.duration_s


def repeat_param(name: str) -> str:
    return "laps"


def _grid(name: str, limits: Limits, extent: tuple[float, float]) -> list[dict[str, float]]:
    """The library's parameter values for one kind: radii from the turning radius up, the
    fastest speed the limits allow (the speed planner holds it where the lateral acceleration
    binds), one repetition."""
    r = turning_radius_m(limits)
    v = MARGIN * limits.speed_max_mps
    long_, short = max(extent), min(extent)
    out: list[dict[str, float]] = []
    if name == "figure_eight":
        for R in (r, 1.3 * r, 1.8 * r, 2.5 * r):
            for gap in (3.0, 10.0):
                D = 2 * R + gap
                if D + 2 * R > long_ or 2 * R > short:
                    continue
                for stops in (0, 2):
                    out.append(dict(radius_m=round(R, 2), spacing_m=round(D, 2), speed_mps=v, laps=1, mirror=0,
                                    stops_per_lap=stops))
    elif name == "circles":
        for R in (r, 1.3 * r, 1.8 * r, 2.5 * r):
            if 2 * R + 2 > short:
                continue
            for mirror in (0, 1):
                for stops in (0, 1, 2):
                    out.append(dict(radius_m=round(R, 2), speed_mps=v, laps=1, mirror=mirror, stops_per_lap=stops))
    elif name == "slalom":
        for A in (MIN_OFFSET_M, 2.5):
            d0 = Slalom.min_spacing_m(A, limits)
            for f in (1.0, 1.15, 1.3, 1.5, 1.7):
                d = round(d0 * f + 0.05, 2)
                n = int(min(7, (long_ - 22.0) // d - 1))  # as many as fit, with the U-turns
                if n < 2:
                    continue
                for cones in sorted({2, 3, n} & set(range(2, n + 1))):
                    for stops in (0, 1):
                        out.append(dict(spacing_m=d, cones=cones, offset_m=A, speed_mps=v, laps=1, mirror=0,
                                        stops_per_lap=stops))
    elif name == "straight_run":
        for L in (20.0, 35.0, 50.0, long_):
            if L + 2 > long_:
                continue
            out.append(dict(length_m=L, speed_mps=v, laps=1, mirror=0))
    return out


def half_extent(g: Geometry) -> tuple[float, float]:
    pts = np.vstack([footprint(g), [[c.x, c.y] for c in g.cones]])
    return float(np.abs(pts[:, 0]).max()), float(np.abs(pts[:, 1]).max())


def _fits(g: Geometry, site, pose) -> bool:
    """Whether the element's path, centred at ``pose``, stays inside the lot's margin."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    pts = footprint(g) @ np.array([[c, s], [-s, c]]) + pose[:2]
    return bool(site.lot.contains(pts, site.margin_m + 0.3).all())


def element_drive(name: str, params: dict[str, float], limits: Limits, rig: Rig,
                  pose: tuple[float, float, float] = (0.0, 0.0, 0.0), rate_hz: float = SCREEN_RATE_HZ):
    """One element alone from rest to rest at ``pose`` (its centre and heading): its geometry,
    course and drive."""
    from .plan import pose_to_lot

    g = kind(name).geometry(params, limits)
    start = pose_to_lot(pose, g.start)
    path = trace(g.pieces, start)
    leg = Leg(path, g.speed(path.s_m), 0.0, 0)
    timed = Course((leg,), name).timed(limits, MARGIN)
    return g, timed, drive(timed.profile, rig.suspension, rate_hz=rate_hz)


def library(rig: Rig, limits: Limits, site, kinds: tuple[str, ...] = tuple(KINDS),
            evaluate: Callable | None = None, placements: Callable[[Geometry], list] | None = None,
            progress: Callable[[int, int], None] | None = None) -> list[Candidate]:
    """Every element of the kinds' grids (:func:`_grid`) that fits the lot, scored alone by
    ``evaluate(trajectory) → Report`` (default: the full evaluator with ``rig``); at the lot's
    centre, heading along its longer side, or at each pose ``placements(geometry)`` gives."""
    from ...score.evaluate import evaluate as full

    evaluate = evaluate or (lambda traj: full(traj, rig))
    lx, ly = site.extent_m
    inner = (lx - 2 * site.margin_m, ly - 2 * site.margin_m)
    specs = [(name, p) for name in kinds for p in _grid(name, limits, inner)]
    out = []
    centre = site.centre_m
    heading = 0.0 if lx >= ly else 0.5 * math.pi
    for i, (name, p) in enumerate(specs):
        try:
            g = kind(name).geometry(p, limits)
        except OptimizeError:
            continue
        ext = half_extent(g)
        if not _fits(g, site, (float(centre[0]), float(centre[1]), heading)):
            continue
        poses = placements(g) if placements is not None else [(float(centre[0]), float(centre[1]), heading)]
        for pose in poses:
            _, timed, traj = element_drive(name, p, limits, rig, pose)
            rep = evaluate(traj)
            out.append(Candidate(name, dict(p), np.asarray(rep.information_scaled), timed.duration_s,
                                 tuple(float(v) for v in pose), ext, float(rep.score)))
        if progress is not None:
            progress(i + 1, len(specs))
    if not out:
        raise OptimizeError(f"the lot ({lx:.0f} × {ly:.0f} m, {site.margin_m:g} m margin) is too small for any "
                            f"element within the limits: the smallest, circles at the turning radius "
                            f"{turning_radius_m(limits):.1f} m, needs {2 * turning_radius_m(limits) + 2:.0f} m "
                            "across inside the margin")
    return out


def lambda_min(M: np.ndarray) -> float:
    return float(np.linalg.eigvalsh(0.5 * (M + M.T))[0])


@dataclass
class Design:
    """Time fractions over the candidates (``weights``, summing to 1), the predicted λ_min of
    ``prior + time × Σ weights·rates`` and the iterations taken."""

    weights: np.ndarray
    value: float
    iterations: int
    history: list[float] = field(default_factory=list)


def e_design(rates: list[np.ndarray], time_s: float, prior: np.ndarray | None = None,
             iterations: int = 400, tol: float = 1e-4) -> Design:
    """Frank–Wolfe on the time fractions maximising λ_min(prior + time_s·Σ ξₑ·ratesₑ) (see the
    module docstring); the step is the best on the segment towards the chosen vertex (golden
    section on the exact λ_min)."""
    R = np.asarray(rates, dtype=float)
    m, p, _ = R.shape
    M0 = np.zeros((p, p)) if prior is None else np.asarray(prior, dtype=float)
    # start from the single best element
    vals = [lambda_min(M0 + time_s * R[e]) for e in range(m)]
    xi = np.zeros(m)
    xi[int(np.argmax(vals))] = 1.0

    def info(x):
        return M0 + time_s * np.tensordot(x, R, axes=1)

    best_xi, best = xi.copy(), lambda_min(info(xi))
    hist = [best]
    it = 0
    for it in range(1, iterations + 1):
        M = info(xi)
        w, V = np.linalg.eigh(0.5 * (M + M.T))
        # the smooth lower bound's sharpness grows over the iterations: early steps see every
        # weak direction, late ones the smallest
        beta = (8.0 + 400.0 * it / iterations) / max(abs(w[0]), 1e-300)

        def smooth(x):
            lam = np.linalg.eigvalsh(0.5 * (info(x) + info(x).T))
            return float(lam[0] - np.log(np.sum(np.exp(-beta * (lam - lam[0])))) / beta)

        a = np.exp(-beta * (w - w[0]))
        a /= a.sum()
        P = (V * a) @ V.T
        grad = time_s * np.einsum("eij,ij->e", R, P)
        e = int(np.argmax(grad))
        gap = grad[e] - grad @ xi
        if gap <= tol * abs(w[0]) * 1e-3:
            break  # the duality gap of the smooth bound: nothing to gain
        active = np.flatnonzero(xi > 0)
        a_ = int(active[np.argmin(grad[active])])
        if grad @ xi - grad[a_] > gap and xi[a_] < 1.0:  # an away step: time off the least useful
            d = xi.copy()
            d[a_] -= 1.0
            g_max = xi[a_] / (1.0 - xi[a_])
        else:  # a Frank–Wolfe step: time to the most useful
            d = -xi.copy()
            d[e] += 1.0
            g_max = 1.0
        lo, hi = 0.0, g_max
        phi = 0.5 * (math.sqrt(5) - 1)
        c1, c2 = hi - phi * (hi - lo), lo + phi * (hi - lo)
        f1, f2 = smooth(xi + c1 * d), smooth(xi + c2 * d)
        for _ in range(25):
            if f1 < f2:
                lo, c1, f1 = c1, c2, f2
                c2 = lo + phi * (hi - lo)
                f2 = smooth(xi + c2 * d)
            else:
                hi, c2, f2 = c2, c1, f1
                c1 = hi - phi * (hi - lo)
                f1 = smooth(xi + c1 * d)
        g = 0.5 * (lo + hi)
        xi = xi + g * d
        xi[xi < 1e-12] = 0.0
        xi /= xi.sum()
        cur = lambda_min(info(xi))
        hist.append(cur)
        if cur > best:
            best_xi, best = xi.copy(), cur
    xi, cur = best_xi, best
    return Design(xi, cur, it, hist)


def repetitions(cands: list[Candidate], weights: np.ndarray, time_s: float, min_share: float = 0.04) -> list[tuple[int, int]]:
    """Whole repetitions of the candidates with a time share of at least ``min_share``: (candidate
    index, repetitions), each at least one, their total duration within ``time_s``; the time
    left after rounding down goes one repetition at a time to the candidate furthest below its
    share."""
    keep = [i for i in np.argsort(-weights) if weights[i] >= min_share]
    if not keep:
        keep = [int(np.argmax(weights))]
    share = np.array([weights[i] for i in keep])
    share /= share.sum()
    d = np.array([cands[i].duration_s for i in keep])
    n = np.maximum(np.floor(share * time_s / d), 1).astype(int)
    while (n * d).sum() > time_s and n.max() > 1:
        j = int(np.argmax(n * d / (share * time_s)))
        if n[j] == 1:
            break
        n[j] -= 1
    while True:
        left = time_s - (n * d).sum()
        room = [j for j in range(len(keep)) if d[j] <= left]
        if not room:
            break
        j = min(room, key=lambda j: n[j] * d[j] / (share[j] * time_s))
        n[j] += 1
    return [(keep[j], int(n[j])) for j in range(len(keep))]


def describe(c: Candidate) -> str:
    p = c.params
    if c.kind in ("figure_eight", "circles"):
        extra = f" R {p['radius_m']:.1f} m" + (f" D {p['spacing_m']:.1f} m" if c.kind == "figure_eight" else "")
        extra += f" stops {int(p.get('stops_per_lap', 0))}" + (" mirrored" if p.get("mirror") else "")
    elif c.kind == "slalom":
        extra = f" d {p['spacing_m']:.1f} m A {p['offset_m']:.1f} m {int(p['cones'])} cones"
    else:
        extra = f" L {p['length_m']:.0f} m"
    return f"{c.kind}{extra} ({c.duration_s:.1f} s)"


def candidates_info(cands: list[Candidate]) -> list[dict[str, Any]]:
    return [{"kind": c.kind, "params": c.params, "duration_s": c.duration_s, "score": c.score} for c in cands]
