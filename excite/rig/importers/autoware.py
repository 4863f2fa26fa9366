"""Autoware's sensor-kit calibration: ``sensor_kit_calibration.yaml`` (the sensors on
``sensor_kit_base_link``) and ``sensors_calibration.yaml`` (the kit, and sensors outside it, on
``base_link``): ``parent: {child: {x, y, z, roll, pitch, yaw}}`` in metres and radians,
``R = Rz(yaw)·Ry(pitch)·Rx(roll)``, composed as a tree like TF.

Every leaf frame of the files is a sensor: without ``lidar``/``camera`` given, each is placed by
what its name says (``velodyne_*``, ``livox_*`` … lidars, ``camera*`` cameras, ``gnss*`` the
antenna, the one ``*imu*`` frame the body frame B) and named after its frame (``velodyne_top``,
``camera0``). The base frame V is ``base_link`` when the files hold it, else the tree's root.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ...errors import RigError
from . import common
from .tree import Hop, Tree, classify, rig_from_tree

_KEYS = ("x", "y", "z", "roll", "pitch", "yaw")


def _hops(path: Path) -> list[Hop]:
    data = common.load_yaml(path)
    if not isinstance(data, dict) or not data:
        raise RigError(f"{path}: expected 'parent: {{child: {{x, y, z, roll, pitch, yaw}}}}'")
    hops = []
    for parent, children in data.items():
        if not isinstance(children, dict):
            raise RigError(f"{path}: {parent}: expected a mapping of child frames")
        for child, pose in children.items():
            key = f"{parent}.{child}"
            if not isinstance(pose, dict):
                raise RigError(f"{path}: {key}: expected {{x, y, z, roll, pitch, yaw}}")
            missing = [k for k in _KEYS if k not in pose]
            if missing:
                raise RigError(f"{path}: {key}.{missing[0]}: missing")
            v = [common.number(pose[k], path, f"{key}.{k}") for k in _KEYS]
            if any(abs(a) > 4 * math.pi for a in v[3:]):
                raise RigError(f"{path}: {key}: roll, pitch, yaw are radians: {v[3:]} is more than two turns")
            R = Rotation.from_euler("ZYX", v[5:2:-1]).as_matrix()  # yaw, pitch, roll
            hops.append(Hop(str(parent), str(child), R, np.array(v[:3])))
    return hops


def rig_from_autoware(sensor_kit: str | Path, *, sensors_calibration: str | Path | None = None,
                      imu: str | None = None, base: str | None = None, lidar: list[str] | None = None,
                      camera: list[str] | None = None, gnss: list[str] | None = None,
                      name: str | None = None) -> common.ImportedRig:
    """A rig from Autoware's calibration files (see the module notes for what is found by name)."""
    sensor_kit = Path(sensor_kit)
    files = [sensor_kit] + ([Path(sensors_calibration)] if sensors_calibration else [])
    tree = Tree([h for f in files for h in _hops(f)], sensor_kit)
    found = classify(tree.leaves())
    if imu is None:
        if len(found["imu"]) != 1:
            raise RigError(f"{sensor_kit}: {len(found['imu'])} frames named like an IMU "
                           f"({', '.join(found['imu']) or 'none'}): name the body frame with --imu")
        imu = found["imu"][0]
    if base is None:
        frames = tree.frames
        roots = sorted(f for f in frames if f not in tree.parent)
        base = "base_link" if "base_link" in frames else roots[0]
    if lidar is None and camera is None:
        lidar, camera = found["lidar"], found["camera"]
        gnss = found["gnss"] if gnss is None else gnss
    notes = [f"from Autoware {', '.join(f.name for f in files)}"]
    return rig_from_tree(tree, imu=imu, base=base, lidar=list(lidar or []), camera=list(camera or []),
                         gnss=gnss, name=name or common.rig_name(sensor_kit), notes=notes)
