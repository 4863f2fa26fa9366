"""Prove the predicted σ: simulate a rig's sensors on a drive, calibrate from the noisy data with
a nonlinear batch estimator, and compare the Monte Carlo spread with the evaluator's Cramér–Rao σ.

- :mod:`.simulate`: raw noisy sensor data from a drive and a true calibration;
- :mod:`.calibrate`: initialisation (rotation from angular rates, then the trajectory) and a
  trust-region Levenberg–Marquardt over the joint sparse problem, reusing the factors;
- :mod:`.monte_carlo`: seeded trials and their statistics (empirical σ with confidence
  intervals, bias, NEES), and the null-space split of a degenerate drive.
"""

from .calibrate import CalibrationResult, Initialisation, SolverSettings, States, calibrate, initialise
from .monte_carlo import MonteCarloResult, MonteCarloSettings, monte_carlo, run_trial, statistics
from ..errors import ValidateError
from .simulate import Calibration, SensorData, SimulationSettings, simulate

__all__ = [
    "Calibration", "CalibrationResult", "Initialisation", "MonteCarloResult", "MonteCarloSettings", "SensorData",
    "SimulationSettings", "SolverSettings", "States", "ValidateError", "calibrate", "initialise", "monte_carlo",
    "run_trial", "simulate", "statistics",
]
