"""Rigs from the calibration files users already have.

- **TF tree** of a bag's ``/tf_static`` (:func:`from_tree`; the bag is read by
  :func:`excite.io.bags.tf.rig_from_tf`): the IMU frame is the body frame B,
  ``T_V_B`` is the IMU in the base frame (V) and each sensor's ``T_B_S`` is its frame in the IMU
  frame, both composed over every hop of the tree. A frame named like a GNSS antenna (``gnss``,
  ``gps``, ``gnss_link``, ``gps/antenna`` …) becomes a ``kind: gnss`` sensor at its position (an
  antenna has no orientation), unless the antennas are named (``gnss=[…]``, ``[]`` for none).
- **Kalibr** (:func:`rig_from_kalibr`): a camchain (``camN.T_cam_imu``, the 4×4 transform of
  IMU-frame points into the camera frame, so ``T_B_S = T_cam_imu⁻¹``; ``timeshift_cam_imu`` with
  ``t_imu = t_cam + shift``) and the ``imu.yaml`` (noise densities, ``update_rate``) loaded as is.
- **Autoware** (:func:`rig_from_autoware`): ``sensor_kit_calibration.yaml`` (and optionally
  ``sensors_calibration.yaml``), ``parent: {child: {x, y, z, roll, pitch, yaw}}`` in metres and
  radians, ``R = Rz(yaw)·Ry(pitch)·Rx(roll)``, composed as a tree like TF.

What the files do not say (IMU noise where no ``imu.yaml`` is given, sensor rates and noise,
accuracy targets, the base frame of a Kalibr rig) is filled with defaults that
:func:`rig_yaml` marks ``# DEFAULT: review`` in the written YAML. Every rig is validated by
:func:`excite.rig.config.build_rig` before it is returned.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from .frames import Edge, static_transform
from ..errors import BagError, RigError
from ..factors.gnss import PRESETS
from .config import read_yaml, build_rig

__all__ = ["ImportedRig", "from_tree", "rig_from_kalibr", "rig_from_autoware", "rig_yaml",
           "DEFAULT_IMU", "DEFAULT_TARGETS"]

# A consumer MEMS IMU (datasheet class of a BMI088 / ICM-42688), Kalibr keys and units.
DEFAULT_IMU = {"accelerometer_noise_density": 2.0e-3, "accelerometer_random_walk": 3.0e-4,
               "gyroscope_noise_density": 1.7e-4, "gyroscope_random_walk": 2.0e-5,
               "update_rate": 200.0}
# drift densities of 0.1 deg and 1 cm per frame pair at 10 Hz (σ·√10)
_ODOMETRY_NOISE = {"rotation_density_deg_per_sqrt_s": 0.31622776601683794, "translation_density_m_per_sqrt_s": 0.0316227766016838}
DEFAULT_SENSOR = {"lidar": {"rate_hz": 10.0, "noise": dict(_ODOMETRY_NOISE)},
                  "camera": {"rate_hz": 10.0, "noise": dict(_ODOMETRY_NOISE)},
                  "gnss": {"rate_hz": 10.0, "noise": dict(PRESETS["standalone"])}}
_GNSS_FRAME = re.compile(r"(^|[/_])(gnss|gps)([/_]|$)", re.IGNORECASE)
DEFAULT_TARGETS = {"*.rot_*": "0.1 deg", "*.trans_*": "1 cm", "*.time_offset": "2 ms",
                   "imu.gyro_bias_*": "0.01 deg/s", "imu.accel_bias_*": "0.02 m/s^2"}


@dataclass
class ImportedRig:
    """A rig config (plain data, ready for YAML) and the keys filled with defaults."""

    config: dict[str, Any]
    defaults: set[str] = field(default_factory=set)  # dotted keys, e.g. "imu", "sensors.0.noise"
    notes: list[str] = field(default_factory=list)  # header comments (sources, what was read)


def _pose(R: np.ndarray, p: np.ndarray) -> dict[str, Any]:
    """A rig Pose: translation and the rotation matrix (exact; rpy would round)."""
    return {"translation_m": [float(x) for x in np.round(p, 9)],
            "matrix": [[float(x) for x in row] for row in np.round(R, 12)]}


def _sensor_name(kind: str, i: int, n: int) -> str:
    return kind if n == 1 else f"{kind}_{i + 1}"


def finish(cfg: dict[str, Any], defaults: set[str], notes: list[str]) -> ImportedRig:
    try:
        build_rig(cfg)
    except RigError as exc:
        raise RigError(f"the imported rig is not valid: {exc}") from None
    return ImportedRig(cfg, defaults, notes)


def gnss_frames(edges: dict[str, Any], exclude: set[str]) -> list[str]:
    """The frames of a tree named like a GNSS antenna (sorted), but those in ``exclude``."""
    frames = set(edges) | {e.parent for e in edges.values()}
    return sorted(f for f in frames - exclude if _GNSS_FRAME.search(f))


def from_tree(edges: dict[str, Any], source: Path, topic: str, imu: str, base: str,
               lidars: list[str], cameras: list[str], name: str,
               antennas: list[str] | None = None) -> tuple[dict, set[str], list[str]]:
    R_V_B, p_V_B = static_transform(source, edges, base, imu, topic)
    if antennas is None:
        antennas = gnss_frames(edges, {imu, base, *lidars, *cameras})
    sensors, defaults = [], {"imu"}
    for kind, frames in (("lidar", lidars), ("camera", cameras), ("gnss", antennas)):
        for i, frame in enumerate(frames):
            R, p = static_transform(source, edges, imu, frame, topic)
            k = len(sensors)
            pose = {"translation_m": _pose(R, p)["translation_m"]} if kind == "gnss" else _pose(R, p)
            sensors.append({"name": _sensor_name(kind, i, len(frames)), "kind": kind,
                            "rate_hz": DEFAULT_SENSOR[kind]["rate_hz"], "T_B_S": pose,
                            "noise": dict(DEFAULT_SENSOR[kind]["noise"])})
            defaults |= {f"sensors.{k}.rate_hz", f"sensors.{k}.noise"}
    targets = {k: v for k, v in DEFAULT_TARGETS.items()  # those that match a coordinate of this rig
               if not (k == "*.rot_*" and not (lidars or cameras)) and not (k.startswith("*.") and not sensors)}
    cfg = {"name": name, "imu": dict(DEFAULT_IMU),
           "vehicle": {"T_V_B": _pose(R_V_B, p_V_B)}, "sensors": sensors, "targets": targets}
    defaults.add("targets")
    return cfg, defaults, list(lidars) + list(cameras) + list(antennas)


def _matrix(value: Any, key: str) -> np.ndarray:
    try:
        T = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise RigError(f"{key}: expected a 4x4 matrix of numbers") from None
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise RigError(f"{key}: expected a 4x4 matrix of finite numbers, got shape {T.shape}")
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or np.linalg.det(R) <= 0:
        raise RigError(f"{key}: the 3x3 block is not a rotation")
    return T


def rig_from_kalibr(camchain: str | Path, imu_yaml: str | Path, *, name: str | None = None,
                    camera_rate_hz: float | None = None) -> ImportedRig:
    """A rig from a Kalibr camchain (``camN.T_cam_imu``, ``timeshift_cam_imu``) and ``imu.yaml``."""
    camchain, imu_yaml = Path(camchain), Path(imu_yaml)
    chain = read_yaml(camchain)
    if not isinstance(chain, dict) or not any(re.fullmatch(r"cam\d+", str(k)) for k in chain):
        raise RigError(f"{camchain}: expected a Kalibr camchain with cam0, cam1, ... at the top level")
    imu = read_yaml(imu_yaml)
    if not isinstance(imu, dict):
        raise RigError(f"{imu_yaml}: expected a Kalibr imu.yaml mapping")
    imu_cfg = {k: imu[k] for k in DEFAULT_IMU if k in imu}
    missing = [k for k in DEFAULT_IMU if k not in imu]
    if missing:
        raise RigError(f"{imu_yaml}: {missing[0]}: missing (a Kalibr imu.yaml has "
                       f"{', '.join(DEFAULT_IMU)})")
    sensors, defaults, notes = [], {"targets", "vehicle.T_V_B"}, [f"from Kalibr {camchain.name} + {imu_yaml.name}"]
    cams = sorted((k for k in chain if re.fullmatch(r"cam\d+", str(k))), key=lambda k: int(k[3:]))
    rate = camera_rate_hz or DEFAULT_SENSOR["camera"]["rate_hz"]
    for i, cam in enumerate(cams):
        entry = chain[cam]
        if not isinstance(entry, dict) or "T_cam_imu" not in entry:
            raise RigError(f"{camchain}: {cam}.T_cam_imu: missing (run Kalibr's camera-IMU calibration)")
        T = _matrix(entry["T_cam_imu"], f"{camchain}: {cam}.T_cam_imu")
        R_C_B, p_C_B = T[:3, :3], T[:3, 3]
        R_B_C = R_C_B.T
        sensors.append({"name": cam, "kind": "camera", "rate_hz": rate,
                        "T_B_S": _pose(R_B_C, -R_B_C @ p_C_B), "noise": dict(DEFAULT_SENSOR["camera"]["noise"])})
        if camera_rate_hz is None:
            defaults.add(f"sensors.{i}.rate_hz")
        defaults.add(f"sensors.{i}.noise")
        shift = entry.get("timeshift_cam_imu")
        if shift is not None:
            if not isinstance(shift, (int, float)) or not math.isfinite(shift):
                raise RigError(f"{camchain}: {cam}.timeshift_cam_imu: expected a number of seconds")
            notes.append(f"{cam}: nominal time offset {float(shift) * 1e3:.3f} ms (timeshift_cam_imu, "
                         "t_imu = t_cam + shift); the information model linearises about zero offset")
        topic = entry.get("rostopic")
        if topic:
            notes.append(f"{cam}: {topic}")
    cfg = {"name": name or "kalibr", "imu": imu_cfg, "vehicle": {"T_V_B": _pose(np.eye(3), np.zeros(3))},
           "sensors": sensors, "targets": dict(DEFAULT_TARGETS)}
    return finish(cfg, defaults, notes)


_AUTOWARE_KEYS = ("x", "y", "z", "roll", "pitch", "yaw")


def _autoware_edges(path: Path, edges: dict[str, Any]) -> None:
    data = read_yaml(path)
    if not isinstance(data, dict) or not data:
        raise RigError(f"{path}: expected 'parent: {{child: {{x, y, z, roll, pitch, yaw}}}}'")
    for parent, children in data.items():
        if not isinstance(children, dict):
            raise RigError(f"{path}: {parent}: expected a mapping of child frames")
        for child, pose in children.items():
            key = f"{parent}.{child}"
            if not isinstance(pose, dict):
                raise RigError(f"{path}: {key}: expected {{x, y, z, roll, pitch, yaw}}")
            missing = [k for k in _AUTOWARE_KEYS if k not in pose]
            if missing:
                raise RigError(f"{path}: {key}.{missing[0]}: missing")
            vals = []
            for k in _AUTOWARE_KEYS:
                v = pose[k]
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise RigError(f"{path}: {key}.{k}: expected a finite number, got {v!r}")
                vals.append(float(v))
            q = Rotation.from_euler("ZYX", vals[5:2:-1]).as_quat()  # yaw, pitch, roll
            edges[child] = Edge(str(parent), str(child), p=[tuple(vals[:3])], q=[tuple(q)])


def rig_from_autoware(sensor_kit: str | Path, *, imu: str, base: str, lidar: list[str] = (),
                      camera: list[str] = (), sensors_calibration: str | Path | None = None,
                      gnss: list[str] | None = None, name: str | None = None) -> ImportedRig:
    """A rig from Autoware's ``sensor_kit_calibration.yaml`` (plus ``sensors_calibration.yaml``
    that places the sensor kit on ``base_link``, when the base frame is outside the kit); GNSS
    antennas at the ``gnss`` frames (default: every frame named like one, as ``gnss_link``)."""
    sensor_kit = Path(sensor_kit)
    edges: dict[str, Any] = {}
    files = [sensor_kit] + ([Path(sensors_calibration)] if sensors_calibration else [])
    for f in files:
        _autoware_edges(f, edges)
    try:
        cfg, defaults, frames = from_tree(edges, sensor_kit, "calibration", imu, base, list(lidar),
                                           list(camera), name or "autoware", None if gnss is None else list(gnss))
    except BagError as exc:
        problem = exc.problem.removeprefix(f"topic {exc.topic}: ") if exc.topic else exc.problem
        raise RigError(f"{sensor_kit}: {problem.replace('on /tf or /tf_static', 'in the calibration files')}") from None
    notes = [f"from Autoware {', '.join(f.name for f in files)}: B = {imu}, V = {base}"]
    notes += [f"{s['name']} = {f}" for s, f in zip(cfg["sensors"], frames)]
    return finish(cfg, defaults, notes)


def _flow(value: Any) -> str:
    text = yaml.safe_dump(value, default_flow_style=True, width=10_000).strip()
    return text[:-3].rstrip() if text.endswith("\n...") else text  # a scalar's document end


def rig_yaml(rig: ImportedRig) -> str:
    """The rig as YAML, each defaulted key marked ``# DEFAULT: review``."""
    cfg, d = rig.config, rig.defaults
    mark = "   # DEFAULT: review"

    def tag(key: str) -> str:
        return mark if key in d else ""

    def pose(indent: str, p: dict[str, Any]) -> list[str]:
        return [f"{indent}{k}: {_flow(p[k])}" for k in ("translation_m", "matrix") if k in p]

    out = [f"# {n}" for n in rig.notes]
    out.append("# Keys marked 'DEFAULT: review' are not in the source files: check them before "
               "trusting a score.")
    out.append(f"name: {_flow(cfg['name'])}")
    out.append(f"imu:{tag('imu')}")
    out += [f"  {k}: {_flow(v)}" for k, v in cfg["imu"].items()]
    out += ["vehicle:", f"  T_V_B:{tag('vehicle.T_V_B')}", *pose("    ", cfg["vehicle"]["T_V_B"])]
    out.append("sensors:" if cfg["sensors"] else "sensors: []")
    for i, s in enumerate(cfg["sensors"]):
        out += [f"  - name: {s['name']}", f"    kind: {s['kind']}",
                f"    rate_hz: {_flow(s['rate_hz'])}{tag(f'sensors.{i}.rate_hz')}",
                "    T_B_S:", *pose("      ", s["T_B_S"]),
                f"    noise: {_flow(s['noise'])}{tag(f'sensors.{i}.noise')}"]
    out.append(f"targets:{tag('targets')}")
    out += [f"  {_flow(k)}: {_flow(v)}" for k, v in cfg["targets"].items()]
    return "\n".join(out) + "\n"
