"""An odometry's own covariance in bags: the pose covariance of ``nav_msgs/Odometry`` and
``geometry_msgs/PoseWithCovarianceStamped`` messages, as the log of a lidar or camera of the rig
(:class:`~excite.motion.trajectory.SensorLog`), so that a stretch where the odometry reports
itself worse (a tunnel, a featureless highway) counts less (``noise.use_reported_covariance``,
:mod:`excite.factors.odometry`).

**What a message's covariance is taken to be.** The 6 × 6 ``pose.covariance`` (row-major over
x, y, z, rotation about x, y, z, in the message's ``header.frame_id`` as ROS defines it) is read
as the covariance of the odometry's *increment* since its previous message (what a scan matcher
or a visual odometry reports for one registration), not of its accumulated pose. Divided by that
interval it is a covariance per second, the drift density's square (the log stores it in the
residual's order: rotation [rad²/s], then translation [m²/s]): over a frame pair of Δt the
relative pose has Δt times it (the increments of the pair independent, as the configured
densities assume). The first message takes the interval after it.

A message whose covariance is all zeros reports none (NaN in the log: the configured densities
hold for its frame pair); a topic where every message's is zero is an error, since the option
would then change nothing without saying so. A reported covariance must be symmetric positive
definite.
"""

from __future__ import annotations

import struct
from array import array
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core import bounds
from ...errors import BagError
from ...motion.trajectory import SensorLog
from .decode import Cursor
from .stream import count_bound, is_ros2, open_bag, stream_messages, time_window, topic_connections

ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
POSE_COVARIANCE_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
COVARIANCE_TYPES = (ODOMETRY_TYPE, POSE_COVARIANCE_TYPE)
# ROS's (x, y, z, rx, ry, rz) to the odometry residual's (rotation, translation)
_ORDER = np.array([3, 4, 5, 0, 1, 2])


@dataclass(frozen=True)
class PoseCovariances:
    """The pose covariances of one topic: header stamps ``t_ns`` and ``covariance`` (n, 6, 6) in
    ROS order (x, y, z, rx, ry, rz; m², rad²), as the messages carry them."""

    t_ns: np.ndarray
    covariance: np.ndarray
    frame: str


def _fields(odometry: bool):
    def read(c: Cursor) -> tuple[int, str, tuple[float, ...]]:
        t, frame = c.header()
        if odometry:
            c.string()  # child_frame_id
        c.doubles(7)  # the pose
        return t, frame, c.doubles(36)
    return read


def read_pose_covariances(path: str | Path, topic: str, *, start_s: float | None = None,
                          end_s: float | None = None) -> PoseCovariances:
    """The pose covariance of every ``nav_msgs/Odometry`` or ``PoseWithCovarianceStamped``
    message of ``topic`` within ``[start_s, end_s]`` (bag seconds), in stamp order."""
    path = Path(path)
    stamps, values, frame = array("q"), array("d"), ""
    with open_bag(path) as reader:
        cons = topic_connections(path, reader, topic)
        msgtype = cons[0].msgtype
        if msgtype not in COVARIANCE_TYPES:
            raise BagError(path, f"type {msgtype} carries no pose covariance (types that do: "
                                 f"{', '.join(t.split('/')[-1] for t in COVARIANCE_TYPES)})", topic)
        count_bound(path, topic, cons, bounds.MAX_SAMPLES, "poses")
        read, ros2 = _fields(msgtype == ODOMETRY_TYPE), is_ros2(cons[0])
        for i, (_, raw) in enumerate(stream_messages(path, reader, cons, topic, *time_window(reader, start_s, end_s))):
            try:
                t, f, cov = read(Cursor(raw, ros2))
            except (struct.error, UnicodeDecodeError) as exc:
                raise BagError(path, f"message {i} is malformed ({exc})", topic) from None
            frame = frame or f
            stamps.append(t)
            values.extend(cov)
    if not stamps:
        raise BagError(path, "no messages" + (" in the window" if (start_s, end_s) != (None, None) else ""), topic)
    t = np.frombuffer(stamps, dtype=np.int64)
    order = np.argsort(t, kind="stable")
    cov = np.frombuffer(values, dtype=float).reshape(-1, 6, 6)[order]
    return PoseCovariances(t[order], cov, frame)


def odometry_log(cov: PoseCovariances, t0_ns: int, path: Path, topic: str) -> SensorLog:
    """The covariances as a lidar's or camera's log: message times in seconds from ``t0_ns`` (the
    trajectory clock's start; repeated stamps: the first) and the covariance per second of each
    message's increment in the residual's order (rotation, translation), NaN where the message
    reports none (see the module docstring)."""
    t = (cov.t_ns - t0_ns).astype(float) * 1e-9
    first = np.r_[True, np.diff(t) > 0]
    t, C = t[first], cov.covariance[first]
    if t.size < 2:
        raise BagError(path, "one message: an increment's covariance needs two", topic)
    zero = np.all(C == 0.0, axis=(1, 2))
    if zero.all():
        raise BagError(path, "every message's pose covariance is zero: the odometry reports none (drop "
                             "noise.use_reported_covariance from the rig's sensor, or name a topic that "
                             "carries one)", topic)
    bad = ~zero & ~np.all(np.isfinite(C), axis=(1, 2))
    if bad.any():
        raise BagError(path, f"message {int(np.argmax(bad))}: its pose covariance is not finite", topic)
    known = np.flatnonzero(~zero)
    sym = 0.5 * (C[known] + np.swapaxes(C[known], 1, 2))
    ev = np.linalg.eigvalsh(sym)
    if np.any(ev[:, 0] <= 0):
        k = int(known[np.argmax(ev[:, 0] <= 0)])
        raise BagError(path, f"message {k}: its pose covariance is not positive definite", topic)
    dt = np.diff(t)
    dt = np.r_[dt[0], dt]  # the interval each message's increment covers (the first: the next one's)
    out = np.full(C.shape, np.nan)
    out[known] = sym[:, _ORDER][:, :, _ORDER] / dt[known, None, None]
    return SensorLog(t, out)
