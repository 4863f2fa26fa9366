"""TF trees: the edges of ``/tf_static`` and ``/tf``, the hops of a chain between two frames
(in time linear in the frames of the tree) and the chain's poses over time."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from ...errors import BagError
from .decode import DECODERS, TF_STATIC_TOPIC, TF_TYPES, PoseSeries, decode_message
from .stream import has_topic, is_ros2, listed, stream_messages, topic_connections


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


def static_edges(path: Path, reader) -> dict[str, Edge]:
    """child → edge of every transform on ``/tf_static`` (later messages override)."""
    edges: dict[str, Edge] = {}
    cons = topic_connections(path, reader, TF_STATIC_TOPIC)
    ros2 = is_ros2(cons[0])
    for i, (_, raw) in enumerate(stream_messages(path, reader, cons, TF_STATIC_TOPIC)):
        for _, parent, child, pose in decode_message(path, TF_STATIC_TOPIC, i, DECODERS[cons[0].msgtype],
                                              raw, ros2):
            edges[child] = Edge(parent, child, p=[pose[:3]], q=[pose[3:]])
    return edges


def _ancestors(frame: str, edges: dict[str, Edge]) -> list[Edge]:
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
    up_p, up_c = _ancestors(parent, edges), _ancestors(child, edges)
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


def tf_chain(path: Path, reader, topic: str, tf_topic: str, parent: str, child: str,
              window) -> PoseSeries:
    cons = topic_connections(path, reader, tf_topic)
    msgtype = cons[0].msgtype
    if msgtype not in TF_TYPES:
        raise BagError(path, f"type {msgtype} is not a TF message (tf2_msgs/TFMessage)", tf_topic)
    edges = static_edges(path, reader) if has_topic(reader, TF_STATIC_TOPIC) else {}
    dynamic: dict[str, Edge] = {}
    ros2 = is_ros2(cons[0])
    t_lists: dict[str, list[int]] = {}
    for i, (_, raw) in enumerate(stream_messages(path, reader, cons, tf_topic, *window)):
        for stamp, par, ch, pose in decode_message(path, tf_topic, i, DECODERS[msgtype], raw, ros2):
            e = dynamic.get(ch)
            if e is None or e.parent != par:
                e = dynamic[ch] = Edge(par, ch)
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


def _edge_at(path: Path, topic: str, e: Edge, t: np.ndarray, base: Edge) -> tuple[np.ndarray, np.ndarray]:
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


def static_transform(path: Path, edges: dict[str, Edge], parent: str, child: str,
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
