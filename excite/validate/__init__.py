"""Prove the predicted σ: simulate a rig's sensors on a drive, calibrate from the noisy data with
a nonlinear batch estimator, and compare the Monte Carlo spread with the evaluator's Cramér–Rao σ.

- :mod:`.simulate`: raw noisy sensor data from a drive and a true calibration;
- :mod:`.calibrate`: Levenberg–Marquardt over the joint sparse problem, reusing the factors;
- :mod:`.monte_carlo`: seeded trials and their statistics (empirical σ with confidence
  intervals, bias, NEES), and the null-space split of a degenerate drive.
"""
