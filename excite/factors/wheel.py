"""Wheel-encoder increments over each keyframe interval.

The rear axle (origin of V) travels ``Δs`` forward and turns ``Δψ`` about the road normal between
keyframes i and j, both taken in the road-aligned axle frame A (the body frame without its
suspension tilt):

    Δψ = e_zᵀ Log(R_W_A,iᵀ R_W_A,j),   Δs = m(Δψ)ᵀ R_W_A,iᵀ (p_V,j − p_V,i),   m = (cos Δψ/2, sin Δψ/2, 0)

(``m`` points along the mean heading, so Δs is the chord of the arc). The left and right wheels
turn by ``(Δs ∓ ½·track·Δψ) / radius_{left,right}`` radians, each with noise ``sigma_rad``.
"""

from __future__ import annotations

import numpy as np

from .. import so3
from ..rig import Rig
from .base import FactorBlock, Nominal, theta_columns


def _geometry(nom: Nominal):
    R_BV = nom.R_V_B.T
    p_BV = -R_BV @ nom.p_V_B  # origin of V in B
    R_BA = R_BV @ nom.R_V_A  # (K,3,3)
    return R_BV, p_BV, R_BA


def blocks(nom: Nominal, rig: Rig) -> FactorBlock | None:
    """Whitened Jacobians of the left/right wheel increments of every keyframe interval."""
    wc = rig.config.wheels
    if wc is None:
        return None
    R, p = nom.R, nom.p
    _, p_BV, R_BA = _geometry(nom)
    N = nom.n_keyframes - 1
    Ri, Rj = R[:-1], R[1:]
    RAi = Ri @ R_BA[:-1]
    RAj = Rj @ R_BA[1:]
    phi = so3.log(np.swapaxes(RAi, 1, 2) @ RAj)
    dpsi = phi[:, 2]
    pVi = p[:-1] + Ri @ p_BV
    pVj = p[1:] + Rj @ p_BV
    c = np.einsum("nji,nj->ni", RAi, pVj - pVi)
    m = np.stack([np.cos(dpsi / 2), np.sin(dpsi / 2), np.zeros(N)], axis=1)
    dm = 0.5 * np.stack([-np.sin(dpsi / 2), np.cos(dpsi / 2), np.zeros(N)], axis=1)
    ds = np.einsum("ni,ni->n", m, c)

    # Jacobians of φ (3) and c (3) w.r.t. [δθ_i, δp_i, δv_i, δθ_j, δp_j, δv_j]
    Jphi = np.zeros((N, 3, 18))
    Jphi[:, :, 0:3] = -so3.left_jacobian_inv(phi) @ np.swapaxes(R_BA[:-1], 1, 2)
    Jphi[:, :, 9:12] = so3.right_jacobian_inv(phi) @ np.swapaxes(R_BA[1:], 1, 2)
    q = np.einsum("nji,nj->ni", Ri, p[1:] + Rj @ p_BV - p[:-1])
    RAiT = np.swapaxes(RAi, 1, 2)
    Jc = np.zeros((N, 3, 18))
    Jc[:, :, 0:3] = np.swapaxes(R_BA[:-1], 1, 2) @ so3.hat(q)
    Jc[:, :, 3:6] = -RAiT
    Jc[:, :, 9:12] = -RAiT @ Rj @ so3.hat(p_BV)
    Jc[:, :, 12:15] = RAiT
    Jpsi = Jphi[:, 2, :]
    Js = np.einsum("ni,nik->nk", m, Jc) + np.einsum("ni,ni->n", dm, c)[:, None] * Jpsi

    rl, rr, b = wc.radius_left_m, wc.radius_right_m, wc.track_m
    Jx = np.stack([(Js - 0.5 * b * Jpsi) / rl, (Js + 0.5 * b * Jpsi) / rr], axis=1)
    if wc.estimate:
        cols = theta_columns(rig, ["wheel.radius_left", "wheel.radius_right", "wheel.track"])
        Jt = np.zeros((N, 2, 3))
        Jt[:, 0, 0] = -(ds - 0.5 * b * dpsi) / rl**2
        Jt[:, 1, 1] = -(ds + 0.5 * b * dpsi) / rr**2
        Jt[:, 0, 2] = -0.5 * dpsi / rl
        Jt[:, 1, 2] = 0.5 * dpsi / rr
    else:
        cols, Jt = np.zeros(0, dtype=int), np.zeros((N, 2, 0))
    return FactorBlock("wheel", np.arange(N), 1, 2, Jx / wc.sigma_rad, Jt / wc.sigma_rad, cols)


def increments(Ri, pi, Rj, pj, R_BA_i, R_BA_j, p_BV, radius_left, radius_right, track) -> np.ndarray:
    """Left and right wheel rotation [rad] between two body poses (the nonlinear model)."""
    RAi, RAj = Ri @ R_BA_i, Rj @ R_BA_j
    dpsi = so3.log(RAi.T @ RAj)[2]
    c = RAi.T @ (pj + Rj @ p_BV - pi - Ri @ p_BV)
    ds = np.cos(dpsi / 2) * c[0] + np.sin(dpsi / 2) * c[1]
    return np.array([(ds - 0.5 * track * dpsi) / radius_left, (ds + 0.5 * track * dpsi) / radius_right])
