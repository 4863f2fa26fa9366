"""The work a request gives the scoring workers: a route and a rig (and a scene) → the evaluator's
JSON report, a figure, a bag's report, a client's rig, lot or rig YAML checked, a scene file read,
a maneuver file.

Every task here runs inside a worker process (:mod:`api.pool`), with the request's deadline and
the worker's memory limit, and returns plain data or raises a :class:`~api.errors.Problem`
naming the request field (``route.waypoints[3]``, ``route.text`` line N), never a server path
(:func:`task`). JSON routes are written in the matching file format first, so every route passes
the same readers and checks.
"""

from __future__ import annotations

import dataclasses
import io
import json
import logging
import math
import re
from collections import Counter
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Callable

import numpy as np

from excite.io import routes
from excite.core.bounds import MAX_NESTING, MAX_RIG_NODES, nesting, size, tightened
from excite.errors import ExciteError, RigError, RouteError, SceneError
from excite.score.evaluate import Options, evaluate
from excite.rig.config import Rig, build_rig, bundled_rigs, load_rig
from excite.motion.trajectory import Trajectory
from excite.motion.vehicle import Limits
from . import problems
from .errors import Problem
from .schemas import parsed_rig

log = logging.getLogger("excite.api")

_EXT = {"tum": ".tum", "kitti": ".txt", "euroc": ".csv", "waypoints_csv": ".csv",
        "geojson": ".geojson", "control_csv": ".csv"}


@dataclass(frozen=True)
class Bounds:
    """The settings' bounds on one route (picklable)."""

    max_samples: int
    max_route_duration_s: float
    max_route_length_m: float


# --------------------------------------------------------------------------------------------
# Rigs


@lru_cache(maxsize=16)
def _bundled(name: str) -> Rig:
    return load_rig(name)


def resolve_rig(rig: str | dict[str, Any], field: str = "rig") -> Rig:
    """A bundled rig by name or an inline rig config; never reads a path the client names."""
    rig = parsed_rig(rig)
    if isinstance(rig, str):
        if rig not in bundled_rigs():
            raise Problem.at(field, f"no bundled rig named {rig!r} (bundled: {', '.join(bundled_rigs())})")
        return _bundled(rig)
    if not isinstance(rig.get("imu"), dict):
        raise Problem.at(f"{field}.imu", "give the IMU block inline as an object (the service "
                                            "reads no files)")
    try:  # a rig too deep or too large is build_rig's to refuse
        if nesting(rig) <= MAX_NESTING and size(rig) <= MAX_RIG_NODES:
            json.dumps(rig, allow_nan=False)
    except ValueError:
        raise Problem.at(field, "contains NaN or infinity") from None
    try:
        return build_rig(rig)
    except RigError as exc:  # rig errors start with the offending key ("imu.update_rate: …")
        key, sep, rest = str(exc).partition(":")
        if sep and " " not in key:
            raise Problem.at(field if key == "rig" else f"{field}.{key}", rest.strip()) from None
        raise Problem.at(field, str(exc)) from None


# --------------------------------------------------------------------------------------------
# Scenes

SCENE_WORK = 20.0
"""A route scored in a scene is this many times the work of the same route scene-blind (the scans
ray-cast along it: :func:`work_size`)."""
_SCENES: dict[str, Any] = {}  # a worker's scenes read last, by digest or bundled name (LRU, a few)
_KEPT_SCENES = 4


DIGEST = re.compile(r"^[0-9a-f]{64}$")  # of a scene (excite.scene.model.Scene.digest)


def scene_spec(store: Any, key_id: str, ref: str | None, field: str = "scene") -> tuple | None:
    """What a worker needs of the scene a request names (:func:`scene_of`): a bundled scene's
    name, or the file of the key's own scene with that digest in ``store`` (None: none named)."""
    from excite.scene.files import bundled_scenes

    if ref is None:
        return None
    if ref in bundled_scenes():
        return ("bundled", ref)
    if DIGEST.match(ref) and store is not None:
        kept = store.scene(key_id, ref)
        if kept is None:
            raise Problem.at(field, f"no scene {ref[:12]}… uploaded with this key (POST /v1/scenes; a scene "
                                    "unused for the retention period, or beyond the key's storage quota, is deleted)")
        return ("upload", ref, kept[0], kept[1])
    raise Problem.at(field, f"{ref!r} is neither a bundled scene ({', '.join(bundled_scenes())}) nor a scene's "
                            "digest (64 hexadecimal digits, from POST /v1/scenes)")


def scene_of(spec: tuple | None, field: str = "scene") -> Any:
    """The scene a request names, resolved by :func:`scene_spec`:
    ``("bundled", name)`` or ``("upload", digest, file name, bytes)`` (None: none); read once per
    worker and kept (a scene's digest is what it holds: the same digest, the same scene)."""
    if spec is None:
        return None
    from excite.scene.files import load_scene

    scene = _SCENES.pop(spec[1], None)
    if scene is None:
        try:
            scene = load_scene(spec[1]) if spec[0] == "bundled" else load_scene(spec[2], data=spec[3])
        except SceneError as exc:
            raise Problem.at(field, str(exc)) from None
        if spec[0] == "upload" and scene.digest != spec[1]:
            raise Problem(500, "the stored scene no longer reads as the scene it was kept as")
    return _keep(spec[1], scene)


def _keep(key: str, scene: Any) -> Any:
    _SCENES[key] = scene  # the most recently used last
    while len(_SCENES) > _KEPT_SCENES:
        _SCENES.pop(next(iter(_SCENES)))
    return scene


def scene_summary(scene: Any, name: str) -> dict[str, Any]:
    """What ``POST /v1/scenes`` answers of a scene read from the file ``name``."""
    lo, hi = scene.bounds
    return {"digest": scene.digest, "name": name, "triangles": scene.n_triangles, "surfaces": len(scene.surfaces),
            "surfaces_by_kind": dict(Counter(surf.kind for surf in scene.surfaces)), "area_m2_by_kind": scene.area_by_kind(),
            "bounds_m": {"min": lo.tolist(), "max": hi.tolist()}}


def scene_file_task(name: str, data: bytes) -> dict[str, Any]:
    """An uploaded scene file read (:func:`excite.scene.files.load_scene`): its summary; a file that
    cannot be read is a problem about the form field ``file`` naming the file and its field."""
    def run() -> dict[str, Any]:
        from excite.scene.files import load_scene

        scene = load_scene(name, data=data)
        return scene_summary(_keep(scene.digest, scene), name)

    return task(run, field="file")


def scene_view_task(spec: tuple, name: str) -> dict[str, Any]:
    """A scene's summary and its outline from above (:func:`excite.scene.outline.outlines`): what
    the page draws under a route."""
    def run() -> dict[str, Any]:
        from excite.scene.outline import outlines

        scene = scene_of(spec)
        return {**scene_summary(scene, name), "outline": outlines(scene)}

    return task(run, field="scene")


# --------------------------------------------------------------------------------------------
# Routes


def _count_bound(n: int, bounds: Bounds, field: str, what: str, status: int = 422) -> None:
    """More rows than ``max_samples``: 422 for JSON arrays (the schema states the bound as
    ``maxItems``), 413 for the lines of a text (a size the schema cannot state)."""
    if n > bounds.max_samples:
        raise Problem.at(field, f"{n} {what} exceed the limit of {bounds.max_samples}", status)


def _where(exc: RouteError, field: str, line_to_index: Callable[[int], str] | None) -> tuple[str, str]:
    """(field, message) of a reader error, located in the request rather than a temp file."""
    if exc.line is None:
        return field, exc.problem
    if line_to_index is None:
        return field, f"line {exc.line}: {exc.problem}"
    return field + line_to_index(exc.line), exc.problem


def route_trajectory(route: dict[str, Any], rig: Rig, limits: Limits, bounds: Bounds,
                     field: str = "route") -> Trajectory:
    """The trajectory of a validated :class:`~api.schemas.RouteIn` (as a dict)."""
    name = route.get("name") or "route"
    try:
        if route.get("text") is not None:
            return _from_text(route, name, rig, limits, bounds, field)
        if route.get("waypoints") is not None:
            return _from_waypoints(route["waypoints"], name, rig, limits, bounds, field)
        if route.get("poses") is not None:
            return _from_poses(route["poses"], name, bounds, field)
        return _from_control(route["control"], name, rig, bounds, field)
    except Problem:
        raise
    except ExciteError as exc:  # a reader's error without a line: the text is the request's
        raise Problem.at(field, exc.problem if isinstance(exc, RouteError) else str(exc)) from None


def _text_of(write: Callable[[io.StringIO], None]) -> str:
    buf = io.StringIO()
    write(buf)
    return buf.getvalue()


def _from_text(route: dict[str, Any], name: str, rig: Rig, limits: Limits, bounds: Bounds,
               field: str) -> Trajectory:
    fmt, text = route["format"], route["text"]
    # A cheap upper bound on the rows (lines; brackets for single-line GeoJSON).
    n = text.count("[") if fmt == "geojson" else text.count("\n") + 1
    _count_bound(n, bounds, f"{field}.text", "lines" if fmt != "geojson" else "coordinates", 413)
    path = routes.Text(text, f"{name}{_EXT[fmt]}")
    try:
        if fmt == "tum":
            return routes.read_tum(path)
        if fmt == "euroc":
            return routes.read_euroc(path)
        if fmt == "kitti":
            times = routes.Text(route["times_text"], f"{name}.times.txt")
            try:
                return routes.read_kitti(path, times)
            except RouteError as exc:
                if exc.source == times.name:
                    raise Problem.at(*_where(exc, f"{field}.times_text", None)) from None
                raise
        if fmt == "waypoints_csv":
            return routes.read_waypoints_csv(path, limits=limits, suspension=rig.suspension)
        if fmt == "geojson":
            return routes.read_geojson(path, limits=limits, suspension=rig.suspension)
        return routes.read_control_csv(path, suspension=rig.suspension)
    except RouteError as exc:
        raise Problem.at(*_where(exc, f"{field}.text", None)) from None


def _from_waypoints(rows: list[list[float]], name: str, rig: Rig, limits: Limits, bounds: Bounds,
                    field: str) -> Trajectory:
    f = f"{field}.waypoints"
    _count_bound(len(rows), bounds, f, "waypoints")
    width = len(rows[0])
    for i, r in enumerate(rows):
        if len(r) != width:
            raise Problem.at(f"{f}[{i}]", f"has {len(r)} numbers, the first waypoint {width}: "
                                             "all rows must be alike")
    pts = np.asarray(rows, dtype=float)
    xyz = pts[:, :3] if width >= 3 else pts[:, :2]
    length = float(np.linalg.norm(np.diff(xyz, axis=0), axis=1).sum())
    if length > bounds.max_route_length_m:
        raise Problem.at(f, f"the route is {length:.0f} m long, over the limit of "
                               f"{bounds.max_route_length_m:g} m")
    cols = ["x", "y", "z", "speed"][:width]
    text = _text_of(lambda f: np.savetxt(f, pts, fmt="%.17g", delimiter=",", header=",".join(cols), comments=""))
    try:
        return routes.read_waypoints_csv(routes.Text(text, f"{name}.csv"), limits=limits, suspension=rig.suspension)
    except RouteError as exc:
        raise Problem.at(*_where(exc, f, lambda line: f"[{line - 2}]")) from None


def _from_poses(poses: list[dict[str, Any]], name: str, bounds: Bounds, field: str) -> Trajectory:
    f = f"{field}.poses"
    _count_bound(len(poses), bounds, f, "poses")
    t = [p["t"] for p in poses]
    if t[-1] - t[0] > bounds.max_route_duration_s:
        raise Problem.at(f, f"the poses span {t[-1] - t[0]:.1f} s, over the limit of "
                               f"{bounds.max_route_duration_s:g} s")
    data = np.array([[p["t"], *p["position"], *p["quaternion_xyzw"]] for p in poses], dtype=float)
    try:
        return routes.read_tum(routes.Text(_text_of(lambda f: np.savetxt(f, data, fmt="%.17g")), f"{name}.tum"))
    except RouteError as exc:
        raise Problem.at(*_where(exc, f, lambda line: f"[{line - 1}]")) from None


def _from_control(control: dict[str, Any], name: str, rig: Rig, bounds: Bounds, field: str) -> Trajectory:
    f = f"{field}.control"
    t = control["t_s"]
    _count_bound(len(t), bounds, f"{f}.t_s", "knots")
    for key in ("speed_mps", "curvature_1pm", "grade_rad", "bank_rad"):
        v = control.get(key)
        if v is not None and len(v) != len(t):
            raise Problem.at(f"{f}.{key}", f"has {len(v)} values for {len(t)} knots (t_s)")
    if t[-1] - t[0] > bounds.max_route_duration_s:
        raise Problem.at(f"{f}.t_s", f"the profile spans {t[-1] - t[0]:.1f} s, over the limit "
                                        f"of {bounds.max_route_duration_s:g} s")
    zeros = [0.0] * len(t)
    data = np.column_stack([t, control["speed_mps"], control["curvature_1pm"],
                            control.get("grade_rad") or zeros, control.get("bank_rad") or zeros])
    start = control.get("start") or {}
    def write(fh):
        fh.write(f"# start: x_m={float(start.get('x_m', 0.0))!r} y_m={float(start.get('y_m', 0.0))!r} "
                 f"heading_rad={float(start.get('heading_rad', 0.0))!r}\n")
        fh.write("t_s,speed_mps,curvature_1pm,grade_rad,bank_rad\n")
        np.savetxt(fh, data, fmt="%.17g", delimiter=",")

    try:
        return routes.read_control_csv(routes.Text(_text_of(write), f"{name}.csv"), suspension=rig.suspension)
    except RouteError as exc:
        raise Problem.at(*_where(exc, f, lambda line: f" (knot {line - 3})")) from None


# --------------------------------------------------------------------------------------------
# The task a worker runs


def plain(x: Any) -> Any:
    """JSON-ready data: numpy to Python, dataclasses to dicts, non-finite floats to None."""
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        x = {f.name: getattr(x, f.name) for f in dataclasses.fields(x)}
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _evaluated(drive: Callable[[Rig], Trajectory], rig: str | dict[str, Any], segments: int, bounds: Bounds,
               scene: tuple | None):
    """(rig, trajectory, report) of the drive ``drive(rig)`` builds, seen in ``scene``; the library
    refuses a planned or logged drive over the service's bounds before building it."""
    r = resolve_rig(rig)
    world = scene_of(scene)
    with tightened(duration_s=bounds.max_route_duration_s, length_m=bounds.max_route_length_m):
        traj = drive(r)
        if world is not None:
            from excite.scene.along import seen

            traj = seen(traj, r, world)
        return r, traj, evaluate(traj, r, Options(segments=segments))


def _planned(route: dict[str, Any], limits: dict[str, float] | None, bounds: Bounds,
             field: str = "route") -> Callable[[Rig], Trajectory]:
    return lambda r: route_trajectory(route, r, Limits(**limits) if limits else Limits(), bounds, field)


def task(fn: Callable[..., Any], *args: Any, field: str = "route") -> Any:
    """``fn(*args)`` with every failure as a :class:`Problem` about ``field`` (in the worker: a
    bug is logged here, and the client gets a bare 500)."""
    try:
        return fn(*args)
    except Problem:
        raise
    except (ExciteError, MemoryError, RecursionError) as exc:
        raise problems.of(exc, "rig" if isinstance(exc, RigError) else field) from None
    except Exception:
        log.exception("a scoring task failed")
        raise Problem(500, problems.INTERNAL) from None


def track(traj: Trajectory, n: int) -> dict[str, list[float]]:
    """The path of V at ``n`` equally spaced times, in the frame its poses were given in (what a
    page draws the route with, over its scene)."""
    t = np.linspace(traj.t_start, traj.t_end, n)
    p = traj.sample(t).p_W_V + traj.origin
    return {"t_s": t.tolist(), "x_m": p[:, 0].tolist(), "y_m": p[:, 1].tolist()}


def score_task(route: dict[str, Any], rig: str | dict[str, Any], segments: int, limits: dict[str, float] | None,
               bounds: Bounds, scene: tuple | None = None, track_points: int = 0, field: str = "route") -> dict[str, Any]:
    """``{"report": …}`` (with ``"track"`` when ``track_points`` > 0, and then in a ``scene``
    also ``"scene_track"``: what the scene leaves undetermined at each scan along the route,
    :func:`excite.scene.survey.along_route`)."""
    def run() -> dict[str, Any]:
        _, traj, report = _evaluated(_planned(route, limits, bounds, field), rig, segments, bounds, scene)
        out = {"report": report.to_dict()}
        if track_points:
            out["track"] = track(traj, track_points)
            if scene is not None:
                from excite.scene.survey import along_route

                out["scene_track"] = along_route(traj)
        return plain(out)

    return task(run, field=field)


def batch_item_task(route: dict[str, Any], rig: str | dict[str, Any], segments: int,
                    limits: dict[str, float] | None, bounds: Bounds, scene: tuple | None, index: int) -> dict[str, Any]:
    """One route of a batch: ``{"report": …}`` or ``{"error": problem document}`` (one bad route
    does not fail the others)."""
    field = f"routes[{index}]"
    try:
        return score_task(route, rig, segments, limits, bounds, scene, field=field)
    except Problem as exc:
        return {"error": exc.body(f"/v1/batch#{field}")}


def bag_score_task(path: str, filename: str, source: dict[str, Any], rig: str | dict[str, Any],
                   segments: int, bounds: Bounds, scene: tuple | None = None) -> dict[str, Any]:
    """The report of an uploaded bag (saved at ``path``) read with ``source``
    (:class:`excite.io.bags.BagSource` fields), seen in ``scene``; problems name the form field,
    never the path."""
    from excite.io.bags import BagSource, read_bag_route

    def read(_: Rig) -> Trajectory:
        traj = read_bag_route(path, **BagSource(**source).options())
        traj.name = f"{filename}:{source['topic']}"
        return traj

    def run() -> dict[str, Any]:
        return plain(_evaluated(read, rig, segments, bounds, scene)[2].to_dict())

    return task(run, field="bag")


def plot_task(route: dict[str, Any], rig: str | dict[str, Any], segments: int, limits: dict[str, float] | None,
              bounds: Bounds, scene: tuple | None, parameter: str | None) -> bytes:
    """The PNG of ``excite score --plot`` for this route (seen in ``scene``)."""
    from excite.score import plots

    def run() -> bytes:
        r, traj, report = _evaluated(_planned(route, limits, bounds), rig, segments, bounds, scene)
        if parameter is not None and parameter not in [c.name for c in r.scored]:
            raise Problem.at("parameter", f"{parameter!r} is not a parameter of rig {r.name} "
                                          f"(parameters: {', '.join(c.name for c in r.scored)})")
        return plots.report_figure(report, traj, parameter)

    return task(run)


def rig_summary(rig: Rig) -> dict[str, Any]:
    from excite.factors import base as registry

    return {"name": rig.name, "description": rig.config.description,
            "keyframe_rate_hz": rig.keyframe_rate_hz,
            "sensors": [{"name": s.name, "kind": s.kind, "rate_hz": s.rate_hz} for s in rig.config.sensors],
            # everything the rig measures, the sections too (imu, wheels, ackermann, …)
            "measurements": [{"name": i.name, "kind": i.kind.name} for i in registry.instances(rig)],
            "parameters": [{"name": c.name, "unit": c.unit, "target": c.target} for c in rig.scored]}


MAX_YAML_EVENTS = 20_000  # a rig file has a few hundred


MAX_YAML_BYTES_HINTED = 64_000  # a calibration file is kilobytes: a bigger refused document is not read again


def rig_yaml_task(text: str) -> dict[str, Any]:
    """A rig YAML file → ``{"rig": its mapping, "summary": …}``. Anchors and aliases are refused
    (a few nested aliases expand to gigabytes), so are documents nested deeper or larger than a
    rig can be: checked on the parser's events before anything is built."""
    import yaml

    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

    def bad(message: str) -> Problem:
        return Problem.at("yaml", message)

    def run() -> dict[str, Any]:
        try:
            return parse()
        except Problem:
            from excite.rig.files import hint  # another tool's file: name the command that imports it

            told = hint("FILE", text) if len(text) <= MAX_YAML_BYTES_HINTED else None
            if told is not None:
                raise bad(told + " (then send that rig)") from None
            raise

    def parse() -> dict[str, Any]:
        try:
            depth = events = 0
            for ev in yaml.parse(text, Loader=loader):
                events += 1
                if isinstance(ev, yaml.AliasEvent):
                    raise bad("anchors and aliases (*name) are not accepted; write the values out")
                if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
                    depth += 1
                    if depth > MAX_NESTING:
                        raise bad(f"nested more than {MAX_NESTING} levels deep (a rig is at most 6)")
                elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                    depth -= 1
                if events > MAX_YAML_EVENTS:
                    raise bad(f"more than {MAX_YAML_EVENTS} values (a rig file holds a few hundred)")
            data = yaml.load(text, Loader=loader)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f"line {mark.line + 1}: " if mark is not None else ""
            raise bad(f"{where}{getattr(exc, 'problem', None) or exc}") from None
        if not isinstance(data, dict):
            raise bad("a rig file is a mapping (name:, imu:, sensors:, …)")
        try:
            json.dumps(data, allow_nan=False)
        except (TypeError, ValueError):
            raise bad("holds values JSON cannot carry (dates, binary, NaN or infinity)") from None
        return {"rig": data, "summary": rig_summary(resolve_rig(data))}

    return task(run, field="yaml")


def lot_task(lot: dict[str, Any] | None, max_vertices: int, rig: str | dict[str, Any]) -> list[dict[str, str]]:
    """What a maneuver request's lot and rig are refused for, as ``errors`` (field, message):
    in a worker, where the memory limit applies to the shape tests (bounded by ``max_vertices``
    before they start) and the deadline to the rig's globs."""
    from excite.plan.site import read_site

    errors = []
    if lot is not None:
        try:
            read_site(lot, max_vertices=max_vertices)
        except ExciteError as exc:
            errors.append({"field": "lot", "message": str(exc)})
        except MemoryError:
            errors.append({"field": "lot", "message": "the lot needs more memory to check than a worker may use"})
    try:
        task(resolve_rig, rig, field="rig")
    except Problem as exc:
        if exc.status != 422:
            raise
        errors += exc.errors or []
    return errors


def optimize_settings(request: dict[str, Any], site: Any = None):
    """The free-form optimizer's settings of a maneuver request (as data), in ``site`` (None: the
    rectangle ``lot_x_m`` × ``lot_y_m``)."""
    from excite.plan import OptimizeSettings

    return OptimizeSettings(duration_s=request["duration_s"], lot_x_m=request["lot_x_m"], lot_y_m=request["lot_y_m"],
                            limits=Limits(**request["limits"]), seed=request["seed"],
                            time_budget_s=request["time_budget_s"], closed=request["closed"],
                            n_random=request["n_random"], criterion=request.get("criterion", "E"), site=site)


def drivable_settings(request: dict[str, Any], scene: tuple | None = None):
    """The drivable search's settings of a maneuver request (as data), in the ``scene`` it names
    (:func:`scene_of`'s spec, resolved by the router or the job runner)."""
    from excite.plan.drivable.search import DrivableSettings
    from excite.plan.site import read_site

    return DrivableSettings(duration_s=request["duration_s"], lot_x_m=request["lot_x_m"], lot_y_m=request["lot_y_m"],
                            site=read_site(request["lot"]) if request.get("lot") else None,
                            limits=Limits(**request["limits"]), time_budget_s=request["time_budget_s"],
                            speed_max_mps=request.get("speed_max_mps"), draws=request.get("draws", 30),
                            seed=request["seed"], workers=1, scene=scene_of(scene))


def drivable_check_task(request: dict[str, Any], scene: tuple | None = None) -> list[dict[str, str]]:
    """What a drivable plan's request is refused for before it becomes a job (a lot too small for
    any element, an instructed speed above the lot's safe speed, a scene that does not reach over
    the lot), as ``errors``."""
    from excite.plan.drivable.search import check_problem

    try:
        settings = drivable_settings(request, scene)
        check_problem(settings.lot, settings.limits, settings.speed_max_mps)
    except Problem as exc:
        return exc.errors or [{"field": "scene", "message": exc.detail}]
    except ExciteError as exc:
        text = str(exc)
        field = next((f for f in ("speed_max_mps", "scene") if text.startswith(f)), "lot")
        return [{"field": field, "message": text}]
    return []


def drivable_file_task(plan: dict[str, Any], rig: str | dict[str, Any], fmt: str, lot: dict[str, Any] | None,
                       lot_x_m: float, lot_y_m: float, origin: tuple[float, float] | None) -> bytes:
    """A drivable plan's file: its sheet (``sheet_pdf``, ``sheet_png``), cone layout (``cones``,
    GeoJSON: lon/lat where the lot has an origin) or the plan itself (``plan``)."""
    from excite.plan.drivable.plan import build, cones_geojson, plan_from_dict
    from excite.plan.drivable.sheet import sheet
    from excite.plan.settings import vehicle_limits
    from excite.plan.site import Site, read_site

    def make() -> bytes:
        p = plan_from_dict(plan)
        if fmt == "plan":
            return json.dumps(p.to_dict(), indent=2).encode()
        site = read_site(lot) if lot else Site.rectangle(lot_x_m, lot_y_m)
        built = build(p, vehicle_limits(resolve_rig(rig), Limits()))
        if fmt == "cones":
            return json.dumps(cones_geojson(built, origin or site.origin)).encode()
        return sheet(built, site, "pdf" if fmt == "sheet_pdf" else "png")

    return task(make)


def maneuver_file(profile: dict[str, Any], rig: Rig, fmt: str, name: str,
                  origin: tuple[float, float] | None = None) -> str:
    """A finished job's maneuver (its stored control profile) as the text of a file in ``fmt``: tum,
    csv (waypoints), control (CSV) or geojson; the drive rebuilt with the rig's suspension and written
    by :mod:`excite.io.routes`. GeoJSON (WGS84 lon/lat) needs the lot's origin: the inverse of the
    projection :func:`excite.io.routes.read_geojson` uses, so the file reads back to the same drive."""
    import tempfile
    from pathlib import Path

    from excite.motion.vehicle import ControlProfile, drive
    from excite.plan.site import maneuver_geojson

    prof = ControlProfile(**{**profile, "start": tuple(profile["start"])})
    with tempfile.TemporaryDirectory(prefix="excite-") as tmp:
        path = Path(tmp) / f"{name}.{fmt}"
        if fmt == "control":
            return routes.write_control_csv(prof, path).read_text()
        traj = drive(prof, rig.suspension)
        traj.name = name
        if fmt == "tum":
            return routes.write_tum(traj, path).read_text()
        text = routes.write_waypoints_csv(traj, path).read_text()
        if fmt == "csv":
            return text
        xyzv = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
        return maneuver_geojson(xyzv[:, :3], xyzv[:, 3], origin, name)


def maneuver_task(profile: dict[str, Any], rig: str | dict[str, Any], fmt: str, name: str,
                  origin: tuple[float, float] | None) -> str:
    """:func:`maneuver_file` of a job's stored rig (a client's: resolved here, in a worker)."""
    return task(lambda: maneuver_file(profile, resolve_rig(rig), fmt, name, origin))


def work_size(route: dict[str, Any], scene: Any = None) -> float:
    """The seconds of drive a route holds, estimated without reading it (what admission weighs):
    the span of its times, or its length at 5 m/s, or one keyframe per line of text; in a
    ``scene``, :data:`SCENE_WORK` times that."""
    seconds = 1.0
    try:
        if route.get("control") is not None:
            seconds = float(route["control"]["t_s"][-1]) - float(route["control"]["t_s"][0])
        elif route.get("poses") is not None:
            seconds = float(route["poses"][-1]["t"]) - float(route["poses"][0]["t"])
        elif route.get("waypoints") is not None:
            p = np.asarray(route["waypoints"], dtype=float)[:, :2]
            seconds = float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) / 5.0
        elif route.get("text") is not None:
            seconds = 0.1 * route["text"].count("\n")
    except (KeyError, IndexError, TypeError, ValueError):
        pass
    return (SCENE_WORK if scene is not None else 1.0) * max(1.0, seconds)


def warm() -> bool:
    """Load the bundled rigs and score a short drive (the pool's first task: imports, caches and
    any compiled kernels are ready before /readyz says so, not in the first request)."""
    for n in bundled_rigs():
        _bundled(n)
    route = {"control": {"t_s": [0.0, 5.0, 10.0], "speed_mps": [0.0, 4.0, 0.0],
                         "curvature_1pm": [0.0, 0.1, 0.0]}}
    try:
        score_task(route, bundled_rigs()[0], 0, None, Bounds(1000, 60.0, 1000.0))
    except Problem as exc:
        log.warning("warm-up scoring failed: %s", exc.detail)
    return True
