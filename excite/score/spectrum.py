"""What a marginal information matrix determines: rank, null space, spectrum, σ and the score.

One function, :func:`analyse`, answers it for the score, for the score with priors and for the
Monte Carlo validation, so that they cannot disagree.

**The rank test is a property of the drive and the sensors**, never of the targets or the units.
It is made on ``N = D Λ_θ D`` with ``D = diag(H_θθ)^-½``: each coordinate's marginal information
relative to the information it had before the trajectory was eliminated (the fraction of it
that survives marginalisation; 1 for a coordinate nothing else competes with). Rescaling a
coordinate (a target, a unit) rescales its row of ``Λ`` and of ``H`` alike, so ``N`` does not
change. The elimination is accurate to ~1e-13 of each coordinate's own information, so
eigenvalues of ``N`` below ``RANK_RTOL = 1e-10`` are exact symmetries of the problem; weak but real
information (a vertical lever arm seen only through suspension pitch) sits at 1e-4…1e-2.
A coordinate whose information before marginalisation is itself at rounding level
(``diag H_θθ ≤ INFORMATION_FLOOR · max diag H_θθ``, SI units: e.g. a time offset on a drive with
exactly constant velocity, whose Jacobian column is rounding noise of 1e-18 against 1e9) carries
none: normalising it would make rounding noise look like information.

The score and σ stay in target units: ``S Λ S`` with ``S = diag(targets)``, restricted to the
observable subspace (the complement of the null space the test found), so a target changes the
score and σ/target but never which directions are unobservable. σ itself is computed from ``N``
(the pseudo-inverse on its observable subspace, scaled back by ``D``): it does not depend on the
targets even in rounding, however far apart they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RANK_RTOL = 1e-10
INFORMATION_FLOOR = 1e-20
NORMALISATION = "diag(H_θθ)^-½ Λ_θ diag(H_θθ)^-½ (information before marginalisation)"
_NULL_WEIGHT = 1e-6  # a coordinate with this much of its unit vector in the null space is unobservable


@dataclass(frozen=True)
class Spectrum:
    """What :func:`analyse` finds, over the coordinates of ``Λ`` in their order.

    ``values`` (ascending) and ``vectors`` (columns, unit length) span the scaled space
    ``x = θ / target``: the first ``nullity`` are the null space (value 0, each vector dominated by
    one coordinate as far as the null space allows), the rest the eigenpairs of ``S Λ S`` on the
    observable subspace. ``normalised``: eigenvalues of ``N`` (the rank test). ``sigma``:
    Cramér–Rao σ per coordinate in SI units, NaN where the coordinate is unobservable (its unit
    vector has a component in the null space)."""

    values: np.ndarray
    vectors: np.ndarray
    nullity: int
    normalised: np.ndarray
    sigma: np.ndarray
    threshold: float

    @property
    def rank(self) -> int:
        return self.values.size - self.nullity

    @property
    def score(self) -> float:
        """``λ_min(S Λ S)``, 0 when anything is unobservable."""
        return 0.0 if self.nullity or self.values.size == 0 else float(self.values[0])

    @property
    def condition(self) -> float | None:
        if self.nullity or self.values.size == 0 or self.values[0] <= 0:
            return None
        return float(self.values[-1] / self.values[0])

    @property
    def null_space(self) -> np.ndarray:
        """Orthonormal basis of the null space in scaled coordinates (p × nullity)."""
        return self.vectors[:, :self.nullity]


def analyse(information: np.ndarray, information_before: np.ndarray, targets: np.ndarray,
            rtol: float = RANK_RTOL) -> Spectrum:
    """Rank, null space, scaled spectrum and σ of the marginal information ``information`` (SI,
    p × p), given the diagonal of the information before marginalisation ``information_before``
    (SI, p) and the accuracy targets (SI, p). See the module docstring."""
    Lam = 0.5 * (information + information.T)
    p = Lam.shape[0]
    h = np.asarray(information_before, dtype=float)
    S = np.asarray(targets, dtype=float)
    if Lam.shape != (p, p) or h.shape != (p,) or S.shape != (p,):
        raise ValueError("information, information_before and targets must be p × p, p and p")
    if not (np.all(np.isfinite(Lam)) and np.all(np.isfinite(h)) and np.all(np.isfinite(S))):
        raise ValueError("the information is not finite")

    carries = h > INFORMATION_FLOOR * max(float(h.max(initial=0.0)), 1e-300)
    C = np.flatnonzero(carries)
    d = 1.0 / np.sqrt(h[C])
    N = Lam[np.ix_(C, C)] * np.outer(d, d)
    wN, U = np.linalg.eigh(N)
    null_N = wN < rtol
    normalised = np.concatenate([np.zeros(p - C.size), wN])

    # null space in θ: the coordinates without information, and D·u for u in the null space of N
    Z = np.zeros((p, p - C.size + int(null_N.sum())))
    Z[np.flatnonzero(~carries), np.arange(p - C.size)] = 1.0
    Z[np.ix_(C, np.arange(p - C.size, Z.shape[1]))] = d[:, None] * U[:, null_N]
    null_weight = np.ones(p)
    null_weight[C] = (U[:, null_N] ** 2).sum(axis=1)
    unobservable = null_weight > _NULL_WEIGHT

    # scaled coordinates x = θ / S: the null space S⁻¹Z, and S Λ S on its complement
    Zx = _readable_basis(Z / S[:, None])
    nullity = Zx.shape[1]
    M = Lam * np.outer(S, S)
    Q = _complement(Zx, p)
    w, E = np.linalg.eigh(Q.T @ M @ Q)
    V = Q @ E
    # σ from the normalised information, whose conditioning no target can spoil:
    # σ_i² = d_i² (N⁺)_ii on the observable subspace
    Uo, wo = U[:, ~null_N], wN[~null_N]
    sigma = np.full(p, np.nan)
    sigma[C] = d * np.sqrt((Uo ** 2) @ (1.0 / wo))
    sigma[unobservable] = np.nan
    return Spectrum(values=np.concatenate([np.zeros(nullity), w]), vectors=np.hstack([Zx, V]),
                    nullity=nullity, normalised=normalised, sigma=sigma, threshold=rtol)


def _readable_basis(Z: np.ndarray) -> np.ndarray:
    """An orthonormal basis of span(Z) whose vectors are each dominated by one coordinate as far
    as the subspace allows: repeatedly the projection of the coordinate axis that lies most in
    the (remaining) subspace. Any basis is correct; this one can be read by its names."""
    if Z.shape[1] == 0:
        return Z
    u, s, _ = np.linalg.svd(Z, full_matrices=False)
    B = u[:, s > 1e-12 * s.max()]
    out = []
    while B.shape[1]:
        i = int(np.argmax((B ** 2).sum(axis=1)))
        v = B @ B[i]
        v /= np.linalg.norm(v)
        v *= np.sign(v[np.argmax(np.abs(v))])
        out.append(v)
        B = B - np.outer(v, v @ B)
        u, s, _ = np.linalg.svd(B, full_matrices=False)
        B = u[:, s > 1e-8]
    return np.column_stack(out)


def _complement(Z: np.ndarray, p: int) -> np.ndarray:
    """Orthonormal basis of the orthogonal complement of the orthonormal columns Z (p × (p − k))."""
    if Z.shape[1] == 0:
        return np.eye(p)
    q, _ = np.linalg.qr(np.hstack([Z, np.eye(p)]))
    return q[:, Z.shape[1]:p]
