"""Rig configs: the bundled rig, Kalibr IMU files, units, and errors that name the key."""

from __future__ import annotations

import math

import pytest
import yaml

from excite.cli.app import main
from excite.errors import RigError
from excite.rig.config import RIGS_DIR, build_rig, load_rig, parse_quantity


def base():
    return yaml.safe_load((RIGS_DIR / "robotaxi.yaml").read_text())


def test_bundled_rig_estimates_every_parameter():
    rig = load_rig("robotaxi")
    names = [c.name for c in rig.scored]
    assert names[:7] == ["lidar.rot_x", "lidar.rot_y", "lidar.rot_z", "lidar.trans_x", "lidar.trans_y",
                         "lidar.trans_z", "lidar.time_offset"]
    assert {"imu.gyro_bias_z", "imu.accel_bias_x", "wheel.radius_left", "wheel.radius_right",
            "wheel.track", "cam_front.time_offset"} <= set(names)
    assert [c.name for c in rig.coordinates if c.nuisance] == ["cam_front.scale", "wheel.slip", "wheel.scrub",
                                                                   "vehicle.slip_angle"]
    assert rig.keyframe_rate_hz == 10.0
    assert next(c for c in rig.scored if c.name == "lidar.rot_x").target == pytest.approx(math.radians(0.05))


@pytest.mark.parametrize("text, unit, expected", [
    ("0.5 cm", "m", 0.005), ("0.05 deg", "rad", math.radians(0.05)), ("0.5 ms", "s", 5e-4),
    (0.002, "m", 0.002), ("2 mg", "m/s^2", 2 * 9.80665e-3), ("10 deg/h", "rad/s", math.radians(10) / 3600)])
def test_quantities_with_units(text, unit, expected):
    assert parse_quantity(text, unit, "k") == pytest.approx(expected)


@pytest.mark.parametrize("text, unit, message", [
    ("1 cm", "rad", "not a unit of rad"), ("-1 cm", "m", "positive"), ("abc", "m", "cannot read"),
    ("1 furlong", "m", "unknown unit"), ("nan", "m", "cannot read"), (float("nan"), "m", "positive and finite"),
    (float("inf"), "m", "positive and finite")])
def test_bad_quantities_name_the_key(text, unit, message):
    with pytest.raises(RigError, match=message) as e:
        parse_quantity(text, unit, "targets.x")
    assert "targets.x" in str(e.value)


def test_kalibr_imu_yaml_loads_as_is(tmp_path):
    (tmp_path / "imu.yaml").write_text(
        "rostopic: /imu0\nupdate_rate: 200.0\naccelerometer_noise_density: 0.0028\n"
        "accelerometer_random_walk: 0.00086\ngyroscope_noise_density: 0.00016\n"
        "gyroscope_random_walk: 2.2e-05\n")
    data = base()
    data["imu"] = "imu.yaml"
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(data))
    rig = load_rig(tmp_path / "rig.yaml")
    assert rig.config.imu.gyroscope_noise_density == 0.00016
    assert rig.config.imu.update_rate == 200.0


@pytest.mark.parametrize("mutate, key", [
    (lambda d: d["imu"].pop("gyroscope_noise_density"), "imu.gyroscope_noise_density"),
    (lambda d: d["imu"].__setitem__("gyroscope_noise_density", -1), "imu.gyroscope_noise_density"),
    (lambda d: d["sensors"][0].__setitem__("rate_hz", 3.0), "sensors.0.rate_hz"),
    (lambda d: d["sensors"][0].__setitem__("colour", "red"), "sensors.0.colour"),
    (lambda d: d["targets"].pop("wheel.track"), "wheel.track"),
    (lambda d: d["targets"].__setitem__("lidar.rot_w", "1 deg"), "targets.lidar.rot_w"),
    (lambda d: d["sensors"][1].__setitem__("name", "lidar"), "sensors"),
    (lambda d: d["imu"].__setitem__("update_rate", 205), "imu.update_rate"),
    (lambda d: d["sensors"][0]["T_B_S"].__setitem__("matrix", [[1, 0, 0], [0, 1, 0], [0, 0, 1]]), "sensors.0.T_B_S"),
])
def test_errors_name_the_key(mutate, key):
    data = base()
    mutate(data)
    with pytest.raises(RigError) as e:
        build_rig(data)
    assert key in str(e.value)


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d.__setitem__("keyframe_rat_hz", 10), "keyframe_rat_hz: not a key of a rig file here"),
    (lambda d: d["sensors"][1].__setitem__("name", "lidar"), "sensors: sensor names must be unique, repeated: lidar"),
    (lambda d: (d.__setitem__("keyframe_rate_hz", None), d["sensors"][1].__setitem__("rate_hz", 15.0)),
     "sensors.0.rate_hz: 10 Hz must divide the keyframe rate (not given: the fastest sensor's) 15 Hz by a whole "
     "number: declare lidar at 7.5 Hz (its noise is a drift density: σ does not change with the rate it is "
     "declared at), or set keyframe_rate_hz to a whole multiple of 10 Hz"),
])
def test_errors_read_as_sentences_not_validator_jargon(mutate, message):
    data = base()
    mutate(data)
    with pytest.raises(RigError) as e:
        build_rig(data)
    assert str(e.value) == message


def test_unknown_bundled_rig_lists_the_bundled_ones():
    with pytest.raises(RigError, match="bundled: robotaxi"):
        load_rig("nosuch")


def test_bad_yaml_names_file_and_line(tmp_path):
    p = tmp_path / "rig.yaml"
    p.write_text("name: x\nimu: [\n")
    with pytest.raises(RigError, match=r"rig.yaml, line \d+: not valid YAML"):
        load_rig(p)


def test_rig_show_prints_the_bundled_rig(capsys):
    assert main(["rig", "show", "robotaxi"]) == 0
    out = capsys.readouterr().out
    assert yaml.safe_load(out)["name"] == "robotaxi"
    assert main(["rig", "show", "nosuch"]) == 1


# --------------------------------------------------------------------------------------------
# Writing a rig by hand


def _sedan_without(*globs: str) -> dict:
    data = yaml.safe_load((RIGS_DIR / "sedan.yaml").read_text())
    for g in globs:
        data["targets"].pop(g)
    return data


def test_a_car_rig_missing_six_targets_gets_one_error_naming_all_six():
    data = _sedan_without("wheel.scale_*", "wheel.track_*")
    with pytest.raises(RigError) as e:
        build_rig(data)
    msg = str(e.value)
    missing = ["wheel.scale_fl", "wheel.scale_fr", "wheel.scale_rl", "wheel.scale_rr", "wheel.track_front",
               "wheel.track_rear"]
    first = msg.splitlines()[0]
    assert first.startswith("targets: no accuracy target for 6 parameters (")
    assert all(name in first for name in missing)
    # the lines it offers, pasted under targets:, make the rig whole
    pasted = yaml.safe_load("\n".join(msg.splitlines()[1:]))
    assert set(pasted) == {"wheel.scale_*", "wheel.track_*"}
    data["targets"].update(pasted)
    rig = build_rig(data)
    assert {c.name for c in rig.scored} >= set(missing)


def test_a_rig_with_no_targets_names_every_parameter_once(capsys, tmp_path):
    data = _sedan_without(*list(yaml.safe_load((RIGS_DIR / "sedan.yaml").read_text())["targets"]))
    path = tmp_path / "car.yaml"
    path.write_text(yaml.safe_dump(data))
    assert main(["rig", "show", str(path)]) == 1
    err = capsys.readouterr().err
    n = len(build_rig(yaml.safe_load((RIGS_DIR / "sedan.yaml").read_text())).scored)
    assert f"targets: no accuracy target for {n} parameters" in err
    pasted = yaml.safe_load("\n".join(err.strip().splitlines()[1:]))
    data["targets"] = pasted
    assert len(build_rig(data).scored) == n


def test_the_rate_error_says_the_fix_and_the_fix_works():
    data = base()
    data["keyframe_rate_hz"] = None
    data["sensors"][0]["rate_hz"] = 20.0  # a 20 Hz lidar: keyframes at 20 Hz
    data["sensors"][1]["rate_hz"] = 15.0  # a 15 Hz camera
    with pytest.raises(RigError) as e:
        build_rig(data)
    msg = str(e.value)
    assert msg.startswith("sensors.1.rate_hz: 15 Hz must divide the keyframe rate (not given: the fastest "
                          "sensor's) 20 Hz by a whole number: declare cam_front at 10 Hz")
    assert "σ does not change with the rate it is declared at" in msg
    fix = float(msg.split("declare ")[1].split(" at ")[1].split(" Hz")[0])
    assert fix == 10.0
    data["sensors"][1]["rate_hz"] = fix
    build_rig(data)
