"""Writers of every format the rig importers read, written here from each tool's documented
keys and conventions (not from the importers), for the write → import round trips.

A :class:`Spec` is a rig's geometry: the IMU in the vehicle frame and each sensor's pose in the
IMU frame. Each writer lays it out as its tool does: Kalibr's ``T_cam_imu`` (IMU points into the
camera: the inverse of the camera's pose), OpenVINS's ``T_imu_cam`` (the pose itself), VINS-Fusion's
``body_T_camN`` (the pose), LIO-SAM's ``extrinsicRot``/``extrinsicTrans`` (IMU coordinates into
the lidar's: the inverse), FAST-LIO's ``extrinsic_R``/``extrinsic_T`` (the lidar's pose),
FAST-LIVO's ``Rcl``/``Pcl`` (the lidar seen from the camera), URDF joints and Autoware's
``{x, y, z, roll, pitch, yaw}`` (parent → child poses, R = Rz·Ry·Rx, fixed axes), and a bag's
``/tf_static`` (rosbags' own serialisation).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

IMU = {"accelerometer_noise_density": 1.86e-3, "accelerometer_random_walk": 4.33e-4,
       "gyroscope_noise_density": 1.87e-4, "gyroscope_random_walk": 2.66e-5, "update_rate": 200.0}


@dataclass
class Sensor:
    frame: str
    kind: str
    R: np.ndarray  # pose in the IMU frame B
    p: np.ndarray


@dataclass
class Spec:
    R_V_B: np.ndarray
    p_V_B: np.ndarray
    sensors: list[Sensor] = field(default_factory=list)


def random_spec(seed: int, lidars: tuple[str, ...] = (), cameras: tuple[str, ...] = ()) -> Spec:
    rng = np.random.default_rng(seed)

    def pose():
        return Rotation.random(random_state=rng).as_matrix(), rng.uniform(-2.0, 2.0, 3)

    spec = Spec(*pose())
    for kind, frames in (("lidar", lidars), ("camera", cameras)):
        spec.sensors += [Sensor(f, kind, *pose()) for f in frames]
    return spec


def _inv(R, p):
    return R.T, -R.T @ p


def _T(R, p) -> list[list[float]]:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return [[float(x) for x in row] for row in T]


def _dump(data) -> str:
    return yaml.safe_dump(data, sort_keys=False)


def kalibr(spec: Spec, folder: Path, *, openvins: bool = False, output_imu: bool = False) -> tuple[Path, Path]:
    """A camchain (OpenVINS: ``T_imu_cam`` and OpenCV's header) and an IMU file (Kalibr's input,
    or its output with ``imu0:`` and a second IMU)."""
    chain = {}
    for i, s in enumerate(spec.sensors):
        entry = ({"T_imu_cam": _T(s.R, s.p)} if openvins else {"T_cam_imu": _T(*_inv(s.R, s.p))})
        entry.update({"cam_overlaps": [], "camera_model": "pinhole", "rostopic": f"/cam{i}/image_raw"})
        chain[f"cam{i}"] = entry
    header = "%YAML:1.0\n" if openvins else ""
    cam = folder / "camchain-imucam-rt.yaml"
    cam.write_text(header + _dump(chain))
    imu_data = ({"imu0": {"T_i_b": _T(np.eye(3), np.zeros(3)), **IMU, "model": "calibrated", "rostopic": "/imu0"},
                 "imu1": {**IMU, "update_rate": 100.0}} if output_imu else dict(IMU))
    imu = folder / "imu-rt.yaml"
    imu.write_text(header + _dump(imu_data))
    return cam, imu


def _opencv(name: str, T: list[list[float]]) -> str:
    data = ", ".join(repr(x) for row in T for x in row)
    return f"{name}: !!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: d\n   data: [{data}]\n"


def vins(spec: Spec, folder: Path) -> Path:
    text = f"%YAML:1.0\n\nimu: 1\nnum_of_cam: {len(spec.sensors)}\n"
    text += "".join(_opencv(f"body_T_cam{i}", _T(s.R, s.p)) for i, s in enumerate(spec.sensors))
    text += "freq: 10\nacc_n: 0.1\ngyr_n: 0.01\nacc_w: 0.001\ngyr_w: 0.0001\ntd: 0.0\n"
    path = folder / "vins_config.yaml"
    path.write_text(text)
    return path


def lio_sam(spec: Spec, folder: Path, ros2: bool = True) -> Path:
    (s,) = spec.sensors
    R_L_I, t = _inv(s.R, s.p)
    params = {"lidarFrame": s.frame, "baselinkFrame": "base_link", "N_SCAN": 16, "Horizon_SCAN": 1800,
              "imuAccNoise": 3.99e-3, "imuGyrNoise": 1.56e-3, "imuAccBiasN": 6.44e-5, "imuGyrBiasN": 3.56e-5,
              "extrinsicTrans": [float(x) for x in t], "extrinsicRot": [float(x) for x in R_L_I.ravel()],
              "extrinsicRPY": [float(x) for x in np.eye(3).ravel()]}
    path = folder / "params.yaml"
    path.write_text(_dump({"/**": {"ros__parameters": params}} if ros2 else {"lio_sam": params}))
    return path


def fast_lio(spec: Spec, folder: Path) -> Path:
    """FAST-LIO (one lidar) or FAST-LIVO2 (a lidar and a camera, ``extrin_calib:``)."""
    lidar = spec.sensors[0]
    block = {"extrinsic_T": [float(x) for x in lidar.p], "extrinsic_R": [float(x) for x in lidar.R.ravel()]}
    data = {"preprocess": {"lidar_type": 2, "scan_line": 32, "scan_rate": 10}, "mapping": {"acc_cov": 0.1}}
    if len(spec.sensors) > 1:
        cam = spec.sensors[1]
        # the lidar seen from the camera: T_C_L = T_B_C⁻¹ · T_B_L
        R_C_B, p_C_B = _inv(cam.R, cam.p)
        block.update({"Rcl": [float(x) for x in (R_C_B @ lidar.R).ravel()],
                      "Pcl": [float(x) for x in R_C_B @ lidar.p + p_C_B]})
        data["extrin_calib"] = block
    else:
        data["mapping"].update(block)
    path = folder / "fast_lio.yaml"
    path.write_text(_dump(data))
    return path


def _rpy(R) -> list[float]:
    """roll, pitch, yaw with R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    return [float(x) for x in Rotation.from_matrix(R).as_euler("xyz")]


def _tree(spec: Spec) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """(parent, child, R, p): base_link → imu_link, base_link → mount → each sensor (a mount in
    between, so that poses compose over two hops)."""
    R_m, p_m = Rotation.from_euler("xyz", [0.1, -0.2, 0.3]).as_matrix(), np.array([0.5, -0.1, 1.2])
    hops = [("base_link", "imu_link", spec.R_V_B, spec.p_V_B), ("base_link", "mount_link", R_m, p_m)]
    for s in spec.sensors:
        R_V_S, p_V_S = spec.R_V_B @ s.R, spec.R_V_B @ s.p + spec.p_V_B
        R_m_S, p_m_S = R_m.T @ R_V_S, R_m.T @ (p_V_S - p_m)
        hops.append(("mount_link", s.frame, R_m_S, p_m_S))
    return hops


def urdf(spec: Spec, folder: Path, movable: bool = False) -> Path:
    links = {"base_link"} | {c for _, c, _, _ in _tree(spec)}
    out = ['<?xml version="1.0"?>', '<robot name="rt">']
    out += [f'  <link name="{n}"/>' for n in sorted(links)]
    for i, (parent, child, R, p) in enumerate(_tree(spec)):
        kind = "revolute" if movable and child == "mount_link" else "fixed"
        xyz = " ".join(repr(float(x)) for x in p)
        rpy = " ".join(repr(x) for x in _rpy(R))
        out.append(f'  <joint name="j{i}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
                   f'<origin xyz="{xyz}" rpy="{rpy}"/></joint>')
    out.append("</robot>")
    path = folder / "rt.urdf"
    path.write_text("\n".join(out) + "\n")
    return path


def autoware(spec: Spec, folder: Path) -> tuple[Path, Path]:
    """``sensors_calibration.yaml`` places the kit (the mount) on base_link,
    ``sensor_kit_calibration.yaml`` the IMU and the sensors on the kit."""
    hops = _tree(spec)
    (_, _, R_V_B, p_V_B), (_, _, R_m, p_m) = hops[0], hops[1]
    R_m_B, p_m_B = R_m.T @ R_V_B, R_m.T @ (p_V_B - p_m)

    def entry(R, p):
        r = _rpy(R)
        return {"x": float(p[0]), "y": float(p[1]), "z": float(p[2]), "roll": r[0], "pitch": r[1], "yaw": r[2]}

    kit = {"mount_link": {"imu_link": entry(R_m_B, p_m_B), **{c: entry(R, p) for _, c, R, p in hops[2:]}}}
    base = {"base_link": {"mount_link": entry(R_m, p_m)}}
    k, b = folder / "sensor_kit_calibration.yaml", folder / "sensors_calibration.yaml"
    k.write_text(_dump(kit))
    b.write_text(_dump(base))
    return k, b


def tf_bag(spec: Spec, folder: Path) -> Path:
    """A ROS 2 bag whose ``/tf_static`` holds the tree, in one message."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    M = store.types
    stamp = M["builtin_interfaces/msg/Time"](sec=1, nanosec=0)
    transforms = []
    for parent, child, R, p in _tree(spec):
        q = Rotation.from_matrix(R).as_quat()
        transforms.append(M["geometry_msgs/msg/TransformStamped"](
            header=M["std_msgs/msg/Header"](stamp=stamp, frame_id=parent), child_frame_id=child,
            transform=M["geometry_msgs/msg/Transform"](
                translation=M["geometry_msgs/msg/Vector3"](x=p[0], y=p[1], z=p[2]),
                rotation=M["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))))
    msg = M["tf2_msgs/msg/TFMessage"](transforms=transforms)
    path = folder / "tf_bag"
    with Writer(path, version=8) as w:
        conn = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=store)
        w.write(conn, 1_000_000_000, store.serialize_cdr(msg, "tf2_msgs/msg/TFMessage"))
    return path
