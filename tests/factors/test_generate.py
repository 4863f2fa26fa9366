"""The generator of the evaluator's kernels (:mod:`excite.factors.generate`): its output is what
the kinds' statements give, it covers every registered kind and every variant the example rigs
use, each compiled kernel equals its statement evaluated in CasADi's virtual machine, and a kind
registered from outside excite (the speedometer of ``tests/factors/test_base.py``) is generated
and compiled on demand, or evaluated in the virtual machine where no compiler may run."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from excite.factors import base as registry
from excite.factors import generate, kernels, layout, symbolic
from excite.factors.base import Nominal
from excite.motion.vehicle import ControlProfile, drive
from excite.rig import kernels as rig_kernels
from excite.rig.config import RIGS_DIR, load_rig



def test_the_committed_kernels_are_what_the_statements_give():
    """``generated.c`` is regenerated from the statements and compared, byte for byte (it is never
    edited by hand: ``python -m excite.rig.kernels`` rewrites it)."""
    assert generate.TARGET.read_text() == rig_kernels.source(), \
        "excite/factors/generated.c is not what the statements give: run `python -m excite.rig.kernels`"


def test_every_registered_kind_and_every_bundled_rig_has_its_kernels_compiled_in():
    specs = rig_kernels.specs()
    kinds = {k.name for k in registry.kinds()} | {k.opening.name for k in registry.kinds()
                                                   if isinstance(k, registry.OpensChain)}
    assert kinds <= {spec.kind.name for spec in specs.values()}, \
        "a registered kind has no generated kernel: add a rig with it to EXAMPLES in excite/rig/kernels.py"
    compiled = kernels.compiled()
    assert set(specs) == set(compiled)
    for path in sorted(RIGS_DIR.glob("*.yaml")):
        rig = load_rig(path.stem)
        for kind, entry in generate.instances(rig):
            lay = layout.layout(kind, rig, entry)
            for what in generate.kernels_of(kind, lay):
                assert lay.name(what) in compiled, (path.name, lay.name(what))


_T = np.linspace(0.0, 12.0, 25)
_PROFILE = ControlProfile(_T, 5 + 2 * np.sin(_T), 0.1 * np.cos(0.7 * _T), grade_rad=0.05 * np.sin(_T),
                          bank_rad=0.04 * np.cos(1.3 * _T))


def _inputs(spec, fn) -> list[np.ndarray]:
    """A factor's inputs to the kernel on a 3-D drive of its example rig: keyframes, the interval's
    summary (the generated fold), the entry's quantities and constants; for the fold's kernels a
    state part-way through an interval."""
    rig, kind, lay = spec.rig, spec.kind, spec.lay
    traj = drive(_PROFILE, rig.suspension)
    if kind.name == "ground_plane":  # its factors are where the drive sees the road
        from excite.scene import along, shapes

        traj = along.seen(traj, rig, shapes.ground(-300.0, -300.0, 300.0, 300.0))
    nom = Nominal.of(traj, rig)
    c = layout.constant_inputs(lay, layout.constant_values(kind, rig, spec.entry))
    first = registry.factor_keyframes(kind, rig, spec.entry, nom.n_keyframes, nom)
    k = int(first[min(7, first.size - 1)])
    stride = registry.stride(kind, rig, spec.entry)
    if spec.what in ("step", "step2", "finish"):
        rng = np.random.default_rng(5)
        state = rng.normal(size=lay.n_state) * 1e-2
        state[-1] = 3.0  # samples taken so far
        i0 = k * nom.imu_per_keyframe
        R = nom.imu_R[i0].ravel()
        sample = [nom.imu_R[i0 + 5].ravel(), nom.imu_f[i0 + 5]]
        return {"step": [state, R, *sample, c], "step2": [state, R, *sample, nom.imu_R[i0 + 4].ravel(), nom.imu_f[i0 + 4], c],
                "finish": [state, R, nom.imu_R[i0 + lay.n_samples].ravel(), c]}[spec.what]
    s = (kernels.summaries(nom, np.array([k]), lay, tuple(f"{w}_{kind.name}" for w in ("step", "step2", "finish")), c)[0]
         if lay.n_summary else np.zeros(0))
    xs = [nom.keyframe_table[k + a * stride] for a in range(lay.arity)]
    return xs + [s, layout.quantity_inputs(lay, per_entry=True), c]


@pytest.mark.parametrize("name", sorted(rig_kernels.specs()))
def test_each_compiled_kernel_equals_its_statement(name):
    """The compiled kernel against the same function in CasADi's virtual machine, at a factor of a
    3-D drive of the example rig it was generated for."""
    spec = rig_kernels.specs()[name]
    fn = generate.functions(spec.kind, spec.lay, spec.what)
    args = _inputs(spec, fn)
    want = [np.array(o).ravel(order="F") for o in fn.call([ca.DM(a) for a in args])]
    outs = [np.empty(fn.nnz_out(i)) for i in range(fn.n_out())]
    from excite.core.native import module

    module().run(name, np.zeros(1, dtype=np.int64), tuple(np.ascontiguousarray(a, dtype=float)[None] for a in args),
                 (-2,) * len(args), tuple(o[None] for o in outs))
    for got, w in zip(outs, want):
        assert np.all(np.isfinite(w))
        np.testing.assert_allclose(got, w, rtol=1e-12, atol=1e-12 * np.abs(w).max())
    # it computes something — but a statement whitened by zero (a lidar's road plane: only a
    # scene's whitening informs it) has whitened rows of zero, and its unwhitened rows no state
    if spec.what == "lin" and spec.kind.name == "ground_plane":
        assert all(np.abs(o).max() == 0.0 for o in outs)
    else:
        assert max(np.abs(w).max() for w in want) > 0


@pytest.mark.parametrize("name", [n for n, spec in sorted(rig_kernels.specs().items()) if spec.what in ("lin", "raw")])
def test_a_kernel_run_on_four_factors_at_once_gives_each_factors_numbers(name):
    """A kernel over a batch runs four factors at once where it has a batched form (the same
    statements on vectors of the factors' numbers): each factor's Jacobians are bit for bit those of
    the factor run alone (the batched factors, and the one left over)."""
    spec = rig_kernels.specs()[name]
    fn = generate.functions(spec.kind, spec.lay, spec.what)
    one = _inputs(spec, fn)
    rng = np.random.default_rng(3)
    rows = [np.stack([np.asarray(a, dtype=float) * (1 + 1e-3 * rng.normal(size=np.size(a))) for _ in range(5)])
            for a in one]  # five factors near the drive's
    from excite.core.native import module

    def run(inputs):
        outs = tuple(np.empty((len(inputs[0]), fn.nnz_out(i))) for i in range(fn.n_out()))
        module().run(name, np.zeros(len(inputs[0]), dtype=np.int64), tuple(inputs), (-2,) * len(inputs), outs)
        return outs

    together = run(rows)
    alone = [run([r[f:f + 1] for r in rows]) for f in range(5)]
    for i, got in enumerate(together):
        np.testing.assert_array_equal(got, np.vstack([a[i] for a in alone]))
    assert max(np.abs(o).max() for o in together) > 0 or spec.kind.name == "ground_plane"


def test_the_fold_of_four_intervals_at_once_is_each_interval_folded_alone():
    """The fold runs its two-sample step on four intervals at once where it has the step's batched
    form (the same statements on vectors of the intervals' numbers): every summary is the one of
    its interval folded alone, bit for bit (the batched intervals, and those left over)."""
    rig = load_rig("robotaxi")
    nom = Nominal.of(drive(_PROFILE, rig.suspension), rig)
    kind, entry = next((k, e) for k, e in generate.instances(rig) if registry.implements(k, registry.ReadsImu))
    lay = layout.layout(kind, rig, entry)
    assert f"{lay.name('step2')}_x{generate.LANES}" in generate.TARGET.read_text(), "the fold's step has no batched form"
    c = layout.constant_inputs(lay, layout.constant_values(kind, rig, entry))
    fold = tuple(lay.name(w) for w in ("step", "step2", "finish"))
    first = np.array([0, 3, 4, 9, 10, 11, 30, 31, 50])  # two batches of four and one interval alone
    together = kernels.summaries(nom, first, lay, fold, c)
    alone = np.vstack([kernels.summaries(nom, first[i:i + 1], lay, fold, c) for i in range(first.size)])
    assert np.abs(alone).max() > 0
    np.testing.assert_array_equal(together, alone)


@pytest.fixture(scope="module")
def speedometer_rig():
    from factors.test_base import Speedometer  # the kind declared in that test file alone

    registry.register(Speedometer())
    base = load_rig("robotaxi")
    data = base.config.model_dump()
    data["sensors"].append({"name": "speedo", "kind": "speedometer", "rate_hz": 10.0,
                            "noise": {"speed_noise_density": 0.02}})
    data["targets"]["speedo.scale_factor"] = 0.001
    yield base.with_config(**data)
    registry.unregister("speedometer")


def test_a_kind_from_outside_is_generated_on_demand(speedometer_rig, monkeypatch, tmp_path):
    """No kernel of the speedometer is compiled in: with a compiler it is generated and compiled
    into the cache on first use (and found there by a later process), without one — or with
    compiling disabled — it is evaluated in CasADi's virtual machine; all three give the
    statement's derivative."""
    rig = speedometer_rig
    t = np.linspace(0.0, 20.0, 41)
    nom = Nominal.of(drive(ControlProfile(t, 6 + 3 * np.sin(t / 4), 0.08 * np.sin(t / 3)), rig.suspension), rig)
    entry = rig.config.sensors[-1]
    kind = registry.kind_of_sensor("speedometer")
    lay = layout.layout(kind, rig, entry)
    assert lay.name("lin") not in kernels.compiled()
    ref = symbolic.blocks(kind, nom, rig, entry)
    monkeypatch.setenv("EXCITE_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("EXCITE_COMPILE", "0")
    assert generate.on_demand(kind, rig, entry, "lin") is None
    vm = kernels.jacobians(kind, nom, rig, entry)
    monkeypatch.setenv("EXCITE_COMPILE", "1")
    made = generate.on_demand(kind, rig, entry, "lin")
    assert made is not None and list((tmp_path / "kernels").glob("lin_speedometer_*.so"))
    fast = kernels.jacobians(kind, nom, rig, entry)
    for blk in (vm, fast):
        np.testing.assert_allclose(blk.Jx, ref.Jx, rtol=1e-12, atol=1e-12 * np.abs(ref.Jx).max())
        np.testing.assert_allclose(blk.Jt, ref.Jt, rtol=1e-12, atol=1e-12 * np.abs(ref.Jt).max())


def test_a_statement_that_reads_its_entry_is_not_generated_ahead(speedometer_rig):
    """Kernels compiled with the package serve every entry of a variant: a statement that reads
    ``f.entry`` (the speedometer's σ) cannot be one of them, and the generator says what to do."""
    rig = speedometer_rig
    entry = rig.config.sensors[-1]
    kind = registry.kind_of_sensor("speedometer")
    with pytest.raises(TypeError, match=r"constants\(\)"):
        generate.functions(kind, layout.layout(kind, rig, entry), "lin")
