"""SO(3) helpers and trajectory sampling against independent references."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from excite.core import so3
from excite.motion import kernels as motion_kernels
from excite.motion.vehicle import ControlProfile, drive


@pytest.mark.parametrize("scale", [1e-7, 1e-3, 9e-3, 0.3, 2.5])
def test_exp_log_match_scipy(scale):
    phi = np.random.default_rng(0).normal(size=(200, 3)) * scale
    np.testing.assert_allclose(so3.exp(phi), Rotation.from_rotvec(phi).as_matrix(), atol=1e-14)
    inside = np.linalg.norm(phi, axis=1) < np.pi - 1e-3  # Log returns the shortest rotation vector
    np.testing.assert_allclose(so3.log(so3.exp(phi[inside])), phi[inside], atol=1e-12)


@pytest.mark.parametrize("phi", [[0.0, 0.0, 0.0], [1e-3, -2e-3, 0.0], [0.3, -0.2, 1.1]])
def test_single_rotation_vector(phi):
    """Unbatched input (as the nonlinear IMU model uses it), on both sides of the series switch."""
    np.testing.assert_allclose(so3.exp(np.array(phi)), Rotation.from_rotvec(phi).as_matrix(), atol=1e-15)


def _spline_rotation(p0, p1, p2, t):
    """The compiled rotation sampler on one segment with φ(t) = p0 + p1 t + p2 t² and R_key = I."""
    c = np.zeros((4, 1, 3))
    c[1, 0], c[2, 0], c[3, 0] = p2, p1, p0
    t = np.asarray(t, dtype=float)
    return motion_kernels.rotation_samples(t, np.zeros(t.size, dtype=np.int64), np.array([0.0, 1.0]), c, np.eye(3)[None])


@pytest.mark.parametrize("scale", [1e-6, 5e-3, 0.02, 1.0])
def test_body_rate_and_acceleration_are_derivatives_of_exp(scale):
    """For R(t) = Exp(φ(t)): R, ω = (RᵀṘ)∨ and α = ω̇ by central differences in t, on both sides
    of the series switch of the coefficients."""
    rng = np.random.default_rng(1)
    h = 1e-5
    for _ in range(20):
        p0, p1, p2 = (rng.normal(size=3) * scale for _ in range(3))
        R, w, al = _spline_rotation(p0, p1, p2, [0.0])
        np.testing.assert_allclose(R[0], so3.exp(p0), atol=1e-15)

        def omega_fd(t):
            Rm, Rp = _spline_rotation(p0, p1, p2, [t - h, t + h])[0]
            W = so3.exp(p0 + p1 * t + p2 * t * t).T @ (Rp - Rm) / (2 * h)
            return np.array([W[2, 1], W[0, 2], W[1, 0]])

        np.testing.assert_allclose(w[0], omega_fd(0.0), atol=1e-8 * max(scale, 1e-3))
        alpha_fd = (omega_fd(1e-3) - omega_fd(-1e-3)) / 2e-3
        np.testing.assert_allclose(al[0], alpha_fd, atol=1e-5 * max(scale, 1e-2))


@pytest.fixture(scope="module")
def traj():
    t = np.linspace(0, 30, 31)
    return drive(ControlProfile(t, 8 + 3 * np.sin(t / 3), 0.1 * np.sin(t / 2), grade_rad=0.05 * np.sin(t / 4),
                                bank_rad=0.03 * np.cos(t / 3)))


def test_sampling_equals_scipy_rotation_spline(traj):
    t = np.linspace(traj.t_start, traj.t_end, 4321)
    s = traj.sample(t)
    np.testing.assert_allclose(s.R_W_V, traj._rot(t).as_matrix(), atol=1e-13)
    np.testing.assert_allclose(s.omega_V, traj._rot(t, 1), atol=1e-12)
    np.testing.assert_allclose(s.alpha_V, traj._rot(t, 2), atol=1e-10)


def test_compiled_imu_sampling_equals_the_vectorised_one(traj):
    t = np.linspace(traj.t_start, traj.t_end, 4321)
    R_V_B, p_V_B = so3.rot_z(0.2) @ so3.rot_x(0.05), np.array([1.4, 0.1, 0.6])
    R, w, f = traj.imu(t, R_V_B, p_V_B)
    b = traj.sample(t).body(R_V_B, p_V_B)
    np.testing.assert_allclose(R, b.R_W_B, atol=1e-13)
    np.testing.assert_allclose(w, b.omega_B, atol=1e-12)
    np.testing.assert_allclose(f, b.specific_force_B, atol=1e-10)
