"""Timed poses as logged, not smoothed (an odometry's error is what its drift densities are
measured from): a pose topic or TF chain of a bag, a TUM file, or an EuRoC ground-truth CSV, as
:class:`excite.rig.noise.TimedPoses` with times in seconds on the file's own clock."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import RouteError
from ..rig.noise import TimedPoses
from .bags import is_bag, read_poses
from .poses import MIN_POSES
from .poses import QUAT_NORM_TOL
from .routes import document, numbers, split_rows


def read_timed_poses(path: str | Path, topic: str | None = None) -> TimedPoses:
    """The poses of a bag's ``topic``, or of a TUM (``t tx ty tz qx qy qz qw``) or EuRoC CSV file."""
    path = Path(path)
    if is_bag(path):
        if topic is None:
            raise RouteError("a bag: name its pose topic (or a TF chain /tf:PARENT.CHILD)", source=str(path))
        s = read_poses(path, topic)
        return TimedPoses(s.t_ns.astype(float) * 1e-9, s.R, s.p, topic.strip("/"))
    if topic is not None:
        raise RouteError(f"a topic ({topic}) is for a bag; this is a file of poses", source=str(path))
    doc = document(path)
    if path.suffix.lower() == ".csv":
        table = split_rows(doc, ",")
        d = numbers(table, None)
        if d.shape[1] < 8:
            raise RouteError(f"expected at least 8 columns (timestamp, p_xyz, q_wxyz), got {d.shape[1]}",
                             source=table.source, line=table.lines[0])
        ns = np.array([int(float(r[0])) for r in table.rows], dtype=np.int64)
        t = (ns - ns[0]).astype(float) * 1e-9 + float(ns[0]) * 1e-9
        R = Rotation.from_quat(_unit(d[:, 4:8], table), scalar_first=True).as_matrix()
    else:
        table = split_rows(doc, None)
        d = numbers(table, (8,))
        t = d[:, 0]
        R = Rotation.from_quat(_unit(d[:, 4:8], table)).as_matrix()
    if len(d) < MIN_POSES:
        raise RouteError(f"too few poses: {len(d)}, need at least {MIN_POSES}", source=table.source)
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0)) + 1
        raise RouteError(f"times must increase: {t[k]:.9g} s after {t[k - 1]:.9g} s", source=table.source,
                         line=table.lines[k])
    return TimedPoses(t, R, d[:, 1:4], path.stem)


def _unit(q: np.ndarray, table) -> np.ndarray:
    norm = np.linalg.norm(q, axis=1)
    bad = np.abs(norm - 1.0) > QUAT_NORM_TOL
    if bad.any():
        k = int(np.argmax(bad))
        raise RouteError(f"quaternion norm {norm[k]:.6g}, not 1 (tolerance {QUAT_NORM_TOL:g})", source=table.source,
                         line=table.lines[k])
    return q / norm[:, None]
