"""What a camera's frame pair tells about its relative pose: the bearings of the features on the
scene's surfaces, each landmark eliminated.

**One landmark.** A feature at ``X`` (in the optical frame S_i of frame i: z forward, x right, y
down) is seen in frame i at the normalized image coordinates ``u_i = π(X)``, ``π(P) = (P_x/P_z,
P_y/P_z)``, and in frame j at ``u_j = π(P_j)``, ``P_j = R_ijᵀ (X − t_ij)``, with ``T_ij = (R_ij,
t_ij)`` frame j's pose in frame i. Under a right perturbation ``δ = [φ, ρ]`` of ``T_ij`` (``R_ij
Exp(φ)``, ``t_ij + R_ij ρ``: in S_j, the lidar's and the odometry's convention)

    ∂P_j/∂X = R_ijᵀ,   ∂P_j/∂φ = [P_j]×,   ∂P_j/∂ρ = −I,

and each coordinate of ``u`` has the noise ``σ = pixel_noise / focal``. The landmark's four rows
over ``[X, δ]`` (4 × 9) hold ``H = JᵀJ/σ²``; its position is not known, so it is eliminated: the
Schur complement ``H_δδ − H_δX H_XX⁻¹ H_Xδ`` is the information its bearings hold about ``δ``.
Four coordinates less three of position leave one row: the epipolar constraint
``f_i · (t_ij × R_ij f_j) = 0`` on the rays ``f = (u, 1)``, with the bearings' noise carried
through it (rank 1: :func:`epipolar_rows`).

**A bound, and where it is met.** The eliminated information is the pair's Cramér–Rao bound, a
linearization at the landmarks' true depths. A bundle adjustment of simulated pairs meets it
where near landmarks fix the translation's direction (40 landmarks 4–30 m away on a ground and a
wall, a metre of baseline, with or without ten more 150–300 m ahead: ``tests/scene/test_camera.py``,
``benchmarks/bench_camera.py``); where every landmark is far ahead its errors are heavy-tailed and
the bound is only a guide. Without baseline (pure rotation) the epipolar constraint is void: the
pair tells nothing, of the rotation either (a monocular odometry that keeps a map would still
track the rotation there: not counted). A far scene tells little: a landmark at depth d sees a
translation ρ only as ρ/d, its information about the translation falling as 1/d².

**Scale.** Bearings leave the translation's length free: the scale direction ``δ = [0, R_ijᵀ
t_ij]`` (every landmark and the translation stretched together) carries no information. The
model's monocular camera has one scale for the whole drive (a nuisance in the odometry's
residual), which the odometry keeps from pair to pair through the landmarks it has triangulated:
a pair's length is known as well as those landmarks' depths, which are what fix the
translation's direction too. The pair's information along the scale direction is therefore taken
to be the mean of its two other translation directions' (their marginal information, the rotation
eliminated): a rich scene then tells the length as the odometry's drift density says, a
textureless or distant one tells nothing of it, as of the rest. A camera that is not monocular is
treated the same way: its pair is bearing-only here (a stereo camera's depth from its own baseline
is not modelled: conservative).

**The quadrature.** Frame i's field of view is cast with a grid of :data:`COLUMNS` ×
:data:`ROWS` cells, even in normalized image coordinates (each an equal share of the image). A
cell's central ray that meets a surface within the camera's range stands for the features of its
cell: the surface's ``features_per_m2`` × the cell's footprint on it (:func:`_cast`); cells at
edges are cast again more finely (:func:`informations`); features seen beyond
:data:`MIN_INCIDENCE_COS` are not found. The detector's budget of ``max_features`` is spread over
the image as evenly as the texture allows (:func:`waterfill`: each cell keeps what it has up to
a common level, the level set so that the frame holds at most the budget, the bucketing visual
front ends do), so that a far, grazing stretch of ground fills its cells and no more. A feature
counts where frame j sees it too: inside its image and range, on the side of the surface facing
it, and not hidden (a second cast from frame j). The pair's information is the sum of its
landmarks', each cell's times its count of features, and the length along the scale direction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.parallel import each
from ..factors.optics import CameraOptics
from .model import Scene

COLUMNS = 24
"""Rays across the image a frame is cast with."""
ROWS = 16
"""Rays down the image a frame is cast with."""
MIN_INCIDENCE_COS = 0.05
"""Features on a surface seen more obliquely than this (|n·d| below it: beyond 87° from its
normal, its texture foreshortened twentyfold) are not found."""
REFINE = 3
"""Rays across and down a cell that is cast again (see :func:`informations`)."""
PAIRS_PER_CALL = 64
"""Frame pairs ray-cast in one call to the ray caster (bounds the memory of a long drive)."""


@dataclass(frozen=True)
class FramePattern:
    """The grid a frame is cast with: ``cols`` × ``rows`` cells even in normalized image
    coordinates, of size ``du`` × ``dv``, their centres ``u`` (cols) and ``v`` (rows)."""

    u: np.ndarray
    v: np.ndarray
    du: float
    dv: float

    @property
    def cols(self) -> int:
        return self.u.size

    @property
    def rows(self) -> int:
        return self.v.size

    def rays(self, u: np.ndarray, v: np.ndarray, du: float, dv: float) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions (… × 3) through the image points ``u, v`` and the solid angle of a
        cell of ``du`` × ``dv`` about each."""
        d = np.stack([u, v, np.ones(np.shape(u))], axis=-1)
        norm = np.linalg.norm(d, axis=-1)
        return d / norm[..., None], du * dv / norm**3

    @property
    def directions(self) -> np.ndarray:
        """The cells' central rays, column-major (cols · rows × 3)."""
        U, V = np.meshgrid(self.u, self.v, indexing="ij")
        return self.rays(U.ravel(), V.ravel(), self.du, self.dv)[0]


def pattern(optics: CameraOptics, density: float = 1.0) -> FramePattern:
    """The grid a frame of ``optics`` is cast with (``density`` multiplies the columns and the
    rows: a finer quadrature of the same camera, for checks)."""
    cols = max(1, int(round(COLUMNS * density)))
    rows = max(1, int(round(ROWS * density)))
    hx, hy = optics.half_extent
    du, dv = 2 * hx / cols, 2 * hy / rows
    return FramePattern(-hx + (np.arange(cols) + 0.5) * du, -hy + (np.arange(rows) + 0.5) * dv, du, dv)


def project(P: np.ndarray) -> np.ndarray:
    """Normalized image coordinates ``(P_x/P_z, P_y/P_z)`` of points (… × 3) in an optical frame."""
    return P[..., :2] / P[..., 2:3]


def _dproject(P: np.ndarray) -> np.ndarray:
    """``∂π/∂P`` (… × 2 × 3)."""
    z = P[..., 2]
    out = np.zeros(P.shape[:-1] + (2, 3))
    out[..., 0, 0] = out[..., 1, 1] = 1.0 / z
    out[..., 0, 2] = -P[..., 0] / z**2
    out[..., 1, 2] = -P[..., 1] / z**2
    return out


def _skew(v: np.ndarray) -> np.ndarray:
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def in_frame_j(P_i: np.ndarray, R_ij: np.ndarray, t_ij: np.ndarray) -> np.ndarray:
    """Landmarks ``P_i`` (… × 3, in S_i) in frame j's optical frame: ``R_ijᵀ (P_i − t_ij)``."""
    return np.einsum("...kj,...k->...j", R_ij, P_i - t_ij)


def jacobians(P_i: np.ndarray, R_ij: np.ndarray, t_ij: np.ndarray) -> np.ndarray:
    """Each landmark's rows ``[u_i; u_j]`` over ``[X, φ, ρ]`` (N × 4 × 9; see the module docstring)."""
    P_i = np.asarray(P_i, float)
    R_ij = np.broadcast_to(np.asarray(R_ij, float), P_i.shape[:-1] + (3, 3))
    P_j = in_frame_j(P_i, R_ij, np.asarray(t_ij, float))
    Di, Dj = _dproject(P_i), _dproject(P_j)
    J = np.zeros(P_i.shape[:-1] + (4, 9))
    J[..., :2, :3] = Di
    J[..., 2:, :3] = Dj @ np.swapaxes(R_ij, -1, -2)
    J[..., 2:, 3:6] = Dj @ _skew(P_j)
    J[..., 2:, 6:] = -Dj
    return J


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def epipolar_rows(P_i: np.ndarray, R_ij: np.ndarray, t_ij: np.ndarray, sigma: float) -> np.ndarray:
    """Each landmark's whitened epipolar row (N × 6): ``g`` with ``g gᵀ`` its information about δ,
    its position eliminated. The constraint ``e = f_i · (t_ij × R_ij f_j)`` on the rays ``f = (u,
    1)`` holds whatever the landmark's depth; its noise is the bearings' carried through it
    (``σ² (|∂e/∂u_i|² + |∂e/∂u_j|²)``), its row ``∂e/∂δ``. This equals the Schur complement of
    the landmark's four rows (the one direction of the observations its position cannot absorb)."""
    P_i = np.asarray(P_i, float)
    R = np.broadcast_to(np.asarray(R_ij, float), P_i.shape + (3,))
    t = np.broadcast_to(np.asarray(t_ij, float), P_i.shape)
    f_i = P_i / P_i[..., 2:3]
    P_j = in_frame_j(P_i, R, t)
    f_j = P_j / P_j[..., 2:3]
    g = np.einsum("...ij,...j->...i", R, f_j)  # frame j's ray in S_i
    fit = _cross(f_i, t)
    de_ui = _cross(t, g)[..., :2]
    de_uj = np.einsum("...ji,...j->...i", R, fit)  # Rᵀ (f_i × t)
    d_phi = _cross(f_j, de_uj)
    d_rho = np.einsum("...ji,...j->...i", R, _cross(g, f_i))
    noise = sigma**2 * (np.sum(de_ui**2, axis=-1) + np.sum(de_uj[..., :2] ** 2, axis=-1))
    row = np.concatenate([d_phi, d_rho], axis=-1)
    return row / np.sqrt(np.where(noise > 0, noise, np.inf))[..., None]


def eliminated(P_i: np.ndarray, R_ij: np.ndarray, t_ij: np.ndarray, sigma: float) -> np.ndarray:
    """Each landmark's information about ``δ = [φ, ρ]`` with its position eliminated (N × 6 × 6):
    ``g gᵀ`` of its epipolar row (:func:`epipolar_rows`, rank 1; zero without parallax)."""
    g = epipolar_rows(np.asarray(P_i, float).reshape(-1, 3), R_ij, t_ij, sigma)
    return g[:, :, None] * g[:, None, :]


def with_length(A: np.ndarray, R_ij: np.ndarray, t_ij: np.ndarray) -> np.ndarray:
    """``A`` (… × 6 × 6, bearing information about δ of pairs ``R_ij, t_ij``) with the
    information along each pair's scale direction ``[0, R_ijᵀ t̂_ij]``: the mean of its other
    two translation directions' marginal information (see the module docstring)."""
    A = np.array(A, float)
    t = np.asarray(t_ij, float)
    norm = np.linalg.norm(t, axis=-1, keepdims=True)
    e = np.einsum("...kj,...k->...j", np.asarray(R_ij, float), t / np.where(norm > 0, norm, 1.0))
    C = A[..., 3:, 3:] - A[..., 3:, :3] @ np.linalg.pinv(A[..., :3, :3], rcond=1e-12, hermitian=True) @ A[..., :3, 3:]
    s = 0.5 * (np.trace(C, axis1=-2, axis2=-1) - np.einsum("...i,...ij,...j->...", e, C, e))
    s = np.where(norm[..., 0] > 0, np.maximum(s, 0.0), 0.0)
    A[..., 3:, 3:] += s[..., None, None] * e[..., :, None] * e[..., None, :]
    return A


def pair_information(P_i: np.ndarray, R_ij: np.ndarray, t_ij: np.ndarray, sigma: float,
                     weights: np.ndarray | None = None) -> np.ndarray:
    """The information of a frame pair's bearings of landmarks ``P_i`` (N × 3, in S_i, each
    ``weights`` features) about ``δ`` (6 × 6, [rotation, translation], right perturbation of
    ``T_ij`` in S_j), the landmarks eliminated and the length along the scale direction added
    (:func:`with_length`)."""
    S = eliminated(P_i, R_ij, t_ij, sigma)
    w = np.ones(S.shape[0]) if weights is None else np.asarray(weights, float)
    return with_length(np.einsum("n,nij->ij", w, S), R_ij, t_ij)


def waterfill(expected: np.ndarray, share: np.ndarray, group: np.ndarray, budget: float, groups: int) -> np.ndarray:
    """Counts ``expected`` of cells, each a ``share`` of its frame's image, capped at a common
    level of features per image (the same for every cell of a ``group``: a frame) so that each
    frame holds at most ``budget``: cells under the level keep theirs, the others hold it."""
    e = np.maximum(np.asarray(expected, float), 0.0)
    out = e.copy()
    totals = np.bincount(group, weights=e, minlength=groups)
    for g in np.flatnonzero(totals > budget):
        k = np.flatnonzero(group == g)
        q = e[k] / share[k]  # features per image
        order = np.argsort(q)
        qs, a = q[order], share[k][order]
        below = np.concatenate([[0.0], np.cumsum(qs * a)[:-1]])  # cells under qs[i]: all they have
        above = np.cumsum(a[::-1])[::-1]  # the image share of the cells from i on
        total = below + qs * above  # the frame's sum with the level at qs[i]
        i = int(np.searchsorted(total, budget))
        level = (budget - below[i]) / above[i]
        out[k] = np.minimum(e[k], level * share[k])
    return out


@dataclass(frozen=True)
class Pairs:
    """Frame pairs ray-cast: each pair's information about its relative pose (``H``, P × 6 × 6,
    [rotation, translation], a right perturbation of ``T_ij`` in S_j) and the features it tracks
    from frame i to frame j (``features``, expected counts)."""

    H: np.ndarray
    features: np.ndarray


@dataclass(frozen=True)
class _Rays:
    """Rays of frame i cast into the scene, flat over the pairs: the pair of each (``pair``), its
    direction in S_i (``d``), its range (``r``), the surface it found (−1: none, or one it sees
    too obliquely or out of range), that surface's normal in W, its cell's share of the image
    (``share``), the features expected in the cell (``expected``) and whether the cell's
    footprint is one plane within range (``whole``: not an edge)."""

    pair: np.ndarray
    d: np.ndarray
    r: np.ndarray
    surface: np.ndarray
    normal: np.ndarray
    share: np.ndarray
    expected: np.ndarray
    whole: np.ndarray


def _cast(scene: Scene, R: np.ndarray, p: np.ndarray, pair: np.ndarray, u: np.ndarray, v: np.ndarray,
          du: float, dv: float, share: float, optics: CameraOptics, per_m2: np.ndarray) -> _Rays:
    """Cast the cells centred at ``u, v`` (normalized image coordinates, each of pair ``pair``,
    frames at ``R, p``): a cell's features are its surface's density × its footprint on the
    plane its central ray meets, the quadrilateral where the plane meets its four corner rays
    (exact for a plane); where a corner misses the plane, leaves the range or meets it too
    obliquely, the footprint is ``Δω r² / |cos θ|`` of the central ray and the cell an edge."""
    qn = np.sqrt(u * u + v * v + 1.0)
    d = np.stack([u / qn, v / qn, 1.0 / qn], axis=1)
    Rp = R[pair]
    d_W = np.einsum("nij,nj->ni", Rp, d)
    hits = scene.cast(p[pair], d_W, optics.max_range_m)
    n_S = np.einsum("nji,nj->ni", Rp, hits.normal)  # the normal in S_i
    nx, ny, nz = n_S[:, 0], n_S[:, 1], n_S[:, 2]
    nd = (nx * u + ny * v + nz) / qn  # n·d
    cos = np.abs(nd)
    ok = hits.hit & (hits.distance >= optics.min_range_m) & (cos >= MIN_INCIDENCE_COS)
    surface = np.where(ok, hits.surface, -1)
    c = hits.distance * nd  # the plane n·X = c (c < 0: n faces the camera)
    corners = []
    whole = ok.copy()
    for su, sv in ((-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)):
        uc, vc = u + su * du, v + sv * dv
        nq = nx * uc + ny * vc + nz
        lam = np.where(nq < 0, c / np.where(nq < 0, nq, -1.0), -1.0)
        norm = np.sqrt(uc * uc + vc * vc + 1.0)
        rng = lam * norm
        whole &= ((lam > 0) & (rng <= optics.max_range_m) & (rng >= optics.min_range_m)
                  & (np.abs(nq) >= MIN_INCIDENCE_COS * norm))
        corners.append((uc * lam, vc * lam, lam))
    (x0, y0, z0), (x1, y1, z1), (x2, y2, z2), (x3, y3, z3) = corners
    ax, ay, az = x2 - x0, y2 - y0, z2 - z0  # the quadrilateral's diagonals
    bx, by, bz = x3 - x1, y3 - y1, z3 - z1
    quad = 0.5 * np.sqrt((ay * bz - az * by) ** 2 + (az * bx - ax * bz) ** 2 + (ax * by - ay * bx) ** 2)
    point = du * dv / qn**3 * hits.distance**2 / np.maximum(cos, MIN_INCIDENCE_COS)
    area = np.where(whole, quad, point)
    expected = np.where(ok, per_m2[np.maximum(surface, 0)] * area, 0.0)
    return _Rays(pair, d, hits.distance, surface, hits.normal, np.full(u.size, share), expected, whole)


def _pair_sums(rows: np.ndarray, pair: np.ndarray, m: int) -> np.ndarray:
    """``Σ r rᵀ`` of the rows (N × k) of each of ``m`` pairs (m × k × k)."""
    k = rows.shape[1]
    out = np.zeros((m, k, k))
    for i in range(k):
        for j in range(i, k):
            out[:, i, j] = out[:, j, i] = np.bincount(pair, weights=rows[:, i] * rows[:, j], minlength=m)
    return out


def informations(scene: Scene, R_W_Si: np.ndarray, p_W_Si: np.ndarray, R_W_Sj: np.ndarray, p_W_Sj: np.ndarray,
                 optics: CameraOptics, density: float = 1.0) -> Pairs:
    """The information of the frame pairs ``i → j`` whose optical frames are at ``R_W_Si,
    p_W_Si`` and ``R_W_Sj, p_W_Sj`` (P × 3 × 3, P × 3) in ``scene`` (see the module docstring),
    :data:`PAIRS_PER_CALL` pairs at a time.

    A cell's features are counted on its footprint (:func:`_cast`); the grid is refined at edges:
    a cell that sees another surface than one of its four neighbours (or a surface where the
    neighbour sees none: an outline, the horizon, the end of the range) or whose footprint is
    not one plane within range is cast again with :data:`REFINE` × :data:`REFINE` rays, which
    take over its share."""
    R_i = np.asarray(R_W_Si, float).reshape(-1, 3, 3)
    p_i = np.asarray(p_W_Si, float).reshape(-1, 3)
    R_j = np.asarray(R_W_Sj, float).reshape(-1, 3, 3)
    p_j = np.asarray(p_W_Sj, float).reshape(-1, 3)
    grid = pattern(optics, density)
    C, Rw = grid.cols, grid.rows
    n = C * Rw
    P = R_i.shape[0]
    H = np.zeros((P, 6, 6))
    features = np.zeros(P)
    per_m2 = np.array([s.features_per_m2 for s in scene.surfaces])
    hx, hy = optics.half_extent
    sigma = optics.bearing_sigma
    U, V = np.meshgrid(grid.u, grid.v, indexing="ij")
    sub = (np.arange(REFINE) + 0.5) / REFINE - 0.5
    SU, SV = np.meshgrid(sub * grid.du, sub * grid.dv, indexing="ij")
    SU, SV = SU.ravel(), SV.ravel()
    fields = ("pair", "d", "r", "normal", "share", "expected")
    def chunk(a: int) -> None:
        b = min(P, a + PAIRS_PER_CALL)
        m = b - a
        Ra, pa = R_i[a:b], p_i[a:b]
        base = _cast(scene, Ra, pa, np.repeat(np.arange(m), n), np.tile(U.ravel(), m), np.tile(V.ravel(), m),
                     grid.du, grid.dv, 1.0 / n, optics, per_m2)
        sid = base.surface.reshape(m, C, Rw)
        refine = (~base.whole & (base.surface >= 0)).reshape(m, C, Rw)
        for axis in (1, 2):
            lo = [slice(None)] * 3
            hi = [slice(None)] * 3
            lo[axis], hi[axis] = slice(None, -1), slice(1, None)
            differ = sid[tuple(lo)] != sid[tuple(hi)]
            refine[tuple(lo)] |= differ
            refine[tuple(hi)] |= differ
        keep = ~refine.ravel()
        cat = {f: getattr(base, f)[keep] for f in fields}
        if refine.any():
            km, kc, kr = np.nonzero(refine)
            fine = _cast(scene, Ra, pa, np.repeat(km, REFINE**2), (grid.u[kc][:, None] + SU).ravel(),
                         (grid.v[kr][:, None] + SV).ravel(), grid.du / REFINE, grid.dv / REFINE,
                         1.0 / (n * REFINE**2), optics, per_m2)
            cat = {f: np.concatenate([cat[f], getattr(fine, f)]) for f in fields}
        count = waterfill(cat["expected"], cat["share"], cat["pair"], float(optics.max_features), m)
        # frame j: the same landmarks, inside its image and range, facing it and not hidden
        live = np.flatnonzero(count > 0)
        pr = cat["pair"][live]
        R_ij = np.swapaxes(Ra, 1, 2) @ R_j[a:b]
        t_ij = np.einsum("mkj,mk->mj", Ra, p_j[a:b] - pa)
        P_i = cat["d"][live] * cat["r"][live, None]
        P_j = in_frame_j(P_i, R_ij[pr], t_ij[pr])
        z = P_j[:, 2]
        zs = np.where(z > 0, z, 1.0)
        rj = np.linalg.norm(P_j, axis=1)
        to_j = pa[pr] + np.einsum("nij,nj->ni", Ra[pr], P_i) - p_j[a:b][pr]
        seen = ((z > 0) & (np.abs(P_j[:, 0]) <= hx * zs) & (np.abs(P_j[:, 1]) <= hy * zs)
                & (rj >= optics.min_range_m) & (rj <= optics.max_range_m)
                & (np.sum(cat["normal"][live] * to_j, axis=1) < 0))
        k = np.flatnonzero(seen)
        if k.size:
            back = scene.cast(p_j[a:b][pr[k]], to_j[k] / rj[k, None], rj[k] + 1.0)
            seen[k[back.distance < rj[k] - (0.02 + 1e-3 * rj[k])]] = False
        live, P_i, pr = live[seen], P_i[seen], pr[seen]
        w = count[live]
        features[a:b] = np.bincount(pr, weights=w, minlength=m)
        g = epipolar_rows(P_i, R_ij[pr], t_ij[pr], sigma) * np.sqrt(w)[:, None]
        A = _pair_sums(g, pr, m)
        H[a:b] = with_length(A, R_ij, t_ij)

    each(chunk, range(0, P, PAIRS_PER_CALL))  # chunks on threads (Embree and numpy release the GIL)
    return Pairs(H=H, features=features)
