"""The drivable search in a scene: every drive it scores is seen in the scene first."""

from __future__ import annotations

import pytest

from excite.errors import OptimizeError
from excite.motion.vehicle import drive
from excite.plan.drivable.search import DrivableSettings, Scorer, optimize_drivable
from excite.plan.site import Site, read_site
from excite.rig.config import RIGS_DIR, build_rig, read_yaml
from excite.scene.along import seen
from excite.scene.files import load_scene
from excite.score.evaluate import evaluate


def _lidar_rig():
    """The robotaxi without its camera: the lidar's odometry, the IMU and the wheels."""
    doc = read_yaml(RIGS_DIR / "robotaxi.yaml")
    doc["sensors"] = [s for s in doc["sensors"] if s["kind"] != "camera"]
    return build_rig(doc, base_dir=RIGS_DIR)


def test_a_scene_outside_the_lot_is_refused_naming_both_extents():
    scene = load_scene("lot_buildings_one_side")
    far = read_site({"type": "FeatureCollection", "properties": {"crs": "local"}, "features": [
        {"type": "Feature", "properties": {"role": "lot"}, "geometry": {"type": "Polygon", "coordinates": [
            [[460, -25], [540, -25], [540, 25], [460, 25], [460, -25]]]}}]})
    with pytest.raises(OptimizeError, match=r"^scene: lot_buildings_one_side.* spans x -72 to 70 m, y -45 to 66 m "
                                            r"and the lot x 460 to 540 m, y -25 to 25 m: they do not overlap"):
        DrivableSettings(site=far, scene=scene)
    DrivableSettings(site=Site.rectangle(80, 50), scene=scene)  # the lot the scene was drawn around


@pytest.mark.slow
def test_every_phase_of_the_search_scores_its_drives_in_the_scene():
    """The library, the refinement, the driver model's drives and the result: each figure is the
    scene-aware score, which for this rig is far from the blind one (the ground fixes the lidar's
    height, blind only the body's pitch and roll tell it)."""
    rig = _lidar_rig()
    scene = load_scene("lot_buildings_one_side")
    settings = DrivableSettings(duration_s=30.0, kinds=("circles",), max_elements=1, draws=5, time_budget_s=20.0,
                                workers=1, scene=scene)
    res = optimize_drivable(rig, settings)
    traj = drive(res.built.timed().profile, rig.suspension)
    in_scene = evaluate(seen(traj, rig, scene), rig).score
    blind = evaluate(traj, rig).score
    assert in_scene > 5 * blind  # the scene matters to this rig's score
    # the result's report: seen in the scene and named so
    assert res.report.scene is not None and res.report.scene["digest"] == scene.digest
    assert res.report.score == pytest.approx(in_scene, rel=1e-9)
    # the plans compared (scored by the refinement) and the driver model's drives: the scene's level
    assert all(r["score"] > 5 * blind for r in res.rows)
    assert res.robust.scores.size >= 5 and res.robust.scores.min() > 5 * blind
    # the library's rates: the design's predicted λ_min (over the whole duration) at the scene's level
    assert res.design[0]["predicted"] > 5 * blind


def test_a_lidar_rig_ranks_by_the_scenes_field_and_reports_exactly():
    """The search's two scorers: for a rig with lidars only, the field over the lot (cast once)
    and the exact scans; a rig with a camera (whose pairs depend on the drive's motion) and a
    search without a scene score every drive one way."""
    from excite.plan.drivable.search import scene_scorers
    from excite.rig.config import load_rig

    scene = load_scene("lot_buildings_one_side")
    lot = Site.rectangle(40, 30)
    rank, exact = scene_scorers(_lidar_rig(), scene, lot)
    assert rank.field is not None and exact.field is None and exact.scene is scene
    lo = rank.field.xs.min(), rank.field.ys.min()
    hi = rank.field.xs.max(), rank.field.ys.max()
    assert lo[0] < -20 and lo[1] < -15 and hi[0] > 20 and hi[1] > 15  # the whole lot, a lever arm beyond
    rank, exact = scene_scorers(load_rig("robotaxi"), scene, lot)
    assert rank is exact and exact.field is None and exact.scene is scene
    rank, exact = scene_scorers(_lidar_rig(), None, lot)
    assert rank is exact and exact.scene is None
