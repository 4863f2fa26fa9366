"""Mine long logs for the windows that best determine the calibration.

A log is cut into short chunks of keyframes (``chunk_s``, the window resolution). Each chunk is
sampled, linearised and its inner keyframes eliminated once (:func:`summarise`): what remains is
its *summary*, the information over ``[x_a, x_b, θ]`` (its two end states and the calibration;
:class:`excite.information.elimination.Piece`). Summaries of adjacent chunks combine by eliminating the
state they share, an associative operation, so the information of any window made of whole
chunks follows from its chunks' summaries without touching a factor again. Windows of ``L``
chunks are combined with the two-stack sliding-window scheme: the chunks are grouped in blocks
of ``L``; every window is the suffix of one block joined to the prefix of the next, and all
suffixes and prefixes are built once: about three combinations per window, batched over the log.

**A window is closed exactly as the evaluator closes a drive**, so that its Λ_θ is the
evaluator's on the cropped drive (:func:`crop`: the same trajectory restricted to the window's
keyframes, sampled bit for bit as in the whole): the yaw gauge and the opening factors (a GNSS
antenna's first fix) on its first keyframe, the
non-holonomic constraint at its last keyframe, and the last keyframe's local increment and bias
deviation held at zero (``_chain_end``: with random-walk biases θ's bias columns are the bias at
the window's end). Holding a column at zero is deleting it from the reduced system. The two
agree to rounding (the sums run in another order), which the tests check against
:func:`excite.score.evaluate.evaluate` of the crop.

:func:`mine` scores every window of a given length and finds the shortest window that reaches
a goal (a score, or every parameter's target), by bisection on the window length (a longer
window holds all the factors of a shorter one, so reaching a goal is taken to be monotone in the
length; the exact evaluator confirms every reported window).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..io import remote
from ..score import spectrum
from ..errors import EvaluationError
from ..score.evaluate import evaluate, scaled, scene_of, scored_mask
from ..factors.base import STATE_DIM, Nominal
from ..information.closure import Closure
from ..information.elimination import at_keyframe, piece
from ..information.problem import check_length, columns, frame_step, linearise
from ..core.parallel import n_threads, pool
from ..rig.config import Rig
from ..motion.trajectory import Trajectory

DEFAULT_CHUNK_S = 10.0
CROP_RATE_HZ = 100.0  # poses per second of a TUM crop


@dataclass(frozen=True)
class Summaries:
    """The chunk summaries of one log (see the module docstring).

    ``T[c]`` is chunk ``c``'s information over ``[x_a, x_b, θ]`` (states of dimension ``sd``,
    θ over :func:`excite.information.problem.columns` of one drive); ``opening[c]`` and ``cap[c]`` the
    information a window adds at its first keyframe ``edges[c]`` (the gauge and the opening
    factors of :meth:`~excite.information.closure.Closure.start`, over ``[x_a, θ]``) and at
    its last keyframe ``edges[c + 1]`` (the non-holonomic constraint there, over ``[x_b, θ]``); ``diag_tt[c]``
    diag H_θθ of the chunk before elimination."""

    t0: float  # time of keyframe 0 [s]
    rate_hz: float  # keyframes per second
    edges: np.ndarray  # keyframe of each chunk boundary (C + 1)
    T: np.ndarray  # (C, 2 sd + p, 2 sd + p)
    opening: np.ndarray  # (C, sd + p, sd + p)
    cap: np.ndarray  # (C, sd + p, sd + p)
    diag_tt: np.ndarray  # (C, p)
    length_m: np.ndarray  # (C,)
    sd: int
    free: np.ndarray  # the components of a window's last keyframe that stay free (the closure's)

    @property
    def n_chunks(self) -> int:
        return self.T.shape[0]

    def time(self, k: int) -> float:
        """Time of keyframe ``k`` [s] (the log's own clock)."""
        return self.t0 + k / self.rate_hz


def _chunk_edges(K: int, rig: Rig, chunk_s: float) -> np.ndarray:
    """Chunk boundaries of a drive of ``K`` keyframes: every ``chunk_s`` rounded to a multiple of
    every sensor's frame stride (no factor reaches across a boundary), the last chunk shorter."""
    step = frame_step(rig)
    size = max(step, int(round(chunk_s * rig.keyframe_rate_hz / step)) * step)
    edges = list(range(0, K - 1, size)) + [K - 1]
    if len(edges) > 2 and edges[-1] - edges[-2] < step:  # no sliver of a chunk at the end
        del edges[-2]
    return np.array(edges)


def _A(sd: int, p: int) -> np.ndarray:
    """Indices of ``[x_a, θ]`` in a summary over ``[x_a, x_b, θ]``."""
    return np.r_[0:sd, 2 * sd:2 * sd + p]


def _span(traj: Trajectory, rig: Rig, edges: np.ndarray, p: int, sd: int) -> list[tuple]:
    """The summaries of consecutive chunks ``edges[0] … edges[-1]`` (keyframes of the drive):
    sampled and linearised in one go (little interpreter time per keyframe), then each chunk's
    factors split off and its inner keyframes eliminated. Each chunk is linearised as an inner
    chunk of a drive; what a window starting or ending at its ends adds is kept apart (the gauge
    and the opening factors;
    the non-holonomic constraint at its last keyframe, which the next chunk also holds)."""
    k0 = int(edges[0])
    sub = Nominal.of(traj, rig, keyframes=(k0, int(edges[-1])))
    m = int(edges[-1]) - k0
    closure = Closure.of(rig)
    blocks = [b for b in linearise(sub, rig, closure, last=True, walk=False) if b is not None and b.n_factors]
    if closure.state_dim > STATE_DIM:  # not anchored: a chunk's end is a window's end only sometimes
        blocks.append(closure.walk(m, float(sub.t[1] - sub.t[0])))
    rel = edges - k0
    speed = np.linalg.norm(traj.sample(sub.t).v_W, axis=1)  # the rear axle's, as Nominal.length_m
    length = 0.5 * (speed[1:] + speed[:-1]) * np.diff(sub.t)  # per keyframe interval
    out = []
    for a, e in zip(rel[:-1], rel[1:]):
        own = [b.select((b.first >= a) & (b.first < e)).shifted(-a) for b in blocks]
        cap = [b.select(b.first == e).shifted(-e) for b in blocks if b.n_states == 1]  # one-keyframe factors
        pc = piece([b for b in own if b.n_factors], k0 + a, k0 + e, p, sd)
        T = np.zeros((2 * sd + p,) * 2)  # over [x_a, x_b, θ]; the kernels keep H_bb's lower triangle only
        T[np.ix_(_A(sd, p), _A(sd, p))] = pc.H_ee
        T[sd:2 * sd, sd:2 * sd] = np.tril(pc.H_bb) + np.tril(pc.H_bb, -1).T
        T[sd:2 * sd, _A(sd, p)] = pc.H_be
        T[_A(sd, p), sd:2 * sd] = pc.H_be.T
        opening = at_keyframe(closure.start(sub.window(a, e), rig), sd, p)
        out.append((T, opening, at_keyframe(cap, sd, p), pc.diag_tt, float(length[a:e].sum())))
    return out


_SPAN_KEYFRAMES = 2000  # keyframes linearised in one go at most


def summarise(traj: Trajectory, rig: Rig, chunk_s: float = DEFAULT_CHUNK_S) -> Summaries:
    """The chunk summaries of ``traj`` (chunks of about ``chunk_s`` seconds; spans of chunks on
    the thread pool)."""
    if not (math.isfinite(chunk_s) and chunk_s > 0):
        raise EvaluationError(f"chunk_s must be a duration > 0 s, got {chunk_s}")
    t0, K = Nominal.grid(traj, rig)
    check_length(K, rig)
    edges = _chunk_edges(K, rig, chunk_s)
    p = len(columns(rig, 1)[0])
    sd = Closure.of(rig).state_dim
    C = edges.size - 1  # as many spans as a multiple of the thread count: every thread an equal share
    n_spans = -(-max(1, -(-(K - 1) // _SPAN_KEYFRAMES)) // n_threads()) * n_threads()
    per_span = max(1, -(-C // n_spans))
    spans = [edges[i:i + per_span + 1] for i in range(0, edges.size - 1, per_span)]
    parts = [x for span in pool().map(lambda e: _span(traj, rig, e, p, sd), spans) for x in span]
    T, opening, cap, diag_tt, length = (np.array(x) for x in zip(*parts))
    return Summaries(t0, rig.keyframe_rate_hz, edges, T, opening, cap, diag_tt, length, sd, Closure.of(rig).free())


def _join(T1: np.ndarray, T2: np.ndarray, sd: int) -> np.ndarray:
    """Summaries of windows ``a … m`` and ``m … b`` (stacks) joined into ``a … b``: x_m eliminated."""
    n, q, _ = T1.shape
    A, B, Th = slice(0, sd), slice(sd, 2 * sd), slice(2 * sd, q)
    M = T1[:, B, B] + T2[:, A, A]
    C = np.empty((n, q, sd))  # [x_a, x_b, θ] × x_m
    C[:, A] = T1[:, A, B]
    C[:, B] = T2[:, B, A]
    C[:, Th] = T1[:, Th, B] + T2[:, Th, A]
    out = np.zeros((n, q, q))
    out[:, A, A] = T1[:, A, A]
    out[:, A, Th] = T1[:, A, Th]
    out[:, Th, A] = T1[:, Th, A]
    out[:, B, B] = T2[:, B, B]
    out[:, B, Th] = T2[:, B, Th]
    out[:, Th, B] = T2[:, Th, B]
    out[:, Th, Th] = T1[:, Th, Th] + T2[:, Th, Th]
    out -= C @ np.linalg.solve(M, np.swapaxes(C, 1, 2))
    return 0.5 * (out + np.swapaxes(out, 1, 2))


def _close(T: np.ndarray, opening: np.ndarray, cap: np.ndarray, sd: int, free: np.ndarray) -> np.ndarray:
    """Λ_θ of windows from their summaries: the gauge and the opening factors at the first keyframe, the constraint at
    the last, whose increment and bias deviation are held at zero (deleted); both states eliminated."""
    T = T.copy()
    A = _A(sd, T.shape[1] - 2 * sd)
    T[:, A[:, None], A] += opening
    T[:, sd:, sd:] += cap
    x = np.r_[0:sd, sd + free]  # the last keyframe: what stays free of it
    th = np.arange(2 * sd, T.shape[1])
    Exx = T[:, x[:, None], x]
    Etx = T[:, th[:, None], x]
    Lam = T[:, th[:, None], th] - Etx @ np.linalg.solve(Exx, np.swapaxes(Etx, 1, 2))
    return 0.5 * (Lam + np.swapaxes(Lam, 1, 2))


def window_information(s: Summaries, L: int, first: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Λ_θ (over :func:`excite.information.problem.columns`) of every window of ``L`` consecutive chunks,
    in order of their first chunk, and each one's diag H_θθ (two-stack scheme: module docstring);
    with ``first``, of the one window that starts at chunk ``first``."""
    if first is not None:
        T = s.T[first]
        for c in range(first + 1, first + L):
            T = _join(T[None], s.T[c][None], s.sd)[0]
        return (_close(T[None], s.opening[first][None], s.cap[first + L - 1][None], s.sd, s.free),
                (s.diag_tt[first:first + L].sum(axis=0) + _cap_diag(s.cap[first + L - 1], s.sd)
                 + _cap_diag(s.opening[first], s.sd))[None])
    C, sd = s.n_chunks, s.sd
    if not 1 <= L <= C:
        raise EvaluationError(f"a window of {L} chunks does not fit a log of {C}")
    suf, pre = s.T.copy(), s.T.copy()
    for r in range(L - 2, -1, -1):  # suffixes within each block of L chunks, right to left
        i = np.arange(r, C - 1, L)
        i = i[(i + 1) % L != 0]
        if i.size:
            suf[i] = _join(s.T[i], suf[i + 1], sd)
    for r in range(1, L):  # prefixes within each block, left to right
        j = np.arange(r, C, L)
        pre[j] = _join(pre[j - 1], s.T[j], sd)
    starts = np.arange(C - L + 1)
    ends = starts + L - 1
    W = suf[starts].copy()
    split = starts % L != 0
    if split.any():
        W[split] = _join(suf[starts[split]], pre[ends[split]], sd)
    csum = np.vstack([np.zeros(s.diag_tt.shape[1]), np.cumsum(s.diag_tt, axis=0)])
    return (_close(W, s.opening[starts], s.cap[ends], sd, s.free),
            csum[ends + 1] - csum[starts] + _cap_diag(s.cap[ends], sd) + _cap_diag(s.opening[starts], sd))


def _cap_diag(cap: np.ndarray, sd: int) -> np.ndarray:
    """diag H_θθ of what a window adds at one keyframe over ``[x, θ]`` (the constraint at its last
    keyframe: its slip-angle column; the opening factors at its first)."""
    return np.diagonal(cap[..., sd:, sd:], axis1=-2, axis2=-1)


@dataclass
class Window:
    """One window of a log and what it determines. Times on the log's own clock."""

    log: str
    start_s: float
    end_s: float
    score: float
    passed: bool  # every parameter's σ within its target
    kind: str  # "best" (of the given length) | "shortest" (reaching the goal)
    sigma: dict[str, float | None]  # Cramér–Rao σ per scored parameter (SI; None: unobservable)
    misses: list[str]  # parameters whose σ is above target (or unobservable), worst first
    length_m: float = 0.0
    confirmed_score: float | None = None  # the exact evaluator's on the crop
    path: str = ""

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "duration_s": self.duration_s}


@dataclass
class LogResult:
    """What :func:`mine` found in one log: its best windows, the shortest window reaching the
    goal (None when even the whole log does not), or the error that kept it from being mined."""

    log: str
    path: str
    duration_s: float = 0.0
    windows_evaluated: int = 0
    best: list[Window] = field(default_factory=list)
    shortest: Window | None = None
    whole_score: float | None = None  # the whole log's (the best any window can reach)
    error: str | None = None
    seconds: float = 0.0
    scene: dict[str, str] | None = None  # the scene it was mined in, as a report names it


@dataclass(frozen=True)
class Goal:
    """What the shortest window must reach: ``min_score`` (score ≥ it) or, when None, every
    parameter's target (the report's ``passed``)."""

    min_score: float | None = None

    def met(self, score: np.ndarray, passed: np.ndarray) -> np.ndarray:
        """Which windows (their scores and ``passed``) reach the goal."""
        return passed if self.min_score is None else score >= self.min_score

    def describe(self) -> str:
        return "every target" if self.min_score is None else f"score ≥ {self.min_score:g}"


def _analysed(rig: Rig, Lam: np.ndarray, diag: np.ndarray) -> tuple[float, np.ndarray]:
    """(score, σ per scored coordinate) of one window, as :func:`excite.score.evaluate.evaluate`."""
    Ls, _ = scaled(rig, Lam)
    S = np.array([c.target for c in rig.scored])
    spec = spectrum.analyse(Ls, diag[scored_mask(rig, diag.size)], S)
    return spec.score, spec.sigma


def _window(rig: Rig, log: str, s: Summaries, c0: int, c1: int, kind: str) -> Window:
    """Window of chunks ``c0 … c1``, analysed in full (:func:`excite.score.spectrum.analyse`)."""
    Lam, diag = window_information(s, c1 - c0 + 1, first=c0)
    score, sigma = _analysed(rig, Lam[0], diag[0])
    coords = list(rig.scored)
    sig = {c.name: None if np.isnan(x) else float(x) for c, x in zip(coords, sigma)}
    ratio = {c.name: math.inf if np.isnan(x) else x / c.target for c, x in zip(coords, sigma)}
    misses = sorted((n for n, r in ratio.items() if r > 1), key=lambda n: -ratio[n])
    return Window(log, s.time(int(s.edges[c0])), s.time(int(s.edges[c1 + 1])), float(score), not misses, kind,
                  sig, misses, float(s.length_m[c0:c1 + 1].sum()))


def batch_scores(rig: Rig, Lam_all: np.ndarray, diag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Score and ``passed`` (every σ within its target) of a stack of windows at once: what
    :func:`excite.score.spectrum.analyse` finds, without its null-space basis (a window with any
    unobservable direction scores 0 and does not pass). The tests hold the two equal."""
    scored = scored_mask(rig, Lam_all.shape[1])
    nu = ~scored
    Lam = Lam_all[:, scored][:, :, scored]
    if nu.any():  # the nuisances' Schur complement, as evaluate._marginalise_nuisance
        B = Lam_all[:, scored][:, :, nu]
        Cm = Lam_all[:, nu][:, :, nu]
        dn = np.sqrt(np.maximum(np.diagonal(Cm, axis1=1, axis2=2), 1e-300))
        X = np.linalg.pinv(Cm / (dn[:, :, None] * dn[:, None, :]), rcond=1e-12, hermitian=True)
        Bd = B / dn[:, None, :]
        Lam = Lam - Bd @ X @ np.swapaxes(Bd, 1, 2)
    Lam = 0.5 * (Lam + np.swapaxes(Lam, 1, 2))
    h = diag[:, scored]
    carries = h > spectrum.INFORMATION_FLOOR * np.maximum(h.max(axis=1, keepdims=True), 1e-300)
    d = 1.0 / np.sqrt(np.where(carries, h, 1.0))
    wN, U = np.linalg.eigh(Lam * d[:, :, None] * d[:, None, :])
    full = carries.all(axis=1) & (wN[:, 0] >= spectrum.RANK_RTOL)
    S = np.array([c.target for c in rig.scored])
    score = np.where(full, np.linalg.eigvalsh(Lam * np.outer(S, S))[:, 0], 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = d * np.sqrt(np.einsum("nik,nk->ni", U ** 2, 1.0 / wN))
    passed = full & np.all(sigma <= S, axis=1)
    return score, passed


def scores(rig: Rig, s: Summaries, L: int) -> tuple[np.ndarray, np.ndarray]:
    """Score and ``passed`` of every window of ``L`` chunks (:func:`batch_scores`)."""
    return batch_scores(rig, *window_information(s, L))


def best_windows(scored: np.ndarray, L: int, n: int) -> list[int]:
    """First chunks of the ``n`` best windows of ``L`` chunks that do not overlap (greedy)."""
    taken = np.zeros(scored.size + L, dtype=bool)
    out = []
    for i in np.argsort(-scored, kind="stable"):
        if not taken[i:i + L].any():
            out.append(int(i))
            taken[i:i + L] = True
            if len(out) == n:
                break
    return out


def mine(traj: Trajectory, rig: Rig, window_s: float, goal: Goal | None = None, per_log: int = 1,
         chunk_s: float = DEFAULT_CHUNK_S, confirm: bool = True, log: str | None = None) -> LogResult:
    """The best ``per_log`` non-overlapping windows of ``window_s`` (rounded to whole chunks) of
    ``traj`` and, with a ``goal``, the shortest window that reaches it; each confirmed by the
    exact evaluator on its crop when ``confirm``."""
    import time

    if not (math.isfinite(window_s) and window_s > 0):
        raise EvaluationError(f"window must be a duration > 0 s, got {window_s}")
    c0 = time.perf_counter()
    log = log or traj.name
    s = summarise(traj, rig, chunk_s)
    C = s.n_chunks
    L = min(C, max(1, math.floor(window_s / chunk_s + 0.5)))  # half up: 25 s of 10 s chunks are 3
    sc, _ = scores(rig, s, L)
    res = LogResult(log, "", duration_s=s.time(int(s.edges[-1])) - s.t0, windows_evaluated=sc.size)
    res.best = [_window(rig, log, s, i, i + L - 1, "best") for i in best_windows(sc, L, per_log)]
    if goal is not None:
        whole = scores(rig, s, C)
        res.whole_score = float(whole[0][0])
        res.windows_evaluated += 1
        if goal.met(*whole)[0]:
            lo, hi = 0, C  # no window of lo chunks reaches the goal, one of hi does
            found = whole
            while hi - lo > 1:
                mid = (lo + hi) // 2
                sc_m = scores(rig, s, mid)
                res.windows_evaluated += sc_m[0].size
                if goal.met(*sc_m).any():
                    hi, found = mid, sc_m
                else:
                    lo = mid
            ok = goal.met(*found)
            i = int(np.flatnonzero(ok)[np.argmax(found[0][ok])])
            res.shortest = _window(rig, log, s, i, i + hi - 1, "shortest")
    if confirm:
        for w in res.best + ([res.shortest] if res.shortest else []):
            w.confirmed_score = evaluate(crop(traj, w.start_s, w.end_s), rig).score
    res.seconds = time.perf_counter() - c0
    return res


def crop(traj: Trajectory, start_s: float, end_s: float) -> Trajectory:
    """The drive restricted to a window (times on its clock, at keyframes of its grid): what the
    exact evaluator is given to confirm a window."""
    return traj.cropped(start_s, min(end_s, traj.t_end), name=f"{traj.name} [{start_s:.1f}, {end_s:.1f}] s")


# --------------------------------------------------------------------------------------------
# Fleets: one task per log, on the engine (local processes or a Dask cluster)


@dataclass(frozen=True)
class Task:
    """What one engine task mines: a route (read where the task runs) and the mining settings."""

    spec: Any  # excite.fleet.batch.RouteSpec
    window_s: float
    goal: Goal | None = None
    per_log: int = 1
    chunk_s: float = DEFAULT_CHUNK_S


def mine_task(task: Task) -> LogResult:
    """Mine one log of a fleet; never raises: a log that cannot be read or mined comes back with
    its ``error`` (as :func:`excite.fleet.batch.evaluate_spec`)."""
    import time

    from .batch import error_text, load

    t0 = time.perf_counter()
    spec = task.spec
    if spec.error is not None:
        return LogResult(spec.name, spec.path, error=spec.error)
    try:
        rig, traj = load(spec)
        res = mine(traj, rig, task.window_s, task.goal, task.per_log, task.chunk_s, log=spec.name)
    except Exception as exc:
        return LogResult(spec.name, spec.path, error=error_text(exc, spec.path)[0],
                         seconds=time.perf_counter() - t0)
    res.path = spec.path
    res.scene = scene_of([traj])
    for w in res.best + ([res.shortest] if res.shortest else []):
        w.path = spec.path
    return res


def _lost(task: Task, exc: BaseException) -> LogResult:
    return LogResult(task.spec.name, task.spec.path, error=f"worker failed: {type(exc).__name__}: {exc}")


def mine_logs(tasks: list[Task], jobs: int | None = None, scheduler: str | None = None,
              on_result: Callable[[LogResult, Any], None] | None = None) -> list[LogResult]:
    """Mine every log on the engine (:func:`excite.core.engine.run`); results in the order of ``tasks``."""
    from ..core import engine

    return engine.run(mine_task, tasks, failed=_lost, jobs=jobs, scheduler=scheduler,
                      on_result=None if on_result is None else (lambda i, r, pr: on_result(r, pr)))


def ranked(results: list[LogResult]) -> tuple[list[Window], list[Window]]:
    """(best windows of every log, best score first; shortest windows reaching the goal,
    shortest first, then by score)."""
    best = sorted((w for r in results for w in r.best), key=lambda w: -w.score)
    shortest = sorted((r.shortest for r in results if r.shortest), key=lambda w: (w.duration_s, -w.score))
    return best, shortest


CSV_COLUMNS = ("log", "start_s", "end_s", "duration_s", "score", "confirmed_score", "passed", "kind",
               "length_m", "misses", "path")


def windows_csv(windows: list[Window]) -> str:
    """The windows as CSV (``log,start_s,end_s,...``; ``misses`` separated by ``;``)."""
    import csv
    import io

    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for x in windows:
        d = x.to_dict()
        w.writerow([";".join(d[c]) if c == "misses" else
                    "" if d[c] is None else repr(d[c]) if isinstance(d[c], float) else d[c]
                    for c in CSV_COLUMNS])
    return out.getvalue()


def results_json(results: list[LogResult], window_s: float, goal: Goal | None) -> dict[str, Any]:
    """Everything :func:`mine_logs` found, as JSON data: the ranked windows and each log's outcome."""
    best, shortest = ranked(results)
    return {"version": 1, "window_s": window_s, "goal": None if goal is None else goal.describe(),
            "best": [w.to_dict() for w in best], "shortest": [w.to_dict() for w in shortest],
            "logs": [{"log": r.log, "path": r.path, "duration_s": r.duration_s,
                      "windows_evaluated": r.windows_evaluated, "whole_score": r.whole_score,
                      "reached": None if goal is None else r.shortest is not None,
                      "error": r.error, "seconds": r.seconds, "scene": r.scene} for r in results]}


def write_crop(window: Window, spec: Any, folder: str | Path) -> list[Path]:
    """The crop of ``window`` of the log ``spec`` (a :class:`excite.fleet.batch.RouteSpec`) in
    ``folder``: its TUM poses and, for a bag, the bag cut to the window. Returns the files."""
    from ..io.bags import crop_bag, is_bag
    from .batch import load
    from ..io.routes import write_tum

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    name = remote.name_of(spec.path) if remote.is_url(spec.path) else str(spec.path)
    stem = f"{Path(name).stem or Path(name).name}_{window.start_s:.1f}-{window.end_s:.1f}s"
    with remote.local(spec.path) as path:  # a URL is fetched once, for the route and the bag
        _, traj = load(replace(spec, path=path), see=False)
        tum = folder / f"{stem}.tum"
        write_tum(crop(traj, window.start_s, window.end_s), tum, rate_hz=CROP_RATE_HZ)
        out = [tum]
        if is_bag(path):
            out.append(crop_bag(path, folder / f"{stem}{'.bag' if name.endswith('.bag') else ''}",
                                window.start_s, window.end_s, spec.topic))
    return out
