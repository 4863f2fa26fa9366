"""What one lidar scan tells about the sensor's pose: the information of point-to-plane registration.

A scan's point ``p`` (in the sensor frame S) lies on a surface of unit normal ``n`` (in S). Moving
the scan by a small right perturbation ``δ = [φ, ρ]`` of its pose (rotation, translation, in S)
moves the point by ``φ × p + ρ``, and the point-to-plane distance to the surface by

    e = nᵀ(φ × p + ρ) = [p × n; n]ᵀ δ,

so a scan whose points lie off their surfaces by σ_r along the normal (the lidar's range noise,
at every incidence: an oblique return's footprint spreads it along its ray by σ_r/c, c the cosine
of its incidence) holds the information

    H = Σ_points w / σ_r² · [p × n; n] [p × n; n]ᵀ        (6 × 6, order [rotation, translation])

about its pose against the surfaces, taken as exact — what an ICP's Gauss–Newton Hessian is at its solution
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

from ..core.parallel import each
from ..factors.optics import LidarBeams
from .model import Scene

CAST_BEAMS = 16
"""Most beams a scan is cast with (more beams are represented by these, evenly chosen)."""
AZIMUTHS = 256
"""Azimuths a scan is cast with over the lidar's horizontal field."""
MIN_INCIDENCE_COS = 0.1
"""Returns whose ray meets the surface more obliquely than this (|n·d| below it: beyond 84°
from the normal) are dropped, as a lidar's are: too little light comes back."""
REFINE = 8
"""Rays cast across the span between two neighbouring rays that see different surfaces."""
SCANS_PER_CALL = 64
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
    elevations: np.ndarray
    azimuths: np.ndarray
    azimuth_step: float
    full_circle: bool

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
    return ScanPattern(d, w, beams.min_range_m, beams.max_range_m, beams.range_noise_m, chosen, az, fov / n_az,
                       beams.horizontal_fov_deg >= 360.0)


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
    its pose (``H``, S × 6 × 6 in the sensor frame, [rotation, translation]), the information of
    the road plane fitted to its returns from the ground (``G``, S × 4 × 4: ``Σ w/σ² [p; 1][p; 1]ᵀ``
    over the plane's ``[δn, δh]`` in the sensor frame, a point on the plane ``nᵀp + h = 0``, n its
    upward normal and h the sensor's height above it: see
    :mod:`excite.factors.ground`) and its number of returns (``returns``)."""

    H: np.ndarray
    G: np.ndarray
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


def _rows(scene: Scene, R: np.ndarray, origin: np.ndarray, d_S: np.ndarray, scan: ScanPattern
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rays ``d_S`` (m × n × 3, in the sensor frames of m scans at ``R``, ``origin``: m × 3 × 3,
    m × 3): whether each returned (``ok``), the surface it hit (−1 for none), its row
    ``[p × n; n]`` and, for a return from the ground, its row ``[p; 1]`` of the road plane's fit
    (zero rows otherwise); flat over the m·n rays."""
    m, n = d_S.shape[:2]
    d_W = d_S @ np.swapaxes(R, 1, 2)
    hits = scene.cast(origin[:, None, :], d_W, scan.max_range_m)
    facing = hits.cos >= MIN_INCIDENCE_COS
    ok = hits.hit & (hits.distance >= scan.min_range_m) & facing
    pts = d_S.reshape(-1, 3) * np.where(ok, hits.distance, 0.0)[:, None]
    nrm = (hits.normal.reshape(m, n, 3) @ R).reshape(-1, 3) * ok[:, None]
    J = np.empty((m * n, 6))
    J[:, 0] = pts[:, 1] * nrm[:, 2] - pts[:, 2] * nrm[:, 1]
    J[:, 1] = pts[:, 2] * nrm[:, 0] - pts[:, 0] * nrm[:, 2]
    J[:, 2] = pts[:, 0] * nrm[:, 1] - pts[:, 1] * nrm[:, 0]
    J[:, 3:] = nrm
    ground = (ok & scene.is_ground()[np.maximum(hits.surface, 0)]).astype(float)
    P = np.empty((m * n, 4))
    P[:, :3] = pts * ground[:, None]
    P[:, 3] = ground
    return ok, np.where(ok, hits.surface, -1), J, P


def _directions(elevation: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Unit directions of elevation and azimuth angles (broadcast together), … × 3."""
    elevation, azimuth = np.broadcast_arrays(elevation, azimuth)
    ce = np.cos(elevation)
    return np.stack([ce * np.cos(azimuth), ce * np.sin(azimuth), np.sin(elevation)], axis=-1)


def _grid_directions(elevations: np.ndarray, azimuths: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """:func:`_directions` of every elevation × azimuth (elevation-major), the azimuths of scan k
    turned by ``turn[k]``: m × (n_el · n_az) × 3, each angle's sine and cosine taken once."""
    ce, se = np.cos(elevations), np.sin(elevations)
    az = azimuths[None, :] + turn[:, None]
    ca, sa = np.cos(az), np.sin(az)
    out = np.empty((turn.size, elevations.size, azimuths.size, 3))
    out[..., 0] = ce[None, :, None] * ca[:, None, :]
    out[..., 1] = ce[None, :, None] * sa[:, None, :]
    out[..., 2] = se[None, :, None]
    return out.reshape(turn.size, -1, 3)


def _sum_by_scan(rows: np.ndarray, weight: float, scan_of: np.ndarray, m: int) -> np.ndarray:
    """``Σ weight · r rᵀ`` of the rows of each of m scans (``scan_of``: each row's scan, in
    ascending order), m × d × d."""
    out = np.zeros((m, rows.shape[1], rows.shape[1]))
    bounds = np.searchsorted(scan_of, np.arange(m + 1))
    for k in np.flatnonzero(np.diff(bounds)):
        r = rows[bounds[k]:bounds[k + 1]]
        out[k] = weight * (r.T @ r)
    return out


def informations(scene: Scene, R_W_S: np.ndarray, p_W_S: np.ndarray, beams: LidarBeams,
                 density: float = 1.0, offsets: np.ndarray | None = None) -> Scans:
    """The registration information of a scan at each of the poses (see the module docstring),
    :data:`SCANS_PER_CALL` scans cast at a time; ``offsets``: each scan's azimuths turned by that
    fraction of a step (none: the same azimuths for every scan).

    The quadrature is refined where it matters: between two neighbouring rays of a beam that
    return from different surfaces (or one returns and the other does not: an edge, a pole, the
    end of a wall), :data:`REFINE` rays are cast evenly over the span between them and take over
    the two half-cells they cover, so that an edge's position is resolved to a fraction of a step."""
    R_W_S = np.asarray(R_W_S, float).reshape(-1, 3, 3)
    p_W_S = np.asarray(p_W_S, float).reshape(-1, 3)
    scan = pattern(beams, density)
    n_el, n_az = scan.elevations.size, scan.azimuths.size
    S = R_W_S.shape[0]
    off = np.zeros(S) if offsets is None else np.asarray(offsets, float)
    H = np.zeros((S, 6, 6))
    G = np.zeros((S, 4, 4))
    returns = np.zeros(S, dtype=np.int64)
    step = scan.azimuth_step
    w0 = scan.weight[0] / scan.range_noise_m**2
    def chunk(a: int) -> None:
        b = min(S, a + SCANS_PER_CALL)
        m = b - a
        d_S = _grid_directions(scan.elevations, scan.azimuths, off[a:b] * step)
        ok, sid, J, P = _rows(scene, R_W_S[a:b], p_W_S[a:b], d_S, scan)
        ok, sid = ok.reshape(m, n_el, n_az), sid.reshape(m, n_el, n_az)
        w = np.full((m, n_el, n_az), w0)
        # edges: a ray and its next neighbour along the beam see different things
        nxt = np.roll(sid, -1, axis=2)
        edge = sid != nxt
        if scan.full_circle is False:
            edge[:, :, -1] = False
        ks, ke, ka = np.nonzero(edge)
        if ks.size:
            flat = np.concatenate([(ks * n_el + ke) * n_az + ka, (ks * n_el + ke) * n_az + (ka + 1) % n_az])
            w -= 0.5 * w0 * np.bincount(flat, minlength=w.size).reshape(w.shape)
            frac = (np.arange(REFINE) + 0.5) / REFINE
            r_s = np.repeat(ks, REFINE)
            r_el = np.repeat(scan.elevations[ke], REFINE)
            r_az = (np.repeat(scan.azimuths[ka] + off[a + ks] * step, REFINE) + np.tile(frac, ks.size) * step)
            d_r = _directions(r_el, r_az)[:, None, :]
            r_ok, _, r_J, r_P = _rows(scene, R_W_S[a + r_s], p_W_S[a + r_s], d_r, scan)
            H[a:b] += _sum_by_scan(r_J, w0 / REFINE, r_s, m)
            G[a:b] += _sum_by_scan(r_P, w0 / REFINE, r_s, m)
            returns[a:b] += np.bincount(r_s, weights=r_ok, minlength=m).astype(np.int64)
        Jf = J.reshape(m, n_el * n_az, 6)
        H[a:b] += np.swapaxes(Jf * w.reshape(m, -1, 1), 1, 2) @ Jf
        Pf = P.reshape(m, n_el * n_az, 4)
        G[a:b] += np.swapaxes(Pf * w.reshape(m, -1, 1), 1, 2) @ Pf
        returns[a:b] += ok.reshape(m, -1).sum(axis=1)

    each(chunk, range(0, S, SCANS_PER_CALL))  # chunks on threads (Embree and numpy release the GIL)
    return Scans(H=H, G=G, returns=returns)
