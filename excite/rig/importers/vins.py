"""VINS-Fusion's configuration (OpenCV YAML, ``%YAML:1.0``): ``body_T_camN`` (``!!opencv-matrix``,
4×4) is camera N's pose in the IMU (body) frame, so ``T_B_S = body_T_camN`` as it is, for
N < ``num_of_cam``. Two cameras are a stereo pair (metric); one is monocular. ``freq`` (the rate
VINS-Fusion tracks frames at; 0: the camera's own) is the cameras' rate. ``acc_n``, ``gyr_n``,
``acc_w``, ``gyr_w`` are VINS-Fusion's continuous-time noise settings, usually inflated well
above the sensor's own densities to absorb what its model leaves out: taken as the IMU's, and
marked for review; the IMU rate is not in the file. ``td`` (``t_imu = t_cam + td``) is noted.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...errors import RigError
from . import common

_IMU = {"acc_n": "accelerometer_noise_density", "acc_w": "accelerometer_random_walk",
        "gyr_n": "gyroscope_noise_density", "gyr_w": "gyroscope_random_walk"}


def rig_from_vins(path: str | Path, *, name: str | None = None) -> common.ImportedRig:
    """A rig from a VINS-Fusion (or VINS-Mono) configuration file."""
    path = Path(path)
    data = common.mapping(common.load_yaml(path), path, "a VINS-Fusion configuration")
    n = data.get("num_of_cam", 1)
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 2:
        raise RigError(f"{path}: num_of_cam: expected 1 or 2, got {n!r}")
    review: dict[str, str] = {}
    notes = [f"from the VINS-Fusion configuration {path.name}"]
    freq = data.get("freq")
    rate = None if freq in (None, 0) else common.number(freq, path, "freq")
    sensors = []
    for i in range(n):
        key = f"body_T_cam{i}"
        if key not in data:
            raise RigError(f"{path}: {key}: missing (num_of_cam is {n})")
        R, p = common.transform(data[key], path, key, notes)
        why = ("num_of_cam 2: a stereo pair, metric" if n == 2 else
               "num_of_cam 1: monocular (scale a nuisance of each drive)")
        sensors.append(common.odometry_sensor(f"cam{i}", "camera", R, p, review, i, rate_hz=rate,
                                              rate_from=" (freq: 0 tracks at the camera's rate)",
                                              monocular=n == 1, monocular_why=why))
    if data.get("imu", 1) in (0, False):
        imu = common.default_imu(review, "imu: 0 (VINS-Fusion without an IMU)")
    elif all(k in data for k in _IMU):
        imu = {kalibr: common.number(data[k], path, k) for k, kalibr in _IMU.items()}
        imu["update_rate"] = common.DEFAULT_IMU["update_rate"]
        review["imu"] = ("acc_n, gyr_n, acc_w, gyr_w are VINS-Fusion's settings, often inflated well above the "
                         f"sensor's densities; the IMU rate is not in the file ({imu['update_rate']:g} Hz assumed)")
    else:
        imu = common.default_imu(review)
    td = data.get("td")
    if td:
        notes.append(f"nominal time offset {common.number(td, path, 'td') * 1e3:.3f} ms (td, t_imu = t_cam + td)")
    cfg: dict[str, Any] = {"name": name or common.rig_name(path), "imu": imu,
                           "vehicle": {"T_V_B": common.pose(np.eye(3), np.zeros(3))}, "sensors": sensors,
                           "targets": common.default_targets(sensors)}
    review["vehicle.T_V_B"] = "not in the file: the IMU at the rear-axle centre, x forward, z up, assumed"
    review["targets"] = common.targets_review()
    return common.finish(cfg, review, notes, path)
