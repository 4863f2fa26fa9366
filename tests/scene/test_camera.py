"""A camera frame pair's information from the scene against independent computations: finite
differences of the projection, a dense Schur complement over every landmark and the pose, the
facts of two-view geometry (one landmark one row, no information along the scale, none without
parallax, translation weakening as the square of the distance), a Monte Carlo of two-view bundle
adjustment, and what a scene does to the robotaxi's camera along a slalom."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from excite.core import so3
from excite.errors import RigError
from excite.factors.base import Nominal
from excite.factors.optics import DEFAULT_CAMERA, CameraOptics
from excite.motion.maneuvers import slalom
from excite.motion.vehicle import drive
from excite.rig.config import build_rig, load_rig
from excite.scene import along, camera, shapes
from excite.scene.model import Scene
from excite.score.evaluate import evaluate

import two_view

SIGMA = DEFAULT_CAMERA.bearing_sigma  # 1 px at 1000 px: 1 mrad
R_IJ = so3.exp(np.array([0.01, 0.04, -0.02]))
T_IJ = np.array([0.15, -0.05, 1.0])  # a metre forward, a little to the right and up
# the optical frame of a camera looking along the world's +x (z forward, x right, y down)
LOOK_X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def observed(X, R, t, delta=np.zeros(6)):
    """``[u_i, u_j]`` of landmark X (S_i) with ``T_ij`` perturbed on the right by ``delta``."""
    R2 = R @ so3.exp(delta[:3])
    t2 = t + R @ delta[3:]
    return np.concatenate([two_view.pi(X), two_view.pi(R2.T @ (X - t2))])


# --------------------------------------------------------------------------------------------
# One landmark, many landmarks: the algebra against independent computation


def test_a_landmarks_jacobian_equals_finite_differences_of_its_projections():
    rng = np.random.default_rng(4)
    for X in two_view.landmarks(rng, 8):
        J = camera.jacobians(X[None], R_IJ, T_IJ)[0]
        h = 1e-6
        num = np.zeros((4, 9))
        for k in range(9):
            e = np.zeros(9)
            e[k] = h
            num[:, k] = (observed(X + e[:3], R_IJ, T_IJ, e[3:]) - observed(X - e[:3], R_IJ, T_IJ, -e[3:])) / (2 * h)
        assert np.allclose(J, num, rtol=1e-6, atol=1e-8 * np.abs(J).max())


def dense_schur(X, R, t, sigma, weights=None):
    """The reference: the pair's full Jacobian over every landmark's position and the pose
    (rows whitened, each landmark's by √weight), ``H = JᵀJ``, the landmarks eliminated by numpy."""
    n = X.shape[0]
    w = np.ones(n) if weights is None else weights
    J = np.zeros((4 * n, 3 * n + 6))
    for k in range(n):
        Jk = camera.jacobians(X[k][None], R, t)[0] * np.sqrt(w[k]) / sigma
        J[4 * k:4 * k + 4, 3 * k:3 * k + 3] = Jk[:, :3]
        J[4 * k:4 * k + 4, 3 * n:] = Jk[:, 3:]
    H = J.T @ J
    Hxx, Hxd, Hdd = H[:3 * n, :3 * n], H[:3 * n, 3 * n:], H[3 * n:, 3 * n:]
    return Hdd - Hxd.T @ np.linalg.solve(Hxx, Hxd)


def test_the_eliminated_information_equals_a_dense_schur_complement():
    rng = np.random.default_rng(5)
    X = two_view.landmarks(rng, 24)
    w = rng.uniform(0.5, 3.0, X.shape[0])
    ref = dense_schur(X, R_IJ, T_IJ, SIGMA, w)
    ours = np.einsum("n,nij->ij", w, camera.eliminated(X, R_IJ, T_IJ, SIGMA))
    assert np.allclose(ours, ref, rtol=1e-8, atol=1e-9 * np.abs(ref).max())


def test_one_landmark_is_one_row_that_does_not_see_the_scale():
    rng = np.random.default_rng(6)
    e = two_view.scale_direction(R_IJ, T_IJ)
    for X in two_view.landmarks(rng, 6):
        S = camera.eliminated(X[None], R_IJ, T_IJ, SIGMA)[0]
        lam = np.linalg.eigvalsh(S)
        assert lam[-1] > 0 and np.all(np.abs(lam[:-1]) < 1e-9 * lam[-1])  # rank 1: the epipolar constraint
        assert np.linalg.norm(S @ e) < 1e-9 * lam[-1]
    A = camera.eliminated(two_view.landmarks(rng), R_IJ, T_IJ, SIGMA).sum(axis=0)
    lam = np.linalg.eigvalsh(A)
    assert np.linalg.norm(A @ e) < 1e-9 * lam[-1]
    assert lam[1] > 1e-6 * lam[-1]  # five directions told, the scale's not


def test_the_length_is_told_as_well_as_the_translations_other_directions():
    rng = np.random.default_rng(7)
    X = two_view.landmarks(rng)
    bare = camera.eliminated(X, R_IJ, T_IJ, SIGMA).sum(axis=0)
    full = camera.pair_information(X, R_IJ, T_IJ, SIGMA)
    e = R_IJ.T @ T_IJ / np.linalg.norm(T_IJ)
    # the translation's marginal information, the rotation eliminated: two directions besides e
    C = np.linalg.inv(np.linalg.inv(bare + np.outer(np.r_[np.zeros(3), e], np.r_[np.zeros(3), e]))[3:, 3:]) \
        - np.outer(e, e)
    other = np.sort(np.linalg.eigvalsh(C))[1:]
    added = full - bare
    assert np.allclose(added[:3], 0.0) and np.allclose(added[:, :3], 0.0)
    assert e @ added[3:, 3:] @ e == pytest.approx(other.mean(), rel=1e-6)
    assert np.linalg.matrix_rank(full) == 6


# --------------------------------------------------------------------------------------------
# What a pair cannot tell


def test_a_pair_without_baseline_tells_nothing():
    """Pure rotation: the epipolar constraint is void (no baseline, no parallax) — nothing of the
    translation, and (the pair on its own keeping no map) nothing of the rotation either."""
    X = two_view.landmarks(np.random.default_rng(8))
    assert np.all(camera.pair_information(X, R_IJ, np.zeros(3), SIGMA) == 0.0)
    # ray-cast: a camera turning where it stands in a lot with buildings
    lot = Scene.combine([shapes.ground(-60, -60, 60, 60), shapes.box(15, -20, 30, 20, 10)])
    R_i = LOOK_X
    R_j = so3.exp(np.array([0.0, 0.0, 0.05])) @ LOOK_X
    p = np.array([0.0, 0.0, 1.5])
    pairs = camera.informations(lot, R_i[None], p[None], R_j[None], p[None], DEFAULT_CAMERA)
    assert pairs.features[0] > 100  # it tracks its features …
    assert np.all(pairs.H[0] == 0.0)  # … and learns nothing from them


def test_textureless_surfaces_tell_nothing():
    def scene(f):
        return Scene.combine([shapes.ground(-60, -60, 60, 60, features_per_m2=f),
                              shapes.box(15, -20, 30, 20, 10, features_per_m2=f)])
    R_j = so3.exp(np.array([0.0, 0.0, 0.02])) @ LOOK_X
    args = (LOOK_X[None], np.array([[0.0, 0.0, 1.5]]), R_j[None], np.array([[1.0, 0.1, 1.5]]), DEFAULT_CAMERA)
    bare = camera.informations(scene(0.0), *args)
    assert bare.features[0] == 0.0 and np.all(bare.H == 0.0)
    textured = camera.informations(scene(0.5), *args)
    assert textured.features[0] > 100 and np.linalg.matrix_rank(textured.H[0]) == 6


def _wall_ahead(distance, per_m2=100.0):
    """A wall across the view ``distance`` ahead of a camera at the origin looking along x."""
    return shapes.wall((distance, 80.0), (distance, -80.0), 80.0, features_per_m2=per_m2).transformed(
        np.eye(3), np.array([0.0, 0.0, -40.0]))


def _pair_on(scene):
    R_j = so3.exp(np.array([0.0, 0.0, 0.01])) @ LOOK_X
    return camera.informations(scene, LOOK_X[None], np.zeros((1, 3)), R_j[None], np.array([[1.0, -0.3, 0.1]]),
                               DEFAULT_CAMERA)


def test_a_plane_far_away_leaves_the_translation_weak():
    """Bearings see a translation ρ only as ρ/d: per feature, the translation's information falls
    as 1/d², the rotation's does not; beyond the range, nothing."""
    per_feature = {}
    for d in (10.0, 20.0, 40.0):
        pairs = _pair_on(_wall_ahead(d))
        H = pairs.H[0]
        trans = H[3:, 3:] - H[3:, :3] @ np.linalg.solve(H[:3, :3], H[:3, 3:])  # marginal: rotation eliminated
        per_feature[d] = (np.trace(trans), np.trace(H[:3, :3])) / pairs.features[0]
    for near, far in ((10.0, 20.0), (20.0, 40.0)):
        ratio = per_feature[far][0] / per_feature[near][0]
        assert ratio == pytest.approx((near / far) ** 2, rel=0.15)
        assert 0.7 < per_feature[far][1] / per_feature[near][1] < 1.4
    beyond = _pair_on(_wall_ahead(DEFAULT_CAMERA.max_range_m + 20.0))
    assert beyond.features[0] == 0.0 and np.all(beyond.H == 0.0)


# --------------------------------------------------------------------------------------------
# The quadrature: features counted on the surfaces' footprints, within the detector's budget


def test_a_walls_features_are_its_footprint_times_its_texture_within_the_budget():
    """The camera faces a wall 10 m away square on: its image covers (W/f·d) × (H/f·d) of it."""
    d = 10.0
    footprint = (DEFAULT_CAMERA.width_px / DEFAULT_CAMERA.focal_px * d) * (DEFAULT_CAMERA.height_px / DEFAULT_CAMERA.focal_px * d)
    still = (LOOK_X[None], np.zeros((1, 3)), LOOK_X[None], np.zeros((1, 3)), DEFAULT_CAMERA)
    for per_m2 in (0.5, 2.0):
        expected = min(per_m2 * footprint, DEFAULT_CAMERA.max_features)
        assert camera.informations(_wall_ahead(d, per_m2), *still).features[0] == pytest.approx(expected, rel=1e-6)


def test_the_budget_is_spread_over_the_image_as_evenly_as_the_texture_allows():
    expected = np.array([1.0, 1.0, 10.0, 100.0])
    share = np.full(4, 0.25)
    # 20 features: the two poor cells keep theirs, the rich ones share the other 18
    assert np.allclose(camera.waterfill(expected, share, np.zeros(4, int), 20.0, 1), [1.0, 1.0, 9.0, 9.0])
    assert np.allclose(camera.waterfill(expected, share, np.zeros(4, int), 500.0, 1), expected)
    # a cell of half the image holds twice the level
    out = camera.waterfill(np.array([50.0, 50.0, 50.0]), np.array([0.5, 0.25, 0.25]), np.zeros(3, int), 40.0, 1)
    assert np.allclose(out, [20.0, 10.0, 10.0])


# --------------------------------------------------------------------------------------------
# Monte Carlo: a two-view bundle adjustment of noisy pixels against the predicted covariance


@pytest.mark.montecarlo
@pytest.mark.slow
def test_two_view_bundle_adjustment_meets_the_predicted_covariance():
    """500 pairs of noisy pixels (1 px): four sets of 40 landmarks on a ground and a wall 4–30 m
    away, 125 pairs each, each pair's relative pose estimated by bundle adjustment with the scale
    held (its length is the odometry's, not the bearings'); the error's NEES over the five other
    directions against the covariance the eliminated information predicts for its set. Their mean
    must fall within the 95 % interval of χ²₅'s."""
    nees = []
    for seed in range(4):
        rng = np.random.default_rng(seed)
        X = two_view.landmarks(rng)
        A = camera.eliminated(X, R_IJ, T_IJ, SIGMA).sum(axis=0)
        nees.append(two_view.nees(X, R_IJ, T_IJ, SIGMA, A, 125, rng))
    nees = np.concatenate(nees)
    trials = nees.size
    lo, hi = chi2.ppf([0.025, 0.975], 5 * trials) / trials
    assert lo < nees.mean() < hi, f"mean NEES {nees.mean():.3f} outside [{lo:.3f}, {hi:.3f}]"


# --------------------------------------------------------------------------------------------
# Along a drive, and what it does to the robotaxi's camera

RIG = load_rig("robotaxi")
CAM = next(s for s in RIG.config.sensors if s.kind == "camera")


@pytest.fixture(scope="module")
def slalom_drive():
    return drive(slalom(40.0), RIG.suspension)


def _lot(ground_per_m2, buildings):
    parts = [shapes.ground(-60, -45, 60, 45, features_per_m2=ground_per_m2)]
    if buildings:
        parts += [shapes.box(-40, 30, -10, 45, 12), shapes.box(0, 30, 35, 42, 9), shapes.box(-50, -44, -30, -35, 6)]
    return Scene.combine(parts)


def test_a_keyframe_reads_the_pair_that_ends_at_its_sample(slalom_drive):
    """Stored in world-aligned axes at the sample, turned back by the keyframe's own camera
    orientation: where the keyframe is the sample, it is the pair ray-cast there."""
    scene = _lot(0.05, True)
    traj = along.seen(slalom_drive, RIG, scene)
    nom = Nominal.of(traj, RIG)
    samples = traj.scene.t[CAM.name]
    k = next(k for k in range(5, nom.n_keyframes) if np.min(np.abs(samples - nom.t[k])) < 1e-9)
    R_j = nom.R[k] @ CAM.T_B_S.R
    B = np.kron(np.eye(2), R_j)
    stored = B.T @ nom.scene[CAM.name][k] @ B
    dt = 1.0 / CAM.rate_hz
    R_Si, p_Si = along.sensor_poses(slalom_drive, RIG, CAM, np.array([nom.t[k] - dt]))
    R_Sj, p_Sj = along.sensor_poses(slalom_drive, RIG, CAM, np.array([nom.t[k]]))
    direct = camera.informations(scene, R_Si, p_Si, R_Sj, p_Sj, DEFAULT_CAMERA).H[0]
    assert np.abs(direct).max() > 0
    assert np.allclose(stored, direct, rtol=1e-6, atol=1e-9 * np.abs(direct).max())


def _camera_sigmas(traj):
    return {p.name: p.sigma for p in evaluate(traj, RIG).parameters if p.name.startswith(CAM.name + ".")}


def test_what_the_scene_does_to_the_robotaxis_camera(slalom_drive):
    """A plain asphalt lot (0.01 features/m²: what the camera finds is mostly far down the
    ground, where a cell's footprint is large) leaves the camera weaker than blind; façades (1
    feature/m²) in view help; a richly textured ground approaches the densities (each pair's
    bearings then tell ~1 mm and ~0.005°, the densities 3 cm and 0.1°); a textureless lot leaves
    the camera's extrinsic undetermined. Never better than blind: a scene only limits a pair."""
    blind = _camera_sigmas(slalom_drive)
    open_lot = _camera_sigmas(along.seen(slalom_drive, RIG, _lot(0.01, False)))
    buildings = _camera_sigmas(along.seen(slalom_drive, RIG, _lot(0.01, True)))
    rich = _camera_sigmas(along.seen(slalom_drive, RIG, _lot(2.0, False)))
    bare = _camera_sigmas(along.seen(slalom_drive, RIG, _lot(0.0, False)))
    for n in blind:
        assert blind[n] * (1 - 1e-9) <= buildings[n] < open_lot[n], n
        assert rich[n] == pytest.approx(blind[n], rel=0.03), n
        assert bare[n] is None, n
    assert open_lot[CAM.name + ".trans_x"] > 1.1 * blind[CAM.name + ".trans_x"]


# --------------------------------------------------------------------------------------------
# The rig's optics


def _robotaxi_with(**camera_keys):
    data = RIG.config.model_dump()
    for e in data["sensors"]:
        if e["kind"] == "camera":
            e.update(camera_keys)
    return data


def test_a_cameras_optics_are_read_from_the_rig_and_bad_ones_refused():
    rig = build_rig(_robotaxi_with(optics={"width_px": 1280, "height_px": 720, "focal_px": 800.0}))
    optics = next(s for s in rig.config.sensors if s.kind == "camera").optics
    assert optics == CameraOptics(width_px=1280, height_px=720, focal_px=800.0)
    assert optics.bearing_sigma == pytest.approx(1.0 / 800.0)
    with pytest.raises(RigError, match="max_range_m"):
        build_rig(_robotaxi_with(optics={"min_range_m": 50.0, "max_range_m": 20.0}))
    with pytest.raises(RigError, match="focal_px"):
        build_rig(_robotaxi_with(optics={"focal_px": 1e9}))
    data = RIG.config.model_dump()
    next(e for e in data["sensors"] if e["kind"] == "lidar")["optics"] = {}
    with pytest.raises(RigError, match="optics applies to cameras only"):
        build_rig(data)
