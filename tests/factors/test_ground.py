"""A lidar's road plane: the information of a stop and of a drive over level road, against the
closed form of the plane fit and against the dense reference."""

from __future__ import annotations

import numpy as np
import pytest

from excite.factors import base as registry
from excite.factors.base import Nominal
from excite.factors.ground import GroundPlane, information
from excite.information import dense, elimination, problem
from excite.motion.vehicle import ControlProfile, Suspension, drive
from excite.rig.config import build_rig, load_rig
from excite.scene import along, lidar, shapes
from excite.score.evaluate import evaluate
from excite.factors.optics import lidar_beams

RIG = load_rig("robotaxi")
LOT = shapes.ground(-400.0, -400.0, 400.0, 400.0)


def figure_eight(stop_s: float, moving_s: float = 64.0) -> ControlProfile:
    """Planar turns both ways at 6 m/s, after standing ``stop_s`` seconds (level ground)."""
    t = np.linspace(0.0, stop_s + moving_s, int((stop_s + moving_s) * 4) + 1)
    moving = np.clip((t - stop_s) / 3.0, 0.0, 1.0)
    speed = 6.0 * moving**2 * (3 - 2 * moving)
    curvature = 0.08 * np.sin(2 * np.pi * np.maximum(t - stop_s, 0.0) / 30.0)
    return ControlProfile(t, speed, curvature)


def lidar_sigmas(rep):
    return {p.name: p.sigma for p in rep.parameters if p.name in ("lidar.trans_z", "lidar.rot_x", "lidar.rot_y")}


def test_a_stop_holds_the_road_s_worth_and_no_more():
    """Standing still, every frame sees the same patch of road: together they hold
    ``nF (I + Q nF)⁻¹`` (n frames of the plane fit F, the road's covariance Q), written out here
    from a scan of the ground at the standing pose."""
    traj = along.seen(drive(figure_eight(10.0), Suspension.rigid()), RIG, LOT)
    nom = Nominal.of(traj, RIG)
    s = next(e for e in RIG.config.sensors if e.kind == "lidar")
    kind = GroundPlane()
    frames = registry.factor_keyframes(kind, RIG, s, nom.n_keyframes, nom)
    standing = frames[nom.t[frames] < 9.0]
    assert standing.size >= 80
    Lam = information(nom, RIG, s, frames)[nom.t[frames] < 9.0].sum(axis=0)
    # the plane fit of one scan at the standing pose, from its ground returns
    R_W_S = nom.R[standing[0]] @ s.T_B_S.R
    p_W_S = nom.p[standing[0]] + nom.R[standing[0]] @ s.T_B_S.p
    scan = lidar.pattern(lidar_beams(s.beams))
    pts, nrm, w, _ = lidar.cast_scan(LOT, R_W_S, p_W_S, scan)
    rows = np.hstack([pts, np.ones((len(pts), 1))])
    n = R_W_S.T @ np.array([0.0, 0.0, 1.0])
    P = np.eye(4)
    P[:3, :3] -= np.outer(n, n)
    F = P @ ((rows * (w / scan.range_noise_m**2)[:, None]).T @ rows) @ P
    Q = np.zeros((4, 4))
    Q[:3, :3] = np.radians(s.ground_plane.road_tilt_sigma_deg) ** 2 * P[:3, :3]
    Q[3, 3] = s.ground_plane.road_height_sigma_m**2
    # the frames sharing the stop's patch: the standing ones and those within half a patch
    m = np.sum(np.linalg.norm(nom.p[frames] - nom.p[standing[0]], axis=1) <= 0.5 * s.ground_plane.patch_length_m)
    n_st = standing.size
    expected = n_st * F @ np.linalg.inv(np.eye(4) + m * Q @ F)
    # the quadrature's azimuths turn from sample to sample: the same plane to a fraction of a percent
    assert np.allclose(Lam, expected, rtol=0.02, atol=0.02 * np.abs(expected).max())
    # and what it means: the lidar's height to the road's σ (the standing frames hold n of the
    # patch's m frames' worth), never better
    cov = np.linalg.pinv(Lam, hermitian=True)
    assert np.sqrt(cov[3, 3]) == pytest.approx(s.ground_plane.road_height_sigma_m * np.sqrt(m / n_st), rel=0.05)
    tilt = np.radians(s.ground_plane.road_tilt_sigma_deg) * np.sqrt(m / n_st)
    assert np.sqrt(cov[0, 0]) == pytest.approx(tilt, rel=0.05) and np.sqrt(cov[1, 1]) == pytest.approx(tilt, rel=0.05)


@pytest.mark.parametrize("stop_s", [0.0, 10.0])
def test_the_road_plane_s_sigmas_equal_the_dense_reference(stop_s):
    traj = along.seen(drive(figure_eight(stop_s, 16.0), RIG.suspension), RIG, LOT)
    nom = Nominal.of(traj, RIG)
    prob = problem.build([nom], RIG)
    fast = elimination.marginal(prob)
    ref = dense.marginal_dense(prob)
    idx = [RIG.index(n) for n in ("lidar.trans_z", "lidar.rot_x", "lidar.rot_y")]
    cf = np.linalg.inv(fast)[np.ix_(idx, idx)]
    cr = np.linalg.inv(ref)[np.ix_(idx, idx)]
    assert np.allclose(np.sqrt(np.diag(cf)), np.sqrt(np.diag(cr)), rtol=1e-7)


def test_the_road_determines_what_planar_driving_cannot():
    """The same planar drive: blind, the lidar's height is left to what little the odometry's
    pitch says; seeing the road, it is set to millimetres, and a stop adds the road's tilt."""
    blind = lidar_sigmas(evaluate(drive(figure_eight(0.0), RIG.suspension), RIG))
    road = lidar_sigmas(evaluate(along.seen(drive(figure_eight(0.0), RIG.suspension), RIG, LOT), RIG))
    stop = lidar_sigmas(evaluate(along.seen(drive(figure_eight(10.0), RIG.suspension), RIG, LOT), RIG))
    assert blind["lidar.trans_z"] > 0.05 and road["lidar.trans_z"] < 0.005
    assert stop["lidar.rot_x"] <= road["lidar.rot_x"] and stop["lidar.rot_y"] <= road["lidar.rot_y"]
    # without the road plane (switched off in the rig) the scene can only take information away
    data = RIG.config.model_dump()
    for e in data["sensors"]:
        if e["kind"] == "lidar":
            e["ground_plane"]["enabled"] = False
    off = build_rig(data)
    no_plane = lidar_sigmas(evaluate(along.seen(drive(figure_eight(0.0), off.suspension), off, LOT), off))
    assert all(no_plane[k] >= blind[k] * (1 - 1e-9) for k in blind)
