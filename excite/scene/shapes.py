"""Scenes made of simple shapes: the ground, walls, buildings extruded from their outline, poles,
boxes and the tunnels and streets built from them (what a vector scene in GeoJSON describes, and
the degenerate scenes of the design document).

Every function returns a :class:`~excite.scene.model.Scene` of one surface; combine them with
:meth:`Scene.combine <excite.scene.model.Scene.combine>`. Polygons are triangulated by
``mapbox_earcut`` (concave outlines included).
"""

from __future__ import annotations

import numpy as np

from ..errors import SceneError
from .model import Scene, Surface  # noqa: F401 (Surface: re-exported for scene builders)

MAX_POLYGON_VERTICES = 100_000
"""Most vertices of one polygon outline."""


def _scene(vertices, faces, surface: Surface, source: str = "scene") -> Scene:
    return Scene(np.asarray(vertices, float), np.asarray(faces, dtype=np.int64),
                 np.zeros(len(faces), dtype=np.int64), (surface,), source=source)


def ground(x_min: float, y_min: float, x_max: float, y_max: float, z: float = 0.0, *, cell_m: float = 0.0,
           name: str = "ground", features_per_m2: float = 2.0) -> Scene:
    """A level rectangle of ground at height ``z`` (two triangles, or a grid of ``cell_m`` cells)."""
    if not (x_max > x_min and y_max > y_min):
        raise SceneError(f"ground {name}: empty rectangle ({x_min}, {y_min}) … ({x_max}, {y_max})")
    nx = max(1, int(np.ceil((x_max - x_min) / cell_m))) if cell_m > 0 else 1
    ny = max(1, int(np.ceil((y_max - y_min) / cell_m))) if cell_m > 0 else 1
    xs, ys = np.linspace(x_min, x_max, nx + 1), np.linspace(y_min, y_max, ny + 1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    v = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z)])
    i = np.arange(nx)[:, None] * (ny + 1) + np.arange(ny)[None, :]
    i = i.ravel()
    faces = np.vstack([np.column_stack([i, i + ny + 1, i + ny + 2]), np.column_stack([i, i + ny + 2, i + 1])])
    return _scene(v, faces, Surface("ground", name, features_per_m2))


def polygon_faces(outline: np.ndarray, *, source: str = "polygon") -> np.ndarray:
    """Triangles (indices into ``outline``) of a simple polygon's interior (K × 2, not closed)."""
    import mapbox_earcut

    ring = np.asarray(outline, float)
    if ring.ndim != 2 or ring.shape[1] != 2 or ring.shape[0] < 3:
        raise SceneError(f"{source}: an outline needs at least 3 points (x, y)")
    if ring.shape[0] > MAX_POLYGON_VERTICES:
        raise SceneError(f"{source}: {ring.shape[0]} vertices, more than the {MAX_POLYGON_VERTICES} "
                         "an outline may have")
    tri = mapbox_earcut.triangulate_float64(ring, np.array([ring.shape[0]], dtype=np.uint32))
    if tri.size == 0:
        raise SceneError(f"{source}: the outline encloses no area (self-intersecting or collinear)")
    return np.asarray(tri, dtype=np.int64).reshape(-1, 3)


def _open_ring(outline) -> np.ndarray:
    ring = np.asarray(outline, float)[:, :2]
    if ring.shape[0] > 1 and np.allclose(ring[0], ring[-1]):
        ring = ring[:-1]
    return ring


def prism(outline, height: float, *, base: float = 0.0, kind: str = "building", name: str = "",
          features_per_m2: float = 1.0, roof: bool = True) -> Scene:
    """The outline (K × 2, closed or not) extruded from ``base`` to ``base + height``: its walls,
    and its roof where ``roof``."""
    label = name or kind
    if not (np.isfinite(height) and height > 0):
        raise SceneError(f"{label}: height {height} m must be positive")
    ring = _open_ring(outline)
    if ring.shape[0] > MAX_POLYGON_VERTICES:
        raise SceneError(f"{label}: {ring.shape[0]} vertices, more than the {MAX_POLYGON_VERTICES} "
                         "an outline may have")
    if ring.shape[0] < 3:
        raise SceneError(f"{label}: an outline needs at least 3 points")
    K = ring.shape[0]
    lo = np.column_stack([ring, np.full(K, base)])
    hi = np.column_stack([ring, np.full(K, base + height)])
    v = np.vstack([lo, hi])
    a = np.arange(K)
    b = (a + 1) % K
    faces = [np.column_stack([a, b, b + K]), np.column_stack([a, b + K, a + K])]
    if roof:
        faces.append(polygon_faces(ring, source=label) + K)
    return _scene(v, np.vstack(faces), Surface(kind, name, features_per_m2))


def wall(p0, p1, height: float, *, base: float = 0.0, kind: str = "wall", name: str = "",
         features_per_m2: float = 1.0) -> Scene:
    """A vertical wall over the segment ``p0 → p1`` (x, y), from ``base`` to ``base + height``."""
    label = name or kind
    p0, p1 = np.asarray(p0, float)[:2], np.asarray(p1, float)[:2]
    if not (np.isfinite(height) and height > 0):
        raise SceneError(f"{label}: height {height} m must be positive")
    if np.linalg.norm(p1 - p0) <= 0:
        raise SceneError(f"{label}: its two ends coincide")
    v = np.array([[*p0, base], [*p1, base], [*p1, base + height], [*p0, base + height]])
    return _scene(v, [[0, 1, 2], [0, 2, 3]], Surface(kind, name, features_per_m2))


def cylinder(center, radius: float, height: float, *, base: float = 0.0, sides: int = 12, kind: str = "pole",
             name: str = "", features_per_m2: float = 1.0) -> Scene:
    """A vertical cylinder (a pole, a tree trunk, a cone's body) of ``sides`` faces."""
    label = name or kind
    if not (np.isfinite(radius) and radius > 0 and np.isfinite(height) and height > 0):
        raise SceneError(f"{label}: radius {radius} m and height {height} m must be positive")
    a = np.linspace(0.0, 2 * np.pi, sides, endpoint=False)
    ring = np.asarray(center, float)[:2] + radius * np.column_stack([np.cos(a), np.sin(a)])
    return prism(ring, height, base=base, kind=kind, name=name, features_per_m2=features_per_m2)


def box(x_min: float, y_min: float, x_max: float, y_max: float, height: float, *, base: float = 0.0,
        kind: str = "building", name: str = "", features_per_m2: float = 1.0) -> Scene:
    """An axis-aligned box (a building, a parked truck)."""
    ring = [(x_min, y_min), (x_max, y_min), (x_max, y_max), (x_min, y_max)]
    return prism(ring, height, base=base, kind=kind, name=name, features_per_m2=features_per_m2)


def ceiling(x_min: float, y_min: float, x_max: float, y_max: float, z: float, *, name: str = "ceiling",
            features_per_m2: float = 1.0) -> Scene:
    """A level ceiling at height ``z`` (a tunnel's, a parking deck's), facing down."""
    g = ground(x_min, y_min, x_max, y_max, z)
    return _scene(g.vertices, g.faces[:, ::-1], Surface("ceiling", name, features_per_m2))


def tunnel(length: float, width: float, height: float, *, x0: float = 0.0, y_center: float = 0.0,
           features_per_m2: float = 0.2) -> Scene:
    """A straight tunnel along x from ``x0``: ground, two side walls and a ceiling; its ends open."""
    x1 = x0 + length
    y0, y1 = y_center - width / 2, y_center + width / 2
    return Scene.combine([ground(x0, y0, x1, y1),
                          wall((x0, y0), (x1, y0), height, name="right wall", features_per_m2=features_per_m2),
                          wall((x1, y1), (x0, y1), height, name="left wall", features_per_m2=features_per_m2),
                          ceiling(x0, y0, x1, y1, height, features_per_m2=features_per_m2)], source="tunnel")
