"""Geographic coordinates: the local frame of a georeferenced lot, route or scene.

A drive, a lot and a scene given in lon/lat (WGS84) are worked on in local metres (x east, y
north) of a transverse Mercator projection about an origin (pyproj): the lot's, where there is
one (the mean of its outline's vertices), so that a plan, its cones and the scene around it share
one frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Projection:
    """Transverse Mercator about ``origin`` (lon, lat): the local frame (x east, y north) of a
    georeferenced lot, as :func:`excite.io.routes.read_geojson` projects."""

    origin: tuple[float, float]

    def _tm(self, inverse: bool):
        from pyproj import Transformer

        lon0, lat0 = self.origin
        crs = (f"+proj=tmerc +lat_0={lat0!r} +lon_0={lon0!r} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m")
        return Transformer.from_crs(crs, "EPSG:4326", always_xy=True) if inverse else \
            Transformer.from_crs("EPSG:4326", crs, always_xy=True)

    def to_local(self, lonlat: np.ndarray) -> np.ndarray:
        x, y = self._tm(False).transform(lonlat[:, 0], lonlat[:, 1])
        return np.column_stack([x, y])

    def to_lonlat(self, xy: np.ndarray) -> np.ndarray:
        lon, lat = self._tm(True).transform(xy[:, 0], xy[:, 1])
        return np.column_stack([lon, lat])


