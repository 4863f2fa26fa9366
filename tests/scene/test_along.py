"""A drive seeing a scene: each lidar frame pair told what the surfaces in view can tell, combined
with the odometry's drift — checked against the algebra it states, the rank it must keep, and
what a scene can and cannot do to σ."""

from __future__ import annotations

import numpy as np
import pytest

from excite.core import so3
from excite.factors import base as registry
from excite.factors.base import Nominal
from excite.factors.odometry import Odometry, pair_sigmas, scene_whitening
from excite.motion.maneuvers import slalom
from excite.motion.vehicle import Suspension, drive
from excite.rig.config import build_rig, load_rig
from excite.scene import along, shapes
from excite.scene.model import Scene
from excite.score.evaluate import evaluate

RIG = load_rig("robotaxi")
LOT = shapes.ground(-60, -45, 60, 45)
BUILDINGS = Scene.combine([LOT, shapes.box(-40, 30, -10, 45, 12), shapes.box(0, 30, 35, 42, 9),
                           shapes.box(-50, -44, -30, -35, 6)])


@pytest.fixture(scope="module")
def slalom_drive():
    return drive(slalom(40.0), RIG.suspension)


def lidar_pairs(traj):
    nom = Nominal.of(traj, RIG)
    s = next(e for e in RIG.config.sensors if e.kind == "lidar")
    kind = Odometry()
    first = registry.factor_keyframes(kind, RIG, s, nom.n_keyframes)
    return nom, s, first, registry.stride(kind, RIG, s)


def test_open_lot_pairs_have_exactly_three_directions_without_information():
    level = drive(slalom(20.0), Suspension.rigid())  # the body does not tilt: the lidar stays level
    nom, s, first, stride = lidar_pairs(along.seen(level, RIG, LOT))
    W = scene_whitening(nom, s, first, stride)
    # three rows of exact zeros: no information at all, not a rounding error's worth
    assert np.all(np.sum(np.all(W == 0.0, axis=2), axis=1) == 3)
    # the null directions are the pair's yaw and horizontal translation (the lidar is level)
    _, _, Vt = np.linalg.svd(W[len(W) // 2])
    null = Vt[-3:]
    assert np.linalg.norm(null[:, [0, 1, 5]]) < 1e-6


def test_pair_information_is_the_sum_of_covariances(slalom_drive):
    """Where the scene constrains every direction, ``WᵀW = (A_r⁻¹ + Q)⁻¹``: the registration's
    covariance and the drift's added, computed here the direct way."""
    nom, s, first, stride = lidar_pairs(along.seen(slalom_drive, RIG, BUILDINGS))
    W = scene_whitening(nom, s, first, stride)
    k = len(first) // 3
    i, j = first[k], first[k] + stride
    R_Si, R_Sj = nom.R[i] @ s.T_B_S.R, nom.R[j] @ s.T_B_S.R
    B = np.kron(np.eye(2), R_Sj)
    A = B.T @ nom.scene[s.name][j] @ B
    M = np.kron(np.diag([1.0, 0.0]), np.eye(3)) + np.kron(np.diag([0.0, 1.0]), (R_Si.T @ R_Sj).T)
    A_r = M.T @ A @ M
    sig_r, sig_t = pair_sigmas(s)
    Q = np.diag([sig_r**2] * 3 + [sig_t**2] * 3)
    direct = np.linalg.inv(np.linalg.inv(A_r) + Q)
    assert np.allclose(W[k].T @ W[k], direct, rtol=1e-8, atol=1e-8 * np.abs(direct).max())


def _without_road_plane():
    data = RIG.config.model_dump()
    for e in data["sensors"]:
        if e["kind"] == "lidar":
            e["ground_plane"]["enabled"] = False
    return build_rig(data)


def test_a_scene_never_adds_odometry_information_and_structure_helps(slalom_drive):
    """The odometry's pairs only (the road plane, which adds a measurement, switched off)."""
    rig = _without_road_plane()
    blind = {p.name: p.sigma for p in evaluate(slalom_drive, rig).parameters}
    lot = {p.name: p.sigma for p in evaluate(along.seen(slalom_drive, rig, LOT), rig).parameters}
    built = {p.name: p.sigma for p in evaluate(along.seen(slalom_drive, rig, BUILDINGS), rig).parameters}
    # Λ_pair ≤ Q⁻¹ in the Loewner order, so no marginal σ can shrink
    assert all(lot[n] >= blind[n] * (1 - 1e-9) and built[n] >= blind[n] * (1 - 1e-9) for n in blind)
    # the open lot leaves the lidar's horizontal lever arm and yaw to what the rest can say
    for n in ("lidar.trans_x", "lidar.trans_y", "lidar.rot_z"):
        assert lot[n] > 5 * built[n]


def test_moving_scene_and_route_together_changes_no_sigma(slalom_drive):
    R = so3.exp(np.array([0.0, 0.0, 0.9]))
    p = np.array([1200.0, -300.0, 12.0])
    a = evaluate(along.seen(slalom_drive, RIG, BUILDINGS), RIG)
    b = evaluate(along.seen(slalom_drive.transformed(R, p), RIG, BUILDINGS.transformed(R, p)), RIG)
    for x, y in zip(a.parameters, b.parameters):
        assert y.sigma == pytest.approx(x.sigma, rel=1e-4), x.name


def test_a_window_sees_what_the_whole_drive_sees(slalom_drive):
    traj = along.seen(slalom_drive, RIG, BUILDINGS)
    whole = Nominal.of(traj, RIG)
    part = Nominal.of(traj, RIG, keyframes=(40, 120))
    assert np.array_equal(part.scene["lidar"], whole.scene["lidar"][40:121])
