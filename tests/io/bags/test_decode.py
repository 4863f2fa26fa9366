"""Every decompression of a bag's chunks is bounded by what the chunk declares."""

from __future__ import annotations

import bz2
import pytest


def test_every_decompression_is_bounded():
    from excite.io.bags import MAX_CHUNK_BYTES, Budget, decompress
    from excite.io.bags.mcap import RATIO_FLOOR, bounded_decompressor

    zeros = bz2.compress(bytes(RATIO_FLOOR + 1))
    with pytest.raises(ValueError, match="expands past"):
        bounded_decompressor("bz2", Budget(1 << 40))(zeros)
    assert len(bounded_decompressor("bz2", Budget(1 << 40))(bz2.compress(bytes(1000)))) == 1000
    budget = Budget(5000)  # a read's total
    expand = bounded_decompressor("bz2", budget)
    expand(bz2.compress(bytes(4000)))
    with pytest.raises(ValueError, match="5,000 bytes per read"):
        expand(bz2.compress(bytes(4000)))
    with pytest.raises(ValueError, match="cannot be decompressed"):
        decompress("lz4", b"garbage" * 20, 100)
    with pytest.raises(ValueError, match="over the limit"):
        decompress("zstd", b"", MAX_CHUNK_BYTES + 1)
    with pytest.raises(ValueError, match="unknown chunk compression"):
        decompress("brotli", b"x", 10)


def _summaryless_mcap(path, chunks: int, size: int):
    """An MCAP without a summary: ``chunks`` zstd chunks of ``size`` zeros each, every one within
    the per-chunk bounds (at most 64 MiB of zeros)."""
    import struct

    try:
        from compression import zstd
    except ImportError:
        from backports import zstd

    def rec(op: int, body: bytes) -> bytes:
        return struct.pack("<BQ", op, len(body)) + body

    def string(s: str) -> bytes:
        return struct.pack("<I", len(s)) + s.encode()

    c = zstd.ZstdCompressor()
    data = c.compress(bytes(size)) + c.flush()
    chunk = rec(0x06, struct.pack("<QQQI", 0, 10**9, size, 0) + string("zstd") + struct.pack("<Q", len(data)) + data)
    path.write_bytes(b"\x89MCAP0\r\n" + rec(0x01, string("ros2") + string("test")) + chunk * chunks
                     + rec(0x0F, struct.pack("<I", 0)) + rec(0x02, struct.pack("<QQI", 0, 0, 0)) + b"\x89MCAP0\r\n")
    return path


@pytest.mark.parametrize("chunks, size", [(16, 64 << 20), (64, 256 << 10), (1000, 64 << 10)],
                         ids=["16 x 64 MiB", "64 x 256 KiB", "1000 x 64 KiB"])
def test_an_mcap_without_a_summary_is_read_within_its_budget_however_its_zeros_are_split(tmp_path, monkeypatch,
                                                                                          chunks, size):
    """A small MCAP without a summary whose chunks each stay within the per-chunk bounds (16
    chunks of 64 MiB of zeros in 34 KB, or many small ones): the read decompresses at most the
    file's budget (100 times its size, at least 4 MiB) in all, whatever the split, and ends in a
    one-line BagError — never a walk through a gigabyte of records."""
    from excite.errors import BagError
    from excite.io.bags import mcap
    from excite.io.bags.reader import read_poses

    path = _summaryless_mcap(tmp_path / "zeros.mcap", chunks, size)
    assert not mcap.has_summary(path)
    limit = max(4 << 20, 100 * path.stat().st_size)  # the bound the reader's documentation states
    assert chunks * size > limit  # expanded whole, each would exceed the budget
    expanded = []
    real = mcap._expand

    def counting(kind: str, data: bytes, most: int) -> bytes:
        out = real(kind, data, most)
        expanded.append(len(out))
        return out

    monkeypatch.setattr(mcap, "_expand", counting)
    with pytest.raises(BagError) as err:
        read_poses(path, "/odom")
    assert "\n" not in str(err.value)
    assert sum(expanded) <= limit + len(expanded), (sum(expanded), limit)
