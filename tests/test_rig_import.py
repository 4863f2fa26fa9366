"""Rigs from Kalibr and Autoware files, written here from the formats' documented keys; expected
transforms composed independently (numpy inverse, scipy Euler angles)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from excite.cli.app import main
from excite.errors import RigError
from excite.rig.config import load_rig
from excite.rig.importers import rig_from_autoware, rig_from_kalibr, rig_yaml

T_CAM_IMU = [[0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
             [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
             [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
             [0.0, 0.0, 0.0, 1.0]]
IMU = {"rostopic": "/imu0", "update_rate": 200.0, "accelerometer_noise_density": 2.0e-3,
       "accelerometer_random_walk": 3.0e-3, "gyroscope_noise_density": 1.6968e-4,
       "gyroscope_random_walk": 1.9393e-5}


@pytest.fixture
def kalibr(tmp_path):
    chain = {"cam0": {"T_cam_imu": T_CAM_IMU, "timeshift_cam_imu": 0.00512, "rostopic": "/cam0/image_raw",
                      "camera_model": "pinhole", "intrinsics": [458.6, 457.3, 367.2, 248.4],
                      "distortion_model": "radtan", "distortion_coeffs": [-0.28, 0.07, 0.0002, 1.8e-05],
                      "resolution": [752, 480], "cam_overlaps": [1]},
             "cam1": {"T_cam_imu": np.linalg.inv(np.array(T_CAM_IMU)).tolist(), "timeshift_cam_imu": 0.0,
                      "rostopic": "/cam1/image_raw", "resolution": [752, 480]}}
    (tmp_path / "camchain-imucam.yaml").write_text(yaml.safe_dump(chain))
    (tmp_path / "imu.yaml").write_text(yaml.safe_dump(IMU))
    return tmp_path / "camchain-imucam.yaml", tmp_path / "imu.yaml"


def test_kalibr_camchain_and_imu_yaml_load_as_a_rig(kalibr, tmp_path):
    imported = rig_from_kalibr(*kalibr, camera_rate_hz=20)
    out = tmp_path / "rig.yaml"
    out.write_text(rig_yaml(imported))
    rig = load_rig(out)
    cam0 = rig.config.sensors[0]
    T_B_C = np.linalg.inv(np.array(T_CAM_IMU))
    np.testing.assert_allclose(cam0.T_B_S.R, T_B_C[:3, :3], atol=1e-9)
    np.testing.assert_allclose(cam0.T_B_S.p, T_B_C[:3, 3], atol=1e-9)
    np.testing.assert_allclose(rig.config.sensors[1].T_B_S.p, np.array(T_CAM_IMU)[:3, 3], atol=1e-9)
    for k in ("accelerometer_noise_density", "gyroscope_random_walk", "update_rate"):
        assert getattr(rig.config.imu, k) == IMU[k]
    text = out.read_text()
    assert "5.120 ms" in text  # the nominal time offset, noted
    assert "T_V_B:   # DEFAULT: review" in text and "targets:   # DEFAULT: review" in text
    assert [s.name for s in rig.config.sensors] == ["cam0", "cam1"]


def test_kalibr_errors_name_the_key(kalibr, tmp_path):
    chain, imu = kalibr
    bad = yaml.safe_load(chain.read_text())
    bad["cam0"]["T_cam_imu"][0][0] = 5.0
    chain.write_text(yaml.safe_dump(bad))
    with pytest.raises(RigError, match=r"cam0.T_cam_imu: the 3x3 block is not a rotation"):
        rig_from_kalibr(chain, imu)
    imu.write_text(yaml.safe_dump({k: v for k, v in IMU.items() if k != "gyroscope_noise_density"}))
    with pytest.raises(RigError, match="gyroscope_noise_density: missing"):
        rig_from_kalibr(chain, imu)


SENSOR_KIT = {"sensor_kit_base_link": {
    "camera0/camera_link": {"x": 0.10731, "y": 0.56343, "z": -0.27697, "roll": -0.025, "pitch": 0.315, "yaw": 1.035},
    "velodyne_top_base_link": {"x": 0.0, "y": 0.0, "z": 0.0, "roll": 0.0, "pitch": 0.0, "yaw": 1.575},
    "tamagawa/imu_link": {"x": 0.0, "y": 0.0, "z": 0.0, "roll": 3.14159265359, "pitch": 0.0, "yaw": 3.14159265359},
    "gnss_link": {"x": -0.1, "y": 0.0, "z": -0.2, "roll": 0.0, "pitch": 0.0, "yaw": 0.0}}}
SENSORS = {"base_link": {"sensor_kit_base_link": {"x": 0.9, "y": 0.0, "z": 2.0, "roll": -0.001, "pitch": 0.015, "yaw": -0.0364}}}


def _T(d):
    """Autoware's {x, y, z, roll, pitch, yaw} as (R, p): R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    R = Rotation.from_euler("xyz", [d["roll"], d["pitch"], d["yaw"]])  # extrinsic x, y, z
    return R, np.array([d["x"], d["y"], d["z"]])


def test_autoware_sensor_kit_loads_as_a_rig(tmp_path, capsys):
    kit, cal = tmp_path / "sensor_kit_calibration.yaml", tmp_path / "sensors_calibration.yaml"
    kit.write_text(yaml.safe_dump(SENSOR_KIT))
    cal.write_text(yaml.safe_dump(SENSORS))
    out = tmp_path / "rig.yaml"
    assert main(["rig", "from-autoware", str(kit), "--sensors-calibration", str(cal), "--imu",
                 "tamagawa/imu_link", "--base", "base_link", "--lidar", "velodyne_top_base_link",
                 "--camera", "camera0/camera_link", "-o", str(out)]) == 0
    rig = load_rig(out)
    R_vk, p_vk = _T(SENSORS["base_link"]["sensor_kit_base_link"])
    R_ki, p_ki = _T(SENSOR_KIT["sensor_kit_base_link"]["tamagawa/imu_link"])
    R_vb, p_vb = R_vk * R_ki, R_vk.apply(p_ki) + p_vk
    np.testing.assert_allclose(rig.config.vehicle.T_V_B.R, R_vb.as_matrix(), atol=1e-9)
    np.testing.assert_allclose(rig.config.vehicle.T_V_B.p, p_vb, atol=1e-9)
    for sensor, frame in zip(rig.config.sensors, ("velodyne_top_base_link", "camera0/camera_link")):
        R_ks, p_ks = _T(SENSOR_KIT["sensor_kit_base_link"][frame])
        R_bs, p_bs = R_ki.inv() * R_ks, R_ki.inv().apply(p_ks - p_ki)
        np.testing.assert_allclose(sensor.T_B_S.R, R_bs.as_matrix(), atol=1e-9)
        np.testing.assert_allclose(sensor.T_B_S.p, p_bs, atol=1e-9)


def test_autoware_missing_frame_and_key(tmp_path):
    kit = tmp_path / "sensor_kit_calibration.yaml"
    kit.write_text(yaml.safe_dump(SENSOR_KIT))
    with pytest.raises(RigError, match="'base_link'.*sensor_kit_base_link") as e:
        rig_from_autoware(kit, imu="tamagawa/imu_link", base="base_link")
    assert str(e.value).startswith(f"{kit}: frame 'base_link' appears in no transform in the calibration files")
    broken = {"sensor_kit_base_link": {"gnss_link": {"x": 0, "y": 0, "z": 0, "roll": 0, "pitch": 0}}}
    kit.write_text(yaml.safe_dump(broken))
    with pytest.raises(RigError, match="sensor_kit_base_link.gnss_link.yaw: missing"):
        rig_from_autoware(kit, imu="gnss_link", base="sensor_kit_base_link")
