"""Trees of transforms (:mod:`excite.rig.frames`): a TF chain resolves in linear time in the number
of frames, and its errors are short."""

from __future__ import annotations

import pytest

from excite.errors import BagError
from excite.rig.frames import MAX_HOPS, Edge, chain_edges


def test_tf_chains_resolve_in_linear_time_and_their_errors_are_short(tmp_path):
    n = 50_000
    edges = {f"a{i}": Edge(f"a{i - 1}" if i else "root", f"a{i}") for i in range(n)}
    edges.update({f"b{i}": Edge(f"b{i - 1}" if i else "root", f"b{i}") for i in range(n)})
    hops = chain_edges(tmp_path, "/tf", "a10", "b20", edges)
    assert len(hops) == 32 and hops[0][0].child == "a10" and hops[-1][0].child == "b20"
    with pytest.raises(BagError, match=f"100,000 hops, over the limit of {MAX_HOPS}"):
        chain_edges(tmp_path, "/tf", f"a{n - 1}", f"b{n - 1}", edges)
    with pytest.raises(BagError) as exc:
        chain_edges(tmp_path, "/tf", "nowhere", "a1", edges)
    assert len(str(exc.value)) < 2000 and "and 99,961 more" in str(exc.value)
