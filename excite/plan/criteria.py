"""Design criteria on the target-scaled marginal information M = S Λ_θ S, and LI-Init's heuristic.

Every criterion is a function of the spectrum λ of M, oriented so that *larger is better*:

- ``E`` (the score): λ_min — the worst-determined direction, relative to its target;
- ``D``: log det M = Σ log λ_i — the volume of the information ellipsoid (Kalibr's
  information-gain criterion on the target-scaled marginal);
- ``A``: −trace M⁻¹ = −Σ 1/λ_i — minus the sum of the squared σ/target over the eigen-directions.

A rank-deficient M gives −∞ for all three. :func:`rotation_excitation` is the practitioner's
check LI-Init runs before it calibrates: the eigenvalues of Σ [ω]ₓᵀ[ω]ₓ over the drive (enough
rotation about every axis?). It sees only the motion, not the rig.
"""

from __future__ import annotations

import numpy as np

CRITERIA = ("E", "D", "A")
NAMES = {"E": "E-optimal (λ_min)", "D": "D-optimal (log det)", "A": "A-optimal (trace of inverse)"}


def value(M: np.ndarray, criterion: str) -> float:
    """The criterion at the (symmetric) matrix M; larger is better; −∞ where M is singular."""
    w = np.linalg.eigvalsh(np.asarray(M, dtype=float))
    return spectral(w, criterion)


def spectral(w: np.ndarray, criterion: str) -> float:
    """The criterion from the ascending spectrum ``w`` of M."""
    if criterion == "E":
        return float(w[0])
    tol = 1e-12 * max(abs(float(w[-1])), 1e-300)
    if w[0] <= tol:
        return -np.inf
    if criterion == "D":
        return float(np.sum(np.log(w)))
    if criterion == "A":
        return float(-np.sum(1.0 / w))
    raise ValueError(f"criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")


def smooth(w: np.ndarray, criterion: str, mu: float, beta: float) -> tuple[float, np.ndarray]:
    """The smooth objective IPOPT *minimises* and its derivative with respect to each eigenvalue.

    ``E``: the soft minimum ``−(μ/β) log Σ exp(−β λ_i/μ)``, negated and divided by μ (within
    log(p)/β of −λ_min/μ); ``D``: −Σ log(λ_i/μ); ``A``: μ Σ 1/λ_i. ``μ`` is the scale of the start's
    weakest eigenvalue, so that every objective is of order one. Where an eigenvalue is not
    positive the D and A objectives are undefined; they return +∞ and IPOPT backtracks.
    """
    if criterion == "E":
        x = -beta * w / mu
        c = x.max()
        e = np.exp(x - c)
        pi = e / e.sum()
        return float((c + np.log(e.sum())) / beta), -pi / mu
    if w[0] <= 0:
        return np.inf, np.zeros_like(w)
    if criterion == "D":
        return float(-np.sum(np.log(w / mu))), -1.0 / w
    if criterion == "A":
        return float(mu * np.sum(1.0 / w)), -mu / w**2
    raise ValueError(f"criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")


def rotation_excitation(omega_B: np.ndarray) -> np.ndarray:
    """Ascending eigenvalues of Σ [ω]ₓᵀ[ω]ₓ over the body rates ``omega_B`` (n, 3) [rad/s],
    divided by n (LI-Init's excitation check: every eigenvalue must be large enough)."""
    w = np.asarray(omega_B, dtype=float)
    # [ω]ₓᵀ[ω]ₓ = |ω|² I − ω ωᵀ
    A = np.sum(np.einsum("ni,ni->n", w, w)) * np.eye(3) - w.T @ w
    return np.linalg.eigvalsh(A / max(len(w), 1))


def smooth_curvature(w: np.ndarray, criterion: str, mu: float, beta: float) -> tuple[np.ndarray, np.ndarray]:
    """First and second derivatives of :func:`smooth` with respect to the eigenvalues:
    ``(∂f/∂λ (p,), ∂²f/∂λ∂λ (p, p))``."""
    if criterion == "E":
        x = -beta * w / mu
        e = np.exp(x - x.max())
        pi = e / e.sum()
        return -pi / mu, (beta / mu**2) * (np.diag(pi) - np.outer(pi, pi))
    if criterion == "D":
        return -1.0 / w, np.diag(1.0 / w**2)
    if criterion == "A":
        return -mu / w**2, np.diag(2.0 * mu / w**3)
    raise ValueError(f"criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")


def spectral_hessian(w: np.ndarray, V: np.ndarray, d1: np.ndarray, d2: np.ndarray,
                     dM: np.ndarray) -> np.ndarray:
    """The Hessian ``H[k, l] = d²F[dM_k, dM_l]`` of a spectral function F(M) = φ(λ(M)) along the
    symmetric directions ``dM`` (n, p, p), from the eigen-decomposition ``M = V diag(w) Vᵀ`` and
    φ's derivatives ``d1``, ``d2`` (:func:`smooth_curvature`): with ``E = Vᵀ dM V``,
    ``Σᵢⱼ φᵢⱼ E_ii E_jj + Σ_{i≠j} (φᵢ − φⱼ)/(λᵢ − λⱼ) E_ij²`` (Lewis; the divided difference
    becomes ``φᵢᵢ − φᵢⱼ`` where the eigenvalues coincide)."""
    E = np.einsum("ai,kab,bj->kij", V, dM, V)
    diag = np.einsum("kii->ki", E)
    dw = w[:, None] - w[None, :]
    close = np.abs(dw) <= 1e-12 * max(np.abs(w).max(), 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        G = np.where(close, np.diag(d2)[:, None] - d2, (d1[:, None] - d1[None, :]) / dw)
    np.fill_diagonal(G, 0.0)
    return diag @ d2 @ diag.T + np.einsum("kij,ij,lij->kl", E, G, E)
