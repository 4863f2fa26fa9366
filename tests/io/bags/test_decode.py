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
