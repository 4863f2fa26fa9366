"""GNSS fixes read from bags: sensor_msgs/NavSatFix in ROS 1, ROS 2 and MCAP, their
status and covariance, the drive carrying them, and the Husky bag scored with its GPS."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

import excite.cli.score  # noqa: F401  (registers `excite score` on the app)
from excite.cli.app import app
from excite.errors import BagError
from excite.io.bags import bag_info, fix_agreement, read_bag_route, read_fixes, write_bag

from excite.io.bags.reader import _bag_route
from excite.motion.maneuvers import figure_eight
from excite.motion.trajectory import SensorLog
from excite.motion.vehicle import drive
from excite.rig.config import build_rig, load_rig
from excite.score.evaluate import evaluate
from helpers import gnss_rig, sigmas
from helpers import REPO

EXAMPLES = REPO / "examples"
HUSKY = "husky_robot_localization.bag"
ODOM, IMU = "/husky_velocity_controller/odom", "/imu/data"


@pytest.fixture(scope="module")
def eight():
    return drive(figure_eight(30.0), gnss_rig().suspension)


@pytest.mark.parametrize("suffix", [".bag", ""])
def test_navsatfix_round_trip(tmp_path, eight, suffix):
    """ROS 1 and a ROS 2 folder with MCAP storage (whose .mcap reads on its own): fixes every
    0.1 s, an outage of 'no fix' messages from 10 to 14 s, a diagonal covariance."""
    path = write_bag(eight, tmp_path / f"drive{suffix}", rate_hz=50.0, fix_topic="/fix", fix_rate_hz=10.0,
                     fix_sigma_m=(0.03, 0.06), fix_outages=((10.0, 14.0),))
    paths = [path] if suffix else [path, next(path.glob("*.mcap"))]
    n = eight.times(10.0).size
    for p in paths:
        fixes = read_fixes(p, "/fix")
        assert fixes.t_ns.size == n and fixes.frame == "gnss"
        off = ~fixes.fixed
        assert off.sum() == 41  # 10.0 … 14.0 s
        assert np.allclose(fixes.covariance[0], np.diag([0.03 ** 2, 0.03 ** 2, 0.06 ** 2]))
        enu = fixes.enu()
        truth = eight.sample(eight.times(10.0)).p_W_V
        assert np.abs(enu - (truth - truth[0])).max() < 1e-3  # geodetic and back, with pyproj
        traj = read_bag_route(p, "/odom", gnss_topic="/fix", gnss_sensor="antenna")
        log = traj.logs["antenna"]
        assert log.t.size == n - 41 and not np.any((log.t > 9.95) & (log.t < 14.05))
        assert np.allclose(log.covariance[5], np.diag([0.03 ** 2, 0.03 ** 2, 0.06 ** 2]))
    assert {ti.topic: ti.use for ti in bag_info(path)}["/fix"] == "gnss"


def test_a_bags_fixes_score_as_the_same_log_given_directly(tmp_path, eight):
    path = write_bag(eight, tmp_path / "drive.bag", rate_hz=50.0, fix_topic="/fix", fix_outages=((10.0, 14.0),))
    rig = gnss_rig()
    from_bag = read_bag_route(path, "/odom", gnss_topic="/fix")
    plain, _ = _bag_route(path, "/odom", None, None, None, None, "vehicle", 1.0, None)
    t = np.arange(eight.times(10.0).size) * 0.1
    direct = plain.with_logs({"gnss": SensorLog(t[(t < 9.99) | (t > 14.01)])})
    assert sigmas(evaluate(from_bag, rig)) == pytest.approx(sigmas(evaluate(direct, rig)), rel=1e-12)
    assert sigmas(evaluate(from_bag, rig))["gnss.trans_x"] > sigmas(evaluate(plain, rig))["gnss.trans_x"]


def test_clear_errors(tmp_path, eight):
    path = write_bag(eight, tmp_path / "drive.bag", rate_hz=50.0, fix_topic="/fix")
    with pytest.raises(BagError, match=r"/odom.*not sensor_msgs/NavSatFix"):
        read_fixes(path, "/odom")
    with pytest.raises(BagError, match=r"no such topic.*/fix"):
        read_fixes(path, "/gps")
    with pytest.raises(BagError, match="no fixes in the window"):
        read_fixes(path, "/fix", start_s=100.0, end_s=200.0)


def _edited_fixes(src, dst, edit):
    """``src`` (a ROS 1 bag) rewritten to ``dst`` with every NavSatFix message passed through ``edit``."""
    import dataclasses

    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    with Reader(src) as r, Writer(dst) as w:
        conns = {c.id: w.add_connection(c.topic, c.msgtype, typestore=ts) for c in r.connections}
        for c, t, raw in r.messages():
            if c.msgtype == "sensor_msgs/msg/NavSatFix":
                raw = ts.serialize_ros1(edit(ts.deserialize_ros1(raw, c.msgtype), dataclasses.replace), c.msgtype)
            w.write(conns[c.id], t, raw)
    return dst


@pytest.mark.parametrize("name, edit, words", [
    ("no_fix", lambda m, re: re(m, status=re(m.status, status=-1)), "no fixes: each of its 300 messages says NO_FIX"),
    ("lat91", lambda m, re: re(m, latitude=91.0), "fix 0: its latitude 91 is outside the sane range [-90, 90] deg"),
    ("lat1e300", lambda m, re: re(m, latitude=1e300), "fix 0: its latitude 1e+300 is outside the sane range"),
    ("lon", lambda m, re: re(m, longitude=-181.5), "fix 0: its longitude -181.5 is outside the sane range"),
    ("alt", lambda m, re: re(m, altitude=1e9), "fix 0: its altitude 1e+09 is outside the sane range"),
    ("cov", lambda m, re: re(m, position_covariance=np.diag([1e308, 1.0, 1.0]).ravel()),
     "fix 0: its position_covariance entry 1e+308 is outside the sane range"),
])
def test_fixes_out_of_range_are_one_line_errors_in_the_cli(tmp_path, capsys, eight, name, edit, words):
    """Fixes no receiver reports (a latitude past the pole, a covariance of 1e308 m², a topic of
    NO_FIX only) are refused naming the fix, the number and the range: in the library and as the
    command line's one-line error (exit 1, no traceback)."""
    from excite.cli.app import main

    base = write_bag(eight, tmp_path / "drive.bag", rate_hz=50.0, fix_topic="/fix")
    path = _edited_fixes(base, tmp_path / f"{name}.bag", edit)
    with pytest.raises(BagError, match=re.escape(words)):
        read_fixes(path, "/fix")
    rig = tmp_path / "rig.yaml"
    rig.write_text(yaml.safe_dump(gnss_rig().config.model_dump(mode="json", exclude_none=True)))
    capsys.readouterr()
    assert main(["score", str(path), "--topic", "/odom", "--gnss-topic", "/fix", "--rig", str(rig)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("excite: error:") and words in err[0], err


def test_the_husky_bags_gps(data_dir):
    """989 NavSatFix at 2.5 Hz, no outage, SBAS fixes with an approximated diagonal covariance
    (the up variance 4× the horizontal); the fixes follow the wheel odometry's path to the metres
    a skid steer drifts by."""
    path = data_dir / HUSKY
    fixes = read_fixes(path, "/fix")
    assert fixes.t_ns.size == 989 and np.all(fixes.status == 1) and fixes.frame == "/gps"
    c = fixes.covariance
    assert np.allclose(c[:, 0, 0], c[:, 1, 1]) and np.allclose(c[:, 2, 2], 4 * c[:, 0, 0])
    assert 0.6 < c[:, 0, 0].min() and c[:, 0, 0].max() < 3.0
    traj, t0 = _bag_route(path, ODOM, None, None, None, None, "vehicle", 1.0, None)
    a = fix_agreement(traj, fixes, t0)
    assert a.n_fixes == 989 and a.rate_hz == pytest.approx(2.5, rel=0.01) and a.longest_gap_s < 0.5
    assert 2.0 < a.horizontal_rms_m < 15.0


def test_the_husky_bag_scored_with_its_gps(data_dir):
    """examples/husky_gnss.yaml through ``excite score --gnss-topic``: what the README says it
    determines (the horizontal lever arm to about a decimetre, the time offset to about 0.1 s; the
    vertical lever arm not at all: a rigid robot on a flat lot)."""
    args = ["score", str(data_dir / HUSKY), "--rig", str(EXAMPLES / "husky_gnss.yaml"), "--topic", ODOM,
            "--imu-topic", IMU, "--gnss-topic", "/fix", "--json"]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    s = {p["name"]: p["sigma"] for p in rep["parameters"]}
    assert s["gnss.trans_y"] is None  # B's y is the robot's up axis (the IMU is mounted on its side)
    assert 0.05 < s["gnss.trans_x"] < 0.3 and 0.05 < s["gnss.trans_z"] < 0.3
    assert 0.03 < s["gnss.time_offset"] < 0.3
    assert "989 fixes" in r.stderr
    vertical = [m for m in rep["weak_modes"] if m["status"] == "unobservable"]
    assert vertical and "suspension" in vertical[0]["advice"]


def test_the_gnss_topic_needs_one_antenna(data_dir):
    r = CliRunner().invoke(app, ["score", str(data_dir / HUSKY), "--topic", ODOM, "--gnss-topic", "/fix"])
    assert r.exit_code != 0 and "0 GNSS antennas" in r.output
    assert load_rig("robotaxi")  # (the bundled rig has none)


# --- importers ---------------------------------------------------------------------------------


def test_autoware_places_the_gnss_frame_it_finds(data_dir):
    """Autoware's sample sensor kit has a gnss_link at (-0.1, 0, -0.2) on the kit, whose IMU sits at
    the kit's origin turned by roll π, yaw π (R = diag(-1, 1, -1)): the antenna is at (0.1, 0, 0.2)
    in the IMU frame (its orientation dropped), with the standalone preset marked for review."""
    from excite.rig.importers import rig_from_autoware

    d = data_dir / "rig_files" / "autoware"
    imported = rig_from_autoware(d / "sensor_kit_calibration.yaml", sensors_calibration=d / "sensors_calibration.yaml")
    rig = build_rig(imported.config)
    (gnss,) = [s for s in rig.config.sensors if s.kind == "gnss"]
    assert gnss.name == "gnss"
    np.testing.assert_allclose(gnss.T_B_S.p, [0.1, 0.0, 0.2], atol=1e-9)
    assert gnss.T_B_S.rpy_deg is None and gnss.T_B_S.matrix is None
    i = [s["name"] for s in imported.config["sensors"]].index("gnss")
    assert "standalone" in imported.review[f"sensors.{i}.noise"]
    assert {c.name for c in rig.coordinates} >= {"gnss.trans_x", "gnss.time_offset"}
    none = rig_from_autoware(d / "sensor_kit_calibration.yaml", sensors_calibration=d / "sensors_calibration.yaml",
                             gnss=[])
    assert not [s for s in none.config["sensors"] if s["kind"] == "gnss"]


def test_tf_import_places_a_named_antenna(data_dir):
    from excite.io.bags import read_static_tf
    from excite.io.bags import rig_from_tf

    path = data_dir / "nav2_turtlebot.mcap"
    static = read_static_tf(path)
    assert not any("gps" in f or "gnss" in f for f in static)  # none to find: nothing placed
    assert not [s for s in rig_from_tf(path, imu="imu_link", base="base_link").config["sensors"]
                if s["kind"] == "gnss"]
    frame = "rplidar_link"  # stand-in for an antenna frame of this tree
    imported = rig_from_tf(path, imu="imu_link", base="base_link", gnss=[frame])
    (entry,) = imported.config["sensors"]
    assert entry["kind"] == "gnss" and set(entry["T_B_S"]) == {"translation_m"}
