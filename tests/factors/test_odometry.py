"""A lidar's or camera's odometry noise (:mod:`excite.factors.odometry`).

The noise is a drift density (σ of a relative pose over Δt = density·√Δt): a lidar of the same
quality at 10, 20 or 40 Hz is told the same σ, and rigs with per-pair keys are refused with the
density that keeps their numbers at their sensor's rate.

An odometry's own covariance: with ``noise.use_reported_covariance`` a lidar's
or camera's frame pairs are whitened by the covariance its log reports (``nav_msgs/Odometry``,
``PoseWithCovarianceStamped``), so that a stretch the odometry reports worse shows in σ.

- A reported covariance equal to the densities scores as the densities; pairs reported c times
  worse have rows exactly 1/√c of the others (analytic).
- An anisotropic world-frame covariance against a reference built here: the evaluator's rows
  unwhitened and whitened again by the inverse symmetric square root of each pair's covariance
  turned into the sensor frame with the trajectory's own orientation (not the kernel's path).
- A bag round trip (ROS 1 Odometry, ROS 2 MCAP PoseWithCovarianceStamped): per-message
  covariance equal to the densities gives the densities' σ; a stretch reported 100× worse in
  translation makes the lidar's lever arm worse and leaves what the rotation rows carry; a topic
  without covariance is a clear error.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import sqrtm
from typer.testing import CliRunner

import excite.cli.score  # noqa: F401  (registers `excite score` on the app)
from excite.cli.app import app
from excite.errors import BagError, RigError
from excite.factors.base import Nominal
from excite.factors.odometry import pair_sigmas
from excite.information import elimination, problem
from excite.information.closure import marginalise_nuisance
from excite.io.bags import read_bag_route, read_pose_covariances, write_bag
from excite.io.routes import read_route
from excite.motion.maneuvers import figure_eight
from excite.motion.trajectory import SensorLog
from excite.motion.vehicle import drive
from excite.rig.config import build_rig, load_rig
from excite.score.evaluate import evaluate
from helpers import REPO

RATE = 10.0
TRAJ = REPO / "trajectories"


def lidar_rig(reported: bool = True, scale: float = 1.0):
    """The bundled robotaxi with its lidar only (densities × ``scale``), asking for the reported
    covariance or not."""
    data = load_rig("robotaxi").config.model_dump()
    lidar = data["sensors"][0]
    lidar["noise"] = dict(lidar["noise"], use_reported_covariance=reported,
                          rotation_density_deg_per_sqrt_s=lidar["noise"]["rotation_density_deg_per_sqrt_s"] * scale,
                          translation_density_m_per_sqrt_s=lidar["noise"]["translation_density_m_per_sqrt_s"] * scale)
    data["sensors"] = [lidar]
    return build_rig(data)


def densities(rig) -> tuple[float, float]:
    n = rig.config.sensors[0].noise
    return np.radians(n.rotation_density_deg_per_sqrt_s), n.translation_density_m_per_sqrt_s


def sigmas(rep) -> dict[str, float]:
    return {p.name: p.sigma for p in rep.parameters}


def per_second(rig, n: int) -> np.ndarray:
    """The densities as a log's covariance per second (rotation, translation)."""
    dr, dt = densities(rig)
    return np.broadcast_to(np.diag([dr ** 2] * 3 + [dt ** 2] * 3), (n, 6, 6)).copy()


@pytest.fixture(scope="module")
def eight():
    return drive(figure_eight(20.0), lidar_rig().suspension)


@pytest.fixture(scope="module")
def frames(eight):
    return np.arange(eight.t_start, eight.t_end + 1e-9, 1.0 / RATE)


def _lidar_blocks(prob):
    """The lidar's factor blocks (one per chunk of the drive; ``first`` counts from the drive's start)."""
    return [b for b in prob.blocks if b.name == "lidar"]


def _stacked(prob):
    bs = _lidar_blocks(prob)
    return (np.concatenate([b.first for b in bs]), np.concatenate([b.Jx for b in bs]),
            np.concatenate([b.Jt for b in bs]))


def test_a_reported_covariance_equal_to_the_densities_scores_as_them(eight, frames):
    rig = lidar_rig()
    base = sigmas(evaluate(eight, lidar_rig(reported=False)))
    same = eight.with_logs({"lidar": SensorLog(frames, per_second(rig, frames.size))})
    assert sigmas(evaluate(same, rig)) == pytest.approx(base, rel=1e-9)
    # ten times the σ everywhere is a lidar of ten times the densities; without the option, the log changes nothing
    worse = eight.with_logs({"lidar": SensorLog(frames, 100.0 * per_second(rig, frames.size))})
    assert sigmas(evaluate(worse, rig)) == pytest.approx(sigmas(evaluate(eight, lidar_rig(False, 10.0))), rel=1e-9)
    assert sigmas(evaluate(worse, lidar_rig(reported=False))) == pytest.approx(base, rel=1e-12)


def test_pairs_reported_worse_weigh_one_over_the_square_root(eight, frames):
    """Pairs whose closing message reports c times the covariance have rows exactly 1/√c of the
    densities' rows; every other pair's rows are the densities'."""
    rig, c = lidar_rig(), 25.0
    Q = per_second(rig, frames.size)
    bad = (frames - frames[0] > 8.0) & (frames - frames[0] < 12.0)
    Q[bad] *= c
    logged = eight.with_logs({"lidar": SensorLog(frames, Q)})
    nom = Nominal.of(logged, rig)
    first, Jx, Jt = _stacked(problem.build(nom, rig))
    first0, Jx0, Jt0 = _stacked(problem.build(Nominal.of(eight, rig), lidar_rig(reported=False)))
    assert np.array_equal(first, first0)
    t_close = nom.t[first + 1] - nom.t[0]  # stride 1: a lidar frame every keyframe
    closing = (t_close > 8.0 + 0.05) & (t_close < 12.0 - 0.05)
    assert closing.sum() == 39
    f = np.where(closing, 1.0 / np.sqrt(c), 1.0)[:, None, None]
    assert np.abs(Jx - f * Jx0).max() <= 1e-12 * np.abs(Jx0).max()
    assert np.abs(Jt - f * Jt0).max() <= 1e-12 * np.abs(Jt0).max()
    s, s0 = sigmas(evaluate(logged, rig)), sigmas(evaluate(eight, lidar_rig(reported=False)))
    assert all(s[n] > s0[n] for n in ("lidar.trans_x", "lidar.trans_y", "lidar.rot_z", "lidar.time_offset"))


def _sigma_of(Lam, rig):
    names, nuisance = problem.columns(rig, 1)
    L = marginalise_nuisance(Lam, ~nuisance)
    C = np.linalg.inv(L)
    return {n: float(np.sqrt(C[i, i])) for i, n in enumerate(x for x, nu in zip(names, nuisance) if not nu)}


def test_an_anisotropic_world_covariance_against_a_reference(eight, frames):
    """A highway-like stretch: the odometry reports its along-track (world x and y mixed by a
    rotation) translation and its yaw far worse. The reference: the densities' rows unwhitened,
    then whitened by Σ^{-1/2} (symmetric square root) with Σ = Δt Bᵀ Q B, B from the
    trajectory's sampled orientation and the rig's mounting."""
    rig = lidar_rig()
    dr, dt_ = densities(rig)
    rng = np.random.default_rng(27)
    A = rng.normal(size=(6, 6))
    Qs = np.diag([dr ** 2, dr ** 2, 30 * dr ** 2, 50 * dt_ ** 2, 2 * dt_ ** 2, dt_ ** 2]) + 0.1 * dt_ ** 2 * A @ A.T
    Q = per_second(rig, frames.size)
    stretch = (frames - frames[0] > 5.0) & (frames - frames[0] < 15.0)
    Q[stretch] = Qs
    logged = eight.with_logs({"lidar": SensorLog(frames, Q)})
    nom = Nominal.of(logged, rig)
    plain = lidar_rig(reported=False)
    prob = problem.build(Nominal.of(eight, plain), plain)
    sig_r, sig_t = dr * np.sqrt(1 / RATE), dt_ * np.sqrt(1 / RATE)
    D = np.diag([sig_r] * 3 + [sig_t] * 3)
    R_V_B = rig.config.vehicle.T_V_B.R
    Qlog = nom.logs["lidar"].covariance

    def rewhitened(b):
        i, j = b.first, b.first + b.stride
        R_S = eight.sample(nom.t[i]).R_W_V @ R_V_B @ rig.config.sensors[0].T_B_S.R
        W = np.empty((b.n_factors, 6, 6))
        for n in range(b.n_factors):
            if not np.all(np.isfinite(Qlog[j[n]])):
                W[n] = np.linalg.inv(D)
                continue
            B = np.kron(np.eye(2), R_S[n])
            S = (nom.t[j[n]] - nom.t[i[n]]) * B.T @ Qlog[j[n]] @ B
            W[n] = np.real(np.linalg.inv(sqrtm(S)))
        return replace(b, Jx=W @ (D @ b.Jx), Jt=W @ (D @ b.Jt))

    blocks = tuple(rewhitened(b) if b.name == "lidar" else b for b in prob.blocks)
    ref = _sigma_of(elimination.marginal(replace(prob, blocks=blocks)), rig)
    got = sigmas(evaluate(logged, rig))
    for name in ("lidar.trans_x", "lidar.trans_y", "lidar.trans_z", "lidar.rot_z", "lidar.time_offset",
                 "imu.accel_bias_x"):
        assert got[name] == pytest.approx(ref[name], rel=1e-6), name
    base = sigmas(evaluate(eight, plain))
    assert got["lidar.trans_x"] > 1.05 * base["lidar.trans_x"]


def test_a_drive_turned_in_the_world_turns_its_odometrys_covariance(eight, frames):
    """Invariance: the drive and its world-frame covariance turned about the vertical and moved
    score alike (each 3-block of the 6 × 6 covariance turns with the world)."""
    from excite.core import so3

    rig = lidar_rig()
    dr, dt_ = densities(rig)
    Q = per_second(rig, frames.size)
    Q[40:120] = np.diag([dr ** 2, dr ** 2, 20 * dr ** 2, 60 * dt_ ** 2, dt_ ** 2, 3 * dt_ ** 2])
    logged = eight.with_logs({"lidar": SensorLog(frames, Q)})
    turned = logged.transformed(so3.rot_z(0.9), np.array([300.0, -40.0, 5.0]))
    a, b = sigmas(evaluate(logged, rig)), sigmas(evaluate(turned, rig))
    assert b == pytest.approx(a, rel=1e-6)
    # not turning the covariance with the drive is another problem
    unturned = turned.with_logs({"lidar": SensorLog(frames, Q)})
    assert sigmas(evaluate(unturned, rig))["lidar.trans_x"] != pytest.approx(a["lidar.trans_x"], rel=1e-3)


# --- from a bag -------------------------------------------------------------------------------


def _ros(rig, n, stretch=None, factor=1.0):
    """Per-message covariance in ROS order (x, y, z, rx, ry, rz) equal to the densities over a
    message interval, the translation × ``factor`` where ``stretch(t)``."""
    dr, dt_ = densities(rig)
    per = 1.0 / RATE

    def cov(t):
        C = np.broadcast_to(np.diag([dt_ ** 2 * per] * 3 + [dr ** 2 * per] * 3), (t.size, 6, 6)).copy()
        if stretch is not None:
            C[stretch(t), :3, :3] *= factor
        return C
    return cov


@pytest.mark.parametrize("suffix,msgtype", [(".bag", "nav_msgs/msg/Odometry"),
                                            ("", "geometry_msgs/msg/PoseWithCovarianceStamped")])
def test_a_bag_round_trip(tmp_path, eight, suffix, msgtype):
    rig = lidar_rig()
    plain_rig = lidar_rig(reported=False)
    same = write_bag(eight, tmp_path / f"same{suffix}", msgtype=msgtype, rate_hz=RATE,
                     pose_covariance=_ros(rig, 0))
    traj = read_bag_route(same, "/odom", odometry_topic="/odom", odometry_sensor="lidar")
    plain = read_bag_route(same, "/odom")
    base = sigmas(evaluate(plain, plain_rig))
    assert sigmas(evaluate(traj, rig)) == pytest.approx(base, rel=1e-9)
    tunnel = lambda t: (t >= 8.0) & (t <= 14.0)  # noqa: E731
    worse = write_bag(eight, tmp_path / f"tunnel{suffix}", msgtype=msgtype, rate_hz=RATE,
                      pose_covariance=_ros(rig, 0, tunnel, 100.0))
    traj = read_bag_route(worse, "/odom", odometry_topic="/odom", odometry_sensor="lidar")
    log = traj.logs["lidar"]
    k = int(np.argmin(np.abs(log.t - 10.0)))
    dr, dt_ = densities(rig)
    # in the residual's order (rotation, translation), per second
    assert np.allclose(np.diag(log.covariance[k]), [dr ** 2] * 3 + [100 * dt_ ** 2] * 3, rtol=1e-9)
    got = sigmas(evaluate(traj, rig))
    for name in ("lidar.trans_x", "lidar.trans_y", "lidar.trans_z"):
        assert got[name] > 1.1 * base[name], (name, got[name], base[name])
    # σ between the densities' and a lidar 10× worse in translation all along
    ten = build_rig({**rig.config.model_dump(), "sensors": [dict(
        rig.config.model_dump()["sensors"][0], noise=dict(rig.config.sensors[0].noise.model_dump(),
                                                         translation_density_m_per_sqrt_s=10 * dt_))]})
    assert got["lidar.trans_x"] < sigmas(evaluate(plain, ten))["lidar.trans_x"]


def test_clear_errors(tmp_path, eight, monkeypatch):
    zeros = write_bag(eight, tmp_path / "zeros.bag", rate_hz=RATE)
    with pytest.raises(BagError, match=r"/odom.*every message's pose covariance is zero.*use_reported_covariance"):
        read_bag_route(zeros, "/odom", odometry_topic="/odom")
    posed = write_bag(eight, tmp_path / "posed.bag", msgtype="geometry_msgs/msg/PoseStamped", rate_hz=RATE)
    with pytest.raises(BagError, match=r"PoseStamped carries no pose covariance"):
        read_pose_covariances(posed, "/odom")
    bad = write_bag(eight, tmp_path / "bad.bag", rate_hz=RATE,
                    pose_covariance=lambda t: -np.broadcast_to(np.eye(6), (t.size, 6, 6)))
    with pytest.raises(BagError, match=r"message 0: its pose covariance is not positive definite"):
        read_bag_route(bad, "/odom", odometry_topic="/odom")
    from excite.io.bags import covariance

    monkeypatch.setattr(covariance.bounds, "MAX_SAMPLES", 100)  # refused from the bag's index, before reading
    with pytest.raises(BagError, match=r"/odom.*200 messages, over the limit of 100 poses"):
        read_pose_covariances(bad, "/odom")


def test_the_cli_needs_one_sensor_asking_for_it(tmp_path, eight):
    rig = lidar_rig()
    path = write_bag(eight, tmp_path / "drive.bag", rate_hz=RATE, pose_covariance=_ros(rig, 0))
    runner = CliRunner()
    res = runner.invoke(app, ["score", str(path), "--topic", "/odom", "--odometry-topic", "/odom"])
    assert res.exit_code == 2 and "0 lidars or cameras with noise.use_reported_covariance" in res.output
    (tmp_path / "rig.yaml").write_text(__import__("yaml").safe_dump(rig.config.model_dump(mode="json")))
    res = runner.invoke(app, ["score", str(path), "--topic", "/odom", "--odometry-topic", "/odom",
                              "--rig", str(tmp_path / "rig.yaml"), "--json"])
    assert res.exit_code == 0, res.output
    assert "with a pose covariance, weigh the frame pairs of lidar" in res.stderr
    res = runner.invoke(app, ["score", str(path), "--topic", "/odom", "--rig", str(tmp_path / "rig.yaml"), "--json"])
    assert res.exit_code == 0 and "lidar sets noise.use_reported_covariance and the drive carries no" in res.stderr


def test_an_odometry_publishing_faster_than_the_frames(tmp_path, eight):
    """Messages at 20 Hz, each with the densities' covariance over its own 0.05 s, for a lidar of
    10 Hz frames: each message's covariance divided by its interval, times the pair's 0.1 s, is
    the densities' covariance of the pair (and not half of it)."""
    rig = lidar_rig()
    dr, dt_ = densities(rig)
    half = lambda t: np.broadcast_to(np.diag([dt_ ** 2 * 0.05] * 3 + [dr ** 2 * 0.05] * 3),  # noqa: E731
                                     (t.size, 6, 6)).copy()
    path = write_bag(eight, tmp_path / "fast.bag", rate_hz=20.0, pose_covariance=half)
    traj = read_bag_route(path, "/odom", odometry_topic="/odom")
    assert np.allclose(traj.logs["lidar"].covariance[3], np.diag([dr ** 2] * 3 + [dt_ ** 2] * 3), rtol=1e-6)
    base = sigmas(evaluate(read_bag_route(path, "/odom"), lidar_rig(reported=False)))
    assert sigmas(evaluate(traj, rig)) == pytest.approx(base, rel=1e-6)
    # and the log is what weighs the pairs: taken per pair as is (not per interval), σ would be √½ of it
    log = traj.logs["lidar"]
    as_is = sigmas(evaluate(traj.with_logs({"lidar": SensorLog(log.t, 0.5 * log.covariance)}), rig))
    assert as_is["lidar.trans_x"] < 0.9 * base["lidar.trans_x"]


# --- densities: the same σ at any frame rate --------------------------------------------------


def _lidar_at(rate_hz: float):
    base = load_rig("robotaxi")
    sensors = base.config.model_dump()["sensors"]
    sensors[0]["rate_hz"] = rate_hz  # the camera stays at 10 Hz, every 1/2/4 keyframes
    return base.with_config(keyframe_rate_hz=rate_hz, sensors=sensors)


def test_a_faster_lidar_of_the_same_density_is_told_the_same_sigma():
    traj = read_route(TRAJ / "slalom.tum")
    sigma = {}
    for f in (10.0, 20.0, 40.0):
        rep = evaluate(traj, _lidar_at(f))
        sigma[f] = {p.name: p.sigma for p in rep.parameters}
    for name, s10 in sigma[10.0].items():
        for f in (20.0, 40.0):
            assert sigma[f][name] == pytest.approx(s10, rel=0.03), (name, f, sigma[f][name], s10)


def test_the_per_pair_sigma_is_the_density_times_root_dt():
    rig = _lidar_at(40.0)
    lidar = rig.config.sensors[0]
    sig_r, sig_t = pair_sigmas(lidar)
    assert sig_t == pytest.approx(lidar.noise.translation_density_m_per_sqrt_s * math.sqrt(1 / 40.0), rel=1e-15)
    assert sig_r == pytest.approx(math.radians(lidar.noise.rotation_density_deg_per_sqrt_s) / math.sqrt(40.0), rel=1e-15)
    # the bundled rig's densities are its old per-pair σ at 10 Hz, exactly
    assert pair_sigmas(load_rig("robotaxi").config.sensors[0]) == (math.radians(0.05), 0.02)


@pytest.mark.parametrize("old, new, factor", [("rotation_sigma_deg", "rotation_density_deg_per_sqrt_s", 0.05),
                                              ("translation_sigma_m", "translation_density_m_per_sqrt_s", 0.02)])
def test_the_old_per_pair_keys_give_the_equivalent_density(old, new, factor):
    data = load_rig("robotaxi").config.model_dump()
    data["sensors"][1]["rate_hz"] = 20.0
    data["keyframe_rate_hz"] = 20.0
    data["sensors"][1]["noise"] = {old: factor}
    with pytest.raises(RigError) as err:
        build_rig(data)
    msg = str(err.value)
    assert msg.startswith(f"sensors.1.noise.{old}: ")
    assert f"sensors.1.noise.{new}" in msg and "20 Hz" in msg
    want = f"{factor * math.sqrt(20.0):.6g}"
    assert f"{new}: {want}" in msg, msg
    # the value it names keeps the old σ per pair
    data["sensors"][1]["noise"] = {"rotation_density_deg_per_sqrt_s": 1.0, "translation_density_m_per_sqrt_s": 1.0,
                                   new: float(want)}
    s = build_rig(data).config.sensors[1]
    got = pair_sigmas(s)[0 if old.startswith("rotation") else 1]
    assert got == pytest.approx(math.radians(factor) if old.startswith("rotation") else factor, rel=1e-5)
