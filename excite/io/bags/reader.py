"""The entry points: what is in a bag, its poses (a topic or a TF chain), its IMU, its static
transforms, and a bag's drive as a trajectory."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from ...core import bounds
from ...errors import BagError, RouteError
from ...motion.trajectory import Trajectory
from ..poses import DEFAULT_CUTOFF_HZ, MIN_POSES, R_CAM_VEH, trajectory_from_poses
from .decode import (AXES, DECODERS, IMU_TYPE, POSE_TYPES, TF_STATIC_TOPIC, TF_TYPES, PoseSeries, Series,
                     decode_message, imu_fields)
from .covariance import odometry_log, read_pose_covariances
from .gnss import NAVSAT_TYPE, fix_log, read_fixes
from .imu import ImuSeries, ImuTrajectory, imu_series
from .mcap import mcap_files, mcap_read, verify_chunks
from .stream import (budget, count_bound, has_topic, is_ros2, open_bag, reader_errors, stream_messages, time_window,
                     topic_connections, topic_list)
from ...rig import importers
from ...rig.frames import static_transform
from .tf import static_edges, tf_chain
from .vehicle import VEHICLE_USES


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag: its type, message count, span and rate, and how excite can use it.

    ``use``: ``"pose"`` (a trajectory source), ``"tf"`` (TF chains: ``sources`` lists them as
    ``/tf:parent.child``), ``"imu"`` (angular rate and specific force), ``"gnss"`` (NavSatFix
    fixes), ``"wheels"`` (JointState: wheel speeds, a steering angle), ``"ego_velocity"`` (a radar's
    twist) or ``""``.
    """

    topic: str
    msgtype: str
    count: int
    duration_s: float
    rate_hz: float | None
    use: str
    sources: tuple[str, ...] = ()


def bag_info(path: str | Path) -> list[TopicInfo]:
    """Every topic of the bag with its type, count, span (bag receive times), rate and use.

    Streams the whole bag once; only ``/tf`` messages are decoded (for their frame pairs).
    """
    path = Path(path)
    out = []
    with open_bag(path) as reader:
        for topic in sorted({c.topic for c in reader.connections}):
            cons = [c for c in reader.connections if c.topic == topic]
            msgtype = cons[0].msgtype
            ros2 = is_ros2(cons[0])
            first = last = None
            n = 0
            pairs: dict[tuple[str, str], None] = {}
            dyn = msgtype in TF_TYPES and topic != TF_STATIC_TOPIC
            for t_ns, raw in stream_messages(path, reader, cons, topic):
                first = t_ns if first is None else first
                last = t_ns
                if dyn:
                    for _, parent, child, _ in decode_message(path, topic, n, DECODERS[msgtype], raw, ros2):
                        pairs[(parent, child)] = None
                n += 1
            span = 0.0 if n == 0 else (last - first) * 1e-9
            rate = (n - 1) / span if n > 1 and span > 0 else None
            use, sources = "", ()
            if msgtype in POSE_TYPES:
                use = "pose"
            elif msgtype == IMU_TYPE:
                use = "imu"
            elif msgtype == NAVSAT_TYPE:
                use = "gnss"
            elif msgtype in VEHICLE_USES:
                use = VEHICLE_USES[msgtype]
            elif dyn and pairs:
                use = "tf"
                sources = tuple(f"{topic}:{parent}.{child}" for parent, child in pairs)
            out.append(TopicInfo(topic, msgtype, n, span, rate, use, sources))
    return out


def _count_bound(path: Path, topic: str, cons: list, imu: bool) -> None:
    """Refuse a topic with more messages than a route may have samples (IMU: IMU samples),
    from the bag's own index, before anything is read."""
    limit, what = (bounds.MAX_IMU_SAMPLES, "IMU samples") if imu else (bounds.MAX_SAMPLES, "poses")
    count_bound(path, topic, cons, limit, what)


def read_series(path: Path, reader, wanted: dict[str, Callable], window) -> dict[str, Series]:
    """One pass over the bag for every topic in ``wanted`` (topic → decoder): MCAP files through
    :func:`~.mcap.mcap_read` when their chunks are in time order, everything else through
    rosbags (MCAP chunks verified under the bounds first). Topics with more messages than the
    work bounds allow are refused first."""
    cons = {topic: topic_connections(path, reader, topic) for topic in wanted}
    for topic, fn in wanted.items():
        _count_bound(path, topic, cons[topic], imu=fn is imu_fields)

    def fresh() -> dict[str, Series]:
        return {t: Series(path, t, fn, is_ros2(cons[t][0])) for t, fn in wanted.items()}

    files = mcap_files(path)
    if files is not None:
        out = fresh()
        try:
            if mcap_read(files, out, window, budget(reader)):
                return out
            verify_chunks(files, budget(reader))
        except (struct.error, ValueError, KeyError, IndexError, OSError, EOFError) as exc:
            raise BagError(path, f"the bag is truncated or corrupt while reading ({exc})",
                           ", ".join(wanted)) from None
    out = fresh()
    by_id = {c.id: out[t] for t, tc in cons.items() for c in tc}
    errors = reader_errors()
    try:
        for c, _, raw in reader.messages(connections=[c for tc in cons.values() for c in tc],
                                         start=window[0], stop=window[1]):
            by_id[c.id].add(raw)
    except errors as exc:
        raise BagError(path, f"the bag is truncated or corrupt while reading ({exc})",
                       ", ".join(wanted)) from None
    except (ValueError, OSError, MemoryError) as exc:  # a chunk past the decompression bounds
        raise BagError(path, f"cannot be read: {exc}", ", ".join(wanted)) from None
    return out


def _parse_source(topic: str) -> tuple[str, str, str] | None:
    """``/tf:parent.child`` → (``/tf``, parent, child); None for a plain topic."""
    if ":" not in topic:
        return None
    tf_topic, chain = topic.split(":", 1)
    if "." not in chain:
        return None
    parent, child = chain.split(".", 1)
    return tf_topic, parent, child


def read_poses(path: str | Path, topic: str, *, start_s: float | None = None,
               end_s: float | None = None, child_frame: str | None = None) -> PoseSeries:
    """The timed poses a topic (or a TF chain ``/tf:parent.child``) carries, cropped to
    ``[start_s, end_s]`` seconds from the start of the bag.

    Rejects an unknown topic (listing the bag's topics), a type without a pose, an empty topic or
    window, a chain that does not connect (naming the missing link), unit-norm violations and
    stamps that go backwards. Exact repeats (same stamp, same pose) are dropped.
    """
    return _read_drive(Path(path), topic, None, start_s, end_s, child_frame)[0]


def _read_drive(path: Path, topic: str, imu_topic: str | None, start_s: float | None,
                end_s: float | None, child_frame: str | None = None) -> tuple[PoseSeries, "ImuSeries | None"]:
    """The poses of ``topic`` and the IMU of ``imu_topic``: one pass over the bag for a pose
    topic and its IMU, a second one for a TF chain's IMU."""
    chain = _parse_source(topic)
    with open_bag(path) as reader:
        window = time_window(reader, start_s, end_s)
        wanted = {}
        if chain is None:
            wanted[topic] = DECODERS[_pose_type(path, reader, topic)]
        if imu_topic is not None:
            cons = topic_connections(path, reader, imu_topic)
            if cons[0].msgtype != IMU_TYPE:
                raise BagError(path, f"type {cons[0].msgtype} is not sensor_msgs/Imu", imu_topic)
            wanted[imu_topic] = imu_fields
        series = read_series(path, reader, wanted, window) if wanted else {}
        if chain is not None:
            poses = tf_chain(path, reader, topic, *chain, window)
        else:
            t, d, frame, child = series[topic].result()
            if not t.size:
                raise BagError(path, "no messages" + (" in the window" if window != (None, None) else ""),
                               topic)
            poses = PoseSeries(t, d[:, :3], d[:, 3:], frame or "",
                               child or child_frame or topic.strip("/") or "body")
    imu = None if imu_topic is None else imu_series(path, imu_topic, *series[imu_topic].result()[:3])
    return _checked(path, topic, poses), imu


def _pose_type(path: Path, reader, topic: str) -> str:
    msgtype = topic_connections(path, reader, topic)[0].msgtype
    if msgtype in TF_TYPES:
        raise BagError(path, f"{msgtype} carries many transforms: name the chain as "
                             f"{topic}:PARENT.CHILD (see `excite route info`)", topic)
    if msgtype not in POSE_TYPES:
        raise BagError(path, f"type {msgtype} carries no pose (scoreable types: "
                             f"{', '.join(t.split('/')[-1] for t in POSE_TYPES)}, or a TF chain "
                             "/tf:PARENT.CHILD)", topic)
    return msgtype


def _checked(path: Path, topic: str, s: PoseSeries) -> PoseSeries:
    bad = ~np.all(np.isfinite(s.p), axis=1) | ~np.all(np.isfinite(s.q), axis=1)
    if bad.any():
        raise BagError(path, f"message {int(np.argmax(bad))} has a NaN or infinite pose", topic)
    norm = np.linalg.norm(s.q, axis=1)
    bad = np.abs(norm - 1.0) > 1e-3
    if bad.any():
        k = int(np.argmax(bad))
        raise BagError(path, f"message {k}: quaternion norm {norm[k]:.6g}, not 1", topic)
    dt = np.diff(s.t_ns)
    same = np.concatenate([[False], (dt == 0) & np.all(s.p[1:] == s.p[:-1], axis=1)
                           & np.all(s.q[1:] == s.q[:-1], axis=1)])
    if same.any():
        keep = ~same
        s = PoseSeries(s.t_ns[keep], s.p[keep], s.q[keep], s.frame, s.child)
        dt = np.diff(s.t_ns)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0)) + 1
        what = "repeats" if dt[k - 1] == 0 else "goes backwards"
        raise BagError(path, f"stamps are not monotonic: message {k}'s stamp {what} "
                             f"({s.t_ns[k] * 1e-9:.9f} s after {s.t_ns[k - 1] * 1e-9:.9f} s)", topic)
    if s.t_ns.size < MIN_POSES:
        raise BagError(path, f"too few poses: {s.t_ns.size}, need at least {MIN_POSES}", topic)
    # the drive they imply, before any spline or grid is built from them
    span = float(s.t_ns[-1] - s.t_ns[0]) * 1e-9
    too_much = bounds.work_problem(span, 1e9 / float(np.median(dt)), bounds.MAX_SAMPLES, "samples")
    if too_much:
        raise BagError(path, too_much, topic)
    return PoseSeries(s.t_ns, s.p, s.q / np.linalg.norm(s.q, axis=1)[:, None], s.frame, s.child)


def read_static_tf(path: str | Path) -> dict[str, tuple[str, np.ndarray, np.ndarray]]:
    """``child → (parent, translation (3,), quaternion x-y-z-w (4,))`` from ``/tf_static``."""
    path = Path(path)
    with open_bag(path) as reader:
        if not has_topic(reader, TF_STATIC_TOPIC):
            raise BagError(path, f"the bag has no {TF_STATIC_TOPIC} (topics: {topic_list(reader)})",
                           TF_STATIC_TOPIC)
        edges = static_edges(path, reader)
    return {c: (e.parent, np.asarray(e.p[0], float), np.asarray(e.q[0], float)) for c, e in edges.items()}


def read_imu(path: str | Path, topic: str, *, start_s: float | None = None,
             end_s: float | None = None) -> ImuSeries:
    """The ``sensor_msgs/Imu`` samples of ``topic`` within ``[start_s, end_s]`` (bag seconds)."""
    path = Path(path)
    with open_bag(path) as reader:
        cons = topic_connections(path, reader, topic)
        if cons[0].msgtype != IMU_TYPE:
            raise BagError(path, f"type {cons[0].msgtype} is not sensor_msgs/Imu", topic)
        series = read_series(path, reader, {topic: imu_fields}, time_window(reader, start_s, end_s))
    return imu_series(path, topic, *series[topic].result()[:3])


@dataclass(frozen=True)
class BagSource:
    """What to read from a bag: the trajectory ``topic`` (or ``/tf:parent.child``), an optional
    ``imu_topic``, a window ``[start_s, end_s]`` in seconds from the start of the bag, the frame
    to take as V (``vehicle_frame``, via ``/tf_static``), the pose axes (``vehicle`` or
    ``optical``), an optional ``sensor_msgs/NavSatFix`` topic ``gnss_topic`` whose fixes
    (times, outages, covariance) the drive carries as the log of the rig's sensor ``gnss_sensor``,
    and an optional ``nav_msgs/Odometry`` or ``PoseWithCovarianceStamped`` topic
    ``odometry_topic`` whose pose covariances it carries as the log of the rig's lidar or camera
    ``odometry_sensor`` (:mod:`.covariance`)."""

    topic: str | None = None
    imu_topic: str | None = None
    start_s: float | None = None
    end_s: float | None = None
    vehicle_frame: str | None = None
    axes: str = "vehicle"
    gnss_topic: str | None = None
    gnss_sensor: str = "gnss"
    odometry_topic: str | None = None
    odometry_sensor: str = "lidar"

    @staticmethod
    def required(bag: "BagSource | None", path: Path) -> "BagSource":
        """``bag`` when it names a topic; otherwise an error listing what the bag can score."""
        if bag is not None and bag.topic:
            return bag
        found = [s for ti in bag_info(path) for s in ((ti.topic,) if ti.use == "pose" else ti.sources)]
        raise BagError(path, "a bag needs a trajectory source: pass --topic (scoreable here: "
                             f"{', '.join(found) if found else 'nothing'})")

    def options(self) -> dict:
        out = {"topic": self.topic, "imu_topic": self.imu_topic, "start_s": self.start_s,
               "end_s": self.end_s, "vehicle_frame": self.vehicle_frame, "axes": self.axes}
        if self.gnss_topic is not None:
            out.update(gnss_topic=self.gnss_topic, gnss_sensor=self.gnss_sensor)
        if self.odometry_topic is not None:
            out.update(odometry_topic=self.odometry_topic, odometry_sensor=self.odometry_sensor)
        return out


def read_bag_route(path: str | Path, topic: str, *, imu_topic: str | None = None,
                   start_s: float | None = None, end_s: float | None = None,
                   vehicle_frame: str | None = None, axes: str = "vehicle",
                   cutoff_hz: float = DEFAULT_CUTOFF_HZ, rate_hz: float | None = None,
                   gnss_topic: str | None = None, gnss_sensor: str = "gnss",
                   odometry_topic: str | None = None, odometry_sensor: str = "lidar") -> Trajectory:
    """A bag's trajectory source (and optional measured IMU) as a trajectory of V (see the
    module notes); with ``gnss_topic``, carrying that NavSatFix topic's fixes as the log of the
    rig's sensor ``gnss_sensor`` (:func:`excite.io.bags.gnss.fix_log`); with ``odometry_topic``,
    that topic's pose covariances as the log of the rig's lidar or camera ``odometry_sensor``
    (:func:`excite.io.bags.covariance.odometry_log`)."""
    path = Path(path)
    traj, t0_ns = _bag_route(path, topic, imu_topic, start_s, end_s, vehicle_frame, axes, cutoff_hz, rate_hz)
    logs = {}
    if gnss_topic is not None:
        log = fix_log(read_fixes(path, gnss_topic, start_s=start_s, end_s=end_s), t0_ns)
        inside = (log.t >= traj.t_start) & (log.t <= traj.t_end)
        if not inside.any():
            raise BagError(path, f"no fix within the {traj.duration:.1f} s of poses on {topic}: not the same "
                                 "drive?", gnss_topic)
        logs[gnss_sensor] = log
    if odometry_topic is not None:
        log = odometry_log(read_pose_covariances(path, odometry_topic, start_s=start_s, end_s=end_s), t0_ns,
                           path, odometry_topic)
        if not np.any((log.t >= traj.t_start) & (log.t <= traj.t_end)):
            raise BagError(path, f"no message within the {traj.duration:.1f} s of poses on {topic}: not the "
                                 "same drive?", odometry_topic)
        logs[odometry_sensor] = log
    return traj.with_logs(logs) if logs else traj


def _bag_route(path: Path, topic: str, imu_topic: str | None, start_s: float | None, end_s: float | None,
               vehicle_frame: str | None, axes: str, cutoff_hz: float,
               rate_hz: float | None) -> tuple[Trajectory, int]:
    """The trajectory of :func:`read_bag_route` and the stamp [ns] its clock starts at."""
    if axes not in AXES:
        raise BagError(path, f"axes must be one of {', '.join(AXES)}, got {axes!r}")
    if start_s is not None and end_s is not None and end_s <= start_s:
        raise BagError(path, f"the window is empty: --end {end_s:g} s is not after --start {start_s:g} s")
    s, imu = _read_drive(path, topic, imu_topic, start_s, end_s)
    R, p = s.R, s.p
    if axes == "optical":
        R = R_CAM_VEH.T @ R @ R_CAM_VEH
        p = p @ R_CAM_VEH
    if vehicle_frame is not None and vehicle_frame != s.child:
        with open_bag(path) as reader:
            if not has_topic(reader, TF_STATIC_TOPIC):
                raise BagError(path, f"cannot move the poses of {s.child!r} to {vehicle_frame!r}: "
                                     f"the bag has no {TF_STATIC_TOPIC}", topic)
            edges = static_edges(path, reader)
        R_C_V, p_C_V = static_transform(path, edges, s.child, vehicle_frame, topic)
        p = p + np.einsum("nij,j->ni", R, p_C_V)
        R = R @ R_C_V
    name = f"{path.stem if path.is_file() else path.name}:{topic}"
    try:
        traj = trajectory_from_poses(s.t_s, p, R, cutoff_hz=cutoff_hz, rate_hz=rate_hz, name=name)
    except BagError:
        raise
    except RouteError as exc:
        raise BagError(path, exc.problem, topic) from None
    if imu is None:
        return traj, int(s.t_ns[0])
    t_imu = (imu.t_ns - s.t_ns[0]).astype(float) * 1e-9
    lo, hi = max(t_imu[0], traj.t_start), min(t_imu[-1], traj.t_end)
    if hi - lo < 0.5 * traj.duration:
        raise BagError(path, f"the IMU covers {max(hi - lo, 0):.1f} s of the {traj.duration:.1f} s "
                             f"of poses on {topic}: not the same drive?", imu_topic)
    return ImuTrajectory.of(traj, t_imu, imu.omega, imu.accel, imu.frame), int(s.t_ns[0])


def rig_from_tf(path: str | Path, *, imu: str, base: str, lidar: list[str] = (), camera: list[str] = (),
                gnss: list[str] | None = None, name: str | None = None) -> importers.ImportedRig:
    """A rig from a bag's ``/tf_static`` (composed by :func:`excite.rig.importers.rig_from_tree`):
    B is the ``imu`` frame, V the ``base`` frame; sensors at the ``lidar`` and ``camera`` frames,
    named after them; GNSS antennas at the ``gnss`` frames (default: every frame named like one,
    ``gnss``, ``gps_link``, …)."""
    path = Path(path)
    static = read_static_tf(path)
    hops = [importers.Hop(parent, child, Rotation.from_quat(q).as_matrix(), np.asarray(p, float))
            for child, (parent, p, q) in static.items()]
    return importers.rig_from_tree(importers.Tree(hops, f"{path} {TF_STATIC_TOPIC}"), imu=imu, base=base,
                                   lidar=list(lidar), camera=list(camera), gnss=None if gnss is None else list(gnss),
                                   name=name or importers.common.rig_name(path),
                                   notes=[f"from the {TF_STATIC_TOPIC} tree of {path.name}"])
