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
from .routes import _check_count, _check_times, _quaternions, document, numbers, split_rows


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
        q = _quaternions(d[:, 4:8], table.source, table.lines, 5)
        R = Rotation.from_quat(q, scalar_first=True).as_matrix()
    else:
        table = split_rows(doc, None)
        d = numbers(table, (8,))
        t = d[:, 0]
        R = Rotation.from_quat(_quaternions(d[:, 4:8], table.source, table.lines, 5)).as_matrix()
    _check_count(len(d), MIN_POSES, "poses", table.source, table.lines)
    _check_times(t, table.source, table.lines)
    return TimedPoses(t, R, d[:, 1:4], path.stem)
