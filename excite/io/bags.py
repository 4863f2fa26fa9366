"""Drives logged in ROS bags: ROS 1 ``.bag``, ROS 2 bag folders (sqlite3 or MCAP storage) and
bare ``.mcap`` files, read with ``rosbags`` (pure Python, no ROS installation).

Trajectory sources (``topic``):

- a topic of ``geometry_msgs/PoseStamped``, ``PoseWithCovarianceStamped``, ``TransformStamped``
  or ``nav_msgs/Odometry``: the pose of the message's child frame (``child_frame_id``, else the
  frame the user names) in ``header.frame_id``, at ``header.stamp``;
- a TF chain ``/tf:PARENT.CHILD`` (evo's convention): the pose of ``CHILD`` in ``PARENT``,
  composed over every hop between them; dynamic hops come from ``/tf`` (the first dynamic hop's
  stamps are the samples, further dynamic hops are interpolated at them) and static hops from
  ``/tf_static``.

The poses go through the same smoothing fit as a TUM file
(:func:`excite.io.routes.trajectory_from_poses`): a bag and a TUM export of it score alike.

**Body frame.** The poses describe one frame of the robot (``base_link``, a camera, ...); excite
takes that frame as the vehicle frame V (rear-axle centre, x forward, y left, z up). With
``vehicle_frame`` the poses are moved to another frame of the robot through ``/tf_static``
(``T_W_V = T_W_C · T_C_V``). Poses logged in camera-optical axes (x right, y down, z forward, as
visual SLAM writes them) are mapped to vehicle axes with ``axes="optical"``.

**Measured IMU.** With ``imu_topic`` (``sensor_msgs/Imu``), the drive's angular rate and specific
force at the IMU samples of the evaluator are the *measured* ones (linearly interpolated to the
rig's IMU rate), not the derivatives of the smoothed poses: real excitation and real vibration
enter the information model. The IMU message frame is taken as the rig's body frame B. The
orientation, position and velocity keep coming from the poses. How well the two agree is
measured by :func:`imu_agreement` (1-s means of measured against pose-derived rate and specific
force, the constant offset between them and the rotation that best aligns them) and printed
by ``excite score``; a large mounting mismatch means the rig's ``T_V_B`` is not the IMU's.

Decoding is streamed (one message at a time) and the fields excite needs are read straight from
the serialized bytes (CDR for ROS 2, the ROS 1 wire format): a fraction of the cost of building
full message objects. :func:`write_bag` writes a drive as a bag (ROS 1 ``.bag`` or a ROS 2
folder with MCAP storage), so every format has a round trip.

Every problem is a :class:`BagError` naming the file, the topic and what is wrong.
"""

from __future__ import annotations

import struct
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from ..core import bounds
from ..errors import BagError, RouteError
from .routes import DEFAULT_CUTOFF_HZ, MIN_POSES, R_CAM_VEH, is_bag, trajectory_from_poses
from ..motion.trajectory import Trajectory

__all__ = [
    "BagError", "BagSource", "TopicInfo", "PoseSeries", "ImuSeries", "ImuTrajectory", "ImuAgreement",
    "is_bag", "bag_info", "read_poses", "read_imu", "read_static_tf", "read_bag_route",
    "imu_agreement", "write_bag", "POSE_TYPES", "TF_TYPES", "IMU_TYPE",
]

POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped",
              "geometry_msgs/msg/TransformStamped", "nav_msgs/msg/Odometry")
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
IMU_TYPE = "sensor_msgs/msg/Imu"
TF_TOPIC, TF_STATIC_TOPIC = "/tf", "/tf_static"
AXES = ("vehicle", "optical")


# --------------------------------------------------------------------------------------------
# Opening and streaming


def _reader_errors() -> tuple[type[Exception], ...]:
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Ros1Error
    from rosbags.rosbag2 import ReaderError as Ros2Error

    return (AnyReaderError, Ros1Error, Ros2Error, struct.error, EOFError)


@contextmanager
def _open(path: Path):
    from rosbags.highlevel import AnyReader

    if not path.exists():
        raise FileNotFoundError(2, "No such file or directory", str(path))
    if not is_bag(path):
        raise BagError(path, "not a bag (expected a ROS 1 .bag, an .mcap file or a ROS 2 bag "
                             "folder with metadata.yaml)")
    errors = _reader_errors()
    try:
        reader = AnyReader([path])
        reader.open()
    except errors as exc:
        raise BagError(path, f"cannot read the bag, truncated or corrupt ({exc})") from None
    try:
        yield reader
    finally:
        reader.close()


def _stream(path: Path, reader, connections, topic: str, start_ns: int | None = None,
            stop_ns: int | None = None) -> Iterator[tuple[int, bytes]]:
    """(bag time, raw bytes) of the messages on ``connections``, one at a time; reader failures
    mid-file become a :class:`BagError`."""
    errors = _reader_errors()
    try:
        for _, t_ns, raw in reader.messages(connections=connections, start=start_ns, stop=stop_ns):
            yield t_ns, raw
    except errors as exc:
        raise BagError(path, f"the bag is truncated or corrupt while reading ({exc})", topic) from None


def _connections(path: Path, reader, topic: str) -> list:
    cons = [c for c in reader.connections if c.topic == topic]
    if not cons:
        raise BagError(path, f"no such topic in the bag (topics: {_topic_list(reader)})", topic)
    return cons


def _topic_list(reader) -> str:
    topics = sorted({c.topic for c in reader.connections})
    return ", ".join(topics) if topics else "none"


def _window(reader, start_s: float | None, end_s: float | None) -> tuple[int | None, int | None]:
    """Bag times (ns) of a window given in seconds from the start of the bag."""
    start = None if start_s is None else reader.start_time + int(round(start_s * 1e9))
    stop = None if end_s is None else reader.start_time + int(round(end_s * 1e9)) + 1
    return start, stop


# --------------------------------------------------------------------------------------------
# Decoding the fields excite needs straight from the serialized bytes


_U32 = {"<": struct.Struct("<I"), ">": struct.Struct(">I")}
_I32 = {"<": struct.Struct("<i"), ">": struct.Struct(">i")}
_F64 = {(e, n): struct.Struct(f"{e}{n}d") for e in "<>" for n in (3, 4, 7, 9, 36)}


class _Cursor:
    """Reads a ROS 1 message or a ROS 2 CDR message (alignment relative to the payload after the
    4-byte encapsulation header, endianness from it) field by field."""

    __slots__ = ("b", "o", "base", "e", "ros2", "stamp_at", "kept")

    def __init__(self, raw: bytes, ros2: bool):
        self.b, self.ros2 = raw, ros2
        self.stamp_at, self.kept = 0, []  # offsets of the stamp and of the kept doubles
        if ros2:
            if len(raw) < 4:
                raise struct.error("shorter than the CDR header")
            self.e = "<" if raw[1] & 1 else ">"
            self.o = self.base = 4
        else:
            self.e, self.o, self.base = "<", 0, 0

    def _align(self, n: int) -> None:
        if self.ros2:
            self.o += (-(self.o - self.base)) % n

    def u32(self) -> int:
        self._align(4)
        (v,) = _U32[self.e].unpack_from(self.b, self.o)
        self.o += 4
        return v

    def string(self) -> str:
        n = self.u32()
        if self.o + n > len(self.b):
            raise struct.error("string runs past the end of the message")
        s = bytes(self.b[self.o:self.o + n])
        self.o += n
        return (s[:-1] if self.ros2 and s.endswith(b"\0") else s).decode("utf-8", "replace")

    def doubles(self, n: int, keep: bool = False) -> tuple[float, ...]:
        """``n`` float64; ``keep`` marks the values a decoder returns (their offset is noted)."""
        self._align(8)
        if keep:
            self.kept.append((self.o, n))
        v = _F64[(self.e, n)].unpack_from(self.b, self.o)
        self.o += 8 * n
        return v

    def header(self) -> tuple[int, str]:
        """(stamp [ns], frame_id) of a std_msgs/Header."""
        if self.ros2:
            self._align(4)
            self.stamp_at = self.o
            (sec,) = _I32[self.e].unpack_from(self.b, self.o)
            self.o += 4
            nsec = self.u32()
        else:
            self.u32()  # seq
            self.stamp_at = self.o
            sec, nsec = self.u32(), self.u32()
        return sec * 1_000_000_000 + nsec, self.string()


# A decoded pose: (stamp ns, frame_id, child_frame_id or None, (px, py, pz, qx, qy, qz, qw)).
_Pose = tuple[int, str, "str | None", tuple[float, ...]]


def _pose_stamped(c: _Cursor) -> list[_Pose]:
    t, frame = c.header()
    return [(t, frame, None, c.doubles(7, keep=True))]


def _transform_stamped(c: _Cursor) -> list[_Pose]:
    t, frame = c.header()
    child = c.string()
    return [(t, frame, child, c.doubles(7, keep=True))]


def _tf_message(c: _Cursor) -> list[_Pose]:
    return [_transform_stamped(c)[0] for _ in range(c.u32())]


_DECODERS: dict[str, Callable[[_Cursor], list[_Pose]]] = {
    "geometry_msgs/msg/PoseStamped": _pose_stamped,
    "geometry_msgs/msg/PoseWithCovarianceStamped": _pose_stamped,  # pose first, covariance after
    "geometry_msgs/msg/TransformStamped": _transform_stamped,
    "nav_msgs/msg/Odometry": _transform_stamped,  # header, child_frame_id, pose first
    "tf2_msgs/msg/TFMessage": _tf_message,
    "tf/msg/tfMessage": _tf_message,
}


def _imu_fields(c: _Cursor) -> list[_Pose]:
    """(stamp, frame, None, angular rate + linear acceleration) of a sensor_msgs/Imu."""
    t, frame = c.header()
    c.doubles(4)  # orientation
    c.doubles(9)
    w = c.doubles(3, keep=True)
    c.doubles(9)
    return [(t, frame, None, w + c.doubles(3, keep=True))]


def _decode(path: Path, topic: str, index: int, fn: Callable, raw: bytes, ros2: bool):
    try:
        return fn(_Cursor(raw, ros2))
    except (struct.error, KeyError) as exc:
        raise BagError(path, f"message {index} is malformed ({exc})", topic) from None


_BATCH = 4096  # messages decoded at once (bounded memory)


@dataclass
class _Template:
    """The layout of a topic's first message: later messages of the same length whose bytes
    between the stamp and the first kept value are the same (same frame names) share it, and
    their stamps and values are read for a whole batch at once with numpy."""

    length: int
    key: bytes
    key_from: int
    stamp_at: int
    kept: list[tuple[int, int]]
    e: str
    ros2: bool
    head: bytes  # the CDR encapsulation header (ROS 2), which sets the byte order

    def matches(self, raw: bytes) -> bool:
        return len(raw) == self.length and raw[:len(self.head)] == self.head and \
            raw[self.key_from:self.key_from + len(self.key)] == self.key

    def columns(self, batch: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
        return self.columns_of(np.frombuffer(b"".join(batch), dtype=np.uint8).reshape(len(batch), self.length))

    def columns_of(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stamps [ns] and kept values of messages stacked as rows of bytes."""
        return self._parse(rows[:, self._cols()])

    def gather(self, buf: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stamps and kept values of the messages starting at ``starts`` in ``buf``, reading only
        those bytes."""
        return self._parse(buf[starts[:, None] + self._cols()[None, :]])

    def _cols(self) -> np.ndarray:
        parts = [np.arange(self.stamp_at, self.stamp_at + 8)]
        parts += [np.arange(o, o + 8 * n) for o, n in self.kept]
        return np.concatenate(parts)

    def _parse(self, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g = np.ascontiguousarray(g)
        sec = g[:, 0:4].copy().view(f"{self.e}{'i4' if self.ros2 else 'u4'}")[:, 0]
        nsec = g[:, 4:8].copy().view(f"{self.e}u4")[:, 0]
        vals = g[:, 8:].copy().view(f"{self.e}f8").astype(float)
        return sec.astype(np.int64) * 1_000_000_000 + nsec, vals


class _Series:
    """Collects (stamps ns, values (n, k), frame, child) of single-value messages of one topic,
    decoded in batches through a :class:`_Template` where the layout repeats and one by one
    where it does not."""

    def __init__(self, path: Path, topic: str, fn: Callable, ros2: bool):
        self.path, self.topic, self.fn, self.ros2 = path, topic, fn, ros2
        self.t_parts: list[np.ndarray] = []
        self.v_parts: list[np.ndarray] = []
        self.batch: list[bytes] = []
        self.tmpl: _Template | None = None
        self.frame, self.child = "", None
        self.n = 0

    def _flush(self) -> None:
        if self.batch:
            t, v = self.tmpl.columns(self.batch)
            self.t_parts.append(t)
            self.v_parts.append(v)
            self.batch.clear()

    def add(self, raw: bytes) -> None:
        i, self.n = self.n, self.n + 1
        if self.tmpl is not None and self.tmpl.matches(raw):
            self.batch.append(raw)
            if len(self.batch) >= _BATCH:
                self._flush()
            return
        self._flush()
        try:
            c = _Cursor(raw, self.ros2)
            ((stamp, self.frame, child, vals),) = self.fn(c)
        except (struct.error, KeyError, ValueError) as exc:
            raise BagError(self.path, f"message {i} is malformed ({exc})", self.topic) from None
        self.child = child or self.child
        self.t_parts.append(np.array([stamp], dtype=np.int64))
        self.v_parts.append(np.array([vals], dtype=float))
        if self.tmpl is None and c.kept:
            start = c.stamp_at + 8
            self.tmpl = _Template(len(raw), bytes(raw[start:c.kept[0][0]]), start, c.stamp_at,
                                  list(c.kept), c.e, self.ros2, bytes(raw[:4]) if self.ros2 else b"")

    def add_many(self, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> None:
        """The messages at ``buf[starts[i]:starts[i] + lengths[i]]``, in order: gathered with
        numpy when every one fits the template, one by one otherwise."""
        k = 0
        if self.tmpl is None and starts.size:
            self.add(bytes(buf[starts[0]:starts[0] + lengths[0]]))
            k = 1
        tmpl = self.tmpl
        if tmpl is not None and k < starts.size:
            st, ln = starts[k:], lengths[k:]
            fits = ln == tmpl.length
            if fits.all():
                key = np.frombuffer(tmpl.head + tmpl.key, dtype=np.uint8)
                cols = np.concatenate([np.arange(len(tmpl.head)),
                                       tmpl.key_from + np.arange(len(tmpl.key))])
                if np.array_equal(buf[st[:, None] + cols[None, :]], np.broadcast_to(key, (st.size, key.size))):
                    self._flush()
                    t, v = tmpl.gather(buf, st)
                    self.t_parts.append(t)
                    self.v_parts.append(v)
                    self.n += st.size
                    return
        for a, n in zip(starts[k:], lengths[k:]):
            self.add(bytes(buf[a:a + n]))

    def result(self) -> tuple[np.ndarray, np.ndarray, str, str | None]:
        self._flush()
        if not self.t_parts:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 7)), self.frame, self.child
        return np.concatenate(self.t_parts), np.vstack(self.v_parts), self.frame, self.child


def _count_bound(path: Path, topic: str, cons: list, imu: bool) -> None:
    """Refuse a topic with more messages than a route may have samples (IMU: IMU samples),
    from the bag's own index, before anything is read."""
    limit, what = (bounds.MAX_IMU_SAMPLES, "IMU samples") if imu else (bounds.MAX_SAMPLES, "poses")
    n = sum(int(getattr(c, "msgcount", 0) or 0) for c in cons)
    if n > limit:
        raise BagError(path, f"{n:,} messages, over the limit of {limit:,} {what} (crop the "
                             "drive with a window)", topic)


def _read_series(path: Path, reader, wanted: dict[str, Callable], window) -> dict[str, _Series]:
    """One pass over the bag for every topic in ``wanted`` (topic → decoder): MCAP files through
    :func:`_mcap_messages` when their chunks are in time order, everything else through
    rosbags. Topics with more messages than the work bounds allow are refused first."""
    cons = {topic: _connections(path, reader, topic) for topic in wanted}
    for topic, fn in wanted.items():
        _count_bound(path, topic, cons[topic], imu=fn is _imu_fields)

    def fresh() -> dict[str, _Series]:
        return {t: _Series(path, t, fn, _is_ros2(cons[t][0])) for t, fn in wanted.items()}

    files = _mcap_files(path)
    if files is not None:
        out = fresh()
        try:
            if _mcap_read(files, out, window):
                return out
        except (struct.error, ValueError, KeyError, OSError, EOFError) as exc:
            raise BagError(path, f"the bag is truncated or corrupt while reading ({exc})",
                           ", ".join(wanted)) from None
    out = fresh()
    by_id = {c.id: out[t] for t, tc in cons.items() for c in tc}
    errors = _reader_errors()
    try:
        for c, _, raw in reader.messages(connections=[c for tc in cons.values() for c in tc],
                                         start=window[0], stop=window[1]):
            by_id[c.id].add(raw)
    except errors as exc:
        raise BagError(path, f"the bag is truncated or corrupt while reading ({exc})",
                       ", ".join(wanted)) from None
    return out


# MCAP (https://mcap.dev/spec): records are opcode u8, length u64, content; messages sit in
# (compressed) chunks. Reading the chunks here, a record at a time, costs a fraction of a
# general reader's per-message work; the order rosbags would give (by log time) is kept as long
# as every chunk starts after the previous one ended, which a recorder writes.
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_DATA_END, _OP_FOOTER = 0x04, 0x05, 0x06, 0x0F, 0x02
_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")


def _mcap_files(path: Path) -> list[Path] | None:
    """The MCAP files of a bare ``.mcap`` or of a ROS 2 folder with MCAP storage, else None."""
    if path.is_file():
        return [path] if path.suffix.lower() == ".mcap" else None
    try:
        import yaml

        info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        if info.get("storage_identifier") != "mcap" or info.get("compression_format"):
            return None
        return [path / f for f in info["relative_file_paths"]]
    except (OSError, KeyError, TypeError, ValueError):
        return None


MAX_CHUNK_BYTES = 1 << 30  # one MCAP chunk, decompressed (recorders write a few MB)


def _decompress(kind: str, data: bytes, size: int) -> bytes:
    """A chunk's records: at most the ``size`` it declares, itself bounded, so that a small
    file cannot expand into all of memory."""
    if size > MAX_CHUNK_BYTES:
        raise ValueError(f"a chunk declares {size:,} bytes, over the limit of {MAX_CHUNK_BYTES:,}")
    if kind == "":
        out = data
    elif kind == "zstd":
        try:
            from compression import zstd
        except ImportError:
            from backports import zstd
        out = zstd.ZstdDecompressor().decompress(data, max_length=size + 1)
    elif kind == "lz4":
        from lz4.frame import LZ4FrameDecompressor

        out = LZ4FrameDecompressor().decompress(data, max_length=size + 1)
    else:
        raise ValueError(f"unknown chunk compression {kind!r}")
    if len(out) != size:
        raise ValueError(f"a chunk declares {size:,} bytes but holds {len(out):,} or more")
    return out


_OP_MESSAGE_INDEX = 0x07
_INDEX_ENTRY = np.dtype([("t", "<u8"), ("o", "<u8")])


def _message_indexes(fh) -> dict[int, np.ndarray] | None:
    """The MessageIndex records that follow a chunk (channel → (log time, offset) entries), or
    None when the writer left them out; the file is left at the next other record."""
    out: dict[int, np.ndarray] = {}
    while True:
        pos = fh.tell()
        head = fh.read(9)
        if len(head) < 9:
            fh.seek(pos)
            break
        op, n = _REC.unpack(head)
        if op != _OP_MESSAGE_INDEX:
            fh.seek(pos)
            break
        rec = fh.read(n)
        cid, nbytes = struct.unpack_from("<HI", rec, 0)
        out[cid] = np.frombuffer(rec, dtype=_INDEX_ENTRY, count=nbytes // 16, offset=6)
    return out or None


def _mcap_read(files: list[Path], out: dict[str, _Series], window) -> bool:
    """Feed the messages of ``out``'s topics within ``window`` (log time, ns) to their series;
    False (nothing to trust) when chunks or messages are out of time order."""
    start, stop = window
    channels: dict[int, _Series | None] = {}
    last = -1

    def records(buf: bytes | memoryview, o: int, end: int):
        while o + 9 <= end:
            op, n = _REC.unpack_from(buf, o)
            yield op, o + 9, o + 9 + n
            o += 9 + n

    def channel(buf, o: int) -> None:
        cid, _, n = struct.unpack_from("<HHI", buf, o)
        topic = bytes(buf[o + 8:o + 8 + n]).decode()
        channels[cid] = out.get(topic)

    for f in files:
        with f.open("rb") as fh:
            if fh.read(8) != _MCAP_MAGIC:
                raise ValueError("not an MCAP file")
            while True:
                head = fh.read(9)
                if len(head) < 9:
                    raise EOFError("the file ends inside the data section")
                op, n = _REC.unpack(head)
                if op in (_OP_DATA_END, _OP_FOOTER):
                    break
                if op == _OP_CHANNEL:
                    channel(fh.read(n), 0)
                    continue
                if op == _OP_MESSAGE:  # a message outside chunks: leave it to rosbags
                    return False
                if op != _OP_CHUNK:
                    fh.seek(n, 1)
                    continue
                body = fh.read(n)
                if len(body) < n:
                    raise EOFError("the file ends inside a chunk")
                t0, t1, size, _, clen = struct.unpack_from("<QQQII", body, 0)
                if t0 < last:
                    return False
                index = _message_indexes(fh)
                if stop is not None and t0 >= stop or start is not None and t1 < start:
                    last = max(last, t1)
                    continue
                kind = body[32:32 + clen].decode()
                (rlen,) = struct.unpack_from("<Q", body, 32 + clen)
                data = _decompress(kind, body[40 + clen:40 + clen + rlen], size)
                view = memoryview(data)
                if index is not None:
                    need = {cid for cid in index if cid not in channels}
                    for rop, a, _ in records(view, 0, len(data) if need else 0):
                        if rop == _OP_CHANNEL:
                            channel(view, a)
                            need.discard(struct.unpack_from("<H", view, a)[0])
                            if not need:
                                break
                    buf = np.frombuffer(data, dtype=np.uint8)
                    for cid, entries in index.items():
                        series = channels.get(cid)
                        if series is None or not entries.size:
                            continue
                        t_log, off = entries["t"].astype(np.int64), entries["o"].astype(np.int64)
                        if np.any(np.diff(t_log) < 0) or t_log[0] < last:
                            return False
                        keep = np.ones(t_log.size, dtype=bool)
                        if start is not None:
                            keep &= t_log >= start
                        if stop is not None:
                            keep &= t_log < stop
                        off = off[keep]
                        lens = buf[off[:, None] + np.arange(1, 9)[None, :]].copy().view("<u8")[:, 0].astype(np.int64)
                        series.add_many(buf, off + 9 + _MSG.size, lens - _MSG.size)
                    last = max(last, t1)
                    continue
                for rop, a, b in records(view, 0, len(data)):
                    if rop == _OP_CHANNEL:
                        channel(view, a)
                    elif rop == _OP_MESSAGE:
                        cid, _, t_log, _ = _MSG.unpack_from(view, a)
                        if t_log < last:
                            return False
                        last = t_log
                        series = channels.get(cid)
                        if series is not None and (start is None or t_log >= start) and \
                                (stop is None or t_log < stop):
                            series.add(bytes(view[a + 22:b]))
    return True


# --------------------------------------------------------------------------------------------
# What is in a bag


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag: its type, message count, span and rate, and how excite can use it.

    ``use``: ``"pose"`` (a trajectory source), ``"tf"`` (TF chains: ``sources`` lists them as
    ``/tf:parent.child``), ``"imu"`` (angular rate and specific force) or ``""``.
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
    with _open(path) as reader:
        for topic in sorted({c.topic for c in reader.connections}):
            cons = [c for c in reader.connections if c.topic == topic]
            msgtype = cons[0].msgtype
            ros2 = _is_ros2(cons[0])
            first = last = None
            n = 0
            pairs: dict[tuple[str, str], None] = {}
            dyn = msgtype in TF_TYPES and topic != TF_STATIC_TOPIC
            for t_ns, raw in _stream(path, reader, cons, topic):
                first = t_ns if first is None else first
                last = t_ns
                if dyn:
                    for _, parent, child, _ in _decode(path, topic, n, _DECODERS[msgtype], raw, ros2):
                        pairs[(parent, child)] = None
                n += 1
            span = 0.0 if n == 0 else (last - first) * 1e-9
            rate = (n - 1) / span if n > 1 and span > 0 else None
            use, sources = "", ()
            if msgtype in POSE_TYPES:
                use = "pose"
            elif msgtype == IMU_TYPE:
                use = "imu"
            elif dyn and pairs:
                use = "tf"
                sources = tuple(f"{topic}:{parent}.{child}" for parent, child in pairs)
            out.append(TopicInfo(topic, msgtype, n, span, rate, use, sources))
    return out


def _has_topic(reader, topic: str) -> bool:
    return any(c.topic == topic for c in reader.connections)


def _is_ros2(connection) -> bool:
    from rosbags.interfaces import ConnectionExtRosbag2

    return isinstance(connection.ext, ConnectionExtRosbag2)


# --------------------------------------------------------------------------------------------
# Pose series


@dataclass(frozen=True)
class PoseSeries:
    """Timed poses of ``child`` in ``frame``: ``t_ns`` (int64 stamps), positions ``p`` (n, 3) and
    unit quaternions ``q`` (n, 4, x-y-z-w)."""

    t_ns: np.ndarray
    p: np.ndarray
    q: np.ndarray
    frame: str
    child: str

    @property
    def t_s(self) -> np.ndarray:
        """Seconds from the first stamp (subtracted in integer nanoseconds: no precision lost)."""
        return (self.t_ns - self.t_ns[0]).astype(float) * 1e-9

    @property
    def R(self) -> np.ndarray:
        return Rotation.from_quat(self.q).as_matrix()


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
    with _open(path) as reader:
        window = _window(reader, start_s, end_s)
        wanted = {}
        if chain is None:
            wanted[topic] = _DECODERS[_pose_type(path, reader, topic)]
        if imu_topic is not None:
            cons = _connections(path, reader, imu_topic)
            if cons[0].msgtype != IMU_TYPE:
                raise BagError(path, f"type {cons[0].msgtype} is not sensor_msgs/Imu", imu_topic)
            wanted[imu_topic] = _imu_fields
        series = _read_series(path, reader, wanted, window) if wanted else {}
        if chain is not None:
            poses = _tf_chain(path, reader, topic, *chain, window)
        else:
            t, d, frame, child = series[topic].result()
            if not t.size:
                raise BagError(path, "no messages" + (" in the window" if window != (None, None) else ""),
                               topic)
            poses = PoseSeries(t, d[:, :3], d[:, 3:], frame or "",
                               child or child_frame or topic.strip("/") or "body")
    imu = None if imu_topic is None else _imu_series(path, imu_topic, *series[imu_topic].result()[:3])
    return _checked(path, topic, poses), imu


def _pose_type(path: Path, reader, topic: str) -> str:
    msgtype = _connections(path, reader, topic)[0].msgtype
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


# --------------------------------------------------------------------------------------------
# TF trees


@dataclass
class _Edge:
    """The transform of ``child`` in its parent: static (one pose) or dynamic (a series)."""

    parent: str
    child: str
    t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    p: list = field(default_factory=list)
    q: list = field(default_factory=list)

    @property
    def static(self) -> bool:
        return self.t_ns.size == 0


def _static_edges(path: Path, reader) -> dict[str, _Edge]:
    """child → edge of every transform on ``/tf_static`` (later messages override)."""
    edges: dict[str, _Edge] = {}
    cons = _connections(path, reader, TF_STATIC_TOPIC)
    ros2 = _is_ros2(cons[0])
    for i, (_, raw) in enumerate(_stream(path, reader, cons, TF_STATIC_TOPIC)):
        for _, parent, child, pose in _decode(path, TF_STATIC_TOPIC, i, _DECODERS[cons[0].msgtype],
                                              raw, ros2):
            edges[child] = _Edge(parent, child, p=[pose[:3]], q=[pose[3:]])
    return edges


def read_static_tf(path: str | Path) -> dict[str, tuple[str, np.ndarray, np.ndarray]]:
    """``child → (parent, translation (3,), quaternion x-y-z-w (4,))`` from ``/tf_static``."""
    path = Path(path)
    with _open(path) as reader:
        if not _has_topic(reader, TF_STATIC_TOPIC):
            raise BagError(path, f"the bag has no {TF_STATIC_TOPIC} (topics: {_topic_list(reader)})",
                           TF_STATIC_TOPIC)
        edges = _static_edges(path, reader)
    return {c: (e.parent, np.asarray(e.p[0], float), np.asarray(e.q[0], float)) for c, e in edges.items()}


def _ancestors(frame: str, edges: dict[str, _Edge]) -> list[_Edge]:
    """Edges from ``frame`` up to its root (child → parent order)."""
    out, seen = [], {frame}
    while frame in edges:
        e = edges[frame]
        out.append(e)
        frame = e.parent
        if frame in seen:
            break  # a loop in a malformed tree: stop at the repeat
        seen.add(frame)
    return out


def chain_edges(path: Path, topic: str, parent: str, child: str,
                edges: dict[str, _Edge]) -> list[tuple[_Edge, bool]]:
    """The hops from ``parent`` to ``child`` as (edge, forward): forward edges go down the tree
    (compose as is), backward ones up (compose inverted). Names the missing link otherwise."""
    frames = set(edges) | {e.parent for e in edges.values()}
    for f in (parent, child):
        if f not in frames:
            raise BagError(path, f"frame {f!r} appears in no transform on /tf or /tf_static "
                                 f"(frames: {', '.join(sorted(frames))})", topic)
    up_p, up_c = _ancestors(parent, edges), _ancestors(child, edges)
    roots_p = [parent] + [e.parent for e in up_p]
    roots_c = [child] + [e.parent for e in up_c]
    common = next((f for f in roots_c if f in roots_p), None)
    if common is None:
        raise BagError(path, f"the TF chain {parent} → {child} does not connect: {parent!r} hangs "
                             f"from {roots_p[-1]!r} and {child!r} from {roots_c[-1]!r}, and no "
                             f"transform links {roots_p[-1]!r} and {roots_c[-1]!r}", topic)
    hops = [(e, False) for e in up_p[:roots_p.index(common)]]
    hops += [(e, True) for e in reversed(up_c[:roots_c.index(common)])]
    return hops


def _tf_chain(path: Path, reader, topic: str, tf_topic: str, parent: str, child: str,
              window) -> PoseSeries:
    cons = _connections(path, reader, tf_topic)
    msgtype = cons[0].msgtype
    if msgtype not in TF_TYPES:
        raise BagError(path, f"type {msgtype} is not a TF message (tf2_msgs/TFMessage)", tf_topic)
    edges = _static_edges(path, reader) if _has_topic(reader, TF_STATIC_TOPIC) else {}
    dynamic: dict[str, _Edge] = {}
    ros2 = _is_ros2(cons[0])
    t_lists: dict[str, list[int]] = {}
    for i, (_, raw) in enumerate(_stream(path, reader, cons, tf_topic, *window)):
        for stamp, par, ch, pose in _decode(path, tf_topic, i, _DECODERS[msgtype], raw, ros2):
            e = dynamic.get(ch)
            if e is None or e.parent != par:
                e = dynamic[ch] = _Edge(par, ch)
                t_lists[ch] = []
            t_lists[ch].append(stamp)
            e.p.append(pose[:3])
            e.q.append(pose[3:])
    for ch, e in dynamic.items():
        e.t_ns = np.asarray(t_lists[ch], dtype=np.int64)
    edges.update(dynamic)
    hops = chain_edges(path, topic, parent, child, edges)
    moving = [e for e, _ in hops if not e.static]
    if not moving:
        raise BagError(path, f"every hop of {parent} → {child} is static: the chain does not move",
                       topic)
    base = moving[0]  # its stamps, in recorded order (read_poses rejects non-monotonic ones)
    t = base.t_ns
    if t.size == 0:
        raise BagError(path, "no messages in the window", topic)
    R = np.broadcast_to(np.eye(3), (t.size, 3, 3)).copy()
    p = np.zeros((t.size, 3))
    for e, forward in hops:
        Re, pe = _edge_at(path, topic, e, t, base)
        if forward:  # T ← T · T_e
            p = p + np.einsum("nij,nj->ni", R, pe)
            R = R @ Re
        else:  # T ← T · T_e⁻¹
            Rinv = np.swapaxes(Re, 1, 2)
            p = p - np.einsum("nij,nj->ni", R @ Rinv, pe)
            R = R @ Rinv
    return PoseSeries(t, p, Rotation.from_matrix(R).as_quat(), parent, child)


def _edge_at(path: Path, topic: str, e: _Edge, t: np.ndarray, base: _Edge) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation of an edge at stamps ``t``; dynamic hops other than ``base`` are
    interpolated (slerp, linear) and must cover ``t``."""
    n = t.size
    if e.static:
        R = Rotation.from_quat(np.asarray(e.q[0], float)).as_matrix()
        return np.broadcast_to(R, (n, 3, 3)), np.broadcast_to(np.asarray(e.p[0], float), (n, 3))
    if e is base:
        return Rotation.from_quat(np.asarray(e.q, float)).as_matrix(), np.asarray(e.p, float)
    order = np.argsort(e.t_ns, kind="stable")
    te, pe, qe = e.t_ns[order], np.asarray(e.p, float)[order], np.asarray(e.q, float)[order]
    keep = np.concatenate([[True], np.diff(te) > 0])
    te, pe, qe = te[keep], pe[keep], qe[keep]
    if te.size < 2 or t[0] < te[0] or t[-1] > te[-1]:
        raise BagError(path, f"the hop {e.parent} → {e.child} does not cover the stamps of "
                             f"{base.parent} → {base.child} (crop with --start/--end)", topic)
    x = (te - te[0]).astype(float)
    xt = (t - te[0]).astype(float)
    R = Slerp(x, Rotation.from_quat(qe))(xt).as_matrix()
    return R, np.column_stack([np.interp(xt, x, pe[:, i]) for i in range(3)])


def static_transform(path: Path, edges: dict[str, _Edge], parent: str, child: str,
                     topic: str = TF_STATIC_TOPIC) -> tuple[np.ndarray, np.ndarray]:
    """``(R, p)`` of ``child`` in ``parent`` composed through static transforms only."""
    R, p = np.eye(3), np.zeros(3)
    for e, forward in chain_edges(path, topic, parent, child, edges):
        if not e.static:
            raise BagError(path, f"the hop {e.parent} → {e.child} is not static", topic)
        Re = Rotation.from_quat(np.asarray(e.q[0], float)).as_matrix()
        pe = np.asarray(e.p[0], float)
        if forward:
            p, R = p + R @ pe, R @ Re
        else:
            p, R = p - R @ Re.T @ pe, R @ Re.T
    return R, p


# --------------------------------------------------------------------------------------------
# IMU


@dataclass(frozen=True)
class ImuSeries:
    """Measured angular rate ``omega`` [rad/s] and specific force ``accel`` [m/s²] in ``frame``."""

    t_ns: np.ndarray
    omega: np.ndarray
    accel: np.ndarray
    frame: str


def read_imu(path: str | Path, topic: str, *, start_s: float | None = None,
             end_s: float | None = None) -> ImuSeries:
    """The ``sensor_msgs/Imu`` samples of ``topic`` within ``[start_s, end_s]`` (bag seconds)."""
    path = Path(path)
    with _open(path) as reader:
        cons = _connections(path, reader, topic)
        if cons[0].msgtype != IMU_TYPE:
            raise BagError(path, f"type {cons[0].msgtype} is not sensor_msgs/Imu", topic)
        series = _read_series(path, reader, {topic: _imu_fields}, _window(reader, start_s, end_s))
    return _imu_series(path, topic, *series[topic].result()[:3])


def _imu_series(path: Path, topic: str, t_ns: np.ndarray, d: np.ndarray, frame: str) -> ImuSeries:
    if t_ns.size < 2:
        raise BagError(path, f"{t_ns.size} IMU messages: need at least 2", topic)
    dt = np.diff(t_ns)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0)) + 1
        raise BagError(path, f"stamps are not monotonic: message {k}'s stamp "
                             f"{'repeats' if dt[k - 1] == 0 else 'goes backwards'}", topic)
    omega, accel = d[:, :3], d[:, 3:]
    if not (np.all(np.isfinite(omega)) and np.all(np.isfinite(accel))):
        raise BagError(path, "an IMU sample is NaN or infinite", topic)
    return ImuSeries(t_ns, omega, accel, frame)


class ImuTrajectory(Trajectory):
    """A logged trajectory whose IMU samples are measured: :meth:`imu` returns the orientation of
    B from the poses and the *measured* angular rate and specific force (interpolated linearly;
    the IMU frame is the rig's B, so the rig's mounting is not applied to them again)."""

    t_imu: np.ndarray  # seconds on the trajectory's clock
    omega_B: np.ndarray
    f_B: np.ndarray
    imu_frame: str

    @classmethod
    def of(cls, traj: Trajectory, t_imu: np.ndarray, omega_B: np.ndarray, f_B: np.ndarray,
           imu_frame: str) -> "ImuTrajectory":
        out = cls.__new__(cls)
        out.__dict__.update(traj.__dict__)
        out.t_imu, out.omega_B, out.f_B, out.imu_frame = t_imu, omega_B, f_B, imu_frame
        return out

    def imu(self, t, R_V_B, p_V_B):
        R_W_B, _, _ = super().imu(t, R_V_B, p_V_B)
        t = np.clip(np.asarray(t, dtype=float), self.t_start, self.t_end)
        w = np.column_stack([np.interp(t, self.t_imu, self.omega_B[:, i]) for i in range(3)])
        f = np.column_stack([np.interp(t, self.t_imu, self.f_B[:, i]) for i in range(3)])
        return R_W_B, w, f

    def modelled_imu(self, t, R_V_B, p_V_B):
        """What the poses alone predict (the base trajectory's IMU)."""
        return super().imu(t, R_V_B, p_V_B)


@dataclass(frozen=True)
class ImuAgreement:
    """Measured IMU against the poses' prediction, over 1-s means (the band both resolve).

    ``gyro_offset_radps``/``accel_offset_mps2``: mean measured − predicted (biases, mounting);
    ``gyro_rms_radps``/``accel_rms_mps2``: RMS of what is left; ``misalignment_deg``: the angle of
    the rotation that best maps predicted onto measured rates and specific forces (0 when the
    rig's mounting is the IMU's; None when the drive does not determine it); ``seconds``: time
    both cover.
    """

    seconds: float
    gyro_offset_radps: np.ndarray
    gyro_rms_radps: float
    accel_offset_mps2: np.ndarray
    accel_rms_mps2: float
    misalignment_deg: float | None

    def text(self) -> str:
        mis = "—" if self.misalignment_deg is None else f"{self.misalignment_deg:.2f} deg"
        return (f"measured IMU vs poses over {self.seconds:.0f} s (1-s means): gyro "
                f"{np.degrees(self.gyro_rms_radps):.3g} deg/s RMS, offset "
                f"{np.degrees(np.linalg.norm(self.gyro_offset_radps)):.3g} deg/s; accel "
                f"{self.accel_rms_mps2:.3g} m/s² RMS, offset "
                f"{np.linalg.norm(self.accel_offset_mps2):.3g} m/s²; mounting mismatch {mis}")


def imu_agreement(traj: ImuTrajectory, R_V_B: np.ndarray, p_V_B: np.ndarray) -> ImuAgreement:
    """How well the measured IMU of ``traj`` agrees with its poses for a rig mounted at
    ``(R_V_B, p_V_B)`` (see :class:`ImuAgreement`)."""
    t = traj.t_imu[(traj.t_imu >= traj.t_start) & (traj.t_imu <= traj.t_end)]
    n_blocks = int((t[-1] - t[0]) // 1.0) if t.size else 0
    if n_blocks < 1:
        raise RouteError("the IMU overlaps the poses for less than 1 s")
    _, w_m, f_m = traj.imu(t, R_V_B, p_V_B)
    _, w_p, f_p = traj.modelled_imu(t, R_V_B, p_V_B)
    block = np.minimum(((t - t[0]) // 1.0).astype(int), n_blocks - 1)
    counts = np.bincount(block, minlength=n_blocks)[:, None]

    def means(x):
        return np.stack([np.bincount(block, x[:, i], n_blocks) for i in range(3)], axis=1) / counts

    wm, wp, fm, fp = means(w_m), means(w_p), means(f_m), means(f_p)
    gw, gf = (wm - wp).mean(axis=0), (fm - fp).mean(axis=0)
    rw = float(np.sqrt(np.mean(np.sum((wm - wp - gw) ** 2, axis=1))))
    rf = float(np.sqrt(np.mean(np.sum((fm - fp - gf) ** 2, axis=1))))
    # The mounting rotation from both vector sets at once (1-s means of specific force, gravity
    # included, and of angular rate scaled to the same size): a planar drive turns about one
    # axis only, its accelerations and gravity give the other two.
    scale = 9.80665 / max(float(np.sqrt(np.mean(np.sum(wp ** 2, axis=1)))), 1e-6)
    pred, meas = np.vstack([fp, wp * scale]), np.vstack([fm - gf, (wm - gw) * scale])
    mis = None
    if np.linalg.matrix_rank(pred, tol=0.05 * np.sqrt(pred.shape[0])) >= 2:
        rot, _ = Rotation.align_vectors(meas, pred)
        mis = float(np.degrees(rot.magnitude()))
    return ImuAgreement(float(t[-1] - t[0]), gw, rw, gf, rf, mis)


# --------------------------------------------------------------------------------------------
# Bag → trajectory


@dataclass(frozen=True)
class BagSource:
    """What to read from a bag: the trajectory ``topic`` (or ``/tf:parent.child``), an optional
    ``imu_topic``, a window ``[start_s, end_s]`` in seconds from the start of the bag, the frame
    to take as V (``vehicle_frame``, via ``/tf_static``) and the pose axes (``vehicle`` or
    ``optical``)."""

    topic: str | None = None
    imu_topic: str | None = None
    start_s: float | None = None
    end_s: float | None = None
    vehicle_frame: str | None = None
    axes: str = "vehicle"

    @staticmethod
    def required(bag: "BagSource | None", path: Path) -> "BagSource":
        """``bag`` when it names a topic; otherwise an error listing what the bag can score."""
        if bag is not None and bag.topic:
            return bag
        found = [s for ti in bag_info(path) for s in ((ti.topic,) if ti.use == "pose" else ti.sources)]
        raise BagError(path, "a bag needs a trajectory source: pass --topic (scoreable here: "
                             f"{', '.join(found) if found else 'nothing'})")

    def options(self) -> dict:
        return {"topic": self.topic, "imu_topic": self.imu_topic, "start_s": self.start_s,
                "end_s": self.end_s, "vehicle_frame": self.vehicle_frame, "axes": self.axes}


def read_bag_route(path: str | Path, topic: str, *, imu_topic: str | None = None,
                   start_s: float | None = None, end_s: float | None = None,
                   vehicle_frame: str | None = None, axes: str = "vehicle",
                   cutoff_hz: float = DEFAULT_CUTOFF_HZ, rate_hz: float | None = None) -> Trajectory:
    """A bag's trajectory source (and optional measured IMU) as a trajectory of V (see the
    module notes)."""
    path = Path(path)
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
        with _open(path) as reader:
            if not _has_topic(reader, TF_STATIC_TOPIC):
                raise BagError(path, f"cannot move the poses of {s.child!r} to {vehicle_frame!r}: "
                                     f"the bag has no {TF_STATIC_TOPIC}", topic)
            edges = _static_edges(path, reader)
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
        return traj
    t_imu = (imu.t_ns - s.t_ns[0]).astype(float) * 1e-9
    lo, hi = max(t_imu[0], traj.t_start), min(t_imu[-1], traj.t_end)
    if hi - lo < 0.5 * traj.duration:
        raise BagError(path, f"the IMU covers {max(hi - lo, 0):.1f} s of the {traj.duration:.1f} s "
                             f"of poses on {topic}: not the same drive?", imu_topic)
    return ImuTrajectory.of(traj, t_imu, imu.omega, imu.accel, imu.frame)


# --------------------------------------------------------------------------------------------
# Writing


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
              imu_rate_hz: float = 200.0, tf: bool = False, start_ns: int = 1_700_000_000 * 10**9) -> Path:
    """Write V's poses sampled at ``rate_hz`` as ``msgtype`` messages on ``topic`` (and, with
    ``tf``, as ``/tf`` ``frame → child`` plus a ``/tf_static`` ``child → imu_frame``), and with
    ``imu_topic`` a perfect IMU mounted at ``T_V_B`` (R, p) at ``imu_rate_hz``.

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

    def message(t_ns, p, q, v_body, w_body):
        h = header(t_ns, frame)
        if msgtype.endswith("/PoseStamped"):
            return M[msgtype](header=h, pose=pose(p, q))
        if msgtype.endswith("/PoseWithCovarianceStamped"):
            return M[msgtype](header=h, pose=M["geometry_msgs/msg/PoseWithCovariance"](
                pose=pose(p, q), covariance=np.zeros(36)))
        if msgtype.endswith("/TransformStamped"):
            return transform(t_ns, p, q, frame, child)
        return M[msgtype](header=h, child_frame_id=child,
                          pose=M["geometry_msgs/msg/PoseWithCovariance"](pose=pose(p, q), covariance=np.zeros(36)),
                          twist=M["geometry_msgs/msg/TwistWithCovariance"](
                              twist=M["geometry_msgs/msg/Twist"](linear=vec(v_body), angular=vec(w_body)),
                              covariance=np.zeros(36)))

    s = traj.sample(traj.times(rate_hz))
    q = Rotation.from_matrix(s.R_W_V).as_quat()
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)
    v_body = np.einsum("nji,nj->ni", s.R_W_V, s.v_W)
    stamps = start_ns + np.round((s.t - s.t[0]) * 1e9).astype(np.int64)
    records: list[tuple[int, str, bytes]] = []
    tf_type = "tf2_msgs/msg/TFMessage"
    for k in range(s.t.size):
        t_ns = int(stamps[k])
        records.append((t_ns, topic, serialize(message(t_ns, s.p_W_V[k], q[k], v_body[k], s.omega_V[k]), msgtype)))
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
    records.sort(key=lambda r: r[0])
    static = None
    if tf:
        qb = Rotation.from_matrix(R_V_B).as_quat()
        static = serialize(M[tf_type](transforms=[transform(start_ns, p_V_B, qb, child, imu_frame)]), tf_type)
    types = {topic: msgtype, TF_TOPIC: tf_type, TF_STATIC_TOPIC: tf_type}
    if imu_topic is not None:
        types[imu_topic] = IMU_TYPE
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
    with _open(path) as reader:
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
