"""`excite optimize --drivable` / `--plan`: bad problems end in one line naming the limit; a plan
file is driven into its sheet, cones and report."""

from __future__ import annotations

import json

import pytest


@pytest.mark.parametrize("args, words", [
    (["--lot", "16x16"], "too small for any element"),
    (["--lot", "40x30", "--speed-max", "14"], "above the lot's safe speed"),
])
def test_a_bad_drivable_problem_is_one_line_and_exit_1(tmp_path, capsys, args, words):
    from excite.cli.app import main

    assert main(["optimize", "--drivable", "-o", str(tmp_path / "out"), *args]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("excite: error:") and words in err[0], err


def test_a_plan_file_is_driven_into_its_sheet_cones_and_report(tmp_path, capsys):
    from excite.cli.app import main

    plan = {"duration_s": 40, "elements": [{"kind": "figure_eight", "params": {
        "radius_m": 7, "spacing_m": 18, "speed_mps": 8, "laps": 1, "stops_per_lap": 2},
        "pose": {"x_m": 0, "y_m": 0, "heading_deg": 0}}]}
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    out = tmp_path / "out"
    assert main(["optimize", "--plan", str(tmp_path / "plan.json"), "--draws", "5", "-o", str(out)]) == 0
    for name in ("plan.json", "cones.geojson", "sheet.pdf", "sheet.png", "control.csv", "report.json"):
        assert (out / name).stat().st_size > 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["drivable"]["robust"]["draws"] == 5 and len(rep["drivable"]["instructions"]) == 1
    plan["elements"][0]["params"]["spacing_m"] = 9.0
    (tmp_path / "bad.json").write_text(json.dumps(plan))
    assert main(["optimize", "--plan", str(tmp_path / "bad.json"), "-o", str(out)]) == 1
    assert "below twice the vehicle's turning radius" in capsys.readouterr().err


@pytest.mark.parametrize("args, words", [
    (["--scene", "lot_buildings_one_side"], "--scene"),  # the free-form optimizer plans blind
    (["--drivable", "--scene", "no_such_scene.ply"], "no_such_scene.ply"),
])
def test_a_bad_scene_is_one_line_and_a_non_zero_exit(tmp_path, capsys, args, words):
    from excite.cli.app import main

    assert main(["optimize", "-o", str(tmp_path / "out"), *args]) != 0
    err = [line for line in capsys.readouterr().err.strip().splitlines() if line.strip()]
    assert any(words in line for line in err), err


def test_a_plan_file_is_scored_in_the_scene_it_is_given(tmp_path, capsys):
    from excite.cli.app import main
    from excite.io.routes import read_route
    from excite.rig.config import load_rig
    from excite.scene.along import seen
    from excite.scene.files import load_scene
    from excite.score.evaluate import evaluate

    plan = {"duration_s": 30, "elements": [{"kind": "circles", "params": {
        "radius_m": 8, "speed_mps": 6, "laps": 1, "stops_per_lap": 0}, "pose": {"x_m": 0, "y_m": 5, "heading_deg": 0}}]}
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    out = tmp_path / "out"
    assert main(["optimize", "--plan", str(tmp_path / "plan.json"), "--draws", "5", "--scene",
                 "lot_buildings_one_side", "-o", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    scene = load_scene("lot_buildings_one_side")
    assert rep["scene"]["digest"] == scene.digest
    rig = load_rig("robotaxi")
    traj = read_route(out / "control.csv", suspension=rig.suspension)
    assert rep["score"] == pytest.approx(evaluate(seen(traj, rig, scene), rig).score, rel=1e-3)
