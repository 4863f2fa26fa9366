"""What one lidar scan tells about the sensor's pose: the information of point-to-plane registration.

A scan's point ``p`` (in the sensor frame S) lies on a surface of unit normal ``n`` (in S). Moving
the scan by a small right perturbation ``δ = [φ, ρ]`` of its pose (rotation, translation, in S)
moves the point by ``φ × p + ρ``, and the point-to-plane distance to the surface by

    e = nᵀ(φ × p + ρ) = [p × n; n]ᵀ δ,

so a scan whose points have range noise σ_r along the normal holds the information

    H = Σ_points w / σ_r² · [p × n; n] [p × n; n]ᵀ        (6 × 6, order [rotation, translation])

about its pose against the surfaces — what an ICP's Gauss–Newton Hessian is at its solution
(small_gicp's ``PLANE_ICP`` states its residual per axis, ``n ⊙ (q − T p)``; where the normals are
axis-aligned the two are the same). A direction no surface constrains has no information at all:
the open flat lot leaves x, y and yaw free, a tunnel its axis, a single wall the translation
along it — exact zeros, not small numbers, because every row is ``[p × n; n]`` of a surface that
does not see that motion.

**The scan is a quadrature.** Rays are cast (occlusion honoured: :meth:`Scene.cast
<excite.scene.model.Scene.cast>`) on a pattern coarser than the lidar's: up to
:data:`CAST_BEAMS` of its beams (evenly chosen) × :data:`AZIMUTHS` azimuths. Each ray stands for
the real points of its cell, counted as independent only ``correlation_deg`` apart
(:class:`~excite.factors.optics.LidarBeams`): its weight ``w`` is the number of independent
measurements in its cell. The information per solid angle is the lidar's, so doubling the rays
cast changes nothing once they resolve the scene.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..factors.optics import LidarBeams
from .model import Scene

CAST_BEAMS = 32
"""Most beams a scan is cast with (more beams are represented by these, evenly chosen)."""
AZIMUTHS = 256
"""Azimuths a scan is cast with over the lidar's horizontal field."""
MIN_INCIDENCE_COS = 0.1
"""Returns whose ray meets the surface more obliquely than this (|n·d| below it: beyond 84°
from the normal) are dropped, as a lidar's are: too little light comes back."""
SCANS_PER_CALL = 256
"""Scans ray-cast in one call to the ray caster (bounds the memory of a long drive)."""


@dataclass(frozen=True)
class ScanPattern:
    """The rays a scan is cast with, in the sensor frame (unit ``directions``, R × 3), each with
    its ``weight`` (independent measurements of its cell), and the lidar's range limits and noise."""

    directions: np.ndarray
    weight: np.ndarray
    min_range_m: float
    max_range_m: float
    range_noise_m: float

    @property
    def n_rays(self) -> int:
        return self.directions.shape[0]


def pattern(beams: LidarBeams, density: float = 1.0) -> ScanPattern:
    """The rays a scan of ``beams`` is cast with (``density`` multiplies the azimuths cast: a
    finer quadrature of the same lidar, for checks)."""
    elev = beams.elevations_rad
    n_beams = elev.size
    n_elev = min(n_beams, CAST_BEAMS)
    chosen = elev[np.unique(np.round(np.linspace(0, n_beams - 1, n_elev)).astype(int))]
    n_elev = chosen.size
    n_az = max(1, int(round(AZIMUTHS * density)))
    fov = np.radians(beams.horizontal_fov_deg)
    az = -0.5 * fov + (np.arange(n_az) + 0.5) * fov / n_az
    E, A = np.meshgrid(chosen, az, indexing="ij")
    d = np.column_stack([(np.cos(E) * np.cos(A)).ravel(), (np.cos(E) * np.sin(A)).ravel(), np.sin(E).ravel()])
    corr = np.radians(beams.correlation_deg)
    per_azimuth = (fov / n_az) / max(np.radians(beams.horizontal_resolution_deg), corr)
    per_beam = (n_beams / n_elev) * min(1.0, beams.beam_spacing_rad / corr)
    w = np.full(d.shape[0], per_azimuth * per_beam)
    return ScanPattern(d, w, beams.min_range_m, beams.max_range_m, beams.range_noise_m)


def point_rows(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """``[p × n; n]`` of every point (N × 6): the derivative of its point-to-plane distance by the
    scan's pose perturbation ``[φ, ρ]``."""
    return np.hstack([np.cross(points, normals), normals])


def point_information(points: np.ndarray, normals: np.ndarray, sigma: float,
                      weights: np.ndarray | None = None) -> np.ndarray:
    """``H = Σ w/σ² [p × n; n][p × n; n]ᵀ`` of points and unit normals in the sensor frame (N × 3)."""
    J = point_rows(np.asarray(points, float), np.asarray(normals, float))
    w = np.ones(J.shape[0]) if weights is None else np.asarray(weights, float)
    return (J * (w / sigma**2)[:, None]).T @ J


@dataclass(frozen=True)
class Scans:
    """Scans ray-cast at poses ``R_W_S, p_W_S`` (S × 3 × 3, S × 3): each scan's information about
    its pose (``H``, S × 6 × 6 in the sensor frame, [rotation, translation]) and its number of
    returns (``returns``)."""

    H: np.ndarray
    returns: np.ndarray


def cast_scan(scene: Scene, R_W_S: np.ndarray, p_W_S: np.ndarray, scan: ScanPattern):
    """One scan's returns: points and normals in the sensor frame (N × 3 each), their weights and
    the surface each hit."""
    d_W = scan.directions @ np.asarray(R_W_S, float).T
    hits = scene.cast(np.broadcast_to(p_W_S, d_W.shape), d_W, scan.max_range_m)
    ok = hits.hit & (hits.distance >= scan.min_range_m) & (np.abs(np.einsum("ij,ij->i", hits.normal, d_W)) >= MIN_INCIDENCE_COS)
    pts = scan.directions[ok] * hits.distance[ok, None]
    nrm = hits.normal[ok] @ np.asarray(R_W_S, float)
    return pts, nrm, scan.weight[ok], hits.surface[ok]


def informations(scene: Scene, R_W_S: np.ndarray, p_W_S: np.ndarray, beams: LidarBeams,
                 density: float = 1.0) -> Scans:
    """The registration information of a scan at each of the poses (see the module docstring),
    all scans cast :data:`SCANS_PER_CALL` at a time."""
    R_W_S = np.asarray(R_W_S, float).reshape(-1, 3, 3)
    p_W_S = np.asarray(p_W_S, float).reshape(-1, 3)
    scan = pattern(beams, density)
    S, Rn = R_W_S.shape[0], scan.n_rays
    H = np.zeros((S, 6, 6))
    returns = np.zeros(S, dtype=np.int64)
    for a in range(0, S, SCANS_PER_CALL):
        b = min(S, a + SCANS_PER_CALL)
        d_W = scan.directions[None] @ np.swapaxes(R_W_S[a:b], 1, 2)
        o = np.broadcast_to(p_W_S[a:b, None, :], d_W.shape)
        hits = scene.cast(o.reshape(-1, 3), d_W.reshape(-1, 3), scan.max_range_m)
        facing = np.abs(np.einsum("ij,ij->i", hits.normal, d_W.reshape(-1, 3))) >= MIN_INCIDENCE_COS
        ok = (hits.hit & (hits.distance >= scan.min_range_m) & facing).reshape(b - a, Rn)
        dist = np.where(ok, hits.distance.reshape(b - a, Rn), 0.0)
        pts = scan.directions[None] * dist[..., None]
        nrm = hits.normal.reshape(b - a, Rn, 3) @ R_W_S[a:b]
        J = np.concatenate([np.cross(pts, nrm), nrm], axis=2)
        w = np.where(ok, scan.weight[None], 0.0) / scan.range_noise_m**2
        H[a:b] = np.swapaxes(J * w[..., None], 1, 2) @ J
        returns[a:b] = ok.sum(axis=1)
    return Scans(H=H, returns=returns)
