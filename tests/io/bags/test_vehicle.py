"""A car's own signals in bags (:mod:`excite.io.bags.vehicle`): JointState wheel speeds and
steering, TwistWithCovarianceStamped radar ego-velocity; the round trip in ROS 1 and ROS 2
(MCAP), a simulated CAN stream through a bag into the Ackermann kind's measurements, and the
errors for what is not supported."""

from __future__ import annotations

import re

import numpy as np
import pytest

from excite.errors import BagError
from excite.factors import base as registry
from excite.factors.ackermann import interval_means, physical_stream
from excite.factors.base import Nominal
from excite.io.bags import (bag_info, can_recording, ego_velocity_at, ego_velocity_noise, read_ego_velocity,
                            read_wheel_speeds, write_bag, write_vehicle_bag)
from excite.motion.vehicle import ControlProfile, drive
from excite.rig.config import build_rig
from excite.score.agreement import agreement

from helpers import car_data

JOINTS = ("front_left_wheel_joint", "front_right_wheel_joint", "rear_left_wheel_joint", "rear_right_wheel_joint")


@pytest.fixture(params=["ros1.bag", "ros2"])
def bag(request, tmp_path):
    t = np.arange(0.0, 3.0, 0.01)
    speeds = np.column_stack([30 + np.sin(t + k) for k in range(4)])
    radar_t = t[::5]
    v = np.column_stack([10 + np.cos(radar_t), 0.1 * radar_t, np.zeros_like(radar_t)])
    path = write_vehicle_bag(tmp_path / request.param, wheel_t_s=t, wheel_speeds=speeds, steering=0.2 * np.sin(t),
                             radar_t_s=radar_t, radar_v=v, radar_sigma=[0.1, 0.4, 0.8])
    return path, t, speeds, radar_t, v


def test_wheel_speeds_steering_and_ego_velocity_round_trip(bag):
    path, t, speeds, radar_t, v = bag
    w = read_wheel_speeds(path, "/joint_states", JOINTS, steering_joint="steering_joint")
    assert np.array_equal(w.speeds, speeds) and np.allclose(w.steering, 0.2 * np.sin(t))
    assert np.allclose((w.t_ns - w.t_ns[0]) * 1e-9, t - t[0], atol=1e-9)
    e = read_ego_velocity(path, "/radar/ego_velocity")
    assert np.array_equal(e.v, v) and e.frame == "radar"
    assert np.allclose(ego_velocity_noise(e), [0.1, 0.4, 0.8])
    at = ego_velocity_at(e, int(w.t_ns[0]), np.array([0.0, 0.05, 0.1, 10.0]), dimensions=2)
    assert np.allclose(at[0], v[0, :2]) and np.allclose(at[2], v[2, :2]) and np.isnan(at[3]).all()
    uses = {ti.topic: ti.use for ti in bag_info(path)}
    assert uses == {"/joint_states": "wheels", "/radar/ego_velocity": "ego_velocity"}


def test_the_joints_are_the_callers_in_their_order(bag):
    path, _, speeds, _, _ = bag
    w = read_wheel_speeds(path, "/joint_states", (JOINTS[1], JOINTS[0], JOINTS[3], JOINTS[2]))
    assert np.array_equal(w.speeds, speeds[:, [1, 0, 3, 2]]) and w.steering is None


def test_what_is_not_supported_is_a_clear_error(bag, tmp_path):
    path = bag[0]
    with pytest.raises(BagError, match="no joint 'wheel_fl' \\(joints: front_left_wheel_joint, "):
        read_wheel_speeds(path, "/joint_states", ("wheel_fl",) + JOINTS[1:])
    with pytest.raises(BagError, match="type geometry_msgs/msg/TwistWithCovarianceStamped is not supported here "
                                       "\\(supported: sensor_msgs/JointState\\)"):
        read_wheel_speeds(path, "/radar/ego_velocity", JOINTS)
    with pytest.raises(BagError, match="supported: geometry_msgs/TwistWithCovarianceStamped, geometry_msgs/TwistStamped"):
        read_ego_velocity(path, "/joint_states")
    with pytest.raises(BagError, match="name four different wheel joints"):
        read_wheel_speeds(path, "/joint_states", JOINTS[:3] + JOINTS[:1])
    with pytest.raises(BagError, match="no such topic"):
        read_ego_velocity(path, "/radar")
    t = np.linspace(0.0, 5.0, 51)
    poses = write_bag(drive(ControlProfile(t, 3 + np.sin(t), 0 * t)), tmp_path / "poses.bag")
    with pytest.raises(BagError, match="type nav_msgs/msg/Odometry is not supported here"):
        read_wheel_speeds(poses, "/odom", JOINTS)


def test_an_empty_position_sequence_before_the_velocities(tmp_path):
    """JointState often carries velocities only: an empty ``position`` has no alignment padding."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    M = ts.types
    path = tmp_path / "velocities_only"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/wheels", "sensor_msgs/msg/JointState", typestore=ts)
        for k in range(3):
            msg = M["sensor_msgs/msg/JointState"](
                header=M["std_msgs/msg/Header"](stamp=M["builtin_interfaces/msg/Time"](sec=100 + k, nanosec=0),
                                                frame_id="x"),
                name=list(JOINTS), position=np.zeros(0), velocity=np.arange(4.0) + k, effort=np.zeros(0))
            w.write(c, (100 + k) * 10**9, ts.serialize_cdr(msg, "sensor_msgs/msg/JointState"))
    got = read_wheel_speeds(path, "/wheels", JOINTS)
    assert np.array_equal(got.speeds, np.arange(4.0)[None] + np.arange(3.0)[:, None])
    with pytest.raises(BagError, match="carries 0 positions for 4 joints: no steering angle"):
        read_wheel_speeds(path, "/wheels", JOINTS,
                          steering_joint=JOINTS[0])


def test_a_simulated_can_stream_through_a_bag_is_the_kinds_measurement(tmp_path):
    """The physical simulator's CAN stream (angular rates: ``speeds: radps``) written as
    JointState, read back, averaged over the keyframe intervals: the Ackermann kind's recorded
    measurement, and against the drive's motion it agrees to its noise."""
    from excite.validate.simulate import Calibration, Simulation, SimulationSettings

    data = car_data()
    data["ackermann"].update(speeds="radps", radius_m=0.33, speed_noise_density=0.015, speed_quantum=0.0)
    data["targets"] = {**{k: v for k, v in data["targets"].items() if k != "wheel.scale_*"},
                       "wheel.radius_*": "0.3 mm"}
    rig = build_rig(data)
    k = np.linspace(0.0, 30.0, 31)
    traj = drive(ControlProfile(k, 6 + 3 * np.sin(k / 3), 0.08 * np.sin(k / 5)), rig.suspension)
    nom = Nominal.of(traj, rig)
    sim = Simulation(traj, nom, rig, Calibration.nominal(rig), np.random.default_rng(4),
                     SimulationSettings(wheel_slip_per_g=0.0, wheel_scrub_per_g2=0.0, slip_angle_deg_per_mps2=0.0))
    rec = physical_stream(sim, rig.config.ackermann)
    path = write_vehicle_bag(tmp_path / "can.bag", wheel_t_s=rec.t, wheel_speeds=rec.speeds, steering=rec.steering_rad)
    w = read_wheel_speeds(path, "/joint_states", JOINTS, steering_joint="steering_joint")
    back = can_recording(w, int(w.t_ns[0]) - int(round(rec.t[0] * 1e9)))
    speeds, steer = interval_means(back, nom.t)
    direct = np.column_stack(interval_means(rec, nom.t))
    assert np.allclose(np.column_stack([speeds, steer]), direct, atol=1e-9)
    a = agreement(traj, rig, "ackermann", direct)
    assert 0.8 < a.whitened_rms_nominal < 1.2  # the simulated noise, nothing else
    assert any(i.kind.name == "ackermann" for i in registry.instances(rig))


@pytest.mark.parametrize("what, change, reader, words", [
    ("wheel speed", {"wheel_speeds": 1e300}, "wheels", "message 7: its wheel speed 1e+300 is outside the sane range "
                                                       "[-1000, 1000] rad/s or m/s"),
    ("steering", {"steering": -400.0}, "wheels", "message 7: its steering joint 'steering_joint''s position -400 is "
                                                 "outside the sane range [-50, 50] rad"),
    ("ego-velocity", {"radar_v": 1e300}, "radar", "message 7: its linear velocity 1e+300 is outside the sane range "
                                                  "[-150, 150] m/s"),
    ("covariance", {"radar_sigma": 1e154}, "radar", "its linear covariance entry 1e+308 is outside the sane range"),
])
def test_signals_no_car_sends_are_refused_naming_the_message_and_range(tmp_path, what, change, reader, words):
    """A wheel speed of 1e300, a steering angle of 400 rad, an ego-velocity of 1e300 m/s or a
    velocity covariance of 1e308 is no car's: an error naming the message, the value and the range."""
    t = np.arange(0.0, 2.0, 0.05)
    data = {"wheel_speeds": np.full((t.size, 4), 30.0), "steering": 0.1 * np.sin(t),
            "radar_v": np.column_stack([10 + 0 * t, 0 * t, 0 * t]), "radar_sigma": np.array([0.1, 0.4, 0.8])}
    (name, value), = change.items()
    if name == "radar_sigma":
        data[name] = np.full(3, value)
    else:
        data[name] = data[name].copy()
        data[name][7] = value
    path = write_vehicle_bag(tmp_path / "car.bag", wheel_t_s=t, wheel_speeds=data["wheel_speeds"],
                             steering=data["steering"], radar_t_s=t, radar_v=data["radar_v"],
                             radar_sigma=data["radar_sigma"])
    with pytest.raises(BagError, match=re.escape(words)):
        if reader == "wheels":
            read_wheel_speeds(path, "/joint_states", JOINTS, steering_joint="steering_joint")
        else:
            read_ego_velocity(path, "/radar/ego_velocity")
