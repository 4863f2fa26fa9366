"""A scene: the surfaces around a drive that a lidar ranges and a camera finds features on.

A :class:`Scene` is a triangle mesh in the world frame W of the drive (z up, metres): every
triangle belongs to one :class:`Surface` (the ground, a building, a wall, a pole, a point-cloud
map's splats), which says what it is and how many visual features per square metre a camera
finds on it. Meshes, extruded vector scenes (:mod:`excite.scene.shapes`) and point-cloud maps
(each point a small disc along its normal) all become triangles, so one ray caster serves them
all: Intel Embree through ``embreex`` (:meth:`Scene.cast`), the ray tracer trimesh uses.

Sizes are bounded before anything is built (:data:`~excite.core.bounds.MAX_SCENE_TRIANGLES`,
:data:`~excite.core.bounds.MAX_SCENE_EXTENT_M`); a scene with a NaN vertex, a face that names
no vertex or a degenerate extent is refused with a :class:`~excite.errors.SceneError` naming
what is wrong.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from functools import cached_property
from typing import Iterable

import numpy as np

from ..core import bounds
from ..errors import SceneError

SURFACE_KINDS = ("ground", "building", "wall", "pole", "vegetation", "vehicle", "map", "mesh", "ceiling")
"""What a surface is (the ground carries the road plane; the rest is structure)."""


@dataclass(frozen=True)
class Surface:
    """One surface of a scene: ``kind`` (:data:`SURFACE_KINDS`), a ``name`` for reports, and the
    visual features a camera finds on it per square metre (texture: a plain wall few, a
    façade or vegetation many)."""

    kind: str
    name: str = ""
    features_per_m2: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in SURFACE_KINDS:
            raise SceneError(f"surface kind {self.kind!r}: not one of {', '.join(SURFACE_KINDS)}")
        if not (np.isfinite(self.features_per_m2) and 0.0 <= self.features_per_m2 <= 1e4):
            raise SceneError(f"surface {self.name or self.kind}: features_per_m2 {self.features_per_m2} "
                             "is outside 0 … 10000")


@dataclass(frozen=True)
class Hits:
    """What rays found: per ray, whether it hit (``hit``), the distance along its unit direction
    (``distance``; the range limit where it did not), the hit triangle (``face``, −1 for none),
    the unit normal of that triangle facing the ray's origin (``normal``), its surface's index
    (``surface``, −1 for none) and the cosine of the ray's incidence on it (``cos``, ``|n · d|``;
    0 for none)."""

    hit: np.ndarray
    distance: np.ndarray
    face: np.ndarray
    normal: np.ndarray
    surface: np.ndarray
    cos: np.ndarray


@dataclass(frozen=True, eq=False)
class Scene:
    """Triangles ``vertices[faces]`` in W, each of surface ``surfaces[face_surface[f]]``;
    ``source`` names where it came from (a file, a bundled scene) for messages."""

    vertices: np.ndarray
    faces: np.ndarray
    face_surface: np.ndarray
    surfaces: tuple[Surface, ...]
    source: str = "scene"
    _embree: list = field(default_factory=list, repr=False, compare=False)

    def __post_init__(self) -> None:
        v = np.ascontiguousarray(self.vertices, dtype=float)
        f = np.ascontiguousarray(self.faces, dtype=np.int64)
        s = np.ascontiguousarray(self.face_surface, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise SceneError(f"vertices: shape {v.shape}, expected N × 3", source=self.source)
        if f.ndim != 2 or f.shape[1] != 3:
            raise SceneError(f"faces: shape {f.shape}, expected M × 3", source=self.source)
        if f.shape[0] > bounds.MAX_SCENE_TRIANGLES:
            raise SceneError(f"{f.shape[0]} triangles: more than the {bounds.MAX_SCENE_TRIANGLES} a scene may hold",
                             source=self.source)
        if f.shape[0] == 0:
            raise SceneError("no triangles: a scene needs at least the ground", source=self.source)
        if not np.all(np.isfinite(v)):
            bad = int(np.flatnonzero(~np.all(np.isfinite(v), axis=1))[0])
            raise SceneError(f"vertex {bad}: not a finite number", source=self.source)
        if f.min() < 0 or f.max() >= v.shape[0]:
            raise SceneError(f"faces: index outside the {v.shape[0]} vertices", source=self.source)
        if s.shape != (f.shape[0],) or s.min() < 0 or s.max() >= len(self.surfaces):
            raise SceneError("face_surface: one surface index per face, within the surfaces", source=self.source)
        extent = np.ptp(v[:, :2], axis=0).max() if v.size else 0.0
        if extent > bounds.MAX_SCENE_EXTENT_M:
            raise SceneError(f"extent {extent:.0f} m: more than the {bounds.MAX_SCENE_EXTENT_M:.0f} m a scene "
                             "may span", source=self.source)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)
        object.__setattr__(self, "face_surface", s)
        object.__setattr__(self, "surfaces", tuple(self.surfaces))

    def __reduce__(self):
        """Pickled without its ray caster (rebuilt on first use: a worker process casts its own)."""
        return (Scene, (self.vertices, self.faces, self.face_surface, self.surfaces, self.source))

    # --- what it is ------------------------------------------------------------------------

    @property
    def n_triangles(self) -> int:
        return int(self.faces.shape[0])

    @cached_property
    def triangles(self) -> np.ndarray:
        """The triangles' corners (M × 3 × 3)."""
        return self.vertices[self.faces]

    @cached_property
    def face_normals(self) -> np.ndarray:
        """Unit normals of the triangles (M × 3; by the corners' order, zero for a degenerate one)."""
        t = self.triangles
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)

    @cached_property
    def face_areas(self) -> np.ndarray:
        t = self.triangles
        return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)

    @property
    def bounds(self) -> np.ndarray:
        """``[[x_min, y_min, z_min], [x_max, y_max, z_max]]`` of its vertices."""
        return np.array([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    @cached_property
    def digest(self) -> str:
        """SHA-256 of its geometry and surfaces: equal scenes have equal digests."""
        h = hashlib.sha256()
        for a in (self.vertices, self.faces, self.face_surface):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(repr([(s.kind, s.name, s.features_per_m2) for s in self.surfaces]).encode())
        return h.hexdigest()

    def area_by_kind(self) -> dict[str, float]:
        """Total area of the triangles of each surface kind [m²]."""
        out: dict[str, float] = {}
        kinds = np.array([s.kind for s in self.surfaces])[self.face_surface]
        for k in dict.fromkeys(kinds):
            out[str(k)] = float(self.face_areas[kinds == k].sum())
        return out

    # --- making new scenes -----------------------------------------------------------------

    @staticmethod
    def combine(parts: Iterable["Scene"], source: str = "scene") -> "Scene":
        """One scene of all of ``parts``' triangles and surfaces."""
        parts = list(parts)
        if not parts:
            raise SceneError("nothing to combine", source=source)
        if sum(p.n_triangles for p in parts) > bounds.MAX_SCENE_TRIANGLES:
            raise SceneError(f"more than the {bounds.MAX_SCENE_TRIANGLES} triangles a scene may hold", source=source)
        v, f, s, surf = [], [], [], []
        nv = 0
        for p in parts:
            v.append(p.vertices)
            f.append(p.faces + nv)
            s.append(p.face_surface + len(surf))
            surf.extend(p.surfaces)
            nv += p.vertices.shape[0]
        return Scene(np.vstack(v), np.vstack(f), np.concatenate(s), tuple(surf), source=source)

    def transformed(self, R: np.ndarray, p: np.ndarray) -> "Scene":
        """The same scene moved by the rigid motion ``x ↦ R x + p``."""
        return Scene(self.vertices @ np.asarray(R, float).T + np.asarray(p, float), self.faces, self.face_surface,
                     self.surfaces, source=self.source)

    # --- rays ------------------------------------------------------------------------------

    @property
    def _origin(self) -> np.ndarray:
        """The centre the ray caster works about (float32 keeps millimetres within kilometres of it)."""
        return 0.5 * (self.vertices.min(axis=0) + self.vertices.max(axis=0))

    def _caster(self):
        if not self._embree:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh

            scene = rtcore_scene.EmbreeScene()
            TriangleMesh(scene, np.ascontiguousarray(self.triangles - self._origin, dtype=np.float32))
            self._embree.append(scene)
        return self._embree[0]

    @cached_property
    def _by_face(self) -> tuple[np.ndarray, np.ndarray]:
        """Each face's unit normal and surface, and after them a zero normal and surface −1: what
        a ray that meets no face (index −1) gets."""
        return np.vstack([self.face_normals, np.zeros((1, 3))]), np.append(self.face_surface, -1)

    def cast(self, origins: np.ndarray, directions: np.ndarray, max_range: float | np.ndarray) -> Hits:
        """The first triangle each ray meets within ``max_range`` of its origin (occlusion
        honoured): ``directions`` N × 3 in W, of unit length (or … × 3, taken flat), ``origins``
        the same or any shape that broadcasts to them (one origin per scan: m × 1 × 3)."""
        shape = np.shape(directions)
        d = np.asarray(directions, float).reshape(-1, 3)
        n = d.shape[0]
        o32 = np.empty(shape, np.float32)
        o32[...] = np.asarray(origins, float) - self._origin
        reach = np.broadcast_to(np.asarray(max_range, float), (n,))
        out = self._caster().run(o32.reshape(-1, 3), np.ascontiguousarray(d, dtype=np.float32),
                                 dists=np.ascontiguousarray(reach, dtype=np.float32), output=1)
        face = out["primID"].astype(np.int64)
        hit = face >= 0
        dist = np.where(hit, out["tfar"], reach)
        normals, surfaces = self._by_face
        normal = normals[face]
        nd = np.einsum("ij,ij->i", normal, d)
        normal[nd > 0] *= -1.0
        return Hits(hit=hit, distance=dist, face=face, normal=normal, surface=surfaces[face], cos=np.abs(nd))

    def is_ground(self) -> np.ndarray:
        """Per surface: whether it is the ground (carries the road plane)."""
        return np.array([s.kind == "ground" for s in self.surfaces])
