"""Bags as routes: the real ROS 1 / ROS 2 / MCAP files, TF chains, measured IMU, writer round
trips, and one-line errors for bad bags.

Expected values come from independent computations: rosbags' own full message decoding, TF
chains composed here with scipy rotations, the same samples fitted in memory.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from excite.io import bags
from excite.io.bags import decode, reader, stream  # noqa: F401 (bags.decode, .reader, .stream below)
from excite.errors import BagError
from excite.io.bags import BagSource, ImuTrajectory, imu_agreement, read_bag_route, write_bag
from excite.cli.app import main
from excite.score.evaluate import evaluate
from excite.rig.config import build_rig, load_rig
from excite.io.bags import rig_from_tf
from excite.rig.frames import Edge, chain_edges
from excite.io.poses import trajectory_from_poses
from excite.io.routes import read_route
from helpers import weave_drive
from helpers import REPO

NAV2 = "nav2_turtlebot.mcap"
SENSOR_FRAMES = {"rplidar": "rplidar_link", "oakd_rgb_camera": "oakd_rgb_camera_optical_frame"}  # name: frame


def _score(traj, rig) -> float:
    return evaluate(traj, rig).score


@pytest.fixture(scope="module")
def turtlebot_rig(data_dir):
    """The TurtleBot's rig from its own /tf_static (defaults for noise and targets)."""
    imported = rig_from_tf(data_dir / NAV2, imu="imu_link", base="base_link",
                           lidar=[SENSOR_FRAMES["rplidar"]], camera=[SENSOR_FRAMES["oakd_rgb_camera"]])
    return build_rig(imported.config)


# --------------------------------------------------------------------------------------------
# Reading the real files


def _reference_messages(path: Path, topic: str):
    """(stamp ns, frame, child, position, quaternion) per pose, from rosbags' full decoding."""
    out = []
    with AnyReader([path]) as r:
        for c, _, raw in r.messages(connections=[c for c in r.connections if c.topic == topic]):
            m = r.deserialize(raw, c.msgtype)
            for tr in getattr(m, "transforms", [m]):
                pose = getattr(tr, "transform", None)
                if pose is not None:
                    p, q = pose.translation, pose.rotation
                else:
                    pp = tr.pose.pose if hasattr(tr.pose, "pose") else tr.pose
                    p, q = pp.position, pp.orientation
                stamp = tr.header.stamp.sec * 10**9 + tr.header.stamp.nanosec
                out.append((stamp, tr.header.frame_id, getattr(tr, "child_frame_id", None),
                            (p.x, p.y, p.z), (q.x, q.y, q.z, q.w)))
    return out


@pytest.mark.parametrize("name,topic", [(NAV2, "/odom"), (NAV2, "/amcl_pose"), (NAV2, "/tf"),
                                        (NAV2, "/tf_static"), ("ROS_example.bag", "groundtruth"),
                                        ("tf_example_ros2", "/tf")])
def test_field_decoder_matches_full_message_decoding(data_dir, name, topic):
    """The fast decoder reads the same stamps, frames and poses as rosbags' message objects."""
    path = data_dir / name
    ref = _reference_messages(path, topic)
    mine = []
    with bags.stream.open_bag(path) as reader:
        cons = [c for c in reader.connections if c.topic == topic]
        fn = bags.decode.DECODERS[cons[0].msgtype]
        for i, (_, raw) in enumerate(bags.stream.stream_messages(path, reader, cons, topic)):
            mine += bags.decode.decode_message(path, topic, i, fn, raw, bags.stream.is_ros2(cons[0]))
    assert len(mine) == len(ref) > 0
    for (t, f, ch, pose), (t_r, f_r, ch_r, p_r, q_r) in zip(mine, ref):
        assert (t, f) == (t_r, f_r)
        assert ch == ch_r or ch_r is None
        assert pose == tuple(p_r) + tuple(q_r)


@pytest.mark.parametrize("topic", ["/odom", "/amcl_pose", "/tf:odom.base_link"])
def test_mcap_chunk_reader_reads_what_rosbags_reads(data_dir, topic, monkeypatch):
    """The MCAP chunk reader (message indexes, numpy gathers) against rosbags' reader, with and
    without a window."""
    path = data_dir / NAV2
    for window in ({}, {"start_s": 20.0, "end_s": 50.0}):
        fast = bags.read_poses(path, topic, **window)
        with monkeypatch.context() as m:
            m.setattr(bags.reader, "mcap_files", lambda p: None)
            slow = bags.read_poses(path, topic, **window)
        assert np.array_equal(fast.t_ns, slow.t_ns) and fast.t_ns.size > 10
        assert np.array_equal(fast.p, slow.p) and np.array_equal(fast.q, slow.q)
        assert (fast.frame, fast.child) == (slow.frame, slow.child)


def test_route_info_lists_topics_types_rates_and_sources(data_dir, capsys):
    info = {t.topic: t for t in bags.bag_info(data_dir / NAV2)}
    assert info["/odom"].msgtype == "nav_msgs/msg/Odometry" and info["/odom"].count == 2639
    assert info["/odom"].use == "pose" and 90 < info["/odom"].duration_s < 100
    assert "/tf:odom.base_link" in info["/tf"].sources and "/tf:map.odom" in info["/tf"].sources
    assert info["/amcl_pose"].use == "pose" and info["/tf_static"].use == ""
    assert main(["route", "info", str(data_dir / NAV2)]) == 0
    out = capsys.readouterr().out
    assert "/tf:odom.base_link" in out and "nav_msgs/Odometry" in out and "2639" in out


def test_odom_topic_and_tf_chain_give_the_same_score(data_dir, turtlebot_rig):
    """/odom (nav_msgs/Odometry) and /tf:odom.base_link describe the same motion: the same σ per
    parameter (within 1 %), the same unobservable set, and the same score on a rig whose
    parameters a planar drive determines."""
    path = data_dir / NAV2
    odom = evaluate(read_route(path, bag=BagSource("/odom")), turtlebot_rig)
    tf = evaluate(read_route(path, bag=BagSource("/tf:odom.base_link")), turtlebot_rig)
    for a, b in zip(odom.parameters, tf.parameters):
        assert (a.sigma is None) == (b.sigma is None), a.name
        if a.sigma is not None:
            assert b.sigma == pytest.approx(a.sigma, rel=0.01), a.name
    # planar driving leaves the vertical lever arms undetermined (DESIGN.md's table)
    unobservable = {p.name for p in odom.parameters if p.sigma is None}
    assert {"rplidar.trans_z", "oakd_rgb_camera.trans_z"} <= unobservable
    sensors = [dict(s.model_dump(), estimate={"extrinsic": False, "time_offset": True})
               for s in turtlebot_rig.config.sensors]
    targets = {k: v for k, v in turtlebot_rig.config.targets.items() if "rot" not in k and "trans" not in k}
    observable = turtlebot_rig.with_config(sensors=sensors, targets=targets)
    s_odom = _score(read_route(path, bag=BagSource("/odom")), observable)
    s_tf = _score(read_route(path, bag=BagSource("/tf:odom.base_link")), observable)
    assert s_odom > 0
    assert s_tf == pytest.approx(s_odom, rel=0.01)


def test_turtlebot_scores_from_the_command_line(data_dir, tmp_path, capsys):
    """The README flow: a rig from the bag's TF tree, then the bag scored with it."""
    rig = tmp_path / "turtlebot.yaml"
    assert main(["rig", "from-tf", str(data_dir / NAV2), "--imu", "imu_link", "--base", "base_link",
                 "--lidar", "rplidar_link", "--camera", "oakd_rgb_camera_optical_frame", "-o", str(rig)]) == 0
    assert "# REVIEW: " in rig.read_text()
    capsys.readouterr()
    assert main(["score", str(data_dir / NAV2), "--topic", "/odom", "--rig", str(rig), "--json"]) == 0
    import json

    rep = json.loads(capsys.readouterr().out)
    assert rep["score"] is not None and np.isfinite(rep["score"]) and 90 < rep["duration_s"] < 100


def test_slam_estimate_gives_the_same_verdict_as_ground_truth(data_dir):
    """ROS_example.bag: ORB-SLAM is a noisy estimate of the ground-truth drive (camera-optical
    axes); over the same 5 minutes, every parameter gets the same pass/fail."""
    path = data_dir / "ROS_example.bag"
    rig = load_rig("robotaxi")
    # 5 minutes from the start of the SLAM estimate (bag time = header stamps in this bag)
    start = (bags.read_poses(path, "ORB-SLAM").t_ns[0] - bags.read_poses(path, "groundtruth").t_ns[0]) * 1e-9
    window = {"start_s": start, "end_s": start + 300.0}
    slam = read_route(path, bag=BagSource("ORB-SLAM", axes="optical", **window))
    truth = read_route(path, bag=BagSource("groundtruth", axes="optical", **window))
    a, b = evaluate(truth, rig), evaluate(slam, rig)
    assert a.score > 0 and b.score > 0
    assert [p.ok for p in a.parameters] == [p.ok for p in b.parameters]
    assert any(p.ok for p in a.parameters) and not all(p.ok for p in a.parameters)


def test_tf_chain_in_a_ros2_sqlite_bag_composes_every_hop(data_dir):
    """tf_example_ros2/: /tf:odom.base_link = odom→base_footprint (/tf) · base_footprint→base_link
    (/tf_static), composed here independently; the chain then scores."""
    path = data_dir / "tf_example_ros2"
    got = bags.read_poses(path, "/tf:odom.base_link")
    dyn = _reference_messages(path, "/tf")
    (_, parent, child, p_s, q_s), = _reference_messages(path, "/tf_static")
    assert (parent, child) == ("base_footprint", "base_link")
    R_s = Rotation.from_quat(q_s)
    t = np.array([m[0] for m in dyn])
    R_d = Rotation.from_quat([m[4] for m in dyn])
    p_expect = np.array([m[3] for m in dyn]) + R_d.apply(p_s)
    R_expect = (R_d * R_s).as_matrix()
    assert np.array_equal(got.t_ns, t)
    np.testing.assert_allclose(got.p, p_expect, atol=1e-12)
    np.testing.assert_allclose(got.R, R_expect, atol=1e-12)
    rep = evaluate(read_route(path, bag=BagSource("/tf:odom.base_link")), load_rig("robotaxi"))
    assert np.isfinite(rep.score) and rep.duration_s == pytest.approx(51.6, abs=0.2)


def test_rig_from_tf_static_matches_the_composed_tree(data_dir, turtlebot_rig):
    """T_V_B and each sensor's T_B_S equal the /tf_static chain composed here from rosbags'
    messages with scipy: T_base_imu, T_imu_sensor = T_base_imu⁻¹ · T_base_sensor."""
    tree = {child: (parent, Rotation.from_quat(q), np.array(p))
            for _, parent, child, p, q in _reference_messages(data_dir / NAV2, "/tf_static")}

    def in_base(frame):
        R, p = Rotation.identity(), np.zeros(3)
        while frame != "base_link":
            parent, R_e, p_e = tree[frame]
            R, p = R_e * R, R_e.apply(p) + p_e
            frame = parent
        return R, p

    R_vb, p_vb = in_base("imu_link")
    cfg = turtlebot_rig.config
    np.testing.assert_allclose(cfg.vehicle.T_V_B.R, R_vb.as_matrix(), atol=1e-9)
    np.testing.assert_allclose(cfg.vehicle.T_V_B.p, p_vb, atol=1e-9)
    for sensor in cfg.sensors:
        R_vs, p_vs = in_base(SENSOR_FRAMES[sensor.name])
        R_bs, p_bs = R_vb.inv() * R_vs, R_vb.inv().apply(p_vs - p_vb)
        np.testing.assert_allclose(sensor.T_B_S.R, R_bs.as_matrix(), atol=1e-9)
        np.testing.assert_allclose(sensor.T_B_S.p, p_bs, atol=1e-9)
    # the optical frame looks along the robot's x: its z axis is base x
    cam = next(s for s in cfg.sensors if s.kind == "camera")
    np.testing.assert_allclose((R_vb.as_matrix() @ cam.T_B_S.R)[:, 2], [1, 0, 0], atol=1e-9)


# --------------------------------------------------------------------------------------------
# Round trips through the writer


@pytest.fixture(scope="module")
def drive():
    return weave_drive()


def _reference_score(drive, rig, rate_hz: float = 50.0) -> float:
    """The score of the same pose samples (stamps in whole nanoseconds, as a bag stores them)
    fitted in memory."""
    s = drive.sample(drive.times(rate_hz))
    t = np.round((s.t - s.t[0]) * 1e9) * 1e-9
    return _score(trajectory_from_poses(t, s.p_W_V, s.R_W_V, name="ref"), rig)


@pytest.mark.parametrize("suffix,msgtype,topic", [
    ("", "nav_msgs/msg/Odometry", "/odom"),
    (".bag", "nav_msgs/msg/Odometry", "/odom"),
    ("", "geometry_msgs/msg/PoseStamped", "/pose"),
    (".bag", "geometry_msgs/msg/PoseWithCovarianceStamped", "/pose"),
    ("", "geometry_msgs/msg/TransformStamped", "/transform"),
    (".bag", "nav_msgs/msg/Odometry", "/tf:odom.base_link"),
    ("", "nav_msgs/msg/Odometry", "/tf:odom.base_link"),
])
def test_written_bag_reads_back_to_the_same_score(tmp_path, drive, suffix, msgtype, topic):
    rig = load_rig("robotaxi")
    tf = topic.startswith("/tf:")
    path = write_bag(drive, tmp_path / f"drive{suffix}", topic="/odom" if tf else topic,
                     msgtype=msgtype, tf=tf)
    expected = _reference_score(drive, rig)
    got = _score(read_route(path, bag=BagSource(topic)), rig)
    assert got == pytest.approx(expected, rel=1e-9)
    if suffix == "":  # the ROS 2 folder's .mcap reads on its own
        (mcap,) = path.glob("*.mcap")
        assert _score(read_route(mcap, bag=BagSource(topic)), rig) == pytest.approx(expected, rel=1e-9)


def test_vehicle_frame_moves_the_poses_through_tf_static(tmp_path, drive):
    """Poses of base_link moved to imu_link via /tf_static are the IMU's poses, composed here
    from the same samples and fitted the same way."""
    R_vb, p_vb = Rotation.from_euler("z", 30, degrees=True).as_matrix(), np.array([0.4, -0.1, 0.7])
    path = write_bag(drive, tmp_path / "d", tf=True, T_V_B=(R_vb, p_vb))
    traj = read_route(path, bag=BagSource("/odom", vehicle_frame="imu_link"))
    s = drive.sample(drive.times(50.0))
    t = np.round((s.t - s.t[0]) * 1e9) * 1e-9
    expected = trajectory_from_poses(t, s.p_W_V + s.R_W_V @ p_vb, s.R_W_V @ R_vb)
    got, want = traj.sample(traj.times(50.0)), expected.sample(expected.times(50.0))
    np.testing.assert_allclose(got.p_W_V, want.p_W_V, atol=1e-6)
    np.testing.assert_allclose(got.R_W_V, want.R_W_V, atol=1e-9)


# --------------------------------------------------------------------------------------------
# Measured IMU


def test_measured_imu_replaces_the_pose_derivatives_and_agrees(tmp_path, drive):
    rig = load_rig("robotaxi")
    pose = rig.config.vehicle.T_V_B
    path = write_bag(drive, tmp_path / "d", imu_topic="/imu", T_V_B=(pose.R, pose.p))
    traj = read_bag_route(path, "/odom", imu_topic="/imu")
    assert isinstance(traj, ImuTrajectory) and traj.imu_frame == "imu_link"
    mcap_path = bags.read_imu(path, "/imu")
    with pytest.MonkeyPatch.context() as m:
        m.setattr(bags.reader, "mcap_files", lambda p: None)
        rosbags_path = bags.read_imu(path, "/imu")
    assert np.array_equal(mcap_path.omega, rosbags_path.omega) and np.array_equal(mcap_path.t_ns, rosbags_path.t_ns)
    t = traj.times(200.0)[10:-10]
    _, w, f = traj.imu(t, pose.R, pose.p)
    _, w_true, f_true = drive.imu(t + drive.t_start, pose.R, pose.p)
    np.testing.assert_allclose(w, w_true, atol=1e-9)  # the measured samples, not the fit's
    np.testing.assert_allclose(f, f_true, atol=1e-9)
    agree = imu_agreement(traj, pose.R, pose.p)
    assert agree.misalignment_deg is not None and agree.misalignment_deg < 0.5
    assert np.degrees(agree.gyro_rms_radps) < 0.2 and agree.accel_rms_mps2 < 0.1
    plain = _score(read_bag_route(path, "/odom"), rig)
    assert _score(traj, rig) == pytest.approx(plain, rel=0.1)


def test_imu_mounted_otherwise_than_the_rig_says_shows_as_misalignment(tmp_path, drive):
    rig = load_rig("robotaxi")
    pose = rig.config.vehicle.T_V_B
    tilted = Rotation.from_euler("z", 10, degrees=True).as_matrix() @ pose.R
    path = write_bag(drive, tmp_path / "d", imu_topic="/imu", T_V_B=(tilted, pose.p))
    traj = read_bag_route(path, "/odom", imu_topic="/imu")
    agree = imu_agreement(traj, pose.R, pose.p)
    assert agree.misalignment_deg == pytest.approx(10.0, abs=1.0)


# --------------------------------------------------------------------------------------------
# Bad bags: one-line errors naming file, topic and problem


def _cli_error(capsys, *args) -> str:
    assert main(["score", *map(str, args)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("excite: error: ") and "\n" not in err and "Traceback" not in err
    return err


def test_unknown_topic_lists_the_available_ones(data_dir, capsys):
    err = _cli_error(capsys, data_dir / NAV2, "--topic", "/odometry")
    assert NAV2 in err and "/odometry" in err and "/odom, /tf, /tf_static" in err


def test_bag_without_topic_lists_what_it_can_score(data_dir, capsys):
    err = _cli_error(capsys, data_dir / "tf_example_ros2")
    assert "--topic" in err and "/tf:odom.base_footprint" in err


def test_type_without_a_pose_and_tf_without_chain(tmp_path, drive, capsys):
    path = write_bag(drive, tmp_path / "d", imu_topic="/imu", tf=True)
    err = _cli_error(capsys, path, "--topic", "/imu")
    assert "/imu" in err and "sensor_msgs/msg/Imu carries no pose" in err
    err = _cli_error(capsys, path, "--topic", "/tf")
    assert "/tf:PARENT.CHILD" in err


def test_tf_chain_that_does_not_connect_names_the_missing_link(tmp_path, data_dir, capsys):
    err = _cli_error(capsys, data_dir / "tf_example_ros2", "--topic", "/tf:odom.lidar")
    assert "'lidar'" in err and "base_footprint" in err  # the unknown frame, with the known ones
    edges = {"base_link": Edge("odom", "base_link"),
             "camera": Edge("camera_mount", "camera", p=[(0, 0, 0)], q=[(0, 0, 0, 1)])}
    with pytest.raises(BagError, match="'odom' and 'camera_mount'"):
        chain_edges(Path("x.bag"), "/tf:odom.camera", "odom", "camera", edges)


def _write_poses(path: Path, stamps_ns: list[int], topic: str = "/pose") -> Path:
    ts = get_typestore(Stores.ROS2_HUMBLE)
    M = ts.types
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection(topic, "geometry_msgs/msg/PoseStamped", typestore=ts)
        w.add_connection("/empty", "geometry_msgs/msg/PoseStamped", typestore=ts)
        for k, t in enumerate(stamps_ns):
            msg = M["geometry_msgs/msg/PoseStamped"](
                header=M["std_msgs/msg/Header"](stamp=M["builtin_interfaces/msg/Time"](
                    sec=t // 10**9, nanosec=t % 10**9), frame_id="map"),
                pose=M["geometry_msgs/msg/Pose"](
                    position=M["geometry_msgs/msg/Point"](x=float(k), y=0.0, z=0.0),
                    orientation=M["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))
            w.write(c, 10**18 + k * 10**8, ts.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped"))
    return path


def test_non_monotonic_stamps_and_empty_topics(tmp_path, capsys):
    stamps = [10**18 + k * 10**8 for k in range(20)]
    stamps[7], stamps[8] = stamps[8], stamps[7]
    path = _write_poses(tmp_path / "p", stamps)
    err = _cli_error(capsys, path, "--topic", "/pose")
    assert "/pose" in err and "not monotonic" in err and "message 8" in err
    err = _cli_error(capsys, path, "--topic", "/empty")
    assert "/empty" in err and "no messages" in err
    err = _cli_error(capsys, path, "--topic", "/pose", "--start", "100")
    assert "no messages in the window" in err


def test_truncated_and_corrupt_bags(tmp_path, data_dir, capsys):
    for name, keep in ((NAV2, 0.5), ("ROS_example.bag", 0.5)):
        cut = tmp_path / name
        data = (data_dir / name).read_bytes()
        cut.write_bytes(data[:int(len(data) * keep)])
        err = _cli_error(capsys, cut, "--topic", "/odom")
        assert str(cut) in err and "truncated or corrupt" in err
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not a bag at all" * 64)
    assert "truncated or corrupt" in _cli_error(capsys, junk, "--topic", "/odom")


def test_topic_options_on_a_text_route_are_refused(capsys):
    route = REPO / "trajectories" / "circle_left.tum"
    err = _cli_error(capsys, route, "--topic", "/odom")
    assert "bags only" in err


# --------------------------------------------------------------------------------------------
# Batch


def test_batch_manifest_takes_bags_with_topics(data_dir, tmp_path):
    from excite.fleet import batch as gate

    manifest = tmp_path / "routes.yaml"
    manifest.write_text(f"""\
rig: robotaxi
routes:
  - route: {data_dir / NAV2}
    topic: /tf:odom.base_link
    min_score: 0
  - route: {data_dir / 'tf_example_ros2'}
    topic: /tf:odom.base_link
    min_score: 0
  - route: {data_dir / NAV2}
    name: no-such-topic
    topic: /nope
""")
    results = gate.run(gate.collect([manifest]), jobs=1)
    assert [r.status for r in results] == ["passed", "passed", "error"]
    assert "/nope" in results[2].error and "/odom" in results[2].error
