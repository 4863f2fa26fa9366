"""A planned maneuver as a file: TUM poses, waypoints CSV, control CSV or GeoJSON.

The job stores the control profile; the drive is rebuilt with the rig's suspension and written
by :mod:`excite.io.routes`. GeoJSON (WGS84 lon/lat) needs the lot's origin: the inverse of the
projection :func:`excite.io.routes.read_geojson` uses, so the file reads back to the same drive.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from excite.io import routes
from excite.rig.config import Rig
from excite.motion.vehicle import ControlProfile, drive

FILES = {"tum": ("text/plain", "tum"), "csv": ("text/csv", "csv"), "control": ("text/csv", "control.csv"),
         "geojson": ("application/geo+json", "geojson")}  # each format's media type and file suffix


def maneuver_file(profile: dict[str, Any], rig: Rig, fmt: str, name: str,
                  origin: tuple[float, float] | None = None) -> str:
    """The text of the maneuver (a stored :class:`ControlProfile`) in ``fmt`` (tum | csv | control | geojson)."""
    from excite.plan.site import maneuver_geojson

    prof = ControlProfile(**{**profile, "start": tuple(profile["start"])})
    with tempfile.TemporaryDirectory(prefix="excite-") as tmp:
        path = Path(tmp) / f"{name}.{FILES[fmt][1]}"
        if fmt == "control":
            return routes.write_control_csv(prof, path).read_text()
        traj = drive(prof, rig.suspension)
        traj.name = name
        if fmt == "tum":
            return routes.write_tum(traj, path).read_text()
        text = routes.write_waypoints_csv(traj, path).read_text()
        if fmt == "csv":
            return text
        xyzv = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
        return maneuver_geojson(xyzv[:, :3], xyzv[:, 3], origin, name)
