"""Which tool's file a path holds, told from its keys: for a file given where a rig is expected,
the import command that reads it."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from ...errors import RigError
from . import common


def _has(data: Any, key: str, depth: int = 3) -> bool:
    return common.find_key(data, key, depth) is not None


def detect(path: str | Path) -> tuple[str, str] | None:
    """(what the file is, the command that imports it), or None when it is none of the formats."""
    path = Path(path)
    try:
        text = common.read_text(path)
    except RigError:
        return None
    head = text.lstrip()[:2000]
    if head.startswith("<?xml") or head.startswith("<robot") or "<robot" in head:
        if path.suffix == ".xacro" or "xmlns:xacro" in head:
            return "xacro", f"xacro {path.name} > robot.urdf, then `excite rig from-urdf robot.urdf --imu LINK`"
        return "URDF", f"excite rig from-urdf {path} --imu LINK"
    try:
        data = common.load_yaml(path, text)
    except RigError:
        return None
    if not isinstance(data, dict) or {"sensors", "targets", "vehicle"} & set(data):
        return None  # not a mapping, or a rig (whose own error is the one to read)
    if any(isinstance(v, dict) and ("T_cam_imu" in v or "T_imu_cam" in v) for v in data.values()):
        return "Kalibr camchain", f"excite rig from-kalibr {path} IMU_YAML"
    if "accelerometer_noise_density" in data or any(
            re.fullmatch(r"imu\d+", str(k)) and isinstance(v, dict) and "accelerometer_noise_density" in v
            for k, v in data.items()):
        return "Kalibr IMU", f"excite rig from-kalibr CAMCHAIN {path}"
    if "body_T_cam0" in data:
        return "VINS-Fusion", f"excite rig from-vins {path}"
    if _has(data, "extrinsicRot"):
        return "LIO-SAM", f"excite rig from-lio-sam {path}"
    if _has(data, "extrinsic_R"):
        return "FAST-LIO" + ("/FAST-LIVO" if _has(data, "Rcl") else ""), f"excite rig from-fast-lio {path}"
    children = [c for v in data.values() if isinstance(v, dict) for c in v.values()]
    if children and all(isinstance(c, dict) and {"x", "y", "z", "roll", "pitch", "yaw"} <= set(c) for c in children):
        return "Autoware calibration", f"excite rig from-autoware {path}"
    return None


def hint(path: str | Path) -> str | None:
    """``this is a … file: `excite rig from-… FILE``` for a file of one of the formats."""
    found = detect(path)
    if found is None:
        return None
    what, command = found
    also = (f" (or name it as a rig's IMU block: `imu: {Path(path).name}`)" if what == "Kalibr IMU" else "")
    return f"this is {'an' if what[0] in 'AEIO' else 'a'} {what} file, not a rig: `{command}` writes a rig from it{also}"
