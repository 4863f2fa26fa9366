"""A scan's registration information against independent computations: finite differences of
ray-cast ranges (the dense reference), small_gicp's point-to-plane Hessians, and the degenerate
scenes whose null directions are known exactly."""

from __future__ import annotations

import numpy as np
import pytest

from excite.core import so3
from excite.factors.optics import LIDAR_PRESETS, lidar_beams
from excite.scene import lidar, shapes
from excite.scene.model import Scene

BEAMS = lidar_beams(None)
EYE = np.eye(3)
AT = np.array([0.0, 0.0, 1.8])

OPEN_LOT = shapes.ground(-100, -100, 100, 100)
TUNNEL = shapes.tunnel(400.0, 10.0, 6.0, x0=-200.0)
ONE_WALL = Scene.combine([OPEN_LOT, shapes.wall((-60, 8), (60, 8), 5.0)])
CANYON = Scene.combine([OPEN_LOT, shapes.box(-100, 9, 100, 20, 15), shapes.box(-100, -20, 100, -9, 15)])
BUILDINGS = Scene.combine([OPEN_LOT, shapes.box(-30, 10, 30, 25, 12), shapes.box(5, -30, 20, -12, 8),
                           shapes.cylinder((-8, -6), 0.2, 4.0)])


def info(scene, R=EYE, p=AT, density=1.0):
    return lidar.informations(scene, R[None], p[None], BEAMS, density).H[0]


def ranges(scene, R, p, scan):
    """The ranges the scan's rays measure from the pose ``R, p`` (the lidar's own measurements)."""
    d = scan.directions @ R.T
    return scene.cast(np.broadcast_to(p, d.shape), d, scan.max_range_m)


def finite_difference_information(scene, R, p, steps=(2e-4, 2e-3)):
    """The dense reference: every ray's range differentiated numerically by the sensor's pose
    (central differences of the ray caster), turned from a range into a point-to-plane distance
    by the incidence ``n·d`` (a range error along the ray moves the point off its plane by
    ``(n·d) δr``), summed as ``Σ w/σ² g gᵀ``. Rays whose hit moves to another triangle under the
    step (edges) are left out. Steps: 2e-4 rad (a grazing ray's range is far from linear in
    the rotation) and 2 mm (planes are exactly linear in a translation)."""
    scan = lidar.pattern(BEAMS)
    base = ranges(scene, R, p, scan)
    facing = np.abs(np.einsum("ij,ij->i", base.normal @ R, scan.directions)) >= lidar.MIN_INCIDENCE_COS
    keep = base.hit & (base.distance >= scan.min_range_m) & facing
    G = np.zeros((scan.n_rays, 6))
    for k in range(6):
        step = steps[0] if k < 3 else steps[1]
        dv = np.zeros(6)
        dv[k] = step
        out = []
        for sgn in (1.0, -1.0):
            Rk = R @ so3.exp(sgn * dv[:3])
            pk = p + R @ (sgn * dv[3:])
            h = ranges(scene, Rk, pk, scan)
            keep &= h.hit & (h.face == base.face)
            out.append(h.distance)
        G[:, k] = (out[0] - out[1]) / (2 * step)
    n_S = base.normal @ R
    cos = np.einsum("ij,ij->i", n_S, scan.directions)
    g = -cos[:, None] * G
    w = scan.weight / scan.range_noise_m**2
    return (g[keep] * w[keep, None]).T @ g[keep], keep


def null_space(H, rel=1e-9):
    lam, V = np.linalg.eigh(H)
    return V[:, lam <= rel * lam[-1]]


@pytest.mark.parametrize("scene, null", [
    (OPEN_LOT, [3, 4, 2]),  # x, y and yaw
    (TUNNEL, [3]),  # along its axis
    (ONE_WALL, [3]),  # along the wall (the ground takes z, roll and pitch, the wall y and yaw)
    (CANYON, [3]),  # along the street
    (BUILDINGS, []),  # nothing
])
def test_degenerate_scenes_leave_exactly_their_null_directions(scene, null):
    H = info(scene)
    N = null_space(H)
    assert N.shape[1] == len(null)
    if not null:
        assert np.linalg.eigvalsh(H)[0] > 1e-6 * np.linalg.eigvalsh(H)[-1]
        return
    expected = np.eye(6)[:, null]
    # the null space is spanned by the named directions
    assert np.linalg.norm(expected @ expected.T @ N - N) < 1e-9
    lam = np.linalg.eigvalsh(H)
    assert np.all(lam[: len(null)] <= 1e-12 * lam[-1])


@pytest.mark.parametrize("scene", [OPEN_LOT, TUNNEL, ONE_WALL, BUILDINGS], ids=["open", "tunnel", "wall", "buildings"])
def test_information_equals_finite_differences_of_ray_cast_ranges(scene):
    R = so3.exp(np.array([0.02, -0.03, 0.7]))
    H = info(scene, R, AT)
    H_fd, keep = finite_difference_information(scene, R, AT)
    assert keep.sum() > 500
    # the rays lost at edges are a few percent: compare over the same rays
    scan = lidar.pattern(BEAMS)
    pts, nrm, w, _ = lidar.cast_scan(scene, R, AT, scan)
    hits = ranges(scene, R, AT, scan)
    facing = np.abs(np.einsum("ij,ij->i", hits.normal @ R, scan.directions)) >= lidar.MIN_INCIDENCE_COS
    ok = hits.hit & (hits.distance >= scan.min_range_m) & facing
    same = keep[ok]
    H_same = lidar.point_information(pts[same], nrm[same], scan.range_noise_m, w[same])
    scale = np.abs(H_same).max()
    assert np.abs(H_fd - H_same).max() < 2e-3 * scale
    # and the directions it leaves free are the reference's
    assert null_space(H).shape[1] == null_space(H_fd, 1e-6).shape[1]


def _small_gicp_hessians(points):
    small_gicp = pytest.importorskip("small_gicp")
    pc = small_gicp.PointCloud(points)
    small_gicp.estimate_normals(pc, num_neighbors=20)
    tree = small_gicp.KdTree(pc)
    factor, rejector = small_gicp.PointToPlaneICPFactor(), small_gicp.DistanceRejector()
    H = np.zeros((len(points), 6, 6))
    for i in range(len(points)):
        ok, H[i], _, _ = factor.linearize(pc, pc, tree, np.eye(4), i, rejector)
        assert ok
    return H, pc.normals()[:, :3]


@pytest.mark.parametrize("scene", [OPEN_LOT, TUNNEL, ONE_WALL, BUILDINGS], ids=["open", "tunnel", "wall", "buildings"])
def test_equal_to_small_gicp_point_to_plane_hessian(scene):
    """small_gicp's PLANE_ICP residual is ``n ⊙ (q − T p)`` (per axis), whose Hessian equals
    ``[p × n; n][p × n; n]ᵀ`` where the normal is along an axis: the scenes are axis-aligned and
    the scan at the identity, and the points compared are those whose neighbourhood lies on one
    face (small_gicp's estimated normal is the face's to rounding)."""
    scan = lidar.pattern(BEAMS)
    pts, nrm, w, _ = lidar.cast_scan(scene, EYE, AT, scan)
    H_i, n_est = _small_gicp_hessians(pts)
    same = np.abs(np.abs(np.einsum("ij,ij->i", n_est, nrm)) - 1.0) < 1e-9
    assert same.mean() > 0.5
    ours = lidar.point_information(pts[same], nrm[same], 1.0)
    theirs = H_i[same].sum(axis=0)
    assert np.abs(ours - theirs).max() <= 1e-6 * np.abs(ours).max()


def test_within_five_percent_of_small_gicp_with_its_own_normals():
    """On a scan as dense as the lidar's (every beam, its azimuth resolution), small_gicp's own
    normals give the same Hessian to 5 % on the diagonal."""
    beams = LIDAR_PRESETS["vlp16"]
    n_az = int(round(360.0 / beams.horizontal_resolution_deg))
    E, A = np.meshgrid(beams.elevations_rad, np.linspace(-np.pi, np.pi, n_az, endpoint=False), indexing="ij")
    d = np.column_stack([(np.cos(E) * np.cos(A)).ravel(), (np.cos(E) * np.sin(A)).ravel(), np.sin(E).ravel()])
    hits = BUILDINGS.cast(np.broadcast_to(AT, d.shape), d, 60.0)
    pts, nrm = d[hits.hit] * hits.distance[hits.hit, None], hits.normal[hits.hit]
    ours = lidar.point_information(pts, nrm, 1.0)
    H_i, _ = _small_gicp_hessians(pts)
    assert np.all(np.abs(np.diag(H_i.sum(axis=0)) / np.diag(ours) - 1.0) < 0.05)


def test_rigid_motion_of_scene_and_sensor_changes_nothing():
    R = so3.exp(np.array([0.0, 0.0, 1.1]))
    p = np.array([250.0, -40.0, 3.0])
    H = info(BUILDINGS, so3.exp(np.array([0.01, 0.0, 0.3])), AT)
    moved = BUILDINGS.transformed(R, p)
    H2 = info(moved, R @ so3.exp(np.array([0.01, 0.0, 0.3])), R @ AT + p)
    assert np.abs(H - H2).max() < 1e-3 * np.abs(H).max()


@pytest.mark.parametrize("scene", [BUILDINGS, TUNNEL], ids=["buildings", "tunnel"])
def test_finer_quadrature_keeps_the_information_per_solid_angle(scene):
    """Twice the rays: the information per solid angle is the lidar's, not the quadrature's (a
    lone wall's yaw, carried by its most oblique returns, needs a finer quadrature than this)."""
    H1, H2 = info(scene), info(scene, density=2.0)
    d1, d2 = np.diag(H1), np.diag(H2)
    ok = d1 > 1e-9 * d1.max()
    assert np.all(np.abs(d2[ok] / d1[ok] - 1.0) < 0.05)


def test_scene_refuses_what_it_cannot_hold():
    from excite.errors import SceneError

    with pytest.raises(SceneError, match="vertex 1: not a finite number"):
        Scene(np.array([[0, 0, 0], [np.nan, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]), np.zeros(1, int),
              (shapes.Surface("ground"),))
    with pytest.raises(SceneError, match="height -3"):
        shapes.prism([(0, 0), (1, 0), (1, 1)], -3.0)
    with pytest.raises(SceneError, match="vertices, more than"):
        shapes.prism(np.random.default_rng(0).normal(size=(200_000, 2)), 3.0)


def test_a_scene_travels_to_another_process_and_casts_there():
    import pickle

    BUILDINGS.cast(np.zeros((1, 3)) + AT, np.array([[1.0, 0.0, 0.0]]), 100.0)  # its caster built here
    copy = pickle.loads(pickle.dumps(BUILDINGS))
    assert copy.digest == BUILDINGS.digest
    assert np.array_equal(info(copy), info(BUILDINGS))
