"""Live guidance during the calibration drive: the marginal information of the calibration as
the keyframes come in, per-parameter progress to target, advice, and a ``done`` event.

Three layers, each usable alone:

- :class:`Incremental` runs the evaluator's elimination forward. A chunk of keyframes is
  appended (a :class:`~excite.factors.base.Nominal` that starts at the previous chunk's last
  keyframe), linearised and its inner keyframes eliminated exactly as the batch evaluator does a
  chunk (:func:`excite.information.elimination.piece`); the running state is the Schur complement on
  ``[x_end, θ]``, into which each new piece is folded by eliminating the old end keyframe.
  :meth:`Incremental.information` closes the drive "so far" the way the batch evaluator closes a
  drive at its last keyframe: the one-keyframe factors at the end keyframe (the non-holonomic constraint) are added, its
  increment (it has no successor yet) and, with random-walk biases, its bias deviation (θ's bias
  columns are the bias at the end of the drive) are held at zero, and the rest of ``x_end`` is
  eliminated. Cost and memory per update are constant (matrices of the state and parameter
  size); the past is never revisited. On a whole drive the result is the batch evaluator's.
- :class:`Guide` turns the information so far into an update: the report
  (:func:`excite.score.evaluate.report_of`), per parameter σ/target, "% of target reached"
  (target/σ, capped at 100 %), an ETA at the information rate of the last ``window_s``, the
  motion a parameter still needs in the vehicle's words (:func:`excite.score.advice.needs`), the
  weakest direction, and ``done``: once every parameter is within target (``passed``), or, with
  ``passed`` false, when nothing more is gained from the motion so far — every parameter not
  within target has needed other motion (no gain, or an ETA past ``horizon_s``) at every update
  of a whole ``window_s``. That one says which parameters need which motion; it fires again only
  after some parameter has gained again (the driver changed the motion) and then nothing has for
  a whole window.
- :class:`PoseStream` turns timed poses arriving one by one into keyframe chunks. Batch
  evaluation fits smoothing splines to a whole file (:func:`excite.io.poses.trajectory_from_poses`),
  so a pose's fitted value depends (exponentially weakly) on every later pose: a stream can only
  approximate it. A chunk of keyframes is committed once the poses reach ``lookahead_s`` past its
  end, from the same fit restricted to the poses within ``lookahead_s`` on either side (the
  smoothing kernel's reach at 1 Hz cutoff is ~0.2 s; the latency is ``lookahead_s`` + a chunk).
  When the source ends, :meth:`PoseStream.finish` fits the kept poses the batch way and evaluates
  them once: the final update *is* ``excite score`` of the same poses. Memory: the poses
  themselves (13 numbers each: 3.7 MB for an hour at 10 Hz) and a constant state.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np
import scipy.linalg as sla

from . import advice
from ..core import bounds
from ..errors import EvaluationError, RouteError
from .evaluate import Options, Report, evaluate, report_of
from ..factors.base import Nominal
from ..factors.base import STATE_DIM
from ..information.closure import Closure
from ..information.elimination import DriveInformation, Piece, at_keyframe, piece
from ..information.problem import columns, frame_step, linearise
from ..rig.config import Rig
from ..io.poses import DEFAULT_CUTOFF_HZ, MIN_POSES, trajectory_from_poses
from ..motion.trajectory import Trajectory

CHUNK_S = 1.0  # drive time per appended chunk of keyframes (and so per update)
LOOKAHEAD_S = 5.0  # poses a stream waits for past a chunk before committing it
RATE_WINDOW_S = 30.0  # the information rate behind an ETA is measured over this much drive time
HORIZON_S = 3600.0  # a parameter whose ETA lies beyond this needs other motion
MAX_CHUNKS_PER_FIT = 60  # poses that arrive at once are fitted in windows of at most this many chunks


class Incremental:
    """The marginal information of the calibration of one drive, keyframe chunk by chunk (see
    the module docstring). Append chunks with :meth:`append`; read :meth:`information`."""

    def __init__(self, rig: Rig):
        self.rig = rig
        names, self.nuisance = columns(rig, 1)
        self.p = len(names)
        self.closure = Closure.of(rig)
        self.sd = self.closure.state_dim
        self.step = frame_step(rig)
        self.n_keyframes = 0  # keyframes so far (0 before the first chunk)
        self.length_m = 0.0
        self.t_end = None  # time of the last keyframe
        self._state: np.ndarray | None = None  # Schur complement on [x_end, θ]
        self._end_caps: list = []  # the one-keyframe factors at the end keyframe (they close the drive)
        self._diag_tt = np.zeros(self.p)
        self.thread_ms = {"sample": 0.0, "linearise": 0.0, "eliminate": 0.0}

    def append(self, nom: Nominal) -> None:
        """Keyframes ``n_keyframes − 1 … n_keyframes − 1 + m`` (the first is the previous end
        keyframe, or the drive's first), ``m`` a positive multiple of every sensor's frame
        stride, so that each factor falls in exactly one chunk."""
        m = nom.n_keyframes - 1
        if m < 1 or m % self.step:
            raise EvaluationError(f"a chunk must span a positive multiple of {self.step} keyframe "
                                  f"intervals (every sensor's frame stride), got {m}")
        c0 = time.perf_counter()
        first = self._state is None
        blocks, end_caps = [], []
        for b in linearise(nom, self.rig, self.closure, last=True, walk=False):
            if b is None or not b.n_factors:
                continue
            if b.n_states == 1:  # a one-keyframe factor at the chunk's end belongs to the next chunk
                end_caps.append(b.select(b.first == m).shifted(-m))
                b = b.select(b.first < m)
            blocks.append(b)
        if self.sd > STATE_DIM:  # the walk into the end keyframe is not anchored yet
            blocks.append(self.closure.walk(m, float(nom.t[1] - nom.t[0])))
        if first:
            blocks += self.closure.start(nom, self.rig)
        c1 = time.perf_counter()
        a = max(self.n_keyframes - 1, 0)
        pc = piece([b for b in blocks if b.n_factors], a, a + m, self.p, self.sd)
        self._state = self._fold(pc)
        self._end_caps = [b for b in end_caps if b.n_factors]
        self._diag_tt += pc.diag_tt
        self.n_keyframes = a + m + 1
        self.length_m += nom.length_m
        self.t_end = float(nom.t[-1])
        c2 = time.perf_counter()
        self.thread_ms["linearise"] += (c1 - c0) * 1e3
        self.thread_ms["eliminate"] += (c2 - c1) * 1e3

    def _fold(self, piece: Piece) -> np.ndarray:
        """The state on ``[x_b, θ]`` after ``piece`` (over ``[x_a, θ]`` and ``x_b``) joins the
        state on ``[x_a, θ]``: the old end keyframe x_a eliminated."""
        sd, p = self.sd, self.p
        A = piece.H_ee if self._state is None else self._state + piece.H_ee
        # [x_a | θ, x_b]: eliminate x_a
        B = np.hstack([A[:sd, sd:], piece.H_be[:, :sd].T])
        C = np.zeros((p + sd, p + sd))
        C[:p, :p] = A[sd:, sd:]
        C[:p, p:] = piece.H_be[:, sd:].T
        C[p:, :p] = piece.H_be[:, sd:]
        C[p:, p:] = piece.H_bb
        C -= B.T @ _solve(A[:sd, :sd], B, piece.a)
        out = np.empty_like(C)  # reorder to [x_b, θ]
        out[:sd, :sd] = C[p:, p:]
        out[:sd, sd:] = C[p:, :p]
        out[sd:, :sd] = C[:p, p:]
        out[sd:, sd:] = C[:p, :p]
        return 0.5 * (out + out.T)

    def information(self) -> DriveInformation:
        """Λ_θ of the drive so far, closed at its last keyframe as the batch evaluator closes a
        drive (see the module docstring)."""
        if self._state is None or self.n_keyframes < 3:
            raise EvaluationError(f"the drive is too short: {self.n_keyframes} keyframes, need at least 3")
        sd = self.sd
        H = self._state.copy()
        diag_tt = self._diag_tt.copy()
        if self._end_caps:
            cap = at_keyframe(self._end_caps, sd, self.p)
            H += cap
            diag_tt += np.diag(cap)[sd:]
        free = self.closure.free()
        n = free.size
        keep = np.r_[free, sd:sd + self.p]  # what stays free of x_end, then θ
        H = H[np.ix_(keep, keep)]
        Lam = H[n:, n:] - H[n:, :n] @ _solve(H[:n, :n], H[:n, n:], self.n_keyframes - 1)
        return DriveInformation(
            information=0.5 * (Lam + Lam.T), diag_tt=diag_tt, nuisance=self.nuisance,
            n_keyframes=self.n_keyframes, duration_s=(self.n_keyframes - 1) / self.rig.keyframe_rate_hz,
            length_m=self.length_m, thread_ms=dict(self.thread_ms))


def _solve(A: np.ndarray, B: np.ndarray, keyframe: int) -> np.ndarray:
    try:
        return sla.cho_solve(sla.cho_factor(A, lower=True, check_finite=False), B, check_finite=False)
    except np.linalg.LinAlgError:
        raise EvaluationError(f"the trajectory itself is undetermined by this rig's sensors (the "
                              f"information of keyframe {keyframe} is singular beyond the gauge)") from None


def chunk_keyframes(rig: Rig, chunk_s: float = CHUNK_S) -> int:
    """Keyframe intervals per chunk: about ``chunk_s`` of drive, a multiple of every sensor's
    frame stride."""
    step = frame_step(rig)
    return max(step, int(round(chunk_s * rig.keyframe_rate_hz / step)) * step)


def chunks(traj: Trajectory, rig: Rig, chunk_s: float = CHUNK_S) -> Iterator[Nominal]:
    """A trajectory's keyframes as the chunks a live drive would append (the batch evaluator's
    samples, bit for bit: :meth:`Nominal.of`); a last chunk shorter than the others ends it."""
    _, K = Nominal.grid(traj, rig)
    m, step = chunk_keyframes(rig, chunk_s), frame_step(rig)
    k0 = 0
    while k0 + step <= K - 1:
        k1 = min(k0 + m, k0 + (K - 1 - k0) // step * step)
        yield Nominal.of(traj, rig, keyframes=(k0, k1))
        k0 = k1


# --- what the driver is told -------------------------------------------------------------------


class Guide:
    """Updates from the information so far (see the module docstring). One guide per drive: it
    remembers the recent information for the rates behind the ETAs, and whether ``done`` fired."""

    def __init__(self, rig: Rig, options: Options = Options(), window_s: float = RATE_WINDOW_S,
                 horizon_s: float = HORIZON_S, name: str = "live", scene: dict[str, str] | None = None):
        self.rig, self.options, self.window_s, self.horizon_s, self.name = rig, options, window_s, horizon_s, name
        self.scene = scene  # the scene the drive is seen in, as reports name it (excite.score.evaluate.scene_of)
        self.done = False  # every parameter was within target at some update
        self._stalled = False  # a "nothing more to gain" done fired, and nothing has gained since
        self._gained_s = 0.0  # drive time of the last update at which some parameter was gaining
        self._history: deque[tuple[float, np.ndarray]] = deque()

    def update(self, drive: DriveInformation, elapsed_s: float | None = None) -> list[dict[str, Any]]:
        """The update for ``drive``, followed by a ``done`` event the first time every parameter
        is within target, or when nothing more is gained from the motion so far (see the module
        docstring). ``elapsed_s``: drive time (default: the keyframes' duration)."""
        rep = report_of(drive, self.rig, self.options, route=self.name, scene=self.scene)
        t = drive.duration_s if elapsed_s is None else elapsed_s
        upd = self.describe(rep, t)
        out = [upd]
        status = [p["status"] for p in upd["parameters"]]
        if "gaining" in status:
            self._stalled, self._gained_s = False, t
        if rep.passed:
            if not self.done:
                self.done = True
                out.append({"type": "done", "t_s": t, "passed": True,
                            "reason": "every parameter is within its target", "score": rep.score})
        elif not self._stalled and "gaining" not in status and t - self._gained_s >= self.window_s:
            self._stalled = True
            needs = [{"name": p["name"], "advice": p["advice"]} for p in upd["parameters"] if p["status"] == "needs"]
            out.append({"type": "done", "t_s": t, "passed": False, "score": rep.score, "needs": needs,
                        "reason": f"nothing more to gain from the motion so far: {len(needs)} of "
                                  f"{len(status)} parameters need other motion"})
        return out

    def describe(self, rep: Report, t: float, kind: str = "update") -> dict[str, Any]:
        gained = np.array([0.0 if p.sigma is None else 1.0 / p.sigma ** 2 for p in rep.parameters])
        self._history.append((t, gained))
        while len(self._history) > 2 and self._history[1][0] <= t - self.window_s:
            self._history.popleft()
        t_then, then = self._history[0]
        rate = (gained - then) / (t - t_then) if t > t_then else np.zeros_like(gained)
        coords = {c.name: c for c in self.rig.scored}
        params = []
        for i, p in enumerate(rep.parameters):
            need = 1.0 / p.target ** 2
            eta = None if p.ok else ((need - gained[i]) / rate[i] if rate[i] > 0 else None)
            if p.ok:
                status = "ok"
            elif t <= t_then:  # no rate yet: only an unobservable parameter is known to need other motion
                status = "needs" if p.sigma is None else "gaining"
            else:
                status = "gaining" if eta is not None and eta <= self.horizon_s else "needs"
            params.append({
                "name": p.name, "unit": p.unit, "sigma": p.sigma, "target": p.target,
                "progress": 0.0 if p.sigma is None else float(min(1.0, p.target / p.sigma)),
                "eta_s": None if eta is None else float(eta), "status": status,
                "advice": None if p.ok else advice.needs(self.rig, coords[p.name])})
        weakest = None
        if rep.weak_modes and not rep.passed:
            mode = rep.weak_modes[0]
            names = [n for n, _ in mode.coordinates]
            weakest = {"coordinates": [[n, w] for n, w in mode.coordinates],
                       "sigma_in_targets": mode.sigma_in_targets,
                       "advice": advice.describe(self.rig, [coords[n] for n in names],
                                                 np.array([w for _, w in mode.coordinates]), advice.DRIVER),
                       "detail": mode.advice}
        return {"type": kind, "t_s": float(t), "n_keyframes": rep.n_keyframes,
                "duration_s": rep.duration_s, "length_m": rep.length_m, "score": rep.score,
                "passed": rep.passed, "parameters": params, "weakest": weakest, "scene": rep.scene}


# --- poses in ----------------------------------------------------------------------------------


@dataclass
class _Poses:
    """Timed poses kept for the final fit: t (n), p (n, 3), R (n, 3, 3), grown by doubling."""

    t: np.ndarray
    p: np.ndarray
    R: np.ndarray
    n: int = 0

    @classmethod
    def empty(cls) -> "_Poses":
        return cls(np.empty(64), np.empty((64, 3)), np.empty((64, 3, 3)))

    def add(self, t: np.ndarray, p: np.ndarray, R: np.ndarray) -> None:
        need = self.n + t.size
        if need > self.t.size:
            size = max(need, 2 * self.t.size)
            for name in ("t", "p", "R"):
                old = getattr(self, name)
                new = np.empty((size,) + old.shape[1:])
                new[:self.n] = old[:self.n]
                setattr(self, name, new)
        self.t[self.n:need], self.p[self.n:need], self.R[self.n:need] = t, p, R
        self.n = need

    def since(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        i, j = np.searchsorted(self.t[:self.n], [t0, t1], side="left")
        j = min(self.n, j + 1)
        return self.t[i:j], self.p[i:j], self.R[i:j]


class PoseStream:
    """Timed poses of the vehicle frame V in, updates out (see the module docstring).

    :meth:`add` takes poses in time order and returns the update (and ``done``) of the drive
    so far if they completed a chunk (one update per call: a drive that delivers its poses about
    once a second gets about one update a second; a replay that delivers many seconds at once
    gets one for them all); :meth:`finish` ends the drive and returns the final update, which is the batch
    evaluator's on the same poses (``type`` ``"final"``, with the whole report).

    ``scene``: the scene the drive is in (:mod:`excite.scene`): each committed chunk is seen in it
    (:func:`excite.scene.along.seen` of the fit over the chunk: its scans are placed from the
    chunk's start, where the batch evaluator places them from the drive's), and so is the
    final fit."""

    def __init__(self, rig: Rig, *, name: str = "live", lookahead_s: float = LOOKAHEAD_S,
                 cutoff_hz: float = DEFAULT_CUTOFF_HZ, options: Options = Options(), scene: Any = None):
        if not lookahead_s > 0:
            raise EvaluationError(f"lookahead_s must be positive, got {lookahead_s!r}")
        self.rig, self.name, self.lookahead_s, self.cutoff_hz, self.options = rig, name, lookahead_s, cutoff_hz, options
        self.scene = scene
        self.incremental = Incremental(rig)
        self.guide = Guide(rig, options, name=name,
                           scene=None if scene is None else {"name": scene.source, "digest": scene.digest})
        self._poses = _Poses.empty()
        self._m = chunk_keyframes(rig)
        self._k = 0  # keyframes committed: the next chunk starts at keyframe _k (or 0)
        self.finished = False

    @property
    def n_poses(self) -> int:
        return self._poses.n

    def _time(self, k: int) -> float:
        return float(self._poses.t[0] + k / self.rig.keyframe_rate_hz)

    def add(self, t: np.ndarray, p: np.ndarray, R: np.ndarray) -> list[dict[str, Any]]:
        """Poses at times ``t`` (n), positions ``p`` (n, 3) [m], orientations ``R`` (n, 3, 3)."""
        if self.finished:
            raise EvaluationError("the drive has ended: no more poses")
        t, p, R = np.asarray(t, float).reshape(-1), np.asarray(p, float).reshape(-1, 3), np.asarray(R, float).reshape(-1, 3, 3)
        if not (t.size == p.shape[0] == R.shape[0]):
            raise RouteError(f"{t.size} times for {p.shape[0]} positions and {R.shape[0]} orientations")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p)) and np.all(np.isfinite(R))):
            raise RouteError("a pose is not finite")
        last = self._poses.t[self._poses.n - 1] if self._poses.n else -np.inf
        if t.size and np.any(np.diff(np.concatenate([[last], t])) <= 0):
            raise RouteError("pose times must be strictly increasing")
        self._poses.add(t, p, R)
        if self._poses.n and self._poses.t[self._poses.n - 1] - self._poses.t[0] > bounds.max_duration_s():
            raise RouteError(f"the drive lasts over the limit of {bounds.max_duration_s():g} s")
        latest = self._poses.t[self._poses.n - 1] if self._poses.n else -np.inf
        ready = 0  # chunks the poses now reach lookahead_s past
        while self._poses.n >= MIN_POSES and self._time(self._k + (ready + 1) * self._m) + self.lookahead_s <= latest:
            ready += 1
        for n in [MAX_CHUNKS_PER_FIT] * (ready // MAX_CHUNKS_PER_FIT) + [ready % MAX_CHUNKS_PER_FIT]:
            if n:
                self._commit(n)
        if not ready or self.incremental.n_keyframes < 3:
            return []
        return self.guide.update(self.incremental.information())

    def _commit(self, n: int) -> None:
        """Append the next ``n`` chunks, sampled from one fit of the poses within
        ``lookahead_s`` of them."""
        c0 = time.perf_counter()
        k0 = self._k
        t0, t1 = self._time(k0), self._time(k0 + n * self._m)
        lo = max(self._poses.t[0], t0 - self.lookahead_s)
        tw, pw, Rw = self._poses.since(lo, t1 + self.lookahead_s)
        traj = trajectory_from_poses(tw, pw, Rw, cutoff_hz=self.cutoff_hz, name=self.name)
        if self.scene is not None:
            from ..scene.along import seen

            a = max(traj.t_start, t0 - tw[0])
            b = min(traj.t_end, t1 - tw[0])
            traj = traj.with_scene(seen(traj.cropped(a, b), self.rig, self.scene).scene)
        for j in range(n):
            c1 = time.perf_counter()
            nom = Nominal.of(traj, self.rig, t_start=self._time(self._k) - tw[0], keyframes=(0, self._m))
            self.incremental.thread_ms["sample"] += (time.perf_counter() - (c0 if j == 0 else c1)) * 1e3
            self.incremental.append(nom)
            self._k += self._m

    def finish(self) -> dict[str, Any]:
        """End the drive: the batch evaluator on every pose received (the final update)."""
        self.finished = True
        n = self._poses.n
        if n < MIN_POSES:
            raise RouteError(f"too few poses: {n}, need at least {MIN_POSES}")
        traj = trajectory_from_poses(self._poses.t[:n], self._poses.p[:n], self._poses.R[:n],
                                     cutoff_hz=self.cutoff_hz, name=self.name)
        if self.scene is not None:
            from ..scene.along import seen

            traj = seen(traj, self.rig, self.scene)
        rep = evaluate(traj, self.rig, self.options)
        out = self.guide.describe(rep, float(self._poses.t[n - 1] - self._poses.t[0]), kind="final")
        out["report"] = rep.to_dict()
        out["done"] = self.guide.done or rep.passed
        return out


def updates_of(traj: Trajectory, rig: Rig, options: Options = Options(),
               chunk_s: float = CHUNK_S) -> Iterator[dict[str, Any]]:
    """The updates a drive along ``traj`` gives, chunk by chunk (the exact keyframes of the
    batch evaluator: no pose fitting involved)."""
    from .evaluate import scene_of

    inc, guide = Incremental(rig), Guide(rig, options, name=traj.name, scene=scene_of([traj]))
    for nom in chunks(traj, rig, chunk_s):
        inc.append(nom)
        if inc.n_keyframes >= 3:
            yield from guide.update(inc.information())


__all__ = ["Incremental", "Guide", "PoseStream", "chunks", "chunk_keyframes", "updates_of"]
