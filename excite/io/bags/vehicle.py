"""A car's own signals in a bag: wheel speeds and a steering angle as ``sensor_msgs/JointState``,
a radar's ego-velocity as ``geometry_msgs/TwistWithCovarianceStamped`` (or ``TwistStamped``).

What is supported, and how it is read:

- **Wheel speeds**: ``sensor_msgs/JointState``, the ``velocity`` of four named joints [rad/s]
  (front left, front right, rear left, rear right: the names are the caller's, e.g.
  ``front_left_wheel_joint``), at the message's ``header.stamp``; optionally the ``position``
  [rad] of a steering joint in the same messages (a steering-wheel or a road-wheel angle: the
  rig's ``steering.ratio`` says which). Messages that lack one of the joints, or carry fewer
  velocities than names, are an error naming the message. A topic of wheel speeds in m/s
  (``speeds: mps``) is read the same way: the numbers are the joint's ``velocity``.
- **Radar ego-velocity**: ``geometry_msgs/TwistWithCovarianceStamped`` or ``TwistStamped``: the
  ``linear`` twist is the sensor's own velocity in its frame (``header.frame_id``), positive
  forward when the car drives forward (the convention of radar ego-motion estimators; a driver
  that publishes the world's velocity relative to the sensor is its negative); with covariance,
  the linear block's diagonal gives each component's σ (what :func:`ego_velocity_noise`
  summarises for the rig).

Every other message type on the topic is an error naming the supported ones. The readers return
stamps in nanoseconds; :func:`can_recording` and :func:`ego_velocity_at` turn them into what the
Ackermann and radar kinds compare with their models on a drive's clock (seconds from the poses'
first stamp).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core import bounds
from ...errors import BagError
from ...factors.ackermann import CanRecording
from .decode import Cursor
from ...core.units import listed
from .stream import check_stamps, count_bound, open_bag, stream_messages, time_window, topic_connections, is_ros2

JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
EGO_VELOCITY_TYPES = ("geometry_msgs/msg/TwistWithCovarianceStamped", "geometry_msgs/msg/TwistStamped")
VEHICLE_USES = {JOINT_STATE_TYPE: "wheels", **{t: "ego_velocity" for t in EGO_VELOCITY_TYPES}}  # bag_info's uses


@dataclass(frozen=True)
class WheelSpeeds:
    """Wheel speeds from JointState messages: stamps ``t_ns``, ``speeds`` (n × 4) in the order of
    ``joints`` [rad/s, or the topic's unit], the steering joint's ``steering`` position (n, rad)
    or None, the messages' frame."""

    t_ns: np.ndarray
    speeds: np.ndarray
    steering: np.ndarray | None
    joints: tuple[str, ...]
    frame: str


@dataclass(frozen=True)
class EgoVelocitySeries:
    """A radar's ego-velocity: stamps ``t_ns``, ``v`` (n × 3) [m/s] in the sensor's frame
    ``frame``, the linear block of the covariance ``cov`` (n × 3 × 3) or None (TwistStamped)."""

    t_ns: np.ndarray
    v: np.ndarray
    cov: np.ndarray | None
    frame: str


def _float64s(c: Cursor) -> tuple[float, ...]:
    """A sequence of float64 (an empty one has no alignment padding)."""
    n = c.u32()
    if n > 10_000:
        raise ValueError(f"a sequence of {n:,} numbers")
    return c.doubles(n) if n else ()


def _joint_state(c: Cursor) -> tuple[int, str, list[str], tuple, tuple]:
    t, frame = c.header()
    n = c.u32()
    if n > 10_000:
        raise ValueError(f"{n:,} joint names")
    names = [c.string() for _ in range(n)]
    return t, frame, names, _float64s(c), _float64s(c)


def _messages(path: Path, topic: str, types: tuple[str, ...], start_s, end_s):
    """(index, raw bytes, ros2) of the messages on ``topic``, its type checked."""
    with open_bag(path) as reader:
        cons = topic_connections(path, reader, topic)
        msgtype = cons[0].msgtype
        if msgtype not in types:
            raise BagError(path, f"type {msgtype} is not supported here (supported: "
                                 f"{', '.join(t.replace('/msg/', '/') for t in types)})", topic)
        count_bound(path, topic, cons, bounds.MAX_IMU_SAMPLES)
        ros2 = is_ros2(cons[0])
        start, stop = time_window(reader, start_s, end_s)
        for i, (_, raw) in enumerate(stream_messages(path, reader, cons, topic, start, stop)):
            yield i, raw, ros2, msgtype


def read_wheel_speeds(path: str | Path, topic: str, joints: tuple[str, str, str, str], *,
                      steering_joint: str | None = None, start_s: float | None = None,
                      end_s: float | None = None) -> WheelSpeeds:
    """The velocities of the four ``joints`` [FL, FR, RL, RR] (and the position of
    ``steering_joint``) in the ``sensor_msgs/JointState`` messages of ``topic`` (see the module
    docstring)."""
    path = Path(path)
    if len(joints) != 4 or len(set(joints)) != 4:
        raise BagError(path, f"name four different wheel joints [front left, front right, rear left, rear right], "
                             f"got {list(joints)}", topic)
    t_out, v_out, s_out = [], [], []
    frame = ""
    for i, raw, ros2, _ in _messages(path, topic, (JOINT_STATE_TYPE,), start_s, end_s):
        try:
            t, frame, names, pos, vel = _joint_state(Cursor(raw, ros2))
        except (struct.error, ValueError) as exc:
            raise BagError(path, f"message {i} is malformed ({exc})", topic) from None
        index = {n: k for k, n in enumerate(names)}
        missing = [j for j in joints + ((steering_joint,) if steering_joint else ()) if j not in index]
        if missing:
            raise BagError(path, f"message {i} has no joint {', '.join(repr(m) for m in missing)} (joints: "
                                 f"{listed(names)})", topic)
        if len(vel) < len(names):
            raise BagError(path, f"message {i} carries {len(vel)} velocities for {len(names)} joints", topic)
        t_out.append(t)
        v_out.append([vel[index[j]] for j in joints])
        if steering_joint:
            if len(pos) < len(names):
                raise BagError(path, f"message {i} carries {len(pos)} positions for {len(names)} joints: "
                                     f"no steering angle", topic)
            s_out.append(pos[index[steering_joint]])
    if len(t_out) < 2:
        raise BagError(path, f"{len(t_out)} JointState messages: need at least 2", topic)
    t = np.array(t_out, dtype=np.int64)
    v = np.array(v_out, dtype=float)
    st = np.array(s_out, dtype=float) if steering_joint else None
    _check(path, topic, t, v if st is None else np.column_stack([v, st]))
    _in_range(path, topic, v, "wheel_speed", "wheel speed")
    if st is not None:
        _in_range(path, topic, st[:, None], "steering_rad", f"steering joint {steering_joint!r}'s position")
    return WheelSpeeds(t, v, st, tuple(joints), frame)


def read_ego_velocity(path: str | Path, topic: str, *, start_s: float | None = None,
                      end_s: float | None = None) -> EgoVelocitySeries:
    """The linear twist (and its covariance) of the ``TwistWithCovarianceStamped`` or
    ``TwistStamped`` messages of ``topic`` (see the module docstring)."""
    path = Path(path)
    t_out, v_out, c_out = [], [], []
    frame = ""
    with_cov = True
    for i, raw, ros2, msgtype in _messages(path, topic, EGO_VELOCITY_TYPES, start_s, end_s):
        with_cov = msgtype.endswith("WithCovarianceStamped")
        try:
            c = Cursor(raw, ros2)
            t, frame = c.header()
            lin = c.doubles(3)
            c.doubles(3)  # angular
            cov = c.doubles(36) if with_cov else None
        except (struct.error, ValueError) as exc:
            raise BagError(path, f"message {i} is malformed ({exc})", topic) from None
        t_out.append(t)
        v_out.append(lin)
        if cov is not None:
            c_out.append(np.asarray(cov).reshape(6, 6)[:3, :3])
    if len(t_out) < 2:
        raise BagError(path, f"{len(t_out)} twist messages: need at least 2", topic)
    t = np.array(t_out, dtype=np.int64)
    v = np.array(v_out, dtype=float)
    _check(path, topic, t, v)
    _in_range(path, topic, v, "ego_velocity_mps", "linear velocity")
    covariance = np.array(c_out) if with_cov else None
    if covariance is not None:
        _in_range(path, topic, covariance.reshape(len(covariance), 9), "velocity_covariance_m2ps2", "linear covariance entry")
    return EgoVelocitySeries(t, v, covariance, frame)


def _check(path: Path, topic: str, t: np.ndarray, values: np.ndarray) -> None:
    bad = ~np.all(np.isfinite(values), axis=1)
    if bad.any():
        raise BagError(path, f"message {int(np.argmax(bad))} has a NaN or infinite value", topic)
    check_stamps(path, topic, t)


def _in_range(path: Path, topic: str, values: np.ndarray, name: str, what: str) -> None:
    """Every finite value of ``values`` (a row per message) within :data:`~excite.core.bounds.SIGNALS`' ``name``."""
    r = bounds.SIGNALS[name]
    bad = (values < r.lo) | (values > r.hi)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise BagError(path, f"message {i}: its {what} {values[i, j]:.6g} is outside the sane range {r}", topic)


def can_recording(wheels: WheelSpeeds, t0_ns: int) -> CanRecording:
    """The wheel speeds (and steering) as the Ackermann kind reads them, on the clock of a drive
    whose first pose is stamped ``t0_ns``: each reading holds since the previous stamp."""
    t = (wheels.t_ns - t0_ns).astype(float) * 1e-9
    return CanRecording(t, wheels.speeds, wheels.steering, float(np.median(np.diff(t))))


def ego_velocity_at(series: EgoVelocitySeries, t0_ns: int, t_s: np.ndarray, dimensions: int = 3,
                    tolerance_s: float | None = None) -> np.ndarray:
    """The ego-velocity at the times ``t_s`` (seconds from ``t0_ns``): the nearest message within
    ``tolerance_s`` (default half the messages' median period), NaN where there is none; its
    first ``dimensions`` components (a 2-D radar's x and y)."""
    t = (series.t_ns - t0_ns).astype(float) * 1e-9
    tol = 0.5 * float(np.median(np.diff(t))) if tolerance_s is None else tolerance_s
    k = np.clip(np.searchsorted(t, t_s), 1, t.size - 1)
    k = np.where(np.abs(t[k - 1] - t_s) < np.abs(t[k] - t_s), k - 1, k)
    out = series.v[k, :dimensions].copy()
    out[np.abs(t[k] - t_s) > tol] = np.nan
    return out


def ego_velocity_noise(series: EgoVelocitySeries) -> np.ndarray | None:
    """The median σ of each component [m/s] the messages' covariances state (None without)."""
    if series.cov is None:
        return None
    d = np.diagonal(series.cov, axis1=1, axis2=2)
    if np.any(d < 0):
        return None
    return np.sqrt(np.median(d, axis=0))


# --- writing (the round trip of every format) ---------------------------------------------------


def write_vehicle_bag(path: str | Path, *, wheel_topic: str = "/joint_states",
                      wheel_t_s: np.ndarray | None = None, wheel_speeds: np.ndarray | None = None,
                      joints: tuple[str, ...] = ("front_left_wheel_joint", "front_right_wheel_joint",
                                                 "rear_left_wheel_joint", "rear_right_wheel_joint"),
                      steering: np.ndarray | None = None, steering_joint: str = "steering_joint",
                      radar_topic: str = "/radar/ego_velocity", radar_t_s: np.ndarray | None = None,
                      radar_v: np.ndarray | None = None, radar_sigma: np.ndarray | None = None,
                      radar_frame: str = "radar", start_ns: int = 1_700_000_000 * 10**9) -> Path:
    """A bag of JointState wheel speeds (and steering position) and TwistWithCovarianceStamped
    ego-velocities, stamped ``start_ns`` + the given seconds: ROS 1 for ``.bag``, else a ROS 2
    folder with MCAP storage."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if path.exists():
        raise BagError(path, "exists already: the writer does not overwrite")
    ros1 = path.suffix.lower() == ".bag"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    M = ts.types
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr

    def header(t_ns: int, frame_id: str):
        stamp = M["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        return M["std_msgs/msg/Header"](**({"seq": 0} if ros1 else {}), stamp=stamp, frame_id=frame_id)

    def vec(v):
        return M["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    records = []
    if wheel_t_s is not None:
        names = list(joints) + ([steering_joint] if steering is not None else [])
        for k, t in enumerate(wheel_t_s):
            t_ns = start_ns + int(round(t * 1e9))
            pos = np.zeros(len(names))
            vel = np.zeros(len(names))
            vel[:4] = wheel_speeds[k]
            if steering is not None:
                pos[4] = steering[k]
            msg = M[JOINT_STATE_TYPE](header=header(t_ns, "base_link"), name=names, position=pos, velocity=vel,
                                      effort=np.zeros(0))
            records.append((t_ns, wheel_topic, serialize(msg, JOINT_STATE_TYPE)))
    if radar_t_s is not None:
        mt = EGO_VELOCITY_TYPES[0]
        for k, t in enumerate(radar_t_s):
            t_ns = start_ns + int(round(t * 1e9))
            cov = np.zeros((6, 6))
            if radar_sigma is not None:
                cov[:3, :3] = np.diag(np.asarray(radar_sigma, dtype=float) ** 2)
            v = np.zeros(3)
            v[:np.shape(radar_v)[1]] = radar_v[k]
            msg = M[mt](header=header(t_ns, radar_frame), twist=M["geometry_msgs/msg/TwistWithCovariance"](
                twist=M["geometry_msgs/msg/Twist"](linear=vec(v), angular=vec(np.zeros(3))), covariance=cov.ravel()))
            records.append((t_ns, radar_topic, serialize(msg, mt)))
    records.sort(key=lambda r: r[0])
    types = {wheel_topic: JOINT_STATE_TYPE, radar_topic: EGO_VELOCITY_TYPES[0]}
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer:
        conns = {name: writer.add_connection(name, types[name], typestore=ts) for name in {r[1] for r in records}}
        for t_ns, name, raw in records:
            writer.write(conns[name], t_ns, raw)
    return path

