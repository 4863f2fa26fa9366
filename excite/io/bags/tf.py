"""TF trees in a bag: the edges of ``/tf_static`` and ``/tf`` and the chain's poses over time
(the tree's hops: :mod:`excite.rig.frames`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from ...errors import BagError
from ...rig.frames import Edge, chain_edges
from .decode import DECODERS, TF_STATIC_TOPIC, TF_TYPES, PoseSeries, decode_message
from .stream import has_topic, is_ros2, stream_messages, topic_connections


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

