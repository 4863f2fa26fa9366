"""FAST-LIO's configuration (``mapping.extrinsic_T``, ``mapping.extrinsic_R``), and FAST-LIVO's.

``extrinsic_R`` (9 numbers, row by row) and ``extrinsic_T`` are the lidar's pose in the IMU frame
(FAST-LIO maps a lidar point into the IMU frame as ``R·p + T``): ``T_B_S`` as it is. The lidar's
rate is ``preprocess.scan_rate`` where given; ``scan_line`` (channels) is noted. ``acc_cov``,
``gyr_cov``, … are the filter's tuning (variances per sample, not the sensor's densities): the
IMU's noise is a default marked for review. ``time_offset_lidar_to_imu`` is noted.

FAST-LIVO (``extrin_calib:`` in FAST-LIVO2, ``camera:`` or the top level in FAST-LIVO) adds a
camera: ``Rcl``, ``Pcl`` are the lidar's pose seen from the camera (``T_C_L``), so the camera's
pose in the IMU frame is ``T_B_L · T_C_L⁻¹``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...errors import RigError
from . import common

LIDAR_TYPES = {1: "livox", 2: "velodyne", 3: "ouster", 4: "hesai"}  # preprocess.lidar_type


def rig_from_fast_lio(path: str | Path, *, name: str | None = None) -> common.ImportedRig:
    """A rig from a FAST-LIO (or FAST-LIVO) configuration: its IMU, its lidar (and its camera)."""
    path = Path(path)
    data = common.mapping(common.load_yaml(path), path, "a FAST-LIO configuration")
    found = common.find_key(data, "extrinsic_R")
    if found is None:
        raise RigError(f"{path}: mapping.extrinsic_R: missing (FAST-LIO's configuration has mapping.extrinsic_T "
                       "and mapping.extrinsic_R)")
    block, at = found
    if "extrinsic_T" not in block:
        raise RigError(f"{path}: {at}extrinsic_T: missing")
    notes = [f"from the FAST-LIO configuration {path.name}"]
    review: dict[str, str] = {}
    R_B_L = common.rotation(*common.matrix(block["extrinsic_R"], path, f"{at}extrinsic_R", (3, 3)), path,
                            f"{at}extrinsic_R", notes)
    p_B_L = common.vector(block["extrinsic_T"], path, f"{at}extrinsic_T")
    pre = data.get("preprocess") if isinstance(data.get("preprocess"), dict) else {}
    lidar_type = pre.get("lidar_type")
    lidar_name = LIDAR_TYPES.get(lidar_type, "lidar") if isinstance(lidar_type, int) else "lidar"
    rate = pre.get("scan_rate")
    rate = None if rate is None else common.number(rate, path, "preprocess.scan_rate")
    sensors = [common.odometry_sensor(lidar_name, "lidar", R_B_L, p_B_L, review, 0, rate_hz=rate,
                                      rate_from=" (preprocess.scan_rate)")]
    if "scan_line" in pre:
        notes.append(f"{lidar_name}: scan_line {pre['scan_line']} (lidar_type {lidar_type})")
    common_block = data.get("common") if isinstance(data.get("common"), dict) else {}
    offset = common_block.get("time_offset_lidar_to_imu")
    if offset:
        notes.append(f"{lidar_name}: nominal time offset {common.number(offset, path, 'common.time_offset_lidar_to_imu') * 1e3:.3f} ms")
    cam = common.find_key(data, "Rcl")
    if cam is not None:
        cblock, cat = cam
        if "Pcl" not in cblock:
            raise RigError(f"{path}: {cat}Pcl: missing (FAST-LIVO gives the lidar in the camera as Rcl and Pcl)")
        R_C_L = common.rotation(*common.matrix(cblock["Rcl"], path, f"{cat}Rcl", (3, 3)), path, f"{cat}Rcl", notes)
        p_C_L = common.vector(cblock["Pcl"], path, f"{cat}Pcl")
        R_L_C, p_L_C = common.invert(R_C_L, p_C_L)
        sensors.append(common.odometry_sensor("camera", "camera", R_B_L @ R_L_C, R_B_L @ p_L_C + p_B_L, review, 1))
        notes.append("FAST-LIVO: camera from Rcl, Pcl (the lidar in the camera frame)")
    review["imu"] = ("acc_cov, gyr_cov, … are FAST-LIO's filter tuning, not the sensor's densities: a consumer "
                     "MEMS IMU's densities and 200 Hz assumed")
    cfg: dict[str, Any] = {"name": name or common.rig_name(path), "imu": dict(common.DEFAULT_IMU),
                           "vehicle": {"T_V_B": common.pose(np.eye(3), np.zeros(3))}, "sensors": sensors,
                           "targets": common.default_targets(sensors)}
    review["vehicle.T_V_B"] = "not in the file: the IMU at the rear-axle centre, x forward, z up, assumed"
    review["targets"] = common.targets_review()
    return common.finish(cfg, review, notes, path)
