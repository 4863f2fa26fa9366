"""The test lot: where the maneuver may drive.

A :class:`Site` is the drivable area (a polygon in local metres, non-convex allowed, holes are
keep-out zones) with the edge margin the path of the rear axle keeps, optionally an entry pose
(where the maneuver starts and, with ``closed``, ends), terrain features (:mod:`.terrain`) and
the WGS84 origin of the local frame when the lot came from a map.

The optimizer sees the lot through :meth:`Site.clearance`: a smooth (cubic B-spline) signed
distance to the nearest edge or hole, positive inside, sampled on a grid — one smooth
constraint ``clearance(x, y) ≥ margin`` per sample point, whatever the lot's shape. The
independent check (:meth:`Site.violations`) uses exact point-in-polygon and edge distances.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from ..core import bounds
from ..motion.maneuvers import EDGE_MARGIN_M, Lot
from ..motion.vehicle import ControlProfile
from ..errors import OptimizeError
from ..io.geo import Projection
from ..scene.files import is_scene_feature
from .terrain import Terrain

ENTRY_TOL_M = 0.5  # the drive starts within this distance of the entry point ...
ENTRY_TOL_RAD = math.radians(5.0)  # ... and this angle of the entry heading
_SDF_CELLS = 160  # grid cells along the longer side of the lot for the clearance spline


@dataclass(frozen=True)
class Site:
    """A lot (``lot``: outer polygon and holes, local metres) and what belongs to it.

    ``entry``: (x, y, heading) where the maneuver starts, or None (anywhere inside).
    ``origin``: (lon, lat) of the local frame's origin (transverse Mercator about it), or None.
    """

    lot: Lot
    margin_m: float = EDGE_MARGIN_M
    entry: tuple[float, float, float] | None = None
    terrain: Terrain = field(default_factory=Terrain)
    origin: tuple[float, float] | None = None

    def outline(self) -> dict[str, Any]:
        """The site in local metres as plain data (what a map draws): ``polygon`` and ``holes``
        as lists of [x, y], ``entry`` as [x, y, heading] or None, ``terrain`` as a list of
        ``{role, polygon}``, and the ``margin_m``."""
        def ring(a) -> list[list[float]]:
            return [[round(float(x), 3), round(float(y), 3)] for x, y in np.asarray(a)]

        return {"polygon": ring(self.lot.polygon_m), "holes": [ring(h) for h in self.lot.holes],
                "entry": None if self.entry is None else [float(v) for v in self.entry],
                "terrain": [{"role": f.role, "polygon": ring(f.polygon_m)} for f in self.terrain.features],
                "margin_m": float(self.margin_m)}

    @classmethod
    def rectangle(cls, length_m: float, width_m: float, **kw: Any) -> "Site":
        """``length_m`` along x × ``width_m`` along y, centred on the origin."""
        return cls(Lot.rectangle(length_m=length_m, width_m=width_m), **kw)

    @property
    def extent_m(self) -> tuple[float, float]:
        """Size of the bounding box (along x, along y)."""
        p = self.lot.polygon_m
        return float(np.ptp(p[:, 0])), float(np.ptp(p[:, 1]))

    @property
    def centre_m(self) -> np.ndarray:
        p = self.lot.polygon_m
        return 0.5 * (p.min(axis=0) + p.max(axis=0))

    def place(self, profile: ControlProfile, centre_m=None, angle_rad: float = 0.0) -> ControlProfile:
        """A maneuver generated about the origin, turned by ``angle_rad`` and moved to
        ``centre_m`` (default: the centre of the lot's bounding box)."""
        x, y, h = profile.start
        c = self.centre_m if centre_m is None else np.asarray(centre_m, dtype=float)
        ca_, sa = math.cos(angle_rad), math.sin(angle_rad)
        return ControlProfile(profile.t_s, profile.speed_mps, profile.curvature_1pm, profile.grade_rad,
                              profile.bank_rad, (float(c[0] + ca_ * x - sa * y), float(c[1] + sa * x + ca_ * y),
                                                 h + angle_rad), profile.name)

    def reach_m(self, centre_m: np.ndarray, direction: np.ndarray) -> float:
        """How far from ``centre_m`` the lot extends (with the margin) both ways along
        ``direction``: the smaller of the two reaches."""
        t = np.arange(0.0, float(np.ptp(self.lot.polygon_m, axis=0).max()), 0.5)
        reach = []
        for sgn in (1.0, -1.0):
            ok = self.lot.contains(centre_m + sgn * t[:, None] * direction, self.margin_m)
            reach.append(float(t[np.argmin(ok)] if not ok.all() else t[-1]))
        return min(reach)

    def violations(self, traj, profile: ControlProfile, t_s: np.ndarray) -> list[str]:
        """Where the drive ``traj`` (of ``profile``), sampled at ``t_s``, leaves the lot, comes
        closer than the margin to an edge or a keep-out zone, does not start at the entry pose,
        or disagrees with the terrain under it."""
        out = []
        smp = traj.sample(t_s)
        p_W = smp.p_W_V
        # 1 cm: a reference maneuver generated exactly at the margin is not a violation
        ok = self.lot.contains(p_W, self.margin_m - 0.01)
        if not ok.all():
            k = int(np.argmin(ok))
            d = float(self.lot.clearance_m(p_W[k:k + 1])[0])
            out.append(f"lot: the path comes within {d:.2f} m of the lot's edge or a keep-out zone "
                       f"(margin {self.margin_m:g} m) at t={t_s[k]:.2f} s (x={p_W[k, 0]:.1f} m, "
                       f"y={p_W[k, 1]:.1f} m)")
        if self.entry is not None:
            d = float(np.hypot(p_W[0, 0] - self.entry[0], p_W[0, 1] - self.entry[1]))
            if d > ENTRY_TOL_M:
                out.append(f"entry: the drive starts {d:.2f} m from the entry point")
            dh = abs(math.remainder(profile.start[2] - self.entry[2], 2 * math.pi))
            if dh > ENTRY_TOL_RAD:
                out.append(f"entry: the drive starts {math.degrees(dh):.1f}° off the entry heading")
        c = profile.at(t_s)
        if self.terrain or np.any(c["grade_rad"]) or np.any(c["bank_rad"]):
            psi = np.unwrap(np.arctan2(smp.R_W_A[:, 1, 0], smp.R_W_A[:, 0, 0]))
            out += self.terrain.violations(p_W, psi, smp.speed, c["grade_rad"], c["bank_rad"], t_s)
        return out

    def drape(self, profile: ControlProfile, suspension, rate_hz: float = 20.0) -> ControlProfile:
        """``profile`` driven over this lot's terrain: its grade and bank become the terrain's
        under its path (resampled at ``rate_hz``; unchanged on a flat lot)."""
        if not self.terrain:
            return profile
        from ..motion.vehicle import drive

        t = np.linspace(profile.t_s[0], profile.t_s[-1], int(round(profile.duration_s * rate_hz)) + 1)
        c = profile.at(t)
        prof = profile
        for _ in range(2):  # the grade shortens the horizontal path: drape the draped drive again
            smp = drive(prof, suspension).sample(t)
            psi = np.unwrap(np.arctan2(smp.R_W_A[:, 1, 0], smp.R_W_A[:, 0, 0]))
            g, b = self.terrain.grade_bank_np(smp.p_W_V[:, :2], psi)
            prof = ControlProfile(t, np.maximum(c["speed_mps"], 0.0), c["curvature_1pm"], g, b, profile.start,
                                  profile.name)
        return prof

    def clearance(self) -> ca.Function:
        """Smooth signed distance [m] to the nearest edge or keep-out zone (positive inside):
        a cubic B-spline through the exact distance on a grid; ``(2, n) → (1, n)``."""
        lo = self.lot.polygon_m.min(axis=0) - 2 * self.margin_m
        hi = self.lot.polygon_m.max(axis=0) + 2 * self.margin_m
        h = max(float((hi - lo).max()) / _SDF_CELLS, 0.25)
        gx = np.arange(lo[0], hi[0] + h, h)
        gy = np.arange(lo[1], hi[1] + h, h)
        X, Y = np.meshgrid(gx, gy, indexing="ij")
        d = self.lot.clearance_m(np.column_stack([X.ravel(), Y.ravel()]))
        return ca.interpolant("clearance", "bspline", [gx, gy], d.reshape(X.shape).ravel(order="F"))


# --------------------------------------------------------------------------------------------
# Reading a lot

MAX_LOT_VERTICES = 2000  # outline, keep-out zones and terrain together
MAX_LOT_EXTENT_M = bounds.OPTIMIZE["lot_x_m"].hi  # a lot's bounding box, either side
MIN_LOT_AREA_M2 = 100.0  # room to turn a car in
MAX_LOT_SPAN_DEG = 0.2  # of longitude or latitude: a lot of 2 km is ~0.02°; a projection stays exact
_CHUNK = 256  # edges tested against all others at once (bounded memory)


def _ring(coords: Any, what: str, to_local) -> np.ndarray:
    if not isinstance(coords, list):
        raise OptimizeError(f"{what}: a ring is an array of [x, y] positions, got {type(coords).__name__}")
    for i, c in enumerate(coords):
        if not isinstance(c, list) or len(c) < 2 or not all(_finite(v) for v in c[:2]):
            raise OptimizeError(f"{what}: position {i} must be [x, y] (two finite numbers), got "
                                f"{_show(c)}")
    a = np.array([c[:2] for c in coords], dtype=float)
    if len(a) < 4:
        raise OptimizeError(f"{what}: a ring needs at least 4 finite [x, y] positions (closed), got {len(a)}")
    if not np.allclose(a[0, :2], a[-1, :2]):
        raise OptimizeError(f"{what}: the ring is not closed (its last position must equal its first)")
    return to_local(a[:-1, :2])


def _finite(v: Any) -> bool:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(v) and abs(v) < 1e15
    except OverflowError:
        return False


def _show(v: Any) -> str:
    text = json.dumps(v) if isinstance(v, (list, dict, str, int, float, bool)) or v is None else repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def _count(rings: Any, what: str) -> int:
    if not isinstance(rings, list):
        raise OptimizeError(f"{what}: coordinates must be an array of rings, got {_show(rings)}")
    n = 0
    for r in rings:
        if not isinstance(r, list):
            raise OptimizeError(f"{what}: each ring must be an array of [x, y] positions, got {_show(r)}")
        n += len(r)
    return n


def _area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _edges(rings: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every edge (start, end), the ring it belongs to and its index in that ring."""
    a = np.vstack(rings)
    b = np.vstack([np.roll(r, -1, axis=0) for r in rings])
    ring = np.concatenate([np.full(len(r), k) for k, r in enumerate(rings)])
    idx = np.concatenate([np.arange(len(r)) for r in rings])
    return a, b, ring, idx


def first_crossing(rings: list[np.ndarray]) -> tuple[int, int, int, int] | None:
    """The first pair of edges that touch or cross (ring, edge, ring, edge), neighbours in one
    ring aside; None when the rings are simple and apart. Memory: :data:`_CHUNK` × edges."""
    a, b, ring, idx = _edges(rings)
    sizes = np.array([len(r) for r in rings])
    n = len(a)
    scale = float(np.abs(np.vstack([a, b])).max()) or 1.0
    eps = 1e-12 * scale * scale

    def orient(p, q, r):
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])

    for s in range(0, n, _CHUNK):
        i = np.arange(s, min(n, s + _CHUNK))[:, None]
        j = np.arange(n)[None, :]
        later = j > i
        same = ring[i] == ring[j]
        k = sizes[ring[i]]
        neighbours = same & ((idx[j] == (idx[i] + 1) % k) | (idx[i] == (idx[j] + 1) % k))
        test = later & ~neighbours
        pa, pb, qa, qb = a[i], b[i], a[j], b[j]
        d1, d2 = orient(qa, qb, pa), orient(qa, qb, pb)
        d3, d4 = orient(pa, pb, qa), orient(pa, pb, qb)
        proper = ((d1 > eps) & (d2 < -eps) | (d1 < -eps) & (d2 > eps)) & \
            ((d3 > eps) & (d4 < -eps) | (d3 < -eps) & (d4 > eps))

        def on(p, q, r, d):  # r on segment p-q, given orient(p, q, r) = d
            return (np.abs(d) <= eps) & (np.minimum(p[..., 0], q[..., 0]) - 1e-9 <= r[..., 0]) & \
                (r[..., 0] <= np.maximum(p[..., 0], q[..., 0]) + 1e-9) & \
                (np.minimum(p[..., 1], q[..., 1]) - 1e-9 <= r[..., 1]) & (r[..., 1] <= np.maximum(p[..., 1], q[..., 1]) + 1e-9)

        touch = on(qa, qb, pa, d1) | on(qa, qb, pb, d2) | on(pa, pb, qa, d3) | on(pa, pb, qb, d4)
        hit = test & (proper | touch)
        if hit.any():
            r, c = np.argwhere(hit)[0]
            e1, e2 = int(i[r, 0]), int(j[0, c])
            return int(ring[e1]), int(idx[e1]), int(ring[e2]), int(idx[e2])
    return None


def _ring_name(k: int) -> str:
    return "the lot outline" if k == 0 else f"keep-out zone {k}"


def check_lot_shape(outer: np.ndarray, holes: tuple[np.ndarray, ...], where: str) -> None:
    """Refuse what no maneuver can be planned in, before any of it is built: a lot beyond
    :data:`MAX_LOT_EXTENT_M` or under :data:`MIN_LOT_AREA_M2`, a repeated vertex, a ring that
    crosses itself or another one, a keep-out zone outside the lot or inside another one."""
    ext = np.ptp(outer, axis=0)
    if ext.max() > MAX_LOT_EXTENT_M:
        raise OptimizeError(f"{where}: the lot spans {ext[0]:.0f} m × {ext[1]:.0f} m, over the limit of "
                            f"{MAX_LOT_EXTENT_M:g} m on either side")
    for k, r in enumerate((outer, *holes)):
        step = np.linalg.norm(np.roll(r, -1, axis=0) - r, axis=1)
        if np.any(step < 1e-6):
            raise OptimizeError(f"{where}: {_ring_name(k)} repeats vertex {int(np.argmax(step < 1e-6)) + 1} "
                                "(an edge of zero length)")
    hit = first_crossing([outer, *holes])
    if hit is not None:
        r1, e1, r2, e2 = hit
        if r1 == r2:
            raise OptimizeError(f"{where}: {_ring_name(r1)} crosses itself (edges {e1 + 1} and {e2 + 1})")
        raise OptimizeError(f"{where}: {_ring_name(r1)} and {_ring_name(r2)} cross or touch "
                            f"(edges {e1 + 1} and {e2 + 1})")
    for k, r in enumerate((outer, *holes)):
        if abs(_area(r)) < (MIN_LOT_AREA_M2 if k == 0 else 1e-6):
            what = f"an area of {abs(_area(r)):.3g} m², under {MIN_LOT_AREA_M2:g} m²" if k == 0 else "no area"
            raise OptimizeError(f"{where}: {_ring_name(k)} has {what}")
    for k, h in enumerate(holes):
        if not _inside(outer, h[:1])[0]:
            raise OptimizeError(f"{where}: keep-out zone {k + 1} is not inside the lot")
        for m, other in enumerate(holes):
            if m != k and _inside(other, h[:1])[0]:
                raise OptimizeError(f"{where}: keep-out zone {k + 1} lies inside keep-out zone {m + 1}")
    if abs(_area(outer)) - sum(abs(_area(h)) for h in holes) < MIN_LOT_AREA_M2:
        raise OptimizeError(f"{where}: the keep-out zones leave less than {MIN_LOT_AREA_M2:g} m² to drive in")


def _inside(ring: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Even-odd ray casting, one point at a time against every edge (memory: the edges)."""
    out = np.zeros(len(p), dtype=bool)
    a, b = ring, np.roll(ring, -1, axis=0)
    for n, (x, y) in enumerate(p):
        crosses = (a[:, 1] > y) != (b[:, 1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        out[n] = int(np.sum(crosses & (x < x_at))) % 2 == 1
    return out


def read_site(source: str | Path | dict[str, Any], margin_m: float = EDGE_MARGIN_M,
              max_vertices: int = MAX_LOT_VERTICES) -> Site:
    """A lot from GeoJSON (a file, its text or the parsed data).

    The lot is the one ``Polygon`` Feature (first ring the outline, further rings keep-out
    zones) in lon/lat (WGS84), or in local metres when the FeatureCollection's (or the
    Feature's) ``properties`` say ``"crs": "local"``. Optional Features: a ``Point`` with
    ``"role": "entry"`` and ``"heading_deg"`` (counter-clockwise from east / local x), and
    ``Polygon`` terrain features with ``"role": "ramp" | "bank" | "bump"`` (see :mod:`.terrain`).
    Features of the scene around the lot (with a ``kind`` or a ``height``: buildings, walls,
    poles, read by :mod:`excite.scene.files`) are passed over, so one file serves both.

    Refused, each with an :class:`OptimizeError` naming the part: a malformed document (a
    ``properties`` or ``geometry`` that is not an object, a position that is not two numbers),
    more than ``max_vertices`` vertices in all, lon/lat beyond ±180°/±85° or spanning more than
    :data:`MAX_LOT_SPAN_DEG`, and every shape :func:`check_lot_shape` refuses. Each test's
    memory is bounded by the vertex count, never its square.
    """
    where = "lot"
    if isinstance(source, dict):
        doc = source
    else:
        text = str(source)
        if not text.lstrip().startswith("{"):
            where = str(source)
            try:
                text = Path(source).read_text(encoding="utf-8")
            except OSError as exc:
                raise OptimizeError(f"lot: cannot read {source}: {exc.strerror}") from None
        try:
            doc = json.loads(text)
        except (json.JSONDecodeError, RecursionError) as exc:
            detail = f"{exc.msg} (line {exc.lineno})" if isinstance(exc, json.JSONDecodeError) else "nested too deeply"
            raise OptimizeError(f"{where}: not valid JSON: {detail}") from None
    if not isinstance(doc, dict):
        raise OptimizeError(f"{where}: expected a GeoJSON object")
    feats = doc.get("features") if doc.get("type") == "FeatureCollection" else [doc]
    if not isinstance(feats, list):
        raise OptimizeError(f"{where}: features must be a list")
    top = doc.get("properties") if doc.get("type") == "FeatureCollection" else None
    if top is not None and not isinstance(top, dict):
        raise OptimizeError(f"{where}: properties must be an object, got {_show(top)}")
    local = (top or {}).get("crs") == "local"
    lots, entries, terrain = [], [], []
    total = 0
    for i, f in enumerate(feats):
        name = f"{where}: features[{i}]" if doc.get("type") == "FeatureCollection" else where
        if not isinstance(f, dict):
            raise OptimizeError(f"{name}: a feature must be an object, got {_show(f)}")
        if f.get("type") != "Feature":
            f = {"type": "Feature", "geometry": f, "properties": {}}
        props = f.get("properties")
        props = {} if props is None else props
        if not isinstance(props, dict):
            raise OptimizeError(f"{name}: properties must be an object, got {_show(props)}")
        geom = f.get("geometry")
        geom = {} if geom is None else geom
        if not isinstance(geom, dict):
            raise OptimizeError(f"{name}: geometry must be an object, got {_show(geom)}")
        role = props.get("role", "lot")
        if props.get("crs") == "local":
            local = True
        if is_scene_feature(props):
            continue
        kind = geom.get("type")
        if kind == "Polygon" and role in ("lot", "ramp", "bank", "bump"):
            total += _count(geom.get("coordinates"), f"{name} ({role})")
            if total > max_vertices:
                raise OptimizeError(f"{where}: more than {max_vertices} vertices in all, over the limit "
                                    "(simplify the outline)")
        if kind == "Polygon" and role == "lot":
            lots.append(geom.get("coordinates"))
        elif kind == "Point" and role == "entry":
            entries.append((geom.get("coordinates"), props))
        elif kind == "Polygon" and role in ("ramp", "bank", "bump"):
            terrain.append((role, geom.get("coordinates"), props))
        else:
            raise OptimizeError(f"{name}: a {_show(kind)} feature with role {_show(role)} is not a lot "
                                "Polygon, an entry Point or a ramp/bank/bump Polygon")
    if len(lots) != 1:
        raise OptimizeError(f"{where}: expected exactly one lot Polygon, got {len(lots)}")
    rings = lots[0]
    if not rings:
        raise OptimizeError(f"{where}: the lot Polygon has no rings")
    origin = None
    if local:
        def to_local(a):
            return a
    else:
        ring0 = _ring(rings[0], f"{where}: lot outline", lambda a: a)
        every = np.vstack([ring0] + [_ring(r, f"{where}: keep-out zone {k + 1}", lambda a: a)
                                     for k, r in enumerate(rings[1:])])
        if not (np.all(np.abs(every[:, 0]) <= 180) and np.all(np.abs(every[:, 1]) <= 85)):
            raise OptimizeError(f"{where}: coordinates must be [lon, lat] in degrees within ±180° and ±85° "
                                "(or set properties.crs to \"local\" for metres)")
        span = np.ptp(every, axis=0)
        if span.max() > MAX_LOT_SPAN_DEG:
            raise OptimizeError(f"{where}: the lot spans {span[0]:.3g}° of longitude and {span[1]:.3g}° of "
                                f"latitude, over the limit of {MAX_LOT_SPAN_DEG:g}° (a lot is at most "
                                f"{MAX_LOT_EXTENT_M:g} m across)")
        origin = (float(ring0[:, 0].mean()), float(ring0[:, 1].mean()))
        to_local = Projection(origin).to_local
    outer = _ring(rings[0], f"{where}: lot outline", to_local)
    holes = tuple(_ring(r, f"{where}: keep-out zone {i + 1}", to_local) for i, r in enumerate(rings[1:]))
    check_lot_shape(outer, holes, where)
    try:
        lot = Lot(outer, holes=holes)
    except Exception as exc:  # LimitError from Lot: name the file
        raise OptimizeError(f"{where}: {exc}") from None
    entry = None
    if len(entries) > 1:
        raise OptimizeError(f"{where}: at most one entry Point, got {len(entries)}")
    if entries:
        xy, props = entries[0]
        if not isinstance(xy, list) or len(xy) < 2 or not all(_finite(v) for v in xy[:2]):
            raise OptimizeError(f"{where}: the entry Point needs [x, y] coordinates, got {_show(xy)}")
        heading_deg = props.get("heading_deg", 0.0)
        if not _finite(heading_deg) or abs(heading_deg) > 3600:
            raise OptimizeError(f"{where}: the entry Point's heading_deg must be a number of degrees, "
                                f"got {_show(heading_deg)}")
        p = to_local(np.array([xy[:2]], dtype=float))[0]
        heading = math.radians(float(heading_deg))
        if not lot.contains(p[None], margin_m)[0]:
            raise OptimizeError(f"{where}: the entry point is not inside the lot with the {margin_m:g} m margin")
        entry = (float(p[0]), float(p[1]), heading)
    feats_t = []
    for i, (role, rings_t, props) in enumerate(terrain):
        ring = _ring((rings_t or [None])[0], f"{where}: {role} {i + 1}", to_local)
        feats_t.append(Terrain.feature(role, ring, props, f"{where}: {role} {i + 1}"))
    return Site(lot, margin_m, entry, Terrain(tuple(feats_t)), origin)


def parse_lot(text: str, margin_m: float = EDGE_MARGIN_M) -> Site:
    """``"80x50"`` (a rectangle: extent along x, then y, centred on the origin) or a GeoJSON
    file path."""
    import re

    number = r"\s*(\d+(?:\.\d*)?|\.\d+)\s*"
    m = re.fullmatch(number + "[xX×]" + number, text)
    if m:
        for name, value in zip(("lot_x_m", "lot_y_m"), m.groups()):
            bounds.check_range(bounds.OPTIMIZE, name, float(value), OptimizeError,
                               f"lot: the extent along {name[4]}")
        return Site.rectangle(float(m.group(1)), float(m.group(2)), margin_m=margin_m)
    if not Path(text).exists():
        if re.search(r"[/\\]|\.(geo)?json$", text, re.IGNORECASE):
            raise OptimizeError(f"lot: no such file: {text}")
        raise OptimizeError(f"lot: expected XxY in metres such as 80x50 or a GeoJSON file, got {text!r}")
    return read_site(text, margin_m)


def maneuver_geojson(p_W: np.ndarray, speed_mps: np.ndarray, origin: tuple[float, float], name: str) -> str:
    """The path as a GeoJSON LineString (lon, lat, height) with the speed per point."""
    ll = Projection(origin).to_lonlat(p_W[:, :2])
    coords = [[round(float(a), 9), round(float(b), 9), round(float(z), 3)] for (a, b), z in zip(ll, p_W[:, 2])]
    feature = {"type": "Feature", "geometry": {"type": "LineString", "coordinates": coords},
               "properties": {"name": name, "speed_mps": [round(float(v), 4) for v in speed_mps]}}
    return json.dumps({"type": "FeatureCollection", "features": [feature]})
