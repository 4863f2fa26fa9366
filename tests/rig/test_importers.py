"""Rigs from the files users have: a write → import round trip per format (every pose equal to
1e-9, the writers in :mod:`formats` written from each tool's conventions), the real published
files of ``../shared/data/rig_files/``, rotations to the precision of their digits, and bad input."""

from __future__ import annotations

import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import yaml

import rig_formats as formats
from excite.cli.app import main
from excite.errors import RigError
from excite.io.bags import rig_from_tf
from excite.rig import importers
from excite.rig.config import build_rig, load_rig
from excite.rig.files import MAX_FILE_BYTES, read_kalibr_imu

LIDARS = ("lidar_roof_link", "velodyne_rear_link")
CAMERAS = ("cam_front_link", "cam_left_link")


def _poses_equal(imported, spec, names, with_vehicle: bool) -> None:
    rig = build_rig(imported.config)  # what a user gets when the YAML is loaded
    by_name = {s.name: s for s in rig.config.sensors}
    assert list(by_name) == list(names)
    for name, s in zip(names, spec.sensors):
        got = by_name[name].T_B_S
        np.testing.assert_allclose(got.R, s.R, atol=1e-9, rtol=0)
        np.testing.assert_allclose(got.p, s.p, atol=1e-9, rtol=0)
    if with_vehicle:
        np.testing.assert_allclose(rig.config.vehicle.T_V_B.R, spec.R_V_B, atol=1e-9, rtol=0)
        np.testing.assert_allclose(rig.config.vehicle.T_V_B.p, spec.p_V_B, atol=1e-9, rtol=0)


def _through_yaml(imported, tmp_path: Path):
    """The imported rig as its YAML file loads it (the writer's numbers, not the importer's)."""
    out = tmp_path / "rig.yaml"
    out.write_text(importers.rig_yaml(imported))
    return importers.ImportedRig(yaml.safe_load(out.read_text()))


@pytest.mark.parametrize("openvins, output_imu", [(False, False), (False, True), (True, True)])
def test_kalibr_round_trip(tmp_path, openvins, output_imu):
    spec = formats.random_spec(1, cameras=CAMERAS)
    cam, imu = formats.kalibr(spec, tmp_path, openvins=openvins, output_imu=output_imu)
    imported = _through_yaml(importers.rig_from_kalibr(cam, imu), tmp_path)
    _poses_equal(imported, spec, ["cam0", "cam1"], with_vehicle=False)
    assert {k: imported.config["imu"][k] for k in formats.IMU} == formats.IMU


def test_vins_round_trip(tmp_path):
    spec = formats.random_spec(2, cameras=CAMERAS)
    imported = _through_yaml(importers.rig_from_vins(formats.vins(spec, tmp_path)), tmp_path)
    _poses_equal(imported, spec, ["cam0", "cam1"], with_vehicle=False)
    assert [s["monocular"] for s in imported.config["sensors"]] == [False, False]  # num_of_cam 2: stereo


@pytest.mark.parametrize("ros2", [True, False])
def test_lio_sam_round_trip(tmp_path, ros2):
    spec = formats.random_spec(3, lidars=LIDARS[:1])
    imported = _through_yaml(importers.rig_from_lio_sam(formats.lio_sam(spec, tmp_path, ros2)), tmp_path)
    _poses_equal(imported, spec, ["lidar_roof"], with_vehicle=False)
    assert imported.config["imu"]["accelerometer_noise_density"] == 3.99e-3


@pytest.mark.parametrize("livo", [False, True])
def test_fast_lio_round_trip(tmp_path, livo):
    spec = formats.random_spec(4, lidars=LIDARS[:1], cameras=CAMERAS[:1] if livo else ())
    imported = _through_yaml(importers.rig_from_fast_lio(formats.fast_lio(spec, tmp_path)), tmp_path)
    _poses_equal(imported, spec, ["velodyne", "camera"][: 1 + livo], with_vehicle=False)
    assert imported.config["sensors"][0]["rate_hz"] == 10.0  # preprocess.scan_rate


def test_urdf_round_trip(tmp_path):
    spec = formats.random_spec(5, lidars=LIDARS, cameras=CAMERAS)
    imported = importers.rig_from_urdf(formats.urdf(spec, tmp_path), imu="imu_link", lidar=list(LIDARS),
                                       camera=list(CAMERAS))
    _poses_equal(_through_yaml(imported, tmp_path), spec, ["lidar_roof", "velodyne_rear", "cam_front", "cam_left"],
                 with_vehicle=True)


def test_autoware_round_trip(tmp_path):
    spec = formats.random_spec(6, lidars=LIDARS, cameras=CAMERAS)
    kit, base = formats.autoware(spec, tmp_path)
    imported = importers.rig_from_autoware(kit, sensors_calibration=base)  # every frame placed by its name
    _poses_equal(_through_yaml(imported, tmp_path), spec, ["lidar_roof", "velodyne_rear", "cam_front", "cam_left"],
                 with_vehicle=True)


def test_tf_round_trip(tmp_path):
    spec = formats.random_spec(7, lidars=LIDARS, cameras=CAMERAS)
    imported = rig_from_tf(formats.tf_bag(spec, tmp_path), imu="imu_link", base="base_link", lidar=list(LIDARS),
                           camera=list(CAMERAS))
    _poses_equal(_through_yaml(imported, tmp_path), spec, ["lidar_roof", "velodyne_rear", "cam_front", "cam_left"],
                 with_vehicle=True)


# --------------------------------------------------------------------------------------------
# The files as their projects publish them


def _real(data_dir: Path) -> dict[str, list[str]]:
    """Each published file and the command the rig guide names for it."""
    d = data_dir / "rig_files"
    return {
        "kalibr": ["from-kalibr", f"{d}/kalibr/camchain-imucam-camera_imu.yaml", f"{d}/kalibr/imu.yaml"],
        "kalibr_output": ["from-kalibr", f"{d}/kalibr/camchain-imucam-camera_imu.yaml", f"{d}/kalibr/imu-camera_imu.yaml"],
        "openvins_tumvi": ["from-kalibr", f"{d}/openvins_tumvi/kalibr_imucam_chain.yaml",
                           f"{d}/openvins_tumvi/kalibr_imu_chain.yaml"],
        "openvins_euroc": ["from-kalibr", f"{d}/openvins_euroc/kalibr_imucam_chain.yaml",
                           f"{d}/openvins_euroc/kalibr_imu_chain.yaml"],
        "vins_fusion": ["from-vins", f"{d}/vins_fusion/euroc_stereo_imu_config.yaml"],
        "lio_sam": ["from-lio-sam", f"{d}/lio_sam/params.yaml"],
        "fast_lio": ["from-fast-lio", f"{d}/fast_lio/velodyne.yaml"],
        "autoware": ["from-autoware", f"{d}/autoware/sensor_kit_calibration.yaml",
                     f"{d}/autoware/sensors_calibration.yaml"],
    }


def test_every_published_file_is_read_by_its_importer(data_dir):
    """Each file of rig_files/ is there, and is covered by a command (none left unimported)."""
    covered = {Path(a) for cmd in _real(data_dir).values() for a in cmd[1:]}
    published = {p for p in (data_dir / "rig_files").rglob("*.yaml")}
    assert published == covered


@pytest.mark.parametrize("which", ["kalibr", "kalibr_output", "openvins_tumvi", "openvins_euroc", "vins_fusion",
                                   "lio_sam", "fast_lio", "autoware"])
def test_published_files_import_and_score(data_dir, tmp_path, capsys, which):
    from excite.io.routes import read_route
    from excite.score.evaluate import evaluate

    out = tmp_path / "rig.yaml"
    assert main(["rig", *_real(data_dir)[which], "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "review before trusting a score" in err and "targets: accuracy targets are not in the file" in err
    rig = load_rig(out)
    route = Path(__file__).resolve().parents[2] / "trajectories" / "figure_eight_control.csv"
    rep = evaluate(read_route(route, suspension=rig.suspension), rig)
    assert np.isfinite(rep.score) and rep.score > 0
    sigma = {p.name: p.sigma for p in rep.parameters}
    assert all(np.isfinite(v) for v in sigma.values())


def test_published_imu_files_nest_their_values(data_dir):
    """Kalibr's output and OpenVINS's IMU chains hold the densities under imu0: (with OpenCV's
    header) and read as the flat input file does."""
    d = data_dir / "rig_files"
    flat, _ = read_kalibr_imu(d / "kalibr/imu.yaml")
    nested, _ = read_kalibr_imu(d / "kalibr/imu-camera_imu.yaml")
    assert flat == nested == {"accelerometer_noise_density": 1.86e-3, "accelerometer_random_walk": 4.33e-4,
                              "gyroscope_noise_density": 1.87e-4, "gyroscope_random_walk": 2.66e-5,
                              "update_rate": 500.0}
    tumvi, _ = read_kalibr_imu(d / "openvins_tumvi/kalibr_imu_chain.yaml")
    assert tumvi["accelerometer_noise_density"] == 0.0028


def test_openvins_t_imu_cam_is_the_inverse_of_vins_body_t_cam(data_dir):
    """OpenVINS's EuRoC T_imu_cam and VINS-Fusion's EuRoC body_T_cam0 are the same matrix (the
    camera's pose in the IMU): both importers give the same T_B_S."""
    d = data_dir / "rig_files"
    a = importers.rig_from_kalibr(d / "openvins_euroc/kalibr_imucam_chain.yaml").config["sensors"]
    b = importers.rig_from_vins(d / "vins_fusion/euroc_stereo_imu_config.yaml").config["sensors"]
    for x, y in zip(a, b):
        np.testing.assert_allclose(x["T_B_S"]["matrix"], y["T_B_S"]["matrix"], atol=1e-12)
        np.testing.assert_allclose(x["T_B_S"]["translation_m"], y["T_B_S"]["translation_m"], atol=1e-12)
    # the EuRoC cam0 looks forward-right of the IMU: its optical axis (z) along the IMU's x
    assert np.array(a[0]["T_B_S"]["matrix"])[0, 2] == pytest.approx(0.00414, abs=1e-5)


def test_autoware_kit_names_its_sensors_after_their_frames(data_dir, tmp_path):
    d = data_dir / "rig_files" / "autoware"
    out = tmp_path / "rig.yaml"
    assert main(["rig", "from-autoware", str(d / "sensor_kit_calibration.yaml"),
                 str(d / "sensors_calibration.yaml"), "-o", str(out)]) == 0
    rig = load_rig(out)
    names = [s.name for s in rig.config.sensors]
    assert len(names) == 15 and {"velodyne_top", "velodyne_left", "livox_front_left", "camera0", "gnss"} <= set(names)
    assert not any(n.startswith(("lidar_", "camera_")) for n in names)
    assert rig.name == "sensor_kit_calibration"
    text = out.read_text()
    # the sample IMU is mounted upside down: trans_z of every sensor points down
    assert "whose axes point x backward, y left, z down of the vehicle frame" in text
    gnss = next(c for c in rig.coordinates if c.name == "gnss.trans_x")
    assert gnss.target == pytest.approx(0.75)  # half the standalone fix's 1.5 m, not 1 cm


def test_autoware_report_names_velodyne_top(data_dir, tmp_path, capsys):
    d = data_dir / "rig_files" / "autoware"
    out = tmp_path / "rig.yaml"
    main(["rig", "from-autoware", str(d / "sensor_kit_calibration.yaml"), str(d / "sensors_calibration.yaml"),
          "-o", str(out)])
    capsys.readouterr()
    route = Path(__file__).resolve().parents[2] / "trajectories" / "figure_eight_control.csv"
    assert main(["score", str(route), "--rig", str(out)]) == 0
    report = capsys.readouterr().out
    assert "velodyne_top.trans_z" in report and "lidar_1" not in report
    assert "trans_* are positions in the IMU frame B, whose axes point x backward, y left, z down" in report


# --------------------------------------------------------------------------------------------
# Rotations to the precision of their printed digits


def _rounded_camchain(tmp_path: Path, decimals: int | None, error: float = 0.0) -> Path:
    spec = formats.random_spec(8, cameras=CAMERAS[:1])
    T = np.array(formats._T(*formats._inv(spec.sensors[0].R, spec.sensors[0].p)))
    T[0, :3] *= 1.0 + error
    rows = [[round(float(x), decimals) if decimals is not None else float(x) for x in r] for r in T]
    fmt = (lambda x: f"{x:.{decimals}f}") if decimals is not None else repr
    text = "cam0:\n  T_cam_imu:\n" + "".join(f"  - [{', '.join(fmt(x) for x in r)}]\n" for r in rows)
    path = tmp_path / "camchain-imucam-rounded.yaml"
    path.write_text(text)
    return path


def test_a_camchain_rounded_to_4_decimals_imports_with_the_correction(tmp_path, capsys):
    path = _rounded_camchain(tmp_path, 4)
    out = tmp_path / "rig.yaml"
    assert main(["rig", "from-kalibr", str(path), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "note: cam0.T_cam_imu: re-orthonormalised, corrected by" in err and "its 4 decimals allow 0.00015" in err
    assert "re-orthonormalised" in out.read_text()
    corrected = float(err.split("corrected by ")[1].split(" ")[0])
    assert 1e-6 < corrected < 1.5e-4


def test_a_camchain_with_a_1_percent_error_is_refused_with_deviation_and_tolerance(tmp_path, capsys):
    path = _rounded_camchain(tmp_path, 4, error=0.01)
    assert main(["rig", "from-kalibr", str(path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert err.startswith(f"excite: error: {path}: cam0.T_cam_imu: the rotation block is 0.01 from the nearest rotation")
    assert "more than its printed digits (4 decimals) allow (0.00015): not a rotation" in err


def test_full_precision_rotations_are_held_to_their_digits(tmp_path):
    """17 significant digits allow only the arithmetic's error: a matrix off by 1e-7 is refused."""
    importers.rig_from_kalibr(_rounded_camchain(tmp_path, None))  # as printed by repr: accepted
    with pytest.raises(RigError, match=r"more than its printed digits \(1[0-9]–1[0-9] decimals\)"):
        importers.rig_from_kalibr(_rounded_camchain(tmp_path, None, error=1e-7))


def test_a_reflection_is_refused(tmp_path):
    path = tmp_path / "chain.yaml"
    path.write_text("cam0:\n  T_cam_imu: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]\n")
    with pytest.raises(RigError, match="determinant -1: a reflection"):
        importers.rig_from_kalibr(path)


# --------------------------------------------------------------------------------------------
# Bad input: one line naming the file, the key and the problem, in bounded memory


def _one_line(args: list[str], capsys) -> str:
    assert main(args) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err
    return err


def test_a_urdf_of_100000_links_is_refused_in_bounded_memory(tmp_path, capsys):
    path = tmp_path / "huge.urdf"
    with path.open("w") as f:
        f.write('<robot name="huge">\n')
        for i in range(100_000):
            f.write(f'<link name="l{i}"/>\n')
        f.write("</robot>\n")
    tracemalloc.start()
    err = _one_line(["rig", "from-urdf", str(path), "--imu", "l0"], capsys)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert f"{path}: more than 4096 links or joints" in err
    assert peak < 20e6


def _urdf(tmp_path, joints: list[tuple[str, str]]) -> Path:
    body = "".join(f'<joint name="{p}_to_{c}" type="fixed"><parent link="{p}"/><child link="{c}"/></joint>'
                   for p, c in joints)
    path = tmp_path / "robot.urdf"
    path.write_text(f'<robot name="r">{body}</robot>')
    return path


def test_a_joint_cycle_and_a_missing_link_are_named(tmp_path, capsys):
    path = _urdf(tmp_path, [("base_link", "a"), ("a", "b"), ("b", "c"), ("c", "a")])
    err = _one_line(["rig", "from-urdf", str(path), "--imu", "b"], capsys)
    assert f"{path}: frame 'a' has two parents" in err or f"{path}: the joints form a cycle" in err
    path = _urdf(tmp_path, [("a", "b"), ("b", "c"), ("c", "a")])
    err = _one_line(["rig", "from-urdf", str(path), "--imu", "b"], capsys)
    cycle = err.split("the joints form a cycle: ")[1].split(" → ")
    assert f"{path}: the joints form a cycle: " in err and sorted(cycle[:3]) == ["a", "b", "c"] and cycle[0] == cycle[3]
    path = _urdf(tmp_path, [("base_link", "imu_link"), ("lidar_mount", "lidar_link")])
    err = _one_line(["rig", "from-urdf", str(path), "--imu", "imu_link", "--lidar", "lidar_link"], capsys)
    assert "no joint links 'imu_link' and 'lidar_link': 'imu_link' hangs from 'base_link' and 'lidar_link' from 'lidar_mount'" in err
    err = _one_line(["rig", "from-urdf", str(path), "--imu", "imu_link", "--lidar", "velodyne"], capsys)
    assert f"{path}: frame 'velodyne' is in no joint (frames: base_link, imu_link, lidar_link, lidar_mount)" in err


def test_a_xacro_is_expanded_first(tmp_path, capsys):
    path = tmp_path / "robot.urdf.xacro"
    path.write_text('<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="r"><xacro:property name="a" value="1"/></robot>')
    err = _one_line(["rig", "from-urdf", str(path)], capsys)
    assert "a xacro file" in err and "expand it first, `xacro robot.urdf.xacro > robot.urdf`" in err
    renamed = tmp_path / "robot.urdf"
    renamed.write_text(path.read_text())
    assert "a xacro file" in _one_line(["rig", "from-urdf", str(renamed)], capsys)


def test_an_xml_bomb_is_refused(tmp_path, capsys):
    path = tmp_path / "bomb.urdf"
    path.write_text('<?xml version="1.0"?><!DOCTYPE r [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;">]>'
                    '<robot name="&b;"/>')
    err = _one_line(["rig", "from-urdf", str(path), "--imu", "x"], capsys)
    assert f"{path}: not a URDF" in err


def test_matrices_of_the_wrong_shape_name_the_key(tmp_path, capsys):
    path = tmp_path / "chain.yaml"
    path.write_text("cam0:\n  T_cam_imu: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]\n")
    err = _one_line(["rig", "from-kalibr", str(path)], capsys)
    assert f"{path}: cam0.T_cam_imu: expected a 4x4 matrix (rows, or 16 numbers row by row), got 3 rows" in err
    vins = tmp_path / "vins.yaml"
    vins.write_text("%YAML:1.0\nnum_of_cam: 1\nbody_T_cam0: !!opencv-matrix\n  rows: 3\n  cols: 4\n  dt: d\n"
                    "  data: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0]\n")
    err = _one_line(["rig", "from-vins", str(vins)], capsys)
    assert f"{vins}: body_T_cam0: expected a 4x4 matrix, got rows: 3, cols: 4" in err
    vins.write_text("%YAML:1.0\nnum_of_cam: 1\nbody_T_cam0: !!opencv-matrix\n  rows: 4\n  cols: 4\n  dt: d\n"
                    "  data: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0]\n")
    err = _one_line(["rig", "from-vins", str(vins)], capsys)
    assert f"{vins}: body_T_cam0.data: rows × cols = 16, but data holds 12 numbers" in err
    lio = tmp_path / "params.yaml"
    lio.write_text("extrinsicTrans: [0, 0]\nextrinsicRot: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n")
    err = _one_line(["rig", "from-lio-sam", str(lio)], capsys)
    assert f"{lio}: extrinsicTrans: expected 3 numbers, got 2 numbers" in err


def test_an_opencv_tag_that_is_not_a_matrix(tmp_path, capsys):
    vins = tmp_path / "vins.yaml"
    vins.write_text("%YAML:1.0\nnum_of_cam: 1\nbody_T_cam0: !!opencv-matrix [1, 0, 0]\n")
    err = _one_line(["rig", "from-vins", str(vins)], capsys)
    assert f"{vins}: body_T_cam0: !!opencv-matrix holds a sequence, not a mapping of rows, cols, dt, data" in err
    vins.write_text("%YAML:1.0\nnum_of_cam: 1\nbody_T_cam0: !!opencv-nd-matrix {sizes: [4, 4], dt: d, data: []}\n")
    err = _one_line(["rig", "from-vins", str(vins)], capsys)
    assert f"{vins}: body_T_cam0: !!opencv-nd-matrix is not a matrix excite reads (!!opencv-matrix is)" in err


def test_a_yaml_bomb_is_refused_before_it_expands(tmp_path, capsys):
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [*a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}]"
              for i in range(1, 12)]
    path = tmp_path / "params.yaml"
    path.write_text("\n".join(lines) + "\nextrinsicRot: *a11\n")
    tracemalloc.start()
    err = _one_line(["rig", "from-lio-sam", str(path)], capsys)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert f"{path}, line 2: not valid YAML (anchors and aliases (*name) are not accepted" in err
    assert peak < 20e6
    err = _one_line(["score", "x.csv", "--rig", str(path)], capsys)
    assert "anchors and aliases" in err or "x.csv" in err


def test_a_file_too_large_is_refused_before_it_is_read(tmp_path, capsys):
    path = tmp_path / "params.yaml"
    with path.open("wb") as f:
        f.truncate(MAX_FILE_BYTES + 1)
    err = _one_line(["rig", "from-lio-sam", str(path)], capsys)
    assert f"{path}: 8,388,609 bytes, over the limit of 8,388,608" in err


# --------------------------------------------------------------------------------------------
# A tool's file where a rig is expected


@pytest.mark.parametrize("which, command", [
    ("kalibr/camchain-imucam-camera_imu.yaml", "excite rig from-kalibr"),
    ("kalibr/imu-camera_imu.yaml", "excite rig from-kalibr CAMCHAIN"),
    ("kalibr/imu.yaml", "excite rig from-kalibr CAMCHAIN"),
    ("openvins_tumvi/kalibr_imucam_chain.yaml", "excite rig from-kalibr"),
    ("openvins_euroc/kalibr_imu_chain.yaml", "excite rig from-kalibr CAMCHAIN"),
    ("vins_fusion/euroc_stereo_imu_config.yaml", "excite rig from-vins"),
    ("lio_sam/params.yaml", "excite rig from-lio-sam"),
    ("fast_lio/velodyne.yaml", "excite rig from-fast-lio"),
    ("autoware/sensor_kit_calibration.yaml", "excite rig from-autoware"),
    ("autoware/sensors_calibration.yaml", "excite rig from-autoware SENSOR_KIT_CALIBRATION"),
])
def test_a_tool_file_given_as_a_rig_names_its_importer(data_dir, capsys, which, command):
    path = data_dir / "rig_files" / which
    err = _one_line(["rig", "show", str(path)], capsys)
    assert f"{path}: this is a" in err and f"file, not a rig: `{command}" in err


def test_a_urdf_given_as_a_rig_names_its_importer(tmp_path, capsys):
    spec = formats.random_spec(9, lidars=LIDARS[:1])
    path = formats.urdf(spec, tmp_path)
    err = _one_line(["rig", "show", str(path)], capsys)
    assert "this is a URDF file, not a rig: `excite rig from-urdf" in err


def test_a_kalibr_output_imu_file_loads_as_a_rigs_imu(data_dir, tmp_path):
    """``imu: imu-camera_imu.yaml`` in a rig: the values under imu0: (README: a Kalibr imu.yaml loads as is)."""
    rig_yaml = load_rig("robotaxi").config.model_dump(mode="json", exclude_none=True)
    rig_yaml["imu"] = str(data_dir / "rig_files" / "openvins_tumvi" / "kalibr_imu_chain.yaml")
    path = tmp_path / "rig.yaml"
    path.write_text(json.dumps(rig_yaml))
    rig = load_rig(path)
    assert rig.config.imu.accelerometer_noise_density == 0.0028 and rig.config.imu.update_rate == 200.0


def test_urdf_gazebo_sensors_and_movable_joints(tmp_path):
    spec = formats.random_spec(10, lidars=LIDARS[:1], cameras=CAMERAS[:1])
    path = formats.urdf(spec, tmp_path, movable=True)
    text = path.read_text().replace("</robot>", '<gazebo reference="imu_link"><sensor type="imu"/></gazebo>'
                                    '<gazebo reference="lidar_roof_link"><sensor type="gpu_ray"><update_rate>10'
                                    '</update_rate></sensor></gazebo><gazebo reference="cam_front_link">'
                                    '<sensor type="camera"><update_rate>20</update_rate></sensor></gazebo></robot>')
    path.write_text(text)
    imported = importers.rig_from_urdf(path)
    sensors = imported.config["sensors"]
    assert [(s["name"], s["rate_hz"]) for s in sensors] == [("lidar_roof", 10.0), ("cam_front", 20.0)]
    assert any("joint j1 is revolute: taken at its zero position" in n for n in imported.notes)
