"""Two-view geometry for the camera's checks: landmarks on a ground and a wall, projections, and a
bundle adjustment of one frame pair (the estimator a camera pair's predicted covariance is
checked against: tests/scene/test_camera.py, benchmarks/bench_camera.py)."""

from __future__ import annotations

import numpy as np

from excite.core import so3


def landmarks(rng, n: int = 40) -> np.ndarray:
    """Features on the ground 1.5 m below the camera and on a wall 6 m to its right (S_i)."""
    g = np.column_stack([rng.uniform(-5, 5, n // 2), np.full(n // 2, 1.5), rng.uniform(4, 25, n // 2)])
    w = np.column_stack([np.full(n - n // 2, 6.0), rng.uniform(-4, 1, n - n // 2), rng.uniform(6, 30, n - n // 2)])
    return np.vstack([g, w])


def pi(P: np.ndarray) -> np.ndarray:
    """Normalized image coordinates of points in an optical frame."""
    return P[..., :2] / P[..., 2:3]


def bundle_adjust(ui, uj, R, t, basis, sigma):
    """Levenberg–Marquardt over the pose's five directions ``basis`` (the scale fixed) and each
    landmark's inverse-depth coordinates ``(a, b, w)`` (X = (a, b, 1)/w in S_i), started from the
    landmarks triangulated (midpoint of the two rays) at the nominal pose."""
    n = ui.shape[0]
    f_i = np.column_stack([ui, np.ones(n)])
    f_j = np.column_stack([uj, np.ones(n)]) @ R.T
    depth = np.array([np.linalg.lstsq(np.column_stack([a, -b]), t, rcond=None)[0][0] for a, b in zip(f_i, f_j)])
    # rays that meet behind the cameras, or hardly ahead of them: start the landmark far ahead
    depth = np.where(np.isfinite(depth) & (depth > 2 * np.linalg.norm(t)), np.minimum(depth, 1e4), 1e4)
    ab, w = ui.copy(), 1.0 / depth

    def frame_j(ab, w, R, t):
        return (np.column_stack([ab, np.ones(n)]) - w[:, None] * t) @ R

    def cost(ab, w, R, t):
        P = frame_j(ab, w, R, t)
        return np.inf if np.any(P[:, 2] <= 1e-9) else np.sum((ab - ui) ** 2) + np.sum((pi(P) - uj) ** 2)

    def skew(v):
        return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])

    lam, cur = 1e-3, cost(ab, w, R, t)
    for _ in range(100):
        P = frame_j(ab, w, R, t)
        r = np.concatenate([ab - ui, pi(P) - uj], axis=1) / sigma
        JX = np.zeros((n, 4, 3))
        Jd = np.zeros((n, 4, 6))
        JX[:, 0, 0] = JX[:, 1, 1] = 1.0
        z = P[:, 2]
        D = np.zeros((n, 2, 3))
        D[:, 0, 0] = D[:, 1, 1] = 1 / z
        D[:, :, 2] = -P[:, :2] / z[:, None] ** 2
        JX[:, 2:] = np.concatenate([D @ R.T[:, :2], -(D @ (R.T @ t))[:, :, None]], axis=2)
        Jd[:, 2:, :3] = D @ np.array([skew(p) for p in P])
        Jd[:, 2:, 3:] = -w[:, None, None] * D
        JX /= sigma
        Jd = Jd @ basis / sigma
        Hxx = np.swapaxes(JX, 1, 2) @ JX
        Hxd = np.swapaxes(JX, 1, 2) @ Jd
        bx = np.einsum("nri,nr->ni", JX, r)
        bd = np.einsum("nri,nr->i", Jd, r)
        Hdd = np.einsum("nri,nrj->ij", Jd, Jd)
        while True:
            iH = np.linalg.inv(Hxx + lam * np.einsum("nii->ni", Hxx)[:, :, None] * np.eye(3))
            S = Hdd + lam * np.diag(np.diag(Hdd)) - np.einsum("nai,nab,nbj->ij", Hxd, iH, Hxd)
            dd = -np.linalg.solve(S, bd - np.einsum("nai,nab,nb->i", Hxd, iH, bx))
            dX = -np.einsum("nab,nb->na", iH, bx + Hxd @ dd)
            d6 = basis @ dd
            t2, R2 = t + R @ d6[3:], R @ so3.exp(d6[:3])
            new = cost(ab + dX[:, :2], w + dX[:, 2], R2, t2)
            if new <= cur:
                lam = max(lam / 10, 1e-9)
                break
            lam *= 10
            if lam > 1e8:
                return R, t
        done = cur - new < 1e-14 * cur
        R, t, ab, w, cur = R2, t2, ab + dX[:, :2], w + dX[:, 2], new
        if done:
            break
    return R, t


def scale_direction(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The pair's scale direction in δ (6): every landmark and ``t`` stretched together."""
    return np.r_[np.zeros(3), R.T @ t / np.linalg.norm(t)]


def nees(X: np.ndarray, R: np.ndarray, t: np.ndarray, sigma: float, information: np.ndarray, trials: int,
         rng: np.random.Generator) -> np.ndarray:
    """The NEES of ``trials`` bundle adjustments of the landmarks ``X`` (S_i) seen with noise
    ``sigma`` by the pair ``R, t``, over the five directions besides the scale (held), against
    the covariance ``information`` (6 × 6 about δ) predicts there."""
    basis = np.linalg.qr(np.column_stack([scale_direction(R, t), np.eye(6)]))[0][:, 1:6]
    cov = np.linalg.inv(basis.T @ information @ basis)
    u_i, u_j = pi(X), pi((X - t) @ R)
    out = np.empty(trials)
    for k in range(trials):
        R2, t2 = bundle_adjust(u_i + rng.normal(0, sigma, u_i.shape), u_j + rng.normal(0, sigma, u_j.shape),
                               R, t, basis, sigma)
        err = basis.T @ np.r_[so3.log(R.T @ R2), R.T @ (t2 - t)]
        out[k] = err @ np.linalg.solve(cov, err)
    return out
