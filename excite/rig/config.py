"""Rig configuration: sensors, noise, what to estimate, accuracy targets.

A rig is a YAML file validated by pydantic; every error names the key. The IMU block uses
Kalibr's keys and units, and a Kalibr ``imu.yaml`` can be given by path (``imu: imu.yaml``).
Accuracy targets and priors accept plain SI numbers or strings with units (``"0.5 cm"``,
``"0.05 deg"``, ``"0.5 ms"``), keyed by parameter coordinate name or by a glob over names
(``"*.rot_*"``). Bundled rigs live in ``excite/rig/bundled/``; ``load_rig("robotaxi")`` reads one.
"""

from __future__ import annotations

import fnmatch
import functools
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from ..core import bounds, so3
from ..errors import RigError
from ..motion.vehicle import Suspension

RIGS_DIR = Path(__file__).parent / "bundled"

# unit → (SI factor, SI unit)
_UNITS: dict[str, tuple[float, str]] = {
    "m": (1.0, "m"), "cm": (1e-2, "m"), "mm": (1e-3, "m"),
    "rad": (1.0, "rad"), "mrad": (1e-3, "rad"), "deg": (math.pi / 180.0, "rad"),
    "s": (1.0, "s"), "ms": (1e-3, "s"), "us": (1e-6, "s"),
    "rad/s": (1.0, "rad/s"), "deg/s": (math.pi / 180.0, "rad/s"), "deg/h": (math.pi / 180.0 / 3600.0, "rad/s"),
    "m/s^2": (1.0, "m/s^2"), "mg": (9.80665e-3, "m/s^2"),
    "1": (1.0, "1"),
}
_QUANTITY = re.compile(r"^\s*([-+0-9.eE]+)\s*([a-zA-Z/^0-9]*)\s*$")


def parse_quantity(value: Any, unit: str, key: str) -> float:
    """A positive finite number in SI ``unit`` from a number or a ``"<number> <unit>"`` string."""
    if isinstance(value, bool):
        raise RigError(f"{key}: expected a number or '<number> <unit>', got {value!r}")
    if isinstance(value, (int, float)):
        x = float(value)
    elif isinstance(value, str):
        m = _QUANTITY.match(value)
        if not m:
            raise RigError(f"{key}: cannot read {value!r} as '<number> <unit>'")
        try:
            x = float(m.group(1))
        except ValueError:
            raise RigError(f"{key}: cannot read {value!r} as '<number> <unit>'") from None
        u = m.group(2) or unit
        if u not in _UNITS:
            raise RigError(f"{key}: unknown unit {u!r} (known: {', '.join(sorted(_UNITS))})")
        factor, si = _UNITS[u]
        if si != unit:
            raise RigError(f"{key}: unit {u!r} is not a unit of {unit}")
        x *= factor
    else:
        raise RigError(f"{key}: expected a number or '<number> <unit>', got {value!r}")
    if not math.isfinite(x) or x <= 0:
        raise RigError(f"{key}: must be positive and finite, got {value!r}")
    sane = bounds.QUANTITY.get(unit)
    if sane is not None and not sane.contains(x):
        raise RigError(f"{key}: {value!r} is outside the sane range {sane}")
    return x


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class Pose(_Model):
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
        return _rotation(self.rpy_deg, self.matrix).copy()

    @property
    def p(self) -> np.ndarray:
        return np.asarray(self.translation_m, dtype=float)


@functools.lru_cache(maxsize=1024)
def _rotation(rpy_deg: tuple | None, matrix: tuple | None) -> np.ndarray:
    """:attr:`Pose.R` of a pose's rotation fields (a matrix is re-orthonormalised)."""
    if matrix is not None:
        u, _, vt = np.linalg.svd(np.asarray(matrix, dtype=float))
        return u @ vt
    r, p, y = np.deg2rad(rpy_deg or (0.0, 0.0, 0.0))
    return so3.rot_z(y) @ so3.rot_y(p) @ so3.rot_x(r)


class ImuConfig(_Model):
    """IMU noise in Kalibr's keys and units (continuous-time densities)."""

    model_config = ConfigDict(extra="ignore", frozen=True)  # a Kalibr imu.yaml has rostopic etc.

    accelerometer_noise_density: PositiveFloat  # m/s^2/√Hz
    accelerometer_random_walk: PositiveFloat  # m/s^3/√Hz
    gyroscope_noise_density: PositiveFloat  # rad/s/√Hz
    gyroscope_random_walk: PositiveFloat  # rad/s^2/√Hz
    update_rate: PositiveFloat  # Hz
    estimate_biases: bool = True
    # random_walk: the biases drift with the *_random_walk densities and the report scores the
    # bias at the end of the drive; constant: one bias over the whole drive (shared by drives)
    bias_model: Literal["random_walk", "constant"] = "random_walk"


class SensorNoise(_Model):
    """Noise of one relative-pose measurement between consecutive frames of the sensor."""

    rotation_sigma_deg: PositiveFloat
    translation_sigma_m: PositiveFloat


class Estimate(_Model):
    extrinsic: bool = True
    time_offset: bool = True


class SensorConfig(_Model):
    """An exteroceptive sensor (lidar or camera odometry) rigidly mounted on the body."""

    name: str = Field(pattern=r"^[a-z][a-z0-9_]*$")
    kind: Literal["lidar", "camera"]
    rate_hz: PositiveFloat
    T_B_S: Pose
    noise: SensorNoise
    estimate: Estimate = Estimate()
    monocular: bool = False

    @model_validator(mode="after")
    def _mono_is_camera(self) -> "SensorConfig":
        if self.monocular and self.kind != "camera":
            raise ValueError("monocular applies to cameras only")
        return self


class WheelConfig(_Model):
    """Wheel encoders on the rear axle. ``noise_density`` [rad/s/√Hz]: white noise on each
    wheel's measured rate (quantisation, slip), so that a rotation increment over Δt has
    σ = noise_density·√Δt whatever the keyframe rate (the gyroscope's convention, Kalibr's units)."""

    radius_left_m: PositiveFloat
    radius_right_m: PositiveFloat
    track_m: PositiveFloat
    noise_density: PositiveFloat
    estimate: bool = True


class NonHolonomic(_Model):
    """The rear axle neither slides sideways nor lifts: lateral and vertical velocity ≈ 0, up to a
    white slip velocity of density ``*_noise_density`` [m/s/√Hz] (its information per second does
    not depend on how often the constraint is applied)."""

    lateral_noise_density: PositiveFloat = 0.05 / math.sqrt(10.0)
    vertical_noise_density: PositiveFloat = 0.05 / math.sqrt(10.0)


class SlipConfig(_Model):
    """Tyre slip, linear in the acceleration, estimated as nuisances of each drive (not scored):
    ``wheel.slip`` [1], the rear wheels' longitudinal slip ratio at 1 g of longitudinal
    acceleration (a driven wheel turns faster than it travels, a braking one slower), and
    ``vehicle.slip_angle`` [rad], the rear axle's slip angle at 1 g of lateral acceleration (in a
    turn the axle slides outwards at ``v·β``; vehicle engineers' cornering compliance, deg/g).
    Both are zero at the nominal point; a drive that never accelerates (or never turns) leaves
    them undetermined, which costs the scored parameters nothing."""

    estimate: bool = True


class SuspensionConfig(_Model):
    pitch_deg_per_mps2: float = Field(default=0.3, ge=0, allow_inf_nan=False)
    roll_deg_per_mps2: float = Field(default=0.5, ge=0, allow_inf_nan=False)


class VehicleConfig(_Model):
    T_V_B: Pose = Pose()  # pose of the IMU body frame B in the vehicle frame V (rear-axle centre)
    suspension: SuspensionConfig = SuspensionConfig()
    nonholonomic: NonHolonomic = NonHolonomic()
    slip: SlipConfig = SlipConfig()


class RigConfig(_Model):
    """The whole rig, as validated from YAML."""

    name: str = "rig"
    description: str = ""
    keyframe_rate_hz: PositiveFloat | None = None  # default: the fastest sensor's rate
    imu: ImuConfig
    vehicle: VehicleConfig = VehicleConfig()
    sensors: list[SensorConfig] = []
    wheels: WheelConfig | None = None
    targets: dict[str, float | str] = {}
    priors: dict[str, float | str] = {}

    @field_validator("sensors")
    @classmethod
    def _unique_names(cls, sensors: list[SensorConfig]) -> list[SensorConfig]:
        names = [s.name for s in sensors]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"sensor names must be unique, repeated: {', '.join(sorted(dup))}")
        if {"imu", "wheel"} & set(names):
            raise ValueError("'imu' and 'wheel' are reserved names")
        return sensors


@dataclass(frozen=True)
class Coordinate:
    """One column of the calibration parameter vector."""

    name: str  # e.g. "lidar.trans_z"
    unit: str  # SI unit
    block: str  # "lidar", "imu", "wheel", ...
    kind: str  # "rot", "trans", "time_offset", "gyro_bias", "accel_bias", "radius", "track", "scale",
    # "slip", "slip_angle"
    axis: int  # 0..2 for vector coordinates, else 0
    target: float  # required accuracy (1σ) in SI units; nan for nuisances
    prior_sigma: float | None = None
    nuisance: bool = False  # estimated but not scored (monocular scale, tyre slip)


@dataclass(frozen=True)
class Rig:
    """A validated rig with its parameter coordinates resolved (the column map)."""

    config: RigConfig
    coordinates: tuple[Coordinate, ...]
    keyframe_rate_hz: float

    @property
    def name(self) -> str:
        return self.config.name

    @property
    def suspension(self) -> Suspension:
        s = self.config.vehicle.suspension
        return Suspension(s.pitch_deg_per_mps2, s.roll_deg_per_mps2)

    @property
    def bias_random_walk(self) -> bool:
        """The IMU biases are estimated and drift as random walks (nuisance states per keyframe)."""
        imu = self.config.imu
        return imu.estimate_biases and imu.bias_model == "random_walk"

    def with_constant_biases(self) -> "Rig":
        """This rig with the IMU biases constant over each drive."""
        return self.with_config(imu=dict(self.config.imu.model_dump(), bias_model="constant"))

    @property
    def wheel_increment_sigma_rad(self) -> float:
        """σ of one wheel's rotation increment over a keyframe interval [rad]."""
        return self.config.wheels.noise_density / math.sqrt(self.keyframe_rate_hz)

    @property
    def nonholonomic_sigma_mps(self) -> tuple[float, float]:
        """σ of the lateral and vertical velocity of the rear axle sampled at every keyframe [m/s]:
        a white slip of density q sampled at rate f has σ = q·√f."""
        nh = self.config.vehicle.nonholonomic
        f = math.sqrt(self.keyframe_rate_hz)
        return nh.lateral_noise_density * f, nh.vertical_noise_density * f

    @property
    def scored(self) -> tuple[Coordinate, ...]:
        return tuple(c for c in self.coordinates if not c.nuisance)

    def index(self, name: str) -> int:
        return self._indices[name]

    @functools.cached_property
    def _indices(self) -> dict[str, int]:
        return {c.name: i for i, c in enumerate(self.coordinates)}

    def with_config(self, **changes: Any) -> "Rig":
        """A copy of this rig with top-level config fields replaced (validated again)."""
        data = self.config.model_dump()
        data.update(changes)
        return build_rig(data)


_AXES = "xyz"


def _coordinates(cfg: RigConfig) -> list[tuple[str, str, str, str, int, bool]]:
    """(name, unit, block, kind, axis, nuisance) of every estimated coordinate, in column order."""
    out = []
    for s in cfg.sensors:
        if s.estimate.extrinsic:
            out += [(f"{s.name}.rot_{a}", "rad", s.name, "rot", i, False) for i, a in enumerate(_AXES)]
            out += [(f"{s.name}.trans_{a}", "m", s.name, "trans", i, False) for i, a in enumerate(_AXES)]
        if s.estimate.time_offset:
            out.append((f"{s.name}.time_offset", "s", s.name, "time_offset", 0, False))
        if s.monocular:
            out.append((f"{s.name}.scale", "1", s.name, "scale", 0, True))
    if cfg.imu.estimate_biases:
        out += [(f"imu.gyro_bias_{a}", "rad/s", "imu", "gyro_bias", i, False) for i, a in enumerate(_AXES)]
        out += [(f"imu.accel_bias_{a}", "m/s^2", "imu", "accel_bias", i, False) for i, a in enumerate(_AXES)]
    if cfg.wheels is not None and cfg.wheels.estimate:
        out += [("wheel.radius_left", "m", "wheel", "radius", 0, False),
                ("wheel.radius_right", "m", "wheel", "radius", 1, False),
                ("wheel.track", "m", "wheel", "track", 0, False)]
    if cfg.vehicle.slip.estimate:
        if cfg.wheels is not None:
            out.append(("wheel.slip", "1", "wheel", "slip", 0, True))
        out.append(("vehicle.slip_angle", "rad", "vehicle", "slip_angle", 0, True))
    return out


def _lookup(table: dict[str, float | str], name: str) -> tuple[str, float | str] | None:
    """The entry for ``name``: an exact key wins over the most specific (longest) glob."""
    if name in table:
        return name, table[name]
    hits = [k for k in table if fnmatch.fnmatchcase(name, k)]
    if not hits:
        return None
    key = max(hits, key=len)
    return key, table[key]


def build_rig(data: dict[str, Any], base_dir: Path | None = None) -> Rig:
    """Validate a rig from its parsed YAML; ``base_dir`` resolves a Kalibr ``imu:`` file path."""
    if not isinstance(data, dict):
        raise RigError("rig: expected a mapping at the top level")
    if bounds.nesting(data) > bounds.MAX_NESTING:
        raise RigError(f"rig: nested more than {bounds.MAX_NESTING} levels deep (a rig is at most 6)")
    sensors = data.get("sensors")
    if isinstance(sensors, list) and len(sensors) > bounds.MAX_SENSORS:
        raise RigError(f"sensors: {len(sensors)} sensors, over the limit of {bounds.MAX_SENSORS}")
    data = dict(data)
    if isinstance(data.get("imu"), str):
        path = Path(data["imu"])
        if not path.is_absolute() and base_dir is not None:
            path = base_dir / path
        data["imu"] = _read_yaml(path)
    _refuse_per_keyframe_noise(data)
    try:
        cfg = RigConfig.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(p) for p in err["loc"]) or "rig"
        msg = "not a key of a rig file here" if err["type"] == "extra_forbidden" else err["msg"]
        raise RigError(f"{key}: {msg.removeprefix('Value error, ')}") from None
    for key, x in bounds.rig_numbers(cfg.model_dump()):
        sane = bounds.rig_range(key)
        if sane is not None and not sane.contains(x):
            raise RigError(f"{key}: {x!r} is outside the sane range {sane}")

    rates = [s.rate_hz for s in cfg.sensors]
    kf = cfg.keyframe_rate_hz or (max(rates) if rates else 10.0)
    which = ("keyframe rate" if cfg.keyframe_rate_hz else
             "keyframe rate (not given: the fastest sensor's)" if rates else "keyframe rate (not given: the default)")
    for i, s in enumerate(cfg.sensors):
        ratio = kf / s.rate_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise RigError(f"sensors.{i}.rate_hz: {s.rate_hz} Hz must divide the {which} "
                           f"{kf} Hz by a whole number")
    ratio = cfg.imu.update_rate / kf
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise RigError(f"imu.update_rate: {cfg.imu.update_rate} Hz must be a whole multiple of the "
                       f"{which} {kf} Hz")

    coords = []
    names = []
    for name, unit, block, kind, axis, nuisance in _coordinates(cfg):
        names.append(name)
        target = math.nan
        if not nuisance:
            hit = _lookup(cfg.targets, name)
            if hit is None:
                raise RigError(f"targets: no accuracy target for {name} (add '{name}: <value> <unit>' "
                               f"or a glob such as '*.{name.split('.', 1)[1]}')")
            target = parse_quantity(hit[1], unit, f"targets.{hit[0]}")
        prior = _lookup(cfg.priors, name)
        prior_sigma = None if prior is None else parse_quantity(prior[1], unit, f"priors.{prior[0]}")
        coords.append(Coordinate(name, unit, block, kind, axis, target, prior_sigma, nuisance))
    for table, label in ((cfg.targets, "targets"), (cfg.priors, "priors")):
        for key in table:
            if not any(fnmatch.fnmatchcase(n, key) for n in names):
                raise RigError(f"{label}.{key}: matches no estimated parameter "
                               f"(estimated: {', '.join(names)})")
    if not coords:
        raise RigError("rig: estimates no parameter at all")
    return Rig(cfg, tuple(coords), float(kf))


def _refuse_per_keyframe_noise(data: dict[str, Any]) -> None:
    """Rigs written before the noise densities gave wheel and slip noise per keyframe, which made
    the answer drift with the keyframe rate: name the replacement and its value at this rig's
    keyframe rate (the conversion that keeps the old numbers)."""
    kf = data.get("keyframe_rate_hz")
    kf_text = f"{kf:g} Hz" if isinstance(kf, (int, float)) and not isinstance(kf, bool) and kf > 0 else None
    wheels = data.get("wheels")
    if isinstance(wheels, dict) and "sigma_rad" in wheels:
        v = wheels["sigma_rad"]
        conv = (f"; at this rig's {kf_text} keyframes, sigma_rad: {v:g} is noise_density: {v * math.sqrt(kf):.4g}"
                if kf_text and isinstance(v, (int, float)) else " (noise_density = sigma_rad · √keyframe_rate_hz)")
        raise RigError("wheels.sigma_rad: per-keyframe wheel noise is replaced by wheels.noise_density "
                       f"[rad/s/√Hz], independent of the keyframe rate{conv}")
    nh = (data.get("vehicle") or {}).get("nonholonomic") if isinstance(data.get("vehicle"), dict) else None
    if isinstance(nh, dict):
        for axis in ("lateral", "vertical"):
            old = f"{axis}_sigma_mps"
            if old in nh:
                v = nh[old]
                conv = (f"; at this rig's {kf_text} keyframes, {old}: {v:g} is {axis}_noise_density: "
                        f"{v / math.sqrt(kf):.4g}" if kf_text and isinstance(v, (int, float))
                        else f" ({axis}_noise_density = {old} / √keyframe_rate_hz)")
                raise RigError(f"vehicle.nonholonomic.{old}: per-keyframe slip is replaced by "
                               f"vehicle.nonholonomic.{axis}_noise_density [m/s/√Hz], independent of the "
                               f"keyframe rate{conv}")


def _read_yaml(path: Path) -> Any:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise RigError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise RigError(f"{path}: not a text file ({exc.reason})") from None
    try:
        return yaml.safe_load(text)
    except RecursionError:
        raise RigError(f"{path}: nested more than {bounds.MAX_NESTING} levels deep") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise RigError(f"{path}{where}: not valid YAML ({getattr(exc, 'problem', exc)})") from None


def bundled_rigs() -> list[str]:
    """Names of the rigs shipped with excite."""
    return sorted(p.stem for p in RIGS_DIR.glob("*.yaml"))


def load_rig(name_or_path: str | Path = "robotaxi") -> Rig:
    """A bundled rig by name, or a rig YAML file by path."""
    path = Path(name_or_path)
    if not path.suffix and not path.exists():
        bundled = RIGS_DIR / f"{name_or_path}.yaml"
        if not bundled.exists():
            raise RigError(f"no bundled rig named {str(name_or_path)!r} (bundled: {', '.join(bundled_rigs())})")
        path = bundled
    data = _read_yaml(path)
    try:
        return build_rig(data, base_dir=path.parent)
    except RigError as exc:
        raise RigError(f"{path}: {exc}") from None


def rig_text(name_or_path: str | Path = "robotaxi") -> str:
    """The YAML text of a bundled rig or rig file, as written."""
    path = Path(name_or_path)
    if not path.suffix and not path.exists():
        load_rig(name_or_path)  # raises a clear error for unknown names
        path = RIGS_DIR / f"{name_or_path}.yaml"
    return path.read_text()
