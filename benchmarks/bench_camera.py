"""The camera's scene information: its consistency with two-view bundle adjustment, its
quadrature and sampling, its cost, and what scenes do to the robotaxi's camera.

    python benchmarks/bench_camera.py [--trials 1000]

Figures (benchmarks/results/camera.json):

- ``nees``: the mean NEES (5 directions, the scale held) of two-view bundle adjustments of noisy
  pixels (1 px; ``tests/two_view.py``) against the covariance the eliminated information
  predicts, two landmark sets per geometry: 40 landmarks 4–30 m away on a ground and a wall
  (with and without 10 more 150–300 m ahead), and landmarks only far ahead (20–40 m, 100–200 m;
  a metre of baseline, and 5 cm), beside the χ² 95 % interval of the mean;
- ``quadrature_max_relative``: the largest relative difference of a cam_front σ on the 90 s slalom
  between the default grid and one with 3× the columns and rows, in a lot of sparse texture
  (asphalt, 0.01 features/m²) with and without buildings;
- ``sampling_max_relative``: the same between the default samples along the drive and a sample
  at every keyframe;
- ``pairs_cpu_ms_per_pair``, ``rays_per_pair``: the cost of the camera's pairs along the 10-minute
  drive of ``bench_evaluate`` in the street canyon of ``bench_scene``;
- ``slalom_camera_sigma_over_target``: the 90 s slalom's cam_front σ/target blind and in scenes.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import two_view  # noqa: E402
from bench_evaluate import generated  # noqa: E402
from results import Session, load_average  # noqa: E402
from scenes import canyon_around, lot_with_buildings, slalom_drive  # noqa: E402
from scenes import lot as lot_ground  # noqa: E402

from excite.core import so3  # noqa: E402
from excite.factors.optics import DEFAULT_CAMERA  # noqa: E402
from excite.rig.config import load_rig  # noqa: E402
from excite.scene import along, camera  # noqa: E402
from excite.scene.files import load_scene  # noqa: E402
from excite.scene.model import Scene  # noqa: E402
from excite.score.evaluate import evaluate  # noqa: E402


def consistency(trials: int) -> dict:
    """Mean NEES of two-view bundle adjustments in geometries within and beyond the bound's reach."""
    R = so3.exp(np.array([0.01, 0.04, -0.02]))
    step = np.array([0.15, -0.05, 1.0])
    sigma = DEFAULT_CAMERA.bearing_sigma
    lo, hi = chi2.ppf([0.025, 0.975], 5 * trials) / trials
    out: dict = {"interval": [round(lo, 3), round(hi, 3)], "trials_per_set": trials}

    def ahead(rng, near, far, n=40):
        d = rng.uniform(near, far, n)
        return np.column_stack([rng.uniform(-0.8, 0.8, n) * d, rng.uniform(-0.5, 0.5, n) * d, d])

    cases = {
        "ground and wall 4-30 m, 1 m baseline": (lambda rng: two_view.landmarks(rng), 1.0),
        "the same and 10 landmarks 150-300 m ahead": (lambda rng: np.vstack([two_view.landmarks(rng), np.column_stack(
            [rng.uniform(-2, 2, 10), rng.uniform(-1, 0.5, 10), rng.uniform(150, 300, 10)])]), 1.0),
        "only landmarks 20-40 m ahead, 1 m baseline": (lambda rng: ahead(rng, 20, 40), 1.0),
        "only landmarks 100-200 m ahead, 1 m baseline": (lambda rng: ahead(rng, 100, 200), 1.0),
        "only landmarks 20-40 m ahead, 5 cm baseline": (lambda rng: ahead(rng, 20, 40), 0.05),
    }
    for name, (make, scale) in cases.items():
        t = step * scale
        means = []
        for seed in (1, 2):
            rng = np.random.default_rng(seed)
            X = make(rng)
            A = camera.eliminated(X, R, t, sigma).sum(axis=0)
            means.append(round(float(two_view.nees(X, R, t, sigma, A, trials, rng).mean()), 3))
        out[name] = means
        print(f"{name}: mean NEES {means} (95 % interval {lo:.3f} … {hi:.3f})")
    return out


def camera_sigmas(traj, rig) -> np.ndarray:
    return np.array([p.sigma for p in evaluate(traj, rig).parameters if p.name.startswith("cam_front.")])


def lot(ground_per_m2: float, buildings: bool) -> Scene:
    ground = lot_ground(ground_per_m2)
    return lot_with_buildings(ground) if buildings else Scene.combine([ground])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=500)
    args = parser.parse_args()
    session = Session()
    rig = load_rig("robotaxi")
    cam = next(s for s in rig.config.sensors if s.kind == "camera")
    figures: dict = {"nees": consistency(args.trials)}

    sl = slalom_drive(rig)
    quad, samp = {}, {}
    for name, sc in (("asphalt lot", lot(0.01, False)), ("asphalt lot with buildings", lot(0.01, True))):
        base = camera_sigmas(along.seen(sl, rig, sc), rig)
        fine = camera_sigmas(along.seen(sl, rig, sc, density=3.0), rig)
        keep = (along.SAMPLE_SPACING_M, along.SAMPLE_INTERVAL_S)
        along.SAMPLE_SPACING_M, along.SAMPLE_INTERVAL_S = 1e-3, 1.0 / rig.keyframe_rate_hz
        try:
            dense = camera_sigmas(along.seen(sl, rig, sc), rig)
        finally:
            along.SAMPLE_SPACING_M, along.SAMPLE_INTERVAL_S = keep
        quad[name] = float(f"{np.abs(base / fine - 1).max():.3g}")
        samp[name] = float(f"{np.abs(base / dense - 1).max():.3g}")
        print(f"{name}: 3x the grid {quad[name]:.3g}, a sample per keyframe {samp[name]:.3g} (largest relative "
              "difference of a cam_front sigma)")
    figures["quadrature_max_relative"] = quad
    figures["sampling_max_relative"] = samp

    traj = generated(600.0, rig)
    canyon = canyon_around(traj)
    t = along.sample_times(traj)
    along.camera_pairs(traj, rig, cam, t, canyon)  # warm
    rays = [0]
    cast = canyon.cast

    def counting(o, d, r):
        rays[0] += len(d)
        return cast(o, d, r)

    object.__setattr__(canyon, "cast", counting)
    c0 = time.process_time()
    along.camera_pairs(traj, rig, cam, t, canyon)
    cpu = time.process_time() - c0
    figures["pairs_cpu_ms_per_pair"] = round(cpu * 1e3 / t.size, 3)
    figures["rays_per_pair"] = round(rays[0] / t.size)
    figures["ten_minute_pairs"] = int(t.size)
    print(f"10-minute drive in a canyon: {t.size} pairs, {figures['rays_per_pair']} rays and "
          f"{figures['pairs_cpu_ms_per_pair']} ms CPU per pair; load {load_average()}")

    table = {}
    scenes = {"blind": None, "asphalt lot (0.01/m²)": lot(0.01, False),
              "asphalt lot with façades (1/m²)": lot(0.01, True), "textured lot (2/m²)": lot(2.0, False),
              "open_lot": load_scene("open_lot"), "lot_buildings_one_side": load_scene("lot_buildings_one_side"),
              "street_canyon": load_scene("street_canyon"), "tunnel": load_scene("tunnel")}
    for name, sc in scenes.items():
        rep = evaluate(sl if sc is None else along.seen(sl, rig, sc), rig)
        table[name] = {p.name: (round(p.sigma / p.target, 3) if p.sigma is not None else None)
                       for p in rep.parameters if p.name.startswith("cam_front.")}
        print(name, table[name])
    figures["slalom_camera_sigma_over_target"] = table
    session.record("camera", figures, note="robotaxi rig (cam_front: 1920x1080, 1000 px, 1 px noise, 0.5-80 m, "
                                          "2000 features); NEES from tests/two_view.py's bundle adjustment")


if __name__ == "__main__":
    main()
