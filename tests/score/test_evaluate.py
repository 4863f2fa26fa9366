"""The evaluator against independent computation: degenerate motions, invariances, the dense
oracle, the Cramér–Rao guarantee, and the JSON/npz exports."""

from __future__ import annotations

import json

import numpy as np
import pytest

from excite.information import dense, elimination, problem
from excite.information.closure import Closure
from excite.core import so3
from excite.information import kernels
from excite.errors import EvaluationError
from excite.score.evaluate import Options, evaluate
from excite.factors.base import FactorBlock, Nominal
from excite.rig.config import build_rig, load_rig
from excite.motion.vehicle import ControlProfile, Suspension, drive

T = 60.0
KNOTS = np.linspace(0.0, T, 61)


@pytest.fixture(scope="module")
def rig():
    return load_rig("robotaxi")


def profile(speed, curvature, **kw) -> ControlProfile:
    return ControlProfile(KNOTS, np.broadcast_to(speed, KNOTS.shape), np.broadcast_to(curvature, KNOTS.shape), **kw)


VARIED_SPEED = 6 + 3 * np.sin(KNOTS / 3)
VARIED_CURV = 0.08 * np.sin(KNOTS / 5)


def null_space(rep):
    return rep.null_space


def null_weight(rep, rig):
    """Per scored coordinate, the squared norm of its unit vector's projection on the null space."""
    N = null_space(rep)
    return {c.name: float((N[i] ** 2).sum()) for i, c in enumerate(rig.scored)}


def span_angle_cos(rep, rig, names):
    """Largest cosine between the null space and the span of the named coordinates (1: they share a direction)."""
    N = null_space(rep)
    if N.shape[1] == 0:
        return 0.0
    idx = [[c.name for c in rig.scored].index(n) for n in names]
    return float(np.linalg.svd(N[idx], compute_uv=False).max())


def assert_null_space_is(rep, rig, expected):
    """The null space is exactly the span of the named coordinate axes."""
    weights = null_weight(rep, rig)
    assert rep.nullity == len(expected), (rep.nullity, {k: round(v, 3) for k, v in weights.items() if v > 1e-6})
    for name, wgt in weights.items():
        if name in expected:
            assert wgt > 1 - 1e-6, f"{name} should be unobservable (null weight {wgt:.3g})"
        else:
            assert wgt < 1e-6, f"{name} should be observable (null weight {wgt:.3g})"


# --- the degenerate motions of DESIGN.md (suspension off) ------------------------------------

def test_straight_line_constant_speed(rig):
    rep = evaluate(drive(profile(10.0, 0.0), Suspension.rigid()), rig)
    # travel direction: lidar x (mounted like the body), camera z (optical axis forward)
    assert_null_space_is(rep, rig, {
        "lidar.trans_x", "lidar.trans_y", "lidar.trans_z", "lidar.rot_x", "lidar.time_offset",
        "cam_front.trans_x", "cam_front.trans_y", "cam_front.trans_z", "cam_front.rot_z",
        "cam_front.time_offset", "wheel.track", "imu.accel_bias_x", "imu.accel_bias_y"})
    assert rep.score == 0.0 and not rep.passed
    unobs = {p.name for p in rep.parameters if p.sigma is None}
    assert "wheel.track" in unobs and "wheel.radius_left" not in unobs


def test_planar_driving_leaves_only_vertical_lever_arms(rig):
    rep = evaluate(drive(profile(VARIED_SPEED, VARIED_CURV), Suspension.rigid()), rig)
    assert_null_space_is(rep, rig, {"lidar.trans_z", "cam_front.trans_z"})
    assert {m.coordinates[0][0] for m in rep.weak_modes if m.status == "unobservable"} == {
        "lidar.trans_z", "cam_front.trans_z"}
    assert all("vertical lever arm" in m.advice.lower() for m in rep.weak_modes if m.status == "unobservable")


def test_straight_driving_only_leaves_track(rig):
    rep = evaluate(drive(profile(VARIED_SPEED, 0.0), Suspension.rigid()), rig)
    # no rotation at all: lever arms and the roll about the travel direction go too; time offsets
    # come back with the speed changes
    assert_null_space_is(rep, rig, {
        "lidar.trans_x", "lidar.trans_y", "lidar.trans_z", "lidar.rot_x",
        "cam_front.trans_x", "cam_front.trans_y", "cam_front.trans_z", "cam_front.rot_z",
        "wheel.track", "imu.accel_bias_x", "imu.accel_bias_y"})


def test_circle_at_constant_speed(rig):
    rep = evaluate(drive(profile(6.0, 0.08), Suspension.rigid()), rig)
    w = null_weight(rep, rig)
    for name in ("lidar.time_offset", "cam_front.time_offset", "lidar.trans_z", "cam_front.trans_z"):
        assert w[name] > 1 - 1e-6, name
    # one combination of wheel radii and track
    assert span_angle_cos(rep, rig, ["wheel.radius_left", "wheel.radius_right", "wheel.track"]) > 1 - 1e-6
    assert w["imu.gyro_bias_z"] < 1e-6
    assert rep.nullity >= 6  # several coupled directions, as DESIGN.md warns


def test_one_constant_curvature_leaves_a_wheel_combination(rig):
    rep = evaluate(drive(profile(VARIED_SPEED, 0.08), Suspension.rigid()), rig)
    w = null_weight(rep, rig)
    assert span_angle_cos(rep, rig, ["wheel.radius_left", "wheel.radius_right", "wheel.track"]) > 1 - 1e-6
    assert span_angle_cos(rep, rig, ["wheel.radius_left", "wheel.radius_right"]) < 0.5  # not the radii alone
    assert w["lidar.time_offset"] < 1e-6 and w["cam_front.time_offset"] < 1e-6  # speed varies


def test_suspension_makes_vertical_lever_arm_weak_but_finite(rig):
    rep = evaluate(drive(profile(VARIED_SPEED, VARIED_CURV), rig.suspension), rig)
    assert rep.nullity == 0
    lidar_z = next(p for p in rep.parameters if p.name == "lidar.trans_z")
    assert lidar_z.sigma is not None and lidar_z.sigma > 10 * lidar_z.target
    weak = rep.weak_modes[:2]
    assert {m.coordinates[0][0] for m in weak} == {"lidar.trans_z", "cam_front.trans_z"}
    # orders of magnitude below the rest, and far above the numerical zero
    assert rep.spectrum_scaled[1] < 1e-2 * np.median(rep.spectrum_scaled)
    assert min(rep.spectrum_normalised) > 100 * rep.rank_threshold


# --- invariances ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def general_drive(rig):
    return drive(profile(VARIED_SPEED, VARIED_CURV, grade_rad=0.03 * np.sin(KNOTS / 7)), rig.suspension)


def test_global_rotation_and_translation_leave_score_unchanged(rig, general_drive):
    a = evaluate(general_drive, rig)
    b = evaluate(general_drive.transformed(so3.rot_z(1.234), np.array([4.6e5, 5.4e6, 120.0])), rig)
    assert b.score == pytest.approx(a.score, rel=1e-6)
    np.testing.assert_allclose(b.spectrum_scaled, a.spectrum_scaled, rtol=1e-6)


def _scaled_noise(rig, factor):
    data = rig.config.model_dump()
    imu = data["imu"]
    for k in ("accelerometer_noise_density", "gyroscope_noise_density", "accelerometer_random_walk",
              "gyroscope_random_walk"):
        imu[k] *= factor
    for s in data["sensors"]:
        s["noise"]["rotation_density_deg_per_sqrt_s"] *= factor
        s["noise"]["translation_density_m_per_sqrt_s"] *= factor
    data["wheels"]["noise_density"] *= factor
    nh = data["vehicle"]["nonholonomic"]
    nh["lateral_noise_density"] *= factor
    nh["vertical_noise_density"] *= factor
    return build_rig(data)


def test_halving_every_sigma_quadruples_information(rig, general_drive):
    a = evaluate(general_drive, rig)
    b = evaluate(general_drive, _scaled_noise(rig, 0.5))
    np.testing.assert_allclose(b.information_scaled, 4 * a.information_scaled,
                               atol=1e-9 * np.abs(a.information_scaled).max())
    assert b.score == pytest.approx(4 * a.score, rel=1e-6)


def test_driving_a_route_twice_doubles_information(rig, general_drive):
    """Two recordings of the same route, calibrated together, carry exactly twice the information:
    they share the calibration and nothing else (no leak between the trajectories, one gauge each).
    With constant biases (shared, like the extrinsics); drifting biases are each drive's own."""
    rig = rig.with_constant_biases()
    one = evaluate(general_drive, rig)
    two = evaluate([general_drive, general_drive.transformed(so3.rot_z(0.3), np.array([50.0, 0, 0]))], rig)
    np.testing.assert_allclose(two.information_scaled, 2 * one.information_scaled,
                               atol=1e-9 * np.abs(one.information_scaled).max())
    assert two.score == pytest.approx(2 * one.score, rel=1e-6)
    assert two.duration_s == pytest.approx(2 * one.duration_s)


def test_segments_of_several_drives_each_get_a_gauge(rig, general_drive):
    rep = evaluate([general_drive, general_drive], rig, Options(segments=3))
    assert len(rep.segments) == 3  # the middle segment spans both drives and still evaluates
    assert all(np.isfinite(s.weakest_mode_information) for s in rep.segments)


@pytest.mark.parametrize("segments", [2, 4, 6, 40, 60])
def test_segment_edges_next_to_a_drive_boundary(rig, segments):
    """Segment edges that cut 1–2 keyframes off a drive (two drives of 61 keyframes: edges at 60
    or 62) drop the fragment instead of failing the whole evaluation as undetermined."""
    t = np.linspace(0, 6, 7)
    a, b = (drive(ControlProfile(t, 5 + 2 * np.sin(t + s), 0.1 * np.sin(t / 2 + s)), rig.suspension) for s in (0, 1))
    rep = evaluate([a, b], rig, Options(segments=segments))
    assert len(rep.segments) >= segments - 2
    assert all(s.t_end_s > s.t_start_s and np.isfinite(s.weakest_mode_information) for s in rep.segments)


def test_window_trims_drive_fragments():
    prob = problem.Problem(10, 1, (), np.broadcast_to(np.eye(3), (10, 3, 3)), Closure(True, ("yaw",), 9, np.zeros(0), np.zeros(0, dtype=int)), (0, 5))
    assert problem.trimmed(prob.chain_starts, 0, 9) == (0, 9)
    assert problem.trimmed(prob.chain_starts, 3, 9) == (5, 9)  # keyframes 3, 4: the last two of the first drive
    assert problem.trimmed(prob.chain_starts, 0, 6) == (0, 4)  # keyframes 5, 6: the first two of the second drive
    assert problem.trimmed(prob.chain_starts, 3, 6) is None
    with pytest.raises(EvaluationError, match="fewer than 3 keyframes"):
        prob.window(4, 9)


def test_marginal_does_not_depend_on_the_gauge_fix(rig, general_drive):
    nom = Nominal.of(general_drive, rig)
    K = nom.n_keyframes
    ref = _scaled(elimination.marginal(problem.build(nom, rig, gauge_keyframe=0)), rig)
    scale = np.abs(ref).max()
    for g in (K // 2, K - 1):
        other = _scaled(elimination.marginal(problem.build(nom, rig, gauge_keyframe=g)), rig)
        assert np.abs(other - ref).max() < 1e-9 * scale


def _scaled(L, rig):
    """Λ in units of the targets (entries commensurate; nuisances in units of 0.01, the size of a
    scale error or a tyre's slip ratio or slip angle at 1 g)."""
    S = np.array([0.01 if c.nuisance else c.target for c in rig.coordinates])
    S = np.concatenate([S, np.ones(L.shape[0] - S.size)])  # further drives' nuisances
    return L * np.outer(S, S)


def _small_drive(rig):
    t = np.linspace(0, 12, 13)
    return Nominal.of(drive(ControlProfile(t, 5 + 2 * np.sin(t), 0.1 * np.sin(t / 2), grade_rad=0.02 * np.cos(t)),
                            rig.suspension), rig)


@pytest.fixture(scope="module")
def dense_references(rig):
    """The small drive's marginal by dense numpy, with the gauge prior or with the gauge removed
    altogether (pseudo-inverse), in local and in world-frame states, each with the tolerance the
    fast path must meet against it. Built with the default chunking: the dense marginal does not
    depend on it, so each chunking of the fast path is held to the same four matrices."""
    nom = _small_drive(rig)
    # Round-off differs between the parametrisations: in local states with the gauge prior the
    # dense reference agrees to ~1e-11; world-frame states (the fast path's or the dense one's)
    # and the pseudo-inverse without a gauge lose digits (measured 2e-7 … 2.4e-6 on this drive;
    # since the wheels' scrub nuisance, nearly collinear with the radii on this drive, the
    # eigenvalues of world states without a gauge agree to 5e-6 … 1.1e-5, the rest unchanged).
    return [
        (_scaled(dense.marginal_dense(problem.build(nom, rig)), rig), 1e-9),
        (_scaled(dense.marginal_dense(problem.build(nom, rig), gauge=False), rig), 1e-5),
        (_scaled(dense.marginal_dense(problem.build(nom, rig, local=False)), rig), 1e-5),
        (_scaled(dense.marginal_dense(problem.build(nom, rig, local=False), gauge=False), rig), 3e-5),
    ]


@pytest.mark.slow
@pytest.mark.parametrize("chunk", [500, 7])
def test_fast_path_equals_dense_reference(rig, monkeypatch, chunk, dense_references):
    """Small drive: the chunked elimination (one chunk, or chunks of 7 keyframes) in both
    parametrisations vs dense numpy, with the gauge prior or with the gauge removed altogether
    (pseudo-inverse)."""
    monkeypatch.setattr(problem, "CHUNK_KEYFRAMES", chunk)
    monkeypatch.setattr(elimination, "CHUNK_KEYFRAMES", chunk)
    nom = _small_drive(rig)
    fast = _scaled(elimination.marginal(problem.build(nom, rig)), rig)
    fast_world = _scaled(elimination.marginal(problem.build(nom, rig, local=False)), rig)
    d = np.sqrt(np.diag(fast))

    def err(ref):  # correlation-normalised: independent of units and targets
        return (np.abs(fast - ref) / np.outer(d, d)).max()

    assert err(fast_world) < 1e-5
    for ref, tol in dense_references:
        assert err(ref) < tol
        np.testing.assert_allclose(np.linalg.eigvalsh(fast), np.linalg.eigvalsh(ref), rtol=tol, atol=0)


def _five_hz_lidar(rig):
    data = rig.config.model_dump()
    data["sensors"][0]["rate_hz"] = 5.0  # frames every second keyframe: a wider band
    return build_rig(data)


def test_sensor_slower_than_keyframes(rig):
    """A 5 Hz lidar spans two keyframes per measurement (wider band): fast path still equals dense."""
    slow = _five_hz_lidar(rig)
    t = np.linspace(0, 10, 11)
    nom = Nominal.of(drive(ControlProfile(t, 5 + 2 * np.sin(t), 0.1 * np.sin(t / 2)), slow.suspension), slow)
    prob = problem.build(nom, slow)
    assert prob.bandwidth_blocks == 2
    fast = _scaled(elimination.marginal(prob), slow)
    ref = _scaled(dense.marginal_dense(problem.build(nom, slow, local=False)), slow)
    assert np.abs(fast - ref).max() < 1e-8 * np.abs(fast).max()


def test_streamed_drives_equal_the_dense_reference(rig, monkeypatch):
    """The evaluator's streamed path (each chunk sampled, linearised and eliminated on its own)
    on two drives of different lengths with a 5 Hz lidar and chunks of 6 keyframes, against the
    dense reference of the whole problem."""
    slow = _five_hz_lidar(rig)
    drives = []
    for T_s in (10.0, 7.3):
        t = np.linspace(0, T_s, 12)
        drives.append(drive(ControlProfile(t, 5 + 2 * np.sin(t), 0.1 * np.sin(t / 2), grade_rad=0.02 * np.cos(t)),
                            slow.suspension))
    noms = [Nominal.of(d, slow) for d in drives]
    # dense in local states: with random-walk biases (information 1/(σ_rw²ΔT) ~ 1e12 per step) the
    # world-state dense solve is only good to ~1e-8 (test_fast_path_equals_dense_reference)
    ref = _scaled(dense.marginal_dense(problem.build(noms, slow, local=True)), slow)
    monkeypatch.setattr(problem, "CHUNK_KEYFRAMES", 7)
    monkeypatch.setattr(elimination, "CHUNK_KEYFRAMES", 7)
    got = elimination.drive_information(drives, slow)
    assert got.n_keyframes == sum(n.n_keyframes for n in noms)
    assert got.length_m == pytest.approx(sum(n.length_m for n in noms), rel=1e-12)
    assert got.duration_s == pytest.approx(sum(n.t[-1] - n.t[0] for n in noms), rel=1e-12)
    assert np.abs(_scaled(got.information, slow) - ref).max() < 1e-8 * np.abs(ref).max()


@pytest.mark.parametrize("slab", [3, 64])
def test_sweeps_equal_the_dense_reference(rig, monkeypatch, slab):
    """The evaluator's sweeps from both ends of a drive (5 Hz lidar: factors over two keyframes),
    with chunks of 18 keyframes eliminated slab by slab (3 keyframes: the ring buffer moves on many
    times per chunk, in both directions; 64: once), one and four chunks per half, random-walk and
    constant biases: Λ_θ equals the dense reference."""
    slow = _five_hz_lidar(rig)
    t = np.linspace(0, 14, 15)
    traj = drive(ControlProfile(t, 5 + 2 * np.sin(t), 0.1 * np.sin(t / 2), grade_rad=0.02 * np.cos(t)),
                 slow.suspension)
    monkeypatch.setattr(elimination, "SLAB", slab)
    for r in (slow, slow.with_constant_biases()):
        ref = _scaled(dense.marginal_dense(problem.build(Nominal.of(traj, r), r)), r)
        for chunk in (500, 20):
            monkeypatch.setattr(problem, "CHUNK_KEYFRAMES", chunk)
            monkeypatch.setattr(elimination, "CHUNK_KEYFRAMES", chunk)
            got = _scaled(elimination.drive_information([traj], r).information, r)
            assert np.abs(got - ref).max() < 1e-8 * np.abs(ref).max()


@pytest.mark.parametrize("forward", [True, False])
def test_singular_keyframe_is_named_by_either_sweep(monkeypatch, forward):
    """Unit priors on every state of keyframes 100..106 but 103, in one chunk eliminated slab by
    slab of 2 keyframes from either end: the error names keyframe 103."""
    first = np.array([0, 1, 2, 4, 5, 6])
    Jx = np.broadcast_to(np.eye(9), (first.size, 9, 9)).copy()
    Jt = np.zeros((first.size, 9, 1))
    Jt[:, 0, 0] = 1.0
    prior = FactorBlock("prior", first, 1, 1, Jx, Jt, np.array([0]))
    monkeypatch.setattr(elimination, "SLAB", 2)
    carry = (np.zeros((9, 9)), np.zeros((9, 1)), np.zeros((1, 1)))
    with pytest.raises(EvaluationError, match="keyframe 103 is singular"):
        elimination.eliminated([prior], 6, carry, forward, 100)


def test_undetermined_trajectory_is_a_clear_error(rig, monkeypatch):
    """A rig whose sensors leave a keyframe's own state free (no IMU information) is refused by
    name, not answered with a meaningless Λ."""
    t = np.linspace(0, 10, 11)
    nom = Nominal.of(drive(ControlProfile(t, 5 + 2 * np.sin(t), 0.1 * np.sin(t / 2)), rig.suspension), rig)
    prob = problem.build(nom, rig)
    no_imu = problem.Problem(prob.n_keyframes, prob.n_params, tuple(b for b in prob.blocks if b.name != "imu"),
                                 prob.R_W_B, prob.closure, prob.chain_starts)
    with pytest.raises(EvaluationError, match="trajectory itself is undetermined"):
        elimination.marginal(no_imu)


def test_singular_keyframe_is_named():
    """Unit priors on every state of keyframes 100..106 but 103, inside one chunk: the error
    names keyframe 103."""
    first = np.array([0, 1, 2, 4, 5, 6])
    Jx = np.broadcast_to(np.eye(9), (first.size, 9, 9)).copy()
    Jt = np.zeros((first.size, 9, 1))
    Jt[:, 0, 0] = 1.0
    prior = FactorBlock("prior", first, 1, 1, Jx, Jt, np.array([0]))
    with pytest.raises(EvaluationError, match="keyframe 103 is singular"):
        elimination.piece([prior], 100, 106, 1, 9)


# --- the report -------------------------------------------------------------------------------

def test_cramer_rao_sigma_and_the_score_guarantee(rig, general_drive):
    rep = evaluate(general_drive, rig)
    assert rep.nullity == 0
    cov = np.linalg.inv(rep.information)
    for i, p in enumerate(rep.parameters):
        assert p.sigma == pytest.approx(np.sqrt(cov[i, i]), rel=1e-6)
        assert p.ok == (p.sigma <= p.target)
        # DESIGN.md: σ_i ≤ target_i / √score
        assert p.sigma <= p.target / np.sqrt(rep.score) * (1 + 1e-9)
    assert rep.score == pytest.approx(rep.spectrum_scaled[0])
    assert rep.condition_number == pytest.approx(rep.spectrum_scaled[-1] / rep.spectrum_scaled[0])
    assert rep.passed == all(p.ok for p in rep.parameters)


def test_priors_are_reported_separately(rig, general_drive):
    data = rig.config.model_dump()
    data["priors"] = {"*.trans_z": "2 cm"}
    with_prior = build_rig(data)
    a = evaluate(general_drive, rig)
    b = evaluate(general_drive, with_prior)
    assert b.score == pytest.approx(a.score, rel=1e-12)  # the score is the drive's alone
    z = next(p for p in b.parameters if p.name == "lidar.trans_z")
    assert z.sigma_with_prior < 0.02 < z.sigma
    assert b.score_with_priors > b.score and a.score_with_priors is None


def test_json_report_contract(rig, general_drive):
    rep = evaluate(general_drive, rig, Options(segments=4))
    d = json.loads(json.dumps(rep.to_dict(), allow_nan=False))
    for key in ("score", "passed", "duration_s", "rank", "nullity", "condition_number", "spectrum_scaled",
                "column_map", "parameters", "weak_modes", "timings_ms", "warnings"):
        assert key in d
    assert d["warnings"] == []  # a car's drive
    assert d["spectrum_scaled"] == sorted(d["spectrum_scaled"])
    assert [c["name"] for c in d["column_map"]] == [p["name"] for p in d["parameters"]]
    assert set(d["parameters"][0]) >= {"name", "unit", "sigma", "target", "ok"}
    mode = d["weak_modes"][0]
    weights = [abs(w) for _, w in mode["coordinates"]]
    assert weights == sorted(weights, reverse=True) and mode["advice"]
    assert len(d["segments"]) == 4
    # a segment alone knows less than the whole drive along the weakest direction
    assert all(s["weakest_mode_information"] < rep.spectrum_scaled[0] for s in d["segments"])


def test_unobservable_parameters_have_null_sigma_in_json(rig):
    rep = evaluate(drive(profile(10.0, 0.0), Suspension.rigid()), rig)
    d = json.loads(json.dumps(rep.to_dict(), allow_nan=False))
    track = next(p for p in d["parameters"] if p["name"] == "wheel.track")
    assert track["sigma"] is None and track["ok"] is False
    assert d["condition_number"] is None and d["nullity"] == 13


def test_export_npz_round_trip(rig, tmp_path):
    import scipy.sparse as sp

    t = np.linspace(0, 8, 9)
    rep = evaluate(drive(ControlProfile(t, 5 + np.sin(t), 0.05 * np.sin(t)), rig.suspension), rig)
    path = tmp_path / "dbg.npz"
    rep.export_npz(path)
    z = np.load(path)
    J = sp.coo_matrix((z["J_data"], (z["J_row"], z["J_col"])), shape=tuple(z["J_shape"])).toarray()
    H = sp.coo_matrix((z["H_data"], (z["H_row"], z["H_col"])), shape=tuple(z["H_shape"])).toarray()
    np.testing.assert_allclose(J.T @ J, H, atol=1e-9 * np.abs(H).max())
    order = list(z["variable_order"])
    assert len(order) == J.shape[1] and order[-1] == "vehicle.slip_angle" and order[0] == "x0.rot_x"
    # the exported H reproduces the exported marginal
    p = len(rig.coordinates)
    Hxx, Hxt, Htt = H[:-p, :-p], H[:-p, -p:], H[-p:, -p:]
    Lam = Htt - Hxt.T @ np.linalg.solve(Hxx, Hxt)
    np.testing.assert_allclose(Lam, z["information_all"], atol=1e-8 * np.abs(Lam).max())
    assert list(z["column_names"]) == [c.name for c in rig.scored]


def test_too_short_drive_is_a_clear_error(rig):
    t = np.linspace(0, 0.15, 4)
    with pytest.raises(EvaluationError, match="too short"):
        evaluate(drive(ControlProfile(t, np.ones(4), np.zeros(4))), rig)


def test_kitti_00_report_makes_physical_sense(rig, data_dir):
    """KITTI 00 is 470 s of urban driving: many turns and stops, nearly planar. Turns determine the
    wheel track and the time offsets; the vertical lever arms are the weakest directions."""
    from excite.io.routes import read_kitti

    traj = read_kitti(data_dir / "kitti_00_poses.txt", data_dir / "kitti_00_times.txt")
    rep = evaluate(traj, rig)
    assert rep.nullity == 0 and 0 < rep.score < 1
    assert {rep.weak_modes[0].coordinates[0][0], rep.weak_modes[1].coordinates[0][0]} == {
        "lidar.trans_z", "cam_front.trans_z"}
    sig = {p.name: p for p in rep.parameters}
    assert sig["wheel.track"].ok and sig["wheel.radius_left"].ok and sig["imu.gyro_bias_z"].ok
    assert sig["lidar.time_offset"].sigma < 2e-3
    assert sig["lidar.trans_z"].sigma > 5 * sig["lidar.trans_x"].sigma
    assert 3500 < rep.length_m < 3900 and 460 < rep.duration_s < 475


def _kinds(prob):
    """The factor kinds of a problem's blocks in order, repeats collapsed."""
    names = [b.name for b in prob.blocks]
    return [n for i, n in enumerate(names) if i == 0 or names[i - 1] != n]


def test_linearising_in_chunks_changes_nothing(rig, monkeypatch):
    """Every factor lands in exactly one chunk (sensor frames spanning two keyframes included):
    tiny chunks give the same J rows, kind by kind, and the same marginal as big chunks."""
    slow = _five_hz_lidar(rig)
    t = np.linspace(0, 10, 11)
    nom = Nominal.of(drive(ControlProfile(t, 5 + 2 * np.sin(t), 0.1 * np.sin(t / 2)), slow.suspension), slow)
    whole = problem.build(nom, slow)
    monkeypatch.setattr(problem, "CHUNK_KEYFRAMES", 7)  # → chunks of 6 keyframes (stride 2)
    monkeypatch.setattr(elimination, "CHUNK_KEYFRAMES", 7)
    chunked = problem.build(nom, slow)
    assert len(chunked.blocks) > len(whole.blocks)
    assert _kinds(chunked) == _kinds(whole)
    Jw, Jc = dense.jacobian(whole)[0].toarray(), dense.jacobian(chunked)[0].toarray()
    np.testing.assert_allclose(Jc, Jw, atol=1e-12 * np.abs(Jw).max())
    Lw, Lc = _scaled(elimination.marginal(whole), slow), _scaled(elimination.marginal(chunked), slow)
    assert np.abs(Lc - Lw).max() < 1e-10 * np.abs(Lw).max()


def test_nearly_singular_keyframe_is_named():
    """A keyframe whose state is determined only to rounding (two components seen almost only
    together: their information matrix singular to 1e-18) is refused by name, not eliminated into
    garbage."""
    first = np.arange(0, 7)
    Jx = np.broadcast_to(np.eye(9), (first.size, 9, 9)).copy()
    Jx[3, 4, 5], Jx[3, 5, 5] = 1.0, 1e-9  # column 5 = column 4 + 1e-9 e_5
    Jt = np.zeros((first.size, 9, 1))
    Jt[:, 0, 0] = 1.0
    prior = FactorBlock("prior", first, 1, 1, Jx, Jt, np.array([0]))
    with pytest.raises(EvaluationError, match="keyframe 103 is singular"):
        elimination.piece([prior], 100, 106, 1, 9)


@pytest.mark.parametrize("variant", ["random walk", "constant biases", "5 Hz lidar"])
def test_accumulate_skips_only_zero_columns(rig, variant):
    """Each linearised block names the columns of its Jacobian that can be non-zero (``xcols``,
    reported by the local-state map as it writes them); every other column is zero for every
    factor, and accumulating over ``xcols`` only gives the band, H_xθ and H_θθ of accumulating
    over every column, bit for bit, in either storage order. The backward sweep's order of a
    state's components (bias deviations first, :func:`elimination.ring_order`) stores the same
    numbers, permuted."""
    r = {"random walk": rig, "constant biases": rig.with_constant_biases(), "5 Hz lidar": _five_hz_lidar(rig)}[variant]
    t = np.linspace(0, 8, 9)
    nom = Nominal.of(drive(ControlProfile(t, 5 + 2 * np.sin(t), 0.1 * np.sin(t / 2), grade_rad=0.02 * np.cos(t)),
                           r.suspension), r)
    prob = problem.build(nom, r)
    sd, p, K = prob.state_dim, prob.n_params, prob.n_keyframes
    skipped = 0
    for blk in prob.blocks:
        if blk.xcols is None:  # gauge and placeholder rows: every column is read
            continue
        zero = np.setdiff1d(np.arange(blk.Jx.shape[2]), blk.xcols)
        assert not blk.Jx[:, :, zero].any(), blk.name
        skipped += zero.size
        D = blk.stride * (blk.n_states - 1)
        for sign, origin in ((1, 0), (-1, K - 1)):
            out = []
            for xc, comp in ((blk.xcols, np.arange(sd)), (np.arange(blk.Jx.shape[2]), np.arange(sd)),
                             (blk.xcols, elimination.ring_order(sd, sign > 0))):
                band, Hxt, Htt = np.zeros((D + 1, K, sd, sd)), np.zeros((K, sd, p)), np.zeros((p, p))
                kernels.accumulate(blk.Jx, blk.Jt, blk.cols, blk.first, blk.stride, blk.n_states,
                                   band, Hxt, Htt, 0, blk.n_factors, origin, sign, xc, comp)
                diag = np.tril(band[0]) + np.swapaxes(np.tril(band[0], -1), -1, -2)  # stored: the lower triangle
                out.append((np.concatenate([diag[None], band[1:]])[:, :, comp][:, :, :, comp], Hxt[:, comp], Htt))
            for a, b in zip(out[0], out[1]):
                assert np.array_equal(a, b), (blk.name, sign)
            for a, b in zip(out[0], out[2]):
                assert np.array_equal(a, b), (blk.name, sign, "ring order")
    assert skipped > 0  # the lidar, camera and wheels see no velocity
    assert not np.array_equal(elimination.ring_order(sd, False), np.arange(sd)) or sd == 9


@pytest.mark.parametrize("chunk", [7, 500])
@pytest.mark.parametrize("case", ["random walk", "constant biases", "5 Hz lidar", "two drives"])
def test_streamed_windows_equal_the_windows_of_the_whole_problem(rig, monkeypatch, case, chunk):
    """The segments' information equals the marginal and diag H_θθ of the same window cut out of
    the whole linearised problem (:meth:`Problem.window`): windows inside a drive, at its ends,
    overlapping, and across the boundary of two drives (each with its own monocular scale and
    biases); with a 5 Hz lidar at even keyframes. Chunks of 7 keyframes: every window is longer
    and swept from both ends, chunk by chunk; of 500: the windows are linearised together and
    each eliminated on its own."""
    r = {"constant biases": rig.with_constant_biases(), "5 Hz lidar": _five_hz_lidar(rig)}.get(case, rig)
    t = np.linspace(0, 8, 9)
    drives = [drive(ControlProfile(t, 5 + 2 * np.sin(t + s), 0.1 * np.sin(t / 2 + s), grade_rad=0.02 * np.cos(t)),
                    r.suspension) for s in ((0, 1) if case == "two drives" else (0,))]
    prob = problem.build([Nominal.of(d, r) for d in drives], r)
    K = prob.n_keyframes
    across = (60, 100) if case == "two drives" else (20, 62)  # two drives of 81 keyframes: 81 starts the second
    wins = [(0, 40), (40, K - 1), across, (0, K - 1)]
    monkeypatch.setattr(problem, "CHUNK_KEYFRAMES", chunk)
    monkeypatch.setattr(elimination, "CHUNK_KEYFRAMES", chunk)
    got = elimination.window_information(drives, r, wins)
    for (k0, k1), (Lam, diag) in zip(wins, got):
        win = prob.window(k0, k1)
        ref = elimination.marginal(win)
        assert np.abs(Lam - ref).max() < 1e-9 * np.abs(ref).max(), (k0, k1)
        np.testing.assert_allclose(diag, elimination.theta_diagonal(win), rtol=1e-12)
    if case == "two drives":  # a window across the boundary: each piece closed as a drive of its own
        assert prob.chain_starts[1] in range(63, 99)
    if case == "5 Hz lidar":
        with pytest.raises(EvaluationError, match="multiples of 2 keyframes"):
            elimination.window_information(drives, r, [(3, 40)])


def test_segment_windows_fall_on_frame_pairs_and_skip_drive_fragments(rig):
    slow = _five_hz_lidar(rig)  # frames every second keyframe
    assert elimination.windows([81], slow, 4) == [(0, 20), (20, 40), (40, 60), (60, 80)]
    assert elimination.windows([81], slow, 3) == [(0, 26), (26, 54), (54, 80)]  # 26.7, 53.3 to even keyframes
    assert elimination.windows([80], slow, 2) == [(0, 40), (40, 79)]  # a drive's end stays an edge
    assert elimination.windows([82], slow, 2) == [(0, 40), (40, 81)]  # 81 rounds to 80: the end all the same
    assert elimination.windows([82, 40], slow, 3) == [(0, 40), (40, 81), (82, 121)]
    # two drives of 61 keyframes: an edge at keyframe 60 (the first drive's end) or 62 (the
    # second's 2nd keyframe) cuts a fragment off a drive, which is left out
    assert elimination.windows([61, 61], rig, 2) == [(0, 60), (61, 121)]
    assert elimination.windows([61, 61], rig, 3) == [(0, 40), (40, 81), (81, 121)]  # one across the boundary
    # 41 windows: edges at 59 and 62 leave 2 + 2 keyframes either side of the boundary: none
    wins = elimination.windows([61, 61], rig, 41)
    assert len(wins) == 40 and all(b - a >= 2 for a, b in wins) and (59, 62) not in wins


def test_more_segments_than_the_drive_holds_are_capped_with_a_warning(rig, general_drive):
    """Never silently fewer: asked for more segments than the drive holds, the report has the
    most it holds and says so; so does a drive boundary that leaves a fragment out."""
    K = Nominal.grid(general_drive, rig)[1]
    most = (K - 1) // 2
    rep = evaluate(general_drive, rig, Options(segments=most))
    assert len(rep.segments) == most and not any(w.startswith("segments") for w in rep.warnings)
    rep = evaluate(general_drive, rig, Options(segments=most + 1))
    assert len(rep.segments) == most
    assert [w for w in rep.warnings if w.startswith("segments")] == [
        f"segments: {most + 1} asked, {most} reported: the drive holds at most {most} of 3 keyframes or more "
        f"and a whole number of every sensor's frames ({K} keyframes at 10 Hz)"]
    slow = _five_hz_lidar(rig)  # a frame every second keyframe: still 2 keyframe intervals a segment
    assert len(evaluate(general_drive, slow, Options(segments=most)).segments) == most
    t = np.linspace(0, 6, 7)  # two drives of 61 keyframes: the edge at 60.5 leaves the 2nd drive's first 2 out
    a, b = (drive(ControlProfile(t, 5 + 2 * np.sin(t + s), 0.1 * np.sin(t / 2 + s)), rig.suspension) for s in (0, 1))
    rep = evaluate([a, b], rig, Options(segments=59))
    assert len(rep.segments) == 58 and rep.warnings[-1] == (
        "segments: 59 asked, 58 reported: pieces of fewer than 3 keyframes at a boundary between drives are left out")
