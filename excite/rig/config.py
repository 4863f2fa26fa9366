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
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydantic import ConfigDict, Field, ValidationError, field_validator

from .. import factors  # noqa: F401  (registers the built-in measurement kinds)
from ..core import bounds
from .files import MAX_FILE_BYTES, SafeLoader
from ..core.schema import Model as _Model
from ..core.schema import Pose, PositiveFloat
from ..errors import RigError
from ..factors import base as registry
from ..factors.imu import ImuConfig
from ..factors.nonholonomic import NonHolonomic
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
    axle_height_m: PositiveFloat = 0.35  # the rear axle's centre above the road (a wheel's radius)
    suspension: SuspensionConfig = SuspensionConfig()
    nonholonomic: NonHolonomic = NonHolonomic()
    slip: SlipConfig = SlipConfig()


class RigConfig(_Model):
    """The whole rig, as validated from YAML. ``sensors`` holds each entry validated by its
    measurement kind's own model (:mod:`excite.factors`); a top-level section that a kind reads
    (``wheels``, …) is an extra field validated by that kind's model (:func:`build_rig`)."""

    model_config = ConfigDict(extra="allow", frozen=True)

    name: str = "rig"
    description: str = ""
    keyframe_rate_hz: PositiveFloat | None = None  # default: the fastest sensor's rate
    imu: ImuConfig
    vehicle: VehicleConfig = VehicleConfig()
    sensors: list[Any] = []
    targets: dict[str, float | str] = {}
    priors: dict[str, float | str] = {}

    @field_validator("sensors")
    @classmethod
    def _unique_names(cls, sensors: list[Any]) -> list[Any]:
        names = [s.get("name") if isinstance(s, dict) else getattr(s, "name", None) for s in sensors]
        names = [n for n in names if isinstance(n, str)]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"sensor names must be unique, repeated: {', '.join(sorted(dup))}")
        taken = set(_RESERVED) & set(names)
        if taken:
            raise ValueError(f"{', '.join(repr(n) for n in sorted(taken))}: reserved name(s) "
                             f"(reserved: {', '.join(sorted(_RESERVED))})")
        return sensors


_RESERVED = ("imu", "wheel", "vehicle", "nonholonomic", "steering")  # blocks of the vehicle's own parameters


@dataclass(frozen=True)
class Coordinate:
    """One column of the calibration parameter vector."""

    name: str  # e.g. "lidar.trans_z"
    unit: str  # SI unit
    block: str  # "lidar", "imu", "wheel", ...
    quantity: str  # "rot", "trans", "time_offset", "gyro_bias", "accel_bias", "radius", "track", "scale", …
    axis: int  # 0..2 for vector coordinates, else the axis its quantity reports (0)
    target: float  # required accuracy (1σ) in SI units; nan for nuisances
    prior_sigma: float | None = None
    nuisance: bool = False  # estimated but not scored (monocular scale, tyre slip)
    source: str = ""  # the measurement kind that declares it (excite.factors)


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
        return self.config.imu.bias_random_walk

    def with_constant_biases(self) -> "Rig":
        """This rig with the IMU biases constant over each drive."""
        return self.with_config(imu=dict(self.config.imu.model_dump(), bias_model="constant"))

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


def body_axes(R_V_B: np.ndarray) -> str:
    """Where B's axes point in V, in words: ``x forward, y left, z up`` (within 10°), else as
    vectors."""
    words = {0: ("forward", "backward"), 1: ("left", "right"), 2: ("up", "down")}
    out = []
    for i, axis in enumerate("xyz"):
        col = R_V_B[:, i]
        j = int(np.argmax(np.abs(col)))
        if abs(col[j]) >= math.cos(math.radians(10.0)):
            out.append(f"{axis} {words[j][0 if col[j] > 0 else 1]}")
        else:
            out.append(f"{axis} along ({col[0]:.2f}, {col[1]:.2f}, {col[2]:.2f})")
    return ", ".join(out)


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
    sensors = data.get("sensors")  # the bound that names what is too many, before the overall one
    if isinstance(sensors, list) and len(sensors) > bounds.MAX_SENSORS:
        raise RigError(f"sensors: {len(sensors)} sensors, over the limit of {bounds.MAX_SENSORS}")
    if bounds.size(data) > bounds.MAX_RIG_NODES:
        raise RigError(f"rig: more than {bounds.MAX_RIG_NODES} keys and list items (a rig of "
                       f"{bounds.MAX_SENSORS} sensors with a target per coordinate holds a few hundred)")
    data = dict(data)
    if isinstance(data.get("imu"), str):
        from .files import read_kalibr_imu  # Kalibr's input and output IMU files, OpenCV's header

        path = Path(data["imu"])
        if not path.is_absolute() and base_dir is not None:
            path = base_dir / path
        data["imu"] = read_kalibr_imu(path)[0]
    _refuse_per_keyframe_noise(data)
    try:
        cfg = RigConfig.model_validate(data)
    except ValidationError as exc:
        raise _rig_error(exc) from None
    cfg = _with_kinds(cfg)
    for key, x in bounds.rig_numbers(cfg.model_dump()):
        sane = rig_range(cfg, key)
        if sane is not None and not sane.contains(x):
            raise RigError(f"{key}: {x!r} is outside the sane range {sane}")

    rates = [s.rate_hz for s in cfg.sensors]
    kf = cfg.keyframe_rate_hz or (max(rates) if rates else 10.0)
    which = ("keyframe rate" if cfg.keyframe_rate_hz else
             "keyframe rate (not given: the fastest sensor's)" if rates else "keyframe rate (not given: the default)")
    for i, s in enumerate(cfg.sensors):
        ratio = kf / s.rate_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            fit = kf / math.ceil(ratio - 1e-9)
            why = (" (its noise is a drift density: σ does not change with the rate it is declared at)"
                   if s.kind in ("lidar", "camera") else "")
            raise RigError(f"sensors.{i}.rate_hz: {s.rate_hz:g} Hz must divide the {which} {kf:g} Hz by a whole "
                           f"number: declare {s.name} at {fit:g} Hz{why}, or set keyframe_rate_hz to a whole "
                           f"multiple of {s.rate_hz:g} Hz")
    ratio = cfg.imu.update_rate / kf
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        fit = kf * math.floor(ratio + 1e-9)
        fix = (f"declare the IMU at {fit:g} Hz (its noise densities hold at any rate) or set keyframe_rate_hz "
               f"to a rate dividing {cfg.imu.update_rate:g} Hz" if fit > 0 else
               f"set keyframe_rate_hz to a rate dividing {cfg.imu.update_rate:g} Hz")
        raise RigError(f"imu.update_rate: {cfg.imu.update_rate:g} Hz must be a whole multiple of the "
                       f"{which} {kf:g} Hz: {fix}")

    coords = []
    names = []
    sources = {q.block: k.name for k, _, q in registry.quantities(cfg)}
    columns = registry.columns(cfg)
    missing = [c for c in columns if not c.nuisance and _lookup(cfg.targets, c.name) is None]
    if missing:
        raise RigError(missing_targets(missing))
    for col in columns:
        name, unit = col.name, col.unit
        names.append(name)
        target = math.nan
        if not col.nuisance:
            hit = _lookup(cfg.targets, name)
            target = parse_quantity(hit[1], unit, f"targets.{hit[0]}")
        prior = _lookup(cfg.priors, name)
        prior_sigma = None if prior is None else parse_quantity(prior[1], unit, f"priors.{prior[0]}")
        coords.append(Coordinate(name, unit, col.block, col.quantity, col.axis, target, prior_sigma, col.nuisance,
                                 sources.get(col.block, "")))
    for table, label in ((cfg.targets, "targets"), (cfg.priors, "priors")):
        for key in table:
            if not any(fnmatch.fnmatchcase(n, key) for n in names):
                raise RigError(f"{label}.{key}: matches no estimated parameter "
                               f"(estimated: {', '.join(names)})")
    if not coords:
        raise RigError("rig: estimates no parameter at all")
    return Rig(cfg, tuple(coords), float(kf))


# An example accuracy per unit (per quantity where a unit is shared), for the lines an error offers
_EXAMPLE_TARGETS = {"m": "1 cm", "rad": "0.1 deg", "s": "1 ms", "rad/s": "0.01 deg/s", "m/s^2": "0.02 m/s^2",
                    "1": "0.001", ("ratio", "1"): "0.1"}


def missing_targets(columns: list[Any]) -> str:
    """The error for parameters without a target: all of them named, and the lines to paste
    under ``targets:`` (one glob per sensor and quantity; the values are examples)."""
    groups: dict[tuple[str, str], list[Any]] = {}
    for c in columns:
        groups.setdefault((c.block, c.quantity), []).append(c)
    lines = []
    for (block, _), cols in groups.items():
        suffixes = [c.name.split(".", 1)[1] for c in cols]
        if len(cols) == 1:
            key = cols[0].name
        else:
            stem = os.path.commonprefix(suffixes)
            key = f"{block}.{stem.rsplit('_', 1)[0] + '_' if '_' in stem else stem}*"
        value = _EXAMPLE_TARGETS.get((cols[0].quantity, cols[0].unit), _EXAMPLE_TARGETS.get(cols[0].unit, "<value>"))
        lines.append(f'  "{key}": {value}')
    names = ", ".join(c.name for c in columns)
    return (f"targets: no accuracy target for {len(columns)} parameter{'s' if len(columns) > 1 else ''} "
            f"({names}); add under targets: (example values: put the accuracy you need)\n" + "\n".join(lines))


def _rig_error(exc: ValidationError, prefix: str = "") -> RigError:
    """The first error of a validation, as a rig error naming its key."""
    err = exc.errors()[0]
    key = prefix + ".".join(str(p) for p in err["loc"]) or "rig"
    msg = "not a key of a rig file here" if err["type"] == "extra_forbidden" else err["msg"]
    return RigError(f"{key.rstrip('.') or 'rig'}: {msg.removeprefix('Value error, ')}")


def _with_kinds(cfg: RigConfig) -> RigConfig:
    """``cfg`` with every ``sensors:`` entry validated by the model of the kind that measures it,
    and every extra top-level section by the kind that reads it (any other key is an error)."""
    sensors = []
    for i, s in enumerate(cfg.sensors):
        if not isinstance(s, dict):
            raise RigError(f"sensors.{i}: expected a mapping (name, kind, rate_hz, …), got {type(s).__name__}")
        kind = registry.kind_of_sensor(s.get("kind")) if isinstance(s.get("kind"), str) else None
        if kind is None:
            raise RigError(f"sensors.{i}.kind: {s.get('kind')!r} is not a sensor kind here "
                           f"(known: {', '.join(registry.sensor_kinds())})")
        try:
            sensors.append(kind.config.model_validate(s))
        except ValidationError as exc:
            raise _rig_error(exc, f"sensors.{i}.") from None
    sections = {}
    for key, value in (cfg.model_extra or {}).items():
        kind = registry.kind_of_section(key)
        if kind is None:
            raise RigError(f"{key}: not a key of a rig file here")
        if value is None:
            continue
        try:
            sections[key] = kind.config.model_validate(value)
        except ValidationError as exc:
            raise _rig_error(exc, f"{key}.") from None
    absent = {k.section: None for k in registry.kinds()  # an absent section reads as None
              if k.section is not None and k.section not in RigConfig.model_fields and k.section not in sections}
    return cfg.model_copy(update={"sensors": sensors, **absent, **sections})


def all_ranges() -> dict[str, bounds.Range]:
    """The sane range of every numeric rig key, by dotted glob: the rig's own
    (:data:`excite.core.bounds.RIG`) and every registered kind's (``sensors.*.…`` for a sensor's,
    ``<section>.…`` for a section's)."""
    out = dict(bounds.RIG)
    for kind in registry.kinds():
        prefix = "sensors.*." if kind.sensor_kinds else f"{kind.section}." if kind.section else None
        if prefix is not None:
            out.update({prefix + k: r for k, r in kind.ranges.items()})
    return out


def rig_range(cfg: RigConfig, key: str) -> bounds.Range | None:
    """The sane range of a dotted rig key: its kind's (``sensors.0.noise.rotation_density_deg_per_sqrt_s``,
    ``wheels.track_m``, ``imu.update_rate``), or the rig's own (:data:`excite.core.bounds.RIG`)."""
    head, _, rest = key.partition(".")
    kind = None
    if head == "sensors":
        index, _, rest = rest.partition(".")
        if index.isdigit() and int(index) < len(cfg.sensors):
            kind = registry.kind_of_sensor(cfg.sensors[int(index)].kind)
    else:
        kind = registry.kind_of_section(head)
    if kind is not None and rest in kind.ranges:
        return kind.ranges[rest]
    return bounds.rig_range(key)


_PER_PAIR_NOISE = {"rotation_sigma_deg": ("rotation_density_deg_per_sqrt_s", "deg/√s"),
                   "translation_sigma_m": ("translation_density_m_per_sqrt_s", "m/√s")}


def _refuse_per_keyframe_noise(data: dict[str, Any]) -> None:
    """Rigs written before the noise densities gave wheel and slip noise per keyframe, and lidar
    and camera odometry noise per frame pair, which made the answer drift with the keyframe or
    frame rate: name the replacement and its value at this rig's keyframe rate or the sensor's
    rate (the conversion that keeps the old numbers)."""
    sensors = data.get("sensors")
    for i, s in enumerate(sensors if isinstance(sensors, list) else []):
        noise = s.get("noise") if isinstance(s, dict) else None
        if not isinstance(noise, dict):
            continue
        for old, (new, unit) in _PER_PAIR_NOISE.items():
            if old in noise:
                v, rate = noise[old], s.get("rate_hz")
                known = all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in (v, rate))
                conv = (f"; at this sensor's {rate:g} Hz, {old}: {v:g} is {new}: {v * math.sqrt(rate):.6g}"
                        if known and rate > 0 else f" ({new} = {old} · √rate_hz)")
                raise RigError(f"sensors.{i}.noise.{old}: per-frame-pair odometry noise is replaced by "
                               f"sensors.{i}.noise.{new} [{unit}], a drift density independent of the "
                               f"frame rate{conv}")
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


def read_yaml(path: Path) -> Any:
    try:
        size = Path(path).stat().st_size
        if size > MAX_FILE_BYTES:
            raise RigError(f"{path}: {size:,} bytes, over the limit of {MAX_FILE_BYTES:,} for a rig file")
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise RigError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise RigError(f"{path}: not a text file ({exc.reason})") from None
    try:
        return yaml.load(text, Loader=SafeLoader)  # noqa: S506 (a safe loader)
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
    try:
        return build_rig(read_yaml(path), base_dir=path.parent)
    except RigError as exc:
        from .files import hint  # another tool's file: name the command that imports it

        told = hint(path)
        if told is not None:
            raise RigError(f"{path}: {told}") from None
        raise RigError(str(exc) if str(exc).startswith(f"{path}") else f"{path}: {exc}") from None


def rig_text(name_or_path: str | Path = "robotaxi") -> str:
    """The YAML text of a bundled rig or rig file, as written."""
    path = Path(name_or_path)
    if not path.suffix and not path.exists():
        load_rig(name_or_path)  # raises a clear error for unknown names
        path = RIGS_DIR / f"{name_or_path}.yaml"
    return path.read_text()
