"""The comma2k19 reader (:mod:`excite.io.comma2k19`) on the real RAV4 minute and on folders made
here: one clock, excite's frames, the facts a user relies on (column orders, signs, units, the
GNSS fix epochs), clear errors; and the minute scored from its own CAN wheels, steering and IMU
with the pose as the motion, and with its u-blox GNSS (examples/comma2k19_gnss.yaml)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from excite.errors import RouteError
from excite.factors.ackermann import interval_means
from excite.factors.base import Nominal
from excite.io import comma2k19 as c2k
from excite.io.routes import read_route
from excite.motion.trajectory import SensorLog
from excite.rig.config import load_rig
from excite.score.agreement import agreement
from excite.score.evaluate import evaluate
from helpers import REPO

EXAMPLES = REPO / "examples"


@pytest.fixture(scope="module")
def folder(data_dir) -> Path:
    p = data_dir / "comma2k19_rav4_seg40"
    if not p.is_dir():
        pytest.skip(f"{p} not found")
    return p


@pytest.fixture(scope="module")
def rec(folder):
    return c2k.read_comma2k19(folder)


@pytest.fixture(scope="module")
def rig():
    return load_rig(EXAMPLES / "comma2k19_rav4_can.yaml")


# --- the reader -------------------------------------------------------------------------------


def test_every_signal_is_on_one_clock_from_the_first_pose(rec):
    assert rec.pose.t[0] == 0.0 and rec.pose.t[-1] == pytest.approx(59.95, abs=0.01)
    assert rec.t0_boot_s == pytest.approx(46408.5475, abs=1e-3)
    for s in (rec.gyro, rec.accel, rec.wheel_speeds, rec.steering_rad):
        assert -0.1 < s.t[0] < 0.1 and 59.9 < s.t[-1] < 60.1
    assert rec.radar.t[0] == pytest.approx(0.04, abs=0.01)
    for g in rec.gnss.values():
        lag = g.t - g.fix_t  # logged after the fix epoch: the receiver's latency
        assert 0.1 < lag.min() and lag.max() < 0.3


def test_the_imu_is_in_excites_body_axes(rec):
    """FRD → FLU: at rest on a level road the specific force is +g up; the mean here (a nearly
    level highway, the device pitched 4° down) is close to it."""
    f = rec.accel.value.mean(axis=0)
    assert 9.5 < f[2] < 9.9 and abs(f[1]) < 0.3
    # the gyro's rate about up follows the pose's heading (the minute turns by −0.44° net)
    yaw = np.unwrap(np.arctan2(rec.pose.R_W_C[:, 1, 0], rec.pose.R_W_C[:, 0, 0]))
    assert np.degrees(yaw[-1] - yaw[0]) == pytest.approx(-0.44, abs=0.1)
    rate = np.gradient(yaw, rec.pose.t)
    k = np.searchsorted(rec.gyro.t, rec.pose.t[2:-2])
    gz = np.convolve(rec.gyro.value[:, 2], np.ones(21) / 21, mode="same")[k]
    assert np.corrcoef(gz, np.convolve(rate, np.ones(5) / 5, mode="same")[2:-2])[0, 1] > 0.9


def test_wheel_speeds_are_fl_fr_rl_rr_and_the_steering_is_left_positive(rec):
    """Right minus left correlates positively with the yaw rate (left turn: the right wheels run
    the longer path), and so does the steering angle."""
    w = rec.wheel_speeds
    yaw_rate = np.interp(w.t, rec.gyro.t, rec.gyro.value[:, 2])
    smooth = lambda x: np.convolve(x, np.ones(40) / 40, mode="same")  # noqa: E731
    assert np.corrcoef(smooth(w.value[:, 3] - w.value[:, 2]), smooth(yaw_rate))[0, 1] > 0.1
    assert np.corrcoef(smooth(np.interp(w.t, rec.steering_rad.t, rec.steering_rad.value)), smooth(yaw_rate))[0, 1] > 0.7
    assert np.abs(np.diff(np.unique(w.value[:, 0]))).min() == pytest.approx(c2k.KMH_QUANTUM_MPS, rel=1e-3)
    assert rec.steering_rad.value.max() < np.radians(5)


def test_the_pose_is_the_cameras_in_enu_and_v_is_along_the_travel(rec):
    assert rec.pose.origin[0] == pytest.approx(37.7210000, abs=1e-6)
    assert rec.pose.origin[1] == pytest.approx(-122.4722991, abs=1e-6)
    R_V_C = c2k.camera_in_vehicle(rec)
    # the camera points ~0.8° left of the travel and ~3.8° below it: in its axes the travel is right and up
    d = R_V_C.T @ np.array([1.0, 0.0, 0.0])  # V's x in camera axes
    assert np.degrees(np.arctan2(d[1], d[0])) == pytest.approx(-0.82, abs=0.2)
    assert np.degrees(np.arcsin(d[2])) == pytest.approx(3.76, abs=0.2)
    traj = c2k.trajectory(rec, measured_imu=False)
    s = traj.sample(traj.times(5.0))
    v_V = np.einsum("nji,nj->ni", s.R_W_V, s.v_W)
    assert np.abs(v_V[:, 1]).mean() < 0.1 and np.abs(v_V[:, 2]).mean() < 0.15  # no side slip, no lift
    assert traj.length_m() == pytest.approx(1011.5, abs=2.0)


def test_gnss_fixes_lie_on_the_pose(rec):
    g = rec.gnss["ublox"]
    enu = g.enu(rec.pose.origin)
    m = (g.fix_t > 1) & (g.fix_t < 59)
    p = np.column_stack([np.interp(g.fix_t[m], rec.pose.t, rec.pose.p_W_C[:, k]) for k in range(3)])
    err = np.linalg.norm(enu[m] - p, axis=1)
    assert np.median(err) < 3.0  # the antenna is ~1 m from the camera; the fix epoch ±0.1 s
    assert set(rec.gnss) == {"ublox", "qcom"}


def test_radar_tracks_and_the_stationary_selection(rec):
    r = rec.radar
    assert r.n_cycles == 1200 and r.duplicate.sum() == 62
    assert np.abs(np.degrees(r.azimuth_rad)).max() < 21
    sel = c2k.stationary_detections(rec)
    assert sel.sum() / r.t.size == pytest.approx(0.135, abs=0.005)
    ev = c2k.radar_ego_velocity(rec, sel)
    v = rec.can_speed_mps(ev.t)
    assert np.median(ev.v_mps[:, 0] / v) == pytest.approx(1.0, abs=0.01)


def test_the_folder_is_a_route(folder):
    from excite.io.bags import ImuTrajectory

    traj = read_route(folder)
    assert isinstance(traj, ImuTrajectory) and traj.duration == pytest.approx(59.95, abs=0.01)


def test_the_can_stream_gives_interval_means(rec):
    can = c2k.can_recording(rec)
    edges = np.arange(0.0, 59.9, 0.1)
    sp, st = interval_means(can, edges)
    assert np.isnan(sp[0]).all()  # the first reading's period starts 32 ms after the first pose
    sp, st = sp[1:], st[1:]
    assert np.isfinite(sp).all() and np.isfinite(st).all()
    assert np.mean(sp) == pytest.approx(np.mean(rec.wheel_speeds.value), rel=0.01)


def _fake(tmp_path: Path, folder: Path) -> Path:
    """A copy of the minute's layout to break."""
    out = tmp_path / "seg"
    shutil.copytree(folder, out)
    for p in out.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)
    return out


def _save(path: Path, a) -> None:
    with open(path, "wb") as f:
        np.save(f, a, allow_pickle=True)


@pytest.mark.parametrize("breakage, message", [
    (lambda p: (p / "processed_log/CAN/wheel_speed/value").unlink(), "processed_log/CAN/wheel_speed/value: missing"),
    (lambda p: _save(p / "processed_log/CAN/wheel_speed/value", np.zeros((4974, 3))),
     "processed_log/CAN/wheel_speed: expected 4 columns, got shape (4974, 3)"),
    (lambda p: _save(p / "processed_log/IMU/gyro/t", np.zeros(5)), "processed_log/IMU/gyro: 5 times for 6256 values"),
    (lambda p: _save(p / "processed_log/CAN/steering_angle/t", np.linspace(1, 0, 4974)),
     "processed_log/CAN/steering_angle: times must be finite and sorted"),
    (lambda p: _save(p / "global_pose/frame_orientations", np.ones((1200, 4))),
     "global_pose/frame_orientations: quaternion 0 is not a unit quaternion"),
    (lambda p: _save(p / "processed_log/IMU/accelerometer/value", np.array([{"x": 1}] * 6256, dtype=object)),
     "processed_log/IMU/accelerometer/value: not a numpy array"),
    (lambda p: shutil.rmtree(p / "global_pose"), "not a comma2k19 segment folder"),
])
def test_a_broken_folder_is_a_clear_error_naming_the_signal(tmp_path, folder, breakage, message):
    p = _fake(tmp_path, folder)
    breakage(p)
    with pytest.raises(RouteError) as e:
        c2k.read_comma2k19(p)
    assert message in str(e.value) and str(p) in str(e.value)


# --- the minute scored from its own CAN wheels, steering and IMU --------------------------------


@pytest.fixture(scope="module")
def report(rec, rig):
    return evaluate(c2k.trajectory(rec), rig)


def test_a_minute_of_highway_determines_the_scale_factors_not_the_wheelbase(report):
    sig = {p.name: p for p in report.parameters}
    for w in ("fl", "fr", "rl", "rr"):
        assert sig[f"wheel.scale_{w}"].sigma < 0.3 * sig[f"wheel.scale_{w}"].target  # ~0.02 %
    assert sig["wheel.wheelbase"].sigma > 1000 * sig["wheel.wheelbase"].target  # metres: nearly straight
    assert sig["steering.ratio"].sigma > 1000 * sig["steering.ratio"].target
    assert sig["wheel.track_rear"].sigma > 5 * sig["wheel.track_rear"].target
    assert sig["steering.offset"].sigma < np.radians(0.5)  # the straight driving reads it
    assert sig["radar_front.rot_z"].sigma < sig["radar_front.rot_z"].target
    assert sig["radar_front.trans_x"].sigma > 10 * sig["radar_front.trans_x"].target  # no yaw rate, no lever arm
    assert report.weak_modes[0].coordinates[0][0] in ("wheel.wheelbase", "steering.ratio")


def test_the_wheel_speeds_agree_with_the_pose(rec, rig):
    """Against the pose: 0.8–1 % slow at the nominal scale (0.15 m/s RMS), 3–4 cm/s once the
    scale factors and the CAN time offset are fitted with the pose held."""
    traj = c2k.trajectory(rec, measured_imu=False, cutoff_hz=4.0)
    nom = Nominal.of(traj, rig)
    sp, st = interval_means(c2k.can_recording(rec), nom.t)
    fit = [f"wheel.scale_{w}" for w in ("fl", "fr", "rl", "rr")] + ["wheel.time_offset", "steering.offset"]
    a = agreement(traj, rig, "ackermann", np.column_stack([sp, st]), fit)
    assert np.all(a.rms_nominal[:4] > 0.1) and np.all(a.rms_fitted[:4] < 0.045)
    assert np.degrees(a.rms_fitted[4]) < 0.6
    for w, want in zip(("fl", "fr", "rl", "rr"), (0.9923, 0.9922, 0.9906, 0.9902)):
        assert a.fitted[f"wheel.scale_{w}"] == pytest.approx(want, abs=5e-4)
    assert 0.02 < a.fitted["wheel.time_offset"] < 0.07  # the readings describe the motion ~40-50 ms later


# --- the minute with its u-blox GNSS ----------------------------------------------------------


@pytest.fixture(scope="module")
def minute(rec):
    return rec, c2k.trajectory(rec)


def _with_fixes(rec, traj):
    fixes = rec.gnss["ublox"]
    t = np.asarray(fixes.fix_t, dtype=float)  # the fix epochs on the drive's clock
    return traj.with_logs({"gnss": SensorLog(np.unique(t))})


def test_the_minute_scored_with_its_gnss(minute):
    """An almost straight minute (heading within 1.2°, the body pitching a few tenths of a degree
    under braking), its 19 missing u-blox fixes outages from the log: the fix's time offset is
    determined to a few centimetres' worth (speed 8–20 m/s: tens of ms), the lever arm only to
    metres, horizontally weakest (the constant-heading row of the table, weak rather than exact
    on a real car)."""
    rec, traj = minute
    logged = _with_fixes(rec, traj)
    rig = load_rig(EXAMPLES / "comma2k19_gnss.yaml")
    nom = Nominal.of(logged, rig)
    held = int(nom.logs["gnss"].available.sum())
    assert 560 <= held <= 598  # the fixes the log holds on the keyframes (579 in the minute)
    rep = evaluate(logged, rig)
    s = {p.name: p.sigma for p in rep.parameters}
    assert s["gnss.time_offset"] < 0.1
    assert all(s[f"gnss.trans_{a}"] is None or s[f"gnss.trans_{a}"] > 0.5 for a in "xyz")
    weakest = rep.weak_modes[0]
    assert weakest.coordinates[0][0] in ("gnss.trans_x", "gnss.trans_y") and "heading" in weakest.advice
    full = {p.name: p.sigma for p in evaluate(traj, rig).parameters}
    assert s["gnss.time_offset"] >= full["gnss.time_offset"] * (1 - 1e-9)  # the outages cost, never help
