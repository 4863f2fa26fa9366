"""LIO-SAM's ``params.yaml`` (ROS 1's ``lio_sam:`` or ROS 2's ``/**: ros__parameters:``).

``extrinsicRot`` and ``extrinsicTrans`` take IMU-frame coordinates into the lidar frame
(``x_L = extrinsicRot · x_I + extrinsicTrans``: LIO-SAM rotates the IMU's acceleration and rate
with ``extrinsicRot``), so the lidar's pose in the IMU frame is their inverse. ``extrinsicRPY``
rotates the IMU's *orientation output* (which some IMUs give in another frame than their
measurements): not a mounting of either sensor, it is noted, not used. ``imuAccNoise``,
``imuGyrNoise``, ``imuAccBiasN``, ``imuGyrBiasN`` are continuous-time densities as LIO-SAM uses
them (Kalibr's units); the IMU and lidar rates are not in the file. ``N_SCAN`` and
``Horizon_SCAN`` (the lidar's channels and columns) are noted.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...errors import RigError
from . import common

_IMU = {"imuAccNoise": "accelerometer_noise_density", "imuAccBiasN": "accelerometer_random_walk",
        "imuGyrNoise": "gyroscope_noise_density", "imuGyrBiasN": "gyroscope_random_walk"}


def rig_from_lio_sam(path: str | Path, *, name: str | None = None) -> common.ImportedRig:
    """A rig from a LIO-SAM ``params.yaml``: its IMU and its lidar."""
    path = Path(path)
    data = common.mapping(common.load_yaml(path), path, "LIO-SAM's params.yaml")
    found = common.find_key(data, "extrinsicRot")
    if found is None:
        raise RigError(f"{path}: extrinsicRot: missing (LIO-SAM's params.yaml has extrinsicTrans, "
                       "extrinsicRot, extrinsicRPY)")
    params, at = found
    if "extrinsicTrans" not in params:
        raise RigError(f"{path}: {at}extrinsicTrans: missing")
    notes = [f"from LIO-SAM's {path.name}"]
    review: dict[str, str] = {}
    R_L_I = common.rotation(*common.matrix(params["extrinsicRot"], path, f"{at}extrinsicRot", (3, 3)), path,
                            f"{at}extrinsicRot", notes)
    t = common.vector(params["extrinsicTrans"], path, f"{at}extrinsicTrans")
    R, p = common.invert(R_L_I, t)
    if "extrinsicRPY" in params:
        common.matrix(params["extrinsicRPY"], path, f"{at}extrinsicRPY", (3, 3))
        notes.append("extrinsicRPY rotates the IMU's orientation output, not a mounting: not used")
    frame = params.get("lidarFrame")
    lidar_name = common.frame_name(frame, "lidar") if isinstance(frame, str) and frame else "lidar"
    sensors = [common.odometry_sensor(lidar_name, "lidar", R, p, review, 0)]
    if isinstance(frame, str):
        notes.append(f"{lidar_name} = {frame} (lidarFrame)")
    pattern = [f"{k} {params[k]}" for k in ("sensor", "N_SCAN", "Horizon_SCAN", "lidarMinRange", "lidarMaxRange")
               if k in params]
    if pattern:
        notes.append(f"{lidar_name}: {', '.join(pattern)}")
    if all(k in params for k in _IMU):
        imu = {kalibr: common.number(params[k], path, at + k) for k, kalibr in _IMU.items()}
        imu["update_rate"] = common.DEFAULT_IMU["update_rate"]
        review["imu"] = f"the IMU rate is not in the file: {imu['update_rate']:g} Hz assumed (densities as LIO-SAM uses them)"
    else:
        imu = common.default_imu(review)
    base = params.get("baselinkFrame")
    cfg: dict[str, Any] = {"name": name or common.rig_name(path), "imu": imu,
                           "vehicle": {"T_V_B": common.pose(np.eye(3), np.zeros(3))}, "sensors": sensors,
                           "targets": common.default_targets(sensors)}
    review["vehicle.T_V_B"] = (f"the IMU's pose in {base or 'the base frame'} is not in the file: the IMU at the "
                               "rear-axle centre, x forward, z up, assumed")
    review["targets"] = common.targets_review()
    return common.finish(cfg, review, notes, path)
