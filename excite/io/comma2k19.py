"""A comma2k19 segment folder read as a drive of its own: the car's IMU, its four CAN wheel speeds,
its steering angle and radar tracks, its GNSS fixes and the dataset's pose, on one clock and in
excite's frames.

The format (comma.ai's comma2k19 dataset, one folder per minute-long segment): every signal is
a folder holding two numpy arrays without extension, ``t`` (seconds of the device's boot clock)
and ``value``; ``global_pose`` holds the camera's pose as bare arrays. What excite reads, and how
(the column orders, units and clocks were checked against the raw CAN messages and the pose):

========================================  ==========================================================
``processed_log/IMU/gyro``, ``accelerometer``  ~104 Hz, axes forward-right-down (FRD), rad/s and
                                           m/s² (specific force); to B (x forward, y left, z up):
                                           ``diag(1, −1, −1)``. ``gyro`` is already
                                           ``gyro_uncalibrated − gyro_bias``.
``processed_log/CAN/wheel_speed``          ~83 Hz, m/s, columns [FL, FR, RL, RR] (the Toyota DBC's
                                           0.01 km/h: quantum 0.002778 m/s)
``processed_log/CAN/steering_angle``       the steering-wheel angle, deg, positive to the left,
                                           step 0.1°
``processed_log/CAN/radar``                one row per valid track per 20-Hz cycle: [forward
                                           distance + 2.7 m, lateral distance (left), range rate
                                           m/s (Doppler, not the longitudinal relative speed),
                                           nan, nan, track address, new-track flag]
``processed_log/GNSS/live_gnss_ublox``,    [lat deg, lon deg, speed m/s, UTC **ms** since 1970,
``live_gnss_qcom``                         altitude m (ellipsoidal), bearing deg from north,
                                           clockwise]; the fix epoch is UTC → GPS time of week
                                           (+18 leap s) → boot clock through ``frame_gps_times``
``global_pose/frame_times``, ``_positions``,  20 Hz, the *camera*'s ECEF position and velocity and
``_velocities``, ``_orientations``         its orientation (quaternion w-first, taking camera
                                           FRD vectors into ECEF); a fusion of this IMU, GNSS and
                                           vision, so not independent of the IMU
========================================  ==========================================================

Everything is re-based on one clock, seconds since the first pose (``t0_boot_s`` is that pose's
boot time), and the world is the local ENU frame at the first pose (z up). The pose is the
camera's; excite's vehicle frame V is at the rear axle with x along the direction of travel:
:func:`camera_in_vehicle` finds the camera's rotation in V from the data (V's x is the mean
direction of the camera's velocity: the camera points 0.9° left of travel and 3.8° down on the
example minute) and takes its position in V as given (``CAMERA_IN_V_M``, a RAV4's windshield
mount: 1.8 m ahead of the rear axle, 1.0 m above it; the vertical lever arm is what matters, the
pose seen 1.02 m above the body's pitch centre).

Readers: :func:`read_comma2k19` (the folder as a :class:`Comma2k19`), :func:`trajectory` (the
drive of V through the pose, with the measured IMU: :class:`~excite.io.bags.ImuTrajectory`),
:func:`can_recording` (the CAN stream as :class:`~excite.factors.ackermann.CanRecording`),
:func:`stationary_detections` and :func:`radar_ego_velocity` (the radar's stationary targets and
the ego-velocity fits over them). Every problem is a :class:`~excite.errors.RouteError` naming
the folder and the signal.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..core import bounds, so3
from ..errors import RouteError
from ..factors.ackermann import CanRecording
from ..motion.trajectory import Trajectory
from .poses import DEFAULT_CUTOFF_HZ, trajectory_from_poses
from .sniff import is_comma2k19

R_FLU_FRD = np.diag([1.0, -1.0, -1.0])  # comma's forward-right-down axes → excite's x forward, y left, z up
RADAR_TO_CENTER_M = 2.7  # what the processed radar's forward distance adds to the radar's own
KMH_QUANTUM_MPS = 0.01 / 3.6  # the wheel speeds' resolution
STEERING_QUANTUM_DEG = 0.1
GPS_MINUS_UTC_S = 18.0  # leap seconds since 2017-01-01 (the dataset was recorded in 2018)
GPS_EPOCH_UNIX_S = 315964800.0
WEEK_S = 604800.0
CAMERA_IN_V_M = (1.8, 0.0, 1.0)
WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3

_REQUIRED = ("processed_log/IMU/gyro", "processed_log/IMU/accelerometer", "processed_log/CAN/wheel_speed",
             "processed_log/CAN/steering_angle", "global_pose/frame_times", "global_pose/frame_positions",
             "global_pose/frame_velocities", "global_pose/frame_orientations")


@dataclass(frozen=True)
class Series:
    """One signal: times ``t`` [s, the reader's clock] and values (rows)."""

    t: np.ndarray
    value: np.ndarray


@dataclass(frozen=True)
class RadarTracks:
    """The radar's valid tracks, one row per track and cycle: time ``t`` [s], ``cycle`` (rows
    within 10 ms of each other), the target's position seen from the radar ``x_m`` (forward),
    ``y_m`` (left), its ``range_rate_mps`` (Doppler: negative closing), the track ``address``,
    ``new_track`` (the track's first cycle) and ``duplicate`` (the same three numbers as another
    track of the cycle)."""

    t: np.ndarray
    cycle: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    range_rate_mps: np.ndarray
    address: np.ndarray
    new_track: np.ndarray
    duplicate: np.ndarray

    @property
    def azimuth_rad(self) -> np.ndarray:
        return np.arctan2(self.y_m, self.x_m)

    @property
    def n_cycles(self) -> int:
        return int(self.cycle.max()) + 1 if self.cycle.size else 0

    def cycle_times(self) -> np.ndarray:
        """The first row's time of every cycle."""
        out = np.full(self.n_cycles, np.inf)
        np.minimum.at(out, self.cycle, self.t)
        return out


@dataclass(frozen=True)
class GnssFixes:
    """One receiver's fixes: ``t`` [s] when logged, ``fix_t`` [s] the fix epoch (its UTC stamp on
    the reader's clock; logged 150–200 ms later), ``lat_deg``, ``lon_deg``, ``alt_m`` (ellipsoidal),
    ``speed_mps``, ``bearing_deg`` (course over ground, from north, clockwise), ``utc_s``."""

    receiver: str
    t: np.ndarray
    fix_t: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    speed_mps: np.ndarray
    bearing_deg: np.ndarray
    utc_s: np.ndarray

    def enu(self, origin: tuple[float, float, float]) -> np.ndarray:
        """The fixes in the local ENU frame at ``origin`` (lat, lon [deg], ellipsoidal height [m])."""
        return enu_of(self.lat_deg, self.lon_deg, self.alt_m, origin)


@dataclass(frozen=True)
class CameraPose:
    """The dataset's pose of the camera in the local ENU frame: ``R_W_C`` (camera axes x
    forward, y left, z up), position ``p_W_C`` [m], velocity ``v_W`` [m/s]; ``origin`` the ENU
    origin (lat, lon [deg], ellipsoidal height [m])."""

    t: np.ndarray
    R_W_C: np.ndarray
    p_W_C: np.ndarray
    v_W: np.ndarray
    origin: tuple[float, float, float]


@dataclass(frozen=True)
class Comma2k19:
    """A segment on one clock (seconds since the first pose; ``t0_boot_s`` its boot time), in
    excite's frames: the IMU in B (``gyro``, ``accel``), the four wheel speeds [FL, FR, RL, RR] m/s,
    the steering-wheel angle [rad, left positive], the radar's tracks, the GNSS receivers' fixes
    (by receiver: ``ublox``, ``qcom``; those the folder has) and the camera's pose."""

    path: str
    name: str
    t0_boot_s: float
    gyro: Series
    accel: Series
    wheel_speeds: Series
    steering_rad: Series
    radar: RadarTracks | None
    gnss: dict[str, GnssFixes]
    pose: CameraPose

    def can_speed_mps(self, t: np.ndarray) -> np.ndarray:
        """The mean of the four wheel speeds at ``t`` (the car's own CAN speed is exactly that)."""
        return np.interp(t, self.wheel_speeds.t, self.wheel_speeds.value.mean(axis=1))


# --- reading ----------------------------------------------------------------------------------


def _load(root: Path, rel: str) -> np.ndarray:
    p = root / rel
    if not p.is_file():
        raise RouteError(f"{rel}: missing (a comma2k19 segment has processed_log/… and global_pose/…)",
                         source=str(root))
    try:
        a = np.load(p, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise RouteError(f"{rel}: not a numpy array ({exc})", source=str(root)) from None
    if a.dtype.kind not in "fiu":
        raise RouteError(f"{rel}: expected numbers, got {a.dtype}", source=str(root))
    if a.size > bounds.MAX_SAMPLES * 16:
        raise RouteError(f"{rel}: {a.size:,} numbers, over the limit of {bounds.MAX_SAMPLES * 16:,}", source=str(root))
    return a.astype(float)


def _signal(root: Path, rel: str, columns: int | None, t0: float) -> Series:
    """``rel``'s ``t`` and ``value``, checked: as many rows as times, the columns expected, finite
    increasing times."""
    t = _load(root, f"{rel}/t")
    v = _load(root, f"{rel}/value")
    if t.ndim != 1 or v.shape[0] != t.size:
        raise RouteError(f"{rel}: {t.size} times for {v.shape[0]} values", source=str(root))
    if columns is not None and (v.ndim != (1 if columns == 0 else 2) or (columns and v.shape[1] != columns)):
        want = "one value per time" if columns == 0 else f"{columns} columns"
        raise RouteError(f"{rel}: expected {want}, got shape {v.shape}", source=str(root))
    if t.size < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise RouteError(f"{rel}: times must be finite and sorted ({t.size} of them)", source=str(root))
    return Series(t - t0, v)


def _finite(root: Path, rel: str, s: Series) -> Series:
    bad = ~np.all(np.isfinite(s.value.reshape(s.t.size, -1)), axis=1)
    if bad.any():
        raise RouteError(f"{rel}: value {int(np.argmax(bad))} is NaN or infinite", source=str(root))
    return s


def read_comma2k19(path: str | Path) -> Comma2k19:
    """A comma2k19 segment folder (see the module docstring)."""
    root = Path(path)
    if not is_comma2k19(root):
        raise RouteError("not a comma2k19 segment folder (processed_log/ and global_pose/)", source=str(root))
    for rel in _REQUIRED:
        if not ((root / rel).is_file() or (root / rel / "t").is_file()):
            raise RouteError(f"{rel}: missing", source=str(root))
    gp = root / "global_pose"
    tp = _load(root, "global_pose/frame_times")
    if tp.ndim != 1 or tp.size < 6 or not np.all(np.diff(tp) > 0):
        raise RouteError("global_pose/frame_times: needs 6 or more increasing times", source=str(root))
    t0 = float(tp[0])
    P = _load(root, "global_pose/frame_positions")
    V = _load(root, "global_pose/frame_velocities")
    Q = _load(root, "global_pose/frame_orientations")
    for rel, a, cols in (("frame_positions", P, 3), ("frame_velocities", V, 3), ("frame_orientations", Q, 4)):
        if a.shape != (tp.size, cols) or not np.all(np.isfinite(a)):
            raise RouteError(f"global_pose/{rel}: expected {tp.size} finite rows of {cols}, got {a.shape}",
                             source=str(root))
    norm = np.linalg.norm(Q, axis=1)
    if np.abs(norm - 1).max() > 1e-3:
        raise RouteError(f"global_pose/frame_orientations: quaternion {int(np.argmax(np.abs(norm - 1)))} is not a "
                         "unit quaternion", source=str(root))
    origin = lla_of_ecef(P[0])
    R_enu = R_enu_ecef(origin[0], origin[1])
    R_ecef_frd = Rotation.from_quat(Q / norm[:, None], scalar_first=True).as_matrix()
    pose = CameraPose(tp - t0, R_enu @ R_ecef_frd @ R_FLU_FRD, (P - P[0]) @ R_enu.T, V @ R_enu.T, origin)

    gyro = _finite(root, "processed_log/IMU/gyro", _signal(root, "processed_log/IMU/gyro", 3, t0))
    accel = _finite(root, "processed_log/IMU/accelerometer", _signal(root, "processed_log/IMU/accelerometer", 3, t0))
    wheels = _finite(root, "processed_log/CAN/wheel_speed", _signal(root, "processed_log/CAN/wheel_speed", 4, t0))
    steer = _finite(root, "processed_log/CAN/steering_angle",
                    _signal(root, "processed_log/CAN/steering_angle", 0, t0))
    radar = _radar(root, t0) if (root / "processed_log/CAN/radar/t").is_file() else None
    gnss = {}
    gps = gp / "frame_gps_times"
    tow_minus = None
    if gps.is_file():
        g = _load(root, "global_pose/frame_gps_times")
        if g.shape == (tp.size, 2):
            tow_minus = float(np.median(g[:, 1] - tp))
    for receiver in ("ublox", "qcom"):
        rel = f"processed_log/GNSS/live_gnss_{receiver}"
        if (root / rel / "t").is_file():
            s = _signal(root, rel, 6, t0)
            utc = s.value[:, 3] / 1e3
            if tow_minus is None:
                fix = np.full_like(utc, np.nan)
            else:
                fix = ((utc - GPS_EPOCH_UNIX_S + GPS_MINUS_UTC_S) % WEEK_S) - tow_minus - t0
            gnss[receiver] = GnssFixes(receiver, s.t, fix, s.value[:, 0], s.value[:, 1], s.value[:, 4], s.value[:, 2],
                                       s.value[:, 5], utc)
    return Comma2k19(str(root), root.name, t0, Series(gyro.t, gyro.value @ R_FLU_FRD),
                     Series(accel.t, accel.value @ R_FLU_FRD), wheels,
                     Series(steer.t, np.deg2rad(steer.value)), radar, gnss, pose)


def _radar(root: Path, t0: float) -> RadarTracks:
    s = _signal(root, "processed_log/CAN/radar", 7, t0)
    v = s.value
    if not np.all(np.isfinite(v[:, [0, 1, 2, 5, 6]])):
        raise RouteError("processed_log/CAN/radar: a track's distance, speed or address is NaN", source=str(root))
    cycle = np.cumsum(np.r_[True, np.diff(s.t) > 0.01]) - 1
    duplicate = np.zeros(s.t.size, dtype=bool)
    key = np.round(v[:, :3], 6)
    order = np.lexsort((key[:, 2], key[:, 1], key[:, 0], cycle))
    same = np.all(key[order][1:] == key[order][:-1], axis=1) & (cycle[order][1:] == cycle[order][:-1])
    duplicate[order[1:][same]] = True
    return RadarTracks(s.t, cycle, v[:, 0] - RADAR_TO_CENTER_M, v[:, 1], v[:, 2], v[:, 5].astype(int),
                       v[:, 6] != 0, duplicate)


# --- geodesy (WGS84) --------------------------------------------------------------------------


def lla_of_ecef(p: np.ndarray) -> tuple[float, float, float]:
    """Latitude, longitude [deg] and ellipsoidal height [m] of an ECEF point (Bowring's iteration)."""
    x, y, z = (float(c) for c in p)
    lon = np.arctan2(y, x)
    r = np.hypot(x, y)
    lat = np.arctan2(z, r * (1 - WGS84_E2))
    for _ in range(8):
        n = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
        h = r / np.cos(lat) - n
        lat = np.arctan2(z, r * (1 - WGS84_E2 * n / (n + h)))
    n = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
    return float(np.degrees(lat)), float(np.degrees(lon)), float(r / np.cos(lat) - n)


def ecef_of(lat_deg, lon_deg, alt_m) -> np.ndarray:
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    n = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
    return np.stack([(n + alt_m) * np.cos(lat) * np.cos(lon), (n + alt_m) * np.cos(lat) * np.sin(lon),
                     (n * (1 - WGS84_E2) + alt_m) * np.sin(lat)], axis=-1)


def R_enu_ecef(lat_deg: float, lon_deg: float) -> np.ndarray:
    """The rotation taking ECEF vectors into the ENU frame at (lat, lon)."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    return np.array([[-np.sin(lo), np.cos(lo), 0.0],
                     [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
                     [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]])


def enu_of(lat_deg, lon_deg, alt_m, origin: tuple[float, float, float]) -> np.ndarray:
    """WGS84 points in the local ENU frame at ``origin``."""
    o = ecef_of(*origin)
    return (ecef_of(np.asarray(lat_deg), np.asarray(lon_deg), np.asarray(alt_m)) - o) @ R_enu_ecef(*origin[:2]).T


# --- the drive --------------------------------------------------------------------------------


def camera_in_vehicle(rec: Comma2k19) -> np.ndarray:
    """``R_V_C``, the camera's rotation in V whose x axis is the camera's mean direction of
    travel (no roll: the pose's level is kept)."""
    v_C = np.einsum("nji,nj->ni", rec.pose.R_W_C, rec.pose.v_W)
    moving = np.linalg.norm(v_C, axis=1) > 1.0
    if moving.sum() < 2:
        return np.eye(3)
    d = v_C[moving] / np.linalg.norm(v_C[moving], axis=1, keepdims=True)
    m = d.mean(axis=0)
    yaw = np.arctan2(m[1], m[0])
    pitch = -np.arctan2(m[2], np.hypot(m[0], m[1]))  # positive: the travel points below the camera's x
    # V's x in camera axes is m: V = C rotated by (yaw, pitch); R_C_V = Rz(yaw) Ry(pitch), R_V_C its transpose
    return (so3.rot_z(np.array([yaw]))[0] @ so3.rot_y(np.array([pitch]))[0]).T


def trajectory(rec: Comma2k19, *, camera_in_v_m: tuple[float, float, float] = CAMERA_IN_V_M,
               cutoff_hz: float = DEFAULT_CUTOFF_HZ, rate_hz: float | None = None, measured_imu: bool = True,
               imu_in_v: np.ndarray | None = None) -> Trajectory:
    """The drive of V (rear axle, x along travel) through the dataset's camera pose, in the ENU
    frame of the first pose, on the reader's clock; with ``measured_imu`` its IMU samples are the
    recording's (an :class:`~excite.io.bags.ImuTrajectory`, IMU frame = the rig's B: pass the rig's
    ``R_V_B`` as ``imu_in_v`` to check nothing else)."""
    R_V_C = camera_in_vehicle(rec)
    R_W_V = rec.pose.R_W_C @ R_V_C.T
    p_W_V = rec.pose.p_W_C - np.einsum("nij,j->ni", R_W_V, np.asarray(camera_in_v_m, dtype=float))
    traj = trajectory_from_poses(rec.pose.t, p_W_V, R_W_V, cutoff_hz=cutoff_hz, rate_hz=rate_hz, name=rec.name)
    if not measured_imu:
        return traj
    from .bags.imu import ImuTrajectory

    g, a = rec.gyro, rec.accel
    n = min(g.t.size, a.t.size)
    if not np.allclose(g.t[:n], a.t[:n], atol=1e-3):
        raise RouteError("processed_log/IMU: gyro and accelerometer are not sampled together", source=rec.path)
    t = g.t[:n] - rec.pose.t[0]
    return ImuTrajectory.of(traj, t, g.value[:n], a.value[:n], "comma2k19 IMU (FRD → FLU)")


def can_recording(rec: Comma2k19, *, steering: bool = True) -> CanRecording:
    """The CAN stream as the Ackermann kind reads it (speeds [FL, FR, RL, RR] m/s; steering rad,
    sampled with the speeds on this dataset), on the trajectory's clock (seconds since the first
    pose): :func:`excite.factors.ackermann.interval_means` gives every keyframe interval's means."""
    w, s = rec.wheel_speeds, rec.steering_rad
    st = None
    if steering:
        st = np.interp(w.t, s.t, s.value)
    period = float(np.median(np.diff(w.t)))
    return CanRecording(w.t - rec.pose.t[0], w.value, st, period)


def stationary_detections(rec: Comma2k19, gate_mps: float = 0.5) -> np.ndarray:
    """Which radar detections are stationary targets: a range rate within ``gate_mps`` of what a
    stationary target at the detection's azimuth shows the car at its CAN speed (``ṙ = −v·cos az``:
    the radar points along the travel within a degree, and the lever arm's ω × p is below 0.02 m/s
    on a highway), not a track's first cycle, not a duplicate of another track of its cycle."""
    r = rec.radar
    if r is None:
        raise RouteError("processed_log/CAN/radar: the segment has no radar", source=rec.path)
    v = rec.can_speed_mps(r.t)
    return (np.abs(r.range_rate_mps + v * np.cos(r.azimuth_rad)) < gate_mps) & ~r.new_track & ~r.duplicate


@dataclass(frozen=True)
class EgoVelocity:
    """Per radar cycle with enough stationary targets: time ``t`` [s], the fitted ego-velocity in
    the radar's frame ``v_mps`` (forward, left), the number of targets, the residual RMS [m/s]."""

    t: np.ndarray
    v_mps: np.ndarray
    targets: np.ndarray
    rms_mps: np.ndarray


def radar_ego_velocity(rec: Comma2k19, selected: np.ndarray | None = None, min_targets: int = 2,
                       min_spread_deg: float = 5.0, reject_mps: float = 0.3) -> EgoVelocity:
    """The 2-D ego-velocity of every cycle with at least ``min_targets`` stationary targets spread
    over ``min_spread_deg`` of azimuth: least squares of ``ṙ_i = −(v_x cos az_i + v_y sin az_i)``,
    targets off by more than ``reject_mps`` dropped and the fit repeated."""
    r = rec.radar
    sel = stationary_detections(rec) if selected is None else selected
    az = r.azimuth_rad
    out_t, out_v, out_n, out_r = [], [], [], []
    idx = np.flatnonzero(sel)
    for c in np.unique(r.cycle[idx]):
        i = idx[r.cycle[idx] == c]
        for _ in range(2):
            if i.size < min_targets or np.ptp(az[i]) < np.radians(min_spread_deg):
                break
            U = np.column_stack([np.cos(az[i]), np.sin(az[i])])
            v = np.linalg.lstsq(-U, r.range_rate_mps[i], rcond=None)[0]
            res = r.range_rate_mps[i] + U @ v
            keep = np.abs(res) < reject_mps
            if keep.all():
                out_t.append(r.t[i].min())
                out_v.append(v)
                out_n.append(i.size)
                out_r.append(float(np.sqrt(np.mean(res ** 2))))
                break
            i = i[keep]
    return EgoVelocity(np.array(out_t), np.array(out_v).reshape(-1, 2), np.array(out_n, dtype=int), np.array(out_r))
