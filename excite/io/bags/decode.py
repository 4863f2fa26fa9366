"""Message types and decoding: the fields excite needs, read straight from the serialized bytes
(CDR for ROS 2, the ROS 1 wire format), one message at a time or a batch at once where the
layout repeats (:class:`Series`)."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from ...errors import BagError


POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped",
              "geometry_msgs/msg/TransformStamped", "nav_msgs/msg/Odometry")


TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")


IMU_TYPE = "sensor_msgs/msg/Imu"


TF_TOPIC, TF_STATIC_TOPIC = "/tf", "/tf_static"


AXES = ("vehicle", "optical")


_U32 = {"<": struct.Struct("<I"), ">": struct.Struct(">I")}


_I32 = {"<": struct.Struct("<i"), ">": struct.Struct(">i")}


_F64 = {(e, n): struct.Struct(f"{e}{n}d") for e in "<>" for n in (3, 4, 7, 9, 36)}


class Cursor:
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

    def integer(self, fmt: str) -> int:
        """One integer of struct format ``fmt`` (``b`` int8, ``B`` uint8, ``H`` uint16), aligned to its size."""
        n = struct.calcsize(fmt)
        self._align(n)
        (v,) = struct.unpack_from(self.e + fmt, self.b, self.o)
        self.o += n
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
        v = (_F64.get((self.e, n)) or struct.Struct(f"{self.e}{n}d")).unpack_from(self.b, self.o)
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
Pose = tuple[int, str, "str | None", tuple[float, ...]]


def _pose_stamped(c: Cursor) -> list[Pose]:
    t, frame = c.header()
    return [(t, frame, None, c.doubles(7, keep=True))]


def _transform_stamped(c: Cursor) -> list[Pose]:
    t, frame = c.header()
    child = c.string()
    return [(t, frame, child, c.doubles(7, keep=True))]


def _tf_message(c: Cursor) -> list[Pose]:
    return [_transform_stamped(c)[0] for _ in range(c.u32())]


DECODERS: dict[str, Callable[[Cursor], list[Pose]]] = {
    "geometry_msgs/msg/PoseStamped": _pose_stamped,
    "geometry_msgs/msg/PoseWithCovarianceStamped": _pose_stamped,  # pose first, covariance after
    "geometry_msgs/msg/TransformStamped": _transform_stamped,
    "nav_msgs/msg/Odometry": _transform_stamped,  # header, child_frame_id, pose first
    "tf2_msgs/msg/TFMessage": _tf_message,
    "tf/msg/tfMessage": _tf_message,
}


def imu_fields(c: Cursor) -> list[Pose]:
    """(stamp, frame, None, angular rate + linear acceleration) of a sensor_msgs/Imu."""
    t, frame = c.header()
    c.doubles(4)  # orientation
    c.doubles(9)
    w = c.doubles(3, keep=True)
    c.doubles(9)
    return [(t, frame, None, w + c.doubles(3, keep=True))]


def decode_message(path: Path, topic: str, index: int, fn: Callable, raw: bytes, ros2: bool):
    try:
        return fn(Cursor(raw, ros2))
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


class Series:
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
            c = Cursor(raw, self.ros2)
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
