"""Scans ray-cast in a scene and registered by small_gicp, against the information the scene
model predicts: the Monte Carlo of tests/scene/test_registration_*.py (one module per scene, so
that the test workers share them).

**What the model states** (:mod:`excite.scene.lidar`): a scan whose returns lie off their
surfaces by σ along the normal holds ``H = Σ [p × n; n][p × n; n]ᵀ / σ²`` about its pose
against the surfaces it sees, the surfaces themselves taken as exact — what the earlier scan, or
the local map an odometry keeps, holds of them.

**The simulator** is more physical than that. Scan j is ray-cast (:meth:`Scene.cast
<excite.scene.model.Scene.cast>`, occlusion honoured) on a dense pattern, rays 0.7° apart in
elevation and azimuth over the VLP-32C's vertical field, from a pose 0.1 s along a drive from
scan i's (8 m/s, turning at 0.2 rad/s); returns are dropped as the model drops them (range
limits, incidence beyond :data:`~excite.scene.lidar.MIN_INCIDENCE_COS`). Every return's error
lies along its **ray**, as a lidar measures, not along the normal: a range error of ``σ/c``
(``c = |n · d|``, the cosine of the incidence; σ the lidar's ``range_noise_m``, 3 cm) — the
footprint that stretches over a surface met obliquely spreads the return along the ray, so that
the point's distance off the surface is σ at every incidence, the model's law. The point then
also slides along its surface (up to 30 cm at the steepest incidence kept), across edges and
past the ends of façades, which the model does not count. The target is the map scan i's
surfaces make: the scene ray-cast from scan i's pose on a pattern fourteen times finer (0.05°),
without noise; small_gicp estimates its normals from 20 neighbours, finds each source point's nearest map
point, and registers by its ``PLANE_ICP`` from an initial guess drawn about the truth (0.3° and
3 cm per axis, the motion prior an odometry starts from). The error is the right perturbation
``δ = [φ, ρ]`` of the estimated pose of scan j in scan i's frame.

What it shows (200 registrations per scene; ``pytest -s`` prints the NEES with its interval, the
spread along each axis against the model's σ and the mean error): in the lot with buildings on one
side and in the street canyon the NEES of the errors against ``H⁻¹`` is inside its 95 % interval.

**The map must be fine enough to stand for the surfaces.** The model takes scan i's surfaces as
exact. A façade met at grazing incidence is sampled sparsely along the street by any ray pattern
(rays 0.1° apart land tens of centimetres apart on it at 30 m), and the returns of scan j, which
slide along it with their range error, meet their nearest map points unevenly: with the map cast
0.1° apart, one of the canyon's four poses was biased along the street by 1.3 σ in every draw
(NEES 6.6 for an interval ending at 6.49). The bias goes with the map's spacing (0.07°: 0.1 σ;
0.05°: under 0.1 σ) and with the slide (errors along the normal instead of the ray: 0.3 σ on the
0.1° map); dropping the few returns that slide off their face altogether leaves it (1.05 σ). It is
the map's sampling, not information the scene lacks.

**Registering against the earlier scan itself** — noisy, sampled on the same pattern — is another
matter: its noisy normals and nearest points pull the estimate towards no motion along the
directions the scene constrains least, by centimetres per pair (tens of σ): no information model
holds that. The model is that of registration against a map.

**The tunnel** leaves the translation along its axis without information: ``H``'s row for it is
exactly zero (every normal is across the axis), and so the pair's information along it is zero,
the drift's included. small_gicp's estimate along the axis follows neither the motion nor its
initial guess: nothing holds it, and it slides, iteration after iteration, wherever the map's
sampling lets it (centimetres, more than the guess's spread, where information would hold it to
millimetres), while the directions across the axis are registered to about their σ.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from excite.core import so3
from excite.factors.optics import LIDAR_PRESETS
from excite.scene import lidar
from excite.scene.files import load_scene

small_gicp = pytest.importorskip("small_gicp")


BEAMS = LIDAR_PRESETS["vlp32c"]
SIGMA = BEAMS.range_noise_m
STEP_DEG = 0.7
MAP_STEP_DEG = 0.05
DT = 0.1
SPEED = 8.0
YAW_RATE = 0.2
PRIOR = np.array([math.radians(0.3)] * 3 + [0.03] * 3)
NEIGHBOURS = 20
DRAWS = 50


def dense_pattern(beams, step_deg: float) -> np.ndarray:
    """Rays ``step_deg`` apart in elevation (over the lidar's vertical field) and azimuth."""
    lo, hi = np.degrees(beams.elevations_rad[[0, -1]])
    el = np.radians(np.arange(lo, hi + 1e-9, step_deg))
    az = np.radians(np.arange(0.0, 360.0, step_deg))
    E, A = np.meshgrid(el, az, indexing="ij")
    return np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1).reshape(-1, 3)


RAYS = dense_pattern(BEAMS, STEP_DEG)


def cast(scene, R, p, rays=RAYS, rng=None):
    """A scan from ``R, p``: its points in S and their surfaces' normals in S; with ``rng``, each
    return's range off by ``σ/c`` along its ray (``c`` the cosine of its incidence)."""
    d_W = rays @ R.T
    hits = scene.cast(np.broadcast_to(p, d_W.shape), d_W, BEAMS.max_range_m)
    ok = hits.hit & (hits.distance >= BEAMS.min_range_m) & (hits.cos >= lidar.MIN_INCIDENCE_COS)
    r = hits.distance[ok]
    if rng is not None:
        r = r + rng.normal(0.0, 1.0, r.size) * SIGMA / hits.cos[ok]
    return rays[ok] * r[:, None], hits.normal[ok] @ R


def pose(R, p):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def right_error(T, T_hat):
    """``δ = [φ, ρ]`` with ``T_hat = T ⊞ δ`` (rotation ``R Exp(φ)``, translation ``t + R ρ``)."""
    R = T[:3, :3]
    return np.r_[so3.log(R.T @ T_hat[:3, :3]), R.T @ (T_hat[:3, 3] - T[:3, 3])]


def perturbed(T, d):
    out = T.copy()
    out[:3, :3] = T[:3, :3] @ so3.exp(d[:3])
    out[:3, 3] = T[:3, 3] + T[:3, :3] @ d[3:]
    return out


def surface_map(scene, R, p):
    """The map of what scan i's pose sees: the scene ray-cast on the fine pattern without noise,
    its normals estimated by small_gicp."""
    points, _ = cast(scene, R, p, dense_pattern(BEAMS, MAP_STEP_DEG))
    cloud = small_gicp.PointCloud(points)
    tree = small_gicp.KdTree(cloud, num_threads=2)
    small_gicp.estimate_normals(cloud, tree, num_neighbors=NEIGHBOURS, num_threads=2)
    return cloud, tree


def register(surfaces, source, T0, tolerance):
    """small_gicp's registration of ``source`` to the map ``surfaces`` from ``T0``; it must end
    within ``tolerance`` (per coordinate; infinite along what the scan does not see) of its
    minimum."""
    cloud, tree = surfaces
    res = small_gicp.align(cloud, small_gicp.PointCloud(source), tree, init_T_target_source=T0,
                           registration_type="PLANE_ICP", max_correspondence_distance=1.0, num_threads=2,
                           max_iterations=100, rotation_epsilon=1e-7, translation_epsilon=1e-6)
    # small_gicp's Levenberg-Marquardt may stop on its damping before its step criterion: what
    # matters is that it stopped at the minimum, where a Gauss-Newton step moves nothing
    if tolerance is None:
        return res.T_target_source
    seen = np.isfinite(tolerance)
    step = np.linalg.solve(np.asarray(res.H)[np.ix_(seen, seen)], np.asarray(res.b).ravel()[seen])
    assert np.all(np.abs(step) < tolerance[seen]), (res, step)
    return res.T_target_source


def yaw(a):
    return so3.exp(np.array([0.0, 0.0, a]))


def monte_carlo(scene, starts, draws, seed, speed=SPEED, yaw_rate=YAW_RATE, converged=True):
    """Per start pose (scan i's): the pair's truth, the model's ``H`` of scan j and its σ, and each
    draw's error."""
    rng = np.random.default_rng(seed)
    out = []
    for R_i, p_i in starts:
        R_j = R_i @ yaw(yaw_rate * DT)
        p_j = p_i + R_i @ np.array([speed * DT, 0.0, 0.0])
        T = np.linalg.inv(pose(R_i, p_i)) @ pose(R_j, p_j)
        H = lidar.point_information(*cast(scene, R_j, p_j), SIGMA)
        seen = np.diag(H) > 0
        sigma = np.full(6, np.inf)
        sigma[seen] = np.sqrt(np.diag(np.linalg.inv(H[np.ix_(seen, seen)])))
        surfaces = surface_map(scene, R_i, p_i)
        err = []
        for _ in range(draws):
            source, _ = cast(scene, R_j, p_j, rng=rng)
            d0 = rng.normal(0.0, PRIOR)
            # it ends within a tenth of the model's σ of its minimum (along what is seen)
            err.append(right_error(T, register(surfaces, source, perturbed(T, d0), 0.1 * sigma if converged else None)))
        out.append(dict(T=T, H=H, sigma=sigma, err=np.array(err)))
    return out


def nees(runs):
    """The mean NEES of the errors against ``H⁻¹``, the number of errors and the χ² 95 % interval
    of that mean."""
    total = sum(float(np.einsum("ij,jk,ik->", r["err"], r["H"], r["err"])) for r in runs)
    n = sum(r["err"].shape[0] for r in runs)
    lo, hi = chi2.ppf([0.025, 0.975], 6 * n) / n
    return total / n, n, (lo, hi)


def report(name, runs):
    m, n, (lo, hi) = nees(runs)
    print(f"\n{name}: NEES against H⁻¹: {m:.2f} over {n} registrations (95 % interval {lo:.2f} … {hi:.2f})")
    spread = np.array([r["err"].std(axis=0, ddof=1) / r["sigma"] for r in runs])
    bias = np.array([r["err"].mean(axis=0) / r["sigma"] for r in runs])
    print(f"{name}: spread / the model's σ per axis [φx φy φz ρx ρy ρz], per pose:\n{np.round(spread, 2)}")
    print(f"{name}: mean error / the model's σ, per pose:\n{np.round(bias, 2)}")
    return m, n, (lo, hi), spread, bias
