"""The candidates a maneuver is chosen from, and the one check every candidate passes.

:func:`check` is the independent check: the profile is rounded to what the control CSV holds
(:func:`as_written`), driven with :func:`~excite.motion.vehicle.drive`, and its drive checked against
every limit (:func:`~excite.motion.vehicle.check_limits`) and the lot (point-in-polygon at 20 Hz, with
the edge margin). The pipeline returns only a drive that passed it, and writes that very drive.

The functions below the check run in a worker process next to IPOPT (plain, picklable
arguments; plain results): the reference maneuvers (full evaluator), chunks of random
candidates (screened by the evaluator on the optimizer's coarse rig; the best few are re-scored
by the full evaluator at the end), and the COBYLA baseline. The reference maneuvers' rows are
scored once per problem and cached (:func:`cached_references`, under
:func:`.compiled.cache_dir`).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import LimitError
from ..score.evaluate import Report, evaluate
from ..motion.maneuvers import REFERENCE_MANEUVERS, random_candidates, stop_and_go
from ..rig.config import Rig
from ..motion.trajectory import Trajectory
from ..motion.vehicle import ControlProfile, check_limits, drive
from . import criteria
from .model import coarse_rig

CHECK_RATE_HZ = 20.0


def as_written(profile: ControlProfile, name: str | None = None) -> ControlProfile:
    """The profile exactly as :func:`~excite.io.routes.write_control_csv` writes it (10 significant
    digits), so that the drive that is checked is the drive that is read back."""
    def r(a):
        return np.array([float(f"{v:.10g}") for v in np.asarray(a, dtype=float)])

    return ControlProfile(r(profile.t_s), np.maximum(r(profile.speed_mps), 0.0), r(profile.curvature_1pm),
                          r(profile.grade_rad), r(profile.bank_rad),
                          tuple(float(repr(float(v))) for v in profile.start), name or profile.name)


def check(profile: ControlProfile, rig: Rig, settings, site) -> tuple[Trajectory, list[str]]:
    """The drive of ``profile`` and every limit and lot violation of it (empty: feasible)."""
    traj = drive(profile, rig.suspension)
    out = [str(v) for v in check_limits(traj, settings.limits, CHECK_RATE_HZ)]
    out += site.violations(traj, profile, traj.times(CHECK_RATE_HZ))
    return traj, out


def metrics(report: Report) -> dict[str, Any]:
    """The columns of a comparison row: the score (λ_min), the worst σ/target, log det and
    trace of the inverse of the target-scaled information."""
    w = np.linalg.eigvalsh(report.information_scaled)
    ratios = [math.inf if p.sigma is None else p.sigma / p.target for p in report.parameters]
    worst = max(ratios) if ratios else math.inf
    ld, ti = criteria.spectral(w, "D"), -criteria.spectral(w, "A")
    return {"score": float(report.score), "worst_sigma_ratio": worst if math.isfinite(worst) else None,
            "log_det": ld if math.isfinite(ld) else None, "trace_inv": ti if math.isfinite(ti) else None}


def rotation_min(traj: Trajectory) -> float:
    """λ_min of LI-Init's rotation-excitation matrix over the drive (body rates at 20 Hz)."""
    s = traj.sample(traj.times(CHECK_RATE_HZ))
    return float(criteria.rotation_excitation(s.omega_V)[0])


@dataclass(eq=False)  # identity: two candidates are never "equal" by their arrays
class Candidate:
    """A drive that went through :func:`check`, with what is known about it."""

    name: str
    kind: str  # optimized | reference | random | cobyla | start
    profile: ControlProfile
    violations: list[str]
    model: float | None = None  # the criterion on the coarse model (screening)
    rotation: float | None = None  # λ_min of LI-Init's rotation-excitation matrix
    row: dict[str, Any] = field(default_factory=dict)  # metrics() of the full evaluator, once scored
    report: Report | None = None  # the full evaluator's report, when scored in this process
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def feasible(self) -> bool:
        return not self.violations


def full(c: Candidate, rig: Rig, criterion: str) -> Candidate:
    """Score ``c`` by the full evaluator (fills ``row``); returns ``c``."""
    if not c.row:
        rep = evaluate(drive(c.profile, rig.suspension), rig)
        c.report = rep
        c.row = metrics(rep)
        c.row["value"] = criteria.value(rep.information_scaled, criterion)
    return c


def reference_profiles(rig: Rig, settings, site) -> list[Candidate]:
    """Every reference maneuver that can be generated for the lot (moved to its centre, over
    its terrain), not yet checked."""
    out = []
    lx, ly = site.extent_m
    for name, gen in REFERENCE_MANEUVERS.items():
        try:
            if name == "highway_run":
                prof = gen(settings.duration_s, limits=settings.limits)
            else:
                prof = site.place(gen(settings.duration_s, width_m=ly, length_m=lx, limits=settings.limits,
                                      margin_m=site.margin_m))
        except LimitError:
            continue
        out.append(Candidate(name, "reference", as_written(site.drape(prof, rig.suspension)), []))
    return out + _over_terrain(rig, settings, site)


def _over_terrain(rig: Rig, settings, site) -> list[Candidate]:
    """For every terrain feature, laps of the stop-and-go ellipse centred on it, its long axis
    along the feature's slope, as large as the lot allows: the slope field is flat away from a
    feature, so a start elsewhere gives IPOPT no gradient towards it."""
    out = []
    for i, f in enumerate(site.terrain.features):
        c = f.polygon_m.mean(axis=0)
        d = np.asarray(f.direction)
        a, b = site.reach_m(c, d), site.reach_m(c, np.array([-d[1], d[0]]))
        for shrink in (0.95, 0.8, 0.65, 0.5):
            try:
                prof = stop_and_go(settings.duration_s, width_m=2 * shrink * b, length_m=2 * shrink * a,
                                   limits=settings.limits, margin_m=0.0)
            except LimitError:
                continue
            prof = site.place(prof, c, float(np.arctan2(d[1], d[0])))
            traj = drive(prof, rig.suspension)
            if site.lot.contains(traj.sample(traj.times(5.0)).p_W_V, site.margin_m).all():
                name = f"stop_and_go over {f.role} {i + 1}"
                out.append(Candidate(name, "reference", as_written(site.drape(prof, rig.suspension), name), []))
                break
    return out


def references(rig: Rig, settings, site) -> list[Candidate]:
    """:func:`reference_profiles`, checked and scored by the full evaluator."""
    out = []
    for c in reference_profiles(rig, settings, site):
        traj, c.violations = check(c.profile, rig, settings, site)
        c.rotation = rotation_min(traj)
        full(c, rig, settings.criterion).report = None  # the row is enough: a report is heavy to send back
        out.append(c)
    return out


def _references_path(rig: Rig, settings, site) -> Path:
    """The cache file of the reference maneuvers' rows for this problem: keyed by everything
    they depend on, the source of the whole package included (an evaluator that changes
    invalidates them)."""
    from .compiled import cache_dir, key_of

    pkg = Path(__file__).resolve().parents[1]
    feats = [(f.role, np.asarray(f.polygon_m).round(6).tolist(), f.direction, f.slope, f.height_m, f.max_speed_mps)
             for f in site.terrain.features]
    key = key_of("references", rig.config.model_dump_json(), settings.duration_s, repr(settings.limits),
                 settings.criterion, json.dumps(site.outline()), repr(feats),
                 sources=sorted(p for p in pkg.rglob("*.py") if "cli" not in p.parts))
    return cache_dir() / "references" / f"{key}.json"


def cached_references(rig: Rig, settings, site, generated: list[Candidate] | None = None) -> list[Candidate] | None:
    """:func:`references` from the cache, or None when this problem's are not cached (the cache
    holds only the rows; the profiles are ``generated`` — :func:`reference_profiles` — again)."""
    path = _references_path(rig, settings, site)
    try:
        rows = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    generated = reference_profiles(rig, settings, site) if generated is None else generated
    profiles = {c.name: c.profile for c in generated}
    out = []
    for r in rows:
        if r.get("name") not in profiles:
            return None
        out.append(Candidate(r["name"], "reference", profiles[r["name"]], list(r["violations"]),
                             rotation=r["rotation"], row=dict(r["row"])))
    return out


def store_references(rig: Rig, settings, site, refs: list[Candidate]) -> None:
    """Keep the reference maneuvers' rows (:func:`cached_references`); a cache that cannot be
    written is not an error."""
    if not refs:
        return
    path = _references_path(rig, settings, site)
    rows = [{"name": c.name, "violations": c.violations, "rotation": c.rotation, "row": c.row} for c in refs]
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(rows))
        os.replace(tmp, path)
    except OSError:
        pass


def random_profiles(rig: Rig, settings, site, chunk: int, size: int, first: int) -> list[ControlProfile]:
    """Chunk ``chunk`` (``size`` candidates, numbered from ``first``) of the seed's random
    candidates, over the lot's terrain, not yet checked. Same seed and chunk, same drives."""
    seed = int(np.random.SeedSequence([settings.seed, chunk]).generate_state(1)[0])
    try:
        profs = random_candidates(size, settings.duration_s, site.lot, settings.limits, seed=seed,
                                  suspension=rig.suspension, margin_m=site.margin_m)
    except LimitError:
        return []
    return [as_written(site.drape(p, rig.suspension), name=f"random_{settings.seed}_{first + j}")
            for j, p in enumerate(profs)]


def randoms(rig: Rig, settings, site, chunk: int, size: int, first: int) -> list[Candidate]:
    """:func:`random_profiles`, checked and screened (:func:`screened`)."""
    return screened(rig, settings, site, random_profiles(rig, settings, site, chunk, size, first))


def screened(rig: Rig, settings, site, profiles: list[ControlProfile]) -> list[Candidate]:
    """Random candidates checked and screened by the evaluator on the optimizer's coarse rig."""
    crig = coarse_rig(rig)
    out = []
    for p in profiles:
        traj, bad = check(p, rig, settings, site)
        model = criteria.value(evaluate(traj, crig).information_scaled, settings.criterion)
        out.append(Candidate(p.name, "random", p, bad, model=model, rotation=rotation_min(traj)))
    return out


def cobyla(rig: Rig, settings, site, z0: np.ndarray, budget_s: float) -> dict[str, Any]:
    """The derivative-free baseline from ``z0`` for ``budget_s`` (its own transcription)."""
    from . import baselines
    from .kinematics import profile_from_z
    from .problem import Problem
    from .transcription import cached

    tr = cached(Problem.of(rig, settings, site))
    z, value, n = baselines.cobyla(tr, z0, budget_s, settings.criterion)
    if z is None:
        return {"profile": None, "model": None, "evaluations": n}
    return {"profile": profile_from_z(tr.grid, tr.scales, z, name="cobyla", terrain=site.terrain),
            "model": value, "evaluations": n}

