"""A scene seen from above: each surface's outline as line segments in the ground plane (what a
map draws under a route).

A surface's outline is the boundary of its level triangles seen from above (a building's roof,
a pole's top, the ground, a tunnel's ceiling: each edge that only one of them has) and the trace
of its upright triangles on the ground (a wall, a guard rail: their edges seen from above, points
dropped). Segments are bounded (:data:`MAX_SEGMENTS`): a surface beyond what is left is given
by the rectangle that holds it (a point-cloud map's millions of splats), and the answer says so.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .model import Scene

MAX_SEGMENTS = 20_000
"""Most segments of one scene's outline."""
LEVEL_NZ = 0.5
"""A triangle whose normal's vertical part is at least this is level (seen as an area from above)."""
_GRID_M = 1e-3  # corners closer than this are one corner


def _canonical(e: np.ndarray) -> np.ndarray:
    """Segments (K × 4) as integer keys on the corner grid, each from its lesser end."""
    key = np.round(e / _GRID_M).astype(np.int64)
    swap = (key[:, 0] > key[:, 2]) | ((key[:, 0] == key[:, 2]) & (key[:, 1] > key[:, 3]))
    key[swap] = key[swap][:, [2, 3, 0, 1]]
    return key


def _segments(tri: np.ndarray) -> np.ndarray:
    """The outline of triangles ``tri`` (T × 3 × 3) seen from above (K × 4: x0, y0, x1, y1)."""
    if tri.shape[0] == 0:
        return np.zeros((0, 4))
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    level = np.abs(n[:, 2]) >= LEVEL_NZ * np.maximum(np.linalg.norm(n, axis=1), 1e-300)
    t = tri[:, :, :2]
    edges = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]).reshape(-1, 4)  # 3T × 4, by corner
    lev = np.tile(level, 3)
    out = []
    if lev.any():  # edges of the level triangles that no other level triangle shares
        e = edges[lev]
        _, inverse, counts = np.unique(_canonical(e), axis=0, return_inverse=True, return_counts=True)
        out.append(e[counts[inverse.ravel()] == 1])
    if (~lev).any():  # upright triangles: their edges seen from above, points dropped
        e = edges[~lev]
        out.append(e[np.hypot(e[:, 2] - e[:, 0], e[:, 3] - e[:, 1]) > _GRID_M])
    e = np.vstack(out)
    _, first = np.unique(_canonical(e), axis=0, return_index=True)  # one of each, wall and roof alike
    return e[np.sort(first)]


def outlines(scene: Scene, max_segments: int = MAX_SEGMENTS) -> dict[str, Any]:
    """The scene's outline from above: ``{"surfaces": [{kind, name, segments: [[x0, y0, x1, y1],
    …], boxed}], "bounds_m": [[x_min, y_min], [x_max, y_max]], "boxed": n}`` — ``boxed`` where a
    surface's segments would exceed what is left of ``max_segments`` and its bounding rectangle is
    given instead (the surfaces with the fewest triangles are outlined first), ``omitted`` the
    surfaces left out once not even a rectangle fits."""
    tri = scene.triangles
    order = np.argsort(np.bincount(scene.face_surface, minlength=len(scene.surfaces)), kind="stable")
    left = max_segments
    surfaces: list[dict[str, Any] | None] = [None] * len(scene.surfaces)
    boxed = omitted = 0
    for k in order:
        mine = tri[scene.face_surface == k]
        if mine.shape[0] == 0:
            continue
        if left < 4:
            omitted += 1
            continue
        seg = _segments(mine) if mine.shape[0] <= 3 * left else None
        is_box = seg is None or seg.shape[0] > left - 4
        if is_box:
            lo, hi = mine[:, :, :2].reshape(-1, 2).min(axis=0), mine[:, :, :2].reshape(-1, 2).max(axis=0)
            seg = np.array([[lo[0], lo[1], hi[0], lo[1]], [hi[0], lo[1], hi[0], hi[1]],
                            [hi[0], hi[1], lo[0], hi[1]], [lo[0], hi[1], lo[0], lo[1]]])
            boxed += 1
        left -= seg.shape[0]
        s = scene.surfaces[k]
        surfaces[k] = {"kind": s.kind, "name": s.name, "boxed": is_box,
                       "segments": np.round(seg, 3).tolist()}
    lo, hi = scene.bounds
    return {"surfaces": [s for s in surfaces if s is not None], "bounds_m": [lo[:2].tolist(), hi[:2].tolist()],
            "boxed": boxed, "omitted": omitted}
