"""One trial of benchmarks/bench_car_mc.py re-solved from its start and from the truth: the same
data (run_trial's draws), the cost and the NEES each reaches.

    python benchmarks/car_mc_trial.py physical|model INDEX
"""
import sys
import numpy as np
from excite.cli.validate import with_imu_rate
from excite.io.routes import read_route
from excite.rig.config import load_rig
from excite.score.evaluate import evaluate
from excite.validate.calibrate import calibrate, initialise, States
from excite.validate.monte_carlo import MonteCarloSettings, offset_sigma
from excite.validate.simulate import Calibration, SimulationSettings, simulate

which, index = sys.argv[1], int(sys.argv[2])
rig = with_imu_rate(load_rig("sedan"), 100)
traj = read_route("examples/sedan_planned_60s_control.csv", suspension=rig.suspension)
sim = SimulationSettings() if which == "physical" else SimulationSettings.model(wheel_ticks_per_rev=2048)
settings = MonteCarloSettings(runs=100, seed=0, simulation=sim)
report = evaluate(traj, rig.with_constant_biases())
rng = np.random.default_rng([settings.seed, index])
nominal = Calibration.nominal(rig)
offset = rng.normal(0.0, 1.0, len(rig.coordinates)) * offset_sigma(rig, settings.offset_in_targets, settings.scale_offset)
truth = nominal.plus(rig, offset)
data = simulate(traj, rig, truth, rng, settings.simulation)
tr = data.truth
init = initialise(data, rig, nominal, tr.R[0], tr.p[0])
scored = np.array([not c.nuisance for c in rig.coordinates])
S = np.array([c.target for c in rig.scored])
w, V = np.asarray(report.spectrum_scaled), report.eigenvectors_scaled
mean_truth = truth.with_values("imu", gyro_bias=tr.gyro_bias.mean(axis=0), accel_bias=tr.accel_bias.mean(axis=0))
def nees(cal):
    z = cal.minus(mean_truth, rig)[scored] / S
    return float(((z @ V) ** 2 * w).sum())
for label, cal0, st0 in (("from its start", init.calibration, init.states), ("from the truth", truth, States(tr.R, tr.p, tr.v))):
    res = calibrate(data, rig, cal0, st0, settings.solver)
    print(f"{which} trial {index} {label}: {res.status} ({res.reason}) after {res.iterations} iterations, "
          f"cost {res.cost:.3f}, NEES {nees(res.calibration):.1f}", flush=True)
