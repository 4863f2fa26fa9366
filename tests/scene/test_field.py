"""A scene's field: lidar scans cast once on a grid and looked up along drives, held to the scans
:func:`excite.scene.along.seen` casts along the same drives."""

from __future__ import annotations

import numpy as np
import pytest

from excite.errors import SceneError
from excite.motion.maneuvers import slalom
from excite.motion.vehicle import ControlProfile, Suspension, drive
from excite.rig.config import RIGS_DIR, build_rig, load_rig, read_yaml
from excite.scene import along, shapes
from excite.scene.field import field
from excite.scene.model import Scene
from excite.score.evaluate import evaluate

# buildings on the north side only: what a scan tells depends on where in the lot it is cast
SCENE = Scene.combine([shapes.ground(-60, -45, 60, 45), shapes.box(-40, 28, -10, 40, 12),
                       shapes.box(0, 28, 35, 38, 9)])


def _lidar_rig():
    doc = read_yaml(RIGS_DIR / "robotaxi.yaml")
    doc["sensors"] = [s for s in doc["sensors"] if s["kind"] != "camera"]
    return build_rig(doc, base_dir=RIGS_DIR)


RIG = _lidar_rig()


@pytest.fixture(scope="module")
def fld():
    return field(SCENE, RIG, (-25.0, -20.0), (25.0, 20.0))


def _rel(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a - b, axis=(1, 2)) / np.linalg.norm(b, axis=(1, 2))


def test_a_level_drive_looks_up_the_scans_seen_casts(fld):
    """A drive that does not tilt (a rigid body), across the lot and turning through every
    heading: each sample's information within a few per cent of the scan cast there, where the
    scans differ across the lot by far more (a lookup at the wrong place would show)."""
    t = np.linspace(0.0, 40.0, 401)
    prof = ControlProfile(t, np.full_like(t, 3.0), np.full_like(t, 1.0 / 15.0), start=(-5.0, -15.0, 0.0))
    traj = drive(prof, Suspension.rigid())
    exact, looked = along.seen(traj, RIG, SCENE).scene, fld.seen(traj, RIG).scene
    assert np.array_equal(exact.t["lidar"], looked.t["lidar"])
    H, G = exact.H_W["lidar"], exact.G_W["lidar"]
    err = _rel(looked.H_W["lidar"], H)
    assert err.max() < 0.05 and np.median(err) < 0.02  # the azimuths' sampling and the interpolation
    assert _rel(looked.G_W["lidar"], G).max() < 0.03
    # what the scans tell changes along this drive: the nearest and furthest from the buildings
    assert _rel(H[None, np.argmax(traj.translation(exact.t["lidar"])[0][:, 1])], H[None, np.argmin(
        traj.translation(exact.t["lidar"])[0][:, 1])]).max() > 0.2


@pytest.mark.parametrize("k", [0, 1, 3])
def test_a_vehicle_standing_with_its_lidar_on_a_grid_node_gets_that_nodes_scan(fld, k):
    """The lookup is by the sensor's position and heading (not the vehicle's): a vehicle placed so
    that its lidar stands on node (i, j) at the field's k-th heading reads that scan exactly."""
    i, j = 7, 4
    T = RIG.config.vehicle.T_V_B
    s = along.lidars(RIG)[0]
    arm = (T.p + T.R @ s.T_B_S.p)[:2]
    a = 2 * np.pi * k / 4
    c, sn = np.cos(a), np.sin(a)
    x, y = np.array([fld.xs[i], fld.ys[j]]) - np.array([[c, -sn], [sn, c]]) @ arm
    t = np.linspace(0.0, 4.0, 41)
    traj = drive(ControlProfile(t, np.zeros_like(t), np.zeros_like(t), start=(x, y, a)), Suspension.rigid())
    looked = fld.seen(traj, RIG).scene
    np.testing.assert_allclose(looked.H_W["lidar"], np.broadcast_to(fld.H["lidar"][k, i, j], looked.H_W["lidar"].shape),
                               rtol=1e-6, atol=1e-6 * np.abs(fld.H["lidar"][k, i, j]).max())
    np.testing.assert_allclose(looked.G_W["lidar"][0], fld.G["lidar"][k, i, j], rtol=1e-6,
                               atol=1e-6 * np.abs(fld.G["lidar"][k, i, j]).max())
    assert not np.allclose(fld.H["lidar"][k, i, j], fld.H["lidar"][k, i, j + 6], rtol=0.05)


def test_a_drive_that_tilts_scores_as_seen_scores_it(fld):
    """The field leaves out the body's pitch and roll; a slalom whose body rolls by degrees
    scores within a per cent of the scans cast along it, every parameter's σ too."""
    traj = drive(slalom(30.0), RIG.suspension)
    exact = evaluate(along.seen(traj, RIG, SCENE), RIG)
    looked = evaluate(fld.seen(traj, RIG), RIG)
    assert looked.score == pytest.approx(exact.score, rel=0.01)
    for a, b in zip(exact.parameters, looked.parameters):
        assert b.sigma == pytest.approx(a.sigma, rel=0.02), a.name
    assert looked.scene["digest"] == SCENE.digest


def test_a_field_costs_a_fraction_of_the_scans_it_replaces(fld):
    import time

    traj = drive(slalom(60.0), RIG.suspension)
    c0 = time.process_time()
    along.seen(traj, RIG, SCENE)
    c1 = time.process_time()
    fld.seen(traj, RIG)
    c2 = time.process_time()
    assert c2 - c1 < 0.5 * (c1 - c0)  # CPU time of this process: does not depend on the machine's load


def test_a_rig_with_a_camera_or_a_grid_too_fine_is_refused():
    with pytest.raises(SceneError, match=r"holds lidar scans only; the rig .* has cameras \(cam_front\)"):
        field(SCENE, load_rig("robotaxi"), (-10.0, -10.0), (10.0, 10.0))
    with pytest.raises(SceneError, match=r"scans\) is over 50000 scans: a coarser step_m or a smaller area"):
        field(SCENE, RIG, (-50.0, -40.0), (50.0, 40.0), step_m=0.25)
