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


def _ring(coords: Any, what: str, to_local) -> np.ndarray:
    try:
        a = np.array(coords, dtype=float)
    except (TypeError, ValueError):
        raise OptimizeError(f"{what}: every coordinate must be a pair of numbers") from None
    if a.ndim != 2 or a.shape[1] < 2 or len(a) < 4 or not np.all(np.isfinite(a)):
        raise OptimizeError(f"{what}: a ring needs at least 4 finite [x, y] positions (closed), got {a.shape}")
    if not np.allclose(a[0, :2], a[-1, :2]):
        raise OptimizeError(f"{what}: the ring is not closed (its last position must equal its first)")
    return to_local(a[:-1, :2])


def read_site(source: str | Path | dict[str, Any], margin_m: float = EDGE_MARGIN_M) -> Site:
    """A lot from GeoJSON (a file, its text or the parsed data).

    The lot is the one ``Polygon`` Feature (first ring the outline, further rings keep-out
    zones) in lon/lat (WGS84), or in local metres when the FeatureCollection's (or the
    Feature's) ``properties`` say ``"crs": "local"``. Optional Features: a ``Point`` with
    ``"role": "entry"`` and ``"heading_deg"`` (counter-clockwise from east / local x), and
    ``Polygon`` terrain features with ``"role": "ramp" | "bank" | "bump"`` (see :mod:`.terrain`).
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
        except json.JSONDecodeError as exc:
            raise OptimizeError(f"{where}: not valid JSON: {exc.msg} (line {exc.lineno})") from None
    if not isinstance(doc, dict):
        raise OptimizeError(f"{where}: expected a GeoJSON object")
    feats = doc.get("features") if doc.get("type") == "FeatureCollection" else [doc]
    if not isinstance(feats, list):
        raise OptimizeError(f"{where}: features must be a list")
    feats = [f if f.get("type") == "Feature" else {"type": "Feature", "geometry": f, "properties": {}}
             for f in feats if isinstance(f, dict)]
    local = (doc.get("properties") or {}).get("crs") == "local"
    lots, entries, terrain = [], [], []
    for f in feats:
        props = f.get("properties") or {}
        geom = f.get("geometry") or {}
        role = props.get("role", "lot")
        if props.get("crs") == "local":
            local = True
        if geom.get("type") == "Polygon" and role == "lot":
            lots.append(geom.get("coordinates"))
        elif geom.get("type") == "Point" and role == "entry":
            entries.append((geom.get("coordinates"), props))
        elif geom.get("type") == "Polygon" and role in ("ramp", "bank", "bump"):
            terrain.append((role, geom.get("coordinates"), props))
        else:
            raise OptimizeError(f"{where}: a {geom.get('type')!r} feature with role {role!r} is not a lot "
                                "Polygon, an entry Point or a ramp/bank/bump Polygon")
    if len(lots) != 1:
        raise OptimizeError(f"{where}: expected exactly one lot Polygon, got {len(lots)}")
    rings = lots[0]
    if not isinstance(rings, list) or not rings:
        raise OptimizeError(f"{where}: the lot Polygon has no rings")
    origin = None
    if local:
        def to_local(a):
            return a
    else:
        first = np.array(rings[0][0], dtype=float)
        if not (-180 <= first[0] <= 180 and -85 <= first[1] <= 85):
            raise OptimizeError(f"{where}: coordinates must be [lon, lat] in degrees "
                                "(or set properties.crs to \"local\" for metres)")
        ring0 = np.array(rings[0], dtype=float)[:-1, :2]
        origin = (float(ring0[:, 0].mean()), float(ring0[:, 1].mean()))
        to_local = Projection(origin).to_local
    outer = _ring(rings[0], f"{where}: lot outline", to_local)
    holes = tuple(_ring(r, f"{where}: keep-out zone {i + 1}", to_local) for i, r in enumerate(rings[1:]))
    try:
        lot = Lot(outer, holes=holes)
    except Exception as exc:  # LimitError from Lot: name the file
        raise OptimizeError(f"{where}: {exc}") from None
    entry = None
    if len(entries) > 1:
        raise OptimizeError(f"{where}: at most one entry Point, got {len(entries)}")
    if entries:
        xy, props = entries[0]
        try:
            p = to_local(np.array([xy[:2]], dtype=float))[0]
            heading = math.radians(float(props.get("heading_deg", 0.0)))
        except (TypeError, ValueError, IndexError):
            raise OptimizeError(f"{where}: the entry Point needs [x, y] coordinates and a numeric heading_deg") from None
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


@dataclass(frozen=True)
class Projection:
    """Transverse Mercator about ``origin`` (lon, lat): the local frame (x east, y north) of a
    georeferenced lot, as :func:`excite.io.routes.read_geojson` projects."""

    origin: tuple[float, float]

    def _tm(self, inverse: bool):
        from pyproj import Transformer

        lon0, lat0 = self.origin
        crs = (f"+proj=tmerc +lat_0={lat0!r} +lon_0={lon0!r} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m")
        return Transformer.from_crs(crs, "EPSG:4326", always_xy=True) if inverse else \
            Transformer.from_crs("EPSG:4326", crs, always_xy=True)

    def to_local(self, lonlat: np.ndarray) -> np.ndarray:
        x, y = self._tm(False).transform(lonlat[:, 0], lonlat[:, 1])
        return np.column_stack([x, y])

    def to_lonlat(self, xy: np.ndarray) -> np.ndarray:
        lon, lat = self._tm(True).transform(xy[:, 0], xy[:, 1])
        return np.column_stack([lon, lat])


def maneuver_geojson(p_W: np.ndarray, speed_mps: np.ndarray, origin: tuple[float, float], name: str) -> str:
    """The path as a GeoJSON LineString (lon, lat, height) with the speed per point."""
    ll = Projection(origin).to_lonlat(p_W[:, :2])
    coords = [[round(float(a), 9), round(float(b), 9), round(float(z), 3)] for (a, b), z in zip(ll, p_W[:, 2])]
    feature = {"type": "Feature", "geometry": {"type": "LineString", "coordinates": coords},
               "properties": {"name": name, "speed_mps": [round(float(v), 4) for v in speed_mps]}}
    return json.dumps({"type": "FeatureCollection", "features": [feature]})
