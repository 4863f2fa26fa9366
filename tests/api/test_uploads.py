"""Bag uploads: compressed bags are refused before they expand past the bounds, and an upload is
written to disk once."""

from __future__ import annotations

import bz2
import struct
import time
from pathlib import Path
import numpy as np
import pytest
from servers import LiveServer


LOOP = {"waypoints": [[0, 0], [30, 0], [30, 20], [0, 20], [0, 1]]}
REQUEST_TIMEOUT_S = 60


def _ros1_records(data: bytes):
    """(offset, header fields, data offset, data length) of each top-level record of a ROS 1 bag."""
    o = 13
    while o < len(data):
        (hlen,) = struct.unpack_from("<I", data, o)
        fields, p = {}, o + 4
        while p < o + 4 + hlen:
            (flen,) = struct.unpack_from("<I", data, p)
            k, v = data[p + 4:p + 4 + flen].split(b"=", 1)
            fields[k.decode()] = v
            p += 4 + flen
        (dlen,) = struct.unpack_from("<I", data, p)
        yield o, fields, p + 4, dlen
        o = p + 4 + dlen


def _bz2_bomb_bag(tmp_path: Path, expands_to: int = 300 << 20) -> Path:
    """A ROS 1 bag whose bz2 chunk decompresses to ``expands_to`` bytes of zeros (its
    compressed data padded to the chunk's length, so every offset stays right)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    M = ts.types
    path = tmp_path / "bomb.bag"
    rng = np.random.default_rng(0)
    w = Writer(path)
    w.set_compression(Writer.CompressionFormat.BZ2)
    with w:
        conn = w.add_connection("/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        for i in range(400):
            x = rng.normal(size=3)
            msg = M["geometry_msgs/msg/PoseStamped"](
                header=M["std_msgs/msg/Header"](seq=i, stamp=M["builtin_interfaces/msg/Time"](sec=i, nanosec=0),
                                                frame_id="map"),
                pose=M["geometry_msgs/msg/Pose"](position=M["geometry_msgs/msg/Point"](x=x[0], y=x[1], z=x[2]),
                                                 orientation=M["geometry_msgs/msg/Quaternion"](x=0, y=0, z=0, w=1)))
            w.write(conn, i * 10**9, ts.serialize_ros1(msg, "geometry_msgs/msg/PoseStamped"))
    data = bytearray(path.read_bytes())
    comp = bz2.BZ2Compressor(9)
    bomb = b"".join(comp.compress(bytes(16 << 20)) for _ in range(expands_to >> 24)) + comp.flush()
    chunks = [(o, f, d, n) for o, f, d, n in _ros1_records(bytes(data)) if f.get("op") == b"\x05"]
    assert chunks and chunks[0][1]["compression"] == b"bz2"
    _, _, at, n = chunks[0]
    assert len(bomb) <= n, (len(bomb), n)
    data[at:at + n] = bomb + bytes(n - len(bomb))
    path.write_bytes(bytes(data))
    return path


def _mcap(tmp_path: Path, name: str, kind: str, records: bytes, size: int, chunks: int = 1) -> Path:
    """An MCAP file without a summary: header, ``chunks`` chunks (each ``records`` compressed by
    the caller as ``kind``, declaring ``size``), data end and a footer that points nowhere."""
    def rec(op: int, body: bytes) -> bytes:
        return struct.pack("<BQ", op, len(body)) + body

    def string(s: str) -> bytes:
        return struct.pack("<I", len(s)) + s.encode()

    chunk = struct.pack("<QQQI", 0, 10**9, size, 0) + string(kind) + struct.pack("<Q", len(records)) + records
    body = (b"\x89MCAP0\r\n" + rec(0x01, string("ros2") + string("test")) + rec(0x06, chunk) * chunks
            + rec(0x0F, struct.pack("<I", 0)) + rec(0x02, struct.pack("<QQI", 0, 0, 0)) + b"\x89MCAP0\r\n")
    path = tmp_path / name
    path.write_bytes(body)
    return path


def _zstd_zeros(n: int) -> bytes:
    try:
        from compression import zstd
    except ImportError:
        from backports import zstd
    c = zstd.ZstdCompressor()
    out = b"".join(c.compress(bytes(64 << 20)) for _ in range(n >> 26))
    return out + c.flush()


@pytest.fixture(scope="module")
def bag_server(tmp_path_factory):
    srv = LiveServer(tmp_path_factory.mktemp("bombs"), workers=0, score_workers=1,
                     request_timeout_s=REQUEST_TIMEOUT_S).start()
    yield srv
    srv.stop()


def _upload(srv, path: Path, topic: str = "/pose"):
    with srv.client(headers={"X-Excite-Client": "tests"}) as c:
        return c.post("/v1/score/bag", files={"bag": (path.name, path.read_bytes(), "application/octet-stream")},
                      data={"topic": topic})


@pytest.mark.slow
def test_compressed_bag_bombs_are_refused_before_they_expand(bag_server, tmp_path):
    """A ROS 1 bag whose bz2 chunk expands to 300 MiB, an MCAP without a summary whose zstd chunk
    declares 900 MiB of zeros, one of 16 chunks of 64 MiB of zeros each (34 KB), and an LZ4 chunk
    that is not LZ4: each a 422 naming the bound or the damage (never a 500, nor a worker held
    until the request's time limit), and the next request is served."""
    cases = [
        (_bz2_bomb_bag(tmp_path), "/pose", "expands past"),
        (_mcap(tmp_path, "zeros.mcap", "zstd", _zstd_zeros(192 << 20), 192 << 20), "/odom", "past the bounds"),
        (_mcap(tmp_path, "chunks.mcap", "zstd", _zstd_zeros(64 << 20), 64 << 20, chunks=16), "/odom",
         "bytes per read"),
        (_mcap(tmp_path, "huge.mcap", "zstd", _zstd_zeros(896 << 20), 896 << 20), "/odom", "over the limit"),
        (_mcap(tmp_path, "bad.mcap", "lz4", b"this is not lz4 at all" * 10, 4096), "/odom", "cannot be decompressed"),
    ]
    for path, topic, words in cases:
        assert path.stat().st_size < 300_000
        t0 = time.monotonic()
        r = _upload(bag_server, path, topic)
        took = time.monotonic() - t0
        assert r.status_code == 422, (path.name, r.status_code, r.text[:300])
        assert took < REQUEST_TIMEOUT_S / 3, (path.name, took)  # refused, not walked to the time limit
        body = r.json()
        assert words in body["detail"] and body["errors"][0]["field"] == "bag", body
        assert "/tmp" not in body["detail"]
    with bag_server.client() as c:
        assert c.post("/v1/score", json={"route": LOOP}).status_code == 200


def test_a_bag_upload_is_written_to_disk_once(bag_server, data_dir):
    data = (data_dir / "nav2_turtlebot.mcap").read_bytes()

    def written() -> int:
        return int(next(line.split()[1] for line in Path(f"/proc/{bag_server.proc.pid}/io").read_text().splitlines()
                        if line.startswith("wchar")))

    before = written()
    with bag_server.client(headers={"X-Excite-Client": "tests"}) as c:
        r = c.post("/v1/score/bag", files={"bag": ("nav2.mcap", data, "application/octet-stream")},
                   data={"topic": "/odom"})
    assert r.status_code == 200, r.text[:300]
    assert written() - before < 1.3 * len(data), (written() - before, len(data))
