"""Adding a measurement kind is additive: a speedometer, declared in this file alone.

A speedometer reports the rear axle's forward speed times an unknown scale factor
(``speedo.scale_factor``, nominal 1), with white noise of a density. The kind below is its whole
statement: its rig entry, its one quantity, its residual in CasADi, its noise and its simulated
measurement; it has no compiled kernel, so the evaluator differentiates the residual. Registered
from here, it goes through ``score``, live guidance, mining, the optimizer's CasADi model and the
validator's simulator and calibrator with no other module changed, and its σ matches the dense
reference.
"""

from __future__ import annotations

import math
from typing import Literal

import casadi as ca
import numpy as np
import pytest

from excite.core.schema import Model, PositiveFloat, SensorEntry
from excite.factors import base as registry
from excite.factors import kernels
from excite.factors.base import Kind, Quantity
from excite.motion.vehicle import ControlProfile, drive
from excite.rig.config import load_rig
from helpers import model_samples


class SpeedNoise(Model):
    speed_noise_density: PositiveFloat  # m/s/√Hz


class SpeedometerEntry(SensorEntry):
    kind: Literal["speedometer"]
    noise: SpeedNoise


class Speedometer(Kind):
    name = "speedometer"
    arity = 1
    rows = 1
    sensor_kinds = ("speedometer",)
    config = SpeedometerEntry
    advice = {("scale_factor", None): ("speedometer scale: vary the speed", "needs speed changes")}

    def quantities(self, cfg, s):
        return [Quantity(s.name, "scale_factor", 1, "1", 1.0)]

    def _speed(self, f):
        """Forward speed of the rear axle (origin of V) in the road-aligned axle frame."""
        R_BV = ca.DM(f.R_V_B.T)
        p_BV = ca.DM(-f.R_V_B.T @ f.p_V_B)
        R_W_A = ca.mtimes(f.R[0], ca.mtimes(R_BV, f.R_V_A[0]))
        return ca.dot(R_W_A[:, 0], f.v[0] + ca.mtimes(f.R[0], ca.cross(f.omega[0], p_BV)))

    def measurement(self, f):
        return f.q["scale_factor"] * self._speed(f)

    def residual(self, f, meas):
        return self.measurement(f) - meas

    def sqrt_information(self, f):
        return ca.DM([1.0 / (f.entry.noise.speed_noise_density * math.sqrt(f.entry.rate_hz))])

    def simulate(self, sim, s):
        m = sim.measured(self, s)
        if sim.noisy:
            m = m + sim.rng.normal(0.0, s.noise.speed_noise_density * math.sqrt(s.rate_hz), m.shape)
        return m


@pytest.fixture(scope="module")
def rig():
    registry.register(Speedometer())
    base = load_rig("robotaxi")
    data = base.config.model_dump()
    data["sensors"].append({"name": "speedo", "kind": "speedometer", "rate_hz": 10.0,
                            "noise": {"speed_noise_density": 0.02}})
    data["targets"]["speedo.scale_factor"] = 0.001
    yield base.with_config(**data)
    registry.unregister("speedometer")


@pytest.fixture(scope="module")
def traj(rig):
    t = np.linspace(0.0, 40.0, 81)
    prof = ControlProfile(t, 6 + 3 * np.sin(t / 4), 0.08 * np.sin(t / 3), grade_rad=0.03 * np.sin(t / 5))
    return drive(prof, rig.suspension)


def _sigma(Lam, rig, name):
    from excite.information.closure import marginalise_nuisance

    scored = np.array([not c.nuisance for c in rig.coordinates] + [True] * (Lam.shape[0] - len(rig.coordinates)))
    L = marginalise_nuisance(Lam, scored)
    i = [c.name for c in rig.scored].index(name)
    return float(np.sqrt(np.linalg.inv(L)[i, i]))


@pytest.mark.slow
def test_the_kind_goes_through_score_with_the_dense_reference_sigma(rig, traj):
    from excite.factors.base import Nominal
    from excite.information import dense, problem
    from excite.score.evaluate import evaluate

    rep = evaluate(traj, rig)
    sigma = {p.name: p.sigma for p in rep.parameters}
    assert "speedo.scale_factor" in sigma and rep.nullity == 0
    ref = dense.marginal_dense(problem.build(Nominal.of(traj, rig), rig))
    assert sigma["speedo.scale_factor"] == pytest.approx(_sigma(ref, rig, "speedo.scale_factor"), rel=1e-6)
    # and it is information the speedometer adds: without it the rig has no such parameter, and
    # with it the wheel radii (the other speed scale) are determined better
    without = {p.name: p.sigma for p in evaluate(traj, load_rig("robotaxi")).parameters}
    assert sigma["wheel.radius_left"] < without["wheel.radius_left"]


def test_its_jacobian_is_the_derivative_of_an_independent_speed_model(rig, traj):
    """The evaluator's block for the speedometer (differentiated by CasADi) against central
    differences of the forward speed written here in numpy."""
    from excite.core import so3
    from excite.factors.base import Nominal

    nom = Nominal.of(traj, rig)
    entry = rig.config.sensors[-1]
    blk = kernels.jacobians(Speedometer(), nom, rig, entry)
    k = 37
    R_BV = nom.R_V_B.T
    p_BV = -R_BV @ nom.p_V_B
    sig = entry.noise.speed_noise_density * math.sqrt(entry.rate_hz)

    def speed(d, s=1.0):
        R = nom.R[k] @ so3.exp(d[None, 0:3])[0]
        v = nom.v[k] + d[6:9]
        R_W_A = R @ R_BV @ nom.R_V_A[k]
        return s * R_W_A[:, 0] @ (v + R @ np.cross(nom.omega[k], p_BV)) / sig

    eps = 1e-6
    fd = np.array([(speed(e) - speed(-e)) / (2 * eps) for e in np.eye(9) * eps])
    assert np.allclose(blk.Jx[k, 0], fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())
    col = list(blk.cols).index(rig.index("speedo.scale_factor"))
    assert blk.Jt[k, 0, col] == pytest.approx((speed(np.zeros(9), 1 + eps) - speed(np.zeros(9), 1 - eps)) / (2 * eps))


def test_the_kind_goes_through_live_guidance(rig, traj):
    from excite.score.evaluate import evaluate
    from excite.score.live import Incremental, chunks

    inc = Incremental(rig)
    for c in chunks(traj, rig):
        inc.append(c)
    Lam = inc.information().information
    rep = evaluate(traj, rig)
    assert _sigma(Lam, rig, "speedo.scale_factor") == pytest.approx(
        next(p.sigma for p in rep.parameters if p.name == "speedo.scale_factor"), rel=1e-8)


def test_the_kind_goes_through_mining(rig, traj):
    from excite.fleet import mine
    from excite.information.problem import columns

    s = mine.summarise(traj, rig, chunk_s=10.0)
    Lam, _ = mine.window_information(s, 2, first=1)  # chunks 1 and 2: keyframes 100 … 300
    crop = mine.crop(traj, s.time(int(s.edges[1])), s.time(int(s.edges[3])))
    from excite.score.evaluate import evaluate
    rep = evaluate(crop, rig)
    assert _sigma(Lam[0], rig, "speedo.scale_factor") == pytest.approx(
        next(p.sigma for p in rep.parameters if p.name == "speedo.scale_factor"), rel=1e-6)
    assert len(columns(rig, 1)[0]) == Lam.shape[1]


def test_the_kind_goes_through_the_optimizers_model(rig, traj):
    from excite.factors.base import Nominal
    from excite.information import elimination, problem
    from excite.plan.model import build_model, coarse_rig

    coarse = coarse_rig(rig, 2.0, 4)
    nom = Nominal.of(traj, coarse)
    _, args = model_samples(traj, coarse)
    model = build_model(coarse, nom.n_keyframes)
    Lam = np.array(model.marginal(*args))
    ref = elimination.marginal(problem.build(nom, coarse))
    assert np.abs(Lam - ref).max() <= 1e-6 * np.abs(ref).max()
    i = coarse.index("speedo.scale_factor")
    assert ref[i, i] > 0


def test_the_kind_goes_through_the_simulator_and_the_calibrator(rig, traj):
    from excite.score.evaluate import evaluate
    from excite.validate.calibrate import calibrate, initialise
    from excite.validate.simulate import Calibration, SimulationSettings, simulate

    sigma = next(p.sigma for p in evaluate(traj, rig.with_constant_biases()).parameters
                 if p.name == "speedo.scale_factor")
    nominal = Calibration.nominal(rig)
    delta = np.zeros(len(rig.coordinates))
    delta[rig.index("speedo.scale_factor")] = 0.01  # 10 targets, ~16 σ
    truth = nominal.plus(rig, delta)
    data = simulate(traj, rig, truth, np.random.default_rng(3), SimulationSettings.model())
    assert data.recorded["speedo"].shape == (data.n_keyframes, 1)  # a speed at every keyframe (10 Hz)
    init = initialise(data, rig, nominal, data.truth.R[0], data.truth.p[0])
    res = calibrate(data, rig, init.calibration, init.states)
    assert res.converged, res.reason
    assert 0.8 < res.residual_rms["speedo"] < 1.2  # its residuals are its noise
    err = res.calibration.scalar("speedo", "scale_factor") - truth.scalar("speedo", "scale_factor")
    assert abs(err) < 4 * sigma, (err, sigma)
    assert abs(nominal.scalar("speedo", "scale_factor") - truth.scalar("speedo", "scale_factor")) > 8 * sigma


def test_a_hook_of_kind_is_one_most_kinds_implement():
    """What only one or two kinds need is a protocol of its own, not a hook of every kind: each
    hook of :class:`Kind` is implemented by at least three of the registered kinds."""
    hooks = [n for n, v in vars(Kind).items() if callable(v) and not n.startswith("_")]
    assert {"quantities", "measurement", "residual", "sqrt_information", "simulate"} <= set(hooks)
    for name in hooks:
        own = [k.name for k in registry.kinds() if name in vars(type(k))]
        assert len(own) >= 3, f"Kind.{name} is implemented by {own} only: a protocol of its own"


def test_the_defaults_of_the_protocols():
    """A kind without a protocol gets its default through this module's function of the same name;
    a sensor's factors are at its frames, a section's at every keyframe interval."""
    from helpers import gnss_rig

    rig = gnss_rig(rate_hz=5.0)  # keyframes at the IMU-paced keyframe rate, fixes every 2nd one
    gnss, imu = registry.kind_of_sensor("gnss"), registry.kind_of_section("imu")
    entry = rig.config.sensors[0]
    assert registry.stride(gnss, rig, entry) == round(rig.keyframe_rate_hz / 5.0) == 2
    assert list(registry.frames(gnss, rig, entry, 7)) == [0, 2, 4]  # a pair needs its second keyframe
    assert registry.stride(imu, rig, rig.config.imu) == 1
    assert registry.variant(gnss, entry) == () and registry.block_name(gnss, entry) == entry.name
    assert registry.block_name(imu, rig.config.imu) == "imu"
    wheel = registry.kind_of_section("wheels")
    rec, values = np.zeros((3, 2)), {"scale": 1.0}
    assert registry.prepare_recording(wheel, rig, rig.config.wheels, rec, values) == (rec, values)
    assert isinstance(gnss, registry.PreparesRecording) and not isinstance(wheel, registry.PreparesRecording)
    # a chain's opening: one per entry of the kind, named apart from the entry's own block
    (o,) = registry.openings(rig)
    assert o.kind is gnss.opening and o.entry is entry and o.name != entry.name
    assert [i.name for i in registry.instances(rig)].count(o.name) == 0


PROTOCOLS = (registry.ChoosesEntries, registry.NamesBlocks, registry.HasVariants, registry.ChoosesFactors,
             registry.PreparesRecording, registry.Resamples, registry.ReadsImu, registry.OpensChain)


def test_implements_answers_as_isinstance_for_every_kind_and_protocol_and_holds_no_kind_alive():
    import gc
    import weakref

    kinds = registry.kinds() + [k.opening for k in registry.kinds() if isinstance(k, registry.OpensChain)]
    answers = {(k.name, p.__name__): isinstance(k, p) for k in kinds for p in PROTOCOLS}
    assert any(answers.values()) and not all(answers.values())
    for _ in range(2):  # asked, then remembered
        assert {(k.name, p.__name__): registry.implements(k, p) for k in kinds for p in PROTOCOLS} == answers

    class Bare(Kind):
        name = "bare"

    bare = Bare()
    assert not registry.implements(bare, registry.ReadsImu)
    gone = weakref.ref(bare)
    del bare
    gc.collect()
    assert gone() is None
