"""``excite rig noise``: from TUM files, from a bag's topics, and from an odometry's own reported
covariance; the rig lines it prints paste into a rig."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from excite.cli.app import main
from excite.rig.config import RIGS_DIR, build_rig


def _tum(path, t, R: Rotation, p) -> None:
    q = R.as_quat()
    path.write_text("".join(f"{a:.6f} {b[0]:.9f} {b[1]:.9f} {b[2]:.9f} {c[0]:.12f} {c[1]:.12f} {c[2]:.12f} {c[3]:.12f}\n"
                            for a, b, c in zip(t, p, q)))


def _drive(t):
    R = Rotation.from_euler("ZYX", np.c_[0.5 * np.sin(0.1 * t) + 0.2 * np.sin(0.4 * t), 0.02 * np.sin(0.5 * t),
                                         0.03 * np.sin(0.45 * t)])
    p = np.c_[6.0 * t + 30 * np.sin(0.08 * t), 40 * np.sin(0.06 * t), 0.3 * np.sin(0.2 * t)]
    return R, p


def test_noise_from_tum_files_prints_rig_lines_that_paste(tmp_path, capsys):
    rng = np.random.default_rng(5)
    t_ref = np.arange(0.0, 200.0, 0.02)
    _tum(tmp_path / "gt.tum", t_ref, *_drive(t_ref))
    t = np.arange(2.0, 198.0, 0.1)
    R, p = _drive(t)
    R_rel, t_rel = R[:-1].inv() * R[1:], R[:-1].inv().apply(p[1:] - p[:-1])
    R_rel = R_rel * Rotation.from_rotvec(rng.normal(0, np.radians(0.1) * np.sqrt(0.1), (t.size - 1, 3)))
    t_rel = t_rel + rng.normal(0, 0.03 * np.sqrt(0.1), (t.size - 1, 3))
    Rs, ps = [R[0]], [p[0]]
    for a, b in zip(R_rel, t_rel):
        ps.append(ps[-1] + Rs[-1].apply(b))
        Rs.append(Rs[-1] * a)
    _tum(tmp_path / "odom.tum", t, Rotation.concatenate(Rs), np.array(ps))
    assert main(["rig", "noise", str(tmp_path / "odom.tum"), "--reference", str(tmp_path / "gt.tum")]) == 0
    out = capsys.readouterr().out
    assert max(len(line) for line in out.splitlines()) <= 100
    noise = yaml.safe_load(out.split("rig lines to paste under the lidar's or camera's entry:\n")[1])["noise"]
    rig = yaml.safe_load((RIGS_DIR / "robotaxi.yaml").read_text())
    rig["sensors"][0]["noise"] = noise
    build_rig(rig)
    assert main(["rig", "noise", str(tmp_path / "odom.tum"), "--reference", str(tmp_path / "gt.tum"), "--json"]) == 0
    est = json.loads(capsys.readouterr().out)
    rot, trans = est["rotation_density_deg_per_sqrt_s"], est["translation_density_m_per_sqrt_s"]
    assert abs(rot["value"] - 0.1) < 3 * rot["sigma"] and abs(trans["value"] - 0.03) < 3 * trans["sigma"]
    assert noise["rotation_density_deg_per_sqrt_s"] == float(f"{rot['value']:.3g}")


def test_noise_needs_a_reference_or_a_bag_topic(tmp_path, capsys):
    path = tmp_path / "odom.tum"
    path.write_text("0 0 0 0 0 0 0 1\n")
    assert main(["rig", "noise", str(path)]) == 2
    assert "name the reference" in capsys.readouterr().err


def test_noise_from_the_odometrys_reported_covariance(tmp_path, capsys):
    from helpers import weave_drive

    from excite.io.bags import write_bag

    q_rot, q_trans = np.radians(0.2) ** 2, 0.05 ** 2  # per second: 0.2 deg/√s, 0.05 m/√s
    rate = 20.0

    def cov(t):
        c = np.zeros((t.size, 6, 6))
        c[:, :3, :3] = np.eye(3) * q_trans / rate  # ROS order: x, y, z, then rotations
        c[:, 3:, 3:] = np.eye(3) * q_rot / rate
        return c

    bag = write_bag(weave_drive(), tmp_path / "odom.bag", topic="/odom", rate_hz=rate, pose_covariance=cov)
    assert main(["rig", "noise", str(bag), "--topic", "/odom", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["rotation_density_deg_per_sqrt_s"][1] == pytest.approx(0.2, rel=1e-3)
    assert rep["translation_density_m_per_sqrt_s"][1] == pytest.approx(0.05, rel=1e-3)
    assert main(["rig", "noise", str(bag), "--topic", "/odom"]) == 0
    assert "not checked against a reference" in capsys.readouterr().out


def test_noise_from_a_bag_against_its_ground_truth(data_dir, capsys):
    """The command the rig guide gives, on the real drive: ORB-SLAM against the ground truth."""
    bag = data_dir / "ROS_example.bag"
    assert main(["rig", "noise", str(bag), "--topic", "ORB-SLAM", "--reference-topic", "groundtruth", "--json"]) == 0
    est = json.loads(capsys.readouterr().out)
    rot, trans = est["rotation_density_deg_per_sqrt_s"], est["translation_density_m_per_sqrt_s"]
    # the guide's figures (docs/guides/rigs.md), to the digits it prints
    assert f"{rot['value']:.3g}" == "0.209" and f"{trans['value']:.3g}" == "0.035"
    assert rot["over_1s"] > rot["value"] and est["scale"] == pytest.approx(1.053, abs=2e-3)
