"""Where in a scene a lidar is degenerate, and along what: the map of ``excite scene info``.

On a grid over the scene (every :data:`SPACING_M`, the lidar :data:`HEIGHT_M` above the ground
under each point, its axes the world's), a scan is ray-cast at every point
(:func:`excite.scene.lidar.informations`, all points at once) and its registration information
``H`` (6 × 6, [rotation, translation]) is read for the directions it leaves undetermined:

- **no information**: ``H``'s null space (eigenvalues at most :data:`NULL_RTOL` of the largest:
  the exact zeros of a direction no surface constrains — the open lot's x and y translation and
  yaw, a tunnel's axis);
- **weak**: directions whose σ from one scan exceeds what a lidar odometry drifts per scan pair
  (:data:`REFERENCE_SIGMA_RAD`, :data:`REFERENCE_SIGMA_M`: there the scene, not the drift, limits
  the pair; :mod:`excite.factors.odometry`), found in ``H`` scaled by those σ.

Each set of directions is named in words (``x translation``, ``yaw``, ``translation along 30°``):
an axis that lies wholly in the set is named by itself, and what is left by each direction's
dominant components. A point inside a structure (the ray up and the four level rays all meet
the same surface, not a ceiling) is marked as such rather than scanned from within.

The grid is bounded (:data:`MAX_CELLS`, :data:`MAX_COLUMNS`): a larger scene is surveyed with a
wider spacing, which the survey states.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..factors.optics import LidarBeams, lidar_beams
from .lidar import informations
from .model import Scene

if TYPE_CHECKING:
    from ..motion.trajectory import Trajectory

SPACING_M = 5.0
"""Distance between the points of the survey's grid [m]."""
HEIGHT_M = 1.8
"""Height of the lidar above the ground under each point [m] (a roof lidar's)."""
MAX_CELLS = 3000
"""Most points a survey scans (each a ray-cast scan of the lidar)."""
MAX_COLUMNS = 160
"""Most points across the map (the width of a terminal's line)."""
NULL_RTOL = 1e-9
"""A direction holds no information when its eigenvalue of ``H`` is at most this × the largest."""
REFERENCE_SIGMA_RAD = math.radians(0.05)
"""A rotation is weak when one scan's σ about it exceeds this: a good lidar odometry's drift per
scan pair (the bundled robotaxi's lidar at 10 Hz)."""
REFERENCE_SIGMA_M = 0.02
"""A translation is weak when one scan's σ along it exceeds this (as :data:`REFERENCE_SIGMA_RAD`)."""
AXES = ("rotation about x", "rotation about y", "yaw", "x translation", "y translation", "z translation")
"""The directions of ``H`` in words (rotations first, in world-aligned axes)."""
ON_SURFACE_M = 0.01
"""A grid point this close to a surface is on it (in a wall: no lidar can be there)."""
BEARING_STEP_DEG = 15.0
"""A level translation's bearing is named to this step."""
_WHOLE = 0.9  # an axis whose squared length in a set of directions reaches this lies in it
_PART = 0.2  # components of a direction with at least this squared weight name it
_DOWN_LAYERS = 8  # surfaces passed over looking down for the ground under a point

INSIDE, BLIND, CLEAR = "#", "~", "."
"""Map characters: inside a structure, a scan that returns nothing, every direction determined."""


def name_directions(W: np.ndarray) -> list[str]:
    """Words for the directions spanned by the orthonormal columns of ``W`` (6 × k, in the
    coordinates of :data:`AXES`): every axis lying in the span (within 10 %) by its name, then the
    rest of the span direction by direction — a level translation by its bearing from x towards y
    to :data:`BEARING_STEP_DEG` (``translation along 30°``; 0° is x, 90° y), anything else by its
    dominant components joined by ``+``."""
    k = W.shape[1]
    if k == 0:
        return []
    share = np.sum(W**2, axis=1)  # squared length of each axis's projection onto the span
    whole = [i for i in range(6) if share[i] >= _WHOLE]
    names = [AXES[i] for i in whole]
    if len(whole) >= k:
        return names
    rest = W - np.eye(6)[:, whole] @ (np.eye(6)[:, whole].T @ W)  # the span less the named axes
    U, s, _ = np.linalg.svd(rest, full_matrices=False)
    for v in U[:, : k - len(whole)].T:
        w2 = v**2
        if w2[3] + w2[4] >= _WHOLE:
            bearing = (BEARING_STEP_DEG * round(math.degrees(math.atan2(v[4], v[3])) / BEARING_STEP_DEG)) % 180.0
            names.append(AXES[3] if bearing == 0.0 else AXES[4] if bearing == 90.0 else
                         f"translation along {bearing:.0f}°")
            continue
        parts = [AXES[i] for i in np.argsort(-w2) if w2[i] >= _PART] or [AXES[int(np.argmax(w2))]]
        names.append(" + ".join(parts))
    return list(dict.fromkeys(names))


@dataclass(frozen=True)
class Reading:
    """What one scan of the survey leaves undetermined: ``status`` (``inside``, ``blind``,
    ``clear``, ``weak`` or ``degenerate``), the directions without information and the weak
    ones in words, and σ along the weakest direction with information, in units of the reference
    σ (None where there is none)."""

    status: str
    unobservable: tuple[str, ...] = ()
    weak: tuple[str, ...] = ()
    weakest_sigma_in_reference: float | None = None


def read_scan(H: np.ndarray, returns: int) -> Reading:
    """The :class:`Reading` of one scan's information ``H`` (6 × 6) of ``returns`` returns."""
    if returns == 0 or not np.any(H):
        return Reading("blind")
    d = np.array([REFERENCE_SIGMA_RAD] * 3 + [REFERENCE_SIGMA_M] * 3)
    Hu = d[:, None] * H * d[None, :]  # information per reference σ
    lam, V = np.linalg.eigh(0.5 * (Hu + Hu.T))
    null = lam <= NULL_RTOL * lam[-1]
    weak = ~null & (lam < 1.0)
    observed = lam[~null]
    sigma = float(1.0 / math.sqrt(observed[0])) if observed.size else None
    status = "degenerate" if null.any() else "weak" if weak.any() else "clear"
    return Reading(status, tuple(name_directions(V[:, null])), tuple(name_directions(V[:, weak])), sigma)


@dataclass
class Survey:
    """A scene's survey: the grid (cell centres ``x_m`` × ``y_m``, the lidar at ``z_m`` (ny × nx)),
    each cell's :class:`Reading` (``readings``, rows from the lowest y up) and the map's symbols."""

    scene: Scene
    spacing_m: float
    height_m: float
    asked_spacing_m: float
    beams: LidarBeams
    x_m: np.ndarray
    y_m: np.ndarray
    z_m: np.ndarray
    readings: list[list[Reading]]
    seconds: float = 0.0
    symbols: dict[tuple[str, tuple[str, ...], tuple[str, ...]], str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        counts: dict[tuple, int] = {}
        for row in self.readings:
            for r in row:
                if r.status in ("degenerate", "weak"):
                    key = (r.status, r.unobservable, r.weak)
                    counts[key] = counts.get(key, 0) + 1
        upper = iter("ABCDEFGHIJKLMNOPQRSTUVWXYZ")
        lower = iter("abcdefghijklmnopqrstuvwxyz")
        for key in sorted(counts, key=lambda k: -counts[k]):
            self.symbols[key] = next(upper if key[0] == "degenerate" else lower, "?")

    def symbol(self, r: Reading) -> str:
        return {"inside": INSIDE, "blind": BLIND, "clear": CLEAR}.get(r.status) or \
            self.symbols[(r.status, r.unobservable, r.weak)]

    def rows(self) -> list[str]:
        """The map, one line per row of the grid, the highest y first (x to the right)."""
        return ["".join(self.symbol(r) for r in row) for row in reversed(self.readings)]

    def legend(self) -> list[tuple[str, str, int]]:
        """(symbol, what it means, cells) of every symbol on the map."""
        flat = [r for row in self.readings for r in row]
        out = []
        for sym, text, status in ((CLEAR, "every direction determined", "clear"),
                                  (BLIND, "nothing in range: the scan returns nothing", "blind"),
                                  (INSIDE, "inside a structure", "inside")):
            n = sum(r.status == status for r in flat)
            if n:
                out.append((sym, text, n))
        counts: dict[str, int] = {}
        for r in flat:
            if r.status in ("degenerate", "weak"):
                s = self.symbol(r)
                counts[s] = counts.get(s, 0) + 1
        seen: set[str] = set()
        for (status, null, weak), sym in self.symbols.items():
            if sym in seen:
                continue
            seen.add(sym)
            if sym == "?":
                out.append((sym, "other combinations", counts[sym]))
                continue
            text = []
            if null:
                text.append("no information along " + ", ".join(null))
            if weak:
                text.append("weak along " + ", ".join(weak))
            out.append((sym, "; ".join(text), counts[sym]))
        return out

    def to_dict(self) -> dict[str, Any]:
        s = self.scene
        lo, hi = s.bounds
        kinds: dict[str, int] = {}
        for surf in s.surfaces:
            kinds[surf.kind] = kinds.get(surf.kind, 0) + 1
        return {
            "scene": {"name": s.source, "digest": s.digest},
            "bounds_m": {"min": lo.tolist(), "max": hi.tolist()},
            "extent_m": (hi - lo).tolist(),
            "triangles": s.n_triangles,
            "surfaces": len(s.surfaces),
            "surfaces_by_kind": kinds,
            "area_m2_by_kind": s.area_by_kind(),
            "survey": {
                "spacing_m": self.spacing_m, "asked_spacing_m": self.asked_spacing_m, "height_m": self.height_m,
                "lidar": self.beams.model_dump(),
                "reference_sigma": {"rotation_rad": REFERENCE_SIGMA_RAD, "translation_m": REFERENCE_SIGMA_M},
                "x_m": self.x_m.tolist(), "y_m": self.y_m.tolist(),
                "map": self.rows(),
                "legend": [{"symbol": sym, "meaning": text, "cells": n} for sym, text, n in self.legend()],
                "cells": [{"x_m": float(self.x_m[i]), "y_m": float(self.y_m[j]), "z_m": float(self.z_m[j, i]),
                           "status": r.status, "unobservable": list(r.unobservable), "weak": list(r.weak),
                           "weakest_sigma_in_reference": r.weakest_sigma_in_reference}
                          for j, row in enumerate(self.readings) for i, r in enumerate(row)],
                "seconds": self.seconds,
            },
        }


def grid(scene: Scene, spacing_m: float = SPACING_M) -> tuple[float, np.ndarray, np.ndarray]:
    """(spacing, x, y) of the survey's grid over the scene's footprint: cell centres every
    ``spacing_m``, or wider where that would exceed :data:`MAX_CELLS` or :data:`MAX_COLUMNS`."""
    lo, hi = scene.bounds[:, :2]
    span = np.maximum(hi - lo, 1e-9)
    s = float(spacing_m)
    while True:
        n = np.maximum(1, np.ceil(span / s - 1e-9)).astype(int)
        if n[0] <= MAX_COLUMNS and n[0] * n[1] <= MAX_CELLS:
            break
        s = math.ceil(s * 1.05 * 10.0) / 10.0
    centre = 0.5 * (lo + hi)
    x = centre[0] + (np.arange(n[0]) - 0.5 * (n[0] - 1)) * s
    y = centre[1] + (np.arange(n[1]) - 0.5 * (n[1] - 1)) * s
    return s, x, y


def ground_heights(scene: Scene, xy: np.ndarray) -> np.ndarray:
    """The height of the ground under each point ``xy`` (N × 2): the first surface of kind ground
    met looking down from above the scene (through roofs and ceilings), else the lowest surface
    met, else the scene's lowest point."""
    n = xy.shape[0]
    top = scene.bounds[1, 2] + 1.0
    z = np.full(n, np.nan)
    lowest = np.full(n, np.nan)
    start = np.full(n, top)
    todo = np.arange(n)
    ground = scene.is_ground()
    down = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (n, 3))
    for _ in range(_DOWN_LAYERS):
        if todo.size == 0:
            break
        o = np.column_stack([xy[todo], start[todo]])
        reach = start[todo] - scene.bounds[0, 2] + 1.0
        h = scene.cast(o, down[: todo.size], reach)
        at = start[todo] - h.distance
        hit = h.hit
        lowest[todo[hit]] = at[hit]
        found = hit & ground[np.maximum(h.surface, 0)]
        z[todo[found]] = at[found]
        start[todo[hit]] = at[hit] - 1e-3
        todo = todo[hit & ~found]
    z = np.where(np.isnan(z), lowest, z)
    return np.where(np.isnan(z), scene.bounds[0, 2], z)


def inside(scene: Scene, p: np.ndarray) -> np.ndarray:
    """Whether each point ``p`` (N × 3) is inside a structure: the ray up and the four level rays
    all meet one surface, and it is not a ceiling (a tunnel's inside is a place to drive); or on
    one (a ray meets a surface within :data:`ON_SURFACE_M`)."""
    n = p.shape[0]
    dirs = np.array([[0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], float)
    reach = float(np.linalg.norm(scene.bounds[1] - scene.bounds[0])) + 1.0
    h = scene.cast(np.repeat(p, 5, axis=0), np.tile(dirs, (n, 1)), reach)
    surf = h.surface.reshape(n, 5)
    same = np.all(surf == surf[:, :1], axis=1) & (surf[:, 0] >= 0)
    kinds = np.array([s.kind for s in scene.surfaces] + [""])
    on = np.any((h.hit & (h.distance < ON_SURFACE_M)).reshape(n, 5), axis=1)
    return on | (same & ~np.isin(kinds[surf[:, 0]], ["ceiling", "ground"]))


def survey(scene: Scene, spacing_m: float = SPACING_M, height_m: float = HEIGHT_M,
           beams: LidarBeams | None = None) -> Survey:
    """The survey of ``scene`` (see the module docstring) with the lidar ``beams`` (default
    :func:`~excite.factors.optics.lidar_beams` of None: the rigs' default lidar)."""
    import time

    from ..errors import SceneError

    if not (math.isfinite(spacing_m) and spacing_m > 0):
        raise SceneError(f"--spacing must be a distance > 0 m, got {spacing_m:g}")
    if not (math.isfinite(height_m) and 0 < height_m <= 100):
        raise SceneError(f"--height must be within 0 … 100 m, got {height_m:g}")
    t0 = time.perf_counter()
    b = lidar_beams(beams)
    s, x, y = grid(scene, spacing_m)
    X, Y = np.meshgrid(x, y)  # ny × nx
    xy = np.column_stack([X.ravel(), Y.ravel()])
    z = ground_heights(scene, xy) + height_m
    p = np.column_stack([xy, z])
    within = inside(scene, p)
    H = np.zeros((p.shape[0], 6, 6))
    returns = np.zeros(p.shape[0], dtype=np.int64)
    out = np.flatnonzero(~within)
    if out.size:
        scans = informations(scene, np.broadcast_to(np.eye(3), (out.size, 3, 3)), p[out], b)
        H[out], returns[out] = scans.H, scans.returns
    flat = [Reading("inside") if within[k] else read_scan(H[k], int(returns[k])) for k in range(p.shape[0])]
    readings = [flat[j * x.size:(j + 1) * x.size] for j in range(y.size)]
    return Survey(scene, s, height_m, float(spacing_m), b, x, y, z.reshape(y.size, x.size), readings,
                  seconds=time.perf_counter() - t0)


def along_route(traj: "Trajectory", sensor: str | None = None) -> list[dict[str, Any]]:
    """What the scene leaves undetermined along a drive that sees it (:func:`excite.scene.along.seen`):
    at each scan ray-cast along it for ``sensor`` (default: the first lidar seeing it), its time,
    where the vehicle was (in the scene's frame) and the scan's :class:`Reading` (in world-aligned
    axes, as the survey's map). Empty when the drive sees no scene."""
    view = traj.scene
    if view is None or not view.t:
        return []
    name = sensor if sensor is not None else next(iter(view.t))
    t = view.t[name]
    p = traj.translation(t)[0] + traj.origin
    out = []
    for k, H in enumerate(view.H_W[name]):
        r = read_scan(H, 1 if np.any(H) else 0)
        out.append({"t_s": float(t[k]), "x_m": float(p[k, 0]), "y_m": float(p[k, 1]), "status": r.status,
                    "unobservable": list(r.unobservable), "weak": list(r.weak),
                    "weakest_sigma_in_reference": r.weakest_sigma_in_reference})
    return out
