"""GNSS fixes in bags: ``sensor_msgs/NavSatFix`` topics (ROS 1, ROS 2, MCAP), their covariance,
and what a drive's trajectory carries of them (:class:`~excite.motion.trajectory.SensorLog`: the
fix times on the drive's clock and the receiver's covariance, so that outages and bad geometry
show in σ).

A message whose ``status.status`` is ``STATUS_NO_FIX`` (−1) is no fix: an outage. The covariance
is the message's ``position_covariance`` (ENU, m², row-major) where ``position_covariance_type``
says it is known (APPROXIMATED, DIAGONAL_KNOWN or KNOWN), NaN otherwise. Geodetic coordinates go
to a local east-north-up frame at the first fix with ``pyproj`` (WGS 84 ellipsoidal height, as
NavSatFix's altitude is), for the fixes' own path (:meth:`FixSeries.enu`, :func:`fix_agreement`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core import bounds
from ...errors import BagError
from ...motion.trajectory import SensorLog, Trajectory
from .decode import Cursor
from .stream import open_bag, stream_messages, time_window, topic_connections, is_ros2

NAVSAT_TYPE = "sensor_msgs/msg/NavSatFix"
STATUS_NO_FIX = -1
COVARIANCE_UNKNOWN = 0


@dataclass(frozen=True)
class FixSeries:
    """The fixes of one NavSatFix topic: header stamps ``t_ns``, ``lat``/``lon`` [deg], ``alt``
    [m, ellipsoidal], ``covariance`` (n, 3, 3) ENU [m²] (NaN where not reported), ``status``
    (NavSatStatus: −1 no fix, 0 fix, 1 SBAS, 2 GBAS/RTK) and the message frame."""

    t_ns: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray
    covariance: np.ndarray
    status: np.ndarray
    frame: str

    @property
    def fixed(self) -> np.ndarray:
        """Which messages are fixes (not ``STATUS_NO_FIX``)."""
        return self.status > STATUS_NO_FIX

    def enu(self) -> np.ndarray:
        """East, north, up [m] of every message about the first fix (pyproj: WGS 84 geodetic →
        ECEF, then the local tangent frame there)."""
        from pyproj import Transformer

        tr = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
        x, y, z = tr.transform(self.lon, self.lat, self.alt)
        ecef = np.column_stack([x, y, z])
        i = int(np.argmax(self.fixed)) if self.fixed.any() else 0
        la, lo = np.radians(self.lat[i]), np.radians(self.lon[i])
        R = np.array([[-np.sin(lo), np.cos(lo), 0.0],
                      [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
                      [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]])
        return (ecef - ecef[i]) @ R.T


def navsat_fields(c: Cursor) -> tuple:
    """(stamp ns, frame, status, lat, lon, alt, covariance (9), covariance type) of a NavSatFix."""
    t, frame = c.header()
    status = c.integer("b")
    c.integer("H")  # service
    lat, lon, alt = c.doubles(3)
    cov = c.doubles(9)
    return t, frame, status, lat, lon, alt, cov, c.integer("B")


def read_fixes(path: str | Path, topic: str, *, start_s: float | None = None,
               end_s: float | None = None) -> FixSeries:
    """The ``sensor_msgs/NavSatFix`` messages of ``topic`` within ``[start_s, end_s]`` (seconds
    from the start of the bag), in stamp order."""
    path = Path(path)
    rows = []
    with open_bag(path) as reader:
        cons = topic_connections(path, reader, topic)
        if cons[0].msgtype != NAVSAT_TYPE:
            raise BagError(path, f"type {cons[0].msgtype} is not sensor_msgs/NavSatFix", topic)
        ros2 = is_ros2(cons[0])
        for i, (_, raw) in enumerate(stream_messages(path, reader, cons, topic, *time_window(reader, start_s, end_s))):
            try:
                rows.append(navsat_fields(Cursor(raw, ros2)))
            except (struct.error, UnicodeDecodeError) as exc:
                raise BagError(path, f"message {i} is malformed ({exc})", topic) from None
    if not rows:
        raise BagError(path, "no fixes" + (" in the window" if (start_s, end_s) != (None, None) else ""), topic)
    t = np.array([r[0] for r in rows], dtype=np.int64)
    order = np.argsort(t, kind="stable")
    rows = [rows[i] for i in order]
    geo = np.array([r[3:6] for r in rows], dtype=float)
    cov = np.array([r[6] for r in rows], dtype=float).reshape(-1, 3, 3)
    cov[np.array([r[7] for r in rows]) == COVARIANCE_UNKNOWN] = np.nan
    status = np.array([r[2] for r in rows], dtype=np.int8)
    fixed = status > STATUS_NO_FIX
    if not fixed.any():
        raise BagError(path, f"no fixes: each of its {len(rows)} messages says NO_FIX", topic)
    bad = fixed & ~np.all(np.isfinite(geo), axis=1)
    if bad.any():
        raise BagError(path, f"fix {int(np.argmax(bad))} has a NaN or infinite position", topic)
    for col, name in enumerate(("latitude_deg", "longitude_deg", "altitude_m")):
        r = bounds.SIGNALS[name]
        bad = fixed & ((geo[:, col] < r.lo) | (geo[:, col] > r.hi))
        if bad.any():
            k = int(np.argmax(bad))
            raise BagError(path, f"fix {k}: its {name.split('_')[0]} {geo[k, col]:.6g} is outside the sane range {r}",
                           topic)
    known = np.all(np.isfinite(cov), axis=(1, 2))
    r = bounds.SIGNALS["position_covariance_m2"]
    bad = known & np.any((cov < r.lo) | (cov > r.hi), axis=(1, 2))
    if bad.any():
        k = int(np.argmax(bad))
        worst = cov[k].flat[int(np.argmax(np.abs(cov[k])))]
        raise BagError(path, f"fix {k}: its position_covariance entry {worst:.6g} is outside the sane range {r}", topic)
    if known.any():
        ev = np.linalg.eigvalsh(0.5 * (cov[known] + np.swapaxes(cov[known], 1, 2)))
        if np.any(ev[:, 0] <= 0):
            k = int(np.flatnonzero(known)[np.argmax(ev[:, 0] <= 0)])
            raise BagError(path, f"fix {k}: its position_covariance is not positive definite", topic)
    return FixSeries(t[order], geo[:, 0], geo[:, 1], geo[:, 2], cov, status, rows[0][1])


def fix_log(fixes: FixSeries, t0_ns: int) -> SensorLog:
    """The fixes as a trajectory's log: the times of the messages that are fixes, in seconds from
    ``t0_ns`` (the stamp the trajectory's clock starts at), and their covariance (repeated
    stamps: the first)."""
    keep = fixes.fixed
    t = (fixes.t_ns[keep] - t0_ns).astype(float) * 1e-9
    cov = fixes.covariance[keep]
    first = np.r_[True, np.diff(t) > 0]
    return SensorLog(t[first], cov[first])


@dataclass(frozen=True)
class FixAgreement:
    """The fixes against the poses: how many fixes, their rate, the longest gap between fixes
    (an outage) and the RMS horizontal distance between the fixes and the poses after the best
    2-D rigid alignment (the poses' frame is not the fixes'), over the time both cover."""

    n_fixes: int
    rate_hz: float
    longest_gap_s: float
    horizontal_rms_m: float | None

    def text(self) -> str:
        rms = "—" if self.horizontal_rms_m is None else f"{self.horizontal_rms_m:.2f} m"
        return (f"{self.n_fixes} fixes at {self.rate_hz:.3g} Hz, longest gap {self.longest_gap_s:.2f} s; "
                f"horizontal RMS against the poses after a 2-D alignment {rms}")


def fix_agreement(traj: Trajectory, fixes: FixSeries, t0_ns: int) -> FixAgreement:
    """How the fixes of ``fixes`` (clock: seconds from ``t0_ns``) agree with ``traj``."""
    keep = fixes.fixed
    t = (fixes.t_ns[keep] - t0_ns).astype(float) * 1e-9
    gaps = np.diff(t)
    rate = float((t.size - 1) / (t[-1] - t[0])) if t.size > 1 and t[-1] > t[0] else 0.0
    inside = (t >= traj.t_start) & (t <= traj.t_end)
    rms = None
    if inside.sum() >= 3:
        a = fixes.enu()[keep][inside][:, :2]
        b = traj.sample(t[inside]).p_W_V[:, :2]
        a0, b0 = a - a.mean(axis=0), b - b.mean(axis=0)
        U, _, Vt = np.linalg.svd(b0.T @ a0)
        D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
        R = U @ D @ Vt
        rms = float(np.sqrt(np.mean(np.sum((a0 @ R.T - b0) ** 2, axis=1))))
    return FixAgreement(int(keep.sum()), rate, float(gaps.max()) if gaps.size else 0.0, rms)
