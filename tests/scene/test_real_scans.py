"""A real lidar scan pair no one here wrote: excite's registration information against small_gicp's.

The data: ``../shared/data/lidar_scan_pair_small_gicp/`` (``source.ply``, ``target.ply``, two
consecutive scans of 69,792 and 69,088 points, and ``T_target_source.txt``, the source scan's
pose in the target's frame) is the test data of the registration library small_gicp
(koide3/small_gicp, ``data/``), under the MIT licence (its copy in that folder's ``LICENSE``).
The scans are read by excite's PLY reader (:func:`excite.scene.clouds.read_points`); the points
stored at the origin (5,032 of the target's, the scanner's marks of beams without a return) are
not returns and are dropped. small_gicp estimates the target's normals (its 20 nearest
neighbours), and each source point is matched to its nearest target point at the ground-truth
transform T (within 1 m), the target's normal ``n_t`` turned into the source frame,
``m = Rᵀ n_t``.

**Why a rotation per point.** small_gicp's ``PLANE_ICP`` residual is ``n ⊙ (q − T p)`` (a vector,
per axis of the target frame), so its per-point Hessian is ``Aᵀ diag(n²) A`` with ``A`` the
derivative of ``T p`` by the right perturbation; the classical point-to-plane residual
``nᵀ(q − T p)`` whose Hessian excite sums (``[p × m; m][p × m; m]ᵀ``,
:func:`excite.scene.lidar.point_information`) has ``n nᵀ`` in its place. The two are equal where
the normal lies along an axis of the target frame, and a rotation Q of the target frame changes
neither the residual's distance nor the right perturbation (which lives in the source frame). So
for every point the comparison is made in its own target frame turned so that its normal is the z
axis: the point's 20 target neighbours rotated by Q, small_gicp's normal estimated on them again
(the same neighbourhood: the same normal, Q n, to rounding), and small_gicp's
``PointToPlaneICPFactor.linearize`` evaluated at ``Q T`` gives that point's Hessian. Their sum
over the points is excite's information of the same points and normals (σ = 1).

**small_gicp's own registration** (as it registers this pair itself: 0.25 m voxels, from the
identity) lands 1.6 cm and 0.14° from the given transform; its Hessian at its solution is exactly excite's rows with small_gicp's per-axis
weights — ``Σ_k point_information(p, Rᵀ e_k, weights n_k²)`` over its inliers — and differs from
the classical information by what per-axis weighting makes of normals that are not along the
frame's axes (measured here, not a property of the scene).
"""

from __future__ import annotations

import numpy as np
import pytest

from excite.scene import lidar
from excite.scene.clouds import read_points

small_gicp = pytest.importorskip("small_gicp")

NEIGHBOURS = 20
MAX_DISTANCE_M = 1.0
COMPARED = 10_000
"""Source points compared one by one in their own rotated frame (a random choice of them)."""


def _to_z(n: np.ndarray) -> np.ndarray:
    """A rotation taking the unit vector ``n`` to the z axis."""
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(n, z)
    s, c = np.linalg.norm(v), float(n @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K * ((1.0 - c) / s**2)


@pytest.fixture(scope="module")
def pair(data_dir):
    folder = data_dir / "lidar_scan_pair_small_gicp"
    if not folder.is_dir():
        pytest.skip(f"the real scan pair is not at {folder} (CI always has it)")
    src = read_points(folder / "source.ply").points
    tgt = read_points(folder / "target.ply").points
    assert src.shape == (69792, 3) and tgt.shape == (69088, 3)
    T = np.loadtxt(folder / "T_target_source.txt")
    src = src[np.any(src != 0.0, axis=1)]
    tgt = tgt[np.any(tgt != 0.0, axis=1)]
    target = small_gicp.PointCloud(tgt)
    tree = small_gicp.KdTree(target, num_threads=2)
    small_gicp.estimate_normals(target, tree, num_neighbors=NEIGHBOURS, num_threads=2)
    return src, tgt, T, target, tree


def _matches(src, T, target, tree):
    """Each source point's nearest target point at T and whether it is within the distance."""
    q = src @ T[:3, :3].T + T[:3, 3]
    idx, d2 = tree.batch_nearest_neighbor_search(q)
    return np.asarray(idx), np.asarray(d2) <= MAX_DISTANCE_M**2


@pytest.mark.slow
def test_information_of_the_real_pair_equals_small_gicps_point_by_point(pair):
    src, tgt, T, target, tree = pair
    assert tgt.shape[0] == 69088 - 5032
    R = T[:3, :3]
    idx, near = _matches(src, T, target, tree)
    normals = target.normals()[:, :3]
    factor, rejector = small_gicp.PointToPlaneICPFactor(), small_gicp.DistanceRejector()
    rejector.set_max_distance(MAX_DISTANCE_M)
    chosen = np.sort(np.random.default_rng(0).choice(np.flatnonzero(near), COMPARED, replace=False))
    neighbours = np.asarray(tree.batch_knn_search(tgt[idx[chosen]], NEIGHBOURS)[0])
    theirs = np.zeros((6, 6))
    for k, i in enumerate(chosen):
        Q = _to_z(normals[idx[i]])
        local = small_gicp.PointCloud(tgt[neighbours[k]] @ Q.T)
        local_tree = small_gicp.KdTree(local)
        small_gicp.estimate_normals(local, local_tree, num_neighbors=NEIGHBOURS)
        QT = np.eye(4)
        QT[:3, :3], QT[:3, 3] = Q @ R, Q @ T[:3, 3]
        ok, H_i, _, _ = factor.linearize(local, small_gicp.PointCloud(src[i:i + 1]), local_tree, QT, 0, rejector)
        assert ok
        theirs += H_i
    ours = lidar.point_information(src[chosen], normals[idx[chosen]] @ R, 1.0)
    rel = np.abs(ours - theirs).max() / np.abs(ours).max()
    print(f"excite's information against small_gicp's over {COMPARED} points: {rel:.1e} relative")
    assert rel < 1e-6, rel
    # and the information is the scan's: full rank, every direction seen
    lam = np.linalg.eigvalsh(ours)
    assert lam[0] > 1e-4 * lam[-1]


@pytest.mark.slow
def test_small_gicps_registration_of_the_real_pair(pair):
    """As small_gicp registers this pair itself (its preprocessing: 0.25 m voxels, normals of 10
    neighbours), from the identity."""
    from excite.core import so3

    src, tgt, T, _, _ = pair
    target, tree = small_gicp.preprocess_points(tgt, downsampling_resolution=0.25, num_threads=2)
    source, _ = small_gicp.preprocess_points(src, downsampling_resolution=0.25, num_threads=2)
    res = small_gicp.align(target, source, tree, registration_type="PLANE_ICP",
                           max_correspondence_distance=MAX_DISTANCE_M, num_threads=2)
    That = res.T_target_source
    dp = np.linalg.norm(That[:3, 3] - T[:3, 3])
    dr = np.degrees(np.linalg.norm(so3.log(T[:3, :3].T @ That[:3, :3])))
    print(f"small_gicp's registration from the given transform: {100 * dp:.2f} cm, {dr:.3f} deg")
    assert dp < 0.02 and dr < 0.2
    # its Hessian at its solution: excite's rows with small_gicp's per-axis weights, exactly
    p = source.points()[:, :3]
    idx, near = _matches(p, That, target, tree)
    assert int(near.sum()) == res.num_inliers
    R = That[:3, :3]
    n = target.normals()[idx[near], :3]
    per_axis = sum(lidar.point_information(p[near], np.broadcast_to(R.T[:, k], (int(near.sum()), 3)), 1.0,
                                           n[:, k] ** 2) for k in range(3))
    factor, rejector = small_gicp.PointToPlaneICPFactor(), small_gicp.DistanceRejector()
    rejector.set_max_distance(MAX_DISTANCE_M)
    H = np.zeros((6, 6))
    for i in range(source.size()):
        ok, H_i, _, _ = factor.linearize(target, source, tree, That, i, rejector)
        assert ok == near[i]
        H += H_i
    rel = np.abs(per_axis - H).max() / np.abs(H).max()
    print(f"small_gicp's Hessian at its solution against excite's rows with its per-axis weights: {rel:.1e}")
    assert rel < 1e-9
    # (the Hessian it reports is its last linearisation's, one step before the solution)
    assert np.abs(np.asarray(res.H) - H).max() < 1e-4 * np.abs(H).max()
    # the classical information of the same points and normals differs from it on the diagonal by
    # what per-axis weighting makes of these normals
    classical = lidar.point_information(p[near], n @ R, 1.0)
    ratio = np.diag(classical) / np.diag(H)
    print("classical / small_gicp's per-axis diagonal:", np.round(ratio, 3))
    assert np.all((ratio > 0.5) & (ratio < 2.0))
