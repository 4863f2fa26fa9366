"""The drive and scenes the scene benchmarks cast in (``bench_scene.py``: the lidar,
``bench_camera.py``: the camera): the 90 s slalom in a 120 × 90 m lot, buildings beside it, and a
canyon of buildings around any drive."""

from __future__ import annotations

import numpy as np

from excite.motion.maneuvers import slalom
from excite.motion.trajectory import Trajectory
from excite.motion.vehicle import drive
from excite.scene import shapes
from excite.scene.model import Scene

LOT = (-60, -45, 60, 45)  # x_min, y_min, x_max, y_max [m]: the slalom stays inside
# two buildings on the lot's north side, and a low one at its south-west corner
BUILDINGS = ((-40, 30, -10, 45, 12), (0, 30, 35, 42, 9), (-50, -44, -30, -35, 6))


def slalom_drive(rig) -> Trajectory:
    """The 90 s slalom, driven with ``rig``'s suspension."""
    return drive(slalom(90.0), rig.suspension)


def lot(features_per_m2: float = 2.0) -> Scene:
    """The lot's ground (its texture: features per m², the camera's)."""
    return shapes.ground(*LOT, features_per_m2=features_per_m2)


def lot_with_buildings(ground: Scene, which: int = len(BUILDINGS)) -> Scene:
    """``ground`` and the first ``which`` of :data:`BUILDINGS` (2: both on one side)."""
    return Scene.combine([ground] + [shapes.box(*b) for b in BUILDINGS[:which]])


def canyon_around(traj, clearance_m: float = 9.0, grid_m: float = 20.0, seed: int = 3) -> Scene:
    """Ground under the drive and buildings on a grid wherever the drive does not pass near."""
    from scipy.spatial import cKDTree

    p = traj.translation(traj.times(5.0))[0][:, :2]
    lo, hi = p.min(axis=0) - 40.0, p.max(axis=0) + 40.0
    rng = np.random.default_rng(seed)
    parts = [shapes.ground(lo[0], lo[1], hi[0], hi[1], z=float(traj.translation(traj.times(1.0))[0][:, 2].min()) - 0.5)]
    tree = cKDTree(p)
    half = 0.5 * (grid_m - 4.0)
    for x in np.arange(lo[0], hi[0], grid_m):
        for y in np.arange(lo[1], hi[1], grid_m):
            d, _ = tree.query([x, y])
            if d > clearance_m + half * np.sqrt(2):
                parts.append(shapes.box(x - half, y - half, x + half, y + half, float(rng.uniform(10, 25)), base=-5.0))
    return Scene.combine(parts, source="canyon around the drive")
