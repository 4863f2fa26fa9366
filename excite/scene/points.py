"""A point-cloud map as a scene: every point a small square splat along its surface's normal.

The ray caster meets triangles, so :func:`scene_from_points` turns each point of a map into a
square of two triangles, centred on the point, perpendicular to its normal, of side
:data:`SPLAT_SCALE` × the mean distance to its :data:`NEIGHBOURS` nearest neighbours (the local
point spacing: neighbouring splats overlap, so a ray does not slip through a surface between its
points). Where the map has no normals they are estimated as a scanner's mapping software does:
the direction of least spread (principal component analysis) of the point and its nearest
neighbours (``scipy.spatial.cKDTree``). A normal's sign does not matter: the ray caster turns
every normal towards the ray.

A map denser than :data:`MAX_SPLATS` points is first thinned to a voxel grid (each occupied
voxel's centroid, its normals averaged), the voxel the smallest of sides a power of two apart that
leaves at most :data:`MAX_SPLATS` of them: a lidar's scan is resolved far more coarsely than that (the ray
caster's quadrature is a few hundred azimuths), so the thinned map tells the same.
"""

from __future__ import annotations

import numpy as np

from ..core import bounds
from ..errors import SceneError
from .model import Scene, Surface

MAX_SPLATS = bounds.MAX_SCENE_TRIANGLES // 2
"""Most splats of one map (two triangles each): a denser map is thinned to a voxel grid."""
NEIGHBOURS = 8
"""Nearest neighbours of a point its normal and its spacing are taken from."""
SPLAT_SCALE = 2.0
"""Side of a splat over the mean distance to its :data:`NEIGHBOURS` nearest neighbours (points
sampled uniformly at random on a plane leave 0.1 % of it between their splats)."""
MAX_SPLAT_OVER_MEDIAN = 3.0
"""A splat is at most this many times the map's median splat (an isolated point blocks no view)."""
_CHUNK = 200_000  # points whose neighbourhoods are analysed at once (bounded memory)


def check_points(points: np.ndarray, source: str, field: str = "points") -> np.ndarray:
    """``points`` as N × 3 floats, refused when one is not finite, too many or too far apart."""
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3:
        raise SceneError(f"{field}: shape {p.shape}, expected N × 3", source=source)
    if p.shape[0] > bounds.MAX_SCENE_POINTS:
        raise SceneError(f"{field}: {p.shape[0]:,} points, more than the {bounds.MAX_SCENE_POINTS:,} a map may hold",
                         source=source)
    if p.shape[0] < NEIGHBOURS + 1:
        raise SceneError(f"{field}: {p.shape[0]} points, a map needs at least {NEIGHBOURS + 1}", source=source)
    if not np.isfinite(p).all():
        finite = np.isfinite(p).all(axis=1)
        raise SceneError(f"{field}: point {int(np.argmin(finite))} is not a finite number", source=source)
    lo, hi = p.min(axis=0), p.max(axis=0)
    extent = float((hi - lo).max())
    if extent > bounds.MAX_SCENE_EXTENT_M:
        raise SceneError(f"{field}: extent {extent:.0f} m, more than the {bounds.MAX_SCENE_EXTENT_M:.0f} m a scene "
                         "may span", source=source)
    return p


def _spread(v: np.ndarray) -> np.ndarray:
    """The 21 low bits of each integer spread to every third bit (a Morton code's one axis)."""
    v = v.astype(np.uint64) & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def morton(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Each point's Morton code (21 bits an axis over the points' bounding box) and the side of
    the finest cell it resolves [m]: points close in space are close in the codes' order."""
    lo = points.min(axis=0)
    base = max(float((points.max(axis=0) - lo).max()) / (2**21 - 1), 1e-6)
    code = np.zeros(points.shape[0], dtype=np.uint64)
    for j in range(3):
        code |= _spread(np.floor((points[:, j] - lo[j]) / base).astype(np.int64)) << np.uint64(j)
    return code, base


def thin(points: np.ndarray, normals: np.ndarray | None, limit: int = MAX_SPLATS
         ) -> tuple[np.ndarray, np.ndarray | None, float]:
    """The centroids (and summed normals) of the occupied cells of the finest voxel grid, among
    sides a power of two apart, that has at most ``limit`` of them, and the voxel's side [m]
    (0: ``points`` already had few enough). One sort of the points' Morton codes serves every
    side: a cell of twice the side is the code shifted by three bits."""
    n = points.shape[0]
    if n <= limit:
        return points, normals, 0.0
    code, base = morton(points)
    order = np.argsort(code)
    code = code[order]
    # the level at which each pair of neighbours in the sorted order falls into one cell: above
    # the highest bit in which their codes differ, a third of it (three bits a level)
    diff = code[1:] ^ code[:-1]
    del code
    bit = np.frexp(diff.astype(float))[1] - 1  # highest set bit (−1 for equal codes) ...
    bit -= (np.right_shift(diff, np.maximum(bit, 0).astype(np.uint64)) == 0) & (bit > 0)  # ... exact past 2^53
    split = (bit // 3 + 1).astype(np.int64)  # the pair is apart at every level below this one
    del diff, bit
    cells = n - np.cumsum(np.bincount(split, minlength=23))  # cells of each level: 1 + the pairs apart
    level = int(np.argmax(cells <= limit))
    cell = np.empty(n, dtype=np.int64)
    cell[order] = np.concatenate([[0], np.cumsum(split > level)])
    del order, split
    m = int(cell.max()) + 1
    count = np.bincount(cell, minlength=m).astype(float)
    out = np.column_stack([np.bincount(cell, weights=points[:, j], minlength=m) for j in range(3)]) / count[:, None]
    if normals is not None:
        # a cell's normals summed after turning each to the side of the cell's first one
        nrm = np.asarray(normals, float)
        first = np.empty(m, dtype=np.int64)
        first[cell[::-1]] = np.arange(n - 1, -1, -1)
        sign = np.where(np.einsum("ij,ij->i", nrm, nrm[first[cell]]) < 0, -1.0, 1.0)
        normals = np.column_stack([np.bincount(cell, weights=nrm[:, j] * sign, minlength=m) for j in range(3)])
    return out, normals, base * 2**level


def neighbourhoods(points: np.ndarray, k: int = NEIGHBOURS, workers: int = -1):
    """Each point's ``k`` nearest other points: their distances and indices (N × k each)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points, balanced_tree=False, compact_nodes=False)
    dist, idx = tree.query(points, k=k + 1, workers=workers)
    return dist[:, 1:], idx[:, 1:]


def smallest_eigenvectors(C: np.ndarray) -> np.ndarray:
    """The unit eigenvector of the smallest eigenvalue of each symmetric 3 × 3 matrix (N × 3 × 3),
    in closed form: the eigenvalue from the characteristic cubic (trigonometric solution), the
    vector the largest cross product of two rows of ``C − λI``."""
    a, b, c = C[:, 0, 0], C[:, 1, 1], C[:, 2, 2]
    d, e, f = C[:, 0, 1], C[:, 0, 2], C[:, 1, 2]
    q = (a + b + c) / 3.0
    p1 = d * d + e * e + f * f
    p = np.sqrt(((a - q) ** 2 + (b - q) ** 2 + (c - q) ** 2 + 2.0 * p1) / 6.0)
    safe = np.where(p > 0, p, 1.0)
    A, B, Cc = (a - q) / safe, (b - q) / safe, (c - q) / safe
    D, E, F = d / safe, e / safe, f / safe
    r = np.clip(0.5 * (A * (B * Cc - F * F) - D * (D * Cc - F * E) + E * (D * F - B * E)), -1.0, 1.0)
    lam = q + 2.0 * p * np.cos(np.arccos(r) / 3.0 + 2.0 * np.pi / 3.0)
    r0 = np.stack([a - lam, d, e], axis=1)
    r1 = np.stack([d, b - lam, f], axis=1)
    r2 = np.stack([e, f, c - lam], axis=1)
    cand = np.stack([np.cross(r0, r1), np.cross(r0, r2), np.cross(r1, r2)], axis=1)
    norm = np.linalg.norm(cand, axis=2)
    best = np.argmax(norm, axis=1)
    k = np.arange(C.shape[0])
    v = cand[k, best]
    nv = norm[k, best]
    out = np.divide(v, nv[:, None], out=np.zeros_like(v), where=nv[:, None] > 0)
    out[nv <= 0] = (0.0, 0.0, 1.0)  # isotropic or a single point: no direction is preferred
    return out


def pca_normals(points: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The unit normal of each point: the direction of least spread of it and its neighbours
    (``idx``, N × k), the eigenvector of their covariance with the smallest eigenvalue."""
    out = np.empty_like(points)
    for a in range(0, points.shape[0], _CHUNK):
        b = min(points.shape[0], a + _CHUNK)
        nb = np.concatenate([points[a:b, None, :], points[idx[a:b]]], axis=1)
        nb -= nb.mean(axis=1, keepdims=True)
        out[a:b] = smallest_eigenvectors(np.einsum("nki,nkj->nij", nb, nb))
    return out


def _unit(normals: np.ndarray, source: str, field: str) -> np.ndarray:
    norm = np.linalg.norm(normals, axis=1)
    bad = ~(np.isfinite(norm) & (norm > 1e-9))
    if bad.any():
        raise SceneError(f"{field}: normal {int(np.argmax(bad))} is not a direction (zero or not finite)",
                         source=source)
    return normals / norm[:, None]


def splats(points: np.ndarray, normals: np.ndarray, side: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Squares of ``side`` centred on the points, perpendicular to the unit normals: 4 vertices
    and 2 triangles each."""
    axis = np.zeros_like(normals)
    pick = np.abs(normals[:, 0]) < 0.9
    axis[pick, 0] = 1.0
    axis[~pick, 1] = 1.0
    u = np.cross(normals, axis)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross(normals, u)
    h = 0.5 * side[:, None]
    u *= h
    w *= h
    v = np.stack([points - u - w, points + u - w, points + u + w, points - u + w], axis=1).reshape(-1, 3)
    base = 4 * np.arange(points.shape[0], dtype=np.int64)[:, None]
    faces = np.stack([base + np.array([0, 1, 2]), base + np.array([0, 2, 3])], axis=1).reshape(-1, 3)
    return v, faces


def scene_from_points(points: np.ndarray, normals: np.ndarray | None = None, *, source: str = "points",
                      kind: str = "map", features_per_m2: float = 1.0, workers: int = -1) -> Scene:
    """A map's points (N × 3, in the world frame) as a scene of splats (see the module
    docstring); ``normals`` (N × 3) where the map has them, else estimated. ``workers``: threads
    of the neighbour search (−1: every core)."""
    p = check_points(points, source)
    nrm = None
    if normals is not None:
        nrm = np.asarray(normals, dtype=float)
        if nrm.shape != p.shape:
            raise SceneError(f"normals: shape {nrm.shape}, expected that of the points {p.shape}", source=source)
    p = np.asarray(p, dtype=float)
    p, nrm, voxel = thin(p, nrm)
    if not voxel:  # not thinned: put the points in space-filling order (neighbour searches in cache)
        order = np.argsort(morton(p)[0])
        p = p[order]
        nrm = None if nrm is None else nrm[order]
    dist, idx = neighbourhoods(p, workers=workers)
    nrm = pca_normals(p, idx) if nrm is None else _unit(nrm, source, "normals")
    del idx
    side = SPLAT_SCALE * dist.mean(axis=1)
    del dist
    median = float(np.median(side))
    np.minimum(side, MAX_SPLAT_OVER_MEDIAN * median, out=side)
    side = np.maximum(side, 1e-3 * median if median > 0 else 1e-3)
    v, f = splats(p, nrm, side)
    return Scene(v, f, np.zeros(f.shape[0], dtype=np.int64), (Surface(kind, source, features_per_m2),), source=source)
