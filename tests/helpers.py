"""Factories and invariants shared by the trajectory, route and maneuver tests."""

from __future__ import annotations

import numpy as np

from excite.core import so3
from excite.motion.trajectory import GRAVITY, Trajectory
from excite.motion.vehicle import ControlProfile, Suspension, drive


def weave_profile(duration_s: float = 30.0, name: str = "weave") -> ControlProfile:
    """A gentle drive with varying speed and curvature of both signs (within default limits)."""
    t = np.linspace(0.0, duration_s, int(duration_s * 10) + 1)
    speed = 5.0 + 2.0 * np.sin(2 * np.pi * t / 15.0)
    kappa = 0.05 * np.sin(2 * np.pi * t / 10.0)
    return ControlProfile(t_s=t, speed_mps=speed, curvature_1pm=kappa,
                          grade_rad=0.02 * np.sin(2 * np.pi * t / 20.0), name=name)


def weave_drive(suspension: Suspension = Suspension()) -> Trajectory:
    return drive(weave_profile(), suspension)


def _window(traj: Trajectory, rate_hz: float, window_s: tuple[float, float] | None) -> np.ndarray:
    t = traj.times(rate_hz)
    if window_s is not None:
        t = t[(t >= window_s[0]) & (t <= window_s[1])]
    return t


def orientation_error_from_rates(traj: Trajectory, rate_hz: float = 1000.0,
                                 window_s: tuple[float, float] | None = None) -> float:
    """Integrate the body rate from the first orientation (Exp of RK4-averaged increments) and
    return the largest angle [rad] between the integrated and the sampled orientations."""
    t = _window(traj, rate_hz, window_s)
    dt = 1.0 / rate_hz
    s = traj.sample(t)
    mid = traj.sample(t[:-1] + 0.5 * dt).omega_V
    # RK4-like (Simpson) rate over each step; Exp-product of the increments.
    w = (s.omega_V[:-1] + 4.0 * mid + s.omega_V[1:]) / 6.0
    steps = so3.exp(w * dt)
    R = s.R_W_V[0].copy()
    err = 0.0
    for k in range(steps.shape[0]):
        R = R @ steps[k]
        if (k + 1) % 50 == 0 or k + 1 == steps.shape[0]:
            err = max(err, float(np.linalg.norm(so3.log(s.R_W_V[k + 1].T @ R))))
    return err


def specific_force_error(traj: Trajectory, rate_hz: float = 200.0,
                         window_s: tuple[float, float] | None = None) -> tuple[float, float]:
    """Largest difference [m/s²] between the sampled specific force and Rᵀ(p̈ − g) with p̈ from
    central finite differences of sampled positions at ``rate_hz``, and the largest |f|."""
    t = _window(traj, rate_hz, window_s)[1:-1]
    h = 1.0 / rate_hz
    p = [traj.sample(t + d).p_W_V for d in (-h, 0.0, h)]
    acc = (p[0] - 2 * p[1] + p[2]) / h**2
    s = traj.sample(t)
    f_fd = np.einsum("nji,nj->ni", s.R_W_V, acc - GRAVITY)
    return float(np.abs(f_fd - s.specific_force_V).max()), float(np.abs(s.specific_force_V).max())
