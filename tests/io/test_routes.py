"""Route readers: rejections name file and line; writers round-trip through their readers."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from excite.io import poses, routes
from excite.cli.app import main
from excite.errors import RouteError
from excite.motion.vehicle import Limits, check_limits, drive
from helpers import weave_drive, weave_profile
from helpers import REPO

ROOT = REPO

TUM_OK = "\n".join(f"{0.1 * i:.1f} {i:.1f} 0 0 0 0 0 1" for i in range(10)) + "\n"
KITTI_ROW = "1 0 0 {x} 0 1 0 0 0 0 1 {z}"


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


def _tum_with(line_no: int, row: str) -> str:
    rows = TUM_OK.splitlines()
    rows[line_no - 1] = row
    return "\n".join(rows) + "\n"


REJECTIONS = [
    # (file name, content, line, words in the problem)
    ("empty.tum", "", None, "empty"),
    ("comments.tum", "# only a comment\n", None, "empty"),
    ("cols.tum", _tum_with(4, "0.3 1 2 3 0 0 0"), 4, "expected 8 columns, got 7"),
    ("nan.tum", _tum_with(5, "0.4 nan 0 0 0 0 0 1"), 5, "NaN"),
    ("inf.tum", _tum_with(6, "0.5 inf 0 0 0 0 0 1"), 6, "infinite"),
    ("word.tum", _tum_with(3, "0.2 one 0 0 0 0 0 1"), 3, "cannot parse 'one'"),
    ("dup.tum", _tum_with(7, "0.5 6 0 0 0 0 0 1"), 7, "duplicate time"),
    ("back.tum", _tum_with(7, "0.4 6 0 0 0 0 0 1"), 7, "backwards"),
    ("quat.tum", _tum_with(8, "0.7 7 0 0 0 0 0 1.01"), 8, "norm"),
    ("few.tum", "0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n", 2, "too few poses"),
    ("cols.csv", "x,y\n0,0\n1,1,1\n", 3, "expected 2 columns, got 3"),
    ("header.csv", "x,q\n0,0\n1,1\n", 1, "a header must be x,y"),
    ("one.csv", "x,y\n0,0\n", 2, "too few waypoints"),
    ("repeat.csv", "0,0\n5,0\n5,0\n", 3, "repeats"),
    ("stall.csv", "x,y,speed\n0,0,0\n5,0,0\n9,0,1\n", 3, "speed is 0"),
    ("negspeed.csv", "x,y,z,speed\n0,0,0,1\n5,0,0,-1\n", 3, "negative speed"),
    ("control.csv", "t_s,speed_mps,curvature_1pm\n0,1,0\n1,1,0\n1,2,0\n", 4, "duplicate time"),
    ("control_neg.csv", "t,speed,curvature\n0,1,0\n1,-1,0\n", 3, "negative speed"),
    ("control_nan.csv", "t,speed,curvature,grade\n0,1,0,0\n1,1,nan,0\n", 3, "NaN"),
    ("euroc.csv", "#timestamp,px,py,pz,qw,qx,qy,qz\n" +
     "".join(f"{i * 5000000},{i},0,0,1,0,0,0\n" for i in range(8)) + "40000000,9,0,0,2,0,0,0\n",
     10, "norm"),
    ("euroc_cols.csv", "#timestamp,px,py,pz\n0,1,2,3\n", 2, "at least 8 columns"),
    ("kitti3.txt", "1 2 3\n", None, "cannot tell the format"),
]


@pytest.mark.parametrize("name,text,line,words", REJECTIONS, ids=[r[0] for r in REJECTIONS])
def test_reader_rejects_malformed_input_naming_file_and_line(tmp_path, name, text, line, words):
    path = _write(tmp_path, name, text)
    with pytest.raises(RouteError) as exc:
        routes.read_route(path)
    assert exc.value.source == str(path) and exc.value.line == line
    assert words in str(exc.value) and str(path) in str(exc.value)
    if line is not None:
        assert f"line {line}:" in str(exc.value)


def _kitti(tmp_path, n_poses, n_times, bad_row=None):
    rows = [KITTI_ROW.format(x=0.0, z=float(i)) for i in range(n_poses)]
    if bad_row is not None:
        rows[bad_row - 1] = "2 0 0 0 0 1 0 0 0 0 1 5"
    poses = _write(tmp_path, "poses.txt", "\n".join(rows) + "\n")
    times = _write(tmp_path, "times.txt", "".join(f"{0.1 * i}\n" for i in range(n_times)))
    return poses, times


def test_kitti_rejects_length_mismatch(tmp_path):
    poses, times = _kitti(tmp_path, 10, 9)
    with pytest.raises(RouteError, match=r"times\.txt, line 9: 9 times for 10 poses"):
        routes.read_route(poses, times=times)


def test_kitti_rejects_non_rotation(tmp_path):
    poses, times = _kitti(tmp_path, 10, 10, bad_row=6)
    with pytest.raises(RouteError, match=r"poses\.txt, line 6: the 3x3 block is not a rotation"):
        routes.read_route(poses, times=times)


def test_kitti_without_times_is_explained(tmp_path):
    poses, _ = _kitti(tmp_path, 10, 10)
    with pytest.raises(RouteError, match="--times"):
        routes.read_route(poses)


def test_kitti_camera_forward_is_vehicle_x(tmp_path):
    poses, times = _kitti(tmp_path, 20, 20)  # camera moving along its z (forward) at 10 m/s
    s = routes.read_route(poses, times=times).sample(np.array([1.0]))
    np.testing.assert_allclose(s.v_W[0], [10.0, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(s.R_W_V[0], np.eye(3), atol=1e-9)


@pytest.mark.parametrize("doc,words", [
    ({"type": "Point", "coordinates": [8.5, 47.3]}, "not a LineString"),
    ({"type": "FeatureCollection", "features": []}, "exactly one"),
    ({"type": "LineString", "coordinates": [[8.5, 47.3]]}, "too few waypoints"),
    ({"type": "LineString", "coordinates": [[8.5, 47.3], [8.5, 147.3]]}, "degrees"),
    ({"type": "LineString", "coordinates": [[8.5, 47.3], [8.5]]}, "all alike"),
])
def test_geojson_rejections_name_the_line(tmp_path, doc, words):
    path = _write(tmp_path, "r.geojson", json.dumps(doc, indent=1))
    with pytest.raises(RouteError, match=words) as exc:
        routes.read_route(path)
    assert exc.value.line is not None and exc.value.source == str(path)


def test_geojson_syntax_error_names_the_line(tmp_path):
    path = _write(tmp_path, "bad.geojson", '{\n "type": "LineString",\n "coordinates": [[1, 2],,]\n}')
    with pytest.raises(RouteError, match="line 3: not valid JSON"):
        routes.read_route(path)


def test_geojson_is_projected_to_metres(tmp_path):
    # 0.001 deg of latitude ≈ 111 m north; the path starts at the origin.
    coords = [[8.54, 47.37 + 0.0005 * i, 400.0] for i in range(5)]
    path = _write(tmp_path, "north.geojson", json.dumps(
        {"type": "Feature", "properties": {"speed_mps": 5.0},
         "geometry": {"type": "LineString", "coordinates": coords}}))
    traj = routes.read_route(path)
    s = traj.sample(traj.times(10.0))
    assert traj.length_m() == pytest.approx(4 * 55.6, rel=0.01)
    assert np.abs(s.p_W_V[:, 0]).max() < 0.5 and s.p_W_V[-1, 1] > 200
    assert np.abs(s.p_W_V[:, 2]).max() < 1e-6


def test_waypoints_speed_from_limits(tmp_path):
    path = _write(tmp_path, "w.csv", "x,y\n0,0\n40,0\n60,20\n60,60\n")
    traj = routes.read_route(path)
    assert check_limits(traj, Limits()) == []
    s = traj.sample(traj.times(10.0))
    assert s.speed[0] == pytest.approx(0.0, abs=0.05) and s.speed[-1] == pytest.approx(0.0, abs=0.05)
    assert np.linalg.norm(s.p_W_V[-1, :2] - [60, 60]) < 1.0


# ------------------------------------------------------------------------------------------
# Round trips


def test_tum_round_trip(tmp_path):
    traj = weave_drive()
    back = routes.read_route(routes.write_tum(traj, tmp_path / "w.tum", rate_hz=20.0))
    t = np.linspace(1.0, traj.duration - 1.0, 200)
    a, b = traj.sample(t), back.sample(t)
    assert np.abs(a.p_W_V - b.p_W_V).max() < 0.01  # after re-centring: the drive starts at 0
    ang = np.linalg.norm(routes.so3.log(np.swapaxes(a.R_W_V, 1, 2) @ b.R_W_V), axis=1)
    assert np.degrees(ang).max() < 0.05
    assert np.abs(a.speed - b.speed).max() < 0.05


def test_control_csv_round_trip(tmp_path):
    prof = weave_profile()
    path = routes.write_control_csv(prof, tmp_path / "c.csv")
    back = routes.read_control_profile(path)
    for name in ("t_s", "speed_mps", "curvature_1pm", "grade_rad", "bank_rad"):
        np.testing.assert_allclose(getattr(back, name), getattr(prof, name), rtol=1e-9, atol=1e-12)
    assert back.start == prof.start
    a = drive(prof).sample(np.linspace(0, 30, 50))
    b = routes.read_route(path).sample(np.linspace(0, 30, 50))
    np.testing.assert_allclose(a.p_W_V, b.p_W_V, atol=1e-6)


def test_control_csv_of_a_trajectory_reproduces_it(tmp_path):
    traj = weave_drive()
    back = routes.read_route(routes.write_control_csv(traj, tmp_path / "c.csv", rate_hz=10.0))
    t = np.linspace(0, traj.duration, 100)
    assert np.abs(traj.sample(t).p_W_V - back.sample(t).p_W_V).max() < 0.1


def test_waypoints_round_trip(tmp_path):
    traj = weave_drive()
    back = routes.read_route(routes.write_waypoints_csv(traj, tmp_path / "w.csv", spacing_m=2.0))
    a = traj.sample(traj.times(20.0)).p_W_V
    b = back.sample(back.times(20.0)).p_W_V
    # Same path (every point of one is near the other) and about the same timing.
    d = np.linalg.norm(a[:, None, :2] - b[None, :, :2], axis=2).min(axis=1)
    assert d.max() < 0.3
    assert back.duration == pytest.approx(traj.duration, rel=0.02)
    assert back.length_m() == pytest.approx(traj.length_m(), rel=0.005)


def test_waypoints_that_end_at_a_stop_read_back_whatever_the_last_speed(tmp_path):
    # The last step decelerates to 0: kv + (0 - kv)/span·span rounds below zero for some kv,
    # and the route was refused as reversing (seen on an optimized maneuver's CSV download).
    rows = "\n".join(f"{2.0 * i:.1f},{0.3 * i * i:.2f},0,{v:.4f}"
                      for i, v in enumerate([0.0, 1.0, 2.5, 3.7, 4.1, 2.2]))
    for last in np.linspace(0.1, 9.9, 60):
        path = _write(tmp_path, "w.csv", f"x,y,z,speed\n{rows}\n12,12,0,{last:.4f}\n14,13,0,0\n")
        traj = routes.read_route(path)
        assert traj.sample(traj.times(20.0)).speed.min() >= 0.0


# ------------------------------------------------------------------------------------------
# CLI


def test_route_info_prints_ranges_and_violations(data_dir, capsys):
    code = main(["route", "info", str(data_dir / "kitti_00_poses.txt"), "--times",
                 str(data_dir / "kitti_00_times.txt")])
    out = capsys.readouterr().out
    assert code == 0
    for words in ("470.6 s", "speed [m/s]", "yaw rate [deg/s]", "pitch [deg]", "roll [deg]",
                  "limit violation"):
        assert words in out


def test_route_info_error_is_one_line(tmp_path, capsys):
    path = _write(tmp_path, "bad.tum", _tum_with(5, "0.4 nan 0 0 0 0 0 1"))
    assert main(["route", "info", str(path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err == f"excite: error: {path}, line 5: column 2 is NaN"


def test_route_info_subprocess(tmp_path):
    path = routes.write_control_csv(weave_profile(), tmp_path / "weave.csv")
    cmd = [sys.executable, "-c", "import sys; from excite.cli.app import main; sys.exit(main())"]
    done = subprocess.run(cmd + ["route", "info", str(path)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "30.0 s" in done.stdout and "within all limits" in done.stdout


def test_route_info_checks_a_car_rigs_steering_rate(tmp_path, capsys):
    """A curvature ramp of 0.24 1/(m·s): within the generic limit (0.25), beyond the sedan's
    steering wheel (540 deg/s at ratio 15 and a 2.70 m wheelbase: 0.2327 1/(m·s))."""
    import yaml

    from excite.motion.vehicle import ControlProfile
    from excite.rig.config import RIGS_DIR

    car = yaml.safe_load((RIGS_DIR / "sedan.yaml").read_text())["ackermann"]
    limit = np.radians(car["steering"]["rate_max_deg_per_s"]) / (car["steering"]["ratio"] * car["wheelbase_m"])
    assert limit < 0.24 < Limits().curvature_rate_max_1pms
    t = np.linspace(0.0, 10.0, 201)
    ramp = 0.12 * np.pi / (2 * 0.24)  # a smooth step of 0.12 1/m whose steepest rate is 0.24
    kappa = 0.06 * (1 - np.cos(np.pi * np.clip((t - 4.0) / ramp, 0.0, 1.0)))
    path = routes.write_control_csv(ControlProfile(t, np.full(t.size, 3.0), kappa, name="ramp"), tmp_path / "ramp.csv")
    assert main(["route", "info", str(path)]) == 0
    assert "within all limits" in capsys.readouterr().out
    assert main(["route", "info", str(path), "--rig", "sedan"]) == 0
    out = capsys.readouterr().out
    assert "limit violation" in out and "curvature_rate_max_1pms" in out, out


@pytest.mark.parametrize("lam", [1e-5, 6e-3, 2.0])
def test_smoothing_spline_is_scipys_without_the_per_point_loop(lam):
    """The banded Reinsch solve gives scipy's make_smoothing_spline (the reference it replaces
    for speed: reading a 10-minute route spent two thirds of its time in scipy's loop)."""
    from scipy.interpolate import make_smoothing_spline

    rng = np.random.default_rng(7)
    x = np.cumsum(rng.uniform(0.02, 0.2, 400))
    y = np.c_[np.sin(x), np.cos(3 * x), 0.1 * x] + 0.01 * rng.normal(size=(400, 3))
    ref, ours = make_smoothing_spline(x, y, lam=lam), poses.smoothing_spline(x, y, lam)
    g = np.linspace(x[0], x[-1], 5000)
    scale = np.abs(y).max()
    assert np.abs(ours(g) - ref(g)).max() < 1e-9 * scale
    assert np.abs(ours(g, 1) - ref.derivative()(g)).max() < 1e-8 * scale / np.diff(x).min()


def test_a_gap_in_the_poses_is_refused_where_the_smoothing_would_invent_motion(tmp_path, capsys):
    """30 s cut out of the 90 s figure-eight: the spline would bridge it with motion of its own
    (it scored *better* than the whole drive); the error names the file, the pose after the gap
    and what to do. A gap under 5 periods of the cutoff is smoothed over; a lower cutoff allows
    a longer gap."""
    rows = [r for r in (ROOT / "trajectories" / "figure_eight.tum").read_text().splitlines() if not r.startswith("#")]
    times = [float(r.split()[0]) for r in rows]
    gap = tmp_path / "gap.tum"
    gap.write_text("\n".join(r for r, t in zip(rows, times) if not 30 <= t < 60) + "\n")
    with pytest.raises(RouteError, match=r"line 301: a gap of 30.1 s before the pose at t = 60.000 s: .* split "
                                         r"the log at the gap"):
        routes.read_tum(gap)
    assert main(["score", str(gap)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"excite: error: {gap}, line 301: a gap of 30.1 s") and len(err.splitlines()) == 1
    assert routes.read_tum(gap, cutoff_hz=0.1).duration == pytest.approx(89.9, abs=0.2)  # 50 s allowed
    short = tmp_path / "short_gap.tum"
    short.write_text("\n".join(r for r, t in zip(rows, times) if not 30 <= t < 34.5) + "\n")
    assert routes.read_tum(short).duration == pytest.approx(89.9, abs=0.2)


def test_wrong_options_and_headers_are_named_as_given(tmp_path, capsys):
    """The bag option actually given (not --topic when only --start was), and a control CSV's
    misspelt header told the two headers a CSV may have."""
    assert main(["score", str(ROOT / "trajectories" / "figure_eight.tum"), "--start", "10"]) == 1
    assert "bag options (--start) apply to bags only" in capsys.readouterr().err
    bad = tmp_path / "controls.csv"
    bad.write_text("t_s,speed_mps,curvatur_1pm\n0,0,0\n5,5,0\n10,0,0\n")
    with pytest.raises(RouteError, match=r"line 1: a header must be x,y\[,z\]\[,speed\] \(waypoints\) or "
                                         r"t_s,speed_mps,curvature_1pm.* got t_s,speed_mps,curvatur_1pm"):
        routes.read_route(bad)


def test_a_tum_file_excite_wrote_reads_back_without_a_second_smoothing(tmp_path):
    """write_tum writes a smooth trajectory; smoothing it again at 1 Hz attenuated the motion, and
    a mined window's crop scored 3.6 % (slalom) to 14 % (a bag) under the window. Read back, the
    crop is the same drive (to 0.2 %); an edited first line restores the smoothing."""
    from excite.score.evaluate import evaluate
    from excite.rig.config import load_rig

    rig = load_rig("robotaxi")
    window = routes.read_route(ROOT / "trajectories" / "slalom_control.csv").cropped(30.0, 50.0)
    path = routes.write_tum(window, tmp_path / "crop.tum", rate_hz=100.0)
    want = evaluate(window, rig).score
    assert evaluate(routes.read_tum(path), rig).score == pytest.approx(want, rel=2e-3)
    text = path.read_text()
    path.write_text("# edited by hand\n" + text.split("\n", 1)[1])
    assert evaluate(routes.read_tum(path), rig).score < 0.98 * want


def test_motion_no_car_makes_is_warned_about(tmp_path, data_dir, capsys):
    """A pose moved 500 m (a jump), the EuRoC micro aerial vehicle (pitch −88°): the report says
    the numbers assume a car, and `excite score` prints it on stderr. No reference maneuver, nor
    KITTI 00, draws a warning."""
    from excite.score.evaluate import evaluate
    from excite.rig.config import load_rig
    from excite.motion.vehicle import implausible

    rows = [r for r in (ROOT / "trajectories" / "figure_eight.tum").read_text().splitlines() if not r.startswith("#")]
    f = rows[400].split()
    f[1] = str(float(f[1]) + 500.0)
    rows[400] = " ".join(f)
    jump = tmp_path / "jump.tum"
    jump.write_text("\n".join(rows) + "\n")
    rep = evaluate(routes.read_tum(jump), load_rig("robotaxi"))
    assert any(w.startswith("speed ") and "a pose jump?" in w for w in rep.warnings), rep.warnings
    assert rep.to_dict()["warnings"] == rep.warnings
    assert main(["score", str(jump), "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["warnings"] == rep.warnings
    assert err.count("warning: ") == len(rep.warnings) and "The numbers assume a car." in err
    euroc = implausible(routes.read_euroc(data_dir / "euroc_v102_groundtruth.csv"))
    assert any(w.startswith("pitch -87") for w in euroc), euroc
    for route in sorted((ROOT / "trajectories").glob("*_control.csv")) + sorted((ROOT / "trajectories").glob("*.tum")):
        assert implausible(routes.read_route(route)) == [], route.name
    assert implausible(routes.read_kitti(data_dir / "kitti_00_poses.txt", data_dir / "kitti_00_times.txt")) == []


@pytest.mark.parametrize("name", ["figure_eight.tum", "figure_eight_control.csv", "slalom.tum"])
def test_a_route_held_in_memory_reads_as_its_file(name):
    """Readers take the text itself (a service parses what it holds, no temporary file): the same
    trajectory as from the file, bit for bit, and errors name the text's name."""
    path = REPO / "trajectories" / name
    a = routes.read_route(path)
    for content in (path.read_text(), path.read_bytes()):
        b = routes.read_route(routes.Text(content, name))
        t = a.times(20.0)
        assert np.array_equal(a.sample(t).p_W_V, b.sample(t).p_W_V)
    with pytest.raises(RouteError, match=r"^mine\.tum, line 2: expected 8 columns"):
        routes.read_route(routes.Text("0 0 0 0 0 0 0 1\n1 2 3\n", "mine.tum"))
    with pytest.raises(RouteError, match=r"^x\.tum: not a text file"):
        routes.read_route(routes.Text(b"\xff\xfe\x00", "x.tum"))
