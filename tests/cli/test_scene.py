"""Every command that evaluates a drive takes ``--scene`` (a scene file or a bundled scene's name):
the report names the scene it was scored in, the scene is where the drive's poses say it is
(a logged drive's positions are re-based on its first), and a scene that cannot be read is the
command's one-line error naming the file. ``excite scene info`` prints what a scene holds and
where in it a lidar is degenerate."""

from __future__ import annotations

import json

import numpy as np
import pytest

from excite.cli.app import main
from excite.io.routes import write_tum
from excite.motion.vehicle import ControlProfile, drive
from excite.rig.config import load_rig
from excite.scene.along import seen
from excite.scene.files import load_scene
from excite.score.evaluate import evaluate

RIG = load_rig("robotaxi")


def ground_geojson(path, x0: float, y0: float, x1: float, y1: float, extra: list | None = None):
    """A scene file of level ground over a rectangle (local metres), and ``extra`` features."""
    ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
    doc = {"type": "FeatureCollection", "properties": {"crs": "local"},
           "features": [{"type": "Feature", "properties": {"kind": "ground"},
                         "geometry": {"type": "Polygon", "coordinates": [ring]}}] + (extra or [])}
    path.write_text(json.dumps(doc))
    return path


def weave(start=(0.0, 0.0, 0.0), duration_s: float = 30.0):
    t = np.linspace(0.0, duration_s, int(duration_s * 2) + 1)
    return drive(ControlProfile(t, 5 + 2 * np.sin(t / 3), 0.08 * np.sin(t / 4), start=start, name="weave"),
                 RIG.suspension)


def sigmas(report: dict) -> dict[str, float | None]:
    return {p["name"]: p["sigma"] for p in report["parameters"]}


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """A logged drive (TUM) starting 300 m east and 200 m north of the world's origin, and a scene
    of the ground under it only (none within 100 m of the origin)."""
    d = tmp_path_factory.mktemp("logged")
    route = write_tum(weave(start=(300.0, 200.0, 0.3)), d / "weave.tum", as_log=True)
    scene = ground_geojson(d / "ground.geojson", 150.0, 100.0, 550.0, 450.0)
    return route, scene


def test_score_names_the_scene_and_a_level_lot_takes_what_the_lidar_cannot_see(logged, capsys):
    route, scene = logged
    capsys.readouterr()
    assert main(["score", str(route), "--json"]) == 0
    blind = json.loads(capsys.readouterr().out)
    assert main(["score", str(route), "--json", "--scene", str(scene)]) == 0
    lot = json.loads(capsys.readouterr().out)
    assert blind["scene"] is None
    assert lot["scene"] == {"name": str(scene), "digest": load_scene(scene).digest}
    b, s = sigmas(blind), sigmas(lot)
    # a level lot leaves each lidar pair's x, y translation and yaw without information (the design's
    # degenerate scenes): the lidar's horizontal lever arm loses what its odometry gave it …
    assert s["lidar.trans_x"] > 2 * b["lidar.trans_x"] and s["lidar.trans_y"] > 2 * b["lidar.trans_y"]
    # … and the road in view measures its height, which planar driving leaves nearly free
    assert s["lidar.trans_z"] < b["lidar.trans_z"] / 10
    assert main(["score", str(route), "--scene", str(scene)]) == 0
    text = " ".join(capsys.readouterr().out.split())  # a long name wraps at the pipe's width
    assert f"weave with rig robotaxi in scene {scene} (sha256 {lot['scene']['digest'][:12]}):" in text


def test_a_logged_drive_sees_the_scene_where_its_poses_are(logged, capsys):
    """The TUM file's positions are re-based on its first when read; the scene is seen from where
    they were: as by the same poses placed where they are (not re-based)."""
    from excite.io.routes import read_tum

    route, scene = logged
    capsys.readouterr()
    assert main(["score", str(route), "--json", "--scene", str(scene)]) == 0
    from_file = sigmas(json.loads(capsys.readouterr().out))
    read = read_tum(route)
    assert read.origin == pytest.approx([300.0, 200.0, 0.0])
    placed = read.transformed(np.eye(3), read.origin)
    placed.origin = np.zeros(3)
    in_place = {p.name: p.sigma for p in evaluate(seen(placed, RIG, load_scene(scene)), RIG).parameters}
    assert main(["score", str(route), "--json"]) == 0
    blind = sigmas(json.loads(capsys.readouterr().out))
    # the road plane's height: seen (millimetres) where the ground is, not blind (decimetres)
    assert in_place["lidar.trans_z"] < blind["lidar.trans_z"] / 10
    for name in ("lidar.trans_z", "lidar.trans_x", "lidar.rot_x", "lidar.rot_z"):
        assert from_file[name] == pytest.approx(in_place[name], rel=1e-3), name


def _error(capsys, argv) -> str:
    capsys.readouterr()
    assert main(argv) == 1
    err = capsys.readouterr()
    lines = err.err.strip().splitlines()
    assert len(lines) == 1, err.err
    return lines[0]


def test_a_scene_that_cannot_be_read_is_each_command_s_one_line_error(logged, tmp_path, capsys):
    route, _ = logged
    bad = tmp_path / "bad.geojson"
    bad.write_text(json.dumps({"type": "FeatureCollection", "properties": {"crs": "local"}, "features": [
        {"type": "Feature", "properties": {"kind": "building", "height": -3.0},
         "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [10, 0], [10, 10], [0, 0]]]}}]}))
    missing = tmp_path / "missing.geojson"
    for argv in (["score", str(route)], ["live", str(route), "--replay", "1000x"], ["mine", str(route)],
                 ["batch", str(route)], ["validate", str(route), "--runs", "2"], ["scene", "info"]):
        line = _error(capsys, argv + ["--scene", str(bad)] if argv[0] != "scene" else argv + [str(bad)])
        assert line.startswith(f"excite: error: ") and str(bad) in line and "height" in line, line
        line = _error(capsys, argv + ["--scene", str(missing)] if argv[0] != "scene" else argv + [str(missing)])
        assert str(missing) in line and "no such file" in line, line


def test_batch_takes_a_scene_per_route_and_a_default(logged, tmp_path, capsys):
    route, scene = logged
    (tmp_path / "scenes").mkdir()
    local = ground_geojson(tmp_path / "scenes" / "lot.geojson", 150.0, 100.0, 550.0, 450.0)
    manifest = tmp_path / "routes.yaml"
    manifest.write_text(f"scene: scenes/lot.geojson\nroutes:\n  - route: {route}\n    name: top\n"
                        f"  - route: {route}\n    name: own\n    scene: open_lot\n")
    out = tmp_path / "batch.json"
    main(["batch", str(manifest), str(route), "--scene", str(scene), "--jobs", "1", "--json", str(out)])
    got = {r["name"]: r["scene"]["name"] for r in json.loads(out.read_text())["routes"]}
    assert got == {"top": str(local), "own": "open_lot", str(route): str(scene)}
    for r in json.loads(out.read_text())["routes"]:
        assert r["report"]["scene"] == r["scene"]
    manifest.write_text(f"routes:\n  - route: {route}\n  - route: {route}\n    scene: scenes/none.geojson\n")
    line = _error(capsys, ["batch", str(manifest)])
    assert "routes.1.scene" in line and str(tmp_path / "scenes" / "none.geojson") in line and str(manifest.name) in line


def test_live_s_final_update_is_score_in_the_same_scene(logged, capsys):
    route, scene = logged
    capsys.readouterr()
    main(["live", str(route), "--replay", "100000x", "--json", "--scene", str(scene)])
    updates = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    final = updates[-1]
    assert final["type"] == "final"
    assert main(["score", str(route), "--json", "--scene", str(scene)]) == 0
    scored = json.loads(capsys.readouterr().out)
    assert final["report"]["scene"] == scored["scene"] == final["scene"]
    assert final["report"]["score"] == pytest.approx(scored["score"], rel=1e-9)
    for name, s in sigmas(scored).items():
        assert sigmas(final["report"])[name] == pytest.approx(s, rel=1e-9), name
    # the live updates see the scene too: the road plane's height is found long before the end
    live = [u for u in updates if u["type"] == "update"]
    assert live and all(u["scene"] == scored["scene"] for u in live)
    z = [p["sigma"] for p in live[-1]["parameters"] if p["name"] == "lidar.trans_z"][0]
    assert z < 0.01


def test_mine_records_the_scene_of_each_log(logged, tmp_path, capsys):
    route, scene = logged
    out = tmp_path / "mined.json"
    main(["mine", str(route), "--window", "10", "--scene", str(scene), "--jobs", "1", "--json", str(out)])
    doc = json.loads(out.read_text())
    assert doc["logs"][0]["scene"] == {"name": str(scene), "digest": load_scene(scene).digest}
    assert f"seen in scene {scene}" in capsys.readouterr().out
    best = doc["best"][0]
    # the window's score is the exact evaluator's on the crop, in the scene
    assert best["confirmed_score"] == pytest.approx(best["score"], rel=0.05)


def test_scene_info_prints_what_the_scene_holds_and_where_a_lidar_is_degenerate(tmp_path, capsys):
    wall = {"type": "Feature", "properties": {"kind": "wall", "height": 4.0, "name": "long wall"},
            "geometry": {"type": "LineString", "coordinates": [[-100.0, 15.0], [100.0, 15.0]]}}
    path = ground_geojson(tmp_path / "wall.geojson", -100.0, -40.0, 100.0, 40.0, [wall])
    capsys.readouterr()
    assert main(["scene", "info", str(path), "--spacing", "20"]) == 0
    text = capsys.readouterr().out
    assert "extent: x -100 … 100 m (200 m), y -40 … 40 m (80 m)" in text
    assert "ground 1 (16,000 m²)" in text and "wall 1 (800 m²)" in text
    assert main(["scene", "info", str(path), "--spacing", "20", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["triangles"] == load_scene(path).n_triangles and doc["surfaces"] == 2
    assert doc["area_m2_by_kind"] == pytest.approx({"ground": 16000.0, "wall": 800.0})
    cells = doc["survey"]["cells"]
    assert len(cells) == 10 * 4 and len(doc["survey"]["map"]) == 4
    # a wall along x on level ground leaves the translation along it free, and only that (the
    # design's degenerate scenes), from either side and wherever its ends are in view
    assert all(c["status"] == "degenerate" and c["unobservable"] == ["x translation"] for c in cells)
    symbols = {m["symbol"]: m["meaning"] for m in doc["survey"]["legend"]}
    assert "no information along x translation" in symbols.values()
    for line in text.splitlines():
        if line.strip().startswith(tuple(symbols)) and "points)" in line:
            assert symbols[line.strip()[0]] in line


@pytest.mark.montecarlo
def test_validate_names_the_scene_it_checks_in(logged, capsys):
    route, scene = logged
    capsys.readouterr()
    assert main(["validate", str(route), "--scene", str(scene), "--runs", "2", "--duration", "8",
                 "--simulator", "model", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["scene"] == {"name": str(scene), "digest": load_scene(scene).digest}
    z = next(p for p in doc["parameters"] if p["name"] == "lidar.trans_z")
    assert z["predicted_sigma"] < 0.01  # the road in view (scene-blind: decimetres)
