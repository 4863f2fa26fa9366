"""A lidar's frame pairs in a scene, as the physical simulator measures them.

Where the drive sees a scene, the simulator ray-casts what the lidar sees at each of its frames,
on the lidar's real pattern — every beam at every azimuth step of its horizontal resolution
(:func:`scan_pattern`), not the information model's quadrature at samples along the drive —
occlusion honoured, returns dropped as the model drops them (range limits, grazing incidence).
Each pair's relative pose is then what registering scan j against the surfaces scan i saw gives
(the information model's law: each return σ off its surface, the surfaces taken as exact):

- **its error** is drawn from the registration's covariance (:func:`pair_covariance`):
  ``H⁺``, ``H = Σ J Jᵀ / σ²`` over every return of scan j on the real pattern,
  ``J = [p × n; n]`` — what small_gicp's registrations of such scans against a map of the
  surfaces follow (tests/scan_registration.py). Registering every pair by ICP would cost a
  second or so per pair, hours for a Monte Carlo of a whole drive: the draw from the covariance
  of the pair's actual scan is the approximation;
- **along what the surfaces leave unconstrained** (a tunnel's axis, the open lot's x, y and yaw:
  directions ``H`` has no information about) the two scans look alike wherever the sensor is, and
  the registration reports no motion there (small_gicp's, in a tunnel, slides to where the two
  scans coincide): the pair's motion along them is removed;
- **the odometry's drift** is added as for any odometry (:meth:`~excite.factors.odometry.Odometry.simulate`).

The scans are cast once per drive at the rig's nominal extrinsic (a true extrinsic a few targets
from it sees the same surfaces), and every trial draws its errors from them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ValidateError
from ..factors import base as registry
from ..factors.base import Nominal
from ..factors.optics import lidar_beams
from ..motion.trajectory import Trajectory
from ..scene import lidar
from ..scene.model import Scene

MAX_RAYS = 400_000
"""Most rays of one simulated scan (a 128-beam lidar at 0.18° is 262,000)."""
NULL_RTOL = 1e-9
"""An eigenvalue of a scan's ``H₁`` below this fraction of its largest is a direction it does
not see."""


def scan_pattern(beams) -> lidar.ScanPattern:
    """Every beam of ``beams`` (:class:`~excite.factors.optics.LidarBeams`) at every azimuth step of
    its horizontal resolution over its horizontal field, each ray of weight 1."""
    n_az = max(1, int(round(beams.horizontal_fov_deg / beams.horizontal_resolution_deg)))
    el = beams.elevations_rad
    if el.size * n_az > MAX_RAYS:
        raise ValidateError(f"the lidar's pattern has {el.size * n_az:,} rays per scan, more than the "
                            f"{MAX_RAYS:,} the simulator casts")
    fov = np.radians(beams.horizontal_fov_deg)
    step = fov / n_az
    az = -0.5 * fov + (np.arange(n_az) + 0.5) * step if beams.horizontal_fov_deg < 360.0 else np.arange(n_az) * step
    E, A = np.meshgrid(el, az, indexing="ij")
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1).reshape(-1, 3)
    return lidar.ScanPattern(d, np.ones(d.shape[0]), beams.min_range_m, beams.max_range_m, beams.range_noise_m,
                             el, az, step, beams.horizontal_fov_deg >= 360.0)


def pair_covariance(points: np.ndarray, normals: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """The registration covariance of a scan pair whose scan j has returns ``points`` with unit
    ``normals`` (sensor frame, N × 3) and range noise ``sigma`` (see the module docstring): the
    pseudo-inverse of its information ``H``, and the projector onto the directions its surfaces
    do not constrain (6 × 6 each, order [rotation, translation], a right perturbation of scan j's
    pose)."""
    H = lidar.point_information(points, normals, sigma)
    lam, V = np.linalg.eigh(0.5 * (H + H.T))
    seen = lam > NULL_RTOL * max(lam[-1], 0.0)
    Vs = V[:, seen]
    N = V[:, ~seen] @ V[:, ~seen].T
    return Vs @ np.diag(1.0 / lam[seen]) @ Vs.T, N


@dataclass(frozen=True)
class PairNoise:
    """One lidar's frame pairs in a scene (see the module docstring): the pairs' first keyframes,
    for each pair a square root of its registration covariance (``root``, F × 6 × 6: an error
    ``root @ z`` for z standard normal), the projector onto the directions its scans do not see
    (``null``) and the information the registration reports (``information``: the covariance's
    pseudo-inverse, nothing along ``null``), F × 6 × 6 each, in S_j, [rotation, translation]."""

    first: np.ndarray
    root: np.ndarray
    null: np.ndarray
    information: np.ndarray


def pair_noise(scene: Scene, traj: Trajectory, rig, sensor) -> PairNoise:
    """The :class:`PairNoise` of lidar ``sensor`` of ``rig`` on ``traj`` in ``scene``: scan j of
    every frame pair cast at the sensor's nominal pose at keyframe j."""
    kind = registry.kind_of_sensor(sensor.kind)
    nom = Nominal.of(traj, rig)
    first = registry.factor_keyframes(kind, rig, sensor, nom.n_keyframes, nom)
    j = first + registry.stride(kind, rig, sensor)
    R_BS, p_BS = sensor.T_B_S.R, sensor.T_B_S.p
    R_W_S = nom.R[j] @ R_BS
    p_W_S = nom.p[j] + nom.R[j] @ p_BS
    scan = scan_pattern(lidar_beams(sensor.beams))
    root = np.zeros((j.size, 6, 6))
    null = np.zeros((j.size, 6, 6))
    info = np.zeros((j.size, 6, 6))
    for k in range(j.size):
        pts, nrm, _, _ = lidar.cast_scan(scene, R_W_S[k], p_W_S[k], scan)
        C, N = pair_covariance(pts, nrm, scan.range_noise_m)
        lam, V = np.linalg.eigh(0.5 * (C + C.T))
        seen = np.trace(N) < 6 - 0.5
        lam = np.where(np.einsum("ij,jk,ki->i", V.T, N, V) < 0.5, np.maximum(lam, 0.0), 0.0)
        root[k] = V * np.sqrt(lam)
        null[k] = N
        if seen:
            inv = np.where(lam > 0, 1.0 / np.where(lam > 0, lam, 1.0), 0.0)
            info[k] = (V * inv) @ V.T
    return PairNoise(first, root, null, info)
