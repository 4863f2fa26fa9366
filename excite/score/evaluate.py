"""Score a drive: how well does it determine every calibration parameter of a rig?

:func:`evaluate` samples the drive, linearises the joint problem (:mod:`excite.information`),
marginalises the trajectory and any nuisance parameter (a monocular camera's scale), scales by
the accuracy targets ``S = diag(targets)`` and reports

- the score ``λ_min(S Λ_θ S)``: ≥ 1 guarantees every Cramér–Rao σ is within its target;
- the scaled and unscaled spectra, numerical rank with its threshold, condition number;
- weak and unobservable modes, with their dominant named coordinates and motion advice;
- per-parameter Cramér–Rao σ against target (None where the parameter is unobservable);
- optionally the information each segment of the route contributes.

:class:`Report` is plain data; :meth:`Report.to_dict` is the JSON contract the CLI, the service
and the CI gate share.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from . import advice, spectrum
from ..core import bounds
from ..information import dense
from ..information.closure import ORIGIN, marginalise_nuisance
from ..information.elimination import DriveInformation, drive_information, window_information, windows
from ..information.problem import build, columns, frame_step
from ..errors import EvaluationError
from ..factors.base import Nominal
from ..rig.config import Rig
from ..motion.trajectory import Trajectory
from ..motion.vehicle import implausible

REPORT_VERSION = 2


@dataclass(frozen=True)
class Options:
    """How to evaluate.

    ``segments``: number of equal route segments whose own information is reported (0: none).
    ``weak_below``: scaled eigenvalue under which a mode is reported as weak (1 = its σ reaches
    the targets). ``rank_rtol``: eigenvalues of the normalised information
    ``diag(H_θθ)^-½ Λ_θ diag(H_θθ)^-½`` below it are unobservable directions (see
    :mod:`excite.score.spectrum`: a property of the drive and sensors, not of the targets).
    ``max_modes``: at most this many weak modes are listed.
    """

    segments: int = 0
    weak_below: float = 1.0
    rank_rtol: float = spectrum.RANK_RTOL
    max_modes: int = 12

    def __post_init__(self) -> None:
        for name in bounds.OPTIONS:
            bounds.check_range(bounds.OPTIONS, name, getattr(self, name), EvaluationError)
        if not (0 < self.rank_rtol < 1):
            raise EvaluationError(f"rank_rtol must be in (0, 1), got {self.rank_rtol}")


@dataclass(frozen=True)
class ParameterResult:
    name: str
    unit: str
    sigma: float | None  # Cramér–Rao σ from the drive alone; None if unobservable
    target: float
    ok: bool
    sigma_with_prior: float | None = None


@dataclass(frozen=True)
class WeakMode:
    eigenvalue_scaled: float
    status: str  # "unobservable" | "weak" | "ok"
    coordinates: list[tuple[str, float]]  # dominant coordinates, |weight| descending
    advice: str

    @property
    def sigma_in_targets(self) -> float | None:
        """σ along this direction in units of the targets (None when unobservable)."""
        return None if self.status == "unobservable" else float(1.0 / np.sqrt(self.eigenvalue_scaled))


@dataclass(frozen=True)
class Segment:
    t_start_s: float
    t_end_s: float
    score: float
    weakest_mode_information: float  # v ᵀ (S Λ_seg S) v along the whole route's weakest mode
    parameter_information: dict[str, float]  # diag(S Λ_seg S): information per parameter, in targets⁻²


@dataclass
class Report:
    route: str
    rig: str
    duration_s: float
    length_m: float
    n_keyframes: int
    score: float
    passed: bool
    rank: int
    nullity: int
    rank_threshold: float  # on spectrum_normalised
    rank_normalisation: str
    condition_number: float | None
    spectrum_scaled: list[float]
    spectrum_unscaled: list[float]
    spectrum_normalised: list[float]
    column_map: list[dict[str, Any]]
    parameters: list[ParameterResult]
    weak_modes: list[WeakMode]
    segments: list[Segment]
    warnings: list[str]  # what about the drives the model does not describe (excite.motion.vehicle.implausible)
    score_with_priors: float | None
    timings_ms: dict[str, float]
    information: np.ndarray = field(repr=False)  # Λ_θ over the scored coordinates (SI units)
    information_scaled: np.ndarray = field(repr=False)  # S Λ_θ S
    eigenvectors_scaled: np.ndarray = field(repr=False)  # columns, as spectrum_scaled: the null space first
    _drives: tuple[list[Trajectory], Rig] | None = field(default=None, repr=False)  # for the export
    _all_columns: list[dict[str, Any]] = field(default_factory=list, repr=False)  # incl. nuisances
    _information_all: np.ndarray | None = field(default=None, repr=False)  # Λ over all columns
    scene: dict[str, str] | None = None  # the scene the drive was scored in: {"name", "digest"} (None: none)

    @property
    def null_space(self) -> np.ndarray:
        """Orthonormal basis of the unobservable directions in scaled coordinates (p × nullity)."""
        return self.eigenvectors_scaled[:, :self.nullity]

    def to_dict(self) -> dict[str, Any]:
        """The JSON report (finite floats, None for ∞/undefined)."""
        return {
            "version": REPORT_VERSION,
            "route": self.route,
            "rig": self.rig,
            "score": self.score,
            "passed": self.passed,
            "duration_s": self.duration_s,
            "length_m": self.length_m,
            "n_keyframes": self.n_keyframes,
            "rank": self.rank,
            "nullity": self.nullity,
            "rank_threshold": self.rank_threshold,
            "rank_normalisation": self.rank_normalisation,
            "condition_number": self.condition_number,
            "spectrum_scaled": self.spectrum_scaled,
            "spectrum_unscaled": self.spectrum_unscaled,
            "spectrum_normalised": self.spectrum_normalised,
            "column_map": self.column_map,
            "parameters": [p.__dict__ for p in self.parameters],
            "weak_modes": [
                {"eigenvalue_scaled": m.eigenvalue_scaled, "status": m.status,
                 "sigma_in_targets": m.sigma_in_targets,
                 "coordinates": [[n, w] for n, w in m.coordinates], "advice": m.advice}
                for m in self.weak_modes
            ],
            "segments": [s.__dict__ for s in self.segments],
            "warnings": self.warnings,
            "score_with_priors": self.score_with_priors,
            "timings_ms": self.timings_ms,
            "scene": self.scene,
        }

    def export_npz(self, path: str | Path) -> None:
        """Write J (sparse, whitened), H = JᵀJ (sparse), Λ_θ, the variable ordering and column map."""
        if self._drives is None:
            raise EvaluationError("this report carries no drive to export")
        trajs, rig = self._drives
        prob = build([Nominal.of(t, rig) for t in trajs], rig)
        J, rows = dense.jacobian(prob)
        H = (J.T @ J).tocoo()
        J = J.tocoo()
        states = dense.state_names(prob.n_keyframes, prob.local, prob.state_dim)
        params = [c["name"] for c in self._all_columns]
        np.savez_compressed(
            path,
            J_data=J.data, J_row=J.row, J_col=J.col, J_shape=np.array(J.shape),
            H_data=H.data, H_row=H.row, H_col=H.col, H_shape=np.array(H.shape),
            row_labels=np.array(rows), variable_order=np.array(states + params),
            information_all=self._information_all, information=self.information,
            information_scaled=self.information_scaled,
            column_names=np.array([c["name"] for c in self.column_map]),
            column_units=np.array([c["unit"] for c in self.column_map]),
            column_targets=np.array([c["target"] for c in self.column_map]),
        )


def scaled(rig: Rig, Lam_all: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Λ over the scored coordinates, S Λ S) from Λ over all columns (:func:`excite.information.problem.columns`)."""
    scored = scored_mask(rig, Lam_all.shape[0])
    Lam = marginalise_nuisance(Lam_all, scored)
    S = np.array([c.target for c in rig.scored])
    return Lam, Lam * np.outer(S, S)


def scored_mask(rig: Rig, n_columns: int) -> np.ndarray:
    """Which of ``n_columns`` parameter columns (the rig's, then further drives' nuisances) are scored."""
    out = np.zeros(n_columns, dtype=bool)
    out[:len(rig.coordinates)] = [not c.nuisance for c in rig.coordinates]
    return out


def check_work(trajs: Sequence[Trajectory], rig: Rig) -> None:
    """Refuse drives whose keyframes or IMU samples exceed :mod:`excite.core.bounds` before any is
    allocated (a few bytes of route can describe a day of driving)."""
    for t in trajs:
        too_much = (bounds.work_problem(t.duration, rig.keyframe_rate_hz, bounds.MAX_KEYFRAMES, "keyframes")
                    or bounds.work_problem(t.duration, rig.config.imu.update_rate,
                                           bounds.MAX_IMU_SAMPLES, "IMU samples"))
        if too_much:
            raise EvaluationError(f"{t.name}: {too_much}")


def max_segments(trajs: Sequence[Trajectory], rig: Rig) -> int:
    """The most route segments ``trajs`` hold (:func:`excite.information.elimination.windows`): each at least 3
    keyframes and a whole number of every sensor's frames."""
    K = sum(Nominal.grid(t, rig)[1] for t in trajs)
    return max(1, (K - 1) // max(2, frame_step(rig)))


def evaluate(traj: Trajectory | Sequence[Trajectory], rig: Rig, options: Options = Options()) -> Report:
    """The report of ``traj`` driven with ``rig`` (see the module docstring).

    Several drives are calibrated together: they share the calibration and nothing else, so
    their information adds up.
    """
    trajs = [traj] if isinstance(traj, Trajectory) else list(traj)
    if not trajs:
        raise EvaluationError("no drive to evaluate")
    check_work(trajs, rig)
    t0 = time.perf_counter()
    warnings: list[str] = []

    def check_motion() -> None:  # while the sweeps run
        warnings.extend((f"{t.name}: " if len(trajs) > 1 else "") + w for t in trajs for w in implausible(t))

    drives = drive_information(trajs, rig, meanwhile=check_motion)
    return report_of(drives, rig, options, trajs, t0=t0, warnings=warnings)


def scene_of(trajs: Sequence[Trajectory]) -> dict[str, str] | None:
    """The scene the drives ``trajs`` were scored in, as a report names it: ``{"name", "digest"}``
    (the scene's source and its SHA-256; several scenes' joined by " + "), None when they see none."""
    views = list({t.scene.digest: t.scene for t in trajs if t.scene is not None}.values())
    if not views:
        return None
    return {"name": " + ".join(v.source for v in views), "digest": " + ".join(v.digest for v in views)}


def scene_text(scene: dict[str, str]) -> str:
    """``scene street_canyon (sha256 1a2b3c4d5e6f)``: how a report's text names its scene."""
    short = " + ".join(d[:12] for d in scene["digest"].split(" + "))
    return f"scene {scene['name']} (sha256 {short})"


def report_of(drives: DriveInformation, rig: Rig, options: Options = Options(),
              trajs: Sequence[Trajectory] = (), route: str | None = None, t0: float | None = None,
              warnings: list[str] | None = None, scene: dict[str, str] | None = None) -> Report:
    """The report of the information ``drives`` of the drives ``trajs`` (needed for segments and
    the export only; ``route`` names them otherwise): :func:`evaluate`'s second half, shared with
    the incremental evaluator (:mod:`excite.score.live`). ``t0``: when the information was started;
    ``warnings``: what about the drives the model does not describe, where the caller has it
    (:func:`excite.motion.vehicle.implausible` of ``trajs`` otherwise); ``scene``: the scene the
    drives see, where ``trajs`` are not given (:func:`scene_of` of them otherwise)."""
    trajs = list(trajs)
    if options.segments and not trajs:
        raise EvaluationError("segments need the drives themselves")
    t0 = time.perf_counter() if t0 is None else t0
    Lam_all = drives.information
    if not np.all(np.isfinite(Lam_all)):
        raise EvaluationError("the information is not finite: the drive or the rig has numbers "
                              "beyond what the model can represent")
    Lam, Ls = scaled(rig, Lam_all)
    t3 = time.perf_counter()
    timings = {f"{k}_thread": v for k, v in drives.thread_ms.items()}
    timings["information"] = (t3 - t0) * 1e3

    coords = list(rig.scored)
    S = np.array([c.target for c in coords])
    scored = ~drives.nuisance
    before = drives.diag_tt[scored]
    spec = spectrum.analyse(Lam, before, S, options.rank_rtol)
    w, V = spec.values, spec.vectors
    null = np.arange(w.size) < spec.nullity
    sigma = [None if np.isnan(x) else float(x) for x in spec.sigma]
    w_unscaled = np.linalg.eigvalsh(Lam)

    with_prior: list[float | None] = [None] * len(coords)
    score_with_priors = None
    prior_sig = np.array([np.inf if c.prior_sigma is None else c.prior_sigma for c in coords])
    if np.isfinite(prior_sig).any():
        prior = 1.0 / prior_sig**2
        spec_p = spectrum.analyse(Lam + np.diag(prior), before + prior, S, options.rank_rtol)
        score_with_priors = spec_p.score
        with_prior = [None if np.isnan(x) else float(x) for x in spec_p.sigma]

    params = [ParameterResult(c.name, c.unit, sigma[i], c.target,
                              sigma[i] is not None and sigma[i] <= c.target, with_prior[i])
              for i, c in enumerate(coords)]

    modes = []
    n_modes = max(1, int(np.sum(w < options.weak_below)))
    for k in range(min(n_modes, options.max_modes)):
        v = V[:, k]
        v = v * np.sign(v[np.argmax(np.abs(v))])
        order = np.argsort(-np.abs(v))
        keep = [i for i in order if abs(v[i]) >= 0.1][:6] or [int(order[0])]
        status = "unobservable" if null[k] else ("weak" if w[k] < options.weak_below else "ok")
        modes.append(WeakMode(float(w[k]), status, [(coords[i].name, float(v[i])) for i in keep],
                              advice.describe(rig, [coords[i] for i in keep], v[keep])))
    t4 = time.perf_counter()

    segments, notes = [], []
    if options.segments:
        t_kf = np.concatenate([Nominal.keyframe_times(t, rig) for t in trajs])
        Ks = [Nominal.grid(t, rig)[1] for t in trajs]
        most = max_segments(trajs, rig)
        spans = windows(Ks, rig, min(options.segments, most))
        if len(spans) < options.segments:  # said, never silently fewer
            why = (f"the drive holds at most {most} of 3 keyframes or more and a whole number of every sensor's "
                   f"frames ({sum(Ks)} keyframes at {rig.keyframe_rate_hz:g} Hz)" if options.segments > most else
                   "pieces of fewer than 3 keyframes at a boundary between drives are left out")
            notes.append(f"segments: {options.segments} asked, {len(spans)} reported: {why}")
        v_weak = V[:, 0]
        for (k0, k1), (Lam_w, diag_w) in zip(spans, window_information(trajs, rig, spans)):
            Lam_seg, Lseg = scaled(rig, Lam_w)
            seg = spectrum.analyse(Lam_seg, diag_w[scored], S, options.rank_rtol)
            segments.append(Segment(float(t_kf[k0]), float(t_kf[k1]), seg.score,
                                    float(v_weak @ Lseg @ v_weak),
                                    {c.name: float(Lseg[i, i]) for i, c in enumerate(coords)}))
    t5 = time.perf_counter()
    timings.update(report=(t4 - t3) * 1e3, segments=(t5 - t4) * 1e3, total=(t5 - t0) * 1e3)

    column_map = [{"index": i, "name": c.name, "unit": c.unit, "target": c.target} for i, c in enumerate(coords)]
    names, nuisance = columns(rig, len(trajs) or 1)
    units = {c.name: c.unit for c in rig.coordinates} | {n: "m" for n in ORIGIN}
    all_columns = [{"index": i, "name": n, "unit": units[n.split("@")[0]], "nuisance": bool(nuisance[i])}
                   for i, n in enumerate(names)]
    numbers = [spec.score, *w, *w_unscaled, *(x for x in sigma if x is not None)]
    if not np.all(np.isfinite(numbers)):
        raise EvaluationError("the evaluation produced a non-finite number: the drive or the rig "
                              "has numbers beyond what the model can represent")
    return Report(
        route=route if route is not None else " + ".join(t.name for t in trajs), rig=rig.name,
        duration_s=drives.duration_s, length_m=drives.length_m, n_keyframes=drives.n_keyframes,
        score=spec.score, passed=all(p.ok for p in params), rank=spec.rank, nullity=spec.nullity,
        rank_threshold=spec.threshold, rank_normalisation=spectrum.NORMALISATION,
        condition_number=spec.condition,
        spectrum_scaled=[float(x) for x in w], spectrum_unscaled=[float(x) for x in w_unscaled],
        spectrum_normalised=[float(x) for x in spec.normalised],
        column_map=column_map, parameters=params, weak_modes=modes, segments=segments,
        warnings=(warnings if warnings is not None else
                  [(f"{t.name}: " if len(trajs) > 1 else "") + w for t in trajs for w in implausible(t)]) + notes,
        score_with_priors=score_with_priors, timings_ms={k: round(v, 3) for k, v in timings.items()},
        information=Lam, information_scaled=Ls, eigenvectors_scaled=spec.vectors, _drives=(trajs, rig) if trajs else None, _all_columns=all_columns,
        _information_all=Lam_all, scene=scene if scene is not None else scene_of(trajs),
    )
