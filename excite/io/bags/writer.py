"""Writing a drive as a bag (ROS 1 ``.bag`` or a ROS 2 folder with MCAP storage), so that every
format has a round trip, and cropping a bag to a window."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from ...errors import BagError
from ...motion.trajectory import Trajectory
from .decode import IMU_TYPE, POSE_TYPES, TF_STATIC_TOPIC, TF_TOPIC
from .gnss import NAVSAT_TYPE, STATUS_NO_FIX
from .reader import read_poses
from .stream import open_bag


def _typestore(ros1: bool):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in store.types:  # ROS 1's store lacks it
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                          "tf2_msgs/msg/TFMessage"))
    return store


def write_bag(traj: Trajectory, path: str | Path, *, topic: str = "/odom",
              msgtype: str = "nav_msgs/msg/Odometry", rate_hz: float = 50.0,
              frame: str = "odom", child: str = "base_link", imu_topic: str | None = None,
              imu_frame: str = "imu_link", T_V_B: tuple[np.ndarray, np.ndarray] | None = None,
              imu_rate_hz: float = 200.0, tf: bool = False, start_ns: int = 1_700_000_000 * 10**9,
              fix_topic: str | None = None, fix_rate_hz: float = 10.0,
              fix_sigma_m: tuple[float, float] = (0.02, 0.04), fix_origin: tuple[float, float, float] = (48.0, 11.0, 500.0),
              fix_outages: tuple[tuple[float, float], ...] = (),
              pose_covariance: Callable[[np.ndarray], np.ndarray] | None = None) -> Path:
    """Write V's poses sampled at ``rate_hz`` as ``msgtype`` messages on ``topic`` (and, with
    ``tf``, as ``/tf`` ``frame → child`` plus a ``/tf_static`` ``child → imu_frame``), and with
    ``imu_topic`` a perfect IMU mounted at ``T_V_B`` (R, p) at ``imu_rate_hz``; with
    ``fix_topic``, ``sensor_msgs/NavSatFix`` fixes of V's origin at ``fix_rate_hz`` (the drive's
    x, y, z taken as east, north, up about the geodetic ``fix_origin``), their diagonal covariance
    from ``fix_sigma_m`` (horizontal, vertical; DIAGONAL_KNOWN), and messages without a fix
    (``STATUS_NO_FIX``) within the ``fix_outages`` (seconds from the drive's start). With
    ``pose_covariance`` (seconds from the drive's start → n × 6 × 6, ROS order x, y, z, rx, ry,
    rz), the pose covariance of ``Odometry`` and ``PoseWithCovarianceStamped`` messages (zeros
    otherwise).

    ``path`` ending in ``.bag`` is a ROS 1 bag; anything else a ROS 2 bag folder with MCAP
    storage (its ``.mcap`` file also reads on its own). Quaternions are written with w ≥ 0.
    """
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin, Writer as Writer2

    path = Path(path)
    ros1 = path.suffix.lower() == ".bag"
    if msgtype not in POSE_TYPES:
        raise BagError(path, f"cannot write {msgtype}: one of {', '.join(POSE_TYPES)}")
    ts = _typestore(ros1)
    M = ts.types
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    R_V_B, p_V_B = (np.eye(3), np.zeros(3)) if T_V_B is None else T_V_B

    def header(t_ns: int, frame_id: str):
        stamp = M["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        if ros1:
            return M["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame_id)
        return M["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def pose(p, q):
        return M["geometry_msgs/msg/Pose"](
            position=M["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
            orientation=M["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))

    def vec(v):
        return M["geometry_msgs/msg/Vector3"](x=v[0], y=v[1], z=v[2])

    def transform(t_ns, p, q, parent, ch):
        return M["geometry_msgs/msg/TransformStamped"](
            header=header(t_ns, parent), child_frame_id=ch,
            transform=M["geometry_msgs/msg/Transform"](
                translation=vec(p), rotation=M["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])))

    def message(t_ns, p, q, v_body, w_body, cov):
        h = header(t_ns, frame)
        if msgtype.endswith("/PoseStamped"):
            return M[msgtype](header=h, pose=pose(p, q))
        if msgtype.endswith("/PoseWithCovarianceStamped"):
            return M[msgtype](header=h, pose=M["geometry_msgs/msg/PoseWithCovariance"](
                pose=pose(p, q), covariance=cov))
        if msgtype.endswith("/TransformStamped"):
            return transform(t_ns, p, q, frame, child)
        return M[msgtype](header=h, child_frame_id=child,
                          pose=M["geometry_msgs/msg/PoseWithCovariance"](pose=pose(p, q), covariance=cov),
                          twist=M["geometry_msgs/msg/TwistWithCovariance"](
                              twist=M["geometry_msgs/msg/Twist"](linear=vec(v_body), angular=vec(w_body)),
                              covariance=np.zeros(36)))

    s = traj.sample(traj.times(rate_hz))
    q = Rotation.from_matrix(s.R_W_V).as_quat()
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)
    v_body = np.einsum("nji,nj->ni", s.R_W_V, s.v_W)
    stamps = start_ns + np.round((s.t - s.t[0]) * 1e9).astype(np.int64)
    covs = (np.zeros((s.t.size, 36)) if pose_covariance is None else
            np.asarray(pose_covariance(s.t - s.t[0]), dtype=float).reshape(s.t.size, 36))
    records: list[tuple[int, str, bytes]] = []
    tf_type = "tf2_msgs/msg/TFMessage"
    for k in range(s.t.size):
        t_ns = int(stamps[k])
        records.append((t_ns, topic, serialize(message(t_ns, s.p_W_V[k], q[k], v_body[k], s.omega_V[k], covs[k]), msgtype)))
        if tf:
            records.append((t_ns, TF_TOPIC, serialize(M[tf_type](transforms=[
                transform(t_ns, s.p_W_V[k], q[k], frame, child)]), tf_type)))
    if imu_topic is not None:
        t_imu = traj.times(imu_rate_hz)
        _, w, f = traj.imu(t_imu, R_V_B, p_V_B)
        Imu = M[IMU_TYPE]
        for k in range(t_imu.size):
            t_ns = start_ns + int(round((t_imu[k] - t_imu[0]) * 1e9))
            msg = Imu(header=header(t_ns, imu_frame),
                      orientation=M["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                      orientation_covariance=np.zeros(9), angular_velocity=vec(w[k]),
                      angular_velocity_covariance=np.zeros(9), linear_acceleration=vec(f[k]),
                      linear_acceleration_covariance=np.zeros(9))
            records.append((t_ns, imu_topic, serialize(msg, IMU_TYPE)))
    if fix_topic is not None:
        records += _fixes(traj, M, serialize, header, fix_topic, fix_rate_hz, fix_sigma_m, fix_origin, fix_outages,
                          start_ns)
    records.sort(key=lambda r: r[0])
    static = None
    if tf:
        qb = Rotation.from_matrix(R_V_B).as_quat()
        static = serialize(M[tf_type](transforms=[transform(start_ns, p_V_B, qb, child, imu_frame)]), tf_type)
    types = {topic: msgtype, TF_TOPIC: tf_type, TF_STATIC_TOPIC: tf_type}
    if imu_topic is not None:
        types[imu_topic] = IMU_TYPE
    if fix_topic is not None:
        types[fix_topic] = NAVSAT_TYPE
    if path.exists():
        raise BagError(path, "exists already: the writer does not overwrite")
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer:
        conns = {}
        for name in {r[1] for r in records} | ({TF_STATIC_TOPIC} if static else set()):
            conns[name] = writer.add_connection(name, types[name], typestore=ts)
        if static is not None:
            writer.write(conns[TF_STATIC_TOPIC], start_ns, static)
        for t_ns, name, raw in records:
            writer.write(conns[name], t_ns, raw)
    return path


def _fixes(traj, M, serialize, header, topic, rate_hz, sigma, origin, outages, start_ns) -> list:
    """NavSatFix records of V's origin (see :func:`write_bag`)."""
    from pyproj import Transformer

    t = traj.times(rate_hz)
    enu = traj.sample(t).p_W_V
    la, lo = np.radians(origin[0]), np.radians(origin[1])
    R = np.array([[-np.sin(lo), np.cos(lo), 0.0],
                  [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
                  [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]])
    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x0 = np.array(to_ecef.transform(origin[1], origin[0], origin[2]))
    ecef = x0 + enu @ R
    lon, lat, alt = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(
        ecef[:, 0], ecef[:, 1], ecef[:, 2])
    cov = np.diag([sigma[0] ** 2, sigma[0] ** 2, sigma[1] ** 2]).ravel()
    out = []
    for k in range(t.size):
        t_ns = start_ns + int(round((t[k] - t[0]) * 1e9))
        off = any(a <= t[k] - t[0] <= b for a, b in outages)
        msg = M[NAVSAT_TYPE](header=header(t_ns, "gnss"),
                             status=M["sensor_msgs/msg/NavSatStatus"](status=STATUS_NO_FIX if off else 0, service=1),
                             latitude=float(lat[k]), longitude=float(lon[k]), altitude=float(alt[k]),
                             position_covariance=cov, position_covariance_type=2)
        out.append((t_ns, topic, serialize(msg, NAVSAT_TYPE)))
    return out


def crop_bag(path: str | Path, out: str | Path, start_s: float, end_s: float, topic: str) -> Path:
    """Every message of the bag at ``path`` whose time lies in ``[start_s, end_s]``, counted like
    the trajectory of ``topic`` (seconds from its first message's stamp), copied unchanged to
    ``out`` in the same format (a ROS 1 ``.bag``, else a ROS 2 bag folder with MCAP storage), and
    every ``/tf_static`` message whenever it was sent (a crop needs the static frames)."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin, Writer as Writer2

    path, out = Path(path), Path(out)
    if out.exists():
        raise BagError(out, "exists already: the writer does not overwrite")
    t0_ns = int(read_poses(path, topic).t_ns[0])
    start_ns, stop_ns = t0_ns + int(round(start_s * 1e9)), t0_ns + int(round(end_s * 1e9))
    with open_bag(path) as reader:
        ros1 = all(c.ext.__class__.__name__ == "ConnectionExtRosbag1" for c in reader.connections)
        if ros1 and out.suffix.lower() != ".bag":
            out = out.with_suffix(".bag")
        writer = Writer1(out) if ros1 else Writer2(out, version=9, storage_plugin=StoragePlugin.MCAP)
        with writer:
            conns = {}
            for c in reader.connections:
                if ros1:
                    conns[c.id] = writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest,
                                                        callerid=c.ext.callerid, latching=c.ext.latching)
                else:
                    conns[c.id] = writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, rihs01=c.digest,
                                                        serialization_format=c.ext.serialization_format,
                                                        offered_qos_profiles=c.ext.offered_qos_profiles)
            static = [c for c in reader.connections if c.topic == TF_STATIC_TOPIC]
            for c, t_ns, raw in (reader.messages(connections=static) if static else ()):
                writer.write(conns[c.id], max(start_ns, min(t_ns, stop_ns)), raw)
            moving = [c for c in reader.connections if c.topic != TF_STATIC_TOPIC]
            for c, t_ns, raw in reader.messages(connections=moving, start=start_ns, stop=stop_ns + 1):
                writer.write(conns[c.id], t_ns, raw)
    return out
