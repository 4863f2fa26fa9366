"""Trees of named frames: the transforms between a robot's frames (a TF tree, an Autoware
sensor kit), each a child's pose in its parent, static or over time; the hops of the chain
between two frames (in time linear in the frames of the tree) and the static pose of one frame
in another. The files they come from are read in :mod:`excite.io` (:mod:`excite.io.bags.tf`);
the rig importers compose the static trees of their files with :mod:`excite.rig.importers.tree`."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..core.units import listed
from ..errors import BagError

@dataclass
class Edge:
    """The transform of ``child`` in its parent: static (one pose) or dynamic (a series)."""

    parent: str
    child: str
    t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    p: list = field(default_factory=list)
    q: list = field(default_factory=list)

    @property
    def static(self) -> bool:
        return self.t_ns.size == 0


def ancestors(frame: str, edges: dict[str, Edge]) -> list[Edge]:
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


MAX_HOPS = 256  # transforms in one chain (a robot's tree is a few dozen deep)


def chain_edges(path: Path, topic: str, parent: str, child: str,
                edges: dict[str, Edge]) -> list[tuple[Edge, bool]]:
    """The hops from ``parent`` to ``child`` as (edge, forward): forward edges go down the tree
    (compose as is), backward ones up (compose inverted). Names the missing link otherwise.
    Linear in the frames: each side's way to its root is walked once and indexed."""
    known = set(edges)
    for f in (parent, child):
        if f not in known and not any(e.parent == f for e in edges.values()):
            frames = sorted(known | {e.parent for e in edges.values()})
            raise BagError(path, f"frame {f!r} appears in no transform on /tf or /tf_static "
                                 f"(frames: {listed(frames)})", topic)
    up_p, up_c = ancestors(parent, edges), ancestors(child, edges)
    roots_p = [parent] + [e.parent for e in up_p]
    roots_c = [child] + [e.parent for e in up_c]
    at_p = {f: i for i, f in reversed(list(enumerate(roots_p)))}
    common = next((f for f in roots_c if f in at_p), None)
    if common is None:
        raise BagError(path, f"the TF chain {parent} → {child} does not connect: {parent!r} hangs "
                             f"from {roots_p[-1]!r} and {child!r} from {roots_c[-1]!r}, and no "
                             f"transform links {roots_p[-1]!r} and {roots_c[-1]!r}", topic)
    k_p, k_c = at_p[common], roots_c.index(common)
    if k_p + k_c > MAX_HOPS:
        raise BagError(path, f"the TF chain {parent} → {child} has {k_p + k_c:,} hops, over the limit "
                             f"of {MAX_HOPS}", topic)
    hops = [(e, False) for e in up_p[:k_p]]
    hops += [(e, True) for e in reversed(up_c[:k_c])]
    return hops


def static_transform(path: Path, edges: dict[str, Edge], parent: str, child: str,
                     topic: str | None = None) -> tuple[np.ndarray, np.ndarray]:
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
