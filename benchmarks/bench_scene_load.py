"""A point-cloud map of 10 M points loaded and indexed, ready to ray-cast: ``load_scene`` of a
synthetic street map (the ground, façades on both sides, poles; 1 cm noise) written to a
temporary PCD (binary) and LAS file, then the ray caster's index built by the first cast.

Each run is a fresh process (its peak memory is its own): wall and CPU time of the read, of
the scene built from the points (thinning, normals, splats) and of the index, over ``--runs``
runs per format, alternating.

    python benchmarks/bench_scene_load.py [--points 10000000] [--runs 3] [--when-idle S]

``--when-idle S`` waits up to S seconds before each run until the machine's cores were ≥ 90 %
idle over 0.2 s, and says how many runs started that way.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from results import Session, spread, wait_until_idle  # noqa: E402


def street_map(n: int, seed: int = 0) -> np.ndarray:
    """``n`` points on a street 400 m long: ground (half the points), façades 15–30 m high at
    y = ±15 m with gaps, and poles every 25 m; 1 cm noise."""
    rng = np.random.default_rng(seed)
    k_ground = n // 2
    k_poles = n // 50
    k_wall = n - k_ground - k_poles
    ground = np.column_stack([rng.uniform(-200, 200, k_ground), rng.uniform(-30, 30, k_ground),
                              np.zeros(k_ground)])
    x = rng.uniform(-200, 200, k_wall)
    side = rng.choice([-15.0, 15.0], k_wall)
    height = 15.0 + 15.0 * (np.floor((x + 200) / 40) % 2)
    z = rng.uniform(0, 1, k_wall) * height
    x = np.where(np.abs((x % 40) - 20) < 2, x + 4, x)  # gaps between the buildings
    walls = np.column_stack([x, side, z])
    pole = rng.integers(0, 16, k_poles)
    a = rng.uniform(0, 2 * np.pi, k_poles)
    poles = np.column_stack([-187.5 + 25 * pole + 0.15 * np.cos(a), 12.0 + 0.15 * np.sin(a),
                             rng.uniform(0, 8, k_poles)])
    p = np.vstack([ground, walls, poles])
    return p + rng.normal(0, 0.01, p.shape)


def write_maps(points: np.ndarray, folder: Path) -> dict[str, Path]:
    import laspy
    from pypcd4 import Encoding, PointCloud

    pcd = folder / "street.pcd"
    PointCloud.from_xyz_points(points.astype(np.float32)).save(pcd, encoding=Encoding.BINARY)
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales = [0.001, 0.001, 0.001]
    header.offsets = [0.0, 0.0, 0.0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = points.T
    las.write(folder / "street.las")
    return {"pcd": pcd, "las": folder / "street.las"}


def child(path: str) -> None:
    """One timed load in this process: print its figures as JSON."""
    from excite.scene.clouds import read_points
    from excite.scene.points import scene_from_points

    t0, c0 = time.perf_counter(), time.process_time()
    cloud = read_points(path)
    t1, c1 = time.perf_counter(), time.process_time()
    scene = scene_from_points(cloud.points, cloud.normals, source=path)
    t2, c2 = time.perf_counter(), time.process_time()
    scene.cast(np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]]), 10.0)  # builds the index
    t3, c3 = time.perf_counter(), time.process_time()
    print(json.dumps({"points": int(cloud.points.shape[0]), "triangles": scene.n_triangles,
                      "read_s": t1 - t0, "build_s": t2 - t1, "index_s": t3 - t2, "total_s": t3 - t0,
                      "total_cpu_s": c3 - c0, "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=10_000_000)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--when-idle", type=float, default=0.0, metavar="S",
                        help="wait up to S seconds before each run until the machine's cores are idle")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child)
        return
    session = Session()
    with tempfile.TemporaryDirectory() as tmp:
        files = write_maps(street_map(args.points), Path(tmp))
        sizes = {k: p.stat().st_size for k, p in files.items()}
        runs: dict[str, list[dict]] = {k: [] for k in files}
        started_idle = 0
        for _ in range(args.runs):
            for kind, path in files.items():
                started_idle += wait_until_idle(args.when_idle) if args.when_idle else 0
                out = subprocess.run([sys.executable, __file__, "--child", str(path)], capture_output=True, text=True,
                                     env=dict(os.environ), check=True)
                r = json.loads(out.stdout.strip().splitlines()[-1])
                runs[kind].append(r)
                print(kind, {k: round(v, 2) if isinstance(v, float) else v for k, v in r.items()},
                      "load", " ".join(f"{x:.1f}" for x in os.getloadavg()), flush=True)
    figures = {"points": args.points, "runs_started_idle": f"{started_idle} of {args.runs * len(files)}"}
    for kind, rs in runs.items():
        figures[f"{kind}_file_mib"] = round(sizes[kind] / 2**20, 1)
        figures[f"{kind}_splats"] = rs[0]["triangles"] // 2
        for key in ("total_s", "total_cpu_s", "read_s", "build_s", "index_s"):
            figures[f"{kind}_{key}"] = spread([r[key] for r in rs], 2)
        figures[f"{kind}_peak_rss_mib"] = round(max(r["peak_rss_mib"] for r in rs))
    session.record("scene_load", figures,
                   note=f"a synthetic street map of {args.points:,} points read from a binary PCD and a LAS file, "
                        "made a scene (thinned to at most 1 M splats, normals estimated) and indexed by the ray "
                        "caster; wall seconds (total = read + build + index) and CPU seconds of all threads, "
                        "each run a fresh process")


if __name__ == "__main__":
    main()
