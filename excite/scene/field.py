"""A scene's lidar information over an area, ray-cast once and looked up along many drives.

:func:`excite.scene.along.seen` ray-casts every scan of a drive: a 90 s drive costs a few hundred
scans, 0.2–0.3 s of CPU. A search that scores thousands of drives in the same lot (the drivable
plan's, :mod:`excite.plan.drivable.search`) pays that for every one. A :class:`Field` casts the
scans once, on a grid over the area the drives stay in: for every lidar of the rig, a scan at
every grid position (the sensor where the vehicle standing level at that place with that heading
puts it) and every one of ``headings`` headings, each scan's information turned to world-aligned
axes as :func:`~excite.scene.along.seen` keeps it. :meth:`Field.seen` then gives a drive the
scans of the same sample times (:func:`~excite.scene.along.sample_times`) interpolated from the
grid at each sample's sensor position and heading (bilinear in the position, linear in the
heading); a convex combination of information matrices is one.

What the lookup leaves out: the body's pitch and roll (the scans are cast level; a drive's
suspension tilts the beams by a degree or two), the sensor's height changes with the suspension,
and the spread of the azimuths between samples (each grid scan is cast with the same turn). It is
an approximation to rank candidate drives by, and a search that uses it scores its final choice
with :func:`~excite.scene.along.seen` itself; the tests hold its scores to the exact ones.

A rig with a camera has no field (a camera's frame pair depends on the drive's own motion between
its frames): :func:`field` refuses it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core import bounds
from ..errors import SceneError
from ..factors.optics import lidar_beams
from ..motion.trajectory import SceneView, Trajectory
from .along import cameras, lidars, sample_times, sensor_poses
from .lidar import informations
from .model import Scene

STEP_M = 2.5
"""The grid's spacing [m]."""
HEADINGS = 4
"""Headings a scan is cast at per grid position."""
MAX_SCANS = 50_000
"""At most this many scans in one field (a grid finer or an area larger is refused)."""


@dataclass(frozen=True)
class Field:
    """Per lidar name, the world-aligned information of a scan (``H``: K × X × Y × 6 × 6, and
    the road plane's ``G``: K × X × Y × 4 × 4) at headings ``2πk/K`` and the grid's positions
    ``xs`` × ``ys`` of the sensor. ``digest`` and ``source``: the scene's."""

    xs: np.ndarray
    ys: np.ndarray
    H: dict[str, np.ndarray]
    G: dict[str, np.ndarray]
    digest: str
    source: str

    def _weights(self, x: np.ndarray, y: np.ndarray, psi: np.ndarray):
        """Indices and weights of the 8 grid scans around each (x, y, heading)."""
        def axis(v, grid):
            step = grid[1] - grid[0]
            u = np.clip((v - grid[0]) / step, 0.0, grid.size - 1 - 1e-9)
            i = np.floor(u).astype(int)
            return i, u - i

        ix, fx = axis(x, self.xs)
        iy, fy = axis(y, self.ys)
        k = next(iter(self.H.values())).shape[0]
        u = np.mod(psi, 2 * math.pi) / (2 * math.pi / k)
        ik = np.floor(u).astype(int) % k
        fk = u - np.floor(u)
        out = []
        for a, wa in ((ik, 1 - fk), ((ik + 1) % k, fk)):
            for b, wb in ((ix, 1 - fx), (ix + 1, fx)):
                for c, wc in ((iy, 1 - fy), (iy + 1, fy)):
                    out.append((a, b, c, wa * wb * wc))
        return out

    def seen(self, traj: Trajectory, rig) -> Trajectory:
        """``traj`` carrying the field's scans at the sample times of
        :func:`~excite.scene.along.seen` (see the module docstring)."""
        t = sample_times(traj)
        times, H_W, G_W = {}, {}, {}
        for s in lidars(rig):
            if s.name not in self.H:
                raise SceneError(f"the scene field has no lidar {s.name!r}")
            R, p = sensor_poses(traj, rig, s, t)
            psi = np.arctan2(R[:, 1, 0], R[:, 0, 0])
            H = np.zeros((t.size, 6, 6))
            G = np.zeros((t.size, 4, 4))
            for a, b, c, w in self._weights(p[:, 0], p[:, 1], psi):
                H += w[:, None, None] * self.H[s.name][a, b, c]
                G += w[:, None, None] * self.G[s.name][a, b, c]
            times[s.name], H_W[s.name], G_W[s.name] = t, H, G
        return traj.with_scene(SceneView(self.digest, times, H_W, G_W, self.source))


def field(scene: Scene, rig, lo: tuple[float, float], hi: tuple[float, float], step_m: float = STEP_M,
          headings: int = HEADINGS) -> Field:
    """The scene's :class:`Field` for ``rig`` over the rectangle ``lo`` … ``hi`` (the vehicle's
    positions, [m]; the grid reaches a lever arm beyond it, so that every sensor position of a
    vehicle inside lies within), ``step_m`` apart, ``headings`` headings."""
    if cameras(rig):
        raise SceneError(f"a scene field holds lidar scans only; the rig {rig.name!r} has cameras "
                         f"({', '.join(s.name for s in cameras(rig))}): see each drive with seen()")
    if not lidars(rig):
        raise SceneError(f"the rig {rig.name!r} has no lidar to build a scene field for")
    if not (math.isfinite(step_m) and step_m > 0) or not 1 <= headings <= 64:
        raise SceneError(f"a scene field needs step_m > 0 and 1 to 64 headings, got {step_m} and {headings}")
    T_V_B = rig.config.vehicle.T_V_B
    reach = max(float(np.linalg.norm((T_V_B.p + T_V_B.R @ s.T_B_S.p)[:2])) for s in lidars(rig))
    lo = np.asarray(lo, float) - reach - step_m
    hi = np.asarray(hi, float) + reach + step_m
    nx = int(math.ceil((hi[0] - lo[0]) / step_m)) + 1
    ny = int(math.ceil((hi[1] - lo[1]) / step_m)) + 1
    n = nx * ny * headings * len(lidars(rig))
    if n > MAX_SCANS or max(hi - lo) > bounds.MAX_SCENE_EXTENT_M:
        raise SceneError(f"a scene field of {nx} × {ny} positions × {headings} headings ({n} scans) is over "
                         f"{MAX_SCANS} scans: a coarser step_m or a smaller area")
    xs = lo[0] + step_m * np.arange(nx)
    ys = lo[1] + step_m * np.arange(ny)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    H, G = {}, {}
    for s in lidars(rig):
        R_V_S = T_V_B.R @ s.T_B_S.R
        p_V_S = T_V_B.p + T_V_B.R @ s.T_B_S.p
        Hk, Gk = np.zeros((headings, nx, ny, 6, 6)), np.zeros((headings, nx, ny, 4, 4))
        for k in range(headings):
            a = 2 * math.pi * k / headings
            Rz = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
            R_W_S = Rz @ R_V_S
            # the sensor's position on the grid: the vehicle placed so that its sensor is there
            p = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, p_V_S[2])])
            scans = informations(scene, np.repeat(R_W_S[None], gx.size, axis=0), p, lidar_beams(s.beams))
            B = np.zeros((6, 6))
            B[:3, :3] = B[3:, 3:] = R_W_S
            B4 = np.eye(4)
            B4[:3, :3] = R_W_S
            Hk[k] = (B @ scans.H @ B.T).reshape(nx, ny, 6, 6)
            Gk[k] = (B4 @ scans.G @ B4.T).reshape(nx, ny, 4, 4)
        H[s.name], G[s.name] = Hk, Gk
    return Field(xs, ys, H, G, scene.digest, scene.source)
