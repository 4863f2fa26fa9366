"""What a lidar's beams and a camera's optics are: what a scene is ray-cast with
(:mod:`excite.scene.lidar`, :mod:`excite.scene.camera`).

A rig's lidar entry may name a preset (``beams: vlp16``) or give its pattern: the vertical angles
of its beams (or their count and vertical field of view, evenly spaced), its horizontal
resolution and field of view, its range limits and its range noise. The presets' numbers are the
manufacturers' datasheet figures; their range accuracy is taken as the range noise σ (datasheets
state a typical accuracy, not a σ: this errs on the pessimistic side), and the vertical angles of
the sensors whose beams are not evenly spaced are spread evenly over their field (their real
pattern is denser near the horizon).

``correlation_deg``: the angle within which a lidar's range errors are correlated (the beam's
footprint and the surface's roughness): points closer than this count as one measurement of the
surface, so that a finer pattern does not invent information the surface cannot give.

A rig's camera entry may give its optics (``optics: {width_px: 1280, …}``): the image's size and
focal length (a pinhole with the principal point at the image's centre; the entry's ``T_B_S`` is
the optical frame, z forward, x right, y down), the features' pixel noise, the range within
which features are tracked and the detector's budget of features per frame. Without one, a
camera is :data:`DEFAULT_CAMERA`: a 1920 × 1080 automotive camera of 1000 px focal length (88° ×
57° field of view), 1 px noise, features tracked from 0.5 to 80 m, 2000 per frame.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from ..core.schema import Model, PositiveFloat


class LidarBeams(Model):
    """A lidar's beam pattern, its range limits and noise (see the module docstring)."""

    vertical_angles_deg: tuple[float, ...] | None = Field(None, min_length=1, max_length=512)
    channels: int | None = Field(None, ge=1, le=512)
    vertical_fov_deg: tuple[float, float] | None = None
    horizontal_resolution_deg: float = Field(0.2, gt=0.0, le=10.0)
    horizontal_fov_deg: float = Field(360.0, gt=0.0, le=360.0)
    min_range_m: float = Field(0.5, ge=0.0, le=100.0)
    max_range_m: float = Field(100.0, gt=0.0, le=2000.0)
    range_noise_m: PositiveFloat = 0.03
    correlation_deg: float = Field(0.5, gt=0.0, le=10.0)

    @model_validator(mode="after")
    def _pattern(self) -> "LidarBeams":
        if self.vertical_angles_deg is None and (self.channels is None or self.vertical_fov_deg is None):
            raise ValueError("give vertical_angles_deg, or channels and vertical_fov_deg")
        if self.vertical_angles_deg is not None and (self.channels is not None or self.vertical_fov_deg is not None):
            raise ValueError("give vertical_angles_deg or channels and vertical_fov_deg, not both")
        if self.vertical_fov_deg is not None and not (-90.0 <= self.vertical_fov_deg[0] < self.vertical_fov_deg[1] <= 90.0):
            raise ValueError("vertical_fov_deg: (lowest, highest) within −90 … 90 degrees, lowest first")
        if self.vertical_angles_deg is not None and not all(-90.0 <= a <= 90.0 for a in self.vertical_angles_deg):
            raise ValueError("vertical_angles_deg: every angle within −90 … 90 degrees")
        if self.max_range_m <= self.min_range_m:
            raise ValueError("max_range_m must exceed min_range_m")
        return self

    @property
    def elevations_rad(self) -> np.ndarray:
        """The beams' elevation angles, lowest first [rad]."""
        if self.vertical_angles_deg is not None:
            return np.radians(np.sort(np.asarray(self.vertical_angles_deg, float)))
        lo, hi = self.vertical_fov_deg
        return np.radians(np.linspace(lo, hi, self.channels) if self.channels > 1 else np.array([0.5 * (lo + hi)]))

    @property
    def beam_spacing_rad(self) -> float:
        """The median angle between neighbouring beams (the field's height for a single beam)."""
        e = self.elevations_rad
        return float(np.median(np.diff(e))) if e.size > 1 else np.radians(self.correlation_deg)


def _even(channels: int, lo: float, hi: float, res: float, max_range: float, noise: float) -> LidarBeams:
    return LidarBeams(channels=channels, vertical_fov_deg=(lo, hi), horizontal_resolution_deg=res,
                      max_range_m=max_range, range_noise_m=noise)


LIDAR_PRESETS: dict[str, LidarBeams] = {
    # Velodyne VLP-16 (Puck): 16 beams over ±15°, 0.2° at 10 Hz, 100 m, ±3 cm
    "vlp16": _even(16, -15.0, 15.0, 0.2, 100.0, 0.03),
    # Velodyne VLP-32C (Ultra Puck): 32 beams over −25 … +15°, 0.2° at 10 Hz, 200 m, ±3 cm
    "vlp32c": _even(32, -25.0, 15.0, 0.2, 200.0, 0.03),
    # Velodyne HDL-32E: 32 beams over −30.67 … +10.67° (1.33° apart), 0.16° at 10 Hz, 100 m, ±2 cm
    "hdl32e": _even(32, -30.67, 10.67, 0.16, 100.0, 0.02),
    # Velodyne HDL-64E: 64 beams over −24.9 … +2°, 0.17° at 10 Hz, 120 m, ±2 cm
    "hdl64e": _even(64, -24.9, 2.0, 0.17, 120.0, 0.02),
    # Ouster OS1-64 and OS1-128: 64 / 128 beams over ±22.5°, 2048 columns (0.176°), 120 m, ±3 cm
    "os1_64": _even(64, -22.5, 22.5, 0.176, 120.0, 0.03),
    "os1_128": _even(128, -22.5, 22.5, 0.176, 120.0, 0.03),
}
"""Beam patterns of common lidars by name (the rig's ``beams:`` may name one)."""

DEFAULT_LIDAR = "vlp32c"
"""The pattern of a lidar whose rig entry names none."""


def lidar_beams(value: "LidarBeams | str | None") -> LidarBeams:
    """The beam pattern a rig entry's ``beams`` stands for (a preset's name, a pattern, or None:
    :data:`DEFAULT_LIDAR`)."""
    if value is None:
        return LIDAR_PRESETS[DEFAULT_LIDAR]
    if isinstance(value, str):
        return LIDAR_PRESETS[value]
    return value


class CameraOptics(Model):
    """A camera's image, focal length, pixel noise, tracking range and feature budget (see the
    module docstring)."""

    width_px: int = Field(1920, ge=16, le=20000)
    height_px: int = Field(1080, ge=16, le=20000)
    focal_px: float = Field(1000.0, ge=1.0, le=1e5)
    pixel_noise_px: PositiveFloat = 1.0
    min_range_m: float = Field(0.5, ge=0.0, le=100.0)
    max_range_m: float = Field(80.0, gt=0.0, le=2000.0)
    max_features: int = Field(2000, ge=1, le=100000)

    @model_validator(mode="after")
    def _ranges(self) -> "CameraOptics":
        if self.max_range_m <= self.min_range_m:
            raise ValueError("max_range_m must exceed min_range_m")
        return self

    @property
    def bearing_sigma(self) -> float:
        """σ of a feature's normalized image coordinates, per axis (pixel noise / focal length)."""
        return self.pixel_noise_px / self.focal_px

    @property
    def half_extent(self) -> tuple[float, float]:
        """The image's half width and half height in normalized image coordinates (x/z, y/z)."""
        return 0.5 * self.width_px / self.focal_px, 0.5 * self.height_px / self.focal_px


DEFAULT_CAMERA = CameraOptics()
"""The optics of a camera whose rig entry gives none."""
