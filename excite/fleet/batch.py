"""The CI gate: evaluate many routes against their expectations, in parallel; JUnit XML out.

A route **passes** when

- it comes from the command line: its score is at least ``min_score`` when one is given,
  otherwise every parameter's Cramér–Rao σ is within its rig target (the report's ``passed``);
- it comes from a manifest: it meets every expectation the manifest gives it (``min_score``
  and each ``determine`` bound); a manifest route with no expectation at all must have every
  parameter within its target.

A route that cannot be read or evaluated is an *error* for that route (a JUnit ``<error>``), never
an exception out of :func:`run`: the other routes are still evaluated and reported.

Routes manifest (YAML)::

    version: 1                       # optional
    rig: robotaxi                    # default rig of every route (bundled name or YAML path)
    routes:
      - route: highway_run_control.csv   # file or glob relative to the manifest, or a URL (required)
        name: highway_run                # test-case name (default: the file name)
        description: free text
        rig: robotaxi                    # this route's rig
        scene: street_canyon             # the scene it is scored in: a scene file relative to the
                                         #   manifest or a bundled scene's name (default: the
                                         #   manifest's top-level scene, else the command line's)
        times: kitti_00_times.txt        # KITTI times file, relative to the manifest, or a URL
        topic: /odom                     # bags: pose topic or TF chain /tf:PARENT.CHILD
        imu_topic: /imu                  # bags: measured IMU (optional)
        min_score: 1.0e-4                # λ_min(SΛS) must reach this
        determine:                       # parameter name or glob → what its σ must be
          wheel.radius_*: target         #   within the rig's target
          wheel.track: 1 cm              #   at most this (rig quantity syntax: number in SI or "<n> <unit>")
          lidar.time_offset: observable  #   finite (not in the null space)

Every error names the manifest and the key (``manifest.yaml: routes.2.determine."wheel.trak":
matches no parameter of rig robotaxi``). Rigs and scenes are loaded and every ``determine`` key
is matched against the rig's parameters when the manifest is read, before anything is evaluated.

Paths given to :func:`collect`: route files; bags (``.bag``, ``.mcap``, ROS 2 bag folders; the
trajectory source is ``topic``); folders (their route files: ``.csv .tum .txt .geojson .json``
and bags, without README, manifests and KITTI times files); globs; and manifests
(``.yaml``/``.yml``). A KITTI poses file ``…poses….txt`` pairs with the ``…times….txt`` next
to it when there is one. A URL (``https://…``, ``s3://…``) is one route, read where it is
evaluated (:mod:`excite.io.remote`: a worker on a cluster fetches it itself).
"""

from __future__ import annotations

import fnmatch
import glob as globmod
import json
import math
import os
import time
import traceback
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import yaml

from ..core import engine
from ..io import remote
from ..errors import ExciteError, ManifestError, RigError
from ..score.evaluate import Report, evaluate, scene_text
from ..rig.config import Rig, load_rig, parse_quantity
from ..core.units import human

__all__ = [
    "ManifestError", "Bound", "RouteSpec", "Failure", "RouteResult", "load_manifest", "collect",
    "check", "evaluate_spec", "load", "run", "junit_xml", "results_json", "ROUTE_SUFFIXES",
]

ROUTE_SUFFIXES = (".csv", ".tum", ".txt", ".geojson", ".json")
_MANIFEST_SUFFIXES = (".yaml", ".yml")
_ROUTE_KEYS = ("route", "name", "description", "rig", "scene", "times", "topic", "imu_topic", "min_score",
               "determine")
_TOP_KEYS = ("version", "description", "rig", "scene", "routes")
COMMAND_LINE = "command line"


@dataclass(frozen=True)
class Bound:
    """What one parameter's σ must be: ``mode`` is ``target`` (σ ≤ the rig target), ``bound``
    (σ ≤ ``sigma_max``, SI) or ``observable`` (σ finite). ``key`` is where it was asked for."""

    parameter: str
    mode: str
    sigma_max: float | None
    key: str


@dataclass(frozen=True)
class RouteSpec:
    """One route to evaluate and what it must show. ``error`` is set when the route could not
    even be found (a glob that matches nothing): it is then reported, not evaluated."""

    path: str
    name: str
    rig: str
    source: str = COMMAND_LINE  # the manifest it comes from, or "command line"
    times: str | None = None
    min_score: float | None = None
    determine: tuple[Bound, ...] = ()
    error: str | None = None
    topic: str | None = None  # bags: the trajectory source
    imu_topic: str | None = None
    scene: str | None = None  # the scene it is scored in (a scene file or a bundled scene's name)

    @property
    def default_gate(self) -> bool:
        """No explicit expectation: every parameter must be within its target."""
        return self.min_score is None and not self.determine


@dataclass(frozen=True)
class Failure:
    """One unmet expectation: a parameter's σ (None: unobservable) above its bound, or the score."""

    parameter: str  # coordinate name, or "score"
    value: float | None
    bound: float
    unit: str
    kind: str  # "target" | "bound" | "observable" | "score"

    def short(self) -> str:
        """``wheel.track 1.49 cm > 0.5 cm`` (a table cell)."""

        if self.parameter == "score":
            return f"score {self.value:.3g} < {self.bound:.3g}"
        if self.value is None:
            return f"{self.parameter} unobservable"
        return f"{self.parameter} {human(self.value, self.unit)} > {human(self.bound, self.unit)}"

    def text(self) -> str:
        """``wheel.track: σ 1.49 cm > 0.5 cm (target, 2.98×)`` (a failure message)."""

        if self.parameter == "score":
            return f"score {self.value:.3g} < {self.bound:.3g} (min_score)"
        if self.kind == "observable":
            return f"{self.parameter}: unobservable (must be observable)"
        what = "target" if self.kind == "target" else "bound"
        if self.value is None:
            return f"{self.parameter}: unobservable, must be ≤ {human(self.bound, self.unit)} ({what})"
        return (f"{self.parameter}: σ {human(self.value, self.unit)} > {human(self.bound, self.unit)} "
                f"({what}, {self.value / self.bound:.2f}×)")


@dataclass
class RouteResult:
    """The outcome of one route (plain data: it crosses process boundaries)."""

    name: str
    path: str
    rig: str
    source: str
    passed: bool
    score: float | None = None
    failures: list[Failure] = field(default_factory=list)
    advice: list[str] = field(default_factory=list)
    error: str | None = None
    error_detail: str | None = None
    seconds: float = 0.0
    report: dict[str, Any] | None = None
    warnings: list[str] = field(default_factory=list)  # the report's: motion no car makes, fewer segments
    scene: dict[str, str] | None = None  # the scene it was scored in, as the report names it

    @property
    def status(self) -> str:
        return "error" if self.error is not None else ("passed" if self.passed else "failed")


# --------------------------------------------------------------------------------------------
# Manifest and path collection


def _is_glob(text: str) -> bool:
    return any(ch in text for ch in "*?[")


def _is_route_file(p: Path) -> bool:
    from ..io.bags import is_bag

    if is_bag(p):
        return True
    name = p.name.lower()
    if not p.is_file() or p.suffix.lower() not in ROUTE_SUFFIXES or name.startswith("readme"):
        return False
    return not (p.suffix.lower() == ".txt" and "times" in name)


def _kitti_times(p: Path) -> str | None:
    """The times file next to a KITTI ``…poses….txt``, if there is one."""
    if p.suffix.lower() != ".txt" or "poses" not in p.name:
        return None
    t = p.with_name(p.name.replace("poses", "times"))
    return str(t) if t.is_file() else None


def _display(p: Path | str) -> str:
    """A path relative to the working directory when it is below it (shorter in tables); a URL
    as it is."""
    if remote.is_url(p):
        return str(p)
    p = Path(p)
    try:
        return str(p.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return os.path.normpath(p)


def _expand(pattern: str, base: Path | None = None) -> list[Path]:
    full = pattern if base is None or Path(pattern).is_absolute() else str(base / pattern)
    return [Path(m) for m in sorted(globmod.glob(full, recursive=True))]


@lru_cache(maxsize=32)
def cached_rig(rig: str) -> Rig:
    """The rig of a manifest's reference, read once (the routes of a manifest share their rig)."""
    return load_rig(rig)


@lru_cache(maxsize=4)
def cached_scene(ref: str) -> Any:
    """The scene of a reference (a scene file or a bundled scene's name), read once per process."""
    from ..scene.files import load_scene

    return load_scene(ref)


def _scene_ref(value: Any, base: Path, key: str, where: str) -> str:
    """A manifest's scene: a bundled scene's name, or a file relative to the manifest (read now)."""
    if not isinstance(value, str) or not value:
        raise ManifestError(f"{where}: {key}: expected a scene file or a bundled scene's name, got {value!r}")
    from ..scene.files import bundled_scenes

    ref = value if value in bundled_scenes() else str(base / value)
    try:
        cached_scene(ref)
    except ExciteError as exc:
        raise ManifestError(f"{where}: {key}: {exc}") from None
    return ref


def _resolve_bounds(determine: Any, rig: Rig, rig_name: str, key: str, where: str) -> tuple[Bound, ...]:
    if not isinstance(determine, dict) or not determine:
        raise ManifestError(f"{where}: {key}: expected a mapping of parameter name or glob to "
                            f"'target', 'observable' or a σ bound, got {determine!r}")
    names = [c.name for c in rig.scored]
    units = {c.name: c.unit for c in rig.scored}
    out: dict[str, Bound] = {}
    for pattern, value in determine.items():
        k = f'{key}."{pattern}"'
        if not isinstance(pattern, str):
            raise ManifestError(f"{where}: {k}: parameter names are strings")
        matched = [n for n in names if fnmatch.fnmatchcase(n, pattern)]
        if not matched:
            raise ManifestError(f"{where}: {k}: matches no parameter of rig {rig.name} "
                                f"(parameters: {', '.join(names)})")
        for n in matched:
            if value in ("target", "observable"):
                b = Bound(n, str(value), None, k)
            else:
                try:
                    b = Bound(n, "bound", parse_quantity(value, units[n], k), k)
                except RigError as exc:
                    raise ManifestError(f"{where}: {exc} (or 'target', 'observable')") from None
            out[n] = b  # a later, more specific key overrides an earlier glob
    return tuple(out.values())


def _min_score(value: Any, key: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ManifestError(f"{where}: {key}: expected a number ≥ 0, got {value!r}")
    return float(value)


def _rig_ref(value: Any, base: Path, key: str, where: str) -> str:
    if not isinstance(value, str) or not value:
        raise ManifestError(f"{where}: {key}: expected a bundled rig name or a rig YAML path, got {value!r}")
    p = base / value
    ref = str(p) if (Path(value).suffix or "/" in value) and p.exists() else value
    try:
        cached_rig(ref)
    except ExciteError as exc:
        raise ManifestError(f"{where}: {key}: {exc}") from None
    return ref


def load_manifest(path: str | Path, default_rig: str = "robotaxi", default_scene: str | None = None) -> list[RouteSpec]:
    """The routes of a manifest with their expectations, validated (see the module docstring).

    Route paths, globs, times files and rig paths are relative to the manifest. A route whose
    file is missing is kept (it becomes that route's error when run); a malformed manifest
    raises :class:`ManifestError` naming the key.
    """
    path = Path(path)
    where = _display(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ManifestError(f"{where}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise ManifestError(f"{where}: not a text file ({exc.reason})") from None
    try:
        data = yaml.safe_load(text)
    except RecursionError:
        raise ManifestError(f"{where}: nested too deeply to be a routes manifest") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f", line {mark.line + 1}" if mark is not None else ""
        raise ManifestError(f"{where}{line}: not valid YAML ({getattr(exc, 'problem', exc)})") from None
    if not isinstance(data, dict):
        raise ManifestError(f"{where}: expected a mapping with a 'routes' list at the top level")
    for k in data:
        if k not in _TOP_KEYS:
            raise ManifestError(f"{where}: {k}: unknown key (known: {', '.join(_TOP_KEYS)})")
    if data.get("version", 1) != 1:
        raise ManifestError(f"{where}: version: only version 1 is known, got {data['version']!r}")
    base = path.parent
    top_rig = _rig_ref(data["rig"], base, "rig", where) if "rig" in data else default_rig
    top_scene = _scene_ref(data["scene"], base, "scene", where) if "scene" in data else default_scene
    routes = data.get("routes")
    if not isinstance(routes, list) or not routes:
        raise ManifestError(f"{where}: routes: expected a non-empty list of routes")
    specs: list[RouteSpec] = []
    for i, entry in enumerate(routes):
        key = f"routes.{i}"
        if not isinstance(entry, dict):
            raise ManifestError(f"{where}: {key}: expected a mapping with at least 'route', got {entry!r}")
        for k in entry:
            if k not in _ROUTE_KEYS:
                raise ManifestError(f"{where}: {key}.{k}: unknown key (known: {', '.join(_ROUTE_KEYS)})")
        route = entry.get("route")
        if not isinstance(route, str) or not route:
            raise ManifestError(f"{where}: {key}.route: required, a route file or glob relative to the manifest")
        rig_ref = _rig_ref(entry["rig"], base, f"{key}.rig", where) if "rig" in entry else top_rig
        rig = cached_rig(rig_ref)
        scene = _scene_ref(entry["scene"], base, f"{key}.scene", where) if "scene" in entry else top_scene
        times = entry.get("times")
        if times is not None and not isinstance(times, str):
            raise ManifestError(f"{where}: {key}.times: expected a path, got {times!r}")
        for k in ("topic", "imu_topic"):
            if entry.get(k) is not None and not (isinstance(entry[k], str) and entry[k]):
                raise ManifestError(f"{where}: {key}.{k}: expected a topic name, got {entry[k]!r}")
        min_score = _min_score(entry["min_score"], f"{key}.min_score", where) if "min_score" in entry else None
        bounds = (_resolve_bounds(entry["determine"], rig, rig_ref, f"{key}.determine", where)
                  if "determine" in entry else ())
        name = entry.get("name")
        if name is not None and not isinstance(name, str):
            raise ManifestError(f"{where}: {key}.name: expected text, got {name!r}")
        common = dict(rig=rig_ref, source=where, min_score=min_score, determine=bounds,
                      topic=entry.get("topic"), imu_topic=entry.get("imu_topic"), scene=scene)
        times_path = None if times is None else times if remote.is_url(times) else str(base / times)
        if remote.is_url(route):
            specs.append(RouteSpec(route, name or remote.name_of(route), times=times_path, **common))
        elif _is_glob(route):
            files = [p for p in _expand(route, base) if p.is_file() or _is_route_file(p)]
            if not files:
                specs.append(RouteSpec(str(base / route), name or route, error=f"{key}.route: no file matches "
                                       f"{route!r} in {_display(base)}", **common))
            for p in files:
                specs.append(RouteSpec(str(p), p.name if name is None else f"{name}/{p.name}",
                                       times=times_path or _kitti_times(p), **common))
        else:
            p = base / route
            specs.append(RouteSpec(str(p), name or p.name, times=times_path or _kitti_times(p), **common))
    return specs


def collect(paths: Sequence[str | Path], rig: str = "robotaxi", min_score: float | None = None,
            topic: str | None = None, imu_topic: str | None = None, scene: str | None = None) -> list[RouteSpec]:
    """The routes named by ``paths`` (files, folders, globs, manifests), in order.

    Routes from the command line get ``rig``, ``scene`` and ``min_score``; a manifest's routes carry
    their own expectations (``rig`` and ``scene`` are their defaults when the manifest names none);
    bags from the command line are read with ``topic`` and ``imu_topic``. A path that does not
    exist becomes that route's error; a scene that cannot be read is a :class:`ManifestError`
    (``--scene: …``), before anything is evaluated.
    """
    if min_score is not None and not (math.isfinite(min_score) and min_score >= 0):
        raise ManifestError(f"--min-score must be a number ≥ 0, got {min_score}")
    if scene is not None:
        try:
            cached_scene(scene)
        except ExciteError as exc:
            raise ManifestError(f"--scene: {exc}") from None
    specs: list[RouteSpec] = []

    def route(p: Path) -> None:
        specs.append(RouteSpec(str(p), _display(p), rig, min_score=min_score, times=_kitti_times(p),
                               topic=topic, imu_topic=imu_topic, scene=scene))

    for raw in paths:
        text = str(raw)
        p = Path(text)
        if remote.is_url(text):  # read by whichever process evaluates it (excite.io.remote)
            specs.append(RouteSpec(text, text, rig, min_score=min_score, topic=topic, imu_topic=imu_topic,
                                   scene=scene))
        elif p.suffix.lower() in _MANIFEST_SUFFIXES and not _is_glob(text):
            specs.extend(load_manifest(p, default_rig=rig, default_scene=scene))
        elif p.is_dir() and not _is_route_file(p):
            files = sorted(q for q in p.iterdir() if _is_route_file(q))
            if not files:
                specs.append(RouteSpec(text, _display(p), rig, min_score=min_score,
                                       error=f"{text}: no route files in this folder "
                                             f"({', '.join(ROUTE_SUFFIXES)})"))
            for q in files:
                route(q)
        elif _is_glob(text):
            matches = [m for m in _expand(text) if m.is_file() or _is_route_file(m)]
            if not matches:
                specs.append(RouteSpec(text, text, rig, min_score=min_score, error=f"no file matches {text!r}"))
            for m in matches:
                if m.suffix.lower() in _MANIFEST_SUFFIXES:
                    specs.extend(load_manifest(m, default_rig=rig, default_scene=scene))
                elif _is_route_file(m):
                    route(m)
        else:
            route(p)
    if not specs:
        raise ManifestError("no routes to evaluate")
    for s in specs:  # command-line rigs are checked once, up front, like a manifest's
        if s.source == COMMAND_LINE:
            try:
                cached_rig(s.rig)
            except ExciteError as exc:
                raise ManifestError(f"--rig: {exc}") from None
    return specs


# --------------------------------------------------------------------------------------------
# Expectations and evaluation


def check(report: Report, spec: RouteSpec) -> list[Failure]:
    """The expectations of ``spec`` that ``report`` does not meet (empty: the route passes)."""
    params = {p.name: p for p in report.parameters}
    fails: list[Failure] = []
    if spec.default_gate:
        for p in report.parameters:
            if not p.ok:
                fails.append(Failure(p.name, p.sigma, p.target, p.unit, "target"))
        return _worst_first(fails)
    if spec.min_score is not None and not report.score >= spec.min_score:
        fails.append(Failure("score", report.score, spec.min_score, "1", "score"))
    for b in spec.determine:
        p = params[b.parameter]
        if b.mode == "observable":
            if p.sigma is None:
                fails.append(Failure(p.name, None, math.inf, p.unit, "observable"))
            continue
        bound = p.target if b.mode == "target" else float(b.sigma_max)  # type: ignore[arg-type]
        if p.sigma is None or p.sigma > bound:
            fails.append(Failure(p.name, p.sigma, bound, p.unit, b.mode))
    return _worst_first(fails)


def _worst_first(fails: list[Failure]) -> list[Failure]:
    """The score first, then unobservable parameters, then by σ/bound descending."""
    def key(f: Failure) -> tuple[int, float]:
        if f.parameter == "score":
            return (0, 0.0)
        return (1, 0.0) if f.value is None else (2, -f.value / f.bound)

    return sorted(fails, key=key)


def _advice(report: Report, fails: list[Failure]) -> list[str]:
    """Motion advice for the failing parameters, worst first: for each, the weak mode that
    contributes most to its σ² (weight² / eigenvalue; an unobservable mode first), and for a score
    failure the weakest mode. One line per distinct mode: 'for p: λ … on a +w, b +w: advice'."""
    def share(m: Any, name: str) -> float:
        w = dict(m.coordinates).get(name)
        if w is None:
            return 0.0
        return math.inf if m.status == "unobservable" else w * w / max(m.eigenvalue_scaled, 1e-300)

    out, used = [], set()
    for f in fails:
        if f.parameter == "score":
            mode = report.weak_modes[0] if report.weak_modes else None
        else:
            ranked = sorted(report.weak_modes, key=lambda m: -share(m, f.parameter))
            mode = ranked[0] if ranked and share(ranked[0], f.parameter) > 0 else None
        if mode is None or id(mode) in used:
            continue
        used.add(id(mode))
        coords = ", ".join(f"{n} {w:+.2f}" for n, w in mode.coordinates[:3])
        out.append(f"{f.parameter}: {mode.status} mode (λ {mode.eigenvalue_scaled:.3g}) on {coords}: "
                   f"{mode.advice}")
        if len(out) == 4:
            break
    return out


def load(spec: RouteSpec, see: bool = True) -> tuple[Rig, Any]:
    """The rig and the trajectory of a route (the errors of :func:`excite.io.routes.read_route`),
    seeing its scene where it has one (and ``see``: :func:`excite.scene.along.seen`)."""
    from ..io.bags import BagSource, is_bag
    from ..io.routes import read_route

    rig = cached_rig(spec.rig)
    with remote.local(spec.path) as path, remote.local(spec.times) as times:
        bag = BagSource(spec.topic, spec.imu_topic) if is_bag(path) else None
        traj = read_route(path, times=times, suspension=rig.suspension, bag=bag)
    if spec.scene is not None and see:
        from ..scene.along import seen

        traj = seen(traj, rig, cached_scene(spec.scene))
    return rig, traj


def error_text(exc: Exception, path: str) -> tuple[str, str | None]:
    """(message, traceback or None) of what kept a route from being evaluated: a known failure
    is its message; anything else is a bug, reported with its traceback."""
    if isinstance(exc, ExciteError):
        return str(exc), None
    if isinstance(exc, OSError):
        return f"{exc.filename or path}: {exc.strerror or exc}", None
    return f"internal error: {type(exc).__name__}: {exc}", traceback.format_exc()


def evaluate_spec(spec: RouteSpec, keep_report: bool = False) -> RouteResult:
    """Evaluate one route and check it. Never raises for bad input: a route that cannot be read
    or evaluated comes back with ``error`` set (and the traceback when it was a bug)."""
    t0 = time.perf_counter()
    res = RouteResult(spec.name, spec.path, spec.rig, spec.source, passed=False)
    if spec.error is not None:
        res.error = spec.error
        return res
    try:
        rig, traj = load(spec)
        rep = evaluate(traj, rig)
    except Exception as exc:  # every failure is this route's, reported; the others go on
        res.error, res.error_detail = error_text(exc, spec.path)
    else:
        res.rig = rig.name
        res.scene = rep.scene
        res.score = rep.score
        res.warnings = list(rep.warnings)
        res.failures = check(rep, spec)
        res.passed = not res.failures
        if res.failures:
            res.advice = _advice(rep, res.failures)
        if keep_report:
            res.report = rep.to_dict()
    res.seconds = time.perf_counter() - t0
    return res


def _evaluate_kept(spec: RouteSpec) -> RouteResult:
    return evaluate_spec(spec, keep_report=True)


def _lost(spec: RouteSpec, exc: BaseException) -> RouteResult:
    return RouteResult(spec.name, spec.path, spec.rig, spec.source, False,
                       error=f"worker failed: {type(exc).__name__}: {exc}")


def run(specs: Sequence[RouteSpec], jobs: int | None = None, keep_reports: bool = False,
        on_result: Callable[[RouteResult], None] | None = None, scheduler: str | None = None,
        on_progress: Callable[[engine.Progress], None] | None = None) -> list[RouteResult]:
    """Evaluate every route, on the Dask cluster at ``scheduler`` (or :data:`engine.SCHEDULER_ENV`)
    when there is one, else ``jobs`` local processes at a time (default: one per core; 1 runs in
    this process): :func:`excite.core.engine.run`. Results come back in the order of ``specs``;
    ``on_result`` and ``on_progress`` are called as each one finishes (a progress bar)."""
    if jobs is not None and jobs < 1:
        raise ManifestError(f"--jobs must be ≥ 1, got {jobs}")

    def done(_: int, r: RouteResult, progress: engine.Progress) -> None:
        if on_result:
            on_result(r)
        if on_progress:
            on_progress(progress)

    return engine.run(_evaluate_kept if keep_reports else evaluate_spec, list(specs), failed=_lost, jobs=jobs,
                      scheduler=scheduler, on_result=done)


# --------------------------------------------------------------------------------------------
# Outputs


def _failure_message(r: RouteResult) -> str:
    return "; ".join(f.text() for f in r.failures)


def junit_xml(results: Sequence[RouteResult], total_s: float | None = None) -> str:
    """JUnit XML: one test suite per source (each manifest; the command line), one test case per
    route. A failure's message names every failing parameter with σ against its bound; its text
    adds the score and the motion advice of the weak modes. An unreadable route is an error."""
    suites: dict[str, list[RouteResult]] = {}
    for r in results:
        suites.setdefault(r.source, []).append(r)
    root = ET.Element("testsuites", name="excite batch", tests=str(len(results)),
                      failures=str(sum(r.status == "failed" for r in results)),
                      errors=str(sum(r.status == "error" for r in results)),
                      time=f"{total_s if total_s is not None else sum(r.seconds for r in results):.3f}")
    stamp = datetime.now(timezone.utc).isoformat(timespec="seconds")
    for source, rs in suites.items():
        suite = ET.SubElement(root, "testsuite", name=source, tests=str(len(rs)),
                              failures=str(sum(r.status == "failed" for r in rs)),
                              errors=str(sum(r.status == "error" for r in rs)), skipped="0",
                              time=f"{sum(r.seconds for r in rs):.3f}", timestamp=stamp)
        for r in rs:
            cls = "excite.fleet.batch." + Path(source).stem.replace(".", "_").replace(" ", "_")
            case = ET.SubElement(suite, "testcase", classname=cls, name=r.name, time=f"{r.seconds:.3f}",
                                 file=_display(r.path))
            if r.status == "error":
                el = ET.SubElement(case, "error", type="RouteError", message=r.error or "")
                el.text = r.error_detail or r.error
            elif r.status == "failed":
                el = ET.SubElement(case, "failure", type="ExpectationNotMet", message=_failure_message(r))
                where = f" in {scene_text(r.scene)}" if r.scene else ""
                lines = [f"route {_display(r.path)} with rig {r.rig}{where}: score {r.score:.4g}", "not met:"]
                lines += [f"  {f.text()}" for f in r.failures]
                if r.advice:
                    lines.append("what it takes:")
                    lines += [f"  {a}" for a in r.advice]
                el.text = "\n".join(lines)
            if r.score is not None:
                out = ET.SubElement(case, "system-out")
                out.text = f"score {r.score:.4g} with rig {r.rig}" + (f" in {scene_text(r.scene)}" if r.scene else "")
    ET.indent(root)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def results_json(results: Sequence[RouteResult]) -> dict[str, Any]:
    """The batch as JSON: ``passed`` overall and, per route, its status, score, failures (SI
    values), advice and, when kept, the full report (the ``excite score --json`` document)."""
    def one(r: RouteResult) -> dict[str, Any]:
        d = {k: v for k, v in asdict(r).items() if k not in ("failures", "error_detail")}
        d["status"] = r.status
        d["failures"] = [{**asdict(f), "bound": None if math.isinf(f.bound) else f.bound, "message": f.text()}
                         for f in r.failures]
        return d

    return {"version": 1, "passed": all(r.status == "passed" for r in results),
            "routes": [one(r) for r in results]}


def write_text(path: str | Path, text: str) -> None:
    """Write ``text``, creating the parent folder (a CI artefacts folder may not exist yet)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def dumps(results: Iterable[RouteResult]) -> str:
    return json.dumps(results_json(list(results)), indent=2)
