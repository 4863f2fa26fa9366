"""Monte Carlo validation of the evaluator's Cramér–Rao σ.

:func:`monte_carlo` runs N seeded trials of: draw a true calibration (the rig's nominal values
plus a random offset of ``offset_in_targets`` × target per coordinate), simulate the drive's
sensor data (:func:`~excite.validate.simulate.simulate`, physical by default), initialise from
the nominal values (:func:`~excite.validate.calibrate.initialise`), calibrate
(:func:`~excite.validate.calibrate.calibrate`), and keep the error of the scored coordinates (for
random-walk biases, against their mean over the drive: what a constant-bias calibration
estimates). :func:`statistics` compares them with the evaluator's report:

- per parameter: predicted σ, empirical σ (RMS error, the spread about the truth) with its 95 %
  chi-square interval, the mean error (bias) with its standard error;
- NEES ``eᵀ Λ_θ e`` per trial; its mean over N trials, times N, is χ²(N·d) for d scored
  coordinates if the evaluator is right, which gives the 95 % interval of the mean NEES;
- the solver: convergence rate and every trial's stop reason;
- the model check: the whitened cost at the estimates against its χ² interval, which flags data
  the model does not describe (:meth:`MonteCarloResult.model_check`).

On a rank-deficient drive, the error is split in the evaluator's scaled coordinates
``z = S⁻¹ e`` into its component in the null space of ``S Λ_θ S`` (what the data cannot determine)
and the rest. The estimator (:meth:`~excite.validate.calibrate._Normal.rank`) does not move along the
null space, so there the error is where the solve started and does not shrink;
the complement is estimated, and its NEES (dof = rank) is checked like a full-rank drive's.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from typing import Callable

import numpy as np
from scipy.stats import chi2

from ..errors import ValidateError
from ..score.evaluate import Report, evaluate
from ..rig.config import Rig
from ..motion.trajectory import Trajectory
from .calibrate import CalibrationResult, SolverSettings, States, calibrate, initialise
from .simulate import Calibration, SimulationSettings, offset_sigma, simulate


@dataclass(frozen=True)
class MonteCarloSettings:
    """How the trials are drawn. ``offset_in_targets``: σ of the true calibration's offset from the
    nominal values, in targets (the monocular scale: ``scale_offset``). ``seed``: trial ``i`` uses
    ``numpy.random.default_rng([seed, i])``, so any trial can be re-run alone."""

    runs: int = 100
    seed: int = 0
    offset_in_targets: float = 2.0
    scale_offset: float = 0.01
    simulation: SimulationSettings = SimulationSettings()
    solver: SolverSettings = SolverSettings()
    confidence: float = 0.95

    def __post_init__(self) -> None:
        if self.runs < 2:
            raise ValidateError(f"runs must be at least 2, got {self.runs}")
        if not (self.offset_in_targets >= 0 and np.isfinite(self.offset_in_targets)):
            raise ValidateError(f"offset_in_targets must be ≥ 0, got {self.offset_in_targets}")
        if not 0 < self.confidence < 1:
            raise ValidateError(f"confidence must be in (0, 1), got {self.confidence}")


@dataclass(frozen=True)
class Trial:
    """One trial: the error of every coordinate (estimate ⊟ truth, over ``rig.coordinates``), the
    initial error, and how the solver ended."""

    index: int
    error: np.ndarray
    initial_error: np.ndarray  # where the joint solve started (after :func:`initialise`)
    status: str
    reason: str
    iterations: int
    cost: float
    dof: int  # residuals − unknowns (the expected 2·cost)
    seconds: float
    residual_rms: dict[str, float] = field(default_factory=dict)  # whitened, per factor kind


@dataclass(frozen=True)
class ParameterStats:
    name: str
    unit: str
    predicted_sigma: float | None  # the evaluator's Cramér–Rao σ (None: unobservable)
    empirical_sigma: float  # RMS error about the truth
    sigma_interval: tuple[float, float]  # chi-square confidence interval of the empirical σ
    bias: float  # mean error
    bias_standard_error: float
    target: float = float("nan")  # the accuracy the rig asks for (1σ)

    @property
    def ratio(self) -> float | None:
        """empirical / predicted σ."""
        return None if self.predicted_sigma is None else self.empirical_sigma / self.predicted_sigma

    @property
    def consistent(self) -> bool | None:
        """The predicted σ lies in the empirical σ's confidence interval."""
        if self.predicted_sigma is None:
            return None
        return self.sigma_interval[0] <= self.predicted_sigma <= self.sigma_interval[1]


@dataclass(frozen=True)
class NullSpaceStats:
    """A rank-deficient drive: errors in targets split along the evaluator's null space.

    ``null_rms`` / ``initial_null_rms``: RMS over trials of the error's null-space component after
    and before calibrating (per null dimension); ``null_moved_rms``: RMS of how far the estimate
    moved along the null space; ``observable_rms``: RMS of the complement's component, whitened
    by the predicted information (1 if the evaluator is right).
    """

    nullity: int
    coordinates: list[list[tuple[str, float]]]  # dominant coordinates of each null direction
    null_rms: float
    initial_null_rms: float
    null_moved_rms: float
    observable_whitened_rms: float


@dataclass
class MonteCarloResult:
    report: Report
    settings: MonteCarloSettings
    trials: list[Trial]
    parameters: list[ParameterStats]
    dof: int  # NEES degrees of freedom: scored coordinates (full rank) or the rank
    nees: np.ndarray  # per trial
    nees_mean: float
    nees_interval: tuple[float, float]  # where the mean NEES lies with `confidence` if consistent
    null_space: NullSpaceStats | None
    failures: int  # trials whose solver did not converge (kept in the statistics)
    seconds: float
    names: list[str] = field(default_factory=list)
    # physical simulator: the error, in predicted σ, of a noise-free trial calibrated from the truth:
    # what the physics the model lacks does to the estimate by itself (None: the model's own data)
    systematic: dict[str, float] | None = None

    @property
    def convergence_rate(self) -> float:
        return 1.0 - self.failures / len(self.trials)

    @property
    def stop_reasons(self) -> dict[str, int]:
        """How many trials ended for each reason (``status: reason``)."""
        out: dict[str, int] = {}
        for t in self.trials:
            key = f"{t.status}: {t.reason}"
            out[key] = out.get(key, 0) + 1
        return dict(sorted(out.items(), key=lambda kv: -kv[1]))

    def residual_rms(self) -> dict[str, float]:
        """Whitened residual RMS per factor kind at the estimates, over all trials. Below 1 where the
        trajectory absorbs much of a factor (the IMU's: nine residuals per nine new states); for
        comparing simulators and drives, not a test by itself (see :meth:`model_check`)."""
        kinds = sorted({k for t in self.trials for k in t.residual_rms})
        return {k: float(np.sqrt(np.mean([t.residual_rms[k] ** 2 for t in self.trials if k in t.residual_rms])))
                for k in kinds}

    def model_check(self) -> tuple[float, tuple[float, float]]:
        """The whitened cost at the estimates against its distribution: if the data has the noise
        the model assumes, ``Σ 2·cost ~ χ²(Σ dof)`` over the trials (dof = residuals − unknowns).
        Returns the mean of ``2·cost / dof`` and its interval at the settings' confidence; above the
        interval, the data violates the model (unmodelled slip, discretisation, drifting biases)."""
        c = np.array([2 * t.cost for t in self.trials])
        d = np.array([t.dof for t in self.trials], dtype=float)
        a = 1 - self.settings.confidence
        D = d.sum()
        return float(c.sum() / D), (float(chi2.ppf(a / 2, D) / D), float(chi2.ppf(1 - a / 2, D) / D))

    def worst_ratio(self) -> tuple[str, float] | None:
        """The parameter whose empirical σ is largest against its target, and that ratio."""
        rows = [(p.name, p.empirical_sigma / p.target) for p in self.parameters]
        return max(rows, key=lambda x: x[1]) if rows else None

    @property
    def nees_consistent(self) -> bool:
        return self.nees_interval[0] <= self.nees_mean <= self.nees_interval[1]

    def max_sigma_deviation(self) -> float:
        """Largest |empirical/predicted − 1| over the observable parameters."""
        return max(abs(p.ratio - 1) for p in self.parameters if p.ratio is not None)

    def to_dict(self) -> dict:
        return {
            "route": self.report.route, "rig": self.report.rig, "scene": self.report.scene, "runs": len(self.trials),
            "seed": self.settings.seed, "offset_in_targets": self.settings.offset_in_targets,
            "score": self.report.score, "rank": self.report.rank, "nullity": self.report.nullity,
            "parameters": [{"name": p.name, "unit": p.unit, "target": p.target, "predicted_sigma": p.predicted_sigma,
                            "empirical_sigma": p.empirical_sigma, "sigma_interval": list(p.sigma_interval),
                            "ratio": p.ratio, "bias": p.bias, "bias_standard_error": p.bias_standard_error}
                           for p in self.parameters],
            "nees": {"dof": self.dof, "mean": self.nees_mean, "interval": list(self.nees_interval),
                     "consistent": self.nees_consistent},
            "null_space": None if self.null_space is None else {
                "nullity": self.null_space.nullity,
                "coordinates": [[[n, w] for n, w in c] for c in self.null_space.coordinates],
                "null_rms": self.null_space.null_rms, "initial_null_rms": self.null_space.initial_null_rms,
                "null_moved_rms": self.null_space.null_moved_rms,
                "observable_whitened_rms": self.null_space.observable_whitened_rms},
            "failures": self.failures, "convergence_rate": self.convergence_rate,
            "stop_reasons": self.stop_reasons, "residual_rms": self.residual_rms(),
            "model_check": {"normalised_cost": self.model_check()[0], "interval": list(self.model_check()[1])},
            "worst_sigma_over_target": None if self.worst_ratio() is None else {
                "name": self.worst_ratio()[0], "ratio": self.worst_ratio()[1]},
            "systematic_error_in_sigma": self.systematic,
            "simulation": asdict(self.settings.simulation), "seconds": self.seconds,
        }


def run_trial(traj: Trajectory, rig: Rig, index: int, settings: MonteCarloSettings,
              log: Callable[[dict], None] | None = None, scan_pairs: dict | None = None) -> Trial:
    """One seeded trial (see the module docstring); ``log`` gets the solver's records, each
    tagged with the trial's index; ``scan_pairs``: the lidars' frame pairs where the drive sees a
    scene (:func:`scene_pairs`)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng([settings.seed, index])
    nominal = Calibration.nominal(rig)
    offset = rng.normal(0.0, 1.0, len(rig.coordinates)) * offset_sigma(rig, settings.offset_in_targets,
                                                                        settings.scale_offset)
    truth = nominal.plus(rig, offset)
    data = simulate(traj, rig, truth, rng, settings.simulation, scan_pairs)
    tr = data.truth
    # the first keyframe's pose is the start of the drive at rest (gravity and the stand-still
    # give its orientation; position and yaw are the gauge)
    init = initialise(data, rig, nominal, tr.R[0], tr.p[0])
    res: CalibrationResult = calibrate(data, rig, init.calibration, init.states, settings.solver,
                                       None if log is None else (lambda rec: log({"trial": index, **rec})))
    # a constant-bias calibration of drifting biases estimates their mean over the drive
    truth = truth.with_values("imu", gyro_bias=tr.gyro_bias.mean(axis=0), accel_bias=tr.accel_bias.mean(axis=0))
    return Trial(index, res.calibration.minus(truth, rig), init.calibration.minus(truth, rig), res.status,
                 res.reason, res.iterations, res.cost, res.n_residuals - res.n_unknowns,
                 time.perf_counter() - t0, res.residual_rms or {})


def statistics(report: Report, rig: Rig, trials: list[Trial], settings: MonteCarloSettings,
               seconds: float = 0.0) -> MonteCarloResult:
    """Compare the trials' errors with the evaluator's ``report`` (see the module docstring)."""
    scored = np.array([not c.nuisance for c in rig.coordinates])
    E = np.array([t.error[scored] for t in trials])
    E0 = np.array([t.initial_error[scored] for t in trials])
    N, d = E.shape
    alpha = 1 - settings.confidence
    params = []
    for i, p in enumerate(report.parameters):
        e = E[:, i]
        rms = float(np.sqrt(np.mean(e**2)))
        # N·rms²/σ² ~ χ²(N) about the truth
        lo = rms * np.sqrt(N / chi2.ppf(1 - alpha / 2, N))
        hi = rms * np.sqrt(N / chi2.ppf(alpha / 2, N))
        params.append(ParameterStats(p.name, p.unit, p.sigma, rms, (float(lo), float(hi)), float(e.mean()),
                                     float(e.std(ddof=1) / np.sqrt(N)), rig.scored[i].target))
    S = np.array([c.target for c in rig.scored])
    Z, Z0 = E / S, E0 / S
    w, V = np.asarray(report.spectrum_scaled), report.eigenvectors_scaled
    null = np.arange(w.size) < report.nullity
    Vo, Vn = V[:, ~null], V[:, null]
    # NEES on the observable complement (all of it on a full-rank drive)
    nees = ((Z @ Vo) ** 2 * w[~null]).sum(axis=1)
    dof = int((~null).sum())
    lo = chi2.ppf(alpha / 2, N * dof) / N
    hi = chi2.ppf(1 - alpha / 2, N * dof) / N
    nstats = None
    if null.any():
        names = [c.name for c in rig.scored]
        coords = []
        for k in range(Vn.shape[1]):
            v = Vn[:, k] * np.sign(Vn[np.argmax(np.abs(Vn[:, k])), k])
            order = np.argsort(-np.abs(v))
            coords.append([(names[i], float(v[i])) for i in order if abs(v[i]) >= 0.1][:6])
        zn, zn0 = Z @ Vn, Z0 @ Vn
        nstats = NullSpaceStats(int(null.sum()), coords, float(np.sqrt(np.mean(zn**2))),
                                float(np.sqrt(np.mean(zn0**2))), float(np.sqrt(np.mean((zn - zn0) ** 2))),
                                float(np.sqrt(nees.mean() / max(dof, 1))))
    return MonteCarloResult(report, settings, trials, params, dof, nees, float(nees.mean()), (float(lo), float(hi)),
                            nstats, sum(t.status != "converged" for t in trials), seconds,
                            names=[c.name for c in rig.scored])


def systematic_error(traj: Trajectory, rig: Rig, report: Report, settings: MonteCarloSettings,
                     scan_pairs: dict | None = None) -> dict[str, float]:
    """What the simulator's physics alone does to the estimate: noise-free data of the nominal
    calibration, calibrated from the truth, its error per observable parameter in predicted σ.
    Residuals cannot show an effect the trajectory absorbs (the IMU's discretisation); this can."""
    truth = Calibration.nominal(rig)
    data = simulate(traj, rig, truth, np.random.default_rng([settings.seed, 0, 1]),
                    replace(settings.simulation, noise=False), scan_pairs)
    tr = data.truth
    res = calibrate(data, rig, truth, States(tr.R, tr.p, tr.v), settings.solver)
    truth = truth.with_values("imu", gyro_bias=tr.gyro_bias.mean(axis=0), accel_bias=tr.accel_bias.mean(axis=0))
    e = res.calibration.minus(truth, rig)[[not c.nuisance for c in rig.coordinates]]
    return {p.name: float(x / p.sigma) for p, x in zip(report.parameters, e) if p.sigma}


def _seeing(traj: Trajectory, rig: Rig, scene) -> Trajectory:
    """``traj`` seeing ``scene`` (itself when it already does, or when there is none)."""
    view = getattr(traj, "scene", None)
    if scene is None or (view is not None and view.digest == scene.digest):
        return traj
    from ..scene.along import seen

    return seen(traj, rig, scene)


def scene_pairs(traj: Trajectory, rig: Rig, scene, settings: MonteCarloSettings) -> tuple[Trajectory, dict]:
    """``traj`` seeing ``scene`` (as it is when it already sees it) and, where the simulator
    ray-casts (:attr:`SimulationSettings.ray_cast <excite.validate.simulate.SimulationSettings>`),
    its lidars' frame pairs in it (:func:`excite.validate.scans.pair_noise`, by name). A drive that
    already sees a scene needs the scene itself to be ray-cast."""
    view = getattr(traj, "scene", None)
    if scene is None:
        if view is not None and settings.simulation.ray_cast:
            raise ValidateError(f"the drive sees the scene {view.source}: give the scene itself, which the "
                                "simulator ray-casts")
        return traj, {}
    from ..scene.along import lidars
    from .scans import pair_noise

    traj = _seeing(traj, rig, scene)
    if not settings.simulation.ray_cast:
        return traj, {}
    return traj, {s.name: pair_noise(scene, traj, rig, s) for s in lidars(rig)}


def monte_carlo(traj: Trajectory, rig: Rig, settings: MonteCarloSettings = MonteCarloSettings(),
                progress: Callable[[Trial], None] | None = None,
                log: Callable[[dict], None] | None = None, scene=None) -> MonteCarloResult:
    """N seeded trials of simulate → calibrate on ``traj`` with ``rig``, against the evaluator
    (``log``: the solver's records of every trial, see :func:`run_trial`), and with the physical
    simulator its :func:`systematic_error`. In a ``scene`` (:class:`~excite.scene.model.Scene`)
    the evaluator scores the drive seeing it and the simulator ray-casts the lidars' scans in it
    (:mod:`excite.validate.scans`)."""
    t0 = time.perf_counter()
    traj, pairs = scene_pairs(traj, rig, scene, settings)
    # the calibrator estimates constant biases (drifting ones, from the physical simulator, against
    # their mean over the drive): predict the same
    report = evaluate(traj, rig.with_constant_biases())
    trials = []
    for i in range(settings.runs):
        trials.append(run_trial(traj, rig, i, settings, log, pairs))
        if progress is not None:
            progress(trials[-1])
    res = statistics(report, rig, trials, settings)
    if settings.simulation.physical:
        res.systematic = systematic_error(traj, rig, report, settings, pairs)
    res.seconds = time.perf_counter() - t0
    return res


# ------------------------------------------------------------------------------------------------
# Every trial its own drive: a plan as people drive it


def statistics_driven(reports: list[Report], rig: Rig, trials: list[Trial], settings: MonteCarloSettings,
                      nominal: Report, seconds: float = 0.0) -> MonteCarloResult:
    """Compare trials whose drives differ (trial ``i`` driven as ``reports[i]`` was evaluated)
    with the prediction made from each trial's own drive: the NEES of trial ``i`` is
    ``eᵢᵀ Λᵢ eᵢ`` with its drive's information (χ²(d) each, so the mean over N trials lies in
    χ²(N·d)/N's interval if the evaluator is right), and the predicted σ of a parameter is the RMS
    of its per-drive σ (the errors are a mixture of zero-mean errors of those σ; the empirical σ's
    interval is one σ's, a little narrow for such a mixture). Full-rank drives only. ``nominal`` is the report of the drive as planned: ``result.report``, for reference."""
    scored = np.array([not c.nuisance for c in rig.coordinates])
    E = np.array([t.error[scored] for t in trials])
    N, d = E.shape
    for r in reports:
        if r.nullity:
            raise ValidateError(f"a driven drive leaves {r.nullity} direction(s) undetermined: the per-drive "
                                "prediction needs every drive to determine every parameter")
    alpha = 1 - settings.confidence
    sig = np.array([[np.nan if p.sigma is None else p.sigma for p in r.parameters] for r in reports])
    pred = np.sqrt(np.mean(sig ** 2, axis=0))
    params = []
    for i, p in enumerate(nominal.parameters):
        e = E[:, i]
        rms = float(np.sqrt(np.mean(e ** 2)))
        lo = rms * np.sqrt(N / chi2.ppf(1 - alpha / 2, N))
        hi = rms * np.sqrt(N / chi2.ppf(alpha / 2, N))
        params.append(ParameterStats(p.name, p.unit, float(pred[i]), rms, (float(lo), float(hi)), float(e.mean()),
                                     float(e.std(ddof=1) / np.sqrt(N)), rig.scored[i].target))
    nees = np.array([float(E[k] @ reports[k].information @ E[k]) for k in range(N)])
    lo = chi2.ppf(alpha / 2, N * d) / N
    hi = chi2.ppf(1 - alpha / 2, N * d) / N
    return MonteCarloResult(nominal, settings, trials, params, d, nees, float(nees.mean()), (float(lo), float(hi)),
                            None, sum(t.status != "converged" for t in trials), seconds,
                            names=[c.name for c in rig.scored])


def monte_carlo_driven(drives: Callable[[int], Trajectory], rig: Rig, nominal: Trajectory,
                       settings: MonteCarloSettings = MonteCarloSettings(),
                       progress: Callable[[Trial], None] | None = None,
                       log: Callable[[dict], None] | None = None, scene=None) -> MonteCarloResult:
    """N seeded trials of simulate → calibrate, trial ``i`` on its own drive ``drives(i)`` (a plan
    as the ``i``-th person drives it), against the evaluator's prediction from each trial's own
    drive (:func:`statistics_driven`); the physical simulator's :func:`systematic_error` on the
    first drive. In a ``scene``, every drive seeing it (:func:`scene_pairs`)."""
    t0 = time.perf_counter()
    crig = rig.with_constant_biases()
    trials, reports = [], []
    first = None
    for i in range(settings.runs):
        traj, pairs = scene_pairs(drives(i), rig, scene, settings)
        first = first or (traj, pairs)
        reports.append(evaluate(traj, crig))
        trials.append(run_trial(traj, rig, i, settings, log, pairs))
        if progress is not None:
            progress(trials[-1])
    res = statistics_driven(reports, rig, trials, settings, evaluate(_seeing(nominal, rig, scene), crig))
    if settings.simulation.physical and first is not None:
        res.systematic = systematic_error(first[0], rig, reports[0], settings, first[1])
    res.seconds = time.perf_counter() - t0
    return res
