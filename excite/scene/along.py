"""A scene along a drive: what the rig's lidars and cameras see at samples of the drive, attached to it.

:func:`seen` ray-casts a scan of each lidar (:mod:`excite.scene.lidar`) and a frame pair of each
camera (:mod:`excite.scene.camera`) at samples of the drive —
every :data:`SAMPLE_SPACING_M` of the vehicle's path or every :data:`SAMPLE_INTERVAL_S`, whichever
comes first — and returns the drive carrying them
(:class:`~excite.motion.trajectory.SceneView`): every evaluation of it (score, live windows,
mining, batch) then whitens each lidar and camera frame pair by the scene's information
(:mod:`excite.factors.odometry`). Samples are placed by the drive's own time and path from its
start, so a window of a drive sees what the whole drive sees there.

A scan's information is kept in world-aligned axes: turning in place, a 360° lidar sees the same
surfaces, so between samples only the distance travelled changes what it sees. A camera's pair
is the one that ends at the sample (its frames one frame interval apart, on the drive's own
motion: what the pair tells depends on that motion), its information about the right
perturbation of ``T_ij`` (in S_j) turned to the world's axes by frame j's orientation, as a
lidar scan's: the keyframe that closes a pair near the sample turns it back into its own S_j.
A camera looks one way, so a keyframe that has turned since its sample reads what the camera saw
looking the sample's way (the samples are close enough that this stays small: DESIGN, Scenes).
"""

from __future__ import annotations

import numpy as np

from ..factors.optics import DEFAULT_CAMERA, lidar_beams
from ..motion.trajectory import SceneView, Trajectory
from . import camera
from .lidar import informations
from .model import Scene

SAMPLE_SPACING_M = 4.0
"""Path between two scans ray-cast along a drive [m]."""
SAMPLE_INTERVAL_S = 2.0
"""Longest time between two scans ray-cast along a drive [s] (standing or turning in place)."""
_GRID_HZ = 20.0


def sample_times(traj: Trajectory) -> np.ndarray:
    """The times the scans are ray-cast at: on a 20 Hz grid from the drive's start, the first
    sample and each one :data:`SAMPLE_SPACING_M` of path or :data:`SAMPLE_INTERVAL_S` after the
    previous one, whichever comes first."""
    t = np.arange(traj.t_start, traj.t_end + 1e-9, 1.0 / _GRID_HZ)
    t = t[t <= traj.t_end]
    p = traj.translation(t)[0]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    keep = [0]
    i = 0
    while True:
        nxt = min(np.searchsorted(s, s[i] + SAMPLE_SPACING_M), np.searchsorted(t, t[i] + SAMPLE_INTERVAL_S - 1e-9))
        if nxt >= t.size:
            break
        keep.append(int(nxt))
        i = int(nxt)
    return t[keep]


def azimuth_offsets(t: np.ndarray) -> np.ndarray:
    """Each sample's turn of the scan's azimuths, in steps (``offsets`` of
    :func:`excite.scene.lidar.informations`): the
    golden-ratio sequence over the sample's index on the 20 Hz grid of the drive's clock (the
    same sample, the same turn, whatever window of the drive is looked at)."""
    k = np.round(np.asarray(t, float) * _GRID_HZ)
    return np.mod(k * 0.6180339887498949, 1.0)


def sensor_poses(traj: Trajectory, rig, sensor, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pose of ``sensor`` (a rig entry) in the world at times ``t``: ``R_W_S`` and ``p_W_S``
    (in the frame the drive's poses were given in: a logged drive's positions are re-based on
    its first, :attr:`~excite.motion.trajectory.Trajectory.origin`)."""
    R_W_V = traj.rotation(t)[0]
    p_W_V = traj.translation(t)[0] + traj.origin
    T_V_B, T_B_S = rig.config.vehicle.T_V_B, sensor.T_B_S
    R_W_B = R_W_V @ T_V_B.R
    p_W_B = p_W_V + R_W_V @ T_V_B.p
    return R_W_B @ T_B_S.R, p_W_B + R_W_B @ T_B_S.p


def lidars(rig) -> list:
    """The rig's lidar entries."""
    return [s for s in rig.config.sensors if s.kind == "lidar"]


def cameras(rig) -> list:
    """The rig's camera entries."""
    return [s for s in rig.config.sensors if s.kind == "camera"]


def camera_pairs(traj: Trajectory, rig, sensor, t: np.ndarray, scene: Scene, density: float = 1.0) -> np.ndarray:
    """The information of ``sensor``'s frame pairs that end at the times ``t`` (at the drive's
    start, the first pair), in world-aligned axes (S × 6 × 6; see the module docstring)."""
    dt = 1.0 / sensor.rate_hz
    t_j = np.clip(np.maximum(t, traj.t_start + dt), traj.t_start, traj.t_end)
    t_i = np.maximum(t_j - dt, traj.t_start)
    R_i, p_i = sensor_poses(traj, rig, sensor, t_i)
    R_j, p_j = sensor_poses(traj, rig, sensor, t_j)
    pairs = camera.informations(scene, R_i, p_i, R_j, p_j, sensor.optics or DEFAULT_CAMERA, density)
    B = np.zeros((t.size, 6, 6))
    B[:, :3, :3] = B[:, 3:, 3:] = R_j
    return B @ pairs.H @ np.swapaxes(B, 1, 2)


def seen(traj: Trajectory, rig, scene: Scene, density: float = 1.0) -> Trajectory:
    """``traj`` seeing ``scene`` with ``rig``'s lidars and cameras (see the module docstring;
    ``density`` multiplies the rays of each scan and frame: a finer quadrature, for checks)."""
    t = sample_times(traj)
    times, H_W, G_W = {}, {}, {}
    for s in lidars(rig):
        R_W_S, p_W_S = sensor_poses(traj, rig, s, t)
        scans = informations(scene, R_W_S, p_W_S, lidar_beams(s.beams), density, offsets=azimuth_offsets(t))
        B = np.zeros((t.size, 6, 6))
        B[:, :3, :3] = B[:, 3:, 3:] = R_W_S
        times[s.name] = t
        H_W[s.name] = B @ scans.H @ np.swapaxes(B, 1, 2)
        B4 = np.zeros((t.size, 4, 4))
        B4[:, :3, :3] = R_W_S
        B4[:, 3, 3] = 1.0
        G_W[s.name] = B4 @ scans.G @ np.swapaxes(B4, 1, 2)
    for s in cameras(rig):
        times[s.name] = t
        H_W[s.name] = camera_pairs(traj, rig, s, t, scene, density)
    return traj.with_scene(SceneView(scene.digest, times, H_W, G_W, scene.source))
