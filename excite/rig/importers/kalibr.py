"""Kalibr's camera–IMU calibration: a camchain and an IMU file, as Kalibr writes them and as
OpenVINS ships them.

- **camchain** (``camchain-imucam-*.yaml``): ``camN.T_cam_imu``, the 4×4 transform of IMU-frame
  points into camera N's frame, so ``T_B_S = T_cam_imu⁻¹``; OpenVINS's variant gives its inverse
  ``camN.T_imu_cam`` (the camera's pose in the IMU frame) instead. ``timeshift_cam_imu`` (``t_imu =
  t_cam + shift``) is noted: the information model linearises about a zero offset.
- **IMU file**: Kalibr's input ``imu.yaml`` (the densities at the top level) or its output
  ``imu-*.yaml`` (one entry per IMU, ``imu0:``, ``imu1:``, …; the camchain is relative to
  ``imu0``, the body frame). OpenVINS's copies start with OpenCV's ``%YAML:1.0`` line.

A camchain tells no frame rate, no odometry noise and nothing of the vehicle: those are defaults
marked for review. A chain of one camera is ``monocular`` (marked for review: its odometry has no
scale of its own unless a depth sensor gives it one); cameras that overlap another
(``cam_overlaps``) form a stereo pair and are metric.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import RigError
from ..files import read_kalibr_imu
from . import common

_CAM = re.compile(r"cam(\d+)")
CAMCHAIN_PREFIXES = ("camchain-imucam-", "camchain-")


def rig_from_kalibr(camchain: str | Path, imu_yaml: str | Path | None = None, *, name: str | None = None,
                    camera_rate_hz: float | None = None, imu: str | None = None) -> common.ImportedRig:
    """A rig from a Kalibr camchain and its IMU file (defaults marked for review without one)."""
    camchain = Path(camchain)
    chain = common.mapping(common.load_yaml(camchain), camchain, "a Kalibr camchain")
    cams = sorted((k for k in chain if isinstance(k, str) and _CAM.fullmatch(k)), key=lambda k: int(k[3:]))
    if not cams:
        raise RigError(f"{camchain}: expected a Kalibr camchain with cam0, cam1, … at the top level")
    review: dict[str, str] = {}
    notes = [f"from the Kalibr camchain {camchain.name}"]
    if imu_yaml is None:
        imu_cfg = common.default_imu(review, "no IMU file given")
    else:
        imu_cfg, more = read_kalibr_imu(imu_yaml, imu)
        notes += more
    stereo = {c for c in cams if isinstance(chain[c], dict) and chain[c].get("cam_overlaps")}
    sensors = []
    for i, cam in enumerate(cams):
        entry = chain[cam]
        if not isinstance(entry, dict):
            raise RigError(f"{camchain}: {cam}: expected a mapping (T_cam_imu, intrinsics, …)")
        if "T_cam_imu" in entry:
            R, p = common.invert(*common.transform(entry["T_cam_imu"], camchain, f"{cam}.T_cam_imu", notes))
        elif "T_imu_cam" in entry:
            R, p = common.transform(entry["T_imu_cam"], camchain, f"{cam}.T_imu_cam", notes)
        else:
            raise RigError(f"{camchain}: {cam}.T_cam_imu: missing (nor OpenVINS's T_imu_cam: run Kalibr's "
                           "camera-IMU calibration)")
        if len(cams) == 1:
            mono, why = True, ("one camera in the chain: monocular (scale a nuisance of each drive) assumed; "
                               "set false if a depth sensor gives its odometry a metric scale")
        elif cam in stereo:
            mono, why = False, (f"overlaps {', '.join(str(c) for c in entry['cam_overlaps'])} (cam_overlaps): "
                                "a stereo pair, metric, assumed")
        else:
            mono, why = True, "overlaps no other camera: monocular assumed"
        sensors.append(common.odometry_sensor(cam, "camera", R, p, review, i, rate_hz=camera_rate_hz,
                                              rate_from=" (a camchain has none: --camera-rate)",
                                              monocular=mono, monocular_why=why))
        shift = entry.get("timeshift_cam_imu")
        if shift is not None:
            shift = common.number(shift, camchain, f"{cam}.timeshift_cam_imu")
            notes.append(f"{cam}: nominal time offset {shift * 1e3:.3f} ms (timeshift_cam_imu, t_imu = t_cam + "
                         "shift); the information model linearises about zero offset")
        if entry.get("rostopic"):
            notes.append(f"{cam}: {entry['rostopic']}")
    cfg: dict[str, Any] = {"name": name or common.rig_name(camchain, CAMCHAIN_PREFIXES), "imu": imu_cfg,
                           "vehicle": {"T_V_B": common.pose(np.eye(3), np.zeros(3))}, "sensors": sensors,
                           "targets": common.default_targets(sensors)}
    review["vehicle.T_V_B"] = ("a camchain says nothing of the vehicle: the IMU at the rear-axle centre, "
                               "x forward, z up, assumed")
    review["targets"] = common.targets_review()
    return common.finish(cfg, review, notes, camchain)
