"""Real lots for the optimizer: GeoJSON polygons with keep-out zones, an entry pose, terrain."""

from __future__ import annotations

import json

import numpy as np
import pytest

import excite.plan as opt
from excite.cli.app import main
from excite.score.evaluate import evaluate
from excite.plan.site import read_site
from excite.rig.config import load_rig
from excite.motion.vehicle import ControlProfile, drive
from helpers import ORIGIN, L_OUTER, HOLE, RAMP, l_lot, lot_projection

def _inside(poly, p):
    """Even-odd point-in-polygon (written here, independent of excite.motion.maneuvers.Lot)."""
    poly = np.asarray(poly, float)
    inside = np.zeros(len(p), bool)
    for (x1, y1), (x2, y2) in zip(poly, np.roll(poly, -1, axis=0)):
        cross = (y1 > p[:, 1]) != (y2 > p[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            xs = x1 + (p[:, 1] - y1) * (x2 - x1) / (y2 - y1)
        inside ^= cross & (p[:, 0] < xs)
    return inside


def _edge_distance(poly, p):
    poly = np.asarray(poly, float)
    d = np.full(len(p), np.inf)
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        u = np.clip(((p - a) @ (b - a)) / ((b - a) @ (b - a)), 0, 1)
        d = np.minimum(d, np.linalg.norm(p - (a + u[:, None] * (b - a)), axis=1))
    return d


@pytest.fixture(scope="module")
def rig():
    return load_rig("robotaxi")


def test_geojson_lot_reads_to_the_polygon_it_describes():
    site = read_site(l_lot(ramp=True))
    assert site.origin is not None and len(site.lot.holes) == 1 and len(site.terrain.features) == 1
    # back through the site's own projection, every vertex lands on the test's (up to a shift)
    local = np.array(L_OUTER, float)
    shift = site.lot.polygon_m - local
    assert np.abs(shift - shift.mean(axis=0)).max() < 0.05
    assert site.lot.contains(shift.mean(axis=0) + np.array([[15.0, 15.0]]))[0]
    ramp = site.terrain.features[0]
    assert ramp.slope == pytest.approx(np.tan(np.radians(8.0)))


@pytest.mark.parametrize("doc, message", [
    ("{", "not valid JSON"),
    ({"type": "FeatureCollection", "features": []}, "exactly one lot Polygon"),
    ({"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, 1], [0, 1]]]}, "not closed"),
    ({"type": "Polygon", "coordinates": [[[200, 0], [201, 0], [201, 1], [200, 0]]]}, "lon, lat"),
    ({"type": "Feature", "properties": {"crs": "local"}, "geometry": {"type": "Polygon", "coordinates": [
        [[0, 0], [50, 0], [50, 50], [0, 50], [0, 0]], [[60, 60], [70, 60], [70, 70], [60, 60]]]}},
     "keep-out zone 1 is not inside the lot"),
    ({"type": "FeatureCollection", "properties": {"crs": "local"}, "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [
            [[0, 0], [50, 0], [50, 50], [0, 50], [0, 0]]]}},
        {"type": "Feature", "properties": {"role": "entry", "heading_deg": 0},
         "geometry": {"type": "Point", "coordinates": [1, 1]}}]}, "entry point is not inside"),
    ({"type": "FeatureCollection", "properties": {"crs": "local"}, "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [
            [[0, 0], [50, 0], [50, 50], [0, 50], [0, 0]]]}},
        {"type": "Feature", "properties": {"role": "ramp", "slope_deg": 40, "uphill_deg": 0},
         "geometry": {"type": "Polygon", "coordinates": [[[5, 5], [9, 5], [9, 9], [5, 9], [5, 5]]]}}]},
     "slope_deg must be a number between 0 and 20"),
])
def test_bad_lots_are_rejected_by_name(doc, message):
    with pytest.raises(opt.OptimizeError, match=message):
        read_site(doc if isinstance(doc, str) else json.dumps(doc))


def test_cli_names_a_bad_lot_in_one_line(tmp_path, capsys):
    bad = tmp_path / "lot.geojson"
    bad.write_text(json.dumps({"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, 1], [0, 1]]]}))
    assert main(["optimize", "--lot", str(bad), "-o", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("excite: error:") and "not closed" in err and len(err.splitlines()) == 1
    assert main(["optimize", "--lot", "80y50", "-o", str(tmp_path / "out")]) == 1
    assert "lot: expected XxY in metres" in capsys.readouterr().err
    for lot, message in (("1.2.3x50", "expected XxY in metres"), (".x50", "expected XxY in metres"),
                         ("0x50", "extent along x: 0.0 is outside the sane range [15, 2000] m"),
                         ("80x5", "extent along y: 5.0 is outside"),
                         (str(tmp_path / "missing.geojson"), "no such file")):
        assert main(["optimize", "--lot", lot, "-o", str(tmp_path / "out")]) == 1
        err = capsys.readouterr().err.strip()
        assert err.startswith("excite: error: lot:") and message in err and len(err.splitlines()) == 1, err


def test_the_check_holds_a_drive_to_the_entry_pose_and_the_terrain(rig):
    doc = {"type": "FeatureCollection", "properties": {"crs": "local"}, "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [
            [[0, 0], [80, 0], [80, 50], [0, 50], [0, 0]]]}},
        {"type": "Feature", "properties": {"role": "entry", "heading_deg": 90},
         "geometry": {"type": "Point", "coordinates": [10, 10]}},
        {"type": "Feature", "properties": {"role": "ramp", "slope_deg": 6, "uphill_deg": 90},
         "geometry": {"type": "Polygon", "coordinates": [[[5, 20], [15, 20], [15, 35], [5, 35], [5, 20]]]}}]}
    site = read_site(json.dumps(doc))
    settings = opt.OptimizeSettings(duration_s=20.0, site=site)
    t = np.linspace(0, 10, 101)
    u = 3.0 * np.sin(np.pi * t / 10) ** 2
    north = ControlProfile(t, u, np.zeros_like(t), start=(10.0, 10.0, np.pi / 2))
    from excite.plan.candidates import check

    _, bad = check(north, rig, settings, site)  # flat profile over the ramp: the grade is wrong
    assert any(v.startswith("terrain:") for v in bad)
    _, bad = check(site.drape(north, rig.suspension), rig, settings, site)
    assert bad == []
    _, bad = check(ControlProfile(t, u, np.zeros_like(t), start=(20.0, 10.0, np.pi / 2)), rig, settings, site)
    assert any(v.startswith("entry:") for v in bad)


def _plan(rig, ramp: bool, tmp_path):
    from excite.cli.optimize import write_outputs

    site = read_site(l_lot(ramp))
    s = opt.OptimizeSettings(duration_s=30.0, site=site, time_budget_s=120.0, n_random=4, max_iterations=15)
    res = opt.optimize(rig, s)
    out = tmp_path / ("ramp" if ramp else "flat")
    write_outputs(res, out, site.origin)
    return site, res, out


@pytest.mark.slow
def test_l_shaped_lot_with_a_hole_and_a_ramp(rig, tmp_path):
    """The plan stays in the L with the 3 m margin and out of the building (checked on the
    written GeoJSON, projected here), drives up or down the ramp, and determines the vertical
    lever arms better than the plan for the same lot without the ramp. (The plan is what the
    command returns: an IPOPT iterate or, within this short run, possibly the laps over the ramp
    it started from — whichever scores higher.)"""
    site, res, out = _plan(rig, True, tmp_path)
    assert res.comparison and any(r["result"] for r in res.comparison)
    doc = json.loads((out / "maneuver.geojson").read_text())
    ll = np.array(doc["features"][0]["geometry"]["coordinates"])
    x, y = lot_projection(ORIGIN).transform(ll[:, 0], ll[:, 1])
    p = np.column_stack([x, y])
    assert _inside(L_OUTER, p).all() and not _inside(HOLE, p).any()
    clearance = np.minimum(_edge_distance(L_OUTER, p), _edge_distance(HOLE, p))
    assert clearance.min() >= 3.0 - 0.02
    on_ramp = _inside(RAMP, p)
    assert on_ramp.sum() >= 5
    smp = res.trajectory.sample(res.trajectory.times(10.0))
    assert np.abs(np.degrees(res.profile.at(smp.t)["grade_rad"][on_ramp])).max() > 5.0
    assert np.ptp(smp.p_W_V[:, 2]) > 1.0  # it climbs

    _, flat, _ = _plan(rig, False, tmp_path)

    def sigma(r, name):
        return next(q.sigma for q in r.report.parameters if q.name == name)

    for name in ("lidar.trans_z", "cam_front.trans_z"):
        assert sigma(res, name) < sigma(flat, name)
    assert evaluate(drive(res.profile, rig.suspension), rig).score == pytest.approx(res.report.score, rel=1e-9)


def test_api_takes_a_geojson_lot_and_names_a_bad_one(tmp_path):
    from fastapi.testclient import TestClient

    from api import Settings, create_app

    app = create_app(Settings(db_path=tmp_path / "j.sqlite3", workers=0, score_workers=1))
    with TestClient(app, base_url="http://localhost") as c:
        r = c.post("/v1/maneuvers", json={"lot": l_lot(ramp=True), "criterion": "D", "time_budget_s": 10})
        assert r.status_code == 202, r.text
        job = c.get(r.headers["location"]).json()
        assert job["status"] == "queued"
        bad = {"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, 1], [0, 1]]]}
        r = c.post("/v1/maneuvers", json={"lot": bad})
        assert r.status_code == 422 and r.headers["content-type"].startswith("application/problem+json")
        assert r.json()["errors"][0]["field"] == "lot" and "not closed" in r.json()["detail"]
        assert c.post("/v1/maneuvers", json={"criterion": "F"}).status_code == 422


def test_api_job_on_a_georeferenced_lot_downloads_geojson_without_an_origin(rig, monkeypatch):
    """run_optimization reads the lot, and the job's GeoJSON download projects about the lot's
    own origin: the LineString lands back on the local path."""
    import api.jobs as jobs
    from api.scoring import maneuver_file

    site = read_site(l_lot(ramp=False))
    t = np.linspace(0, 20, 201)
    prof = ControlProfile(t, 3.0 * np.sin(np.pi * t / 20) ** 2, np.zeros_like(t), start=(10.0, 10.0, 0.0))
    seen = {}

    def fake_optimize(rig_, settings, progress, should_stop):
        seen["site"] = settings.lot
        from excite.plan.settings import OptimizeResult

        traj = drive(prof, rig_.suspension)
        return OptimizeResult(prof, traj, evaluate(traj, rig_), [], "converged", 1, 0.1, False)

    monkeypatch.setattr("excite.plan.optimize", fake_optimize)
    out = jobs.run_optimization({"rig": "robotaxi", "duration_s": 20, "lot_x_m": 80, "lot_y_m": 50,
                                 "limits": {}, "seed": 0, "time_budget_s": 10, "closed": False, "n_random": 0,
                                 "lot": l_lot(ramp=False), "criterion": "E"}, lambda p: None, lambda: False)
    assert seen["site"].origin == site.origin and len(seen["site"].lot.holes) == 1
    origin = (out["origin"]["lon_deg"], out["origin"]["lat_deg"])
    doc = json.loads(maneuver_file(out["profile"], rig, "geojson", "m", origin))
    ll = np.array(doc["features"][0]["geometry"]["coordinates"])
    local = site.lot.polygon_m - np.array(L_OUTER, float)  # the site's frame = the test's + a shift
    x, y = lot_projection(ORIGIN).transform(ll[:, 0], ll[:, 1])
    first = np.array([x[0], y[0]]) + local.mean(axis=0)
    assert first == pytest.approx([10.0, 10.0], abs=0.05)
