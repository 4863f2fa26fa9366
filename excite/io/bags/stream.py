"""Opening a bag with ``rosbags`` and streaming its messages; a ROS 1 bag's chunks are
decompressed under the bounds of :mod:`.mcap` (``rosbags`` itself would expand a chunk to
whatever its data holds)."""

from __future__ import annotations

import struct
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator
from weakref import WeakKeyDictionary

import numpy as np

from ...core.units import listed
from ...errors import BagError
from ..sniff import is_bag
from .mcap import Budget, bounded_decompressor, has_summary, mcap_files, verify_chunks

_budgets: WeakKeyDictionary = WeakKeyDictionary()  # an open reader → what it may still decompress


def budget(reader) -> Budget:
    """What ``reader`` (from :func:`open_bag`) may still decompress."""
    return _budgets[reader]


def _bound_ros1_chunks(reader, allowance: Budget) -> None:
    """Give each ROS 1 chunk a decompressor held to ``allowance`` (rosbags keeps one per chunk)."""
    from rosbags.rosbag1 import reader as ros1

    kinds = {fn: kind for kind, fn in ros1.decompressors.items()}
    for r in getattr(reader, "readers", []):
        chunks = getattr(r, "chunks", None)
        if not isinstance(chunks, dict):
            continue
        for pos, chunk in chunks.items():
            kind = kinds.get(chunk.decompressor)
            if kind is not None and kind != "none":
                chunks[pos] = type(chunk)(chunk.datasize, chunk.datapos, bounded_decompressor(kind, allowance))


def reader_errors() -> tuple[type[Exception], ...]:
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Ros1Error
    from rosbags.rosbag2 import ReaderError as Ros2Error

    return (AnyReaderError, Ros1Error, Ros2Error, struct.error, EOFError)


@contextmanager
def open_bag(path: Path):
    from rosbags.highlevel import AnyReader

    if not path.exists():
        raise FileNotFoundError(2, "No such file or directory", str(path))
    if not is_bag(path):
        raise BagError(path, "not a bag (expected a ROS 1 .bag, an .mcap file or a ROS 2 bag "
                             "folder with metadata.yaml)")
    errors = reader_errors()
    files = mcap_files(path)
    summary = files is None or all(has_summary(f) for f in files)
    allowance = Budget.for_file(path, summary)
    if not summary:
        # rosbags indexes an MCAP without a summary by reading every chunk and walking its
        # records: verify them first, under the smaller budget of such a file
        try:
            verify_chunks(files, Budget.for_file(path, summary))
        except (EOFError, struct.error, ValueError, KeyError, OSError) as exc:
            raise BagError(path, f"cannot read the bag, truncated or corrupt ({exc})") from None
    try:
        reader = AnyReader([path])
        reader.open()
    except errors as exc:
        raise BagError(path, f"cannot read the bag, truncated or corrupt ({exc})") from None
    _budgets[reader] = allowance
    _bound_ros1_chunks(reader, allowance)
    try:
        yield reader
    finally:
        reader.close()


def stream_messages(path: Path, reader, connections, topic: str, start_ns: int | None = None,
                    stop_ns: int | None = None) -> Iterator[tuple[int, bytes]]:
    """(bag time, raw bytes) of the messages on ``connections``, one at a time; reader failures
    mid-file and chunks past the decompression bounds become a :class:`BagError`."""
    errors = reader_errors()
    try:
        for _, t_ns, raw in reader.messages(connections=connections, start=start_ns, stop=stop_ns):
            yield t_ns, raw
    except errors as exc:
        raise BagError(path, f"the bag is truncated or corrupt while reading ({exc})", topic) from None
    except (ValueError, OSError, MemoryError) as exc:
        raise BagError(path, f"cannot be read: {exc}", topic) from None


def topic_connections(path: Path, reader, topic: str) -> list:
    cons = [c for c in reader.connections if c.topic == topic]
    if not cons:
        raise BagError(path, f"no such topic in the bag (topics: {topic_list(reader)})", topic)
    return cons


def count_bound(path: Path, topic: str, cons: list, limit: int, what: str = "") -> None:
    """Refuse a topic with more than ``limit`` messages (``what`` they would be), from the bag's own
    index, before anything is read."""
    n = sum(int(getattr(c, "msgcount", 0) or 0) for c in cons)
    if n > limit:
        raise BagError(path, f"{n:,} messages, over the limit of {limit:,}{' ' + what if what else ''} (crop the "
                             "drive with a window)", topic)


def check_stamps(path: Path, topic: str, t_ns: np.ndarray) -> None:
    """Refuse stamps that repeat or go backwards, naming the first such message."""
    dt = np.diff(t_ns)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0)) + 1
        raise BagError(path, f"stamps are not monotonic: message {k}'s stamp "
                             f"{'repeats' if dt[k - 1] == 0 else 'goes backwards'}", topic)


def topic_list(reader) -> str:
    topics = sorted({c.topic for c in reader.connections})
    return listed(topics) if topics else "none"


def time_window(reader, start_s: float | None, end_s: float | None) -> tuple[int | None, int | None]:
    """Bag times (ns) of a window given in seconds from the start of the bag."""
    start = None if start_s is None else reader.start_time + int(round(start_s * 1e9))
    stop = None if end_s is None else reader.start_time + int(round(end_s * 1e9)) + 1
    return start, stop


def has_topic(reader, topic: str) -> bool:
    return any(c.topic == topic for c in reader.connections)


def is_ros2(connection) -> bool:
    from rosbags.interfaces import ConnectionExtRosbag2

    return isinstance(connection.ext, ConnectionExtRosbag2)
