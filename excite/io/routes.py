"""Every route file format excite reads and writes, in one place.

Readers return a :class:`~excite.motion.trajectory.Trajectory` of the vehicle frame V; each rejects
malformed input with a :class:`~excite.errors.RouteError` naming the file, the line and the
problem. :func:`read_route` picks the reader from the extension and the content.

Formats
-------
Timed poses (the pose is taken *as the vehicle frame V*: logged poses are of whatever was
tracked, a camera, an IMU or a GNSS antenna; no lever arm to the rear axle is applied):

- **TUM** (``.tum``, or ``.txt`` with 8 columns): ``t tx ty tz qx qy qz qw``, whitespace
  separated, ``#`` comments. Quaternions x-y-z-w, unit within 1e-3.
- **KITTI** (``.txt`` with 12 columns, needs a times file): row-major 3×4 ``[R|t]`` of the left
  camera in the first camera frame; times one per line. Camera axes (x right, y down, z forward)
  are mapped to vehicle axes (x forward, y left, z up), and the world is made z-up by expressing
  it in the first vehicle frame.
- **EuRoC** ground truth (``.csv`` whose header starts with ``#timestamp``, or headerless with 8
  or 17 numeric columns): ``timestamp[ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z[, ...]``;
  quaternion w-first; extra columns (velocity, biases) are ignored.

Timed poses are re-centred (first position and first time subtracted, before any math, so UTM
coordinates and epoch times lose no precision), then fitted with cubic smoothing splines: the
positions, and the unit quaternions (sign-unwrapped, smoothed per component and renormalised: a
smooth curve on SO(3)). The fit is resampled on a uniform grid and the velocity is the spline's
derivative, not a finite difference of noisy poses. ``cutoff_hz`` is the smoothing bandwidth
(-3 dB frequency of the equivalent low-pass; capped at a quarter of the sample rate).

A **comma2k19 segment folder** (``processed_log/`` and ``global_pose/``): the drive of V through
the dataset's camera pose, with the recording's measured IMU (:mod:`excite.io.comma2k19`, which
also reads its CAN wheel speeds, steering, radar tracks and GNSS fixes).

Routes (driven through :func:`~excite.motion.vehicle.drive`, so suspension tilt is modelled):

- **Waypoints CSV** (``.csv``): ``x,y[,z][,speed]`` [m, m/s]. An optional header names the
  columns (``x``/``x_m``, ``y``/``y_m``, ``z``/``z_m``, ``speed``/``speed_mps``); headerless files
  are read as ``x,y`` / ``x,y,z`` / ``x,y,z,speed`` by column count. The path is a C2
  (curvature-continuous) spline through the points. With speeds, v² is linear in arc length
  between waypoints (constant acceleration); without, the fastest profile within the limits
  (speed, lateral acceleration, curvature rate, acceleration/deceleration, jerk), from and to rest.
- **GeoJSON** (``.geojson``/``.json``): one LineString (bare geometry, a Feature, or a
  FeatureCollection with exactly one) of ``[lon, lat(, alt)]`` in WGS84 degrees, projected with
  pyproj to a transverse Mercator about the first point (x east, y north, z = alt − first alt).
  Optional ``properties.speed_mps``: a number or one per point.
- **Control CSV** (``.csv``): a header is required and names the columns
  ``t_s,speed_mps,curvature_1pm[,grade_rad][,bank_rad]`` (short forms ``t,speed,curvature,grade,
  bank`` accepted). An optional comment ``# start: x_m=<x> y_m=<y> heading_rad=<h>`` gives the
  start pose.

Writers: :func:`write_tum`, :func:`write_waypoints_csv`, :func:`write_control_csv`; each output
reads back with the matching reader.
"""

from __future__ import annotations

import json
import math
import re
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

import numpy as np
from scipy.spatial.transform import Rotation

from ..core import bounds, so3
from ..errors import RouteError
from ..motion.paths import plan_given_speed, plan_speed, profile_from_plan, smooth_path
from ..motion.trajectory import Trajectory
from ..motion.vehicle import ControlProfile, Limits, Suspension, drive
from .poses import (DEFAULT_CUTOFF_HZ, MIN_POSES, QUAT_NORM_TOL, R_CAM_VEH, ROTATION_TOL, check_range, check_timed,
                    trajectory_from_poses)
from .sniff import is_bag, is_comma2k19

if TYPE_CHECKING:
    from .bags import BagSource

__all__ = [
    "read_route", "read_tum", "read_kitti", "read_euroc", "read_waypoints_csv", "read_geojson",
    "read_control_csv", "read_control_profile", "route_from_waypoints", "Text",
    "control_profile_of", "write_tum", "write_waypoints_csv", "write_control_csv",
]



# --------------------------------------------------------------------------------------------
# Text tables


@dataclass
class _Table:
    """Numeric rows of a text file with the line number of each row."""

    source: str
    rows: list[list[str]]
    lines: list[int]
    header: list[str] | None = None
    header_line: int | None = None


@dataclass(frozen=True)
class Text:
    """A route file held in memory: its ``content`` and the ``name`` it would have as a file
    (its extension chooses the format, as a path's does; its stem names the route). Every reader
    takes one wherever it takes a path, so a service parses what it holds without a temporary file."""

    content: str | bytes
    name: str = "route"


@dataclass(frozen=True)
class _Doc:
    """A route file's text and how errors name it (the path, or the in-memory text's name)."""

    text: str
    label: str
    name: str

    @property
    def stem(self) -> str:
        return Path(self.name).stem

    @property
    def suffix(self) -> str:
        return Path(self.name).suffix.lower()


Source = str | Path | Text


def document(source: "Source | _Doc") -> _Doc:
    """The text of a path or of a :class:`Text`, decoded as UTF-8 (a clear error otherwise)."""
    if isinstance(source, _Doc):
        return source
    if isinstance(source, Text):
        content, label = source.content, source.name
        if isinstance(content, bytes):
            try:
                content = content.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise RouteError(f"not a text file ({exc.reason})", source=label) from None
        return _Doc(content, label, Path(label).name)
    path = Path(source)
    try:
        return _Doc(path.read_text(encoding="utf-8"), str(path), path.name)
    except UnicodeDecodeError as exc:
        raise RouteError(f"not a text file ({exc.reason})", source=str(path)) from None


def split_rows(doc: _Doc, sep: str | None, header: bool = False) -> _Table:
    """Non-blank, non-comment lines split into fields; with ``header``, a first line holding a
    non-number is returned as the header."""
    table = _Table(doc.label, [], [])
    for i, raw in enumerate(doc.text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f.strip() for f in line.split(sep)] if sep else line.split()
        if header and table.header is None and not table.rows and not is_number(fields[0]):
            table.header, table.header_line = [f.lower() for f in fields], i
            continue
        table.rows.append(fields)
        table.lines.append(i)
    if not table.rows:
        raise RouteError("the file has no data rows (empty file)", source=doc.label)
    return table


def is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def numbers(table: _Table, allowed: tuple[int, ...] | None = None) -> np.ndarray:
    """The rows as a float array; rejects wrong column counts, unparseable numbers, NaN/inf.

    Every row must have as many fields as the header (or, without one, as the first row), and
    that count must be one of ``allowed``.
    """
    if len(table.rows) > bounds.MAX_SAMPLES:
        raise RouteError(f"{len(table.rows):,} rows, over the limit of {bounds.MAX_SAMPLES:,}",
                         source=table.source, line=table.lines[bounds.MAX_SAMPLES])
    want = len(table.header) if table.header else len(table.rows[0])
    if allowed is not None and want not in allowed:
        raise RouteError(f"expected {' or '.join(map(str, allowed))} columns, got {want}",
                         source=table.source, line=table.header_line or table.lines[0])
    try:  # every row well formed: one conversion
        out = np.array(table.rows, dtype=float)
    except ValueError:
        out = None
    if out is None or out.shape != (len(table.rows), want):
        out = _rows_one_by_one(table, want)  # finds the first malformed row
    bad = ~np.isfinite(out)
    if bad.any():
        k, j = np.argwhere(bad)[0]
        what = "NaN" if math.isnan(out[k, j]) else "infinite"
        raise RouteError(f"column {j + 1} is {what}", source=table.source, line=table.lines[k])
    return out


def _rows_one_by_one(table: _Table, want: int) -> np.ndarray:
    out = np.empty((len(table.rows), want))
    for k, (fields, line) in enumerate(zip(table.rows, table.lines)):
        if len(fields) != want:
            raise RouteError(f"expected {want} columns, got {len(fields)}", source=table.source,
                             line=line)
        try:
            out[k] = [float(f) for f in fields]
        except ValueError:
            j = next(j for j, f in enumerate(fields) if not is_number(f))
            raise RouteError(f"column {j + 1}: cannot parse {fields[j]!r} as a number",
                             source=table.source, line=line) from None
    return out


def _check_times(t: np.ndarray, source: str, lines: list[int]) -> None:
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0)) + 1
        what = "duplicate time" if dt[k - 1] == 0 else "time goes backwards"
        raise RouteError(f"{what}: {t[k]:.9g} s after {t[k - 1]:.9g} s (times must be strictly "
                         "increasing)", source=source, line=lines[k])


@contextmanager
def _located(source: str) -> Iterator[None]:
    """Route errors raised while building a drive from a file name the file."""
    try:
        yield
    except RouteError as exc:
        if exc.source is not None:
            raise
        raise RouteError(exc.problem, source=source) from None


def _check_count(n: int, minimum: int, what: str, source: str, lines: list[int]) -> None:
    if n < minimum:
        raise RouteError(f"too few {what}: {n}, need at least {minimum}", source=source,
                         line=lines[-1] if lines else None)


# --------------------------------------------------------------------------------------------
# Timed poses


def _quaternions(q: np.ndarray, source: str, lines: list[int], first_col: int) -> np.ndarray:
    norm = np.linalg.norm(q, axis=1)
    bad = np.abs(norm - 1.0) > QUAT_NORM_TOL
    if bad.any():
        k = int(np.argmax(bad))
        raise RouteError(f"quaternion (columns {first_col}-{first_col + 3}) has norm {norm[k]:.6g}, "
                         f"not 1 (tolerance {QUAT_NORM_TOL:g})", source=source, line=lines[k])
    return q / norm[:, None]


def read_tum(source: Source, *, cutoff_hz: float = DEFAULT_CUTOFF_HZ,
             rate_hz: float | None = None) -> Trajectory:
    """A TUM file ``t tx ty tz qx qy qz qw`` as a trajectory of V (see the module notes)."""
    doc = document(source)
    table = split_rows(doc, None)
    d = numbers(table, (8,))
    _check_count(len(d), MIN_POSES, "poses", table.source, table.lines)
    _check_times(d[:, 0], table.source, table.lines)
    if already_smooth(doc):  # what write_tum wrote: smoothing it again would attenuate the motion
        cutoff_hz = math.inf
    check_timed(d[:, 0], d[:, 1:4], rate_hz, table.source, table.lines, cutoff_hz)
    q = _quaternions(d[:, 4:8], table.source, table.lines, 5)
    return trajectory_from_poses(d[:, 0], d[:, 1:4], Rotation.from_quat(q).as_matrix(),
                                 cutoff_hz=cutoff_hz, rate_hz=rate_hz, name=doc.stem)


def read_euroc(source: Source, *, cutoff_hz: float = DEFAULT_CUTOFF_HZ,
               rate_hz: float | None = None) -> Trajectory:
    """An EuRoC ground-truth CSV (ns timestamps, position, w-first quaternion) as V's trajectory."""
    doc = document(source)
    table = split_rows(doc, ",")
    n_cols = len(table.rows[0])
    if n_cols < 8:
        raise RouteError(f"expected at least 8 columns (timestamp, p_xyz, q_wxyz), got {n_cols}",
                         source=table.source, line=table.lines[0])
    d = numbers(table, (n_cols,))
    _check_count(len(d), MIN_POSES, "poses", table.source, table.lines)
    # Integer nanoseconds: subtract the first stamp exactly before converting to seconds.
    try:
        ns = np.array([int(r[0]) for r in table.rows], dtype=np.int64)
    except ValueError:
        ns = np.round(d[:, 0]).astype(np.int64)
    t = (ns - ns[0]).astype(float) * 1e-9
    _check_times(t, table.source, table.lines)
    check_timed(t, d[:, 1:4], rate_hz, table.source, table.lines, cutoff_hz)
    q = _quaternions(d[:, 4:8], table.source, table.lines, 5)
    R = Rotation.from_quat(q, scalar_first=True).as_matrix()
    return trajectory_from_poses(t, d[:, 1:4], R, cutoff_hz=cutoff_hz, rate_hz=rate_hz,
                                 name=doc.stem)


def read_kitti(source: Source, times: Source, *, cutoff_hz: float = DEFAULT_CUTOFF_HZ,
               rate_hz: float | None = None) -> Trajectory:
    """KITTI camera poses (12 numbers per line) with their times file, as V's trajectory.

    The camera frame is mapped to vehicle axes (x forward, y left, z up) and the world is the
    first *vehicle* frame, so it is z-up as far as the first camera was level.
    """
    doc, tdoc = document(source), document(times)
    table = split_rows(doc, None)
    d = numbers(table, (12,))
    ttable = split_rows(tdoc, None)
    t = numbers(ttable, (1,))[:, 0]
    if len(t) != len(d):
        raise RouteError(f"{len(t)} times for {len(d)} poses in {doc.name}", source=tdoc.label,
                         line=ttable.lines[min(len(t), len(d)) - 1])
    _check_count(len(d), MIN_POSES, "poses", table.source, table.lines)
    _check_times(t, ttable.source, ttable.lines)
    check_timed(t, d[:, [3, 7, 11]], rate_hz, table.source, table.lines, cutoff_hz)
    T = d.reshape(-1, 3, 4)
    R_W_C, p_W_C = T[:, :, :3], T[:, :, 3]
    err = np.abs(np.swapaxes(R_W_C, 1, 2) @ R_W_C - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R_W_C)
    bad = (err > ROTATION_TOL) | (det <= 0)
    if bad.any():
        k = int(np.argmax(bad))
        raise RouteError(f"the 3x3 block is not a rotation (|RᵀR − I| = {err[k]:.3g}, "
                         f"det = {det[k]:.3g}; tolerance {ROTATION_TOL:g})", source=table.source,
                         line=table.lines[k])
    R = R_CAM_VEH.T @ R_W_C @ R_CAM_VEH
    p = p_W_C @ R_CAM_VEH  # R_CAM_VEHᵀ p, row-wise
    return trajectory_from_poses(t, p, Rotation.from_matrix(R).as_matrix(), cutoff_hz=cutoff_hz,
                                 rate_hz=rate_hz, name=doc.stem)


# --------------------------------------------------------------------------------------------
# Routes: waypoints, GeoJSON, control profiles


def route_from_waypoints(points_m: np.ndarray, speeds_mps: np.ndarray | None = None,
                         limits: Limits = Limits(), suspension: Suspension = Suspension(),
                         name: str = "route") -> Trajectory:
    """The drive along a C2 path through ``points_m`` (n, 2|3).

    With ``speeds_mps`` (one per point), v² is linear in arc length between points; without, the
    fastest drive within ``limits`` (from and to rest, see
    :func:`~excite.motion.paths.plan_speed`). Curvature beyond the limit is not corrected: it is
    reported by :func:`~excite.motion.vehicle.check_limits`.
    """
    pts = np.asarray(points_m, dtype=float)
    path = smooth_path(pts)
    if speeds_mps is None:
        plan = plan_speed(path, limits)
    else:
        chord = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        s_pts = np.concatenate([[0.0], np.cumsum(chord)]) * path.length_m / chord.sum()
        v = np.sqrt(np.interp(path.s_m, s_pts, np.asarray(speeds_mps, dtype=float) ** 2))
        plan = plan_given_speed(path, v)
    traj = drive(profile_from_plan(path, plan, name=name), suspension)
    z0 = float(pts[0, 2]) if pts.shape[1] == 3 else 0.0
    return traj if z0 == 0.0 else traj.transformed(np.eye(3), [0.0, 0.0, z0])


_WAYPOINT_COLS = {"x": "x", "x_m": "x", "y": "y", "y_m": "y", "z": "z", "z_m": "z",
                  "speed": "speed", "speed_mps": "speed"}


def _check_waypoints(xyz: np.ndarray, speed: np.ndarray | None, source: str,
                     lines: list[int]) -> None:
    _check_count(len(xyz), 2, "waypoints", source, lines)
    check_range(xyz[:, :2], "position_m", "coordinate", source, lines)
    check_range(xyz[:, 2], "altitude_m", "altitude", source, lines)
    step = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    if np.any(step < 1e-3):
        k = int(np.argmax(step < 1e-3)) + 1
        raise RouteError("waypoint repeats the previous one (closer than 1 mm)", source=source,
                         line=lines[k])
    if speed is not None:
        if np.any(speed < 0):
            k = int(np.argmax(speed < 0))
            raise RouteError(f"negative speed {speed[k]:g} m/s", source=source, line=lines[k])
        check_range(speed, "speed_mps", "speed", source, lines)
        both = (speed[1:] == 0) & (speed[:-1] == 0)
        if both.any():
            k = int(np.argmax(both)) + 1
            raise RouteError("speed is 0 here and at the previous waypoint: the vehicle would "
                             "never get there", source=source, line=lines[k])


def read_waypoints_csv(source: Source, *, limits: Limits = Limits(),
                       suspension: Suspension = Suspension()) -> Trajectory:
    """A waypoints CSV ``x,y[,z][,speed]`` as a drive (see the module notes)."""
    doc = document(source)
    table = split_rows(doc, ",", header=True)
    if table.header is not None:
        unknown = [h for h in table.header if h not in _WAYPOINT_COLS]
        names = [_WAYPOINT_COLS.get(h) for h in table.header]
        if unknown or names[:2] != ["x", "y"] or len(set(names)) != len(names):
            raise RouteError(f"a header must be x,y[,z][,speed] (waypoints) or t_s,speed_mps,curvature_1pm"
                             f"[,grade_rad][,bank_rad] (controls), got {','.join(table.header)}",
                             source=table.source, line=table.header_line)
        d = numbers(table)
    else:
        d = numbers(table, (2, 3, 4))
        names = ["x", "y", "z", "speed"][: d.shape[1]]
    cols = {n: d[:, i] for i, n in enumerate(names)}
    xyz = np.column_stack([cols["x"], cols["y"], cols.get("z", np.zeros(len(d)))])
    speed = cols.get("speed")
    _check_waypoints(xyz, speed, table.source, table.lines)
    with _located(doc.label):
        return route_from_waypoints(xyz, speed, limits, suspension, name=doc.stem)


def _json_line(text: str, pattern: str) -> int | None:
    m = re.search(pattern, text)
    return None if m is None else text.count("\n", 0, m.start()) + 1


def read_geojson(source: Source, *, limits: Limits = Limits(),
                 suspension: Suspension = Suspension()) -> Trajectory:
    """A GeoJSON LineString (lon/lat[/alt]) projected about its first point, as a drive."""
    from pyproj import Transformer

    source_doc = document(source)
    src, text = source_doc.label, source_doc.text
    if not text.strip():
        raise RouteError("the file is empty", source=src)
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RouteError(f"not valid JSON: {exc.msg}", source=src, line=exc.lineno) from None
    except RecursionError:
        raise RouteError("the JSON is nested too deeply to be a GeoJSON LineString", source=src) from None
    geom, props = doc, {}
    if isinstance(doc, dict) and doc.get("type") == "FeatureCollection":
        feats = doc.get("features") or []
        if len(feats) != 1:
            raise RouteError(f"a FeatureCollection must hold exactly one LineString feature, "
                             f"got {len(feats)} features", source=src,
                             line=_json_line(text, r'"features"'))
        doc = feats[0]
    if isinstance(doc, dict) and doc.get("type") == "Feature":
        geom, props = doc.get("geometry") or {}, doc.get("properties") or {}
    gtype = geom.get("type") if isinstance(geom, dict) else None
    if gtype != "LineString":
        raise RouteError(f"the geometry is {gtype!r}, not a LineString", source=src,
                         line=_json_line(text, rf'"type"\s*:\s*"{gtype}"') if gtype else None)
    coords = geom.get("coordinates")
    cline = _json_line(text, r'"coordinates"')
    if not isinstance(coords, list) or not coords:
        raise RouteError("the LineString has no coordinates", source=src, line=cline)
    dims = {len(c) if isinstance(c, list) else -1 for c in coords}
    if not dims <= {2, 3} or len(dims) != 1:
        raise RouteError("every coordinate must be [lon, lat] or [lon, lat, alt], all alike",
                         source=src, line=cline)
    try:
        ll = np.array(coords, dtype=float)
    except (TypeError, ValueError):
        raise RouteError("a coordinate is not a number", source=src, line=cline) from None
    if not np.all(np.isfinite(ll)):
        raise RouteError("a coordinate is NaN or infinite", source=src, line=cline)
    if np.any(np.abs(ll[:, 0]) > 180) or np.any(np.abs(ll[:, 1]) > 90):
        raise RouteError("coordinates must be [lon, lat] in degrees (|lon| ≤ 180, |lat| ≤ 90)",
                         source=src, line=cline)
    lon0, lat0 = float(ll[0, 0]), float(ll[0, 1])
    tm = Transformer.from_crs("EPSG:4326", f"+proj=tmerc +lat_0={lat0!r} +lon_0={lon0!r} +k=1 "
                              "+x_0=0 +y_0=0 +ellps=WGS84 +units=m", always_xy=True)
    x, y = tm.transform(ll[:, 0], ll[:, 1])
    z = ll[:, 2] - ll[0, 2] if ll.shape[1] == 3 else np.zeros(len(ll))
    xyz = np.column_stack([x, y, z])
    speed = props.get("speed_mps") if isinstance(props, dict) else None
    if speed is not None:
        sline = _json_line(text, r'"speed_mps"')
        try:
            speed = np.broadcast_to(np.asarray(speed, dtype=float), (len(ll),)).copy()
        except (TypeError, ValueError):
            raise RouteError("properties.speed_mps must be a number or one number per point",
                             source=src, line=sline) from None
        if not np.all(np.isfinite(speed)):
            raise RouteError("properties.speed_mps contains NaN or inf", source=src, line=sline)
    # Per-point problems are located at the coordinates key: JSON keeps no positions.
    _check_waypoints(xyz, speed, src, [cline] * len(xyz))
    with _located(source_doc.label):
        return route_from_waypoints(xyz, speed, limits, suspension, name=source_doc.stem)


_CONTROL_COLS = {"t": "t_s", "t_s": "t_s", "speed": "speed_mps", "speed_mps": "speed_mps",
                 "curvature": "curvature_1pm", "curvature_1pm": "curvature_1pm",
                 "grade": "grade_rad", "grade_rad": "grade_rad", "bank": "bank_rad",
                 "bank_rad": "bank_rad"}
_START_RE = re.compile(r"#\s*start:\s*x_m=(\S+)\s+y_m=(\S+)\s+heading_rad=(\S+)")


def read_control_profile(source: Source) -> ControlProfile:
    """A control CSV ``t_s,speed_mps,curvature_1pm[,grade_rad][,bank_rad]`` (header required)."""
    doc = document(source)
    table = split_rows(doc, ",", header=True)
    if table.header is None:
        raise RouteError("a control CSV needs a header naming its columns "
                         "t_s,speed_mps,curvature_1pm[,grade_rad][,bank_rad]",
                         source=table.source, line=table.lines[0])
    names = [_CONTROL_COLS.get(h) for h in table.header]
    if None in names or names[:3] != ["t_s", "speed_mps", "curvature_1pm"] or \
            len(set(names)) != len(names):
        raise RouteError("control CSV header must be t_s,speed_mps,curvature_1pm[,grade_rad]"
                         f"[,bank_rad], got {','.join(table.header)}", source=table.source,
                         line=table.header_line)
    d = numbers(table)
    _check_count(len(d), 2, "knots", table.source, table.lines)
    cols = {n: d[:, i] for i, n in enumerate(names)}
    _check_times(cols["t_s"], table.source, table.lines)
    span = float(cols["t_s"][-1] - cols["t_s"][0])
    if span > bounds.max_duration_s():
        raise RouteError(f"the profile lasts {span:.6g} s, over the limit of {bounds.max_duration_s():g} s",
                         source=table.source, line=table.lines[-1])
    if np.any(cols["speed_mps"] < 0):
        k = int(np.argmax(cols["speed_mps"] < 0))
        raise RouteError(f"negative speed {cols['speed_mps'][k]:g} m/s (reversing is not "
                         "modelled)", source=table.source, line=table.lines[k])
    for name in names:
        check_range(cols[name], name, name, table.source, table.lines)
    start = (0.0, 0.0, 0.0)
    for i, raw in enumerate(doc.text.splitlines(), start=1):
        m = _START_RE.match(raw.strip())
        if m:
            try:
                start = tuple(float(g) for g in m.groups())
            except ValueError:
                raise RouteError("cannot parse the start pose", source=table.source, line=i) from None
            if not all(np.isfinite(start)):
                raise RouteError("the start pose is NaN or infinite", source=table.source, line=i)
            for x, kind, what in zip(start, ("position_m", "position_m", "heading_rad"),
                                     ("start x_m", "start y_m", "start heading_rad")):
                check_range(np.array([x]), kind, what, table.source, [i])
            break
    return ControlProfile(t_s=cols["t_s"], speed_mps=cols["speed_mps"],
                          curvature_1pm=cols["curvature_1pm"], grade_rad=cols.get("grade_rad"),
                          bank_rad=cols.get("bank_rad"), start=start, name=doc.stem)


def read_control_csv(source: Source, *, suspension: Suspension = Suspension()) -> Trajectory:
    """A control CSV driven through :func:`~excite.motion.vehicle.drive`."""
    doc = document(source)
    profile = read_control_profile(doc)
    with _located(doc.label):
        return drive(profile, suspension)


# --------------------------------------------------------------------------------------------
# Dispatch


def _sniff_csv(doc: _Doc) -> str:
    for raw in doc.text.splitlines():
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            if line[1:].strip().lower().startswith("timestamp"):
                return "euroc"
            continue
        fields = [f.strip().lower() for f in line.split(",")]
        if not is_number(fields[0]):
            return "control" if any("curvature" in f for f in fields) else "waypoints"
        return "euroc" if len(fields) >= 8 else "waypoints"
    raise RouteError("the file has no data rows (empty file)", source=doc.label)


def _sniff_txt(doc: _Doc) -> int:
    for raw in doc.text.splitlines():
        line = raw.strip()
        if line and not line.startswith("#"):
            return len(line.split())
    raise RouteError("the file has no data rows (empty file)", source=doc.label)


def read_route(source: Source, times: Source | None = None, limits: Limits = Limits(), *,
               suspension: Suspension = Suspension(), cutoff_hz: float = DEFAULT_CUTOFF_HZ,
               rate_hz: float | None = None, bag: "BagSource | None" = None) -> Trajectory:
    """Any supported route file as a trajectory of V, the format chosen by extension and content.

    ``.geojson``/``.json`` → GeoJSON; ``.tum`` → TUM; ``.txt`` → KITTI (12 columns, needs
    ``times``) or TUM (8 columns); ``.csv`` → EuRoC (``#timestamp`` header or ≥ 8 numeric
    columns), control CSV (header with ``curvature``) or waypoints; ``.bag``, ``.mcap`` or a
    ROS 2 bag folder → :func:`excite.io.bags.read_bag_route` with the topic and options of ``bag``;
    a comma2k19 segment folder → :func:`excite.io.comma2k19.trajectory` (V through the dataset's
    pose, its measured IMU).
    ``limits`` and ``suspension`` shape waypoint, GeoJSON and control routes;
    ``cutoff_hz``/``rate_hz`` the timed-pose fit (bags included).
    """
    timed = {"cutoff_hz": cutoff_hz, "rate_hz": rate_hz}
    label = source.name if isinstance(source, Text) else str(source)
    if not isinstance(source, Text):
        path = Path(source)
        if not path.exists():
            raise FileNotFoundError(2, "No such file or directory", str(path))
        if is_bag(path):
            from .bags import BagSource, read_bag_route

            return read_bag_route(path, **BagSource.required(bag, path).options(), **timed)
        if is_comma2k19(path) and bag is None:
            from .comma2k19 import read_comma2k19, trajectory

            return trajectory(read_comma2k19(path), cutoff_hz=cutoff_hz, rate_hz=rate_hz)
    if bag is not None:
        flags = {"topic": "--topic", "imu_topic": "--imu-topic", "start_s": "--start", "end_s": "--end",
                 "vehicle_frame": "--vehicle-frame", "axes": "--axes", "gnss_topic": "--gnss-topic",
                 "odometry_topic": "--odometry-topic"}
        given = [flag for key, flag in flags.items() if getattr(bag, key) not in (None, "vehicle")]
        raise RouteError(f"bag options ({', '.join(given) or 'none given'}) apply to bags only (.bag, .mcap, "
                         "a ROS 2 bag folder)", source=label)
    doc = document(source)
    ext = doc.suffix
    if times is not None:
        return read_kitti(doc, times, **timed)
    if ext in (".geojson", ".json"):
        return read_geojson(doc, limits=limits, suspension=suspension)
    if ext == ".tum":
        return read_tum(doc, **timed)
    if ext == ".txt":
        n = _sniff_txt(doc)
        if n == 12:
            raise RouteError("looks like KITTI poses (12 columns): pass the times file (--times)",
                             source=doc.label)
        if n == 8:
            return read_tum(doc, **timed)
        raise RouteError(f"cannot tell the format of a .txt with {n} columns (TUM has 8, KITTI 12)",
                         source=doc.label)
    if ext == ".csv":
        kind = _sniff_csv(doc)
        if kind == "euroc":
            return read_euroc(doc, **timed)
        if kind == "control":
            return read_control_csv(doc, suspension=suspension)
        return read_waypoints_csv(doc, limits=limits, suspension=suspension)
    raise RouteError(f"unknown route format {ext or '(no extension)'!r}: use .csv, .tum, .txt "
                     "(KITTI with --times, or TUM), .geojson, or a bag (.bag, .mcap, ROS 2 folder)",
                     source=doc.label)


# --------------------------------------------------------------------------------------------
# Writers


SMOOTH_MARK = "already smooth: read back without smoothing"  # in the first line of what write_tum writes


def already_smooth(source: "Source | _Doc") -> bool:
    """Whether the TUM file's first line is the one :func:`write_tum` writes."""
    if isinstance(source, (_Doc, Text)):
        first = document(source).text[:1000].split("\n", 1)[0]
    else:
        with open(source, encoding="utf-8", errors="replace") as f:
            first = f.readline(1000)
    return first.startswith("# excite ") and SMOOTH_MARK in first


def write_tum(traj: Trajectory, path: str | Path, rate_hz: float = 10.0, as_log: bool = False) -> Path:
    """Write V's poses sampled at ``rate_hz`` as TUM ``t tx ty tz qx qy qz qw``. The first line
    says the poses are already smooth, and :func:`read_tum` then fits them with the widest band
    their rate allows instead of smoothing them again (a second smoothing attenuates the motion:
    a mined window's crop scored 14 % under the window). ``as_log``: without that mark, to stand
    for a logged drive (smoothed when read, as a log is)."""
    path = Path(path)
    s = traj.sample(traj.times(rate_hz))
    q = Rotation.from_matrix(s.R_W_V).as_quat()
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)  # canonical sign: w ≥ 0
    data = np.column_stack([s.t, s.p_W_V + traj.origin, q])  # in the frame its poses came in
    mark = "" if as_log else f", {SMOOTH_MARK}"
    header = f"excite {traj.name}: pose of the vehicle frame V in W{mark}\nt tx ty tz qx qy qz qw"
    np.savetxt(path, data, fmt=["%.6f"] + ["%.6f"] * 3 + ["%.9f"] * 4, header=header)
    return path


def write_waypoints_csv(traj: Trajectory, path: str | Path, spacing_m: float = 2.0) -> Path:
    """Write the path as ``x_m,y_m,z_m,speed_mps`` every ``spacing_m`` of travel (and the end).

    Waypoints carry no time: standstills are lost, the speeds are kept.
    """
    path = Path(path)
    s = traj.sample(traj.times(50.0))
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(s.p_W_V, axis=0), axis=1))])
    targets = np.arange(0.0, dist[-1], spacing_m)
    if dist[-1] - targets[-1] > 0.25 * spacing_m:
        targets = np.append(targets, dist[-1])
    else:
        targets[-1] = dist[-1]
    # Arc length is flat where the car stands still: take the first moment at each distance.
    keep = np.concatenate([[True], np.diff(dist) > 1e-9])
    xyz = np.column_stack([np.interp(targets, dist[keep], s.p_W_V[keep, i]) for i in range(3)]) + traj.origin
    speed = np.interp(targets, dist[keep], np.maximum(s.speed[keep], 0.0))
    np.savetxt(path, np.column_stack([xyz, speed]), fmt="%.4f", delimiter=",",
               header="x_m,y_m,z_m,speed_mps", comments="")
    return path


def control_profile_of(traj: Trajectory, rate_hz: float = 10.0,
                       min_speed_mps: float = 0.5) -> ControlProfile:
    """The control profile (speed, curvature, grade, bank) that reproduces a trajectory.

    Curvature is yaw rate / speed; below ``min_speed_mps`` it is held from the nearest moving
    sample (it is undefined at standstill). Grade and bank are the road frame's pitch and roll.
    """
    s = traj.sample(traj.times(rate_hz))
    u = np.maximum(s.speed, 0.0)
    moving = u >= min_speed_mps
    kappa = np.zeros_like(u)
    if moving.any():
        idx = np.flatnonzero(moving)
        kappa = np.interp(np.arange(u.size), idx, s.yaw_rate[idx] / u[idx])
    ypr = so3.yaw_pitch_roll(s.R_W_A)
    return ControlProfile(t_s=s.t, speed_mps=u, curvature_1pm=kappa, grade_rad=-ypr[:, 1],
                          bank_rad=ypr[:, 2],
                          start=(float(s.p_W_V[0, 0] + traj.origin[0]), float(s.p_W_V[0, 1] + traj.origin[1]),
                                 float(ypr[0, 0])),
                          name=traj.name)


def write_control_csv(source: ControlProfile | Trajectory, path: str | Path,
                      rate_hz: float = 10.0) -> Path:
    """Write a control profile (or the one reproducing a trajectory, at ``rate_hz``) as
    ``t_s,speed_mps,curvature_1pm,grade_rad,bank_rad`` with a ``# start:`` comment."""
    path = Path(path)
    prof = control_profile_of(source, rate_hz) if isinstance(source, Trajectory) else source
    x, y, h = prof.start
    data = np.column_stack([prof.t_s, prof.speed_mps, prof.curvature_1pm, prof.grade_rad,
                            prof.bank_rad])
    with path.open("w", encoding="utf-8") as f:
        f.write(f"# excite control profile {prof.name}\n")
        f.write(f"# start: x_m={x!r} y_m={y!r} heading_rad={h!r}\n")
        f.write("t_s,speed_mps,curvature_1pm,grade_rad,bank_rad\n")
        np.savetxt(f, data, fmt="%.10g", delimiter=",")
    return path

