"""The drivable search with and without a scene, both results scored in the scene.

    python benchmarks/bench_drivable_scene.py [--budget 120] [--seed 0] [--scene lot_buildings_one_side]

The rig is the robotaxi without its camera (built from its bundled YAML here): the lidar is then
the rig's only exteroceptive sensor, so what it sees sets the score. The robotaxi itself is
limited by its camera's height (``cam_front.trans_z``), which no scene changes.

The problem is the default one (90 s, the 80 × 50 m lot centred on the origin: the lot the
bundled ``lot_buildings_one_side`` is drawn around, buildings 6 m past its north edge), the same
settings (seed, budget, draws) for both runs:

1. the search blind (``DrivableSettings(scene=None)``);
2. the search in the scene (every drive it scores seen in the scene, the default sampling of
   :mod:`excite.scene.along`);
3. both chosen plans' drives as instructed scored in the scene (``evaluate(seen(traj, rig,
   scene), rig)``), and blind: the ratio of the scene-aware plan's score in the scene to the
   blind plan's.

Writes ``benchmarks/results/drivable_scene.json`` (:mod:`results`).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from results import Session  # noqa: E402

from excite.motion.vehicle import drive  # noqa: E402
from excite.plan.drivable.search import DrivableSettings, optimize_drivable  # noqa: E402
from excite.rig.config import RIGS_DIR, build_rig, read_yaml  # noqa: E402
from excite.scene.along import seen  # noqa: E402
from excite.scene.files import load_scene  # noqa: E402
from excite.score.evaluate import evaluate  # noqa: E402


def lidar_rig():
    """The bundled robotaxi without its camera."""
    doc = read_yaml(RIGS_DIR / "robotaxi.yaml")
    doc["sensors"] = [s for s in doc["sensors"] if s["kind"] != "camera"]
    doc["name"] = "robotaxi without its camera"
    return build_rig(doc, base_dir=RIGS_DIR)


def worst(rep) -> str:
    p = max(rep.parameters, key=lambda p: float("inf") if p.sigma is None else p.sigma / p.target)
    return f"{p.name} {p.sigma / p.target:.3g}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=float, default=120.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--draws", type=int, default=30)
    ap.add_argument("--scene", default="lot_buildings_one_side")
    args = ap.parse_args()
    session = Session()
    rig = lidar_rig()
    scene = load_scene(args.scene)
    out, rows = {}, []
    for name, sc in (("blind", None), ("scene", scene)):
        settings = DrivableSettings(time_budget_s=args.budget, seed=args.seed, draws=args.draws, scene=sc)
        t0 = time.perf_counter()
        res = optimize_drivable(rig, settings)
        wall = time.perf_counter() - t0
        traj = drive(res.built.timed().profile, rig.suspension)
        in_scene = evaluate(seen(traj, rig, scene), rig)
        blind = evaluate(traj, rig)
        elements = [{"kind": e.kind, "x_m": round(e.pose[0], 2), "y_m": round(e.pose[1], 2),
                     "heading_deg": round(float(e.pose[2]) * 57.29577951308232, 1), "dwell_s": round(e.dwell_s, 2),
                     "params": e.params} for e in res.plan.elements]
        out[name] = {"score_in_scene": in_scene.score, "score_blind": blind.score,
                     "worst_in_scene": worst(in_scene), "worst_blind": worst(blind),
                     "p10_search": res.robust.low, "wall_s": round(wall, 1), "timings_s": res.timings_s,
                     "elements": elements}
        rows.append(f"| {name} | {in_scene.score:.4g} ({worst(in_scene)}) | {blind.score:.4g} ({worst(blind)}) | "
                    f"{' + '.join(f'{e.kind} at ({e.pose[0]:.0f}, {e.pose[1]:.0f}) m' for e in res.plan.elements)} "
                    f"| {wall:.0f} s |")
        print(rows[-1], flush=True)
    ratio = out["scene"]["score_in_scene"] / out["blind"]["score_in_scene"]
    table = ["| search | score in the scene (worst σ/target) | score blind (worst σ/target) | elements | wall |",
             "|---|---|---|---|---|", *rows]
    print("\n".join(table))
    print(f"scene-aware plan / blind plan, both scored in {scene.source}: {ratio:.3g}×")
    figures = {"ratio_in_scene": ratio, "scene": scene.source, "scene_sha256": scene.digest, "rig": rig.name,
               "budget_s": args.budget, "seed": args.seed, "draws": args.draws, **out, "table": table}
    path = session.record("drivable_scene", figures, note=(
        f"the drivable search blind and in {scene.source} (robotaxi without its camera, 90 s, 80 × 50 m, "
        f"budget {args.budget:g} s, seed {args.seed}), both plans scored in the scene: {ratio:.3g}×; "
        + " ".join(table)))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
