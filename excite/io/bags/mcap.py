"""excite's own MCAP reader, and every decompression of a bag under bounds that hold before
anything is allocated.

MCAP (https://mcap.dev/spec): records are opcode u8, length u64, content; messages sit in
(compressed) chunks. Reading the chunks here, a record at a time, costs a fraction of a
general reader's per-message work; the order rosbags would give (by log time) is kept as long
as every chunk starts after the previous one ended, which a recorder writes.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from .decode import Series


# MCAP (https://mcap.dev/spec): records are opcode u8, length u64, content; messages sit in
# (compressed) chunks. Reading the chunks here, a record at a time, costs a fraction of a
# general reader's per-message work; the order rosbags would give (by log time) is kept as long
# as every chunk starts after the previous one ended, which a recorder writes.
_MCAP_MAGIC = b"\x89MCAP0\r\n"


_OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_DATA_END, _OP_FOOTER = 0x04, 0x05, 0x06, 0x0F, 0x02


_REC = struct.Struct("<BQ")


_MSG = struct.Struct("<HIQQ")


def mcap_files(path: Path) -> list[Path] | None:
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


MAX_CHUNK_BYTES = 256 << 20  # one chunk, decompressed (recorders write a few MB)
MAX_RATIO = 1000  # a chunk beyond this ratio (and past RATIO_FLOOR) is a bomb: real data is < 50
RATIO_FLOOR = 64 << 20  # small chunks may be all zeros
MIN_BUDGET = 1 << 30  # the least a read may decompress in all (a small bag)
# An MCAP without a summary is indexed by walking every record of every chunk (rosbags does it in
# Python, ~1 µs a record): it may decompress at most this many times its size in all (real
# recordings compress < 50-fold), and at least SUMMARYLESS_FLOOR, so that a small file of empty
# records cannot hold a reader for minutes
SUMMARYLESS_RATIO = 100
SUMMARYLESS_FLOOR = 4 << 20
COMPRESSIONS = ("", "none", "zstd", "lz4", "bz2")


class Budget:
    """What one read of a bag may decompress in all: at least :data:`MIN_BUDGET`, and
    :data:`MAX_RATIO` times the bag's size for a large one."""

    def __init__(self, limit: int):
        self.limit, self.used = limit, 0

    @classmethod
    def for_file(cls, path: Path, summary: bool = True) -> "Budget":
        """The budget of a read of ``path``; ``summary`` False: an MCAP without a summary."""
        try:
            size = sum(f.stat().st_size for f in ([path] if path.is_file() else path.iterdir()))
        except OSError:
            size = 0
        if not summary:
            return cls(max(SUMMARYLESS_FLOOR, SUMMARYLESS_RATIO * size))
        return cls(max(MIN_BUDGET, MAX_RATIO * size))

    def cap(self, compressed: int) -> int:
        """The most a chunk of ``compressed`` bytes may expand to now."""
        return max(0, min(MAX_CHUNK_BYTES, max(RATIO_FLOOR, MAX_RATIO * compressed), self.limit - self.used))

    def spend(self, n: int) -> None:
        self.used += n


def _expand(kind: str, data: bytes, limit: int) -> bytes:
    """At most ``limit + 1`` bytes of ``data`` decompressed: never more is allocated."""
    try:
        if kind == "zstd":
            try:
                from compression import zstd
            except ImportError:
                from backports import zstd
            return zstd.ZstdDecompressor().decompress(data, max_length=limit + 1)
        if kind == "lz4":
            from lz4.frame import LZ4FrameDecompressor

            return LZ4FrameDecompressor().decompress(data, max_length=limit + 1)
        if kind == "bz2":
            import bz2

            return bz2.BZ2Decompressor().decompress(data, max_length=limit + 1)
    except ValueError:
        raise
    except Exception as exc:  # each library's own error for a corrupt stream (lz4: RuntimeError)
        raise ValueError(f"a {kind} chunk cannot be decompressed ({type(exc).__name__}: "
                         f"{str(exc)[:200]})") from None
    raise ValueError(f"unknown chunk compression {kind!r}")


def decompress(kind: str, data: bytes, size: int, budget: Budget | None = None) -> bytes:
    """An MCAP chunk's records: at most the ``size`` it declares, itself bounded (and within
    ``budget``), so that a small file cannot expand into all of memory."""
    if size > MAX_CHUNK_BYTES:
        raise ValueError(f"a chunk declares {size:,} bytes, over the limit of {MAX_CHUNK_BYTES:,}")
    if kind in ("", "none"):
        out = data
    else:
        if budget is not None and size > budget.cap(len(data)):
            raise ValueError(f"a chunk of {len(data):,} bytes declares {size:,} decompressed, past the "
                             f"bounds (at most {MAX_RATIO}-fold beyond {RATIO_FLOOR >> 20} MiB, and "
                             f"{budget.limit:,} bytes per read)")
        out = _expand(kind, data, size)
    if len(out) != size:
        raise ValueError(f"a chunk declares {size:,} bytes but holds {len(out):,} or more")
    if budget is not None:
        budget.spend(size)
    return out


def bounded_decompressor(kind: str, budget: Budget):
    """A replacement for ``rosbags``' decompression of a ROS 1 chunk (which declares no size it
    is held to): at most :meth:`Budget.cap` bytes, else a :class:`ValueError`."""

    def expand(data: bytes) -> bytes:
        cap = budget.cap(len(data))
        out = _expand(kind, data, cap)
        if len(out) > cap:
            raise ValueError(f"a {kind} chunk of {len(data):,} bytes expands past {cap:,} bytes (at most "
                             f"{MAX_RATIO}-fold beyond {RATIO_FLOOR >> 20} MiB, {MAX_CHUNK_BYTES >> 20} MiB "
                             f"a chunk and {budget.limit:,} bytes per read)")
        budget.spend(len(out))
        return out

    return expand


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
        if len(rec) < max(n, 10):
            raise EOFError("the file ends inside a message index")
        cid, nbytes = struct.unpack_from("<HI", rec, 0)
        out[cid] = np.frombuffer(rec, dtype=_INDEX_ENTRY, count=nbytes // 16, offset=6)
    return out or None


def mcap_read(files: list[Path], out: dict[str, Series], window, budget: Budget | None = None) -> bool:
    """Feed the messages of ``out``'s topics within ``window`` (log time, ns) to their series;
    False (nothing to trust) when chunks or messages are out of time order."""
    start, stop = window
    channels: dict[int, Series | None] = {}
    last = -1

    def records(buf: bytes | memoryview, o: int, end: int):
        while o + 9 <= end:
            op, n = _REC.unpack_from(buf, o)
            if not 0x01 <= op <= 0x0F or o + 9 + n > end:
                raise ValueError(f"a chunk holds an invalid record (opcode {op:#x}, length {n:,})")
            yield op, o + 9, o + 9 + n
            o += 9 + n

    def channel(buf, o: int) -> None:
        cid, _, n = struct.unpack_from("<HHI", buf, o)
        topic = bytes(buf[o + 8:o + 8 + n]).decode()
        channels[cid] = out.get(topic)

    for f in files:
        fsize = f.stat().st_size
        with f.open("rb") as fh:
            if fh.read(8) != _MCAP_MAGIC:
                raise ValueError("not an MCAP file")
            while True:
                head = fh.read(9)
                if len(head) < 9:
                    raise EOFError("the file ends inside the data section")
                op, n = _REC.unpack(head)
                if not 0x01 <= op <= 0x0F:
                    raise ValueError(f"an invalid record (opcode {op:#x})")
                if fh.tell() + n > fsize:
                    raise EOFError(f"a record of {n:,} bytes runs past the end of the file")
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
                data = decompress(kind, body[40 + clen:40 + clen + rlen], size, budget)
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


def verify_chunks(files: list[Path], budget: Budget) -> None:
    """Decompress every chunk once under the bounds, keeping nothing: before a general reader
    (which would expand each chunk to whatever it holds) reads the files."""
    for f in files:
        fsize = f.stat().st_size
        with f.open("rb") as fh:
            if fh.read(8) != _MCAP_MAGIC:
                raise ValueError("not an MCAP file")
            while True:
                head = fh.read(9)
                if len(head) < 9:
                    return
                op, n = _REC.unpack(head)
                if not 0x01 <= op <= 0x0F:
                    raise ValueError(f"an invalid record (opcode {op:#x})")
                if fh.tell() + n > fsize:
                    raise EOFError(f"a record of {n:,} bytes runs past the end of the file")
                if op in (_OP_DATA_END, _OP_FOOTER):
                    break
                if op != _OP_CHUNK:
                    fh.seek(n, 1)
                    continue
                body = fh.read(n)
                if len(body) < n:
                    raise EOFError("the file ends inside a chunk")
                _, _, size, _, clen = struct.unpack_from("<QQQII", body, 0)
                kind = body[32:32 + clen].decode()
                (rlen,) = struct.unpack_from("<Q", body, 32 + clen)
                decompress(kind, body[40 + clen:40 + clen + rlen], size, budget)


def has_summary(path: Path) -> bool:
    """Whether an MCAP file's footer points to a summary section (readers index from it)."""
    try:
        with path.open("rb") as fh:
            fh.seek(-37, 2)
            tail = fh.read(37)
    except OSError:
        return False
    if len(tail) < 37 or tail[-8:] != _MCAP_MAGIC or tail[0] != _OP_FOOTER:
        return False
    (summary_start,) = struct.unpack_from("<Q", tail, 9)
    return summary_start != 0
