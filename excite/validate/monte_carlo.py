"""Monte Carlo validation of the evaluator's Cramér–Rao σ.

:func:`monte_carlo` runs N seeded trials of: draw a true calibration (the rig's nominal values
plus a random offset of ``offset_in_targets`` × target per coordinate), simulate the drive's
sensor data (:func:`~excite.validate.simulate.simulate`), calibrate from the nominal values and a
dead-reckoned trajectory (:func:`~excite.validate.calibrate.calibrate`), and keep the error of the
scored coordinates. :func:`statistics` compares them with the evaluator's report:

- per parameter: predicted σ, empirical σ (RMS error, the spread about the truth) with its 95 %
  chi-square interval, the mean error (bias) with its standard error;
- NEES ``eᵀ Λ_θ e`` per trial; its mean over N trials, times N, is χ²(N·d) for d scored
  coordinates if the evaluator is right, which gives the 95 % interval of the mean NEES.

On a rank-deficient drive, the error is split in the evaluator's scaled coordinates
``z = S⁻¹ e`` into its component in the null space of ``S Λ_θ S`` (what the data cannot determine)
and the rest. The estimator (:func:`~excite.validate.calibrate._step`) does not move along the
null space, so there the error is the initial one (the random true offset) and does not shrink;
the complement is estimated, and its NEES (dof = rank) is checked like a full-rank drive's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.stats import chi2

from ..evaluate import Report, evaluate
from ..rig import Rig
from ..trajectory import Trajectory
from .calibrate import CalibrationResult, SolverSettings, calibrate, dead_reckoning
from .simulate import Calibration, SimulationSettings, ValidateError, offset_sigma, simulate


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
    initial_error: np.ndarray
    status: str
    iterations: int
    cost: float
    dof: int  # residuals − unknowns (the expected 2·cost)
    seconds: float


@dataclass(frozen=True)
class ParameterStats:
    name: str
    unit: str
    predicted_sigma: float | None  # the evaluator's Cramér–Rao σ (None: unobservable)
    empirical_sigma: float  # RMS error about the truth
    sigma_interval: tuple[float, float]  # chi-square confidence interval of the empirical σ
    bias: float  # mean error
    bias_standard_error: float

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

    @property
    def nees_consistent(self) -> bool:
        return self.nees_interval[0] <= self.nees_mean <= self.nees_interval[1]

    def max_sigma_deviation(self) -> float:
        """Largest |empirical/predicted − 1| over the observable parameters."""
        return max(abs(p.ratio - 1) for p in self.parameters if p.ratio is not None)

    def to_dict(self) -> dict:
        return {
            "route": self.report.route, "rig": self.report.rig, "runs": len(self.trials),
            "seed": self.settings.seed, "offset_in_targets": self.settings.offset_in_targets,
            "score": self.report.score, "rank": self.report.rank, "nullity": self.report.nullity,
            "parameters": [{"name": p.name, "unit": p.unit, "predicted_sigma": p.predicted_sigma,
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
            "failures": self.failures, "seconds": self.seconds,
        }


def run_trial(traj: Trajectory, rig: Rig, index: int, settings: MonteCarloSettings) -> Trial:
    """One seeded trial (see the module docstring)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng([settings.seed, index])
    nominal = Calibration.nominal(rig)
    offset = rng.normal(0.0, 1.0, len(rig.coordinates)) * offset_sigma(rig, settings.offset_in_targets,
                                                                        settings.scale_offset)
    truth = nominal.plus(rig, offset)
    data = simulate(traj, rig, truth, rng, settings.simulation)
    tr = data.truth
    # start: nominal calibration; trajectory dead-reckoned from the true state at the first
    # keyframe (a drive starts at rest, where gravity and the stand-still give it)
    X0 = dead_reckoning(data, tr.R[0], tr.p[0], tr.v[0], nominal)
    res: CalibrationResult = calibrate(data, rig, nominal, X0, settings.solver)
    return Trial(index, res.calibration.minus(truth, rig), nominal.minus(truth, rig), res.status, res.iterations,
                 res.cost, res.n_residuals - res.n_unknowns, time.perf_counter() - t0)


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
                                     float(e.std(ddof=1) / np.sqrt(N))))
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


def monte_carlo(traj: Trajectory, rig: Rig, settings: MonteCarloSettings = MonteCarloSettings(),
                progress: Callable[[Trial], None] | None = None) -> MonteCarloResult:
    """N seeded trials of simulate → calibrate on ``traj`` with ``rig``, against the evaluator."""
    t0 = time.perf_counter()
    # the simulator draws constant biases and the calibrator estimates them so: predict the same
    report = evaluate(traj, rig.with_constant_biases())
    trials = []
    for i in range(settings.runs):
        trials.append(run_trial(traj, rig, i, settings))
        if progress is not None:
            progress(trials[-1])
    return statistics(report, rig, trials, settings, time.perf_counter() - t0)
