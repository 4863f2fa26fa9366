"""Scene files: a vector scene in GeoJSON, meshes, point-cloud maps and the bundled example scenes.

:func:`load_scene` reads a file by its suffix, or a bundled scene by its name
(:func:`bundled_scenes`), into a :class:`~excite.scene.model.Scene` in the drive's world frame
(z up, metres):

- **GeoJSON** (``.geojson``, ``.json``): a FeatureCollection in the lot's local metres
  (``"properties": {"crs": "local"}``) or in lon/lat, projected as the optimizer projects a lot
  (:func:`~excite.plan.site.read_site`: transverse Mercator about the lot outline's mean, or
  about the centre of the scene's bounding box when the file has no lot). A feature with a
  ``kind`` or a ``height`` is part of the scene:

  - ``Polygon``/``MultiPolygon`` with ``height`` (and ``base``, default 0): a building
    (``kind`` default ``building``; ``wall``, ``vegetation``, ``vehicle`` …) extruded from its
    outline, inner rings its courtyards; with ``kind: ground`` and ``elevation`` (default 0) a
    level piece of ground, with ``kind: ceiling`` and ``elevation`` a level ceiling facing down;
  - ``LineString``/``MultiLineString`` with ``height`` (and ``base``): a wall or guard rail
    along the line (``kind`` default ``wall``);
  - ``Point``/``MultiPoint`` with ``radius`` and ``height`` (and ``base``): a pole, a cone, a
    tree trunk (``kind`` default ``pole``);

  every one optionally with ``features_per_m2`` (a camera's visual features on it) and a
  ``name``. The features the optimizer reads (the lot outline with its keep-out zones, the entry
  point, ramps, banks, bumps) may stand in the same file: they are checked as the optimizer
  checks them and otherwise passed over. The ground, unless the file has a ``kind: ground``
  feature, is a level rectangle at 0 m over everything in the file (the lot included) and
  :data:`~excite.scene.clouds.GROUND_MARGIN_M` beyond (``ground=False``: none).
- **Meshes** (``.ply`` with faces, ``.obj``, ``.stl``) through ``trimesh``: one surface of kind
  ``mesh``; the ground as for GeoJSON, at the mesh's lowest point, unless ``ground=False``.
- **Point-cloud maps** (``.pcd`` through ``pypcd4``, ``.ply`` without faces through
  ``plyfile``, ``.las``/``.laz`` through ``laspy`` with ``lazrs``, and ``sensor_msgs/PointCloud2``
  messages of a bag or MCAP ``topic``): :func:`scene_from_points` — normals estimated where the
  file has none, every point a small square splat along its normal, so that the ray caster sees
  the map. A map holds its own ground.

Every size is bounded before it is allocated (the file, the points a header declares, the
vertices of an outline, the triangles of the whole scene), every number checked (a NaN vertex, an
absurd LAS scale, a negative height), and each refusal is a :class:`~excite.errors.SceneError`
naming the file and the field; nothing is returned half-loaded.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..core import bounds
from ..errors import SceneError
from . import shapes
from .clouds import GROUND_MARGIN_M, MAX_MESH_BYTES, read_bounded  # noqa: F401 (part of this module's interface)
from .model import SURFACE_KINDS, Scene, Surface
from .points import scene_from_points  # noqa: F401 (part of this module's interface)

BUNDLED = Path(__file__).resolve().parent / "bundled"
"""Where the bundled example scenes are (one GeoJSON file each)."""

GEOJSON_SUFFIXES = (".geojson", ".json")
MESH_SUFFIXES = (".obj", ".stl")
CLOUD_SUFFIXES = (".pcd", ".las", ".laz")
SUFFIXES = GEOJSON_SUFFIXES + (".ply",) + MESH_SUFFIXES + CLOUD_SUFFIXES
"""The suffixes :func:`load_scene` reads (a ``.ply`` is a mesh when it has faces, else a map)."""

MAX_GEOJSON_BYTES = 64 * 2**20
"""Largest GeoJSON scene file [bytes]."""
MAX_FEATURE_HEIGHT_M = 1000.0
"""Tallest building, wall or pole [m]."""
MAX_ELEVATION_M = 10_000.0
"""Largest |base| or |elevation| of a feature [m]."""
MAX_RADIUS_M = 50.0
"""Largest radius of a pole or tree [m]."""
MAX_LONLAT_SPAN_DEG = 0.5
"""Largest span of a lon/lat scene in either coordinate (a scene spans at most 20 km)."""
POLE_SIDES = 12
"""Faces around a pole, a cone or a tree trunk."""

# --------------------------------------------------------------------------------------------
# Entry points


def bundled_scenes() -> list[str]:
    """The names of the bundled example scenes (each loads with :func:`load_scene`)."""
    return sorted(p.stem for p in BUNDLED.glob("*.geojson"))


def load_scene(path: str | Path, *, data: bytes | None = None, ground: bool = True,
               topic: str | None = None) -> Scene:
    """The scene in ``path`` (a file by its suffix, a bundled scene by its name, or a bag with
    the ``topic`` of its ``sensor_msgs/PointCloud2`` map); ``data``: the file's bytes when they
    are not on disk (``path`` then only names it and gives its suffix); ``ground``: add the
    ground where the file describes none (see the module docstring)."""
    name = str(path)
    if data is None and name in bundled_scenes():
        file = BUNDLED / f"{name}.geojson"
        return read_geojson(file.read_bytes(), source=name, ground=ground)
    p = Path(path)
    if data is None:
        from ..io.sniff import is_bag

        if is_bag(p) and p.exists():
            if not topic:
                raise SceneError("a bag holds a map on a topic: name its sensor_msgs/PointCloud2 topic", source=name)
            from .clouds import read_bag_map

            return read_bag_map(p, topic)
    suffix = p.suffix.lower()
    if suffix not in SUFFIXES:
        if data is None and not p.exists() and not suffix:
            raise SceneError(f"no such file or bundled scene (bundled: {', '.join(bundled_scenes())})", source=name)
        raise SceneError(f"cannot read a {suffix or 'file without a suffix'} as a scene (expected "
                         f"{', '.join(SUFFIXES)}, a bag with a topic, or a bundled scene)", source=name)
    if suffix in GEOJSON_SUFFIXES:
        return read_geojson(read_bounded(p, data, MAX_GEOJSON_BYTES), source=name, ground=ground)
    from . import clouds

    return clouds.read(p, data, suffix, ground=ground)


# --------------------------------------------------------------------------------------------
# GeoJSON

SCENE_PROPERTIES = ("kind", "height")
"""Properties that make a GeoJSON feature part of the scene, not of the lot the optimizer reads."""


def is_scene_feature(props: dict[str, Any]) -> bool:
    """Whether a feature with these ``properties`` describes the scene (a building, a wall, a
    pole: it has a ``kind`` or a ``height``) rather than the lot, its entry or its terrain."""
    return any(k in props for k in SCENE_PROPERTIES)



def _refuse_constant(name: str):
    raise ValueError(f"{name} is not a number JSON allows")


def read_geojson(text: bytes | str, *, source: str = "scene.geojson", ground: bool = True) -> Scene:
    """A vector scene from GeoJSON text (see the module docstring)."""
    if isinstance(text, bytes):
        if len(text) > MAX_GEOJSON_BYTES:
            raise SceneError(f"{len(text):,} bytes: more than the {MAX_GEOJSON_BYTES:,} a GeoJSON scene may have",
                             source=source)
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise SceneError(f"not UTF-8 text (byte {exc.start})", source=source) from None
    try:
        doc = json.loads(text, parse_constant=_refuse_constant)
    except json.JSONDecodeError as exc:
        raise SceneError(f"not valid JSON: {exc.msg} (line {exc.lineno})", source=source) from None
    except (ValueError, RecursionError) as exc:
        raise SceneError(f"not valid JSON: {exc if isinstance(exc, ValueError) else 'nested too deeply'}",
                         source=source) from None
    return _Vector(doc, source).scene(ground)


def _show(v: Any) -> str:
    text = json.dumps(v) if isinstance(v, (list, dict, str, int, float, bool)) or v is None else repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


_DEFAULT_KIND = {"Polygon": "building", "MultiPolygon": "building", "LineString": "wall",
                 "MultiLineString": "wall", "Point": "pole", "MultiPoint": "pole"}
_POLYGON_KINDS = tuple(k for k in SURFACE_KINDS if k not in ("map", "mesh"))


class _Vector:
    """One GeoJSON document walked: every scene feature checked and kept as arrays in the file's
    units (:attr:`parts`), the lot features handed to the optimizer's reader; then projected and
    built (:meth:`scene`)."""

    def __init__(self, doc: Any, source: str):
        self.source = source
        self.parts: list[tuple[str, str, dict, list[np.ndarray], str]] = []  # geometry, kind, numbers, arrays, name
        self.triangles = 0
        if not isinstance(doc, dict):
            self.fail("", "expected a GeoJSON object")
        collection = doc.get("type") == "FeatureCollection"
        feats = doc.get("features") if collection else [doc]
        if not isinstance(feats, list):
            self.fail("features", f"must be a list, got {_show(feats)}")
        top = doc.get("properties") if collection else None
        if top is not None and not isinstance(top, dict):
            self.fail("properties", f"must be an object, got {_show(top)}")
        self.local = (top or {}).get("crs") == "local"
        self.lot_features = 0
        for i, f in enumerate(feats):
            where = f"features[{i}]" if collection else "feature"
            if not isinstance(f, dict):
                self.fail(where, f"a feature must be an object, got {_show(f)}")
            if f.get("type") != "Feature":
                f = {"type": "Feature", "geometry": f, "properties": {}}
            props = f.get("properties")
            props = {} if props is None else props
            if not isinstance(props, dict):
                self.fail(f"{where}.properties", f"must be an object, got {_show(props)}")
            if props.get("crs") == "local":
                self.local = True
            if not is_scene_feature(props):
                self.lot_features += 1
                continue
            geom = f.get("geometry")
            if not isinstance(geom, dict):
                self.fail(f"{where}.geometry", f"must be an object, got {_show(geom)}")
            self.feature(where, props, geom)
        self.doc = doc

    def fail(self, field: str, problem: str):
        raise SceneError(f"{field}: {problem}" if field else problem, source=self.source)

    def number(self, where: str, props: dict, key: str, default: float | None, lo: float, hi: float,
               lo_open: bool = False) -> float:
        v = props.get(key, default)
        field = f"{where}.properties.{key}"
        if v is None:
            self.fail(field, "is required")
        try:
            ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) and \
                (lo < v if lo_open else lo <= v) and v <= hi
        except OverflowError:
            ok = False
        if not ok:
            shown = _show(v) if not isinstance(v, int) or abs(v) < 10**20 else f"an integer of {len(str(abs(v)))} digits"
            bound = f"above {lo:g}" if lo_open else f"at least {lo:g}"
            self.fail(field, f"{shown}: must be a number {bound} and at most {hi:g}")
        return float(v)

    def positions(self, field: str, coords: Any, least: int) -> np.ndarray:
        """A list of positions as K × 2 (a third value ignored), counted before it is converted."""
        if not isinstance(coords, list):
            self.fail(field, f"must be an array of positions, got {_show(coords)}")
        if len(coords) > shapes.MAX_POLYGON_VERTICES:
            self.fail(field, f"{len(coords):,} vertices: more than the {shapes.MAX_POLYGON_VERTICES:,} "
                             "one outline or line may have")
        try:
            a = np.array(coords, dtype=float)
        except (ValueError, TypeError):
            a = None
        if a is None or a.ndim != 2 or a.shape[1] not in (2, 3) or any(
                isinstance(v, bool) for c in coords for v in c):
            self.fail(field, "each position must be [x, y] or [x, y, z] (numbers)")
        if not np.all(np.isfinite(a)):
            k = int(np.flatnonzero(~np.all(np.isfinite(a), axis=1))[0])
            self.fail(f"{field}[{k}]", "not a finite number")
        a = a[:, :2]
        if a.shape[0] > 1 and np.array_equal(a[0], a[-1]) and least >= 3:
            a = a[:-1]
        if a.shape[0] < least:
            self.fail(field, f"{a.shape[0]} distinct positions: at least {least} needed")
        return a

    def count(self, where: str, n: int) -> None:
        self.triangles += n
        if self.triangles > bounds.MAX_SCENE_TRIANGLES:
            self.fail(where, f"the scene would pass the {bounds.MAX_SCENE_TRIANGLES:,} triangles a scene may hold")

    def feature(self, where: str, props: dict, geom: dict) -> None:
        gtype = geom.get("type")
        coords = geom.get("coordinates")
        field = f"{where}.geometry.coordinates"
        if gtype not in _DEFAULT_KIND:
            self.fail(f"{where}.geometry.type", f"{_show(gtype)}: a scene feature is a Polygon, a LineString or a "
                                                "Point (or their Multi- forms)")
        kind = props.get("kind", _DEFAULT_KIND[gtype])
        allowed = _POLYGON_KINDS if gtype.endswith("Polygon") else \
            tuple(k for k in _POLYGON_KINDS if k not in ("ground", "ceiling"))
        if kind not in allowed:
            self.fail(f"{where}.properties.kind", f"{_show(kind)}: a {gtype} is one of {', '.join(allowed)}")
        name = props.get("name", "")
        if not isinstance(name, str) or len(name) > 200:
            self.fail(f"{where}.properties.name", "must be a text of at most 200 characters")
        nums = {"features_per_m2": self.number(where, props, "features_per_m2", 2.0 if kind == "ground" else 1.0,
                                               0.0, 1e4)}
        if kind in ("ground", "ceiling"):
            nums["elevation"] = self.number(where, props, "elevation", 0.0 if kind == "ground" else None,
                                            -MAX_ELEVATION_M, MAX_ELEVATION_M)
        else:
            nums["height"] = self.number(where, props, "height", None, 0.0, MAX_FEATURE_HEIGHT_M, lo_open=True)
            nums["base"] = self.number(where, props, "base", 0.0, -MAX_ELEVATION_M, MAX_ELEVATION_M)
        if gtype.startswith("Point") or gtype == "MultiPoint":
            nums["radius"] = self.number(where, props, "radius", None, 0.0, MAX_RADIUS_M, lo_open=True)
        multi = gtype.startswith("Multi")
        items = coords if multi else [coords]
        if not isinstance(items, list) or (multi and not items):
            self.fail(field, f"must be an array, got {_show(coords)}")
        arrays: list = []
        for j, item in enumerate(items):
            f_j = f"{field}[{j}]" if multi else field
            if gtype.endswith("Polygon"):
                if not isinstance(item, list) or not item:
                    self.fail(f_j, f"a polygon is an array of rings, got {_show(item)}")
                rings = [self.positions(f"{f_j}[{r}]", ring, 3) for r, ring in enumerate(item)]
                k = sum(r.shape[0] for r in rings)
                if k > shapes.MAX_POLYGON_VERTICES:
                    self.fail(f_j, f"{k:,} vertices: more than the {shapes.MAX_POLYGON_VERTICES:,} one polygon may have")
                self.count(f_j, k + 2 * len(rings) + (0 if kind in ("ground", "ceiling") else 2 * k))
                arrays.append(rings)
            elif gtype.endswith("LineString"):
                line = self.positions(f_j, item, 2)
                self.count(f_j, 2 * (line.shape[0] - 1))
                arrays.append(line)
            else:
                p = self.positions(f_j, [item], 1)
                self.count(f_j, 3 * POLE_SIDES)
                arrays.append(p[0])
        self.parts.append((gtype.removeprefix("Multi"), kind, nums, arrays, name or where))

    # --- projection and building ---------------------------------------------------------------

    def _lot(self) -> "tuple[tuple[float, float] | None, list[np.ndarray]] | None":
        """The lot the file may carry for the optimizer (the Polygon feature of role ``lot``, as
        :func:`excite.plan.site.read_site` reads it): its origin (the mean of its outline's
        vertices, lon/lat; None in local metres) and its rings, in the file's coordinates."""
        if not self.lot_features:
            return None
        collection = self.doc.get("type") == "FeatureCollection"
        for i, f in enumerate(self.doc.get("features") if collection else [self.doc]):
            if f.get("type") != "Feature":
                continue
            props, geom = f.get("properties") or {}, f.get("geometry")
            if is_scene_feature(props) or not isinstance(geom, dict) or geom.get("type") != "Polygon":
                continue
            role = props.get("role", "lot")
            if role in ("ramp", "bank", "bump"):
                continue
            if role != "lot":
                self.fail(f"features[{i}].properties.role" if collection else "properties.role",
                          f"{_show(role)}: a polygon without a kind or a height is the lot (role \"lot\") or its "
                          "terrain (\"ramp\", \"bank\", \"bump\")")
            where = f"features[{i}].geometry.coordinates" if collection else "geometry.coordinates"
            rings = geom.get("coordinates")
            if not isinstance(rings, list) or not rings:
                self.fail(where, "a lot needs its outline (a list of rings)")
            out = []
            for k, ring in enumerate(rings):
                try:
                    r = np.asarray(ring, dtype=float)
                except (TypeError, ValueError):
                    self.fail(f"{where}[{k}]", "a ring must be a list of [x, y] positions")
                if r.ndim != 2 or r.shape[1] < 2 or r.shape[0] < 3 or not np.all(np.isfinite(r)):
                    self.fail(f"{where}[{k}]", "a ring must be at least 3 finite [x, y] positions")
                if r.shape[0] > shapes.MAX_POLYGON_VERTICES:
                    self.fail(f"{where}[{k}]", f"{r.shape[0]} vertices, over the limit of {shapes.MAX_POLYGON_VERTICES}")
                r = r[:, :2]
                out.append(r[:-1] if r.shape[0] > 3 and np.array_equal(r[0], r[-1]) else r)
            origin = None if self.local else (float(out[0][:, 0].mean()), float(out[0][:, 1].mean()))
            return origin, out
        return None

    def _every(self):
        for gtype, _, _, arrays, _ in self.parts:
            for a in arrays:
                if gtype == "Polygon":
                    yield from a
                else:
                    yield np.atleast_2d(a)

    def scene(self, ground: bool) -> Scene:
        lot = self._lot()
        if not self.local:
            pts = [a for a in self._every()]
            if pts:
                every = np.vstack(pts)
                if not (np.all(np.abs(every[:, 0]) <= 180) and np.all(np.abs(every[:, 1]) <= 85)):
                    self.fail("coordinates", "must be [lon, lat] in degrees within ±180° and ±85° (or set "
                                             "properties.crs to \"local\" for metres)")
                span = np.ptp(every, axis=0)
                if span.max() > MAX_LONLAT_SPAN_DEG:
                    self.fail("coordinates", f"span {span[0]:.3g}° of longitude and {span[1]:.3g}° of latitude, "
                                             f"over the limit of {MAX_LONLAT_SPAN_DEG:g}°")
                origin = lot[0] if lot is not None else tuple(0.5 * (every.min(axis=0) + every.max(axis=0)))
                from ..io.geo import Projection

                to_local = Projection(origin).to_local
                if lot is not None:
                    lot = (lot[0], [to_local(r) for r in lot[1]])
                self.parts = [(g, k, n, [[to_local(r) for r in a] if g == "Polygon" else
                                         (to_local(np.atleast_2d(a)) if g == "LineString" else
                                          to_local(np.atleast_2d(a))[0]) for a in arrays], nm)
                              for g, k, n, arrays, nm in self.parts]
        pieces = [self.build(*part) for part in self.parts]
        has_ground = any(k == "ground" for _, k, _, _, _ in self.parts)
        if ground and not has_ground:
            xy = [a for a in self._every()]
            if lot is not None:
                xy += list(lot[1])
            if not xy:
                self.fail("features", "nothing to place a ground under: no feature")
            every = np.vstack(xy)
            lo, hi = every.min(axis=0) - GROUND_MARGIN_M, every.max(axis=0) + GROUND_MARGIN_M
            pieces.insert(0, shapes.ground(lo[0], lo[1], hi[0], hi[1], 0.0))
        if not pieces:
            self.fail("features", "no scene feature (a kind or a height) and no ground")
        try:
            return Scene.combine(pieces, source=self.source)
        except SceneError as exc:
            raise SceneError(exc.problem, source=self.source) from None

    def build(self, gtype: str, kind: str, nums: dict, arrays: list, name: str) -> Scene:
        surface = Surface(kind, name, nums["features_per_m2"])
        v, f = [], []
        nv = 0
        if gtype == "Point":
            arrays = [np.array(arrays)]
        for a in arrays:
            if gtype == "Polygon":
                verts, faces = _polygon(a, kind, nums, name, self.source)
            elif gtype == "LineString":
                verts, faces = _strip(a, nums["base"], nums["height"])
            else:
                verts, faces = _poles(a, nums["radius"], nums["base"], nums["height"])
            v.append(verts)
            f.append(faces + nv)
            nv += verts.shape[0]
        faces = np.vstack(f)
        return Scene(np.vstack(v), faces, np.zeros(faces.shape[0], dtype=np.int64), (surface,), source=self.source)


def _polygon_faces(rings: list[np.ndarray], name: str, source: str) -> np.ndarray:
    """Triangles of a polygon with holes (indices into its rings stacked)."""
    import mapbox_earcut

    ends = np.cumsum([r.shape[0] for r in rings]).astype(np.uint32)
    tri = mapbox_earcut.triangulate_float64(np.vstack(rings), ends)
    if tri.size == 0:
        raise SceneError(f"{name}: the outline encloses no area (self-intersecting or collinear)", source=source)
    return np.asarray(tri, dtype=np.int64).reshape(-1, 3)


def _polygon(rings: list[np.ndarray], kind: str, nums: dict, name: str, source: str):
    every = np.vstack(rings)
    if kind in ("ground", "ceiling"):
        faces = _polygon_faces(rings, name, source)
        v = np.column_stack([every, np.full(every.shape[0], nums["elevation"])])
        up = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])[:, 2]
        flip = (up < 0) if kind == "ground" else (up > 0)
        faces[flip] = faces[flip][:, ::-1]
        return v, faces
    base, top = nums["base"], nums["base"] + nums["height"]
    v, f = [], []
    nv = 0
    for r in rings:
        verts, faces = _strip(np.vstack([r, r[:1]]), base, nums["height"])
        v.append(verts)
        f.append(faces + nv)
        nv += verts.shape[0]
    roof = _polygon_faces(rings, name, source) + nv
    v.append(np.column_stack([every, np.full(every.shape[0], top)]))
    f.append(roof)
    return np.vstack(v), np.vstack(f)


def _poles(centres: np.ndarray, radius: float, base: float, height: float):
    """Vertical cylinders of :data:`POLE_SIDES` faces and a flat top about each of the centres (P × 2)."""
    S = POLE_SIDES
    a = np.linspace(0.0, 2 * np.pi, S, endpoint=False)
    ring = radius * np.column_stack([np.cos(a), np.sin(a)])
    P = centres.shape[0]
    xy = (centres[:, None, :] + ring[None]).reshape(-1, 2)
    lo = np.column_stack([xy, np.full(P * S, base)]).reshape(P, S, 3)
    hi = lo + np.array([0.0, 0.0, height])
    v = np.concatenate([lo, hi], axis=1).reshape(-1, 3)
    i = np.arange(S)
    j = (i + 1) % S
    k = np.arange(1, S - 1)
    one = np.vstack([np.column_stack([i, j, j + S]), np.column_stack([i, j + S, i + S]),
                     np.column_stack([np.full(S - 2, S), k + S, k + 1 + S])])
    faces = (one[None] + (2 * S * np.arange(P))[:, None, None]).reshape(-1, 3)
    return v, faces


def _strip(line: np.ndarray, base: float, height: float):
    """A vertical strip from ``base`` to ``base + height`` along a line of K points (K × 2)."""
    K = line.shape[0]
    v = np.vstack([np.column_stack([line, np.full(K, base)]), np.column_stack([line, np.full(K, base + height)])])
    a = np.arange(K - 1)
    return v, np.vstack([np.column_stack([a, a + 1, a + 1 + K]), np.column_stack([a, a + 1 + K, a + K])])

