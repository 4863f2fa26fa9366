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

MEDIA = {"tum": "text/plain", "csv": "text/csv", "control": "text/csv",
         "geojson": "application/geo+json"}
SUFFIX = {"tum": ".tum", "csv": ".csv", "control": ".csv", "geojson": ".geojson"}


def profile_of(data: dict[str, Any]) -> ControlProfile:
    return ControlProfile(t_s=np.asarray(data["t_s"]), speed_mps=np.asarray(data["speed_mps"]),
                          curvature_1pm=np.asarray(data["curvature_1pm"]),
                          grade_rad=None if data.get("grade_rad") is None else np.asarray(data["grade_rad"]),
                          bank_rad=None if data.get("bank_rad") is None else np.asarray(data["bank_rad"]),
                          start=tuple(data.get("start") or (0.0, 0.0, 0.0)),
                          name=data.get("name") or "maneuver")


def maneuver_file(profile: dict[str, Any], rig: Rig, fmt: str, name: str,
                  origin: tuple[float, float] | None = None) -> str:
    """The text of the maneuver in ``fmt`` (tum | csv | control | geojson)."""
    prof = profile_of(profile)
    with tempfile.TemporaryDirectory(prefix="excite-") as tmp:
        path = Path(tmp) / f"{name}{SUFFIX[fmt]}"
        if fmt == "control":
            routes.write_control_csv(prof, path)
            return path.read_text()
        traj = drive(prof, rig.suspension)
        traj.name = name
        if fmt == "tum":
            routes.write_tum(traj, path)
            return path.read_text()
        routes.write_waypoints_csv(traj, path)
        if fmt == "csv":
            return path.read_text()
        assert origin is not None
        xyzv = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
        return _geojson(xyzv, origin, name)


def _geojson(xyzv: np.ndarray, origin: tuple[float, float], name: str) -> str:
    from excite.plan.site import maneuver_geojson

    return maneuver_geojson(xyzv[:, :3], xyzv[:, 3], origin, name)
