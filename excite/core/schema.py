"""The pydantic pieces every configuration of excite is made of: a strict, frozen base model,
positive finite numbers, a rigid transform (:class:`Pose`), and what every ``sensors:`` entry of
a rig has (:class:`SensorEntry`). Each measurement kind (:mod:`excite.factors`) extends these for
its own entry; :mod:`excite.rig.config` assembles the rig from them."""

from __future__ import annotations

import functools
import math
from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from . import so3


class Model(BaseModel):
    """Strict (unknown keys are errors) and frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True)


PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class Pose(Model):
    """A rigid transform: translation [m] plus rotation as roll/pitch/yaw [deg] (R = Rz·Ry·Rx)
    or as a 3×3 matrix."""

    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] | None = None
    matrix: tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]] | None = None

    @model_validator(mode="after")
    def _one_rotation(self) -> "Pose":
        if self.rpy_deg is not None and self.matrix is not None:
            raise ValueError("give the rotation as rpy_deg or as matrix, not both")
        if not all(math.isfinite(x) for x in self.translation_m):
            raise ValueError("translation_m must be finite")
        if self.matrix is not None:
            R = np.asarray(self.matrix, dtype=float)
            if not np.all(np.isfinite(R)) or np.abs(R).max() > 1.001 or np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
                raise ValueError("matrix must be a proper rotation (orthonormal, det +1)")
        return self

    @property
    def R(self) -> np.ndarray:
        """The rotation matrix (computed once per distinct rotation; a fresh copy each time)."""
        return rotation_of(self.rpy_deg, self.matrix).copy()

    @property
    def p(self) -> np.ndarray:
        return np.asarray(self.translation_m, dtype=float)


@functools.lru_cache(maxsize=1024)
def rotation_of(rpy_deg: tuple | None, matrix: tuple | None) -> np.ndarray:
    """:attr:`Pose.R` of a pose's rotation fields (a matrix is re-orthonormalised)."""
    if matrix is not None:
        u, _, vt = np.linalg.svd(np.asarray(matrix, dtype=float))
        return u @ vt
    r, p, y = np.deg2rad(rpy_deg or (0.0, 0.0, 0.0))
    return so3.rot_z(y) @ so3.rot_y(p) @ so3.rot_x(r)


class Estimate(Model):
    """What of a sensor is estimated: its extrinsic (``T_B_S``) and its clock's time offset."""

    extrinsic: bool = True
    time_offset: bool = True


class SensorEntry(Model):
    """What every ``sensors:`` entry of a rig has: a name (its parameters' prefix), its ``kind``
    (which measurement kind reads it), its rate, its mounting ``T_B_S`` (pose of the sensor in the
    body frame) and what of it is estimated. Each kind's model adds its noise and the rest."""

    name: str = Field(pattern=r"^[a-z][a-z0-9_]*$")
    kind: str
    rate_hz: PositiveFloat
    T_B_S: Pose = Pose()
    estimate: Estimate = Estimate()
